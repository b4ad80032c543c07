"""The extended glance g: (x, y, phi, phi_y) -> (p, h) on height-field objects."""

import math

import numpy as np
import pytest
import torch

from ham.errors import HamError
from ham.world import objects
from ham.world.config import WorldConfig, make_simulator
from ham.world.extended_glance import EDGE_POINTS, ExtendedSimulator, stagger_order
from ham.world.glance import POSE_DIMS, FastSimulator, glance_at
from ham.world.objects import HapticObject
from ham.world.sensor import SensorConfig

# The paper's objects and the mhsb ones (trough and double_ridge with the line glance's feature
# points, which the extended glance carries over as lines along y).
EXTRUDED = objects.resolve_set("paper") + objects.resolve_set("mhsb")


def _dome(x, y):
    return 0.03 - 3.0 * (x**2 + y**2)


DOME = HapticObject.from_surface("t_dome", _dome)
CYL_X = HapticObject.from_surface("t_cyl_x", lambda x, y: 0.02 + np.sqrt(0.05**2 - y**2) - 0.04)
CYL_Y = HapticObject.from_surface("t_cyl_y", lambda x, y: 0.02 + np.sqrt(0.05**2 - x**2) - 0.04)
SLOPE_Y = HapticObject.from_surface("t_slope_y", lambda x, y: 0.03 + 0.2 * y)


@pytest.fixture(scope="module")
def paper_pair():
    return FastSimulator(EXTRUDED), ExtendedSimulator(EXTRUDED)


def test_agrees_with_the_line_glance_on_extruded_objects(paper_pair):
    fast, ext = paper_pair
    g = torch.Generator().manual_seed(0)
    n = 3000
    ids = torch.randint(0, len(EXTRUDED), (n,), generator=g)
    qx, qp = torch.rand(n, generator=g) * 2 - 1, torch.rand(n, generator=g) * 2 - 1
    a_all = fast.glance(ids, qx, qp)
    b_all = ext.glance(ids, qx, qp, torch.zeros(n), torch.zeros(n))
    # Where the block's end meets the rim of the pad's rigid back, the extended glance stops the
    # pad (ExtendedSimulator._edge_stops); the line glance, kept as the paper's, lets its back
    # pass through the block: 10 of these 3,000 glances (steep pads over the trough's high ends
    # and the convex's end), the line glance's back 0.27 to 11 mm inside the block.
    edge = (b_all.z - a_all.z).abs() >= 2e-6
    assert 0 < int(edge.sum()) <= 15
    assert {EXTRUDED[int(i)].name for i in ids[edge]} <= {"trough", "convex"}
    assert bool((b_all.blocked[edge] & ~a_all.blocked[edge] & (b_all.z > a_all.z)[edge]).all())
    u = np.linspace(-0.04, 0.04, 160_001)
    f = fast.sensor.foam_thickness
    for k in edge.nonzero().flatten().tolist():  # the pad's back line (w = f) against the block
        obj, x, phi = EXTRUDED[int(ids[k])], float(a_all.x[k]), float(a_all.phi[k])
        px = x + u * math.cos(phi) + f * math.sin(phi)
        on, edge_x = np.abs(px) <= obj.width / 2, np.clip(px, -obj.width / 2, obj.width / 2)
        top = np.where(on, obj.height_at(edge_x), 0.0)
        depth = [
            (top - float(r.z[k]) + u * math.sin(phi) - f * math.cos(phi)).max()
            for r in (a_all, b_all)
        ]
        assert depth[0] > 2e-4 and depth[1] < 1e-5, depth
    ids, qx, qp = ids[~edge], qx[~edge], qp[~edge]  # everywhere else, the same glance
    n = len(ids)
    a = fast.glance(ids, qx, qp)
    b = ext.glance(ids, qx, qp, torch.zeros(n), torch.zeros(n))
    assert float((a.z - b.z).abs().max()) < 2e-6  # within 2 micrometres (measured: 0.5 um)
    assert ext.features == fast.features and sum(fast.features) > 0
    assert torch.equal(a.blocked, b.blocked) and torch.equal(a.contact, b.contact)
    assert float((a.force - b.force).abs().max()) < 1e-3
    assert float((a.pressure - b.pressure).abs().max()) < 5.0  # Pa, of up to thousands
    touched = a.force > 0
    pa, pb = a.pressure[touched].reshape(-1, 256), b.pressure[touched].reshape(-1, 256)
    corr = torch.nn.functional.cosine_similarity(pa, pb, dim=1)
    assert float(corr.min()) > 0.999
    assert torch.equal(b.height, b.z) and torch.equal(b.y, torch.zeros(n))


