"""Training runs: the CLI end to end, resume gives the same numbers, divergence is caught."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from ham.errors import HamError
from ham.learn.train import TrainConfig, load_run, resume, train
from ham.model.agent import HamConfig

TINY = ["--glances", "2", "--batch-size", "8", "--eval-batches", "2", "--no-progress"]


def ham_inprocess(capsys, *args: str) -> tuple[int, str, str]:
    """The same ``ham`` command line, run in this process (faster than a subprocess)."""
    from ham.cli.main import main

    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def ham(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    env = dict(os.environ, OMP_NUM_THREADS="1")
    p = subprocess.run(
        [sys.executable, "-m", "ham", *args], capture_output=True, text=True, env=env, timeout=300
    )
    if check and p.returncode != 0:
        raise AssertionError(f"ham {' '.join(args)} failed ({p.returncode}):\n{p.stderr}")
    return p


def tiny(**kw) -> TrainConfig:
    base = dict(
        model=HamConfig(glances=2),
        steps=8,
        batch_size=8,
        eval_every=2,
        eval_batches=2,
        seed=3,
    )
    base.update(kw)
    return TrainConfig(**base)


# --------------------------------------------------------------------------- config
def test_learning_rate_schedule():
    c = TrainConfig()
    assert c.learning_rate(0) == pytest.approx(8e-4)
    assert c.learning_rate(800) == pytest.approx(8e-4 * 0.97)
    assert c.learning_rate(400) == pytest.approx(8e-4 * 0.97**0.5)
    assert c.learning_rate(10_000_000) == 1e-6
    assert TrainConfig(lr_step=200).learning_rate(200) == pytest.approx(8e-4 * 0.97)


def test_paper_defaults():
    c = TrainConfig()
    assert (c.batch_size, c.steps, c.eval_every, c.eval_batches) == (64, 50_000, 200, 100)
    assert (c.momentum, c.nesterov, c.beta, c.lr_step) == (0.9, True, 0.4, 800)
    assert c.normalization == "l2"


@pytest.mark.parametrize(
    "kw",
    [{"steps": -1}, {"lr": 0.0}, {"lr": float("nan")}, {"momentum": 1.0}, {"beta": -1.0},
     {"normalization": "max"}, {"device": "tpu"}, {"reinforce_reduction": "median"},
     {"classification_reduction": "max"}, {"classification_glances": "first"},
     {"reward_glances": "every"}, {"reward_discount": 1.01}, {"reward_discount": -0.5},
     {"glance_reduction": "max"}, {"eval_every": 0}],
)  # fmt: skip
def test_bad_train_config(kw):
    with pytest.raises(HamError):
        TrainConfig(**kw)


def test_config_round_trip():
    c = tiny(lr_step=200)
    assert TrainConfig.from_dict(json.loads(json.dumps(c.to_dict()))) == c


# --------------------------------------------------------------------------- the CLI
def test_cli_train_evaluate_heatmap(tmp_path, capsys):
    out = tmp_path / "run"
    p = ham("train", *TINY, "--steps", "4", "--eval-every", "2", "--seed", "1", "--out", str(out))
    assert "trainable weights" in p.stdout
    for name in ("config.json", "metrics.json", "checkpoint.pt", "tb", "training_curve.png"):
        assert (out / name).exists(), name
    m = json.loads((out / "metrics.json").read_text())
    for key in ("best_accuracy", "final_accuracy", "steps", "accuracy_per_glance",
                "accumulated_accuracy_per_glance", "per_object_accuracy", "confusion", "config",
                "history"):  # fmt: skip
        assert key in m, key
    assert m["steps"] == 4
    # how fast, and on what: the machine and code whose last bits the numbers carry
    timing = json.loads((out / "timing.json").read_text())
    assert timing["steps_timed"] == 4 and timing["torch_threads"] >= 1
    assert {"commit", "cpu", "simd", "MKL_CBWR"} <= set(timing["environment"])
    assert [h["step"] for h in m["history"]] == [0, 2, 4]
    assert len(m["accuracy_per_glance"]) == 2
    assert m["config"]["model"]["glances"] == 2
    assert 0 <= m["best_accuracy"] <= 1

    code, stdout, _ = ham_inprocess(capsys, "evaluate", str(out), "--json", "--batches", "2")
    d = json.loads(stdout)
    assert code == 0 and len(d["accuracy_per_glance"]) == 2 and d["episodes"] == 16
    assert sum(map(sum, d["confusion"][-1])) == 16 and len(d["per_object_accuracy"]) == 4
    code, stdout, _ = ham_inprocess(capsys, "evaluate", str(out), "--batches", "1",
                                    "--eval-policy", "sample", "--confusion",
                                    str(tmp_path / "confusion.png"))  # fmt: skip
    assert code == 0 and "sample poses" in stdout
    assert "per true object" in stdout and "ramp_down" in stdout
    assert (tmp_path / "confusion.png").stat().st_size > 0
    code, stdout, _ = ham_inprocess(capsys, "evaluate", str(out), "--batches", "2", "--json",
                                    "--swap-last-pose")  # fmt: skip
    swap = json.loads(stdout)["last_pose_swap"]
    assert code == 0 and swap["own"] == pytest.approx(d["accuracy"], abs=1e-6)
    assert swap["episodes"] == 16
    code, stdout, _ = ham_inprocess(capsys, "evaluate", str(out), "--batches", "2",
                                    "--swap-last-pose")  # fmt: skip
    assert code == 0 and f"own {swap['own']:.4f}, another episode" in stdout

    png = tmp_path / "heat.png"
    code, _, _ = ham_inprocess(capsys, "heatmap", str(out), "--out", str(png), "--batches", "3",
                               "--json", str(tmp_path / "h.json"))  # fmt: skip
    assert code == 0
    assert png.stat().st_size > 0
    h = json.loads((tmp_path / "h.json").read_text())
    assert len(h["counts"]) == 4 and len(h["counts"][0]) == 20
    assert sum(c for obj in h["counts"] for row in obj for c in row) == 3 * 8
    assert len(h["mu_mean"]) == 4

    from ham.experiments.figures import plot_training_curve

    assert plot_training_curve(m, tmp_path / "curve.png").stat().st_size > 0


def test_cli_errors_are_one_line(tmp_path, capsys):
    code, _, err = ham_inprocess(capsys, "train", *TINY, "--steps", "2")
    assert code == 2 and "--out" in err and len(err.strip().splitlines()) == 1
    code, _, err = ham_inprocess(capsys, "train", *TINY, "--table", str(tmp_path / "none.h5"),
                                 "--out", str(tmp_path / "r"))  # fmt: skip
    assert code == 2 and "does not exist" in err
    code, _, err = ham_inprocess(capsys, "evaluate", str(tmp_path / "missing"))
    assert code == 2 and "does not exist" in err
    code, _, err = ham_inprocess(capsys, "train", *TINY, "--steps", "2", "--batch-size", "0",
                                 "--out", str(tmp_path / "b"))  # fmt: skip
    assert code == 2 and "batch_size" in err


def test_nan_stops_the_run_with_the_step_named(tmp_path, capsys):
    code, _, err = ham_inprocess(capsys, "train", *TINY, "--steps", "20", "--eval-every", "10",
                                 "--lr", "1e30", "--out", str(tmp_path / "nan"))  # fmt: skip
    assert code == 2
    assert "diverged at step" in err
    # what is left and what to do: resuming repeats the same numbers
    out = str(tmp_path / "nan")
    assert f"{out!r} keeps the run as saved at step " in err and "smaller --lr" in err
    code, _, err2 = ham_inprocess(capsys, "train", "--resume", out, "--no-progress")
    assert code == 2 and err2.strip() == err.strip().splitlines()[-1]
    assert "resuming diverges again" in err2


# --------------------------------------------------------------------------- resume
def _metrics(out: Path) -> dict:
    return json.loads((out / "metrics.json").read_text())


def test_resume_gives_the_same_numbers(tmp_path):
    full = train(tiny(steps=8), tmp_path / "full", progress=False)
    train(tiny(steps=4), tmp_path / "half", progress=False)
    resumed = resume(tmp_path / "half", steps=8, progress=False)
    assert resumed == full  # bit-identical: every float in the history
    a, b = load_run(tmp_path / "full"), load_run(tmp_path / "half")
    for (n, p), (_, q) in zip(
        a.agent.state_dict().items(), b.agent.state_dict().items(), strict=True
    ):
        assert torch.equal(p, q), n


def test_train_refuses_an_existing_run(tmp_path):
    train(tiny(steps=2), tmp_path / "r", progress=False)
    with pytest.raises(HamError, match="--resume"):
        train(tiny(steps=2), tmp_path / "r", progress=False)


def test_killed_run_resumes_to_the_same_numbers(tmp_path):
    """Kill a CLI run (SIGKILL) after a checkpoint, resume it: the same metrics as uninterrupted."""
    args = [*TINY, "--steps", "150", "--eval-every", "10", "--eval-batches", "1", "--seed", "5"]
    # The uninterrupted reference, in this process with the subprocesses' one thread.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        train(tiny(steps=150, eval_every=10, eval_batches=1, seed=5), tmp_path / "full",
              progress=False)  # fmt: skip
    finally:
        torch.set_num_threads(threads)
    out = tmp_path / "killed"
    env = dict(os.environ, OMP_NUM_THREADS="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "ham", "train", *args, "--out", str(out)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
    )  # fmt: skip
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        try:
            if _metrics(out)["steps"] >= 10:
                break
        except (FileNotFoundError, json.JSONDecodeError, KeyError):
            pass
        time.sleep(0.01)
    if proc.poll() is None:
        proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL  # killed mid-run, not finished
    assert _metrics(out)["steps"] < 150
    ham("train", "--resume", str(out), "--no-progress")
    assert _metrics(out) == _metrics(tmp_path / "full")


def test_resume_refuses_changed_settings(tmp_path, capsys):
    train(tiny(steps=2), tmp_path / "r", progress=False)
    code, _, err = ham_inprocess(capsys, "train", "--resume", str(tmp_path / "r"), "--glances", "3")
    assert code == 2 and "--glances" in err


# --------------------------------------------------------------------------- variants
@pytest.mark.parametrize(
    "model",
    [HamConfig(glances=2, policy="random"), HamConfig(glances=2, core="mlp"),
     HamConfig(glances=2, combiner="mul", lstm_activation="relu", std_activation="sigmoid",
               truncate_bptt=True, bias=False)],
)  # fmt: skip
def test_variants_train(tmp_path, model):
    m = train(tiny(model=model, steps=2), tmp_path / "v", progress=False)
    assert m["steps"] == 2 and m["final_accuracy"] is not None


def test_train_from_a_glance_table(tmp_path):
    from ham.world.config import WorldConfig
    from ham.world.table import build_table

    path = build_table(WorldConfig(), 5, tmp_path / "t.h5", progress=False)
    m = train(tiny(table=str(path), steps=2), tmp_path / "r", progress=False)
    assert m["steps"] == 2
    run = load_run(tmp_path / "r")
    assert type(run.env.source).__name__ == "TableSource"


def test_a_run_is_not_continued_on_another_table_at_its_path(tmp_path):
    """The checkpoint keeps the table's sha256: a different table of the same shape rebuilt at
    the run's table path (here: the Gazebo-like blur) is refused by resume and evaluation, not
    used silently; the run's own table, rebuilt bit-identically, is accepted."""
    from ham.world.config import WorldConfig
    from ham.world.sensor import SensorConfig
    from ham.world.table import build_table

    path = tmp_path / "t.h5"
    build_table(WorldConfig(), 5, path, progress=False)
    train(tiny(table=str(path), steps=2), tmp_path / "r", progress=False)
    blurred = WorldConfig(sensor=SensorConfig(spread_sigma=0.005))
    build_table(blurred, 5, path, progress=False)  # same objects and grid, other images
    with pytest.raises(HamError, match=r"glance table .*t\.h5' is not the one this run trained"):
        resume(tmp_path / "r", steps=4, progress=False)
    with pytest.raises(HamError, match="is not the one this run trained on"):
        load_run(tmp_path / "r")
    build_table(WorldConfig(), 5, path, progress=False)  # the run's own table again
    assert resume(tmp_path / "r", steps=4, progress=False)["steps"] == 4


