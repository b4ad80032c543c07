"""``--objects-file``: the user's own objects, recorded in tables and runs (the real CLI).

A table or run built from an objects file keeps the file's name, sha256 and text; every later
command (train --table, evaluate, heatmap, resume, reproduce workers) registers the objects from
that record, without the flag.
"""

import hashlib
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import ok, one_line_error, run_ham, run_ham_inprocess

HEADER = "import numpy as np\nfrom ham.world.objects import HapticObject, register\n"
#: The example of docs/world.md, "Your own objects": the tests keep the docs' file working.
OWN = (Path(__file__).parents[1] / "docs" / "examples" / "my_objects.py").read_text()
NAMES = ["cylinder", "wedge", "bump", "notch"]


@pytest.fixture(scope="module")
def own(tmp_path_factory):
    """The objects file and a table (grid 11) built from it."""
    d = tmp_path_factory.mktemp("own")
    f = d / "my_objects.py"
    f.write_text(OWN)
    ok(run_ham("table", "build", "--objects-file", str(f), "--grid", "11", "--quiet",
               "--out", str(d / "t.h5")))  # fmt: skip
    return f, d / "t.h5"


def test_objects_and_glance_take_the_file(own):
    f, _ = own
    docs = (Path(__file__).parents[1] / "docs" / "world.md").read_text()
    assert OWN.strip() in docs  # the example shown is the example tested
    rows = json.loads(ok(run_ham("objects", "--objects-file", str(f), "--json")).stdout)
    mine = [r for r in rows if r["name"] in NAMES]
    first = sum(r["origin"] == "built-in" for r in rows)  # the file's objects come next
    assert [(r["id"], r["name"]) for r in mine] == list(enumerate(NAMES, start=first))
    assert all(r["origin"].startswith("objects file 'my_objects.py' (sha256 ") for r in mine)
    assert rows[0]["origin"] == "built-in"
    # a new process: the ids follow the registry, and this one's may hold other tests' objects
    r = ok(run_ham("glance", "--objects-file", str(f), "--objects", ",".join(NAMES),
                   "--object", "cylinder", "--x", "0", "--phi", "0", "--json"))  # fmt: skip
    g = json.loads(r.stdout)
    assert g["object"] == "cylinder" and g["object_id"] == first
    assert g["force"] == pytest.approx(2.0, abs=1e-3)
    assert g["z"] == pytest.approx(0.02 + 0.5 * 0.045, abs=2e-3)  # the pad rests on the top
    r = run_ham_inprocess("glance", "--objects-file", str(f), "--objects", "wedge,bump",
                "--object", "box", "--x", "0", "--phi", "0")  # fmt: skip
    assert "--object 'box' is not in --objects 'wedge,bump'" in one_line_error(r)


def test_a_table_records_the_file_and_its_command(own):
    f, table = own
    info = json.loads(ok(run_ham("table", "info", str(table), "--json")).stdout)
    assert info["objects"] == NAMES
    record = info["world"]["objects_file"]
    assert record == {
        "name": "my_objects.py",
        "sha256": hashlib.sha256(f.read_bytes()).hexdigest(),
        "source": OWN,
    }
    assert info["command"] == (
        f"ham table build --objects-file {f} --grid 11 --quiet --out {table}"
    )
    text = ok(run_ham_inprocess("table", "info", str(table))).stdout
    assert f"objects file: my_objects.py (sha256 {record['sha256']})" in text


def test_train_evaluate_resume_from_the_table_without_the_flag(own, tmp_path):
    _, table = own
    run = tmp_path / "run"
    ok(run_ham_inprocess("train", "--table", str(table), "--steps", "20", "--eval-every", "10",
               "--eval-batches", "2", "--no-progress", "--out", str(run)))  # fmt: skip
    ev = json.loads(ok(run_ham("evaluate", str(run), "--batches", "2", "--json")).stdout)
    assert ev["steps"] == 20 and len(ev["accuracy_per_glance"]) == 3
    ok(run_ham_inprocess("train", "--resume", str(run), "--steps", "30", "--no-progress"))
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["steps"] == 30 and metrics["objects"] == NAMES


