"""MuJoCo glances on height-field objects and the 4-D pose (x, y, phi, phi_y) of issue 12.

Every test runs the real MuJoCo engine; none asserts a timing.
"""

import math
import os
import subprocess
import sys

import numpy as np
import pytest
import torch

from ham.errors import HamError
from ham.world.objects import HapticObject, resolve_set
from ham.world.sensor import SensorConfig

mujoco = pytest.importorskip("mujoco")

from ham.world.mujoco_sim import (  # noqa: E402
    HFIELD_TILE_CELLS,
    SETTLED,
    MujocoConfig,
    MujocoSimulator,
    build_model,
    hfield_samples,
    image_correlation,
)

PHI_MAX = math.pi / 2
#: The pose of the tilted-plane test (rad) and the plane that lies parallel to the face there.
PHI, PHI_Y = 0.2, 0.15
SLOPE_X = -math.tan(PHI)
SLOPE_Y = -math.sin(PHI_Y) / (math.cos(PHI_Y) * math.cos(PHI))


def _plane(x, y):
    return 0.04 + SLOPE_X * x + SLOPE_Y * y


def _dome(x, y):
    return 0.02 + 0.02 * np.clip(1 - (x**2 + y**2) / 0.045**2, 0, None)


PLANE = HapticObject.from_surface("tilted_plane", _plane)
DOME = HapticObject.from_surface("dome_test", _dome)


@pytest.fixture(scope="module")
def sim() -> MujocoSimulator:
    return MujocoSimulator([PLANE, DOME, resolve_set("paper")[0]], threads=2)


def test_height_field_becomes_an_hfield_geom_the_right_way_round():
    m = build_model([PLANE, DOME], config=MujocoConfig(hfield_spacing=1e-3))
    hs = hfield_samples(PLANE, 1e-3)
    assert hs.shape == (91, 91)  # an even number of 1 mm cells: the centre lines are sampled
    # Tiles of HFIELD_TILE_CELLS cells a side, sharing their border samples.
    tiles = [m.geom(i) for i in range(m.ngeom) if m.geom(i).name.startswith("obj0_hfield_")]
    assert len(tiles) == math.ceil(90 / HFIELD_TILE_CELLS) ** 2
    assert all(g.type[0] == mujoco.mjtGeom.mjGEOM_HFIELD for g in tiles)
    # Rays straight down meet the plane's own height at (x, y): rows run from -y to +y.
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)  # geom poses for the rays; no collision of the pad at rest
    geomid = np.zeros(1, dtype=np.int32)
    for x, y in [(0.03, 0.035), (-0.02, -0.04), (0.0, 0.0), (0.041, -0.012)]:
        dist = mujoco.mj_ray(
            m, d, np.array([x, y, 0.5]), np.array([0, 0, -1.0]), None, 1, -1, geomid
        )
        assert 0.5 - dist == pytest.approx(float(_plane(x, y)), abs=1e-7)


def test_pose_rotation_follows_the_spec(sim):
    """d = R_y(phi) R_x(phi_y) (u, v, 0) as written in issue 12's contract."""
    q_phi, q_phi_y = 0.3, -0.2
    m, d, res = sim.settled_scene(1, 0.1, q_phi, -0.2, q_phi_y)
    phi, phi_y = float(res.phi[0]), float(res.phi_y[0])
    assert phi == pytest.approx(q_phi * PHI_MAX) and phi_y == pytest.approx(q_phi_y * PHI_MAX)
    rot = d.xmat[m.body("pad").id].reshape(3, 3)
    for u, v in [(0.04, 0.0), (0.0, 0.04), (-0.03, 0.02)]:
        want = [
            u * math.cos(phi) - v * math.sin(phi_y) * math.sin(phi),
            v * math.cos(phi_y),
            -u * math.sin(phi) - v * math.sin(phi_y) * math.cos(phi),
        ]
        np.testing.assert_allclose(rot @ [u, v, 0.0], want, atol=1e-6)
    # y is the object's half depth times q_y; the pad stands there.
    assert float(res.y[0]) == pytest.approx(-0.2 * DOME.depth / 2)
    assert d.xpos[m.body("pad").id][1] == pytest.approx(float(res.y[0]))


