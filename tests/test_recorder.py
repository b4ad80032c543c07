"""Recording glances from outside (``ham.world.recorder.record_glances``): a robot's glances over
a grid of poses into the ``.npz`` that ``ham table import-recorded`` reads; resumable, checked."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch

from ham.errors import HamError
from ham.world.config import WorldConfig
from ham.world.recorder import record_glances
from ham.world.table import GlanceTable, build_table, import_recorded


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    """Built tables to play the robot: the paper's (x, phi) and the next world's 4-D poses."""
    d = tmp_path_factory.mktemp("recorder")
    four = WorldConfig(objects="curvature2d", pose_dims=("x", "y", "phi", "phi_y"))
    return {
        "paper": GlanceTable.load(build_table(WorldConfig(), 5, d / "p.h5", progress=False)),
        "4d": GlanceTable.load(build_table(four, "2,3,2,2", d / "c.h5", progress=False)),
    }


def robot(table, calls: list | None = None, fail_at: int | None = None, exc=KeyboardInterrupt):
    """A robot that glances by looking the pose up in ``table``; the ``fail_at``-th call raises."""

    def glance(name, q):
        if calls is not None:
            calls.append((name, tuple(q)))
            if fail_at is not None and len(calls) == fail_at:
                raise exc()
        ids = torch.tensor([table.objects.index(name)])
        image, height = table.lookup_pose(ids, torch.tensor(q).view(1, -1), height=True)
        return image[0].numpy(), float(height[0])

    return glance


@pytest.mark.parametrize("which", ["paper", "4d"])
def test_recorded_glances_import_as_the_table_they_came_from(tables, tmp_path, which):
    table = tables[which]
    shape = ",".join(map(str, table.grid_shape))
    out = record_glances(robot(table), table.objects, shape, tmp_path / "r.npz",
                         pose_dims=table.pose_dims, heights=True, progress=False)  # fmt: skip
    assert out == tmp_path / "r.npz" and not (tmp_path / "r.partial.npz").exists()
    with np.load(out) as f:
        assert f[table.objects[0]].shape == (*table.grid_shape, 16, 16)
    imported = GlanceTable.load(import_recorded(out, tmp_path / "r.h5", pose_dims=table.pose_dims))
    assert torch.equal(imported.pressure, table.pressure)
    assert torch.equal(imported.height, table.height)


def test_an_interrupted_recording_resumes_where_it_stopped(tables, tmp_path):
    table, calls = tables["paper"], []
    with pytest.raises(KeyboardInterrupt):
        record_glances(robot(table, calls, fail_at=40), table.objects, 5, tmp_path / "r.npz",
                       heights=True, save_every=7, progress=False)  # fmt: skip
    assert not (tmp_path / "r.npz").exists()
    with np.load(tmp_path / "r.partial.npz") as f:
        assert int(f["__done__"].sum()) == 39  # every glance before the interrupt, saved
    with pytest.raises(HamError, match="is a partial recording that record_glances has not"):
        import_recorded(tmp_path / "r.partial.npz", tmp_path / "p.h5")
    record_glances(robot(table, calls), table.objects, 5, tmp_path / "r.npz", heights=True,
                   save_every=7, progress=False)  # fmt: skip
    # no pose asked twice but the interrupted one, and the table's order: object by object
    assert len(calls) == 4 * 25 + 1 and calls[39] == calls[40]
    assert [c[0] for c in calls[:26]] == [table.objects[0]] * 25 + [table.objects[1]]
    # finished: the same call again asks the robot nothing and leaves the file as it is
    before = (tmp_path / "r.npz").read_bytes()
    record_glances(robot(table, [], fail_at=1), table.objects, 5, tmp_path / "r.npz",
                   heights=True, progress=False)  # fmt: skip
    assert (tmp_path / "r.npz").read_bytes() == before
    whole = record_glances(robot(table), table.objects, 5, tmp_path / "w.npz", heights=True,
                           progress=False)  # fmt: skip
    with np.load(tmp_path / "r.npz") as a, np.load(whole) as b:
        assert sorted(a.files) == sorted(b.files)
        assert all(np.array_equal(a[k], b[k]) for k in a.files)
    # another grid on the same partial file is refused, not mixed in
    with pytest.raises(KeyboardInterrupt):
        record_glances(robot(table, [], fail_at=3), table.objects, 5, tmp_path / "x.npz",
                       heights=True, progress=False, save_every=1)  # fmt: skip
    with pytest.raises(HamError, match="'.*x.partial.npz' is a partial recording of other"):
        record_glances(robot(table), table.objects, 3, tmp_path / "x.npz", heights=True,
                       progress=False)  # fmt: skip


@pytest.mark.parametrize(
    ("answer", "message"),
    [
        (lambda im, h: -im - 1, "returned -1.0 at taxel (0, 0); accepted: pressures in [0, "),
        (lambda im, h: im[:4], "returned an image of shape (4, 16); accepted: (N, N)"),
        (lambda im, h: im[:8, :8], "returned an image of shape (8, 8); accepted: (16, 16)"),
        (lambda im, h: im * np.nan, "returned nan at taxel (0, 0)"),
        (lambda im, h: "image", "returned str; accepted: an (N, N) image"),
    ],
)
def test_a_bad_glance_stops_in_one_line_and_keeps_the_good_ones(tables, tmp_path, answer, message):
    table, calls = tables["paper"], []
    good = robot(table, calls)

    def glance(name, q):
        image, _ = good(name, q)
        return image if len(calls) < 5 else answer(image, None)

    with pytest.raises(HamError, match=re.escape(message)) as e:
        record_glances(glance, table.objects, 5, tmp_path / "r.npz", progress=False)
    assert "\n" not in str(e.value) and "glance('box', q = [-1, 1] (x,phi))" in str(e.value)
    with np.load(tmp_path / "r.partial.npz") as f:
        assert int(f["__done__"].sum()) == 4
    record_glances(lambda n, q: good(n, q)[0], table.objects, 5, tmp_path / "r.npz",
                   progress=False)  # fmt: skip
    assert not (tmp_path / "r.partial.npz").exists()


@pytest.mark.parametrize(
    ("answer", "message"),
    [
        (lambda im, h: im, "returned ndarray; accepted: a pair (image, height)"),
        (lambda im, h: (im, float("inf")), "returned height inf; accepted: a finite height"),
        (lambda im, h: (im, "high"), "returned height 'high'"),
    ],
)
def test_heights_are_checked(tables, tmp_path, answer, message):
    good = robot(tables["paper"])
    with pytest.raises(HamError, match=re.escape(message)):
        record_glances(lambda n, q: answer(*good(n, q)), ["box"], 3, tmp_path / "r.npz",
                       heights=True, progress=False)  # fmt: skip
    assert not (tmp_path / "r.partial.npz").exists()  # nothing was recorded


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"objects": []}, "objects = []; accepted: a list of one or more names"),
        ({"objects": "cup"}, "objects = 'cup'; accepted: a list of one or more names"),
        ({"objects": ["a", "a"]}, "objects = ['a', 'a']: a name twice"),
        ({"objects": ["a.height"]}, "not ending in '.height'"),
        ({"grid": 1}, "grid = 1; accepted: an integer 2..2001"),
        ({"grid": "3,3,3"}, "grid = 3,3,3: 3 axes for the 2 pose dims x,phi"),
        ({"pose_dims": "x,z"}, "pose_dims: unknown pose dimension 'z'"),
        (
            {"out": "r.txt"},
            "recorded glances 'r.txt' ends in '.txt'; accepted: a path ending in .npz",
        ),
        ({"save_every": 0}, "save_every = 0; accepted: an integer >= 1"),
        ({"glance": "robot"}, "glance = 'robot'; accepted: a callable glance(name, q) -> image"),
        ({"heights": 1}, "heights = 1; accepted: true or false"),
    ],
)
def test_bad_arguments_are_refused_in_one_line(tmp_path, monkeypatch, kwargs, message):
    monkeypatch.chdir(tmp_path)
    args = {"glance": lambda n, q: np.zeros((4, 4)), "objects": ["a"], "grid": 3,
            "out": "r.npz"} | kwargs  # fmt: skip
    with pytest.raises(HamError, match=re.escape(message)) as e:
        record_glances(**args, progress=False)
    assert "\n" not in str(e.value) and not list(tmp_path.iterdir())


def test_a_finished_recording_of_another_grid_is_recorded_anew(tables, tmp_path):
    table, calls = tables["paper"], []
    record_glances(robot(table, calls), ["box"], 3, tmp_path / "r.npz", heights=True,
                   progress=False)  # fmt: skip
    record_glances(robot(table, calls), ["box"], 5, tmp_path / "r.npz", heights=True,
                   progress=False)  # fmt: skip
    assert len(calls) == 9 + 25
    with np.load(tmp_path / "r.npz") as f:
        assert f["box"].shape == (5, 5, 16, 16) and "__spec__" in f.files
    imported = GlanceTable.load(import_recorded(tmp_path / "r.npz", tmp_path / "r.h5"))
    assert imported.objects == ["box"]  # "__spec__" is no object


def test_a_partial_recording_changed_since_it_was_saved_is_refused(tables, tmp_path):
    table = tables["paper"]
    with pytest.raises(KeyboardInterrupt):
        record_glances(robot(table, [], fail_at=5), ["box", "convex"], 3, tmp_path / "r.npz",
                       save_every=1, heights=True, progress=False)  # fmt: skip
    with np.load(tmp_path / "r.partial.npz") as f:
        kept = {k: f[k] for k in f.files if k != "convex"}
    np.savez(tmp_path / "r.partial.npz", **kept)
    with pytest.raises(HamError, match=r"the partial recording '.*r.partial.npz' is incomplete "
                       r"\('convex'\); delete it to start over"):  # fmt: skip
        record_glances(robot(table), ["box", "convex"], 3, tmp_path / "r.npz", heights=True,
                       progress=False)  # fmt: skip


def test_objects_recorded_on_different_days_import_as_one_table(tables, tmp_path):
    """Each object recorded into its own file (record_glances, one call each), imported
    together: the objects in the order of the files, the table the one recorded at once."""
    table = tables["paper"]
    files = []
    for name in table.objects:
        files.append(record_glances(robot(table), [name], 5, tmp_path / f"{name}.npz",
                                    heights=True, progress=False))  # fmt: skip
    both = GlanceTable.load(import_recorded(files, tmp_path / "all.h5"))
    assert both.objects == table.objects
    assert torch.equal(both.pressure, table.pressure) and torch.equal(both.height, table.height)
    assert both.info.source == "recorded:" + ",".join(f.name for f in files)
    with pytest.raises(HamError, match=r"box is in both '.*box.npz' and '.*box.npz'; accepted: "
                       "each object"):  # fmt: skip
        import_recorded([files[0], files[0]], tmp_path / "twice.h5")
    np.savez(tmp_path / "bad.npz", cup=np.zeros((3, 3, 16, 16)))
    with pytest.raises(HamError, match=r"box.npz, .*bad.npz': the objects' arrays differ in shape"):
        import_recorded([files[0], tmp_path / "bad.npz"], tmp_path / "mixed.h5")
    with pytest.raises(HamError, match=r"recorded glances \[\]; accepted: an .npz file or a list"):
        import_recorded([], tmp_path / "none.h5")
    assert [p.name for p in tmp_path.glob("*.h5")] == ["all.h5"]  # a refused import writes none


def test_the_cli_imports_several_recorded_files(tables, tmp_path, ham_cli):
    table = tables["paper"]
    files = [str(record_glances(robot(table), [n], 3, tmp_path / f"{n}.npz", heights=True,
                                progress=False)) for n in table.objects[:2]]  # fmt: skip
    r = ham_cli("table", "import-recorded", *files, "--out", str(tmp_path / "two.h5"))
    assert r.returncode == 0, r.stderr
    assert GlanceTable.load(tmp_path / "two.h5").objects == table.objects[:2]
