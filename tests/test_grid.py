"""Grids as data (``ham.experiments.grid``) and ``ham reproduce grid FILE``: the real CLI, real runs."""

import json
from pathlib import Path

import pytest

from ham.errors import HamError
from ham.experiments.grid import Grid, load_grid
from ham.experiments.reproduce import PAPER_GRIDS, PROFILES, paper_grid, plan
from tests.conftest import registries_restored

DOCS = Path(__file__).resolve().parents[1] / "docs" / "grids"

TINY = """\
name = "tiny"
seeds = 2
evaluate = [{policy = "sample", batches = 2}]

[table]
grid = 11

[base]
steps = 10
eval_every = 5
eval_batches = 2

[axes]
model.glances = [1, 2]

[[cells]]
name = "diverges"     # a learning rate no network survives: training stops with a HamError
lr = 1e30
seeds = [0]
"""


def grid_of(text: str, tmp_path: Path, name: str = "g.toml") -> Grid:
    path = tmp_path / name
    path.write_text(text)
    return load_grid(path)


# --------------------------------------------------------------------------- parse and expand
def test_axes_expand_to_their_product_then_the_listed_cells(tmp_path):
    g = grid_of(
        """
        name = "demo"
        seeds = [0, 1]
        [base]
        steps = 100
        "model.core" = "mlp"          # a quoted dotted key is the same as a nested one
        [axes]
        model.glances = [2, 3]
        model.policy = ["learned", "random"]
        [[cells]]
        name = "g10"
        model.glances = 10
        seeds = [5]
        """,
        tmp_path,
    )
    assert [c.name for c in g.expand()] == [
        "glances=2_policy=learned", "glances=2_policy=random",
        "glances=3_policy=learned", "glances=3_policy=random", "g10",
    ]  # fmt: skip
    jobs = g.jobs()
    assert [j.key for j in jobs][:3] == [
        "glances=2_policy=learned-s0",
        "glances=2_policy=learned-s1",
        "glances=2_policy=random-s0",
    ]
    assert len(jobs) == 4 * 2 + 1 and jobs[-1].key == "g10-s5"
    c = jobs[3].config  # glances 2, random, seed 1
    assert (c["model"]["glances"], c["model"]["policy"], c["model"]["core"]) == (2, "random", "mlp")
    assert (c["steps"], c["seed"], c["table"], c["lr"]) == (100, 1, None, 8e-4)  # defaults kept
    assert jobs[-1].config["model"]["glances"] == 10 and jobs[-1].config["steps"] == 100
    # the grid round-trips through its dict (what DIR/grid.json holds)
    assert Grid.from_dict(json.loads(json.dumps(g.to_dict()))) == g


def test_no_axes_no_cells_is_one_run_per_seed_and_json_works(tmp_path):
    g = grid_of('{"name": "one", "seeds": 3, "base": {"lr": 0.001}}', tmp_path, "one.json")
    assert [j.key for j in g.jobs()] == ["base-s0", "base-s1", "base-s2"]
    assert g.jobs()[0].config["lr"] == 0.001


def test_a_table_grid_puts_every_run_on_the_table(tmp_path):
    g = grid_of('name = "t"\n[table]\ngrid = 21\n', tmp_path)
    table = g.table_path(tmp_path)
    assert table == str(tmp_path / "table_21.h5")
    assert g.jobs(table)[0].config["table"] == table
    with pytest.raises(HamError, match="a table path goes with"):
        g.jobs()


def test_the_paper_tables_are_grids_in_docs(tmp_path):
    """docs/grids/table1.toml and table2.toml are the grids `ham reproduce table1|table2` runs."""
    for name in ("table1", "table2"):
        assert load_grid(DOCS / f"{name}.toml") == Grid.from_dict(PAPER_GRIDS[name])
        assert paper_grid(name, PROFILES["paper"]) == Grid.from_dict(PAPER_GRIDS[name])
    keys = [j.key for j in load_grid(DOCS / "table1.toml").jobs("t.h5")]
    assert keys == [j.key for j in plan("table1", PROFILES["paper"], 10, "t.h5")]
    assert keys[:2] == ["full-concat2-g1-s0", "full-concat2-g1-s1"] and len(keys) == 3 * 7 * 10


