"""Objects that vary in x and y: the curvature2d and composite sets, their splits, objects from
grey-scale images and triangle meshes, height fields in objects files, and `ham objects --set`."""

import itertools
import json

import matplotlib.image as mpimg
import numpy as np
import pytest
import trimesh

from ham.errors import HamError
from ham.world import objects
from ham.world.objects import HapticObject
from tests.conftest import ok, one_line_error, run_ham, run_ham_inprocess

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def at(obj: HapticObject, x: float, y: float) -> float:
    return float(obj.surface(np.array([x]), np.array([y]))[0])


# --------------------------------------------------------------------------- sets
def test_paper_and_mhsb_keep_their_ids_and_order():
    assert objects.names()[:8] == [
        "box", "ramp_up", "convex", "ramp_down", "ridge", "trough", "step", "double_ridge",
    ]  # fmt: skip
    assert [o.name for o in objects.resolve_set("paper")] == objects.names()[:4]
    assert not any(o.varies_in_y for o in objects.resolve_set("paper"))


def test_curvature2d_shapes():
    objs = {o.name: o for o in objects.resolve_set("curvature2d")}
    assert len(objs) >= 8 and all(o.varies_in_y for o in objs.values())
    assert {"flat_low", "flat_high", "cylinder_x", "cylinder_y", "dome", "saddle", "bowl"} <= set(
        objs
    )
    low, high = objs["flat_low"], objs["flat_high"]  # differ only in height
    f_low, f_high = low.height_field(9), high.height_field(9)
    assert (low.width, low.depth) == (high.width, high.depth)
    assert np.ptp(f_high - f_low) == 0 and (f_high - f_low)[0, 0] == pytest.approx(0.02)
    d = 0.03
    cx, cy = objs["cylinder_x"], objs["cylinder_y"]
    assert at(cx, -d, 0) == at(cx, d, 0) == at(cx, 0, 0) > at(cx, 0, d)  # axis along x
    assert at(cy, 0, -d) == at(cy, 0, d) == at(cy, 0, 0) > at(cy, d, 0)  # axis along y
    dome, bowl, saddle = objs["dome"], objs["bowl"], objs["saddle"]
    assert at(dome, 0, 0) > at(dome, d, 0) and at(dome, 0, 0) > at(dome, 0, d)
    assert at(bowl, 0, 0) < at(bowl, d, 0) and at(bowl, 0, 0) < at(bowl, 0, d)
    assert at(saddle, d, 0) > at(saddle, 0, 0) > at(saddle, 0, d)
    pyramid, cone = objs["pyramid"], objs["cone"]
    r = 0.02
    assert at(pyramid, r, 0) == pytest.approx(at(pyramid, r, r))  # square contours: ridges
    assert at(cone, r, 0) == pytest.approx(at(cone, r / 2**0.5, r / 2**0.5))  # round contours
    # a ridge of the pyramid: the diagonal stands above its neighbours on both sides
    assert at(pyramid, r, r) > at(pyramid, r - 0.003, r + 0.003)
    assert at(pyramid, r, r) > at(pyramid, r + 0.003, r - 0.003)


def composite_slot_windows(obj: HapticObject) -> list[np.ndarray]:
    """The top under an 8 x 8 cm pad centred on each slot, on a 2 mm grid."""
    g = np.linspace(-0.04, 0.04, 41)
    gx, gy = np.meshgrid(g, g)
    return [obj.surface(gx + cx, gy + cy) for cx, cy in objects.COMPOSITE_SLOTS.values()]


def test_composite_needs_a_search():
    train = objects.resolve_set("composite")
    assert len(train) >= 12 and train == objects.resolve_set("composite:train")
    codes = objects.composite_codes()
    assert len(codes) == len(set(codes)) == 12
    assert all(sorted(c) == sorted("EFVC") for c in codes)
    for obj in train:
        assert (obj.width, obj.depth) == (0.16, 0.16) and obj.varies_in_y
        assert obj.width <= objects.MAX_SIZE
    # one glance (one slot) leaves 3 arrangements; two slots determine it
    for s in range(4):
        for f in "EFVC":
            assert sum(c[s] == f for c in codes) == 3
    for s, t in itertools.combinations(range(4), 2):
        assert len({(c[s], c[t]) for c in codes}) == 12
    # the surfaces say the same: an 8 x 8 cm window sees one feature, shared by 3 objects
    windows = [composite_slot_windows(o) for o in train]
    for s in range(4):
        for i, j in itertools.combinations(range(12), 2):
            same = np.array_equal(windows[i][s], windows[j][s])
            assert same == (codes[i][s] == codes[j][s]), (train[i].name, train[j].name, s)
    # features differ from one another: flat is flat, a bump rises, a dimple sinks, a ridge too
    w = dict(zip(codes[0], windows[0], strict=True))
    plinth = w["F"][0, 0]
    assert np.ptp(w["F"]) == 0
    assert w["V"].max() > plinth and w["V"].min() == plinth
    assert w["C"].min() < plinth and w["C"].max() == plinth
    assert w["E"].max() > plinth and np.array_equal(w["E"][10], w["E"][30])  # along y