def test_a_run_moved_with_its_table_finds_it(tmp_path):
    """A reproduce-like folder (OUT/table.h5, OUT/runs/KEY) moved elsewhere: the runs record the
    table by absolute path, and find it again by name beside or above them, verified by the
    sha256 their checkpoint kept; a table of another sha256 there is not taken."""
    from ham.world.config import WorldConfig
    from ham.world.sensor import SensorConfig
    from ham.world.table import build_table

    build_table(WorldConfig(), 5, tmp_path / "a" / "t.h5", progress=False)
    run = tmp_path / "a" / "runs" / "r"
    train(tiny(table=str(tmp_path / "a" / "t.h5"), steps=2), run, progress=False)
    (tmp_path / "a").rename(tmp_path / "b")
    moved = tmp_path / "b" / "runs" / "r"
    assert load_run(moved).config.table == str(tmp_path / "b" / "t.h5")
    assert resume(moved, progress=False)["steps"] == 2  # finished: nothing to train
    assert json.loads((moved / "config.json").read_text())["table"] == str(tmp_path / "b" / "t.h5")
    assert resume(moved, steps=4, progress=False)["steps"] == 4
    (tmp_path / "b").rename(tmp_path / "c")
    build_table(WorldConfig(sensor=SensorConfig(spread_sigma=0.005)), 5,
                tmp_path / "c" / "t.h5", progress=False)  # fmt: skip
    with pytest.raises(HamError, match=r"'t\.h5' of this run's sha256 beside the run or above"):
        load_run(tmp_path / "c" / "runs" / "r")


