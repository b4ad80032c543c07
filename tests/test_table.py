"""Glance tables: build, round trip, nearest lookup, resume, authors' import, recorded glances,
bad files."""

import json
import re

import h5py
import numpy as np
import pytest
import torch

from ham.errors import HamError
from ham.world.config import WorldConfig, make_simulator
from ham.world.glance import FastSimulator
from ham.world.table import (
    GlanceTable,
    build_table,
    grid_values,
    import_authors,
    import_recorded,
    table_info,
    verify_table,
)

GRID = 11


@pytest.fixture(scope="module")
def table_path(tmp_path_factory):
    return build_table(
        WorldConfig(), GRID, tmp_path_factory.mktemp("t") / "table.h5", progress=False
    )


def test_table_is_self_describing(table_path):
    info = table_info(table_path)
    assert info.grid == GRID and info.objects == ["box", "ramp_up", "convex", "ramp_down"]
    assert info.world["sensor"]["taxels"] == 16 and info.simulator["simulator"] == "fast"
    assert len(info.checksum) == 64
    with h5py.File(table_path) as f:
        assert f["objects/convex/pressure"].shape == (GRID, GRID, 16, 16)
        assert f["objects/convex/pressure"].dtype == np.float32
        assert set(json.loads(f.attrs["geometry"])) == set(info.objects)
        assert "progress" not in f  # a finished table carries no build state
    assert not table_path.with_name(table_path.name + ".partial").exists()


def test_round_trip_on_grid_points_equals_direct_glances(table_path):
    table = GlanceTable.load(table_path)
    sim = make_simulator(WorldConfig())
    q = grid_values(GRID)
    qx, qp = np.meshgrid(q, q, indexing="ij")
    for oid in range(4):
        ids = np.full(qx.size, oid)
        looked = table.lookup(ids, qx.ravel(), qp.ravel())
        direct = sim.glance(ids, qx.ravel(), qp.ravel()).pressure
        assert torch.equal(looked, direct)


def test_lookup_picks_the_nearest_grid_point(table_path):
    table = GlanceTable.load(table_path)
    q = grid_values(GRID)
    step = q[1] - q[0]
    # just below and above the midpoint between grid points 3 and 4
    a = table.lookup([2, 2], [q[3] + 0.49 * step, q[3] + 0.51 * step], [q[5], q[5]])
    assert torch.equal(a[0], table.pressure[2, 3, 5]) and torch.equal(a[1], table.pressure[2, 4, 5])
    with pytest.raises(HamError, match=r"q_phi = -1.01 is outside"):
        table.lookup([0], [0.0], [-1.01])
    with pytest.raises(HamError, match="object id 4 out of range; accepted: 0..3"):
        table.lookup([4], [0.0], [0.0])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_pose_index_of_all_dims_at_once_is_the_per_dim_one(table_path, dtype):
    # the paper's tables index both pose dims in one pass; the per-dim loop (tables whose dims
    # lie on other grids) gives the same indices: on grid points, midpoints and the bounds
    table = GlanceTable.load(table_path)
    q = torch.cat([torch.rand(500, 2, generator=torch.Generator().manual_seed(0)) * 2 - 1,
                   torch.tensor(grid_values(GRID)).repeat(2, 1).T,
                   torch.tensor(grid_values(2 * GRID - 1)).repeat(2, 1).T]).to(dtype)  # fmt: skip
    ids = torch.arange(len(q)) % 4
    at_once = table.pose_index(ids, q, check=False)
    table._stride_t = None
    assert torch.equal(at_once, table.pose_index(ids, q, check=False))
    assert at_once.unique().numel() > 100