def test_composite_splits_are_aligned_instances():
    train = objects.resolve_set("composite:train")
    test = objects.resolve_set("composite:test")
    assert len(test) == len(train) and not {o.name for o in test} & {o.name for o in train}
    for a, b in zip(train, test, strict=True):
        code = a.name.split("_")[1]
        assert b.name.split("_")[1] == code  # label i: the same arrangement
        assert not np.array_equal(a.height_field(33), b.height_field(33))  # another instance
    ids = [objects.object_id(o.name) for o in train + test]
    assert ids == sorted(ids) and ids[0] > objects.object_id("double_ridge")


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ("composite:foo", "'composite:foo'; accepted: composite:train, composite:test"),
        ("paper:train", "'paper:train'"),
        ("", "accepted: paper, mhsb, curvature2d, composite, composite:train"),
    ],
)
def test_bad_set_names_are_refused(spec, match):
    with pytest.raises(HamError, match=match):
        objects.resolve_set(spec)


# --------------------------------------------------------------------------- images
def test_object_from_a_real_png(tmp_path):
    grey = np.array([[0.0, 0.2, 0.4], [0.6, 0.8, 1.0]])
    path = tmp_path / "relief.png"
    mpimg.imsave(path, grey, cmap="gray", vmin=0, vmax=1)
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    obj = HapticObject.from_image("relief_t", path, width=0.06, depth=0.04, height=0.05)
    assert obj.varies_in_y and (obj.width, obj.depth) == (0.06, 0.04)
    # top row of the picture at +y, columns along +x; 8-bit grey levels
    expect = {(-0.03, 0.02): 0.0, (0.03, 0.02): 0.4, (-0.03, -0.02): 0.6, (0.03, -0.02): 1.0}
    for (x, y), g in expect.items():
        assert at(obj, x, y) == pytest.approx(0.05 * g, abs=0.05 / 255)
    assert obj.height == pytest.approx(0.05)


def test_bad_images_are_refused_by_name(tmp_path):
    colour = tmp_path / "colour.png"
    mpimg.imsave(colour, np.array([[0.1, 0.9], [0.5, 0.3]]), cmap="viridis")
    with pytest.raises(HamError, match="colour.png' has colour at row"):
        HapticObject.from_image("c_t", colour)
    with pytest.raises(HamError, match="nothere.png' does not exist"):
        HapticObject.from_image("c_t", tmp_path / "nothere.png")
    with pytest.raises(HamError, match="pic.jpg'; accepted: a .png file"):
        HapticObject.from_image("c_t", tmp_path / "pic.jpg")
    fake = tmp_path / "fake.png"
    fake.write_text("not a png")
    with pytest.raises(HamError, match="cannot read image .*fake.png' as a PNG"):
        HapticObject.from_image("c_t", fake)
    with pytest.raises(HamError, match=r"grey level 1.5 at row 0, column 1"):
        HapticObject.from_image("c_t", np.array([[0.2, 1.5], [0.1, 0.1]]))
    with pytest.raises(HamError, match="image height = 0.2"):
        HapticObject.from_image("c_t", np.ones((2, 2)), height=0.2)
    with pytest.raises(HamError, match="transparent"):
        HapticObject.from_image("c_t", np.full((2, 2, 4), 0.5))
    with pytest.raises(HamError, match="every height is 0"):
        HapticObject.from_image("c_t", np.zeros((3, 3)))


# --------------------------------------------------------------------------- meshes
def test_object_from_a_real_stl_box(tmp_path):
    path = tmp_path / "block.stl"
    trimesh.creation.box(extents=(60.0, 40.0, 20.0)).export(path)  # millimetres
    obj = HapticObject.from_mesh("block_t", path, scale=0.001)
    assert (obj.width, obj.depth) == pytest.approx((0.06, 0.04))
    np.testing.assert_allclose(obj.height_field(13, 9), 0.02, atol=1e-12)  # edges included


def test_object_from_a_real_obj_cone(tmp_path):
    path = tmp_path / "cone.obj"
    trimesh.creation.cone(radius=0.03, height=0.04, sections=64).export(path)
    obj = HapticObject.from_mesh("cone_t", path, pitch=0.0005)
    assert obj.height == pytest.approx(0.04, abs=1e-3)
    for r in (0.0, 0.01, 0.02, 0.029):
        expect = 0.04 * (1 - r / 0.03)
        assert at(obj, r, 0) == pytest.approx(expect, abs=5e-4)
        assert at(obj, 0, -r) == pytest.approx(expect, abs=5e-4)
    assert at(obj, 0.029, 0.029) == 0.0  # beyond the cone's foot: the table