@pytest.mark.parametrize("path", sorted(DOCS.glob("*.toml")), ids=lambda p: p.stem)
def test_every_grid_in_docs_plans_valid_runs(path, tmp_path):
    """Each grid file the docs name loads, and every run it plans is a valid training config."""
    with registries_restored():  # a grid's plugin registers its cores in this process
        g = load_grid(path)
        jobs = g.jobs(g.table_paths(tmp_path, tmp_path / "cache"))
    keys = [j.key for j in jobs]
    assert keys and len(set(keys)) == len(keys)


def test_the_mlp_protocol_grid_is_what_its_results_say():
    """docs/grids/paper_protocol_taxels_mlp.toml: MLP core, taxel read-out, 4 x 3 runs of 50k."""
    g = load_grid(DOCS / "paper_protocol_taxels_mlp.toml")
    jobs = g.jobs("t.h5")
    assert {j.config["model"]["core"] for j in jobs} == {"mlp"}
    assert {j.config["world"]["simulator"] for j in jobs} == {"fast"}
    assert len(jobs) == 12 and {j.config["steps"] for j in jobs} == {50000}


def test_the_agent_grid_is_the_old_script(tmp_path):
    """docs/grids/agent.toml: the runs benchmarks/agent_experiments.sh trained with `ham train`."""
    from ham.cli.agent import _config_from_args
    from ham.cli.main import build_parser

    jobs = {j.key: j for j in load_grid(DOCS / "agent.toml").jobs()}
    assert len(jobs) == 13
    parser = build_parser()
    for key, args in (
        ("g10-s0", "--glances 10 --steps 1500 --seed 0 --eval-every 100 --eval-batches 100"),
        ("g3_learned-s1", "--glances 3 --policy learned --steps 3000 --seed 1 --eval-every 250 --eval-batches 50"),
        ("g2_random-s2", "--glances 2 --policy random --steps 3000 --seed 2 --eval-every 250 --eval-batches 50"),
    ):  # fmt: skip
        config = _config_from_args(parser.parse_args(["train", *args.split(), "--out", "x"]))
        assert jobs[key].config == config.to_dict(), key
    assert [s["policy"] for s in jobs["g10-s0"].evaluate] == ["mean", "sample"]