def _brute_stop_height(obj, x, y, phi, phi_y, sim):
    """The stop height from the object's own surface in float64: read-out points, then the exact
    root of the piecewise-linear force by sorting."""
    u = sim._u.double().numpy()[None, :]
    v = sim._v.double().numpy()[:, None]
    if sim._dv_col is not None:  # the staggered read-out: each column's v offset
        v = v + sim._dv_col.double().numpy()[None, :]
    cp, sp, cy, sy = math.cos(phi), math.sin(phi), math.cos(phi_y), math.sin(phi_y)
    dx = u * cp - v * sy * sp
    dy = v * cy + 0 * u
    dz = -u * sp - v * sy * cp
    e = np.sort((obj.surface(x + dx, y + dy) - dz).ravel())[::-1]
    target = sim.glance_config.force_threshold / sim._c0
    csum = np.cumsum(e)
    for k in range(1, len(e) + 1):
        z = (csum[k - 1] - target) / k
        if k == len(e) or z >= e[k]:
            return z


@pytest.mark.parametrize(
    ("q", "obj"),
    [
        ((0.0, 0.0, 0.0, 0.0), DOME),
        ((0.3, -0.4, 0.1, 0.2), DOME),
        ((-0.5, 0.6, -0.2, 0.3), DOME),
        ((0.2, 0.1, 0.0, -0.25), SLOPE_Y),
        ((0.1, -0.3, 0.15, 0.1), CYL_X),
    ],
)
def test_stop_height_is_exact_on_height_fields(q, obj):
    sim = ExtendedSimulator([obj])
    qx, qy, qp, qpy = q
    r = sim.glance([0], [qx], [qp], [qy], [qpy])
    assert not bool(r.blocked[0]) and float(r.force[0]) == pytest.approx(2.0, abs=1e-4)
    assert float(r.x[0]) == pytest.approx(qx * 0.045, abs=1e-7)
    assert float(r.y[0]) == pytest.approx(qy * 0.045, abs=1e-7)
    assert float(r.phi_y[0]) == pytest.approx(qpy * math.pi / 2, abs=1e-6)
    z = _brute_stop_height(
        obj, float(r.x[0]), float(r.y[0]), float(r.phi[0]), float(r.phi_y[0]), sim
    )
    assert float(r.height[0]) == pytest.approx(z, abs=3e-6)  # the bilinear 0.2 mm map


def test_dome_image_is_round_at_the_top():
    sim = ExtendedSimulator([DOME], rows_per_taxel=4)
    r = sim.glance([0], [0.0], [0.0], [0.0], [0.0])
    img = r.pressure[0]
    assert torch.allclose(img, img.T, atol=1e-3 * float(img.max()))  # round: as wide in u as in v
    assert float(img[7:9, 7:9].min()) == pytest.approx(float(img.max()), rel=1e-5)  # centre
    assert float(img[0, 0]) == 0.0 and float(img[7, 0]) == 0.0  # a small patch, not the whole pad
    assert float(r.height[0]) < 0.03 and float(r.height[0]) > 0.0295


def test_tilt_about_x_is_the_tilt_about_y_transposed():
    # The cylinder along x under phi_y is the cylinder along y under phi, seen transposed.
    sim = ExtendedSimulator([CYL_X, CYL_Y], rows_per_taxel=4)
    a = sim.glance([1], [0.2], [0.3], [0.0], [0.0])
    b = sim.glance([0], [0.0], [0.0], [0.2], [-0.3])
    # (u, v) -> (v, u) maps +phi (lowers +u) to +phi_y (lowers +v); x -> y as well
    b2 = sim.glance([0], [0.0], [0.0], [0.2], [0.3])
    assert float(a.z[0]) == pytest.approx(float(b2.z[0]), abs=1e-6)
    assert torch.allclose(a.pressure[0], b2.pressure[0].T, atol=1.0)
    assert float(b.z[0]) != pytest.approx(float(b2.z[0]), abs=1e-4)  # the sign matters