def test_interrupted_build_resumes_to_the_same_table(tmp_path, monkeypatch, table_path):
    out = tmp_path / "resumed.h5"
    calls = {"n": 0}
    real = FastSimulator.glance

    def failing(self, *a, **k):  # fault injection: the process dies after two blocks
        calls["n"] += 1
        if calls["n"] > 2:
            raise KeyboardInterrupt
        return real(self, *a, **k)

    monkeypatch.setattr(FastSimulator, "glance", failing)
    with pytest.raises(KeyboardInterrupt):
        build_table(WorldConfig(), GRID, out, batch=3 * GRID, progress=False)
    partial = tmp_path / "resumed.h5.partial"
    assert partial.exists() and not out.exists()
    with h5py.File(partial) as f:
        assert 0 < f["progress"][...].sum() < 4 * GRID
    monkeypatch.setattr(FastSimulator, "glance", real)
    build_table(WorldConfig(), GRID, out, batch=3 * GRID, progress=False)
    assert not partial.exists()
    assert table_info(out).checksum == table_info(table_path).checksum


def test_partial_of_another_world_is_refused(tmp_path):
    out = tmp_path / "x.h5"
    with h5py.File(tmp_path / "x.h5.partial", "w") as f:
        f.attrs["world"] = "{}"
        f.attrs["grid"] = GRID
    with pytest.raises(HamError, match="partial build of another world or grid"):
        build_table(WorldConfig(), GRID, out, progress=False)


