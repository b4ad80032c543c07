"""The haptic world: objects, the Myrmex read-out and the 2 N glance controller (fast simulator)."""

import math

import numpy as np
import pytest
import torch

from ham.errors import HamError
from ham.world import objects
from ham.world.config import WorldConfig, make_simulator
from ham.world.glance import FastSimulator, PoseConfig, solve_stop_height
from ham.world.sensor import SensorConfig, normalize

PAPER = objects.resolve_set("paper")


@pytest.fixture(scope="module")
def sim():
    return make_simulator(WorldConfig())


def test_paper_set_order_and_ids():
    assert [o.name for o in PAPER] == ["box", "ramp_up", "convex", "ramp_down"]
    assert [objects.object_id(o.name) for o in PAPER] == [0, 1, 2, 3]
    assert all(o.width == pytest.approx(0.09) and o.depth == pytest.approx(0.09) for o in PAPER)
    assert len({o.height for o in PAPER}) == 1


def test_profiles_match_the_reference_shapes():
    box, up, convex, down = PAPER
    x = np.array([-0.044, 0.0, 0.044])
    assert np.allclose(box.height_at(x), 0.045)
    assert up.height_at(x)[0] < up.height_at(x)[1] < up.height_at(x)[2]  # rises to the right
    assert np.allclose(down.height_at(x), up.height_at(-x))  # mirror image
    c = convex.height_at(x)
    assert c[0] < c[1] < c[2] and c[1] > up.height_at(x)[1]  # convex: above the chord
    assert np.all(box.height_at(np.array([-0.06, 0.06])) == 0)  # table beside the block


def test_flat_pad_on_box_is_uniform_at_2N(sim):
    r = sim.glance([0], [0.0], [0.0])
    img = r.pressure[0].numpy()
    assert float(r.force[0]) == pytest.approx(2.0, abs=1e-5)
    assert np.allclose(img, img.mean(), rtol=1e-5)
    # 2 N over 64 cm^2 is 312.5 Pa (section "Haptic Control of the Simulated Myrmex")
    assert img.mean() == pytest.approx(312.5, rel=1e-4)
    assert bool(r.contact[0]) and not bool(r.blocked[0])
    assert float(r.z[0]) < 0.045  # the foam is pressed a little into the surface


def test_ramp_top_edge_is_a_line(sim):
    r = sim.glance([1], [0.5], [0.0])  # flat pad, centre 2.25 cm left of the ramp's top edge
    img = r.pressure[0].numpy()
    lit = np.flatnonzero(img.sum(0) > 0)
    assert 1 <= len(lit) <= 2  # one or two taxel columns wide ...
    assert np.all(img[:, lit] > 0)  # ... along the whole contact (every row): a line, not blobs
    assert 11 <= lit[0] <= 13  # edge at u = +2.25 cm -> column 12
    assert float(r.force[0]) == pytest.approx(2.0, abs=1e-5)


def test_pad_tilted_to_the_ramp_slope_touches_over_a_band(sim):
    slope = math.atan(0.045 / 0.09)
    q_phi = -slope / (math.pi / 2)  # +u end raised to follow the rising ramp
    r = sim.glance([1], [0.0], [q_phi])
    cols = r.pressure[0].numpy().sum(0)
    assert (cols > 0).sum() >= 12
    assert cols.max() / cols[cols > 0].min() < 1.5  # a roughly even band
    flat = sim.glance([1], [0.0], [0.0]).pressure[0].numpy().sum(0)
    assert (flat > 0).sum() < (cols > 0).sum()


def test_objects_1_and_3_mirror_each_other(sim):
    g = torch.Generator().manual_seed(0)
    qx = torch.rand(200, generator=g) * 2 - 1
    qp = torch.rand(200, generator=g) * 2 - 1
    a = sim.glance(torch.full((200,), 1), qx, qp)
    b = sim.glance(torch.full((200,), 3), -qx, -qp)
    assert torch.allclose(a.pressure, b.pressure.flip(-1), atol=2e-2 * float(a.pressure.max()))
    assert torch.allclose(a.z, b.z, atol=1e-6)
    assert torch.equal(a.contact, b.contact)