def test_object_pose_rotates_and_shifts_the_object():
    sim = ExtendedSimulator([CYL_X, CYL_Y], rows_per_taxel=4)
    plain = sim.glance([1], [0.3], [0.2], [0.0], [0.0])
    turned = sim.glance([0], [0.3], [0.2], [0.0], [0.0], object_pose=([math.pi / 2], [0.0], [0.0]))
    assert float(turned.z[0]) == pytest.approx(float(plain.z[0]), abs=2e-6)
    assert torch.allclose(turned.pressure[0], plain.pressure[0], atol=2.0)
    # Shifting the dome by (dx, dy) is glancing at the pose shifted the other way.
    sim = ExtendedSimulator([DOME])
    a = sim.glance([0], [0.0], [0.1], [0.0], [0.0], object_pose=(0.0, -0.009, 0.0045))
    b = sim.glance([0], [0.2], [0.1], [-0.1], [0.0])
    assert float(a.z[0]) == pytest.approx(float(b.z[0]), abs=2e-6)
    with pytest.raises(HamError, match="object_pose dx"):
        sim.glance([0], [0.0], [0.0], object_pose=(0.0, 1.0, 0.0))
    with pytest.raises(HamError, match="accepted: \\(yaw, dx, dy\\)"):
        sim.glance([0], [0.0], [0.0], object_pose=(0.0, 0.0))


