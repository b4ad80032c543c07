"""Fine-tuning (``TrainConfig.init_from``, ``ham train --init-from DIR``): a fresh run that starts
from another run's weights, in another world or at another number of glances."""

from __future__ import annotations

import json
import re
import shutil
from dataclasses import replace

import pytest
import torch

from ham.errors import HamError
from ham.learn.batched import check_batchable, train_batched
from ham.learn.evaluation import evaluate
from ham.learn.train import TrainConfig, load_run, resume, stream_seed, train
from ham.model.agent import HamConfig
from ham.world.config import WorldConfig
from ham.world.sensor import SensorConfig
from ham.world.table import build_table


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    """A run trained briefly on the fast simulator's table, and a table of another read-out."""
    d = tmp_path_factory.mktemp("fine_tuning")
    table = build_table(WorldConfig(), 11, d / "t.h5", progress=False)
    spread = WorldConfig(sensor=SensorConfig(spread_sigma=0.005))
    other = build_table(spread, 11, d / "spread.h5", progress=False)
    config = TrainConfig(model=HamConfig(glances=2), table=str(table), steps=30, batch_size=16,
                         eval_every=15, eval_batches=2)  # fmt: skip
    train(config, d / "run", progress=False)
    return {"run": d / "run", "config": config, "other": str(other)}


def _weights(run_dir) -> dict[str, torch.Tensor]:
    return load_run(run_dir).agent.state_dict()


def test_a_fine_tuned_run_starts_from_the_source_weights(source, tmp_path):
    config = replace(source["config"], table=source["other"], steps=0, seed=7,
                     init_from=str(source["run"]))  # fmt: skip
    train(config, tmp_path / "ft0", progress=False)
    theirs, ours = _weights(source["run"]), _weights(tmp_path / "ft0")
    assert theirs.keys() == ours.keys()
    assert all(torch.equal(theirs[k], ours[k]) for k in theirs)
    # without init_from the seed's own initial weights
    train(replace(config, init_from=None), tmp_path / "scratch", progress=False)
    assert not torch.equal(_weights(tmp_path / "scratch")["classifier.dense.weight"],
                           theirs["classifier.dense.weight"])  # fmt: skip
    # evaluated on the other table: the source's agent there, exactly
    a = load_run(source["run"], transfer_table=source["other"])
    b = load_run(tmp_path / "ft0")
    assert evaluate(a.agent, a.env, 2, seed=3) == evaluate(b.agent, b.env, 2, seed=3)
    assert json.loads((tmp_path / "ft0" / "config.json").read_text())["init_from"] == str(
        source["run"]
    )


def test_a_fine_tuned_run_resumes_bit_identically_without_its_source(source, tmp_path):
    copy = shutil.copytree(source["run"], tmp_path / "source")
    config = replace(source["config"], table=source["other"], steps=20, eval_every=10,
                     init_from=str(copy))  # fmt: skip
    whole = train(config, tmp_path / "whole", progress=False)
    train(replace(config, steps=10), tmp_path / "parts", progress=False)
    shutil.rmtree(copy)  # the weights are in the run's checkpoint from its first save on
    parts = resume(tmp_path / "parts", steps=20, progress=False)
    assert parts["history"] == whole["history"]


def test_another_number_of_glances_and_other_models(source, tmp_path):
    config = replace(source["config"], model=HamConfig(glances=3), steps=2, eval_every=2,
                     init_from=str(source["run"]))  # fmt: skip
    assert train(config, tmp_path / "g3", progress=False)["steps"] == 2
    for model, field in [(HamConfig(glances=2, hidden_units=32), "hidden_units 256 (here 32)"),
                         (HamConfig(glances=2, core="mlp"), "core 'lstm' (here 'mlp')")]:  # fmt: skip
        with pytest.raises(HamError, match=re.escape(f"is another model: its {field};")):
            train(replace(config, model=model), tmp_path / "other", progress=False)
        assert not (tmp_path / "other").exists()