def test_truncated_corrupt_and_foreign_files_are_refused(tmp_path, table_path):
    data = table_path.read_bytes()
    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(data[: len(data) // 3])
    with pytest.raises(HamError, match="not a complete HDF5 file"):
        GlanceTable.load(truncated)
    text = tmp_path / "notes.h5"
    text.write_text("not a table")
    with pytest.raises(HamError, match="cannot read glance table"):
        GlanceTable.load(text)
    with pytest.raises(HamError, match="does not exist"):
        GlanceTable.load(tmp_path / "missing.h5")
    corrupt = tmp_path / "corrupt.h5"
    corrupt.write_bytes(data)
    with h5py.File(corrupt, "a") as f:
        f["objects/box/pressure"][0, 0, 0, 0] += 1.0
    with pytest.raises(HamError, match="checksum does not match"):
        GlanceTable.load(corrupt)
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["x"] = np.zeros(3)
    with pytest.raises(HamError, match="not a ham glance table"):
        GlanceTable.load(foreign)
    wrong = tmp_path / "wrong.h5"
    wrong.write_bytes(data)
    with h5py.File(wrong, "a") as f:
        del f["objects/box/contact"]
        f["objects/box/contact"] = np.zeros((3, 3), bool)
    with pytest.raises(HamError, match=r"objects/box/contact has shape \(3, 3\)"):
        GlanceTable.load(wrong)


@pytest.mark.parametrize(
    "edit",
    [
        lambda f: f.attrs.__setitem__("geometry", f.attrs["geometry"].replace("0.045", "0.046", 1)),
        lambda f: f.attrs.__setitem__("world", f.attrs["world"].replace('"fast"', '"mujoco"')),
        lambda f: f.attrs.__setitem__("command", "ham table build --grid 7"),
        lambda f: f["objects/box/z"].__setitem__((0, 0), f["objects/box/z"][0, 0] + 1e-3),
        lambda f: f["objects/convex/contact"].__setitem__(
            (1, 1), ~f["objects/convex/contact"][1, 1]
        ),
        lambda f: f["objects/box/force"].__setitem__((2, 2), 0.0),
    ],
    ids=["geometry", "world", "command", "z", "contact", "force"],
)
def test_a_change_outside_the_pressures_is_found_by_the_record_checksum(tmp_path, table_path, edit):
    # The pressure checksum covers the images; a flipped bit in an attribute or in another
    # dataset read as data (a geometry, a z) was silent before the record checksum.
    changed = tmp_path / "changed.h5"
    changed.write_bytes(table_path.read_bytes())
    with h5py.File(changed, "a") as f:
        edit(f)
    for check in (verify_table, GlanceTable.load):
        with pytest.raises(HamError, match="is corrupt: its attributes or force/height/contact"):
            check(changed)
    with pytest.raises(HamError, match=r"accepted: the table as built \(rebuild it with `ham"):
        verify_table(changed)
    # a table from before the record checksum has none and loads
    with h5py.File(changed, "a") as f:
        del f.attrs["record_checksum"]
    verify_table(changed)


def test_import_of_the_authors_layout(tmp_path):
    rng = np.random.default_rng(0)
    src = tmp_path / "authors.h5"
    arrays = [rng.random((21, 21, 256), dtype=np.float32) for _ in range(4)]
    with h5py.File(src, "w") as f:
        for i, a in enumerate(arrays):
            f[f"object_{i}"] = a
    out = import_authors(src, tmp_path / "imported.h5")
    table = GlanceTable.load(out)
    assert table.grid == 21 and table.objects == ["box", "ramp_up", "convex", "ramp_down"]
    assert table.info.source == "authors:authors.h5"
    got = table.lookup([3], [grid_values(21)[4]], [grid_values(21)[17]])
    assert np.array_equal(got[0].numpy().ravel(), arrays[3][4, 17])
    swapped = GlanceTable.load(import_authors(src, tmp_path / "swapped.h5", axes="phi,x"))
    assert np.array_equal(swapped.pressure[1, 4, 17].numpy().ravel(), arrays[1][17, 4])
    with h5py.File(tmp_path / "bad.h5", "w") as f:
        f["object_0"] = np.zeros((5, 5, 100), np.float32)
    with pytest.raises(HamError, match=r"object_0 has shape \(5, 5, 100\)"):
        import_authors(tmp_path / "bad.h5", tmp_path / "o.h5")
    with pytest.raises(HamError, match="accepted: x,phi or phi,x"):
        import_authors(src, tmp_path / "o.h5", axes="y")


def test_a_table_another_process_is_building_is_named(tmp_path):
    """Two builds of one ``--out`` at once: the second says another ham process is building it
    (HDF5's lock on the partial file), in one line, and leaves the first one's file alone."""
    import os

    from tests.conftest import one_line_error, run_ham

    if os.environ.get("HDF5_USE_FILE_LOCKING", "").upper() == "FALSE":
        pytest.skip("HDF5 file locking is off here")
    out = tmp_path / "t.h5"
    with h5py.File(tmp_path / "t.h5.partial", "w") as held:  # as a running build holds it
        held.attrs["mark"] = 1
        line = one_line_error(run_ham("table", "build", "--grid", "5", "--out", str(out)))
    assert f"glance table '{out}' is being built by another ham process" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.h5.partial"]
    with h5py.File(tmp_path / "t.h5.partial", "r") as f:
        assert f.attrs["mark"] == 1


# ------------------------------------------------------------------ recorded glances
def _recorded(table_path, tmp_path, heights=True):
    """table_path's images (and its heights) written as recorded glances (.npz)."""
    t = GlanceTable.load(table_path)
    arrays = {n: t.pressure[i].numpy() for i, n in enumerate(t.objects)}
    if heights:
        with h5py.File(table_path) as f:
            arrays |= {f"{n}.height": f[f"objects/{n}/z"][...] for n in t.objects}
    np.savez(tmp_path / "rec.npz", **arrays)
    return tmp_path / "rec.npz"


def test_recorded_glances_become_a_table(table_path, tmp_path):
    out = import_recorded(_recorded(table_path, tmp_path), tmp_path / "rec.h5")
    info = verify_table(out)
    assert info.source == "recorded:rec.npz" and info.simulator["simulator"] == "recorded"
    assert info.objects == table_info(table_path).objects and info.grid == GRID
    ours, theirs = GlanceTable.load(table_path), GlanceTable.load(out)
    assert torch.equal(ours.pressure, theirs.pressure)
    with h5py.File(table_path) as a, h5py.File(out) as b:
        assert np.array_equal(a["objects/ramp_up/z"][...], b["objects/ramp_up/z"][...])
        assert np.isnan(b["objects/ramp_up/force"][...]).all()  # unknown
    without = import_recorded(_recorded(table_path, tmp_path, heights=False), tmp_path / "n.h5")
    with h5py.File(without) as b:
        assert np.isnan(b["objects/box/z"][...]).all()


def test_a_recorded_table_of_its_own_objects_and_pad_trains(tmp_path):
    from ham.learn.train import TrainConfig, train
    from ham.model.agent import HamConfig

    rng = np.random.default_rng(0)
    images = {"cup": rng.random((3, 3, 8, 8)) * 100, "ball": rng.random((3, 3, 8, 8)) * 100}
    np.savez(tmp_path / "mine.npz", **images)
    out = import_recorded(tmp_path / "mine.npz", tmp_path / "mine.h5")
    info = table_info(out)
    assert info.objects == ["cup", "ball"] and info.taxels == 8 and info.grid == 3
    model = HamConfig(glances=2, n_objects=2, pressure_dim=64)
    config = TrainConfig(model=model, table=str(out), steps=2, batch_size=4, eval_every=2,
                         eval_batches=1)  # fmt: skip
    assert train(config, tmp_path / "run", progress=False)["steps"] == 2


@pytest.mark.parametrize(
    ("arrays", "message"),
    [
        ({}, "holds no object's images"),
        ({"box": np.zeros((3, 3, 16))}, "box has shape (3, 3, 16); accepted: (G_x, G_phi, N, N)"),
        ({"box": np.zeros((3, 3, 16, 8))}, "box has shape (3, 3, 16, 8)"),
        ({"box": np.zeros((1, 1, 16, 16))}, "G >= 2"),
        ({"box": np.full((3, 3, 4, 4), -1.0)}, "holds -1.0 at index (0, 0, 0, 0)"),
        ({"box": np.full((3, 3, 4, 4), np.nan)}, "holds nan"),
        ({"box": np.zeros((3, 3, 4, 4), np.complex64)}, "holds complex64 values"),
        ({"a": np.zeros((3, 3, 4, 4)), "b": np.zeros((2, 2, 4, 4))}, "differ in shape"),
        ({"a": np.zeros((3, 3, 4, 4)), "b.height": np.zeros((3, 3))}, "b.height belongs to no"),
        ({"a": np.zeros((3, 3, 4, 4)), "a.height": np.zeros(3)}, "a.height has shape (3,)"),
        ({"a": np.zeros((3, 3, 4, 4)), "a.height": np.full((3, 3), np.inf)}, "finite heights"),
    ],
)
def test_bad_recorded_glances_are_refused_in_one_line(tmp_path, arrays, message):
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(HamError, match=re.escape(message)) as e:
        import_recorded(tmp_path / "bad.npz", tmp_path / "out.h5")
    assert "\n" not in str(e.value) and not (tmp_path / "out.h5").exists()


FOUR_D = ("x", "y", "phi", "phi_y")


@pytest.fixture(scope="module")
def grid_table(tmp_path_factory):
    """A format-2 table of the next world: height fields over (x, y, phi, phi_y), 3 x 4 x 3 x 2."""
    world = WorldConfig(objects="curvature2d", pose_dims=FOUR_D)
    return build_table(world, "3,4,3,2", tmp_path_factory.mktemp("g") / "c4.h5", progress=False)


def _recorded_grid(table_path, out):
    """A format-2 table's images and heights as recorded glances over its grid's axes."""
    t = GlanceTable.load(table_path)
    arrays = {n: t.pressure[i].numpy() for i, n in enumerate(t.objects)}
    np.savez(out, **arrays, **{f"{n}.height": t.height[i].numpy() for i, n in enumerate(t.objects)})
    return out


@pytest.mark.parametrize("compression", [None, "none"])
def test_recorded_glances_over_any_pose_grid(grid_table, tmp_path, compression):
    src = _recorded_grid(grid_table, tmp_path / "rec.npz")
    out = import_recorded(src, tmp_path / "rec.h5", pose_dims="x,y,phi,phi_y",
                          compression=compression)  # fmt: skip
    info = verify_table(out)
    assert info.format_version == 2 and info.pose_dims == FOUR_D and info.grid_shape == (3, 4, 3, 2)
    assert info.simulator["simulator"] == "recorded" and "pose_dims='x,y,phi,phi_y'" in info.command
    ours, theirs = GlanceTable.load(grid_table), GlanceTable.load(out)
    assert torch.equal(ours.pressure, theirs.pressure) and torch.equal(ours.height, theirs.height)
    with h5py.File(grid_table) as a, h5py.File(out) as b:
        for key in ("contact",):  # the same layout as a built table
            assert np.array_equal(a[f"objects/dome/{key}"][...], b[f"objects/dome/{key}"][...])
        assert np.isnan(b["objects/dome/force"][...]).all()  # unknown
        ds = b["objects/dome/pressure"]
        assert ds.shape == (72, 16, 16)
        assert ds.compression == (None if compression == "none" else "gzip")
    # a table over the stored grid looks up the same glances, streamed from disk too
    streamed = GlanceTable.load(out, lookup="stream")
    q = torch.tensor([[grid_values(3)[1], grid_values(4)[2], grid_values(3)[0], 1.0]])
    assert torch.equal(streamed.lookup_pose([4], q), ours.lookup_pose([4], q))
    streamed._stream.close()


def test_recorded_glances_on_a_grid_that_is_not_square_are_format_2(tmp_path):
    rng = np.random.default_rng(0)
    np.savez(tmp_path / "r.npz", cup=rng.random((5, 3, 4, 4)), ball=rng.random((5, 3, 4, 4)))
    info = verify_table(import_recorded(tmp_path / "r.npz", tmp_path / "r.h5"))
    assert info.format_version == 2 and info.grid_shape == (5, 3) and info.pose_dims == ("x", "phi")
    one = verify_table(import_recorded(tmp_path / "r.npz", tmp_path / "y.h5", pose_dims=("x", "y")))
    assert one.pose_dims == ("x", "y") and one.grid_shape == (5, 3)


@pytest.mark.parametrize(
    ("arrays", "options", "message"),
    [
        (
            {"a": np.zeros((3, 3, 4, 4))},
            {"pose_dims": "x,y,phi,phi_y"},
            "a has shape (3, 3, 4, 4); accepted: (G_x, G_y, G_phi, G_phi_y, N, N) for pose dims "
            "x,y,phi,phi_y",
        ),
        ({"a": np.zeros((3, 3, 1, 4, 4))}, {"pose_dims": "x,y,phi"}, "G >= 2 grid points"),
        ({"a": np.zeros((3, 3, 4, 4))}, {"pose_dims": "x,z"}, "unknown pose dimension 'z'"),
        ({"a": np.zeros((3, 3, 4, 4))}, {"pose_dims": "phi,x"}, "in that order"),
        (
            {"a": np.zeros((3, 3, 4, 4))},
            {"compression": "zip"},
            "compression = 'zip'; accepted: gzip, lzf, none",
        ),
        (
            {"a": np.zeros((3, 3, 4, 4))},
            {"compression": "lzf"},
            "compression = 'lzf' for the paper's (x, phi) table",
        ),
        (
            {"a": np.zeros((3, 2, 2, 4, 4)), "a.height": np.zeros((3, 2))},
            {"pose_dims": "x,y,phi"},
            "a.height has shape (3, 2) (float64); accepted: finite heights (m) of shape (3, 2, 2)",
        ),
    ],
)
def test_bad_recorded_grids_are_refused_in_one_line(tmp_path, arrays, options, message):
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(HamError, match=re.escape(message)) as e:
        import_recorded(tmp_path / "bad.npz", tmp_path / "out.h5", **options)
    assert "\n" not in str(e.value) and not (tmp_path / "out.h5").exists()


def test_a_file_that_is_no_npz_is_refused(tmp_path):
    (tmp_path / "x.npz").write_text("not a zip\n")
    with pytest.raises(HamError, match="is not an .npz file"):
        import_recorded(tmp_path / "x.npz", tmp_path / "out.h5")
    with pytest.raises(HamError, match="cannot read recorded glances .*No such file"):
        import_recorded(tmp_path / "nosuch.npz", tmp_path / "out.h5")
