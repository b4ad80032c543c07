"""Every bad input answered: exit 2 (or HamError), one line naming the value, no traceback, no file.

A table of bad inputs a new user might try: CLI arguments (run in-process through
``ham.cli.main.main`` for speed, a subset also through the real CLI in a subprocess), the Python
loaders, config dataclasses, object constructors and the Gymnasium / ap_gym environments. Each
case names a substring the message must contain (the bad value, or the option). Every case runs
in its own empty working folder (plus a few prepared decoys); afterwards nothing new may be in it
and the shared fixtures must be unchanged.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from ham.errors import HamError
from tests.conftest import run_ham_inprocess

CUDA = torch.cuda.is_available()
AP_ENV = "ap_gym:CircleSquare-s15-nograd-v0"


# --------------------------------------------------------------------------- fixtures
def _edit_table(src: Path, dst: Path, edit) -> Path:
    shutil.copy(src, dst)
    with h5py.File(dst, "r+") as f:
        edit(f)
    return dst


def _set_pressure(value: float, index=(1, 2, 0, 5)):
    def edit(f):
        ds = f["objects/ramp_up/pressure"]
        a = ds[...]
        a[index] = value
        ds[...] = a

    return edit


@pytest.fixture(scope="session")
def fx(tmp_path_factory) -> dict[str, Path]:
    """Shared read-only inputs: a good table, broken tables, a trained run and broken runs."""
    from ham.learn.train import TrainConfig, train
    from ham.model.agent import HamConfig
    from ham.world.config import WorldConfig
    from ham.world.sensor import SensorConfig
    from ham.world.table import build_table

    d = tmp_path_factory.mktemp("bad_inputs_fixtures")
    good = build_table(WorldConfig(), 3, d / "good.h5", progress=False)
    t = {"good": good, "dir": d}
    # tables a run of the paper's world cannot be transferred to (ham evaluate --transfer-table)
    for name, world in (
        ("taxels8", WorldConfig(sensor=SensorConfig(taxels=8))),
        ("reordered", WorldConfig(objects="box,ramp_up,ramp_down,convex")),
        ("xyphi", WorldConfig(pose_dims=("x", "y", "phi"))),
    ):
        t[name] = build_table(world, 3, d / f"{name}.h5", progress=False)

    def attr(key, value):
        def edit(f):
            if value is None:
                del f.attrs[key]
            else:
                f.attrs[key] = value

        return edit

    def drop(path):
        def edit(f):
            del f[path]

        return edit

    def reshape(f):
        del f["objects/box/force"]
        f["objects/box/force"] = np.zeros((2, 2), np.float32)

    def flip_byte(f):
        ds = f["objects/box/pressure"]
        a = ds[...]
        a[0, 0, 0, 0] += 1.0
        ds[...] = a

    edits = {
        "nan": _set_pressure(float("nan")),
        "neg": _set_pressure(-3.0),
        "inf": _set_pressure(float("inf")),
        "huge": _set_pressure(1e16),
        "altered": flip_byte,
        "badsum": attr("checksum", "0" * 64),
        "nosum": attr("checksum", None),
        "noobjects": attr("objects", json.dumps([])),
        "dupobjects": attr("objects", json.dumps(["box", "box"])),
        "objectsnotlist": attr("objects", json.dumps("box")),
        "format": attr("format", "something-else"),
        "version": attr("format_version", 99),
        "grid": attr("grid", 1),
        "missing": drop("objects/convex/pressure"),
        "shape": reshape,
        "world": attr("world", json.dumps({"sensor": {"colour": "red"}})),
    }
    for name, edit in edits.items():
        t[name] = _edit_table(good, d / f"{name}.h5", edit)
    trunc = d / "truncated.h5"
    trunc.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    t["truncated"] = trunc
    text = d / "text.h5"
    text.write_text("not a table\n")
    t["text"] = text
    # the authors' layout (object_0..object_3, grid x grid x 256), with one bad value
    authors = d / "authors_nan.h5"
    with h5py.File(authors, "w") as f:
        for i in range(4):
            a = np.zeros((3, 3, 256), np.float32)
            if i == 2:
                a[1, 1, 7] = np.nan
            f[f"object_{i}"] = a
    t["authors_nan"] = authors
    authors_shape = d / "authors_shape.h5"
    with h5py.File(authors_shape, "w") as f:
        for i in range(4):
            f[f"object_{i}"] = np.zeros((3, 4, 256), np.float32)
    t["authors_shape"] = authors_shape
    for kind, dtype in (("complex", np.complex64), ("text", "S8")):  # both were taken silently
        path = d / f"authors_{kind}.h5"
        with h5py.File(path, "w") as f:
            for i in range(4):
                f[f"object_{i}"] = np.zeros((3, 3, 256), dtype)
        t[f"authors_{kind}"] = path

    run = d / "run"
    cfg = TrainConfig(model=HamConfig(glances=2), steps=1, batch_size=4, eval_every=1,
                      eval_batches=1, table=str(good))  # fmt: skip
    train(cfg, run, progress=False)
    t["run"] = run
    for name in ("badjson", "unknownkey", "nockpt", "badckpt", "badtable"):
        r = d / f"run_{name}"
        shutil.copytree(run, r)
        t[f"run_{name}"] = r
    (d / "run_badjson" / "config.json").write_text("{not json")
    c = json.loads((run / "config.json").read_text())
    (d / "run_unknownkey" / "config.json").write_text(json.dumps({**c, "learning_rate": 1}))
    (d / "run_nockpt" / "checkpoint.pt").unlink()
    (d / "run_badckpt" / "checkpoint.pt").write_bytes(b"garbage")
    (d / "run_badtable" / "config.json").write_text(json.dumps({**c, "table": str(t["nan"])}))
    return t


def _snapshot(root: Path) -> dict[str, tuple[int, int]]:
    return {
        str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns)
        for p in root.rglob("*")
        if p.is_file()
    }


DECOYS = ("adir/", "notes.txt", "fake.png", "fake.h5")
EXAMPLE_GRID = str(Path(__file__).resolve().parents[1] / "docs" / "grids" / "example.toml")


@pytest.fixture
def work(tmp_path, monkeypatch, fx):
    """An empty working folder with decoys (a folder, a text file, text files named .png/.h5)."""
    (tmp_path / "adir").mkdir()
    (tmp_path / "notes.txt").write_text("my notes\n")
    (tmp_path / "fake.png").write_text("not a picture\n")
    (tmp_path / "fake.h5").write_text("not a table\n")
    monkeypatch.chdir(tmp_path)
    before, fixtures = sorted(p.name for p in tmp_path.rglob("*")), _snapshot(fx["dir"])
    yield tmp_path
    after = sorted(p.name for p in tmp_path.rglob("*"))
    assert after == before, f"left behind: {sorted(set(after) - set(before))}"
    assert (tmp_path / "notes.txt").read_text() == "my notes\n"
    assert (tmp_path / "fake.png").read_text() == "not a picture\n"
    assert _snapshot(fx["dir"]) == fixtures, "a fixture file was changed"


def expand(args: list[str], fx: dict[str, Path]) -> list[str]:
    """``{name}`` in an argument is the fixture ``name``'s path (tables, runs)."""
    return [a.format(**{k: str(v) for k, v in fx.items()}) for a in args]


def check_message(err: str, needle: str) -> None:
    lines = [line for line in err.splitlines() if line.strip()]
    assert "Traceback" not in err, err
    assert len(lines) == 1, f"expected one line, got {len(lines)}:\n{err}"
    assert lines[0].startswith("ham: error: "), lines[0]
    assert needle.lower() in lines[0].lower(), f"{needle!r} not in {lines[0]!r}"