def test_an_online_run_reregisters_its_objects(own, tmp_path):
    """Evaluate (in a new process), heatmap and resume build the simulator of the file's objects
    from the run's record (the registry of this process is restored after each command)."""
    f, _ = own
    run = tmp_path / "run"
    ok(run_ham_inprocess("train", "--online", "--objects-file", str(f), "--objects", "bump,notch",
               "--steps", "6", "--eval-every", "6", "--eval-batches", "1", "--batch-size", "8",
               "--no-progress", "--out", str(run)))  # fmt: skip
    world = json.loads((run / "config.json").read_text())["world"]
    assert world["objects"] == "bump,notch"
    assert world["objects_file"]["sha256"] == hashlib.sha256(f.read_bytes()).hexdigest()
    f2 = tmp_path / "moved.py"  # the file itself is not needed any more
    f2.write_text(f.read_text())
    ev = json.loads(ok(run_ham("evaluate", str(run), "--batches", "2", "--json")).stdout)
    assert ev["steps"] == 6
    ok(run_ham_inprocess("heatmap", str(run), "--batches", "2", "--out", str(tmp_path / "h.png")))
    ok(run_ham_inprocess("train", "--resume", str(run), "--steps", "8", "--no-progress"))
    assert json.loads((run / "metrics.json").read_text())["objects"] == ["bump", "notch"]
    r = run_ham_inprocess("train", "--resume", str(run), "--objects-file", str(f), "--steps", "9")
    assert "remove --objects-file" in one_line_error(r)


def test_reproduce_workers_use_the_recorded_objects(own, tmp_path):
    """The local process pool's spawned workers train on the file's objects (a Ray task runs
    the same worker function in a fresh process: test_reproduce checks Ray against the pool)."""
    f, _ = own
    part = ["--profile", "smoke", "--glances", "1", "2", "--variants", "full", "--quiet"]
    out = tmp_path / "local"
    r = ok(run_ham("reproduce", "table1", *part, "--workers", "2", "--objects-file", str(f),
                   "--out", str(out)))  # fmt: skip
    assert "ran 2 run(s)" in r.stdout
    info = json.loads(
        ok(run_ham_inprocess("table", "info", str(out / "table_21.h5"), "--json")).stdout
    )
    assert info["objects"] == NAMES and info["world"]["objects_file"]["name"] == "my_objects.py"
    assert info["command"].startswith("ham reproduce table1 --profile smoke")
    metrics = list(out.glob("runs/*/metrics.json"))
    assert len(metrics) == 2
    for m in metrics:
        assert json.loads(m.read_text())["objects"] == NAMES
    # Another object set in the same OUT would mix glances: refused.
    r = run_ham_inprocess("reproduce", "table1", *part, "--out", str(out))
    assert (
        "holds glances of objects 'cylinder,wedge,bump,notch' from my_objects.py, not 'paper'"
        in one_line_error(r)
    )


def test_a_worker_builds_a_missing_table_from_the_record(own, tmp_path):
    """A fresh worker process (no table on its node) registers the file's objects from the world."""
    from ham.experiments.executors import execute_local
    from ham.experiments.reproduce import PROFILES, plan
    from ham.world.config import WorldConfig
    from ham.world.objects import names, read_objects_file

    f, _ = own
    record = read_objects_file(f)
    assert "cylinder" not in names()  # this process never registers them: the workers do
    world = WorldConfig(objects=",".join(NAMES), objects_file=record)
    table = tmp_path / "table_5.h5"
    jobs = plan("table2", PROFILES["smoke"], 1, str(table))[:1]  # 4 classes, as NAMES
    results: list[dict] = []
    execute_local(jobs, tmp_path, world.to_dict(), 5, 2, results.append)  # a pool of 2 processes
    assert [r["status"] for r in results] == ["done"], results
    info = json.loads(ok(run_ham("table", "info", str(table), "--json")).stdout)
    assert info["objects"] == NAMES and info["world"]["objects_file"] == record