def test_tilted_plane_face_parallel_stops_at_the_analytic_height():
    """The face parallel to a sloped plane: all 256 taxels press equally, each a linear spring
    (contact_stiffness), so the summed normal force 2 N sinks the face ``p = 2 N / (256 k)``
    along the normal, ``p / n_z`` below the plane under the face centre. Settled far tighter
    than a table glance (as the calibration does): the depth is micrometres."""
    sim = MujocoSimulator(
        [PLANE], threads=1, settle_speed=1e-9, settle_tolerance=1e-6, max_steps=4000
    )
    r = sim.glance([0], [0.0], [PHI / PHI_MAX], [0.0], [PHI_Y / PHI_MAX])
    assert int(r.info["status"][0]) == SETTLED
    k = sim.config.contact_stiffness
    force = float(r.force[0])
    assert force == pytest.approx(2.0, rel=1e-5)
    n_z = 1.0 / math.sqrt(1.0 + SLOPE_X**2 + SLOPE_Y**2)
    want = float(_plane(0.0, 0.0)) - force / (256 * k) / n_z
    assert float(r.z[0]) == pytest.approx(want, abs=2e-8)
    assert float(r.height[0]) == float(r.z[0])
    # Every taxel carries its share: the image is uniform to a few percent.
    img = r.pressure[0].numpy()
    assert img.min() > 0.95 * img.mean() and img.max() < 1.05 * img.mean()


def test_dome_glance_one_contact_per_taxel(sim):
    """A taxel near a height-field vertex meets several triangle prisms; only its deepest
    contact is kept, so it is one spring like its neighbours."""
    m, d, res = sim.settled_scene(1, 0.2, 0.1, 0.3, -0.1)
    assert bool(res.contact[0])
    con = d.contact
    n = d.ncon
    geoms = con.geom[:n]
    tax = np.maximum(sim._geom_taxel[geoms[:, 0]], sim._geom_taxel[geoms[:, 1]])
    kept = (tax >= 0) & (con.exclude[:n] == 0)
    assert kept.any()
    assert np.bincount(tax[kept]).max() == 1
    assert ((tax >= 0) & (con.exclude[:n] != 0)).any()  # there were several to thin
    # The stop height lies within a millimetre of the dome under the touching taxels.
    assert float(res.z[0]) == pytest.approx(
        float(_dome(float(res.x[0]), float(res.y[0]))), abs=5e-3
    )


def test_gazebo_face_keeps_its_contact_points_on_a_height_field():
    """The gazebo read-out's one face is not thinned to one contact: flat on the dome's apex it
    rests on the apex (the prisms meeting there each a contact spring: sunk a fraction of a
    millimetre; one contact alone would sink 2 mm), tilted it settles as the taxels do."""
    sim = MujocoSimulator([DOME], threads=1, readout="gazebo")
    r = sim.glance([0, 0], [0.0, 0.3], [0.0, 0.1], [0.0, -0.2], [0.0, 0.1])
    assert (r.info["status"].numpy() == SETTLED).all()
    assert float(r.z[0]) == pytest.approx(float(_dome(0.0, 0.0)), abs=5e-4)
    assert r.contact.all()


def test_paper_object_with_zero_extended_pose_is_the_paper_glance(sim):
    ids, qx, qp = [2, 2, 2], [-0.5, 0.0, 0.7], [0.1, -0.3, 0.0]
    a = sim.glance(ids, qx, qp)
    b = sim.glance(ids, qx, qp, [0.0] * 3, [0.0] * 3)
    for k in ("pressure", "force", "z", "x", "phi"):
        assert torch.equal(getattr(a, k), getattr(b, k)), k
    assert (a.y == 0).all() and (a.phi_y == 0).all()


def test_paper_box_tilted_about_x_is_glanced_from_a_clear_start(sim):
    """phi_y != 0 on an extruded object: the start height comes from MuJoCo's collision test."""
    r = sim.glance([2], [0.0], [0.0], [0.0], [0.2 / PHI_MAX])
    assert int(r.info["status"][0]) == SETTLED
    # The lowest row of taxels rests on the box top (4.5 cm): the face centre sits higher by
    # half the tilted face's drop (4 cm * sin 0.2) minus the rim sphere's reach beyond it.
    assert 0.045 < float(r.z[0]) < 0.045 + 0.04 * math.sin(0.2)
    assert bool(r.contact[0])