def test_stop_height_is_exact_against_bisection():
    g = torch.Generator().manual_seed(1)
    e = torch.rand(64, 32, generator=g, dtype=torch.float64) * 0.01
    target = 0.004
    z = solve_stop_height(e, target)
    lo, hi = e.min(1).values - target, e.max(1).values
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        f = (e - mid[:, None]).clamp_min(0).sum(1)
        lo, hi = torch.where(f > target, mid, lo), torch.where(f > target, hi, mid)
    assert torch.allclose(z, 0.5 * (lo + hi), atol=1e-12)
    assert torch.allclose(
        (e - z[:, None]).clamp_min(0).sum(1), torch.full((64,), target, dtype=torch.float64)
    )


def test_near_vertical_pad_terminates_without_nan(sim):
    r = sim.glance([0, 0, 1, 3], [0.0, 0.3, -0.2, 0.9], [1.0, -1.0, 0.98, -1.0])
    assert torch.isfinite(r.pressure).all() and torch.isfinite(r.z).all()
    assert bool(r.blocked[:2].all())  # the housing, not the foam, stops a vertical pad
    assert (r.force <= 2.0 + 1e-5).all()
    n = normalize(r.pressure, "l2")
    assert torch.isfinite(n).all()
    empty = ~r.contact
    assert empty.any() and torch.all(n[empty] == 0)


def test_every_glance_in_a_random_batch_is_finite_and_stops(sim):
    g = torch.Generator().manual_seed(2)
    n = 5000
    ids = torch.randint(0, 4, (n,), generator=g)
    r = sim.glance(ids, torch.rand(n, generator=g) * 2 - 1, torch.rand(n, generator=g) * 2 - 1)
    assert torch.isfinite(r.pressure).all()
    ok = ~r.blocked
    assert torch.allclose(r.force[ok].float(), torch.full((int(ok.sum()),), 2.0), atol=1e-3)
    assert (r.force[r.blocked] < 2.0 + 1e-4).all()


@pytest.mark.parametrize("kind", ["l2", "l1"])
def test_normalization(sim, kind):
    p = sim.glance([2], [0.1], [0.2]).pressure
    n = normalize(p, kind)
    assert n.shape == (1, 256)
    norm = n.norm(p=2 if kind == "l2" else 1).item()
    assert norm == pytest.approx(1.0, rel=1e-5)
    assert torch.equal(normalize(torch.zeros(2, 16, 16), kind), torch.zeros(2, 256))
    with pytest.raises(HamError, match="accepted: l2, l1, none"):
        normalize(p, "max")


def test_gazebo_spread_and_quantization_options():
    world = WorldConfig(sensor=SensorConfig(spread_sigma=0.005, quantize_bits=12))
    sim = make_simulator(world)
    r = sim.glance([1], [0.5], [0.0])
    img = r.pressure[0].numpy()
    assert (img.sum(0) > 0).sum() >= 4  # the edge line is blurred over several columns
    levels = img / (world.sensor.full_scale / 4095)
    assert np.allclose(levels, np.round(levels), atol=1e-3)  # 12-bit cells


def test_authors_pose_mapping():
    sim = make_simulator(WorldConfig(pose=PoseConfig.preset("authors")))
    x, phi = sim.poses(torch.tensor([0, 3]), torch.tensor([1.0, 1.0]), torch.tensor([1.0, 1.0]))
    assert float(phi[0]) == pytest.approx(0.3 * math.pi)
    assert float(x[0]) == pytest.approx(0.09 - 0.068 * math.sin(0.3 * math.pi), abs=1e-7)
    assert float(x[1]) == pytest.approx(0.055 - 0.068 * math.sin(0.3 * math.pi), abs=1e-7)