BAD_FILES = [
    # (file name, body after the imports, the value the one-line error names)
    ("const.py", "register(HapticObject.from_function('flat', lambda x: 0.03))",
     "object 'flat': profile h(x) returned shape () for x of shape (4097,)"),
    ("short.py", "register(HapticObject.from_function('short', lambda x: x[:10] + 0.02))",
     "object 'short': profile h(x) returned shape (10,) for x of shape (4097,)"),
    ("scalar.py", "import math\nregister(HapticObject.from_function('s', lambda x: math.cos(x)))",
     "object 's': profile h(x) failed on an array x of shape (4097,): TypeError"),
    ("nan.py", "register(HapticObject.from_function('n', lambda x: np.full_like(x, np.nan)))",
     "object 'n': height nan at x = -0.045 m is not finite"),
    ("complex.py", "register(HapticObject.from_function('c', lambda x: np.full_like(x, 0.02) + 0j))",
     "object 'c': profile h(x) returned complex values; accepted: real heights (m)"),  # was taken
    ("text.py", "register(HapticObject.from_surface('t', lambda x, y: np.full(x.shape, '0.02')))",
     "object 't': surface h(x, y) returned text values"),  # and failed later in MuJoCo
    ("ragged.py", "register(HapticObject.from_function('r', lambda x: [[0.02]] + [[0.0, 0.0]]))",
     "object 'r': profile h(x) returned a ragged list (rows of different lengths)"),
    ("text.json", '{"objects": [{"name": "t", "heightmap": ["0.01", "0.02"]}]}',
     "objects file 'text.json': object 't': heightmap must be a 1-D list of >= 2 heights"),
    ("inf.py", "register(HapticObject.from_heightmap('i', [0.01, np.inf]))",
     "object 'i': height inf at x = 0.045 m is not finite"),
    ("below.py", "register(HapticObject.from_polyline('b', [(-0.045, -0.01), (0.045, 0.02)]))",
     "object 'b': height -0.01 at x = -0.045 m is below the table"),
    ("tall.py", "register(HapticObject.from_heightmap('t', [0.02, 0.2]))",
     "object 't': height 0.2 at x = 0.045 m is above the block height limit 0.09 m"),
    ("flat0.py", "register(HapticObject.from_heightmap('z', [0.0, 0.0]))",
     "object 'z': every height is 0 (no block)"),
    ("width0.py", "register(HapticObject.from_function('w', np.ones_like, width=0))",
     "object 'w': width = 0; accepted: a number in [0.001, 0.2] (m)"),
    ("widthneg.py", "register(HapticObject.from_heightmap('w', [0.01, 0.02], width=-0.09))",
     "object 'w': width = -0.09"),
    ("depth0.py", "register(HapticObject.from_polyline('d', [(0, 0.01), (0.09, 0.01)], depth=0.0))",
     "object 'd': depth = 0.0"),
    ("span0.py", "register(HapticObject.from_polyline('p', [(0.01, 0.02), (0.01, 0.03)]))",
     "object 'p': width (last x - first x) = 0.0"),
    ("taken.py", "register(HapticObject.from_heightmap('box', [0.01, 0.02]))",
     "object name 'box' is already registered (built-in)"),
    ("twice.py", "for _ in range(2):\n    register(HapticObject.from_heightmap('cyl', [0.01, 0.02]))",
     "object name 'cyl' is already registered (objects file 'twice.py')"),
    ("comma.py", "register(HapticObject.from_heightmap('a,b', [0.01, 0.02]))", "object name 'a,b'"),
    ("colon.py", "register(HapticObject.from_heightmap('a:b', [0.01, 0.02]))", "object name 'a:b'"),
    ("space.py", "register(HapticObject.from_heightmap('a b', [0.01, 0.02]))", "object name 'a b'"),
    ("slash.py", "register(HapticObject.from_heightmap('a/b', [0.01, 0.02]))", "object name 'a/b'"),
    ("number.py", "register(HapticObject.from_heightmap('12', [0.01, 0.02]))", "object name '12'"),
    ("empty.py", "register(HapticObject.from_heightmap('', [0.01, 0.02]))", "object name ''"),
    ("setname.py", "register(HapticObject.from_heightmap('paper', [0.01, 0.02]))",
     "object name 'paper' is the name of an object set"),
    ("raises.py", "raise RuntimeError('boom')",
     "objects file 'raises.py' raised RuntimeError at line 3: boom"),
    ("syntax.py", "def (", "objects file 'syntax.py' has a syntax error at line 3"),
    ("nothing.py", "x = 1", "objects file 'nothing.py' registers no objects"),
    ("objects.txt", "", "objects file '{dir}/objects.txt': accepted: a .py file"),
    ("missing.py", None, "objects file '{dir}/missing.py' does not exist"),
    ("bad.toml", "objects = [{name = 'w', polyline = [[0, 0.01]]}]",
     "objects file 'bad.toml': object 'w': polyline must be N >= 2 points (x, z)"),
    ("bad.json", "{not json", "objects file 'bad.json' is not valid"),
]  # fmt: skip


