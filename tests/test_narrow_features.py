"""Narrow features: the fast simulator's pad stops on a peak narrower than its read-out spacing.

A 0.6 mm wide, 2 cm tall spike on a 1 cm box used to fall between two read-out points (1.25 mm
apart): the pad passed through it to the box at 1.00 cm with a uniform image, unflagged.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ham.world.config import WorldConfig, make_simulator
from ham.world.glance import FastSimulator
from ham.world.objects import HapticObject, resolve_set
from ham.world.sensor import SensorConfig

A, BASE, TOP, WIDTH = 0.045, 0.01, 0.03, 0.0006


def spike(width: float = WIDTH, top: float = TOP) -> HapticObject:
    w = width / 2
    pts = [(-A, BASE), (-w, BASE), (-w, top), (w, top), (w, BASE), (A, BASE)]
    return HapticObject.from_polyline("spike", pts)


def _scan(sim, n=401, phi=0.0):
    qx = torch.linspace(-0.1, 0.1, n)  # the spike at x = 0 under the pad's middle half
    return sim.glance(torch.zeros(n, dtype=torch.long), qx, torch.full((n,), phi))


@pytest.mark.parametrize("taxels, pitch", [(16, 0.005), (8, 0.01), (32, 0.0025)])
def test_the_pad_stops_on_a_narrow_spike(taxels, pitch):
    sim = FastSimulator([spike()], SensorConfig(taxels=taxels, pitch=pitch))
    r = _scan(sim)
    # 2 N on one read-out point compresses the foam by target = 2 N / c0 (0.5 mm at 16 x 5 mm):
    # the pad stops at most that far below the spike's top, and never above it.
    c0 = sim._c0
    assert float(r.z.min()) >= TOP - 2.0 / c0 - 1e-6
    assert float(r.z.max()) <= TOP
    assert torch.allclose(r.force, torch.full_like(r.force, 2.0), atol=1e-3)
    assert not bool(r.blocked.any()) and bool(r.contact.all())
    # The image is the spike's line: one or two columns pressed, all rows equal.
    cols = r.pressure[:, 0, :]
    assert int((cols > 0).sum(1).max()) <= 2
    assert torch.equal(r.pressure, r.pressure[:, :1, :].expand_as(r.pressure))


def test_no_pose_pushes_the_spike_through_the_foam():
    sim = FastSimulator([spike()])
    g = 121
    qx, qp = torch.meshgrid(torch.linspace(-1, 1, g), torch.linspace(-1, 1, g), indexing="ij")
    r = sim.glance(torch.zeros(g * g, dtype=torch.long), qx.reshape(-1), qp.reshape(-1))
    c, s = torch.cos(r.phi).double(), torch.sin(r.phi).double()
    u = -r.x.double() / c  # where the spike meets the face (pad coordinate)
    under = u.abs() < 0.5 * sim.sensor.size - 1e-3
    depth = TOP - (r.z.double() - u * s)  # how far the spike's top reaches past the face
    assert int(under.sum()) > 1000
    # At most the one-point compression (0.5 mm): never through the 3 mm foam.
    assert float(depth[under].max()) <= 2.0 / sim._c0 + 1e-6


def test_wide_features_and_the_paper_objects_take_the_plain_path():
    # The paper's objects have no narrow peak for any of these pads: their glances are computed
    # exactly as before (tables bit-identical; docs/world.md).
    for sensor in (SensorConfig(), SensorConfig(taxels=8, pitch=0.01), SensorConfig(taxels=32, pitch=0.0025)):  # fmt: skip
        sim = make_simulator(WorldConfig(objects="paper", sensor=sensor))
        assert sim.features == [0, 0, 0, 0]
    # A 3 mm wide spike is sampled anyway: no feature points.
    assert FastSimulator([spike(width=0.003)]).features == [0]
    assert FastSimulator([spike()]).features == [2]  # the two ends of its 0.6 mm top


def test_objects_without_features_are_unchanged_beside_one_with():
    box = resolve_set("paper")  # the four paper objects (ids 0..3); the spike is id 4
    n = 4096
    g = torch.Generator().manual_seed(0)
    ids = torch.randint(0, 4, (n,), generator=g)
    qx, qp = torch.rand(n, generator=g) * 2 - 1, torch.rand(n, generator=g) * 2 - 1
    plain = FastSimulator(box).glance(ids, qx, qp)
    mixed = FastSimulator([*box, spike()]).glance(ids, qx, qp)
    for key in ("pressure", "force", "z", "contact", "blocked"):
        assert torch.equal(getattr(plain, key), getattr(mixed, key)), key
    # ...and the spike's rows in a mixed batch are its rows alone.
    ids[::3] = 4
    mixed = FastSimulator([*box, spike()]).glance(ids, qx, qp)
    sel = ids == 4
    alone = FastSimulator([spike()]).glance(
        torch.zeros(int(sel.sum()), dtype=torch.long), qx[sel], qp[sel]
    )
    for key in ("pressure", "force", "z", "contact", "blocked"):
        assert torch.equal(getattr(mixed, key)[sel], getattr(alone, key)), key
    assert bool((mixed.z[sel] > TOP - 0.001).any())  # some rows stand on the spike


def test_spike_matches_mujoco():
    pytest.importorskip("mujoco")
    from ham.world.mujoco_sim import MujocoSimulator

    objs = [spike()]
    mj = MujocoSimulator(objs, threads=1)
    k = mj.config.contact_stiffness / mj.sensor.taxel_area  # the fast foam calibrated to MuJoCo
    fast = FastSimulator(objs, SensorConfig(foam_stiffness=k))
    qx = torch.tensor([-0.05, -0.02, 0.0, 0.01, 0.03])
    ids, phi = torch.zeros(5, dtype=torch.long), torch.zeros(5)
    a, b = mj.glance(ids, qx, phi), fast.glance(ids, qx, phi)
    # Measured: MuJoCo 2.94-2.99 cm, fast 2.950-2.975 cm.
    np.testing.assert_allclose(a.z.numpy(), b.z.numpy(), atol=5e-4)
    assert not bool(a.blocked.any()) and math.isclose(float(a.force.min()), 2.0, abs_tol=0.02)