# --------------------------------------------------------------------------- validation
@pytest.mark.parametrize(
    "text, message",
    [
        ('name = "x"\n[base]\nmodel.glance = 3\n',
         r"grid 'x' base: unknown key 'model.glance'; accepted: steps, batch_size, lr, .*model.glances"),
        ('name = "x"\n[axes]\nstep = [1, 2]\n', r"grid 'x': unknown key 'step'; accepted: steps,"),
        ('name = "x"\n[[cells]]\nname = "a"\nlrr = 1\n', r"grid 'x' cell 'a': unknown key 'lrr'"),
        ('name = "x"\nsteps = 3\n', r"unknown key 'steps'; accepted: name, description, seeds"),
        ('name = "x"\n[world]\nobject = "paper"\n', r"grid 'x' world: unknown key 'object'; accepted: objects,"),
        ('name = "x"\n[base]\nseed = 3\n', r"key 'seed' is set by the grid's seeds"),
        ('name = "x"\n[base]\nmodel.combiner = "sum"\n',
         r"grid 'x' cell 'base': combiner = 'sum'; accepted: concat2, concat1, add, mul"),
        ('name = "x"\n[axes]\nlr = [0.1, -1.0]\n',
         r"cell 'lr=-1': lr = -1.0; accepted: a finite number > 0"),
        ('name = "x"\n[axes]\nmodel.glances = []\n',
         r"axis 'model.glances' = \[\]; accepted: a non-empty list of values"),
        ('name = "x"\n[axes]\nmodel.glances = [2, 2]\n', r"axis 'model.glances': value 2 is listed twice"),
        ('name = "x"\n[[cells]]\nname = "a"\n[[cells]]\nname = "a"\nlr = 0.1\n', r"duplicate cell 'a'"),
        ('name = "x"\n[[cells]]\nname = "a"\nsteps = 5\n[[cells]]\nname = "b"\nsteps = 5\n',
         r"duplicate cell: 'b' runs the same config as 'a'"),
        ('name = "x"\ndescription = nan\n', r"grid 'x': description = nan; accepted: a string"),
        ('name = "x"\nseeds = 0\n', r"seeds = 0; accepted: a count from 1 to 10000 or a list of up to 10000 distinct"),
        ('name = "x"\nevaluate = [{policy = "greedy"}]\n',
         r"evaluate\[0\]: policy 'greedy'; accepted: mean, sample"),
        ('name = "x"\n[table]\ngrid = 1\n', r"table grid = 1; accepted: an integer 2..2001"),
        ('name = "x"\n[table]\ngrid = 99999\n', r"table grid = 99999; accepted: an integer 2..2001"),
        ('name = "x"\nevaluate = [{batches = 0}]\n', r"batches = 0; accepted: an integer 1 .. 2\*\*63-1"),
        # an empty table flattened to nothing: the key was dropped without a word
        ('name = "x"\n[base]\nsteps = {}\n', r"grid 'x' base: steps = \{\}; accepted: a value \(an empty table"),
        ('name = "x"\n[[cells]]\nname = {}\n', r"grid 'x' cells\[0\]: name = \{\}; accepted: a value"),
        ('name = "x"\n[axes]\nmodel.glances = {}\n', r"axis 'model.glances' = \{\}; accepted: a non-empty list"),
        ('name = "x"\n[base]\nmodel.glances = 1e30\n', r"glances = 1e\+30; accepted: an integer"),
        ('name = "x"\nkey = "{varient}"\n[axes]\nvariant = [{name = "a"}]\n',
         r"key '\{varient\}' cannot be formatted .*accepted fields: variant, model.glances"),
        ('name = "x"\nkey = "{name}"\n', r"key '\{name\}' names the axes' cells, but there are no axes"),
        ('name = "x y"\n', r"grid name 'x y'; accepted: letters, digits"),
        ('name = "x"\n[base\n', r"is not valid TOML"),
        ('name = "x"\n[[cells]]\nname = ""\n', r"cells\[0\]: name = ''; accepted: letters, digits"),
        ('name = "x"\n[[cells]]\nname = 5\n', r"cells\[0\]: name = 5; accepted: letters, digits"),
        ('name = "x"\n[base]\n"model.glances" = 1\nmodel.glances = 2\n',
         r"grid 'x' base: key 'model.glances' is given twice \(quoted and dotted\); accepted: once"),
        ('name = "x"\n[axes]\n"model.glances" = [1]\nmodel.glances = [2]\n',
         r"grid 'x' axis 'model.glances' is given twice"),
        ('name = "x"\n[[cells]]\nname = "a"\n"model.core" = "mlp"\nmodel.core = "lstm"\n',
         r"grid 'x' cell 'a': key 'model.core' is given twice"),
    ],
)  # fmt: skip
def test_bad_grids_stop_with_one_line(tmp_path, text, message):
    with pytest.raises(HamError, match=message) as err:
        grid_of(text, tmp_path)
    assert "\n" not in str(err.value)


def test_a_grid_file_must_exist_and_be_toml_or_json(tmp_path):
    with pytest.raises(HamError, match="cannot be read"):
        load_grid(tmp_path / "missing.toml")
    (tmp_path / "binary.toml").write_bytes(b"\xfc\xa9 not text")
    with pytest.raises(HamError, match="is not UTF-8 text"):
        load_grid(tmp_path / "binary.toml")
    (tmp_path / "g.yaml").write_text("name: x\n")
    with pytest.raises(HamError, match=r"accepted: a \.toml or \.json file"):
        load_grid(tmp_path / "g.yaml")