def test_vertical_pad_flush_beside_a_height_field_glances_like_beside_a_box(sim):
    """q_x = q_phi = -1 stands the pad vertical in the plane of the object's side wall, tilted by
    float32's cos(pi/2) = -4e-8: MuJoCo reports nanometre contacts that no lift clears (this
    raised "no clear start height" for every height-field object). The pad now starts beside
    the wall and slides down it to the table, as it does beside the paper's box."""
    r = sim.glance([1, 2], [-1.0, -1.0], [-1.0, -1.0])
    z, force, status = r.z.numpy(), r.force.numpy(), r.info["status"].numpy()
    assert (status == status[1]).all() and np.allclose(z, z[1], atol=2e-4), (z, status)
    assert np.allclose(force, force[1], atol=0.05), force


def test_bad_inputs_are_named(sim):
    with pytest.raises(HamError, match=r"q_y = 1.5 .*\[-1, 1\]"):
        sim.glance([1], [0.0], [0.0], [1.5], [0.0])
    with pytest.raises(HamError, match=r"q_phi_y = nan"):
        sim.glance([1], [0.0], [0.0], [0.0], [float("nan")])
    with pytest.raises(HamError, match=r"q_x, q_phi, q_y and q_phi_y must have equal lengths"):
        sim.glance([1, 1], [0.0, 0.1], [0.0, 0.0], [0.0, 0.1, 0.2])
    with pytest.raises(HamError, match="object_pose.*accepted: None"):
        sim.glance([1], [0.0], [0.0], object_pose=(torch.zeros(1), torch.zeros(1), torch.zeros(1)))
    with pytest.raises(HamError, match="hfield_spacing = 0.*positive"):
        MujocoSimulator([DOME], hfield_spacing=0.0)


def test_describe_names_hfield_spacing_only_for_height_fields(sim):
    assert sim.describe()["mujoco"]["hfield_spacing"] == sim.config.hfield_spacing
    paper = MujocoSimulator(resolve_set("paper"), threads=1)
    assert "hfield_spacing" not in paper.describe()["mujoco"]


def test_render_takes_the_extended_pose(tmp_path):
    """``ham render --y --phi-y``: a PNG where EGL/OSMesa exists, else a clear message; a pose
    outside [-1, 1] is refused by name."""
    out = tmp_path / "scene.png"
    env = dict(os.environ, MPLBACKEND="Agg")
    env.pop("DISPLAY", None)
    cmd = [sys.executable, "-m", "ham.cli.mujoco_cmds", "render", "--object", "0", "--x", "0.2"]
    cmd += ["--phi", "0.1", "--y", "0.3", "--phi-y", "-0.1", "--out", str(out)]
    cmd += ["--width", "320", "--height", "240"]
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=120)
    if p.returncode == 0:
        assert out.stat().st_size > 1000
    else:
        assert "OpenGL" in p.stderr or "MUJOCO_GL" in p.stderr, p.stderr
    # A pose outside [-1, 1] is refused by name before anything is drawn.
    from ham.cli.mujoco_cmds import render_glance

    with pytest.raises(HamError, match=r"q_y = 1.5 .*\[-1, 1\]"):
        render_glance("paper", "0", 0.2, 0.1, tmp_path / "bad.png", q_y=1.5)
    assert not (tmp_path / "bad.png").exists()


def test_dome_agrees_with_the_fast_extended_glance():
    """Issue 12: on curvature2d's dome, MuJoCo and the fast extended glance (its foam calibrated
    to MuJoCo's taxel stiffness, docs/crosscheck.md) both feel contact, at contact heights within
    1 mm and with correlated images (docs/crosscheck_curvature2d.md)."""
    from ham.world.extended_glance import ExtendedSimulator

    dome = next(o for o in resolve_set("curvature2d") if o.name == "dome")
    mj = MujocoSimulator([dome], threads=2)
    sensor = SensorConfig(foam_stiffness=mj.config.contact_stiffness / mj.sensor.taxel_area)
    mj = MujocoSimulator([dome], sensor, threads=2)
    fast = ExtendedSimulator([dome], sensor)
    q = np.array(
        [
            [0.0, 0.0, 0.0, 0.0],
            [0.5, -0.5, 0.1, 0.1],
            [-0.6, 0.3, -0.15, 0.2],
            [0.3, 0.7, 0.2, -0.1],
            [-0.4, -0.8, 0.0, -0.25],
            [0.9, 0.0, 0.25, 0.0],
        ]
    )
    ids = np.zeros(len(q), dtype=np.int64)
    r = mj.glance(ids, q[:, 0], q[:, 2], q[:, 1], q[:, 3])
    f = fast.glance(ids, q[:, 0], q[:, 2], q[:, 1], q[:, 3])
    assert (r.info["status"].numpy() == SETTLED).all() and not f.blocked.any()
    assert r.contact.all() and f.contact.all()
    np.testing.assert_allclose(r.height.numpy(), f.height.numpy(), atol=1e-3)
    for k in ("x", "y", "phi", "phi_y"):
        assert torch.equal(getattr(r, k), getattr(f, k)), k  # one pose mapping
    assert image_correlation(r.pressure, f.pressure).mean() >= 0.95