def _write_bad(tmp_path: Path, name: str, body: str | None) -> Path:
    f = tmp_path / name
    if body is not None:
        f.write_text(body if f.suffix in (".toml", ".json", ".txt") else HEADER + body + "\n")
    return f


@pytest.mark.parametrize("name, body, message", BAD_FILES, ids=[b[0] for b in BAD_FILES])
def test_a_bad_objects_file_is_refused_and_registers_nothing(tmp_path, name, body, message):
    from ham.errors import HamError
    from ham.world.objects import load_objects_file, names

    f = _write_bad(tmp_path, name, body)
    before = names()
    with pytest.raises(HamError) as err:
        load_objects_file(f)
    text = str(err.value)
    assert message.format(dir=tmp_path) in text and "\n" not in text
    if name not in ("objects.txt", "missing.py"):
        assert text.startswith(f"objects file {name!r}")
    assert names() == before  # a failed file leaves the registry as it was


#: One of each kind through the real CLI: exit 2, one line, no traceback, no file written.
CLI_CASES = ["const.py", "scalar.py", "nan.py", "below.py", "tall.py", "width0.py", "taken.py",
             "comma.py", "number.py", "empty.py", "raises.py", "syntax.py", "nothing.py",
             "missing.py", "bad.toml"]  # fmt: skip


@pytest.mark.parametrize("name", CLI_CASES)
def test_a_bad_objects_file_is_one_line_and_writes_nothing(tmp_path, name):
    _, body, message = next(b for b in BAD_FILES if b[0] == name)
    f = _write_bad(tmp_path, name, body)
    r = run_ham("table", "build", "--objects-file", str(f), "--grid", "3", "--quiet",
                "--out", str(tmp_path / "t.h5"))  # fmt: skip
    assert message.format(dir=tmp_path) in one_line_error(r)
    assert sorted(p.name for p in tmp_path.iterdir()) == ([name] if body is not None else [])


def test_json_and_toml_files_describe_polylines_and_heightmaps(tmp_path):
    f = tmp_path / "shapes.toml"
    f.write_text(
        "[[objects]]\nname = 'low_wedge'\npolyline = [[-0.045, 0.0], [0.045, 0.02]]\n"
        "description = 'a low wedge'\n"
        "[[objects]]\nname = 'stairs'\nheightmap = [0.01, 0.02, 0.03]\nwidth = 0.06\n"
    )
    rows = json.loads(ok(run_ham("objects", "--objects-file", str(f), "--set",
                                 "low_wedge,stairs", "--json")).stdout)  # fmt: skip
    assert [(r["name"], r["width"], r["height"]) for r in rows] == [
        ("low_wedge", 0.09, 0.02),
        ("stairs", 0.06, 0.03),
    ]
    g = tmp_path / "shapes.json"
    g.write_text(json.dumps({"objects": [{"name": "ramp2", "heightmap": [0.0, 0.04]}]}))
    r = ok(run_ham("glance", "--objects-file", str(g), "--object", "ramp2", "--x", "0.5",
                   "--phi", "0", "--json"))  # fmt: skip
    assert json.loads(r.stdout)["force"] == pytest.approx(2.0, abs=1e-3)