# --------------------------------------------------------------------------- the command
@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    from tests.conftest import run_ham

    tmp = tmp_path_factory.mktemp("grid")
    (tmp / "tiny.toml").write_text(TINY)
    out = tmp / "out"
    r = run_ham("reproduce", "grid", str(tmp / "tiny.toml"), "--workers", "2", "--quiet",
                "--out", str(out))  # fmt: skip
    return out, r


def test_a_grid_runs_and_reports(tiny_run):
    out, r = tiny_run
    assert r.returncode == 1, r.stderr  # the diverging cell failed
    assert "ran 4 run(s), skipped 0 finished" in r.stdout
    # the diverging cell was tried once, not retried (--retries 1 by default): it would resume
    # from its checkpoint and diverge again; then reported
    assert "not retrying 1 diverged run(s)" in r.stderr and "attempt 2" not in r.stderr
    assert "ham: run diverges-s0 failed: DivergedError: training diverged at step" in r.stderr
    results = json.loads((out / "results.json").read_text())
    cells = {c["cell"]: c for c in results["cells"]}
    assert list(cells) == ["glances=1", "glances=2", "diverges"]
    g2 = cells["glances=2"]
    assert g2["finished"] == 2 and g2["best_accuracy"]["n"] == 2
    assert 0 <= g2["best_accuracy"]["mean"] <= 1 and g2["best_accuracy"]["sem"] >= 0
    assert g2["evaluations"][0]["accuracy"]["n"] == 2
    assert len(g2["evaluations"][0]["accuracy_per_glance"]) == 2
    assert cells["diverges"]["finished"] == 0 and cells["diverges"]["best_accuracy"]["n"] == 0
    assert [f["key"] for f in results["failures"]] == ["diverges-s0"]
    report = (out / "report.md").read_text()
    mean, sem = g2["best_accuracy"]["mean"], g2["best_accuracy"]["sem"]
    assert f"| `glances=2` | glances=2 | 2/2 | 10 | {mean:.3f} ± {sem:.3f} |" in report
    assert "| `diverges` | lr=1e+30 | 0/1 | 10 | — |" in report
    assert "- `diverges-s0`: DivergedError: training diverged" in report
    # each glance's pose spread at the last evaluation, mean over the cell's seeds
    a, b = (json.loads((out / "runs" / f"glances=2-s{s}" / "metrics.json").read_text())
            for s in (0, 1))  # fmt: skip
    want = [(a["pose_spread"][g] + b["pose_spread"][g]) / 2 for g in range(2)]
    assert g2["pose_spread"] == pytest.approx(want)
    section = report.split("## Pose spread per glance")[1].split("##")[0]
    assert f"| `glances=2` | {want[0]:.3f} (" in section
    assert "| `glances=1` | " in section and section.count("—") == 1  # 1 glance of 2 columns
    # which code and machine made the numbers, in the report and beside the results
    env = results["environment"]
    assert {"commit", "cpu", "simd", "MKL_CBWR", "torch"} <= set(env)
    assert f"commit {env['commit']}, " in report
    assert (out / "curves.png").read_bytes()[:4] == b"\x89PNG"
    # the grid and every run's resolved config are saved beside the results
    plan_ = json.loads((out / "plan.json").read_text())
    assert [j["key"] for j in plan_][:2] == ["glances=1-s0", "glances=1-s1"]
    assert plan_[0]["config"]["table"] == str(out / "table_11.h5")
    assert Grid.from_dict(json.loads((out / "grid.json").read_text())).name == "tiny"
    evaluation = json.loads(
        (out / "runs" / "glances=1-s0" / "eval_sample_2b_seed12345.json").read_text()
    )
    assert evaluation["steps"] == 10 and evaluation["eval_policy"] == "sample"