def test_steep_tilt_about_x_is_blocked_by_the_housing():
    sim = ExtendedSimulator([objects.get("box")])
    r = sim.glance([0, 0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [1.0, -1.0])
    # The face stands vertical: a housing side rests on the box, 3 mm foam + 1 cm body off.
    assert bool(r.blocked.all()) and float(r.force.max()) < 2.0
    assert torch.allclose(r.z, torch.full((2,), 0.045 + 0.04), atol=1e-5)


def test_bad_poses_are_refused_by_name():
    sim = ExtendedSimulator([DOME])
    with pytest.raises(HamError, match="q_y = 1.5"):
        sim.glance([0], [0.0], [0.0], [1.5], [0.0])
    with pytest.raises(HamError, match="q_phi_y = nan"):
        sim.glance([0], [0.0], [0.0], [0.0], [float("nan")])
    with pytest.raises(HamError, match="equal lengths"):
        sim.glance([0, 0], [0.0, 0.1, 0.2], [0.0])
    with pytest.raises(HamError, match="rows_per_taxel"):
        ExtendedSimulator([DOME], rows_per_taxel=0)


def _back_depth(obj, res, k=0, n=801):
    """How deep (m) the pad's rigid back (the plane ``w = foam_thickness`` over the 8 cm face)
    reaches into the block ``obj`` (vertical sides) at glance ``k`` of ``res``: > 0 inside."""
    s = np.linspace(-0.04, 0.04, n)
    u, v = np.meshgrid(s, s)
    phi, phi_y = float(res.phi[k]), float(res.phi_y[k])
    cp, sp, cy, sy = math.cos(phi), math.sin(phi), math.cos(phi_y), math.sin(phi_y)
    w = 0.003
    x = float(res.x[k]) + u * cp - v * sy * sp + w * sp * cy
    y = float(res.y[k]) + v * cy + w * sy
    z = float(res.z[k]) - u * sp - v * sy * cp + w * cp * cy
    on = (np.abs(x) <= obj.width / 2) & (np.abs(y) <= obj.depth / 2)
    top = obj.surface(
        np.clip(x, -obj.width / 2, obj.width / 2), np.clip(y, -obj.depth / 2, obj.depth / 2)
    )
    return float((np.where(on, top, 0.0) - z).max())


def test_the_pads_back_stops_where_a_blocks_edge_meets_it():
    """The pad tilted 0.5 rad about both axes over the flat block's corner (a pose of the
    cross-check lattice): the block's edge meets the rim of the pad's rigid back between the
    housing's samples and the read-out rows. The glance stops the pad there, touching and not
    inside (checked on a 0.1 mm grid of the back); without the edge points the back passed
    0.5 mm into the block (docs/crosscheck_curvature2d.md, "Which model is off")."""
    flat = [o for o in objects.resolve_set("curvature2d") if o.name == "flat_low"]
    q = ([-1.0], [0.5 / (math.pi / 2)], [-1.0], [-0.5 / (math.pi / 2)])  # x, phi, y, phi_y
    sim = ExtendedSimulator(flat)
    r = sim.glance([0], *q)
    assert bool(r.blocked[0]) and -5e-5 < _back_depth(flat[0], r) < 1e-5  # grid: 0.1 mm
    no_edges = ExtendedSimulator(flat)
    none = torch.zeros(1, EDGE_POINTS)
    no_edges._edge_points = lambda ids, *a: (none + no_edges._hu[0], none + no_edges._hv[0])
    old = no_edges.glance([0], *q)
    assert not bool(old.blocked[0]) and _back_depth(flat[0], old) > 4e-4
    assert float(r.height[0]) - float(old.height[0]) > 4e-4
    with pytest.raises(HamError, match="housing_edge_samples = 1; accepted: an integer 2 .. 256"):
        ExtendedSimulator([DOME], housing_edge_samples=1)
    assert "housing_edge_samples" not in sim.describe()
    assert ExtendedSimulator([DOME], housing_edge_samples=9).describe()["housing_edge_samples"] == 9


def test_the_pads_back_stops_on_its_rim_between_the_housings_samples():
    """The pad over the cone's plinth edge, tilted 0.5 rad about x (a pose of the cross-check
    lattice): its back's rim line passes the cone nearest the apex between the housing's 3
    points per side, a smooth maximum. With the rim sampled every 10 mm the back stops there
    (within the 10 mm sampling's ~0.1 mm); with only the housing's samples (``rim_samples =
    3``) it sank 0.9 mm into the cone (1.42 mm before the staggered read-out;
    docs/crosscheck_curvature2d_grid.md)."""
    cone = [o for o in objects.resolve_set("curvature2d") if o.name == "cone"]
    q = ([0.5], [0.0], [1.0], [-0.5 / (math.pi / 2)])  # x, phi, y, phi_y
    r = ExtendedSimulator(cone).glance([0], *q)
    old = ExtendedSimulator(cone, rim_samples=3).glance([0], *q)
    assert bool(r.blocked[0]) and -5e-5 < _back_depth(cone[0], r) < 2e-4
    assert not bool(old.blocked[0]) and _back_depth(cone[0], old) > 8e-4
    with pytest.raises(HamError, match="rim_samples = 1; accepted: an integer 2 .. 256"):
        ExtendedSimulator(cone, rim_samples=1)
    assert ExtendedSimulator(cone, rim_samples=5).describe()["rim_samples"] == 5


def test_the_staggered_read_out_feels_an_edge_inside_a_taxel_row():
    """A level pad over the flat block's edge along x, the edge 1 mm into taxel row 8 (v from 0
    to 5 mm): the foam there is pressed over a fifth of each cell. The staggered read-out's 4
    points per taxel lie at 4 different v (0.625, 1.875, 3.125, 4.375 mm into the row), so one
    of 4 is on the block: a quarter of a full cell's pressure; points on the taxel's centre line
    (``stagger=False``) read all or nothing: nothing."""
    flat = [o for o in objects.resolve_set("curvature2d") if o.name == "flat_low"]
    q = ([0.0], [0.0], [0.044 / 0.045], [0.0])  # x, phi, y (the edge at y = 45 mm), phi_y
    r = ExtendedSimulator(flat).glance([0], *q)
    line = ExtendedSimulator(flat, stagger=False).glance([0], *q)
    assert float(r.force[0]) == pytest.approx(2.0, abs=1e-4)
    img, old = r.pressure[0], line.pressure[0]
    full = float(img[7, 4])
    assert full > 0 and torch.allclose(img[:8], torch.full((8, 16), full), rtol=1e-5)
    assert torch.allclose(img[8], torch.full((16,), 0.25 * full), rtol=1e-5)
    assert float(img[9:].abs().max()) == 0.0
    assert float(old[8].abs().max()) == 0.0 and float(old[7].min()) > 0


def test_the_stagger_puts_each_point_of_a_taxel_in_its_own_stratum():
    """For any ``supersample`` the stagger is a permutation: no quarter of the cell holds two
    of a taxel's points, none is left empty (a stride sharing a factor with ``su`` would)."""
    assert stagger_order(4) == [1, 3, 0, 2]
    for su in range(1, 17):
        assert sorted(stagger_order(su)) == list(range(su)), su
    sim = ExtendedSimulator([DOME], SensorConfig(supersample=6))
    assert sorted(set(sim._dv.tolist())) == pytest.approx(
        [(k + 0.5) / 6 * sim.sensor.pitch - 0.5 * sim.sensor.pitch for k in range(6)]
    )


def test_the_line_glance_refuses_y_and_phi_y():
    fast = FastSimulator(objects.resolve_set("paper"))
    with pytest.raises(HamError, match="q_y = .* is not 0.*pose-dims"):
        fast.glance([0], [0.0], [0.0], q_y=[0.2])
    with pytest.raises(HamError, match="q_phi_y"):
        fast.glance([0], [0.0], [0.0], q_phi_y=[-0.1])
    r = fast.glance([0], [0.0], [0.0], q_y=[0.0], q_phi_y=None)
    assert torch.equal(r.height, r.z) and float(r.y[0]) == 0.0 and float(r.phi_y[0]) == 0.0
    data = r.to_json(0)
    assert {"height", "y", "phi_y"} <= set(data) and data["height"] == data["z"]


def test_world_pose_dims_pick_the_simulator():
    assert WorldConfig().pose_dims == ("x", "phi")
    assert "pose_dims" not in WorldConfig().to_dict()  # the paper's world saves what it saved
    assert isinstance(make_simulator(WorldConfig()), FastSimulator)
    w = WorldConfig(pose_dims=("x", "y", "phi", "phi_y"))
    assert isinstance(make_simulator(w), ExtendedSimulator)
    assert WorldConfig.from_dict(w.to_dict()) == w
    assert WorldConfig.from_dict({"objects": "paper"}).pose_dims == ("x", "phi")
    assert WorldConfig(pose_dims="x,phi_y").pose_dims == ("x", "phi_y")
    for bad, match in [
        (("x", "z"), "unknown pose dimension 'z'"),
        (("phi", "x"), "in that order"),
        ((), "non-empty"),
        (("x", "x"), "each once"),
    ]:
        with pytest.raises(HamError, match=match):
            WorldConfig(pose_dims=bad)


def test_a_height_field_object_picks_the_extended_glance():
    objects.register(DOME, replace=True)
    sim = make_simulator(WorldConfig(objects="t_dome"))
    assert isinstance(sim, ExtendedSimulator)
    r = sim.glance([0], [0.0], [0.0])
    assert float(r.force[0]) == pytest.approx(2.0, abs=1e-4)


def test_glance_at_maps_columns_to_dims():
    sim = ExtendedSimulator([DOME])
    q = torch.tensor([[0.1, -0.2, 0.3, 0.4], [0.0, 0.5, -0.1, 0.2]])
    a = glance_at(sim, [0, 0], q, POSE_DIMS)
    b = sim.glance([0, 0], q[:, 0], q[:, 2], q[:, 1], q[:, 3])
    assert torch.equal(a.pressure, b.pressure) and torch.equal(a.z, b.z)
    c = glance_at(sim, [0, 0], q[:, [1, 3]], ("y", "phi_y"))
    d = sim.glance([0, 0], [0.0], [0.0], q[:, 1], q[:, 3])
    assert torch.equal(c.z, d.z)
    fast = FastSimulator(objects.resolve_set("paper"))
    e = glance_at(fast, [1], [[0.2, 0.1]], ("x", "phi"))
    assert torch.equal(e.z, fast.glance([1], [0.2], [0.1]).z)
    with pytest.raises(HamError, match="accepted: \\(B, 2\\)"):
        glance_at(sim, [0], q, ("x", "phi"))


OBJECTS_FILE = """
from ham.world.objects import HapticObject, register

register(HapticObject.from_surface("cli_dome", lambda x, y: 0.03 - 3.0 * (x**2 + y**2)))
register(HapticObject.from_surface("cli_tilt", lambda x, y: 0.03 + 0.2 * y))
"""


def test_cli_glance_extended_json(ham_cli, ham_main, tmp_path):
    import json

    f = tmp_path / "objs.py"
    f.write_text(OBJECTS_FILE)
    args = ("glance", "--objects-file", str(f), "--object", "cli_dome")
    r = ham_cli(*args, "--x", "0.1", "--y", "-0.2", "--phi", "0.1", "--phi-y", "0.2", "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["y"] == pytest.approx(-0.2 * 0.045, abs=1e-7)
    assert d["phi_y"] == pytest.approx(0.2 * math.pi / 2, abs=1e-6)
    assert d["height"] == d["z"] and d["force"] == pytest.approx(2.0, abs=1e-4)
    assert d["pose_dims"] == ["x", "y", "phi", "phi_y"] and len(d["pressure"]) == 16
    # The same glance in-process gives the same numbers.
    sim = ExtendedSimulator([DOME])  # the same surface
    ref = sim.glance([0], [0.1], [0.1], [-0.2], [0.2])
    assert d["height"] == pytest.approx(float(ref.height[0]), abs=1e-9)
    # y moves the pad on an object sloping in y: higher at +y.
    hi = ham_main("glance", "--objects-file", str(f), "--object", "cli_tilt", "--x", "0",
                 "--phi", "0", "--y", "0.5", "--json")  # fmt: skip
    lo = ham_main("glance", "--objects-file", str(f), "--object", "cli_tilt", "--x", "0",
                 "--phi", "0", "--y", "-0.5", "--json")  # fmt: skip
    assert json.loads(hi.stdout)["height"] > json.loads(lo.stdout)["height"] + 0.005
    text = ham_main(*args, "--x", "0", "--phi", "0")
    assert text.returncode == 0 and "height" in text.stdout and "phi_y" in text.stdout


def test_cli_pose_dims_refused_by_name(ham_cli, ham_main):
    r = ham_cli("glance", "--object", "box", "--x", "0", "--phi", "0", "--pose-dims", "x,z")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "unknown pose dimension 'z'" in r.stderr and "x,y,phi,phi_y" in r.stderr
    r = ham_main("glance", "--object", "box", "--x", "0", "--phi", "0", "--pose-dims", "phi,x")
    assert r.returncode == 2 and "in that order" in r.stderr
    r = ham_main("glance", "--object", "box", "--x", "0", "--phi", "0", "--y", "1.5")
    assert r.returncode == 2 and "q_y = 1.5" in r.stderr
    # The paper's glance is unchanged: no y, no tilt about x, height is z.
    r = ham_main("glance", "--object", "ramp_up", "--x", "0.3", "--phi", "0.2", "--json")
    import json

    d = json.loads(r.stdout)
    fast = FastSimulator(objects.resolve_set("paper")).glance([1], [0.3], [0.2])
    assert d["z"] == float(fast.z[0]) and d["pressure"] == fast.pressure[0].double().tolist()
    assert d["y"] == 0.0 and d["phi_y"] == 0.0 and d["pose_dims"] == ["x", "phi"]


def test_narrow_spike_stops_a_tilted_pad_over_a_turned_object():
    # A 0.6 mm x 2 cm spike on a 1 cm box (tests/test_narrow_features.py): narrower than the
    # read-out spacing, carried over from the line glance as a feature line along y.
    pts = [(-0.045, 0.01), (-0.0003, 0.01), (-0.0003, 0.03), (0.0003, 0.03), (0.0003, 0.01)]
    obj = HapticObject.from_polyline("t_spike", [*pts, (0.045, 0.01)])
    sim = ExtendedSimulator([obj])
    assert sim.features == [2]
    n = 201
    qx = torch.linspace(-0.1, 0.1, n)
    ids = torch.zeros(n, dtype=torch.long)
    runs = {}
    for yaw in (0.0, 0.4):  # the spike's line across the tilted rows, then turned
        pose = (torch.full((n,), yaw), torch.zeros(n), torch.zeros(n))
        runs[yaw] = sim.glance(ids, qx, 0.0, 0.2, 0.15, object_pose=pose)
    sim._feat_x = None  # the same glances without the feature line
    for yaw, r in runs.items():
        pose = (torch.full((n,), yaw), torch.zeros(n), torch.zeros(n))
        bare = sim.glance(ids, qx, 0.0, 0.2, 0.15, object_pose=pose)
        assert float(r.height.min()) > 0.03  # on the spike: its top (3 cm) or its tilted line
        assert bool((r.height >= bare.height).all())
        if yaw == 0.0:  # between two columns the pad used to sink to the box (1 cm)
            assert float((r.height - bare.height).max()) > 0.01


def test_heights_reads_the_surface():
    sim = ExtendedSimulator([DOME])
    x = torch.tensor([[0.0, 0.01, -0.02, 0.05]])
    y = torch.tensor([[0.0, -0.015, 0.03, 0.0]])
    h = sim.heights([0], x, y)
    ref = DOME.surface(x.double().numpy(), y.double().numpy())
    np.testing.assert_allclose(h.numpy(), ref, atol=1e-6)  # 0.5 mm bilinear grid; table beside
    assert float(h[0, 3]) == 0.0


def test_objects_of_different_sizes_glance_as_alone():
    # Different grids per object take the per-row path; it must give each object's own glances.
    wide = HapticObject.from_surface("t_wide", _dome, width=0.15, depth=0.12)
    ramp = objects.get("trough")  # extruded, with feature lines
    mixed = ExtendedSimulator([wide, ramp])
    assert not mixed._uniform
    g = torch.Generator().manual_seed(1)
    n = 300
    q = [torch.rand(n, generator=g) * 2 - 1 for _ in range(4)]
    pose = (torch.rand(n, generator=g) * 6, torch.zeros(n) + 0.004, torch.zeros(n) - 0.003)
    for oid, obj in enumerate((wide, ramp)):
        alone = ExtendedSimulator([obj])
        for kw in ({}, {"object_pose": pose}):
            a = mixed.glance(torch.full((n,), oid), *q, **kw)
            b = alone.glance(torch.zeros(n, dtype=torch.long), *q, **kw)
            assert torch.equal(a.z, b.z) and torch.equal(a.pressure, b.pressure)


def test_a_mixed_batch_gives_each_glance_as_alone():
    # The simulator computes a mixed batch in object order (cache locality) and puts each result
    # back in its row: the rows must equal the same glances one object at a time.
    objs = [DOME, CYL_X, objects.get("trough"), SLOPE_Y]
    sim = ExtendedSimulator(objs, chunk=64)  # several chunks, each mixing objects
    g = torch.Generator().manual_seed(3)
    n = 400
    ids = torch.randint(0, len(objs), (n,), generator=g)
    q = [torch.rand(n, generator=g) * 2 - 1 for _ in range(4)]
    pose = (torch.rand(n, generator=g) * 6, torch.full((n,), 0.002), torch.full((n,), -0.001))
    for kw in ({}, {"object_pose": pose}):
        mixed = sim.glance(ids, *q, **kw)
        for oid in range(len(objs)):
            rows = (ids == oid).nonzero().squeeze(1)
            sub = {"object_pose": tuple(t[rows] for t in pose)} if kw else {}
            alone = sim.glance(ids[rows], *(t[rows] for t in q), **sub)
            for name in ("pressure", "z", "force", "blocked", "x", "y", "phi", "phi_y"):
                assert torch.equal(getattr(mixed, name)[rows], getattr(alone, name)), name