def test_mesh_top_takes_the_highest_triangle():
    # two overlapping flat triangles at 1 and 2 cm, one vertical (ignored)
    tris = np.array(
        [
            [[0, 0, 0.01], [1, 0, 0.01], [0, 1, 0.01]],
            [[0, 0, 0.02], [0.5, 0, 0.02], [0, 0.5, 0.02]],
            [[0, 0, 0], [1, 0, 0], [1, 0, 0.05]],
        ]
    )
    g = np.linspace(0, 1, 5)
    top = objects.mesh_top(tris, g, g)
    assert top[0, 0] == 0.02 and top[0, 2] == 0.02 and top[0, 3] == 0.01
    assert top[4, 4] == 0.0 and top[2, 2] == 0.01  # beyond, and on the hypotenuse


def test_bad_meshes_are_refused_by_name(tmp_path):
    big = tmp_path / "big.stl"
    trimesh.creation.box(extents=(300.0, 40.0, 20.0)).export(big)
    with pytest.raises(HamError, match=r"mesh width \(x extent \* scale\) = 0.3"):
        HapticObject.from_mesh("m_t", big, scale=0.001)
    tall = tmp_path / "tall.stl"
    trimesh.creation.box(extents=(60.0, 40.0, 100.0)).export(tall)
    with pytest.raises(HamError, match=r"height 0.1 at x = .* above the block height limit"):
        HapticObject.from_mesh("m_t", tall, scale=0.001)
    with pytest.raises(HamError, match="none.stl' does not exist"):
        HapticObject.from_mesh("m_t", tmp_path / "none.stl")
    with pytest.raises(HamError, match="m.step'; accepted: a .stl/.obj/.ply file"):
        HapticObject.from_mesh("m_t", tmp_path / "m.step")
    bad = tmp_path / "bad.stl"
    bad.write_bytes(b"\x00" * 10)
    with pytest.raises(HamError, match="bad.stl' has no triangles"):
        HapticObject.from_mesh("m_t", bad)
    with pytest.raises(HamError, match="mesh scale = -1"):
        HapticObject.from_mesh("m_t", big, scale=-1)
    with pytest.raises(HamError, match="mesh pitch = 1e-05 m gives"):
        HapticObject.from_mesh("m_t", big, scale=0.0005, pitch=1e-5)
    with pytest.raises(HamError, match="mesh of type int"):
        HapticObject.from_mesh("m_t", 42)


# --------------------------------------------------------------------------- objects files
def test_height_field_entries_in_objects_files(tmp_path):
    f = tmp_path / "fields.toml"
    f.write_text(
        '[[objects]]\nname = "tilt_t"\nheight_field = [[0.01, 0.02], [0.03, 0.04]]\n'
        'width = 0.08\ndepth = 0.06\ndescription = "a tilted plane"\n'
    )
    names = objects.load_objects(objects.read_objects_file(f))
    assert names == ["tilt_t"]
    obj = objects.get("tilt_t")
    assert obj.varies_in_y and (obj.width, obj.depth) == (0.08, 0.06)
    assert at(obj, 0, 0) == pytest.approx(0.025) and at(obj, 0.04, 0.03) == pytest.approx(0.04)


@pytest.mark.parametrize(
    ("entry", "match"),
    [
        ({"name": "i_t", "image": "relief.png"}, "names the image file 'relief.png'.*not travel"),
        ({"name": "m_t", "mesh": "part.stl"}, "names the mesh file 'part.stl'"),
        ({"name": "h_t", "height_field": [0.01, 0.02]}, "height field must be a 2-D array"),
        ({"name": "h_t", "height_field": [[0.01], [0.02]]}, r"shape \(2, 1\)"),
        ({"name": "h_t", "height_field": [[0.1, 0.2], [0, 0]]}, "above the block height limit"),
        ({"name": "h_t", "height_field": [[1, 1]], "heightmap": [1]}, "shape keys"),
    ],
)
def test_bad_height_field_entries_are_refused(tmp_path, entry, match):
    f = tmp_path / "bad.json"
    f.write_text(json.dumps({"objects": [entry]}))
    with pytest.raises(HamError, match=match):
        objects.load_objects(objects.read_objects_file(f))