def test_a_rerun_skips_finished_runs(tiny_run, ham_cli):
    out, _ = tiny_run
    before = (out / "runs" / "glances=2-s1" / "metrics.json").read_bytes()
    # the saved grid.json is itself a grid file
    r = ham_cli("reproduce", "grid", str(out / "grid.json"), "--workers", "2", "--retries", "0",
                "--quiet", "--out", str(out))  # fmt: skip
    assert r.returncode == 1, r.stderr  # the diverging cell fails again, once
    assert "ran 0 run(s), skipped 4 finished" in r.stdout
    assert "retrying" not in r.stderr
    assert (out / "runs" / "glances=2-s1" / "metrics.json").read_bytes() == before


def test_another_config_in_the_same_folder_is_refused(tiny_run, tmp_path):
    from ham.experiments.grid_run import run_grid

    out, _ = tiny_run
    (tmp_path / "tiny.toml").write_text(TINY.replace("steps = 10", "steps = 20"))
    with pytest.raises(
        HamError,
        match=r"runs/glances=1-s0 holds a run with another config \(steps 10 there, 20 in the grid\)",
    ):
        run_grid(tmp_path / "tiny.toml", out, workers=1, progress=False)  # fmt: skip


def test_a_run_written_before_a_field_existed_is_skipped_not_refused(tiny_run, tmp_path):
    """A config.json written before a field existed loads with the field's default (as resume
    loads it): a rerun skips that finished run instead of calling it another config."""
    import shutil

    from ham.experiments.grid_run import run_grid

    out, _ = tiny_run
    copy = tmp_path / "out"
    shutil.copytree(out, copy)
    run = copy / "runs" / "glances=1-s0"
    config = json.loads((run / "config.json").read_text())
    del config["model"]["probe_grid"], config["move_cost_on"]  # fields of later versions
    (run / "config.json").write_text(json.dumps(config))
    before = (run / "metrics.json").read_bytes()
    summary = run_grid(copy / "grid.json", copy, workers=1, retries=0, progress=False)
    assert summary["skipped"] == 4  # the four finished runs; the diverging cell ran again
    assert (run / "metrics.json").read_bytes() == before


@pytest.mark.parametrize(
    ("executor", "damage"),
    [("local", b"\x00not json"), ("local", b"[1]"), ("local", b'{"steps": "x"}'),
     ("batched", b"[1]")],
)  # fmt: skip
def test_a_finished_run_whose_metrics_are_damaged_writes_them_again(
    tiny_run, tmp_path, executor, damage
):
    """A lost or damaged metrics.json (a full disk, a hand edit) made the rerun's report end in
    a traceback; the run counts as unfinished now, resumes from its final checkpoint with no
    step to take, and writes its metrics again, the same numbers."""
    import shutil

    from ham.experiments.grid_run import run_grid

    out, _ = tiny_run
    copy = tmp_path / "out"
    shutil.copytree(out, copy)
    metrics = copy / "runs" / "glances=2-s1" / "metrics.json"
    before = metrics.read_bytes()
    metrics.write_bytes(damage)
    summary = run_grid(copy / "grid.json", copy, workers=1, retries=0, progress=False,
                       executor=executor)  # fmt: skip
    assert summary["skipped"] == 3 and summary["ran"] == 1
    assert [f["key"] for f in summary["failures"]] == ["diverges-s0"]  # it diverges again
    again, was = json.loads(metrics.read_bytes()), json.loads(before)
    # the same numbers; the batched executor records the table at the copy's path
    assert again["config"].pop("table").endswith("table_11.h5")
    assert was["config"].pop("table").endswith("table_11.h5")
    assert again == was


def test_a_damaged_config_of_a_finished_run_is_not_a_traceback(tiny_run, tmp_path):
    """A run's config.json that is JSON but not a dict (damaged) was a TypeError in the check
    for another config; it counts as unreadable now, and the finished run is skipped."""
    import shutil

    from ham.experiments.grid_run import run_grid

    out, _ = tiny_run
    copy = tmp_path / "out"
    shutil.copytree(out, copy)
    (copy / "runs" / "glances=1-s0" / "config.json").write_text("[1]")
    summary = run_grid(copy / "grid.json", copy, workers=1, retries=0, progress=False)
    assert summary["skipped"] == 4