# --------------------------------------------------------------------------- the CLI cases
# (id, arguments, a substring the one-line message must contain)
CLI_CASES: list[tuple[str, list[str], str]] = [
    # argparse itself: one line, not a usage dump
    ("unknown-command", ["bogus"], "'bogus'"),
    ("no-command", [], "COMMAND"),
    ("table-no-action", ["table"], "build, info"),
    ("table-bad-action", ["table", "bogus"], "'bogus'"),
    ("envs-bad-action", ["envs", "bogus"], "'bogus'"),
    ("glance-missing-phi", ["glance", "--object", "box", "--x", "0"], "--phi"),
    ("glance-x-not-number", ["glance", "--object", "box", "--x", "abc", "--phi", "0"], "'abc'"),
    ("glance-unknown-option", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--bogus"], "--bogus"),
    ("glance-sensor-choice", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--sensor", "foo"], "'foo'"),
    ("glance-pose-choice", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--pose", "foo"], "'foo'"),
    ("glance-bits-not-int", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--quantize-bits", "1.5"], "'1.5'"),
    ("table-grid-not-int", ["table", "build", "--grid", "abc", "--out", "t.h5"], "'abc'"),
    ("train-core-choice", ["train", "--core", "gru", "--out", "r"], "'gru'"),
    ("train-table-and-env", ["train", "--table", "{good}", "--env", AP_ENV, "--out", "r"], "not allowed with"),
    ("reproduce-target", ["reproduce", "foo", "--out", "rp"], "'foo'"),
    ("reproduce-variant", ["reproduce", "table1", "--out", "rp", "--variants", "bogus"], "'bogus'"),
    ("evaluate-no-dir", ["evaluate"], "DIR"),
    ("heatmap-no-out", ["heatmap", "{run}"], "--out"),
    ("evaluate-policy-choice", ["evaluate", "{run}", "--eval-policy", "foo"], "'foo'"),
    # glance poses (a leading minus is a value, not an option)
    ("x-minus-inf", ["glance", "--object", "box", "--x", "-inf", "--phi", "0"], "-inf"),
    ("x-inf", ["glance", "--object", "box", "--x", "inf", "--phi", "0"], "inf"),
    ("x-nan", ["glance", "--object", "box", "--x", "nan", "--phi", "0"], "nan"),
    ("x-minus-nan", ["glance", "--object", "box", "--x", "-nan", "--phi", "0"], "nan"),
    ("x-2", ["glance", "--object", "box", "--x", "2", "--phi", "0"], "2.0"),
    ("x-minus-1.5", ["glance", "--object", "box", "--x", "-1.5", "--phi", "0"], "-1.5"),
    ("x-minus-exp", ["glance", "--object", "box", "--x", "-1e5", "--phi", "0"], "-100000"),
    ("phi-minus-2", ["glance", "--object", "box", "--x", "0", "--phi", "-2"], "-2.0"),
    ("phi-minus-inf", ["glance", "--object", "box", "--x", "0", "--phi", "-inf"], "-inf"),
    ("object-unknown", ["glance", "--object", "nosuch", "--x", "0", "--phi", "0"], "'nosuch'"),
    ("object-id-99", ["glance", "--object", "99", "--x", "0", "--phi", "0"], "99"),
    ("object-id-minus-1", ["glance", "--object", "-1", "--x", "0", "--phi", "0"], "-1"),
    ("object-empty", ["glance", "--object", "", "--x", "0", "--phi", "0"], "''"),
    ("simulator-unknown", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--simulator", "foo"], "'foo'"),
    ("gazebo-on-fast", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--sensor", "gazebo"], "gazebo"),
    # sensor values: physically absurd ones are refused, not silently used
    ("sigma-100", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--spread-sigma", "100"], "100"),
    ("sigma-0", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--spread-sigma", "0"], "0.0"),
    ("sigma-minus", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--spread-sigma", "-0.005"], "-0.005"),
    ("sigma-inf", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--spread-sigma", "inf"], "inf"),
    ("sigma-nan", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--spread-sigma", "nan"], "nan"),
    ("foam-0", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--foam-stiffness", "0"], "0.0"),
    ("foam-minus", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--foam-stiffness", "-5"], "-5"),
    ("foam-inf", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--foam-stiffness", "inf"], "inf"),
    ("foam-minus-inf", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--foam-stiffness", "-inf"], "-inf"),
    ("foam-nan", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--foam-stiffness", "nan"], "nan"),
    ("foam-too-soft", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--foam-stiffness", "1"], "foam_stiffness = 1"),
    ("foam-too-stiff", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--foam-stiffness", "1e30"], "1e+30"),
    ("bits-0", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--quantize-bits", "0"], "0"),
    ("bits-64", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--quantize-bits", "64"], "64"),
    ("bits-minus", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--quantize-bits", "-1"], "-1"),
    # output files: the format's extension, not a folder, not another kind of file, writable
    ("glance-out-dir", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--out", "adir"], "'adir'"),
    ("glance-out-jpg", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--out", "x.jpg"], "'x.jpg'"),
    ("glance-out-noext", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--out", "picture"], "'picture'"),
    ("glance-out-txt", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--out", "notes.txt"], "'notes.txt'"),
    ("glance-out-fake-png", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--out", "fake.png"], "'fake.png'"),
    ("glance-out-under-file", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--out", "notes.txt/x.png"], "notes.txt"),
    ("glance-out-proc", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--out", "/proc/x.png"], "'/proc/x.png'"),
    ("build-out-proc", ["table", "build", "--grid", "3", "--out", "/proc/t.h5"], "/proc/t.h5"),
    ("glance-out-empty", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--out", " "], "' '"),
    ("objects-set-unknown", ["objects", "--set", "nosuch"], "'nosuch'"),
    ("objects-set-99", ["objects", "--set", "99"], "99"),
    ("objects-set-empty", ["objects", "--set", ""], "''"),
    ("objects-set-twice", ["objects", "--set", "box,box"], "box"),
    ("objects-out-dir", ["objects", "--out", "adir"], "'adir'"),
    ("objects-out-jpg", ["objects", "--out", "x.jpg"], "'x.jpg'"),
    ("objects-out-fake-png", ["objects", "--out", "fake.png"], "'fake.png'"),
    ("objects-out-under-file", ["objects", "--out", "notes.txt/o.png"], "notes.txt"),
    # table build
    ("grid-1", ["table", "build", "--grid", "1", "--out", "t.h5"], "1"),
    ("grid-0", ["table", "build", "--grid", "0", "--out", "t.h5"], "0"),
    ("grid-minus", ["table", "build", "--grid", "-3", "--out", "t.h5"], "-3"),
    ("grid-huge", ["table", "build", "--grid", "99999", "--out", "t.h5"], "99999"),
    ("build-out-txt", ["table", "build", "--grid", "3", "--out", "x.txt"], "'x.txt'"),
    ("build-out-dir", ["table", "build", "--grid", "3", "--out", "adir"], "'adir'"),
    ("build-out-fake-h5", ["table", "build", "--grid", "3", "--out", "fake.h5"], "'fake.h5'"),
    ("build-out-png", ["table", "build", "--grid", "3", "--out", "t.png"], "'t.png'"),
    ("build-out-under-file", ["table", "build", "--grid", "3", "--out", "notes.txt/t.h5"], "notes.txt"),
    ("build-objects-unknown", ["table", "build", "--grid", "3", "--out", "t.h5", "--objects", "nosuch"], "'nosuch'"),
    ("build-objects-twice", ["table", "build", "--grid", "3", "--out", "t.h5", "--objects", "box,box"], "box"),
    ("build-objects-empty", ["table", "build", "--grid", "3", "--out", "t.h5", "--objects", ""], "''"),
    ("build-sigma-1", ["table", "build", "--grid", "3", "--out", "t.h5", "--spread-sigma", "1"], "1.0"),
    ("build-foam-soft", ["table", "build", "--grid", "3", "--out", "t.h5", "--foam-stiffness", "10"], "10"),
    ("build-simulator", ["table", "build", "--grid", "3", "--out", "t.h5", "--simulator", "gazebo"], "'gazebo'"),
    # table info / verify: a corrupt table is refused, not described
    *[
        (f"{cmd}-{name}", ["table", cmd, f"{{{name}}}"], needle)
        for cmd in ("info", "verify")
        for name, needle in (
            ("nan", "nan"),
            ("neg", "-3.0"),
            ("inf", "inf"),
            ("altered", "checksum"),
            ("badsum", "checksum"),
            ("nosum", "checksum"),
            ("noobjects", "[]"),
            ("dupobjects", "box"),
            ("objectsnotlist", "'box'"),
            ("format", "something-else"),
            ("version", "99"),
            ("grid", "grid 1"),
            ("missing", "objects/convex/pressure"),
            ("shape", "objects/box/force"),
            ("truncated", "truncated.h5"),
            ("text", "text.h5"),
        )
    ],
    ("info-no-file", ["table", "info", "nosuch.h5"], "'nosuch.h5'"),
    ("info-dir", ["table", "info", "adir"], "'adir'"),
    ("verify-dir", ["table", "verify", "adir"], "'adir'"),
    ("verify-notes", ["table", "verify", "notes.txt"], "'notes.txt'"),
    # table show
    ("show-object-unknown", ["table", "show", "{good}", "--object", "nosuch", "--out", "s.png"], "'nosuch'"),
    ("show-object-9", ["table", "show", "{good}", "--object", "9", "--out", "s.png"], "9"),
    ("show-object-minus", ["table", "show", "{good}", "--object", "-1", "--out", "s.png"], "-1"),
    ("show-n-1", ["table", "show", "{good}", "--object", "box", "--n", "1", "--out", "s.png"], "--n 1"),
    ("show-n-huge", ["table", "show", "{good}", "--object", "box", "--n", "1000", "--out", "s.png"], "--n 1000"),
    ("show-n-minus", ["table", "show", "{good}", "--object", "box", "--n", "-5", "--out", "s.png"], "--n -5"),
    ("show-out-jpg", ["table", "show", "{good}", "--object", "box", "--out", "s.jpg"], "'s.jpg'"),
    ("show-out-dir", ["table", "show", "{good}", "--object", "box", "--out", "adir"], "'adir'"),
    ("show-nan-table", ["table", "show", "{nan}", "--object", "box", "--out", "s.png"], "nan"),
    # table import-authors
    ("import-missing", ["table", "import-authors", "nosuch.h5", "--out", "o.h5"], "'nosuch.h5'"),
    ("import-not-authors", ["table", "import-authors", "{good}", "--out", "o.h5"], "object_0"),
    ("import-axes", ["table", "import-authors", "{good}", "--out", "o.h5", "--axes", "foo"], "'foo'"),
    ("import-recorded-missing", ["table", "import-recorded", "nosuch.npz", "--out", "o.h5"], "cannot read recorded glances 'nosuch.npz'"),
    ("import-recorded-text", ["table", "import-recorded", "notes.txt", "--out", "o.h5"], "recorded glances 'notes.txt' is not an .npz file (a zip of arrays)"),
    ("import-recorded-dir", ["table", "import-recorded", "adir", "--out", "o.h5"], "recorded glances 'adir' is a folder"),
    ("import-recorded-out-txt", ["table", "import-recorded", "notes.txt", "--out", "o.txt"], "'o.txt'"),
    ("import-recorded-pose-dims", ["table", "import-recorded", "nosuch.npz", "--out", "o.h5", "--pose-dims", "x,z"], "pose_dims: unknown pose dimension 'z'; accepted: a non-empty subset of x,y,phi,phi_y"),
    ("import-recorded-pose-dims-order", ["table", "import-recorded", "nosuch.npz", "--out", "o.h5", "--pose-dims", "phi,x"], "pose_dims = 'phi,x'; accepted: a non-empty subset of x,y,phi,phi_y in that order"),
    ("import-recorded-compression", ["table", "import-recorded", "nosuch.npz", "--out", "o.h5", "--compression", "zip"], "argument --compression: invalid choice: 'zip'"),
    # table calibrate
    ("calibrate-missing-table", ["table", "calibrate", "nosuch.h5", "nosuch.npz", "--out", "o.h5"], "glance table 'nosuch.h5' does not exist"),
    ("calibrate-missing-recorded", ["table", "calibrate", "{good}", "nosuch.npz", "--out", "o.h5"], "cannot read recorded glances 'nosuch.npz'"),
    ("calibrate-recorded-text", ["table", "calibrate", "{good}", "notes.txt", "--out", "o.h5"], "recorded glances 'notes.txt' is not an .npz file"),
    ("calibrate-out-txt", ["table", "calibrate", "{good}", "notes.txt", "--out", "o.txt"], "'o.txt'"),
    ("calibrate-kernel-even", ["table", "calibrate", "{good}", "notes.txt", "--out", "o.h5", "--kernel", "4"], "kernel = 4; accepted: an odd integer from 1 to 31"),
    ("calibrate-kernel-text", ["table", "calibrate", "{good}", "notes.txt", "--out", "o.h5", "--kernel", "nine"], "argument --kernel: invalid int value: 'nine'"),
    ("calibrate-no-recorded", ["table", "calibrate", "{good}", "--out", "o.h5"], "ham table calibrate needs the pad's recorded glances (GLANCES.npz), or --readout-from CALIBRATED.h5"),
    ("calibrate-readout-and-recorded", ["table", "calibrate", "{good}", "notes.txt", "--readout-from", "{good}", "--out", "o.h5"], "recorded glances with --readout-from; accepted:"),
    ("calibrate-readout-and-kernel", ["table", "calibrate", "{good}", "--readout-from", "{good}", "--kernel", "3", "--out", "o.h5"], "--kernel with --readout-from; accepted:"),
    ("calibrate-readout-not-calibrated", ["table", "calibrate", "{good}", "--readout-from", "{good}", "--out", "o.h5"], "was not made by ham table calibrate (no read-out in it); accepted: a calibrated table"),
    ("calibrate-readout-missing", ["table", "calibrate", "{good}", "--readout-from", "nosuch.h5", "--out", "o.h5"], "glance table 'nosuch.h5' does not exist"),
    ("import-out-txt", ["table", "import-authors", "{authors_nan}", "--out", "o.txt"], "'o.txt'"),
    ("import-nan", ["table", "import-authors", "{authors_nan}", "--out", "o.h5"], "nan"),
    ("import-shape", ["table", "import-authors", "{authors_shape}", "--out", "o.h5"], "(3, 4, 256)"),
    ("import-complex", ["table", "import-authors", "{authors_complex}", "--out", "o.h5"], "object_0 holds complex64 values; accepted: real pressures"),
    ("import-text", ["table", "import-authors", "{authors_text}", "--out", "o.h5"], "object_0 holds |S8 values; accepted: real pressures"),
    # train (values are checked by TrainConfig / HamConfig / WorldConfig)
    ("train-no-out", ["train"], "--out"),
    ("train-steps-minus", ["train", "--out", "r", "--steps", "-1"], "-1"),
    ("train-glances-0", ["train", "--out", "r", "--glances", "0"], "glances = 0"),
    ("train-init-from-missing", ["train", "--table", "{good}", "--steps", "1", "--init-from", "nosuch", "--out", "r"], "init_from 'nosuch' does not exist; accepted: a folder of ham train"),
    ("train-init-from-no-run", ["train", "--table", "{good}", "--steps", "1", "--init-from", "adir", "--out", "r"], "init_from 'adir' holds no ham train run"),
    ("train-init-from-other-model", ["train", "--table", "{good}", "--steps", "1", "--hidden-units", "32", "--init-from", "{run}", "--out", "r"], "is another model: its hidden_units 256 (here 32); accepted: a run of the same model (the number of glances may differ)"),
    ("train-init-from-no-checkpoint", ["train", "--table", "{good}", "--steps", "1", "--glances", "2", "--init-from", "{run_nockpt}", "--out", "r"], "checkpoint.pt' does not exist"),
    ("train-batch-0", ["train", "--out", "r", "--batch-size", "0"], "batch_size = 0"),
    ("train-lr-minus", ["train", "--out", "r", "--lr", "-1"], "-1"),
    ("train-lr-0", ["train", "--out", "r", "--lr", "0"], "lr = 0"),
    ("train-lr-nan", ["train", "--out", "r", "--lr", "nan"], "nan"),
    ("train-lr-inf", ["train", "--out", "r", "--lr", "inf"], "inf"),
    ("train-beta-minus", ["train", "--out", "r", "--beta", "-1"], "-1"),
    ("train-beta-nan", ["train", "--out", "r", "--beta", "nan"], "nan"),
    ("train-seed-minus", ["train", "--out", "r", "--seed", "-1"], "-1"),
    ("train-seed-huge", ["train", "--out", "r", "--seed", "99999999999"], "seed = 99999999999; accepted: an integer 0..4294967295"),
    ("train-pose-noise-minus", ["train", "--out", "r", "--pose-noise", "-0.1"], "pose_noise = -0.1"),
    ("train-eval-every-0", ["train", "--out", "r", "--eval-every", "0"], "eval_every = 0"),
    ("train-eval-batches-0", ["train", "--out", "r", "--eval-batches", "0"], "eval_batches = 0"),
    ("train-lr-step-0", ["train", "--out", "r", "--lr-step", "0"], "lr_step = 0"),
    ("train-threads-0", ["train", "--out", "r", "--threads", "0"], "--threads 0"),
    ("train-device-cpu-abc", ["train", "--out", "r", "--device", "cpu:abc"], "'cpu:abc'"),
    ("train-device-tpu", ["train", "--out", "r", "--device", "tpu"], "'tpu'"),
    ("train-device-empty", ["train", "--out", "r", "--device", ""], "''"),
    # an empty value was read as not given: online glances instead of the table, no picture
    ("train-table-empty", ["train", "--out", "r", "--table", ""], "--table ''; accepted: a value"),
    ("train-table-equals-empty", ["train", "--out", "r", "--table="], "--table ''"),
    ("train-resume-empty", ["train", "--resume", ""], "--resume ''"),
    ("objects-image-empty", ["objects", "--image", "", "--name", "x"], "--image ''"),
    ("objects-export-empty", ["objects", "--export", ""], "--export ''"),
    ("glance-out-empty-string", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--out", ""], "--out ''"),
    ("evaluate-run-empty", ["evaluate", ""], "RUN ''; accepted: a value"),
    ("table-build-simulator-file-empty", ["table", "build", "--grid", "3", "--out", "t.h5", "--simulator-file", ""], "--simulator-file ''"),
    ("train-device-cuda-99", ["train", "--out", "r", "--device", "cuda:99"], "'cuda:99'"),
    ("train-table-missing", ["train", "--out", "r", "--table", "nosuch.h5"], "'nosuch.h5'"),
    ("train-table-dir", ["train", "--out", "r", "--table", "adir"], "'adir'"),
    ("train-table-text", ["train", "--out", "r", "--table", "fake.h5"], "'fake.h5'"),
    ("train-table-nan", ["train", "--out", "r", "--table", "{nan}", "--steps", "1"], "nan"),
    ("train-table-neg", ["train", "--out", "r", "--table", "{neg}", "--steps", "1"], "-3.0"),
    ("train-table-huge", ["train", "--out", "r", "--table", "{huge}", "--steps", "1"], "1e+15"),
    ("train-table-altered", ["train", "--out", "r", "--table", "{altered}", "--steps", "1"], "checksum"),
    ("train-table-and-objects", ["train", "--out", "r", "--table", "{good}", "--objects", "box"], "--objects 'box'"),
    ("train-table-and-sigma", ["train", "--out", "r", "--table", "{good}", "--spread-sigma", "0.005"], "spread_sigma=0.005"),
    ("train-table-and-simulator", ["train", "--out", "r", "--table", "{good}", "--simulator", "mujoco"], "simulator='mujoco'"),
    ("train-env-and-objects", ["train", "--out", "r", "--env", AP_ENV, "--objects", "mhsb"], "--objects 'mhsb' chooses the haptic world's objects"),
    ("train-env-and-default-objects", ["train", "--out", "r", "--env", AP_ENV, "--objects", "paper"], f"--objects 'paper' chooses the haptic world's objects; --env {AP_ENV} brings its own classes"),
    ("resume-and-sigma", ["train", "--resume", "{run}", "--spread-sigma", "0.005"], "--spread-sigma"),
    ("train-objects-one", ["train", "--out", "r", "--objects", "box"], "n_objects = 1"),
    ("train-objects-unknown", ["train", "--out", "r", "--objects", "nosuch"], "'nosuch'"),
    ("train-sigma-100", ["train", "--out", "r", "--spread-sigma", "100"], "100"),
    ("train-out-file", ["train", "--out", "notes.txt", "--steps", "1"], "'notes.txt'"),
    ("train-out-under-file", ["train", "--out", "notes.txt/r", "--steps", "1"], "notes.txt"),
    ("train-step-length-no-env", ["train", "--out", "r", "--max-step-length", "abc"], "--max-step-length"),
    ("train-actions-no-env", ["train", "--out", "r", "--actions", "relative"], "--actions"),
    ("train-eval-env-no-env", ["train", "--out", "r", "--eval-env", AP_ENV], "--eval-env"),
    ("train-env-unknown", ["train", "--out", "r", "--env", "nosuch"], "'nosuch'"),
    ("train-env-ap-unknown", ["train", "--out", "r", "--env", "ap_gym:Nosuch-v0"], "'Nosuch-v0'"),
    ("resume-missing", ["train", "--resume", "nosuch"], "nosuch"),
    ("resume-dir", ["train", "--resume", "adir"], "adir"),
    ("resume-file", ["train", "--resume", "notes.txt"], "'notes.txt' is a file"),
    ("resume-and-lr", ["train", "--resume", "{run}", "--lr", "1"], "--lr"),
    ("resume-and-out", ["train", "--resume", "{run}", "--out", "r"], "--resume"),
    ("resume-steps-back", ["train", "--resume", "{run}", "--steps", "0"], "--steps 0"),
    # evaluate
    ("evaluate-missing", ["evaluate", "nosuch"], "nosuch"),
    ("evaluate-dir", ["evaluate", "adir"], "adir"),
    ("evaluate-file", ["evaluate", "fake.h5"], "'fake.h5' is a file"),
    ("heatmap-file", ["heatmap", "fake.h5", "--out", "h.png"], "'fake.h5' is a file"),
    ("evaluate-confusion-dir", ["evaluate", "{run}", "--confusion", "adir"], "--confusion 'adir' is a folder"),
    ("evaluate-confusion-jpg", ["evaluate", "{run}", "--confusion", "c.jpg"], "--confusion 'c.jpg' ends in '.jpg'"),
    ("evaluate-batches-0", ["evaluate", "{run}", "--batches", "0"], "batches = 0"),
    ("evaluate-batches-minus", ["evaluate", "{run}", "--batches", "-1"], "-1"),
    ("evaluate-seed-minus", ["evaluate", "{run}", "--seed", "-1"], "seed = -1"),
    ("evaluate-device-cpu-abc", ["evaluate", "{run}", "--device", "cpu:abc"], "'cpu:abc'"),
    ("evaluate-device-foo", ["evaluate", "{run}", "--device", "foo"], "'foo'"),
    ("evaluate-device-cuda-99", ["evaluate", "{run}", "--device", "cuda:99"], "'cuda:99'"),
    ("evaluate-bad-json", ["evaluate", "{run_badjson}"], "config.json"),
    ("evaluate-unknown-key", ["evaluate", "{run_unknownkey}"], "learning_rate"),
    ("evaluate-no-checkpoint", ["evaluate", "{run_nockpt}"], "checkpoint.pt"),
    ("evaluate-bad-checkpoint", ["evaluate", "{run_badckpt}"], "checkpoint.pt"),
    ("evaluate-nan-table", ["evaluate", "{run_badtable}"], "nan"),
    ("evaluate-transfer-missing", ["evaluate", "{run}", "--transfer-table", "nosuch.h5"], "--transfer-table 'nosuch.h5' does not exist; accepted: a glance table file"),
    ("evaluate-transfer-dir", ["evaluate", "{run}", "--transfer-table", "adir"], "--transfer-table 'adir' is a folder; accepted: a glance table file"),
    ("evaluate-transfer-text", ["evaluate", "{run}", "--transfer-table", "{text}"], "not a complete HDF5 file"),
    ("evaluate-transfer-nan", ["evaluate", "{run}", "--transfer-table", "{nan}"], "nan"),
    ("evaluate-transfer-taxels", ["evaluate", "{run}", "--transfer-table", "{taxels8}"], "holds 8 x 8 images but the run reads 16 x 16; accepted: a table of the run's sensor size"),
    ("evaluate-transfer-objects", ["evaluate", "{run}", "--transfer-table", "{reordered}"], "holds objects box, ramp_up, ramp_down, convex but the run classifies box, ramp_up, convex, ramp_down"),
    ("evaluate-transfer-pose-dims", ["evaluate", "{run}", "--transfer-table", "{xyphi}"], "is a grid over x,y,phi but the run chooses poses over x,phi"),
    ("evaluate-transfer-with-objects", ["evaluate", "{run}", "--transfer-table", "{good}", "--objects", "paper"], "--objects 'paper' with --transfer-table"),
    # heatmap
    ("heatmap-out-jpg", ["heatmap", "{run}", "--out", "h.jpg", "--batches", "1"], "'h.jpg'"),
    ("heatmap-out-dir", ["heatmap", "{run}", "--out", "adir", "--batches", "1"], "'adir'"),
    ("heatmap-out-fake", ["heatmap", "{run}", "--out", "fake.png", "--batches", "1"], "'fake.png'"),
    ("heatmap-batches-0", ["heatmap", "{run}", "--out", "h.png", "--batches", "0"], "batches = 0"),
    ("heatmap-bins-0", ["heatmap", "{run}", "--out", "h.png", "--batches", "1", "--bins", "0"], "bins = 0"),
    ("heatmap-bins-huge", ["heatmap", "{run}", "--out", "h.png", "--batches", "1", "--bins", "100000"], "100000"),
    ("heatmap-seed-minus", ["heatmap", "{run}", "--out", "h.png", "--batches", "1", "--seed", "-5"], "-5"),
    ("heatmap-json-dir", ["heatmap", "{run}", "--out", "h.png", "--batches", "1", "--json", "adir"], "'adir'"),
    ("heatmap-json-txt", ["heatmap", "{run}", "--out", "h.png", "--batches", "1", "--json", "h.txt"], "'h.txt'"),
    ("heatmap-transfer-taxels", ["heatmap", "{run}", "--out", "h.png", "--batches", "1", "--transfer-table", "{taxels8}"], "8 x 8 images"),
    # reproduce (checked before any table or run is made)
    ("reproduce-workers-0", ["reproduce", "table1", "--out", "rp", "--workers", "0"], "workers = 0"),
    ("reproduce-workers-minus", ["reproduce", "table1", "--out", "rp", "--workers", "-2"], "-2"),
    ("reproduce-objects-unknown", ["reproduce", "table1", "--out", "rp", "--objects", "abc"], "unknown object set or object 'abc'"),
    ("reproduce-objects-one", ["reproduce", "table1", "--out", "rp", "--objects", "0"], "n_objects = 1; accepted: >= 2 objects"),
    ("reproduce-seeds-huge", ["reproduce", "table1", "--out", "rp", "--seeds", "99999999999"], "seeds = 99999999999; accepted: an integer from 1 to 10000"),
    ("reproduce-grid-seeds-huge", ["reproduce", "grid", EXAMPLE_GRID, "--out", "rp", "--seeds", "99999999999"], "seeds = 99999999999"),
    ("reproduce-retries-minus", ["reproduce", "table1", "--out", "rp", "--retries", "-1"], "retries = -1"),
    ("reproduce-seeds-0", ["reproduce", "table1", "--out", "rp", "--seeds", "0"], "seeds = 0"),
    ("reproduce-steps-0", ["reproduce", "table1", "--out", "rp", "--steps", "0"], "steps = 0"),
    ("reproduce-grid-steps", ["reproduce", "grid", "docs/grids/example.toml", "--out", "rp", "--steps", "5"], "--steps"),
    ("reproduce-glances-0", ["reproduce", "table1", "--out", "rp", "--glances", "0"], "[0]"),
    ("reproduce-glances-minus", ["reproduce", "table1", "--out", "rp", "--glances", "-1"], "[-1]"),
    ("reproduce-glances-101", ["reproduce", "table1", "--out", "rp", "--glances", "101"], "101"),
    ("reproduce-table2-variants", ["reproduce", "table2", "--out", "rp", "--variants", "rloc"], "--variants cut Table 1 and the figures; accepted with table1"),
    ("reproduce-table2-glances", ["reproduce", "table2", "--out", "rp", "--glances", "2"], "--glances cut Table 1"),
    ("reproduce-device", ["reproduce", "table1", "--out", "rp", "--device", "cpu:abc"], "'cpu:abc'"),
    ("reproduce-device-tpu", ["reproduce", "table1", "--out", "rp", "--device", "tpu"], "'tpu'"),
    ("reproduce-ray-address-local", ["reproduce", "table1", "--out", "rp", "--ray-address", "auto"], "'auto'"),
    ("reproduce-ray-address-refused", ["reproduce", "table1", "--out", "rp", "--executor", "ray", "--ray-address", "127.0.0.1:1"], "'127.0.0.1:1'"),
    ("reproduce-ray-address-form", ["reproduce", "table1", "--out", "rp", "--executor", "ray-batched", "--ray-address", "headnode"], "'headnode'"),
    ("reproduce-grid-ray-address-port", ["reproduce", "grid", "docs/grids/example.toml", "--out", "rp", "--executor", "ray", "--ray-address", "head:99999"], "'head:99999'"),
    ("reproduce-out-file", ["reproduce", "table1", "--out", "notes.txt"], "'notes.txt'"),
    ("reproduce-batch-runs-0", ["reproduce", "table1", "--out", "rp", "--executor", "batched", "--batch-runs", "0"], "batch_runs = 0"),
    ("reproduce-groups-together-0", ["reproduce", "table1", "--out", "rp", "--executor", "batched", "--groups-together", "0"], "groups_together = 0; accepted: an integer >= 1"),
    ("reproduce-groups-together-local", ["reproduce", "table1", "--out", "rp", "--groups-together", "2"], "--groups-together needs --executor batched"),
    ("reproduce-cuda-graph-local", ["reproduce", "table1", "--out", "rp", "--cuda-graph"], "--cuda-graph needs --executor batched"),
    ("reproduce-cuda-graph-cpu", ["reproduce", "table1", "--out", "rp", "--executor", "batched", "--cuda-graph"], "--cuda-graph needs --device cuda"),
    ("reproduce-grid-cache-dir-unused", ["reproduce", "grid", EXAMPLE_GRID, "--out", "rp", "--cache-dir", "c"], "--cache-dir 'c': grid"),
    ("reproduce-grid-cuda-graph-cpu", ["reproduce", "grid", EXAMPLE_GRID, "--out", "rp", "--executor", "batched", "--cuda-graph"], "got 'cpu'"),
    # envs
    ("envs-check-glances-0", ["envs", "check", "--glances", "0"], "glances = 0"),
    ("envs-check-num-envs-0", ["envs", "check", "--num-envs", "0"], "--num-envs 0"),
    ("envs-check-table-missing", ["envs", "check", "--table", "nosuch.h5"], "'nosuch.h5'"),
    ("envs-check-table-nan", ["envs", "check", "--table", "{nan}"], "nan"),
    ("envs-bench-num-envs-0", ["envs", "bench", "--num-envs", "0"], "--num-envs [0]"),
    ("envs-bench-threads-0", ["envs", "bench", "--threads", "0"], "--threads 0"),
    ("envs-bench-threads-huge", ["envs", "bench", "--threads", "99999999999"], "--threads 99999999999; accepted: an integer from 1 to"),
    ("sb3-threads-huge", ["sb3", "--out", "s", "--threads", "99999999999"], "this machine's cores"),
    ("train-object-pose-line-glance", ["train", "--out", "r", "--object-yaw-max", "1.5"], "with the line glance (pose dims x,phi, objects 'paper'); accepted: the extended glance"),
    ("train-hidden-units-huge", ["train", "--out", "r", "--hidden-units", "99999999999"], "too large to hold (Storage size calculation overflowed"),
    ("train-glances-beyond-64-bits", ["train", "--out", "r", "--glances", str(10**30)], f"glances = {10**30}; accepted: an integer of at most 64 bits"),
    ("train-hidden-units-overflow", ["train", "--out", "r", "--hidden-units", str(2**62)], "too large to hold (empty(): argument 'size' failed to unpack the object at pos 1 with error \"Overflow when unpacking long long); accepted"),
    # NumPy's "Maximum allowed dimension exceeded" (a ValueError) was a traceback
    ("glance-pitch-huge", ["glance", "--objects", "curvature2d", "--object", "dome", "--pose-dims", "x,y,phi,phi_y", "--x", "0", "--y", "0", "--phi", "0", "--phi-y", "0", "--pitch", "1e30"], "too large to hold (Maximum allowed dimension exceeded); accepted: a request that fits"),
    ("envs-check-num-envs-huge", ["envs", "check", "--num-envs", str(10**30)], f"num_envs = {10**30}; accepted: an integer of at most 64 bits"),
    ("train-lr-beyond-float32", ["train", "--out", "r", "--lr", "1e300"], "lr = 1e+300; accepted: a finite number within float32 (|x| <= 3.4e38)"),
    ("table-build-pitch-beyond-float32", ["table", "build", "--out", "t.h5", "--grid", "3", "--pitch", "1e300"], "pitch = 1e+300; accepted: a finite number within float32"),
    ("train-threads-huge", ["train", "--out", "r", "--threads", "99999999999"], "--threads 99999999999"),
    ("train-env-unknown-id", ["train", "--env", "nosuch", "--out", "e"], "'nosuch'"),
    ("train-env-glances-0", ["train", "--env", AP_ENV, "--out", "e", "--glances", "0"], "glances = 0"),
    ("train-env-steps-minus", ["train", "--env", AP_ENV, "--out", "e", "--steps", "-1"], "-1"),
    ("train-env-step-length-minus", ["train", "--env", AP_ENV, "--out", "e", "--max-step-length", "-1"], "-1"),
    ("train-env-step-length-nan", ["train", "--env", AP_ENV, "--out", "e", "--max-step-length", "nan"], "nan"),
    ("train-env-step-length-abc", ["train", "--env", AP_ENV, "--out", "e", "--max-step-length", "abc"], "'abc'"),
    ("train-env-batch-0", ["train", "--env", AP_ENV, "--out", "e", "--batch-size", "0"], "0"),
    ("train-env-lr-minus", ["train", "--env", AP_ENV, "--out", "e", "--lr", "-1"], "-1"),
    ("train-env-seed-minus", ["train", "--env", AP_ENV, "--out", "e", "--seed", "-1"], "-1"),
    ("train-env-eval-every-0", ["train", "--env", AP_ENV, "--out", "e", "--eval-every", "0"], "eval_every = 0"),
    ("train-env-eval-env", ["train", "--env", AP_ENV, "--out", "e", "--eval-env", "nosuch"], "'nosuch'"),
    ("train-env-out-file", ["train", "--env", AP_ENV, "--out", "notes.txt"], "'notes.txt'"),
    ("train-env-threads-0", ["train", "--env", AP_ENV, "--out", "e", "--threads", "0"], "--threads 0"),
    # render (checked before MuJoCo draws anything)
    ("render-out-jpg", ["render", "--object", "box", "--x", "0", "--phi", "0", "--out", "r.jpg"], "'r.jpg'"),
    ("render-width", ["render", "--object", "box", "--x", "0", "--phi", "0", "--out", "r.png", "--width", "10"], "10"),
    ("render-height", ["render", "--object", "box", "--x", "0", "--phi", "0", "--out", "r.png", "--height", "99999"], "99999"),
    # demo
    ("demo-out-file", ["demo", "--out", "notes.txt"], "'notes.txt'"),
    # the MuJoCo world: named before the engine compiles a scene
    ("mujoco-housing-0", ["glance", "--simulator", "mujoco", "--object", "box", "--x", "0", "--phi", "0", "--housing-thickness", "0"], "housing_thickness = 0.0"),
    ("mujoco-supersample", ["glance", "--simulator", "mujoco", "--object", "box", "--x", "0", "--phi", "0", "--supersample", "8"], "supersample = 8"),
    ("pad-tiny-no-empty-range", ["glance", "--object", "box", "--x", "0", "--phi", "0", "--pitch", "1e-6"], "taxels * pitch > 0.004082 m"),
    # --cache-dir keeps a preset's table: anywhere else it would be ignored
    # a training option that the chosen learner, core or setting does not read
    ("train-hybrid-gae-lambda", ["train", "--out", "r", "--gae-lambda", "0.9"], "gae_lambda = 0.9 with learner 'hybrid'"),
    ("train-hybrid-info-reward", ["train", "--out", "r", "--info-reward", "hit"], "info_reward = 'hit' with learner 'hybrid'"),
    ("train-info-beta", ["train", "--out", "r", "--learner", "info", "--beta", "0.7"], "beta = 0.7 with learner 'info'"),
    ("train-info-replay-size", ["train", "--out", "r", "--learner", "info", "--replay-size", "10"], "replay_size = 10 with learner 'info'"),
    ("train-clip-one-epoch", ["train", "--out", "r", "--learner", "info", "--clip", "0.1"], "clip = 0.1 where nothing reads it"),
    ("train-move-cost-on-no-cost", ["train", "--out", "r", "--learner", "info", "--move-cost-on", "reward"], "move_cost_on = 'reward'"),
    ("train-stop-learner-no-stop", ["train", "--out", "r", "--stop-learner", "hindsight"], "stop_learner = 'hindsight'"),
    ("train-stop-input-no-stop", ["train", "--out", "r", "--stop-input", "core"], "stop_input = 'core' without a learned stop"),
    ("train-mlp-forget-bias", ["train", "--out", "r", "--core", "mlp", "--forget-bias", "2"], "forget_bias = 2.0 with core 'mlp'"),
    ("train-lstm-transformer-heads", ["train", "--out", "r", "--transformer-heads", "8"], "transformer_heads = 8 with core 'lstm'"),
    ("train-add-combine-units", ["train", "--out", "r", "--combiner", "add", "--combine-units", "128"], "combine_units = 128 with combiner 'add'"),
    ("train-random-std-activation", ["train", "--out", "r", "--policy", "random", "--std-activation", "sigmoid"], "std_activation = 'sigmoid' with policy 'random'"),
    ("train-adam-no-nesterov", ["train", "--out", "r", "--optimizer", "adam", "--no-nesterov"], "nesterov = False where nothing reads it"),
    ("objects-view-no-out", ["objects", "--set", "paper", "--view", "3d"], "--view applies only with --out"),
    ("build-compression-paper-table", ["table", "build", "--grid", "3", "--out", "t.h5", "--compression", "none"], "compression = 'none'"),
    ("build-compression-preset", ["table", "build", "--world", "paper-gazebo", "--out", "t.h5", "--compression", "lzf"], "--compression lzf with --world"),
    ("build-cache-dir-no-world", ["table", "build", "--grid", "3", "--out", "t.h5", "--cache-dir", "c"], "--cache-dir 'c' without --world"),
    ("train-cache-dir-no-world", ["train", "--out", "r", "--cache-dir", "c"], "--cache-dir 'c' without --world"),
    ("train-cache-dir-online", ["train", "--out", "r", "--world", "paper-gazebo", "--online", "--cache-dir", "c"], "--cache-dir 'c' with --online"),
    ("reproduce-cache-dir-no-world", ["reproduce", "table1", "--out", "rp", "--cache-dir", "c"], "--cache-dir 'c' without --world"),
    ("build-cache-dir-unmakeable", ["table", "build", "--world", "paper-gazebo", "--out", "t.h5", "--cache-dir", "/proc/no/such"], "cache folder '/proc/no/such' cannot be made"),
]  # fmt: skip
if CUDA:  # on a GPU machine "cuda:99" is still out of range; "no CUDA" cases need a CPU machine
    pass
else:
    CLI_CASES += [
        ("train-device-cuda", ["train", "--out", "r", "--device", "cuda"], "'cuda'"),
        ("evaluate-device-cuda", ["evaluate", "{run}", "--device", "cuda"], "'cuda'"),
        ("reproduce-device-cuda", ["reproduce", "table1", "--out", "rp", "--device", "cuda"], "'cuda'"),
    ]  # fmt: skip


def run_inprocess(argv: list[str]) -> tuple[int, str, str]:
    """The CLI's ``main`` in this process (:func:`tests.conftest.run_ham_inprocess`)."""
    r = run_ham_inprocess(*argv)
    return r.returncode, r.stdout, r.stderr


@pytest.mark.parametrize("case", CLI_CASES, ids=[c[0] for c in CLI_CASES])
def test_cli_bad_input(case, fx, work):
    _, args, needle = case
    rc, out, err = run_inprocess(expand(args, fx))
    assert rc == 2, f"exit {rc}; stdout: {out[-500:]}; stderr: {err[-500:]}"
    check_message(err, needle)


# The real CLI in a subprocess behaves the same (parser errors, HamError, files, devices).
SUBPROCESS = [
    "unknown-command",
    "glance-x-not-number",
    "x-minus-inf",
    "sigma-100",
    "glance-out-jpg",
    "build-out-txt",
    "info-altered",
    "verify-noobjects",
    "train-device-cpu-abc",
    "evaluate-seed-minus",
    "evaluate-transfer-objects",
    "reproduce-workers-0",
    "heatmap-json-dir",
    "envs-check-table-nan",
]


@pytest.mark.parametrize("name", SUBPROCESS)
def test_cli_bad_input_subprocess(name, fx, work, ham_cli):
    _, args, needle = next(c for c in CLI_CASES if c[0] == name)
    r = ham_cli(*expand(args, fx), cwd=work, timeout=120)
    assert r.returncode == 2, f"exit {r.returncode}; stdout: {r.stdout[-500:]}; stderr: {r.stderr}"
    check_message(r.stderr, needle)


def test_a_reader_that_leaves_early_is_no_error(work):
    """``ham objects | head -1``: the pipe closes before ham writes; it exits as a command killed
    by SIGPIPE (141), with nothing on stderr (it said ``ham: error: [Errno 32] Broken pipe``)."""
    import subprocess

    from tests.conftest import ham_command

    argv, env = ham_command("objects")
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=work, env=env)
    proc.stdout.close()  # before ham writes: importing torch takes seconds
    _, err = proc.communicate(timeout=120)
    assert (proc.returncode, err) == (141, b"")


# --------------------------------------------------------------------------- Python API cases
def _table(name):
    def call(fx):
        from ham.world.table import GlanceTable

        GlanceTable.load(fx[name])

    return call


def _world(d):
    def call(fx):
        from ham.world.config import WorldConfig

        WorldConfig.from_dict(d)

    return call


def _gym(env_id=None, **kw):
    def call(fx):
        import gymnasium as gym

        import ham.envs

        kw2 = {k: (str(fx[v[1:-1]]) if isinstance(v, str) and v.startswith("{") else v)
               for k, v in kw.items()}  # fmt: skip
        gym.make(env_id or ham.envs.ENV_ID, **kw2)

    return call


def _ap(**kw):
    def call(fx):
        import ham.envs
        from ham.learn.ap_adapter import import_ap_gym

        import_ap_gym().make(ham.envs.AP_ENV_ID, **kw)

    return call


def _ap_step(action, vector=False):
    def call(fx):
        import ham.envs
        from ham.learn.ap_adapter import import_ap_gym

        ap_gym = import_ap_gym()
        env = (
            ap_gym.make_vec(ham.envs.AP_ENV_ID, num_envs=2)
            if vector
            else ap_gym.make(ham.envs.AP_ENV_ID)
        )
        env.reset(seed=0)
        env.step(action)

    return call


def _vec(**kw):
    def call(fx):
        import gymnasium as gym

        import ham.envs

        gym.make_vec(ham.envs.ENV_ID, **kw)

    return call


def _env_step(action, options=None):
    def call(fx):
        import gymnasium as gym

        import ham.envs

        env = gym.make(ham.envs.ENV_ID).unwrapped
        if action is not None:
            env.reset(seed=0, options=options)
            env.step(action)
        else:
            env.step({"pose": np.zeros(2, np.float32), "prediction": 0})

    return call


def _sensor(**kw):
    def call(fx):
        from ham.world.sensor import SensorConfig

        SensorConfig(**kw)

    return call


def _train_config(**kw):
    def call(fx):
        from ham.learn.train import TrainConfig

        TrainConfig(**kw)

    return call


def _evaluate(**kw):
    def call(fx):
        from ham.learn.evaluation import evaluate, heatmap_data
        from ham.learn.train import load_run

        run = load_run(fx["run"])
        fn = heatmap_data if "bins" in kw else evaluate
        fn(run.agent, run.env, 1, **kw)

    return call


def _load_run(name, **kw):
    def call(fx):
        from ham.learn.train import load_run

        load_run(fx[name] if name in fx else name, **kw)

    return call


def _transfer(table):
    """``load_run`` of the fixtures' run onto fixture table ``table``."""

    def call(fx):
        from ham.learn.train import load_run

        load_run(fx["run"], transfer_table=str(fx[table]))

    return call


def _object(kind, *args, **kw):
    def call(fx):
        from ham.world.objects import HapticObject

        getattr(HapticObject, kind)(*args, **kw)

    return call


def _reproduce(target="table1", **kw):
    def call(fx):
        from ham.experiments.reproduce import reproduce

        reproduce(target, "smoke", "rp", progress=False, **kw)

    return call


def _build(out, grid=3):
    def call(fx):
        from ham.world.config import WorldConfig
        from ham.world.table import build_table

        build_table(WorldConfig(), grid, out, progress=False)

    return call


def _draw(out):
    def call(fx):
        from ham.world.drawing import draw_objects
        from ham.world.objects import resolve_set

        draw_objects(resolve_set("paper"), out)

    return call


def _device(device):
    def call(fx):
        from ham.world.devices import check_device

        check_device(device)

    return call


# (id, call(fixtures), a substring the HamError's message must contain)
PY_CASES = [
    *[(f"load-{n}", _table(n), s) for n, s in (
        ("nan", "nan"), ("neg", "-3.0"), ("inf", "inf"), ("altered", "checksum"),
        ("badsum", "checksum"), ("noobjects", "[]"), ("dupobjects", "box"), ("format", "something-else"),
        ("version", "99"), ("missing", "convex"), ("shape", "force"), ("truncated", "truncated.h5"),
        ("text", "text.h5"), ("grid", "grid 1"),
    )],
    ("load-world-unknown-key", lambda fx: __import__("ham.world.table", fromlist=["x"]).GlanceTable.load(fx["world"]).world, "colour"),
    ("load-device-bad", lambda fx: __import__("ham.world.table", fromlist=["x"]).GlanceTable.load(fx["good"], device="cpu:abc"), "'cpu:abc'"),
    ("load-no-file", lambda fx: __import__("ham.world.table", fromlist=["x"]).GlanceTable.load("nosuch.h5"), "'nosuch.h5'"),
    ("verify-nan", lambda fx: __import__("ham.world.table", fromlist=["x"]).verify_table(fx["nan"]), "nan"),
    ("world-unknown-key", _world({"objects": "paper", "colour": "red"}), "colour"),
    ("world-sensor-unknown", _world({"sensor": {"foam": 1}}), "foam"),
    ("world-pose-unknown", _world({"pose": {"angle": 1}}), "angle"),
    ("world-glance-unknown", _world({"glance": {"force": 2}}), "force"),
    ("world-not-dict", _world("paper"), "'paper'"),
    ("world-sensor-not-dict", _world({"sensor": 5}), "5"),
    ("world-mujoco-not-dict", _world({"mujoco": [1]}), "[1]"),
    ("world-objects-not-str", _world({"objects": 5}), "5"),
    ("world-foam-string", _world({"sensor": {"foam_stiffness": "stiff"}}), "'stiff'"),
    ("world-phi-string", _world({"pose": {"phi_max": "wide"}}), "wide"),
    ("world-phi-5", _world({"pose": {"phi_max": 5}}), "5"),
    ("world-force-minus", _world({"glance": {"force_threshold": -1}}), "-1"),
    ("world-sigma-1", _world({"sensor": {"spread_sigma": 1.0}}), "1.0"),
    ("world-foam-soft", _world({"sensor": {"foam_stiffness": 1.0}}), "foam_stiffness = 1"),
    ("sensor-bits-0", _sensor(quantize_bits=0), "0"),
    ("sensor-bits-64", _sensor(quantize_bits=64), "64"),
    ("sensor-sigma-100", _sensor(spread_sigma=100.0), "100"),
    ("sensor-foam-1e30", _sensor(foam_stiffness=1e30), "1e+30"),
    ("sensor-foam-minus", _sensor(foam_stiffness=-1.0), "-1.0"),
    ("gym-glances-0", _gym(glances=0), "glances = 0"),
    ("gym-glances-float", _gym(glances=2.5), "2.5"),
    ("gym-world-unknown", _gym(world={"colour": "red"}), "colour"),
    ("gym-object-pose-line-glance", _gym(object_pose={"yaw_max": 0.5}), "a random object pose (ObjectPoseConfig(yaw_max=0.5, offset_max=0.0)) with the line glance"),
    ("gym-object-pose-mujoco", _gym(object_pose={"offset_max": 0.01}, world={"simulator": "mujoco", "pose_dims": ["x", "y", "phi", "phi_y"]}), "with simulator 'mujoco'; accepted: simulator 'fast'"),
    ("gym-world-sensor-unknown", _gym(world={"sensor": {"foam": 1}}), "foam"),
    ("gym-world-bad-type", _gym(world=5), "5"),
    ("gym-normalization", _gym(normalization="l3"), "'l3'"),
    ("gym-device-bad", _gym(device="cpu:abc"), "'cpu:abc'"),
    ("gym-device-tpu", _gym(device="tpu"), "'tpu'"),
    ("gym-device-cuda-99", _gym(device="cuda:99"), "'cuda:99'"),
    ("gym-table-missing", _gym(table="nosuch.h5"), "'nosuch.h5'"),
    ("gym-table-nan", _gym(table="{nan}"), "nan"),
    ("gym-table-and-world", _gym(table="{good}", world={"objects": "mhsb"}), "give one"),
    ("gym-render-mode", _gym(render_mode="bogus"), "'bogus'"),
    ("gym-vec-num-envs-0", _vec(num_envs=0), "0"),
    ("gym-step-before-reset", _env_step(None), "reset"),
    ("gym-step-nan-pose", _env_step({"pose": [float("nan"), 0.0], "prediction": 0}), "nan"),
    ("gym-reset-object-99", _env_step({"pose": [0.0, 0.0], "prediction": 0}, {"object": 99}), "99"),
    ("ap-glances-0", _ap(glances=0), "glances = 0"),
    ("ap-action-keys", _ap_step({"pose": [0.0, 0.0], "prediction": np.zeros(4)}), "'pose'"),
    ("ap-prediction-nan", _ap_step({"action": np.zeros(2), "prediction": np.full(4, np.nan)}), "nan"),
    ("ap-prediction-shape", _ap_step({"action": np.zeros(2), "prediction": np.zeros(3)}), "(3,)"),
    ("ap-vec-action-keys", _ap_step({"pose": 1}, vector=True), "'pose'"),
    ("gym-table-int", _gym(table=5), "5"),
    ("gym-reset-unknown-option", _env_step({"pose": [0.0, 0.0], "prediction": 0}, {"objekt": 1}), "objekt"),
    ("gym-reset-options-list", _env_step({"pose": [0.0, 0.0], "prediction": 0}, [1]), "[1]"),
    ("gym-step-extra-key", _env_step({"pose": [0.0, 0.0], "prediction": 0, "force": 2}), "force"),
    ("gym-step-no-prediction", _env_step({"pose": [0.0, 0.0]}), "prediction"),
    ("gym-step-prediction-99", _env_step({"pose": [0.0, 0.0], "prediction": 99}), "99"),
    ("train-config-beta-str", _train_config(beta="high"), "'high'"),
    ("train-config-decay-str", _train_config(lr_decay="slow"), "'slow'"),
    ("train-config-momentum-none", _train_config(momentum=None), "None"),
    ("train-config-nesterov-no-momentum", _train_config(momentum=0.0), "momentum = 0"),
    ("train-config-seed-bool", _train_config(seed=True), "True"),
    ("train-config-table-int", _train_config(table=5), "5"),
    ("train-config-world-dict", _train_config(world={}), "{}"),
    ("train-config-model-dict", _train_config(model={}), "{}"),
    ("train-config-nesterov-str", _train_config(nesterov="no"), "'no'"),
    ("train-config-from-list", lambda fx: __import__("ham.learn.train", fromlist=["x"]).TrainConfig.from_dict([1]), "[1]"),
    ("pose-config-str", lambda fx: __import__("ham.world.glance", fromlist=["x"]).PoseConfig(phi_max="wide"), "'wide'"),
    ("glance-config-str", lambda fx: __import__("ham.world.glance", fromlist=["x"]).GlanceConfig(force_threshold="2N"), "'2N'"),
    ("sensor-bits-bool", _sensor(quantize_bits=True), "True"),
    ("sensor-housing-str", _sensor(housing_thickness="thick"), "thick"),
    ("ap-device-bad", _ap(device="cpu:abc"), "'cpu:abc'"),
    ("ap-world-unknown", _ap(world={"colour": "red"}), "colour"),
    ("train-config-device", _train_config(device="cpu:abc"), "'cpu:abc'"),
    ("train-config-device-tpu", _train_config(device="tpu"), "'tpu'"),
    ("train-config-seed", _train_config(seed=-1), "-1"),
    ("train-config-steps", _train_config(steps=-5), "-5"),
    ("train-config-from-dict", lambda fx: __import__("ham.learn.train", fromlist=["x"]).TrainConfig.from_dict({"learning_rate": 1}), "learning_rate"),
    ("evaluate-seed-minus", _evaluate(seed=-1), "seed = -1"),
    ("evaluate-seed-float", _evaluate(seed=1.5), "1.5"),
    ("heatmap-bins-huge", _evaluate(bins=10**6), "1000000"),
    ("load-run-missing", _load_run("nosuch"), "nosuch"),
    ("load-run-device", _load_run("run", device="cpu:abc"), "'cpu:abc'"),
    ("load-run-device-99", _load_run("run", device="cuda:99"), "'cuda:99'"),
    ("load-run-badckpt", _load_run("run_badckpt"), "checkpoint.pt"),
    ("load-run-transfer-missing", _load_run("run", transfer_table="nosuch.h5"), "'nosuch.h5' does not exist"),
    ("load-run-transfer-pose-dims", _transfer("xyphi"), "is a grid over x,y,phi"),
    ("object-polyline-one-point", _object("from_polyline", "p", [(0.0, 0.0)]), "'p'"),
    ("object-polyline-nan", _object("from_polyline", "p", [(-0.04, 0.0), (0.04, float("nan"))]), "finite"),
    ("object-polyline-backwards", _object("from_polyline", "p", [(0.04, 0.0), (-0.04, 0.01)]), "non-decreasing"),
    ("object-polyline-negative", _object("from_polyline", "p", [(-0.04, -0.01), (0.04, 0.01)]), "height -0.01"),
    ("object-heightmap-short", _object("from_heightmap", "h", [0.01]), "'h'"),
    ("object-function-negative", _object("from_function", "f", lambda x: x), "height -0.045"),
    ("reproduce-workers-0", _reproduce(workers=0), "workers = 0"),
    ("reproduce-retries-minus", _reproduce(retries=-1), "retries = -1"),
    ("reproduce-device", _reproduce(device="cpu:abc"), "'cpu:abc'"),
    ("reproduce-target", _reproduce(target="table9"), "'table9'"),
    ("build-out-txt", _build("t.txt"), "'t.txt'"),
    ("build-out-dir", _build("adir"), "'adir'"),
    ("build-grid-float", _build("t.h5", grid=2.5), "2.5"),
    ("draw-out-jpg", _draw("o.jpg"), "'o.jpg'"),
    ("draw-out-fake", _draw("fake.png"), "'fake.png'"),
    ("device-cpu-1", _device("cpu:1"), "'cpu:1'"),
    ("device-int", _device(3), "3"),
]  # fmt: skip
if not CUDA:
    PY_CASES += [
        ("gym-device-cuda", _gym(device="cuda"), "'cuda'"),
        ("ap-device-cuda", _ap(device="cuda"), "'cuda'"),
        ("load-device-cuda", lambda fx: __import__("ham.world.table", fromlist=["x"]).GlanceTable.load(fx["good"], device="cuda"), "'cuda'"),
        ("load-run-cuda", _load_run("run", device="cuda"), "'cuda'"),
    ]  # fmt: skip


@pytest.mark.parametrize("case", PY_CASES, ids=[c[0] for c in PY_CASES])
def test_python_bad_input(case, fx, work):
    _, call, needle = case
    with pytest.raises(HamError) as info:
        call(fx)
    msg = str(info.value)
    assert "\n" not in msg, msg
    assert needle.lower() in msg.lower(), f"{needle!r} not in {msg!r}"


def test_case_count():
    """The audit's size: at least 150 bad inputs, each a distinct id."""
    ids = [c[0] for c in CLI_CASES] + [c[0] for c in PY_CASES]
    assert len(CLI_CASES) + len(PY_CASES) >= 150
    assert len(set(c[0] for c in CLI_CASES)) == len(CLI_CASES)
    assert len(set(c[0] for c in PY_CASES)) == len(PY_CASES)
    assert ids


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
@pytest.mark.parametrize("out", ["locked/g.png", "locked/sub/g.png"])
def test_unwritable_folder(out, work):
    (work / "locked").mkdir(mode=0o500)
    try:
        rc, _, err = run_inprocess(["glance", "--object", "box", "--x", "0", "--phi", "0",
                                    "--out", out])  # fmt: skip
    finally:
        (work / "locked").rmdir()
    assert rc == 2
    check_message(err, "not writable")


# --------------------------------------------------------------------------- what still works
def test_good_inputs_next_to_the_bad_ones(fx, work):
    """The checks refuse only bad input: a negative pose, a fresh .png, a verified table."""
    rc, out, err = run_inprocess(["glance", "--object", "box", "--x", "-0.5", "--phi", "-1e-1",
                                  "--out", "g.png"])  # fmt: skip
    assert rc == 0, err
    assert "q = (-0.500, -0.100)" in out
    assert (work / "g.png").read_bytes().startswith(b"\x89PNG")
    rc, out, err = run_inprocess(["glance", "--object", "box", "--x", "0", "--phi", "0",
                                  "--out", "g.png", "--spread-sigma", "0.005"])  # fmt: skip
    assert rc == 0, err  # an existing PNG is replaced
    rc, out, err = run_inprocess(["table", "verify", str(fx["good"])])
    assert rc == 0 and out.startswith("ok "), (out, err)
    rc, out, err = run_inprocess(["table", "info", str(fx["good"])])
    assert rc == 0 and "(verified)" in out, (out, err)
    (work / "g.png").unlink()
    assert math.isfinite(float(np.float32(1.0)))
    assert not [p for p in os.listdir(work) if ".tmp" in p]