def test_a_changed_record_or_a_conflicting_file_is_refused(own, tmp_path):
    f, table = own
    run = tmp_path / "run"
    ok(run_ham("train", "--online", "--objects-file", str(f), "--steps", "2", "--eval-every",
               "2", "--eval-batches", "1", "--batch-size", "8", "--no-progress",
               "--out", str(run)))  # fmt: skip
    cfg = json.loads((run / "config.json").read_text())
    cfg["world"]["objects_file"]["source"] += "# edited\n"
    (run / "config.json").write_text(json.dumps(cfg))
    line = one_line_error(run_ham_inprocess("evaluate", str(run), "--batches", "1"))
    assert "objects file 'my_objects.py': recorded sha256" in line and "does not match" in line
    # Same names, other shapes: the table's objects and the file's cannot both be 'cylinder'.
    other = tmp_path / "my_objects.py"
    assert "0.02 + 0.5" in OWN
    other.write_text(OWN.replace("0.02 + 0.5", "0.01 + 0.5"))
    out = tmp_path / "run2"
    r = run_ham_inprocess("train", "--table", str(table), "--objects-file", str(other), "--steps", "2",
                "--out", str(out))  # fmt: skip
    line = one_line_error(r)
    assert "object name 'cylinder' is already registered (objects file 'my_objects.py'" in line
    assert not out.exists()


def test_commands_record_the_real_argv(tmp_path):
    """Python callers and ``main(argv)`` record what ran, not ``sys.argv`` of another program."""
    code = (
        "import sys; from ham.cli.main import main; from ham.world.config import WorldConfig; "
        "from ham.world.table import build_table, table_info; "
        f"build_table(WorldConfig(), 2, {str(tmp_path / 'a.h5')!r}, progress=False); "
        f"main(['table', 'build', '--grid', '2', '--quiet', '--out', {str(tmp_path / 'b.h5')!r}]); "
        f"print(table_info({str(tmp_path / 'a.h5')!r}).command); "
        f"print(table_info({str(tmp_path / 'b.h5')!r}).command)"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    a, b = r.stdout.strip().splitlines()[-2:]
    assert a == f"python -c: ham.world.table.build_table(grid=2, out={str(tmp_path / 'a.h5')!r})"
    assert b == f"ham table build --grid 2 --quiet --out {Path(tmp_path / 'b.h5')}"


def test_object_options_that_would_be_ignored_are_refused(own, tmp_path):
    f, table = own
    r = run_ham("train", "--table", str(table), "--objects", "paper", "--out", str(tmp_path / "a"))
    assert "--objects 'paper' chooses the online world's objects; the table" in one_line_error(r)
    r = run_ham_inprocess("train", "--env", "ap_gym:CIFAR10-v0", "--objects-file", str(f),
                "--out", str(tmp_path / "b"))  # fmt: skip
    assert "--env ap_gym:CIFAR10-v0 brings its own world" in one_line_error(r)
    r = run_ham_inprocess("envs", "check", "--table", str(table), "--objects", "wedge")
    assert "--objects 'wedge' chooses the online world's objects" in one_line_error(r)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"height": 0.0}, "object 'a': height = 0.0; accepted: a number in (0, 0.09] (m)"),
        ({"width": math.nan}, "object 'a': width = nan; accepted: a number in [0.001, 0.2]"),
        ({"depth": 0.3}, "object 'a': depth = 0.3; accepted: a number in [0.001, 0.2] (m)"),
        # a block of 1e-300 m was an IndexError (extended glance) or NumPy's "Maximum allowed
        # dimension exceeded" (the fast simulator's narrow-peak window): found by a sweep
        ({"depth": 1e-300}, "object 'a': depth = 1e-300; accepted: a number in [0.001, 0.2]"),
        ({"profile": 3}, "object 'a': profile 3 is not a function"),
        ({"name": "1"}, "object name '1'; accepted: a letter or '_' first"),
        ({"description": "two\nlines"}, "description 'two\\nlines'; accepted: one line of text"),
    ],
)
def test_the_plain_constructor_checks_its_fields(kwargs, message):
    import numpy as np

    from ham.errors import HamError
    from ham.world.objects import HapticObject

    fields = {"name": "a", "profile": np.ones_like, **kwargs}
    with pytest.raises(HamError) as err:
        HapticObject(**fields)
    assert message in str(err.value)