def test_a_run_too_large_for_the_machine_is_one_line_in_the_report(tmp_path):
    """A model whose size overflows inside torch (an LSTM of 4 x 2**62 rows) fails its run with
    the CLI's one line, not torch's C++ frames (the report read "TypeError: empty(): ...
    Exception raised from THPUtils_unpackLong ..." over many lines)."""
    from ham.experiments.grid_run import run_grid

    (tmp_path / "g.toml").write_text(
        f'name = "huge"\n[base]\nsteps = 2\neval_batches = 1\nmodel.hidden_units = {2**62}\n'
    )
    summary = run_grid(tmp_path / "g.toml", tmp_path / "o", workers=1, retries=0, progress=False)
    assert [f["key"] for f in summary["failures"]] == ["base-s0"]
    report = (tmp_path / "o" / "report.md").read_text()
    line = next(x for x in report.splitlines() if x.startswith("- `base-s0`"))
    assert line.startswith("- `base-s0`: too large to hold (empty(): argument 'size' failed"), line
    assert line.endswith("a smaller batch, model, sensor, grid or object set)"), line


def test_grid_arguments(tmp_path, capsys):
    from ham.cli.main import main

    assert main(["reproduce", "grid", "--out", str(tmp_path)]) == 2
    assert "ham reproduce grid needs a grid FILE" in capsys.readouterr().err
    (tmp_path / "g.toml").write_text('name = "g"\n')
    assert main(["reproduce", "grid", str(tmp_path / "g.toml"), "--profile", "smoke",
                 "--out", str(tmp_path)]) == 2  # fmt: skip
    assert "--profile apply to the paper's tables, not to a grid file" in capsys.readouterr().err
    assert main(["reproduce", "table1", str(tmp_path / "g.toml"), "--out", str(tmp_path)]) == 2
    assert "goes with `ham reproduce grid FILE`, not table1" in capsys.readouterr().err
    (tmp_path / "bad.toml").write_text('name = "g"\n[base]\nmodel.glance = 3\n')
    assert main(["reproduce", "grid", str(tmp_path / "bad.toml"), "--out", str(tmp_path)]) == 2
    assert "unknown key 'model.glance'; accepted:" in capsys.readouterr().err


def test_the_report_shows_per_object_accuracy_when_runs_have_a_confusion_matrix(tiny_run, tmp_path):
    import shutil

    from ham.experiments.grid_run import write_report

    out = tmp_path / "out"
    shutil.copytree(tiny_run[0] / "runs", out / "runs")
    grid = Grid.from_dict(json.loads((tiny_run[0] / "grid.json").read_text()))
    jobs = grid.jobs(grid.table_path(tiny_run[0]))
    for seed, hits in ((0, 5), (1, 3)):  # rows: true object; 8 episodes of each
        path = out / "runs" / f"glances=1-s{seed}" / "metrics.json"
        m = json.loads(path.read_text())
        m["history"][-1]["confusion"] = [[hits, 8 - hits, 0, 0]] + [[0, 0, 8, 0]] * 3
        path.write_text(json.dumps(m))
    for seed in (0, 1):  # runs without a matrix (older runs) get no per-object column
        path2 = out / "runs" / f"glances=2-s{seed}" / "metrics.json"
        m = json.loads(path2.read_text())
        for row in m["history"]:
            row.pop("confusion", None)
        path2.write_text(json.dumps(m))
    summary = write_report(out, grid, jobs, [], command=None, executor="local")
    per = summary["cells"][0]["per_object_accuracy"]
    assert list(per) == json.loads(path.read_text())["objects"]
    first = per[list(per)[0]]
    assert (first["mean"], first["n"]) == (0.5, 2)  # 5/8 and 3/8
    assert "## Accuracy per object" in (out / "report.md").read_text()
    assert "per_object_accuracy" not in summary["cells"][1]  # glances=2: no matrix, no column