def test_table_flag_names_a_runs_moved_table(tmp_path):
    """A run's table moved alone: `--table` on evaluate, heatmap and --resume names its new path,
    accepted only with the sha256 the checkpoint kept (another table, or a run without a table,
    is refused in one line); --resume records the new path."""
    from ham.world.config import WorldConfig
    from ham.world.table import build_table
    from tests.conftest import run_ham_inprocess

    build_table(WorldConfig(), 5, tmp_path / "t.h5", progress=False)
    train(tiny(table=str(tmp_path / "t.h5"), steps=2), tmp_path / "r", progress=False)
    (tmp_path / "t.h5").rename(tmp_path / "moved.h5")
    run = str(tmp_path / "r")
    r = run_ham_inprocess("evaluate", run, "--batches", "1")
    assert r.returncode == 2 and "or --table FILE where it is now" in r.stderr
    r = run_ham_inprocess("evaluate", run, "--batches", "1", "--table", str(tmp_path / "moved.h5"))
    assert r.returncode == 0, r.stderr
    build_table(WorldConfig(), 3, tmp_path / "other.h5", progress=False)
    r = run_ham_inprocess("heatmap", run, "--out", str(tmp_path / "h.png"), "--batches", "1",
                          "--table", str(tmp_path / "other.h5"))  # fmt: skip
    assert r.returncode == 2 and "is not the run's table" in r.stderr
    assert not (tmp_path / "h.png").exists()
    r = run_ham_inprocess("train", "--resume", run, "--steps", "4", "--no-progress", "--table",
                          str(tmp_path / "moved.h5"))  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "r" / "config.json").read_text())["table"] == str(
        tmp_path / "moved.h5"
    )
    train(tiny(steps=2), tmp_path / "online", progress=False)
    with pytest.raises(HamError, match="--table .* for a run without a glance table"):
        load_run(tmp_path / "online", table=str(tmp_path / "moved.h5"))