def test_fine_tuned_runs_train_batched_as_single_runs(source, tmp_path):
    """In a batched group, beside a run from its seed's weights: each its single run's numbers
    (to float tolerance), and a resumed group does not start from the source again."""
    from tests.test_batched import assert_same_runs, train_both

    ft = dict(table=source["other"], steps=6, eval_every=2, batch_size=8, eval_batches=2)
    configs = [
        replace(source["config"], seed=s, **ft, init_from=str(source["run"])) for s in (0, 1)
    ]
    configs.append(replace(source["config"], seed=2, **ft))
    check_batchable(configs[0])  # no refusal
    train_both(tmp_path, configs)
    assert_same_runs(tmp_path, configs)
    assert metrics_of(tmp_path / "b0")["history"][0] != metrics_of(tmp_path / "b2")["history"][0]
    # stopped at step 4 and resumed: the uninterrupted group's numbers (from its checkpoints,
    # not the source's weights again)
    outs = [tmp_path / f"r{c.seed}" for c in configs]
    train_batched([replace(c, steps=4) for c in configs], outs)
    train_batched(configs, outs)
    for c in configs:
        assert (
            metrics_of(tmp_path / f"r{c.seed}")["history"]
            == (metrics_of(tmp_path / f"b{c.seed}")["history"])
        )


def metrics_of(out) -> dict:
    return json.loads((out / "metrics.json").read_text())


def test_the_cli_fine_tunes(source, tmp_path, ham_cli):
    r = ham_cli("train", "--table", source["other"], "--glances", "2", "--steps", "2",
                "--eval-every", "2", "--eval-batches", "1", "--batch-size", "8",
                "--init-from", str(source["run"]), "--out", str(tmp_path / "cli"))  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "cli" / "config.json").read_text())["init_from"] == str(
        source["run"]
    )


def test_a_grid_fine_tunes_each_seed_from_its_own_source(tmp_path):
    """``init_from = ".../a-s{seed}"`` in a grid: each seed's run starts from that seed's
    source run (its first evaluation is the source's agent on the new table); a source that is
    missing is refused before anything trains."""
    from ham.experiments.grid_run import run_grid

    tiny = ('name = "{name}"\nseeds = 2\n{world}[table]\ngrid = 7\n[base]\nsteps = {steps}\n'
            'batch_size = 8\neval_every = 2\neval_batches = 2\nmodel.glances = 2\n{init}')  # fmt: skip
    (tmp_path / "src.toml").write_text(tiny.format(name="src", steps=4, world="", init=""))
    run_grid(tmp_path / "src.toml", tmp_path / "src", workers=1, progress=False)
    ft = tiny.format(name="ft", steps=2, world="[world]\nsensor = { spread_sigma = 0.005 }\n",
                     init=f'init_from = "{tmp_path}/src/runs/base-s{{seed}}"\n')  # fmt: skip
    (tmp_path / "ft.toml").write_text(ft)
    run_grid(tmp_path / "ft.toml", tmp_path / "ft", workers=1, progress=False)
    for seed in (0, 1):
        run = tmp_path / "ft" / "runs" / f"base-s{seed}"
        src = tmp_path / "src" / "runs" / f"base-s{seed}"
        assert json.loads((run / "config.json").read_text())["init_from"] == str(src)
        other = json.loads((run / "config.json").read_text())["table"]
        theirs = load_run(src, transfer_table=other)
        first = evaluate(theirs.agent, theirs.env, 2, seed=stream_seed(seed, 2))
        assert metrics_of(run)["history"][0]["accuracy"] == first.accuracy
    gone = ft.replace("/src/runs/", "/nowhere/").replace('"ft"', '"gone"')
    (tmp_path / "gone.toml").write_text(gone)
    with pytest.raises(HamError, match=r"run base-s0 starts from init_from '.*/nowhere/base-s0', "
                       "which does not exist"):  # fmt: skip
        run_grid(tmp_path / "gone.toml", tmp_path / "gone", workers=1, progress=False)
    assert not (tmp_path / "gone").exists()