def test_export_embeds_an_image_object_that_travels(tmp_path):
    """--image builds the object here; --export embeds it, and the file alone brings it back."""
    png = tmp_path / "relief.png"
    yy, xx = np.mgrid[0:1:21j, 0:1:31j]
    mpimg.imsave(png, 0.2 + 0.8 * xx * yy, cmap="gray", vmin=0, vmax=1)
    out = tmp_path / "relief.json"
    r = ok(run_ham("objects", "--image", str(png), "--name", "relief", "--width", "0.08",
                   "--depth", "0.06", "--height", "0.04", "--export", str(out), "--json"))  # fmt: skip
    made = json.loads(r.stdout)
    assert [m["name"] for m in made] == ["relief"] and made[0]["varies_in_y"]
    entry = json.loads(out.read_text())["objects"][0]
    assert len(entry["height_field"]) == 97 and len(entry["height_field"][0]) == 129
    r = ok(run_ham("objects", "--objects-file", str(out), "--set", "relief", "--json"))
    back = json.loads(r.stdout)[0]
    assert back["origin"].startswith("objects file 'relief.json'")
    assert (back["width"], back["depth"]) == (0.08, 0.06)
    assert back["height"] == pytest.approx(made[0]["height"], abs=1e-6)
    obj = HapticObject.from_image("relief_x", png, width=0.08, depth=0.06, height=0.04)
    again = HapticObject.from_height_field(
        "relief_y", entry["height_field"], width=0.08, depth=0.06
    )
    np.testing.assert_allclose(again.height_field(17), obj.height_field(17), atol=2e-7)


def test_export_of_a_built_in_object_needs_a_new_name(tmp_path):
    """A built-in object's copy could never load beside it: its export is refused unless it is
    renamed (--name, one object); the renamed copy loads in a fresh process and is glanced."""
    r = run_ham_inprocess("objects", "--set", "dome", "--export", "d.json", cwd=tmp_path)
    assert "--export of built-in object 'dome'" in one_line_error(r)
    assert not (tmp_path / "d.json").exists()
    out = tmp_path / "my_dome.json"
    ok(run_ham("objects", "--set", "dome", "--export", str(out), "--name", "my_dome"))
    r = ok(run_ham("glance", "--objects-file", str(out), "--object", "my_dome", "--x", "0",
                   "--phi", "0", "--json"))  # fmt: skip
    copy = json.loads(r.stdout)
    r = ok(run_ham("glance", "--objects", "curvature2d", "--object", "dome", "--x", "0",
                   "--phi", "0", "--json"))  # fmt: skip
    original = json.loads(r.stdout)
    # the sampled copy (129 x 129 heights) stops within 0.1 mm of the analytic dome
    assert copy["height"] == pytest.approx(original["height"], abs=1e-4)


# --------------------------------------------------------------------------- CLI
def test_cli_lists_and_draws_the_sets(tmp_path):
    png = tmp_path / "c2d.png"
    rows = json.loads(
        ok(run_ham("objects", "--set", "curvature2d", "--json", "--out", str(png))).stdout
    )
    assert [r["name"] for r in rows] == list(objects.OBJECT_SETS["curvature2d"])
    assert all(r["varies_in_y"] and r["sets"] == ["curvature2d"] for r in rows)
    assert png.read_bytes()[:8] == PNG_SIGNATURE
    text = ok(run_ham_inprocess("objects", "--set", "composite:test")).stdout
    assert "comp_EFVC_2   16 x 16 cm" in text and "comp_EFVC_1 " not in text.split("split")[0]
    assert "split composite:train: 12 objects: comp_EFVC_1, " in text
    assert "split composite:test: 12 objects: comp_EFVC_2, " in text
    rows = json.loads(ok(run_ham_inprocess("objects", "--set", "composite", "--json")).stdout)
    assert rows[0]["sets"] == ["composite", "composite:train"]


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["--set", "composite:nope"], "'composite:nope'; accepted: composite:train"),
        (["--image", "x.png"], "--image/--mesh needs --name"),
        (["--image", "x.png", "--name", "a_t", "--set", "paper"], "--set with --image"),
        (["--image", "x.png", "--mesh", "y.stl", "--name", "a_t"], "--image and --mesh"),
        (["--mesh", "nothere.stl", "--name", "a_t"], "'nothere.stl' does not exist"),
        (["--set", "paper", "--export", "p.toml"], "--export 'p.toml' ends in '.toml'"),
        (
            ["--set", "dome", "--export", "d.json", "--name", "d_copy", "--samples", "1"],
            "samples = 1",
        ),
        (["--set", "paper", "--width", "0.05"], "--width applies only with --image"),
        (["--set", "paper", "--samples", "9"], "--samples applies only with --export"),
        (["--set", "paper", "--name", "x"], "--name applies only with --image, --mesh or --export"),
        (["--set", "paper", "--export", "p.json", "--name", "x"], "--set 'paper' has 4"),
        (["--set", "dome", "--export", "p.json", "--name", "box"], "'box' is registered already"),
    ],
)
def test_cli_bad_inputs(tmp_path, args, match):
    r = run_ham_inprocess("objects", *args, cwd=tmp_path)
    assert match in one_line_error(r)
    assert not list(tmp_path.iterdir())  # nothing written