def test_user_defined_objects_through_the_public_api():
    ridge = objects.HapticObject.from_function(
        "test_bump", lambda x: 0.03 + 0.01 * np.cos(np.asarray(x) / 0.045 * np.pi / 2)
    )
    steps = objects.HapticObject.from_heightmap("test_stairs", [0.01, 0.01, 0.03, 0.03, 0.02])
    poly = objects.HapticObject.from_polyline(
        "test_notch", [(0, 0.04), (0.04, 0.04), (0.04, 0.02), (0.09, 0.02)]
    )
    for o in (ridge, steps, poly):
        objects.register(o, replace=True)
    sim = FastSimulator([ridge, steps, poly])
    r = sim.glance([0, 1, 2], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    assert torch.allclose(r.force.float(), torch.full((3,), 2.0), atol=1e-4)
    assert objects.get("test_notch") is poly
    with pytest.raises(HamError, match="already registered"):
        objects.register(poly)


@pytest.mark.parametrize(
    "call, match",
    [
        (
            lambda s: s.glance([0], [float("nan")], [0.0]),
            r"q_x = nan is outside the accepted range \[-1, 1\]",
        ),
        (
            lambda s: s.glance([0], [0.0], [1.5]),
            r"q_phi = 1.5 is outside the accepted range \[-1, 1\]",
        ),
        (lambda s: s.glance([7], [0.0], [0.0]), r"object id 7 out of range; accepted: 0..3"),
        (lambda s: s.glance([0, 1], [0.0, 0.1, 0.2], [0.0]), "equal lengths"),
    ],
)
def test_bad_glance_input_is_named(sim, call, match):
    with pytest.raises(HamError, match=match):
        call(sim)


@pytest.mark.parametrize(
    "key, match",
    [
        ("nope", "unknown object 'nope'"),
        (9999, "unknown object id 9999"),
        ("9998", "unknown object id 9998"),
    ],
)
def test_unknown_objects_are_named(key, match):
    with pytest.raises(HamError, match=match):
        objects.get(key)


def test_bad_configs_are_named():
    with pytest.raises(HamError, match="foam_stiffness"):
        SensorConfig(foam_stiffness=-1.0)
    with pytest.raises(HamError, match="phi_max"):
        PoseConfig(phi_max=4.0)
    with pytest.raises(HamError, match="unknown simulator 'ode'"):
        make_simulator(WorldConfig(simulator="ode"))


def test_inlined_image_equals_the_sensor_component():
    # The fast path writes Myrmex.image's result straight into the output; it must stay identical.
    g = torch.Generator().manual_seed(3)
    n = 3000
    ids = torch.randint(0, 4, (n,), generator=g)
    qx, qp = torch.rand(n, generator=g) * 2 - 1, torch.rand(n, generator=g) * 2 - 1
    fast = make_simulator(WorldConfig())
    assert fast._direct_image
    plain = make_simulator(WorldConfig())
    plain._direct_image = False
    a, b = fast.glance(ids, qx, qp), plain.glance(ids, qx, qp)
    assert torch.equal(a.pressure, b.pressure) and torch.equal(a.z, b.z)


def test_the_fast_glances_end_within_the_height_bound():
    # the bound a simulator file's heights are checked against (and the envs' height space):
    # the built-in glances, with extreme pads, stay inside it
    import itertools

    from ham.world.glance import height_bound

    g = torch.Generator().manual_seed(0)
    ran = 0
    for dims, pitch, housing, foam in itertools.product(
        [("x", "phi"), ("x", "y", "phi", "phi_y")], [0.001, 0.005, 0.2], [0.0, 0.3], [0.001, 0.1]
    ):
        sensor = SensorConfig(pitch=pitch, housing_thickness=housing, foam_thickness=foam)
        objs = "paper" if len(dims) == 2 else "curvature2d"
        try:
            sim = make_simulator(WorldConfig(objects=objs, pose_dims=dims, sensor=sensor))
        except HamError:  # a pad wider than the paper's objects are deep
            continue
        q = [torch.rand(500, generator=g) * 2 - 1 for _ in range(4)]
        ids = torch.randint(0, len(sim.objects), (500,), generator=g)
        kw = {"q_y": q[2], "q_phi_y": q[3]} if len(dims) == 4 else {}
        z = sim.glance(ids, q[0], q[1], **kw).z
        assert float(z.abs().max()) <= height_bound(sensor), (dims, pitch, housing, foam)
        ran += 1
    assert ran >= 16