def test_foam_taxel_sinks_like_the_foam_at_the_saddles_point_contact():
    """Issue 12: at the saddle pose where the sphere taxel stopped highest above the fast model
    (the pad's corner on the saddle's rim, docs/crosscheck_curvature2d_grid.md), the sphere
    taxel answers as if its whole cell were pressed (over 1 mm above the converged foam); the
    foam taxel model pushes with the cell's mean compression and stops within 0.2 mm of the
    converged foam, its image the foam's (a point contact: the fast model's 4 points per taxel
    sample it coarsely, 0.86 against the converged foam here, and stop 0.13 mm high)."""
    from ham.experiments.crosscheck2d import converged_foam
    from ham.world.extended_glance import ExtendedSimulator

    saddle = next(o for o in resolve_set("curvature2d") if o.name == "saddle")
    sensor = SensorConfig(foam_stiffness=MujocoConfig().contact_stiffness / 25e-6)
    t = 0.5 / PHI_MAX
    q = np.array([[-1.0, -1.0, -t, -t], [1.0, 1.0, t, t]])  # (q_x, q_y, q_phi, q_phi_y)
    ids = np.zeros(len(q), dtype=np.int64)
    f = ExtendedSimulator([saddle], sensor).glance(ids, q[:, 0], q[:, 2], q[:, 1], q[:, 3])
    assert not f.blocked.any()
    fine = converged_foam([saddle], sensor).glance(ids, q[:, 0], q[:, 2], q[:, 1], q[:, 3])
    dh = {}
    for model in ("sphere", "foam"):
        mj = MujocoSimulator([saddle], sensor, threads=1, taxel_model=model, max_steps=400)
        r = mj.glance(ids, q[:, 0], q[:, 2], q[:, 1], q[:, 3])
        assert (r.info["status"].numpy() == SETTLED).all(), model
        dh[model] = (r.height - fine.height).numpy() * 1e3
        if model == "foam":
            assert image_correlation(r.pressure, fine.pressure).min() >= 0.99
    assert (dh["sphere"] > 1.0).all()
    assert (np.abs(dh["foam"]) < 0.2).all()
    assert ((f.height - fine.height).abs().numpy() * 1e3 < 0.3).all()


def test_foam_taxel_pushes_with_the_cells_mean_compression_on_a_flat_top():
    """Over a whole flat top every cell is pressed evenly: the foam taxel and the sphere taxel
    are the same spring, so the pad stops at the same height (the flat-box calibration holds)."""
    flat = next(o for o in resolve_set("curvature2d") if o.name == "flat_low")
    heights = []
    for model in ("sphere", "foam"):
        mj = MujocoSimulator([flat], threads=1, taxel_model=model)
        r = mj.glance([0], [0.0], [0.0], [0.0], [0.0])
        assert int(r.info["status"][0]) == SETTLED
        heights.append(float(r.height[0]))
    assert abs(heights[0] - heights[1]) < 2e-6


@pytest.mark.parametrize(
    "options, match",
    [
        ({"taxel_model": "springs"}, "taxel_model = 'springs'; accepted: sphere, foam"),
        ({"taxel_model": "foam", "readout": "gazebo"}, "accepted: readout = 'taxels'"),
        ({"taxel_model": "foam", "hfield_contacts": "all"}, "hfield_contacts = 'deepest'"),
        ({"foam_points": 0}, "foam_points = 0; accepted: a positive integer"),
    ],
)
def test_taxel_model_options_are_checked(options, match):
    with pytest.raises(HamError, match=match):
        MujocoConfig(**options)


def test_describe_names_the_taxel_model_only_when_it_is_foam():
    assert "taxel_model" not in MujocoSimulator([DOME], threads=1).describe()["mujoco"]
    d = MujocoSimulator([DOME], threads=1, taxel_model="foam").describe()["mujoco"]
    assert d["taxel_model"] == "foam" and d["foam_points"] == 8
