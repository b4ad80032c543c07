"""Batched training (ham.learn.batched): N runs as one stacked model give the single runs' numbers,
each run keeps its own directory, a diverged run stops alone, resume is bit-identical, and
``ham reproduce --executor batched`` runs a tiny grid."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode

from ham.errors import HamError
from ham.experiments.reproduce import PROFILES, Job, render_report, stopped_at_perfect
from ham.experiments.runs import is_finished
from ham.learn import batched, stacked_ham
from ham.learn.batched import BatchedRuns, _open_runs, train_batched
from ham.learn.evaluation import evaluate
from ham.learn.train import TrainConfig, load_run, resume, stream_seed, train
from ham.model.agent import HamConfig, HapticAttentionModel
from ham.world.config import WorldConfig
from ham.world.table import build_table


def tiny(seed: int, **kw) -> TrainConfig:
    model = kw.pop("model", HamConfig(glances=3))
    base = dict(model=model, steps=8, batch_size=8, eval_every=2, eval_batches=2, seed=seed)
    base.update(kw)
    return TrainConfig(**base)


def metrics(out: Path) -> dict:
    return json.loads((out / "metrics.json").read_text())


def weights(out: Path) -> list[torch.Tensor]:
    return [p.detach() for p in load_run(out).agent.parameters()]


def assert_same_run(batched: Path, single: Path, atol: float = 1e-6, stray: float = 0.0) -> None:
    """The batched run's numbers are the single run's, to float tolerance; with ``stray``, that
    fraction of each weight's elements (rounded down) may be apart by up to one step of the
    learning rate (Adam's normalized update of a gradient near its eps is a matter of rounding)."""
    a, b = metrics(batched), metrics(single)
    assert [h["accuracy"] for h in a["history"]] == [h["accuracy"] for h in b["history"]]
    assert [h["step"] for h in a["history"]] == [h["step"] for h in b["history"]]
    for ha, hb in zip(a["history"][1:], b["history"][1:], strict=True):
        assert ha["train_loss"] == pytest.approx(hb["train_loss"], rel=1e-5)
        mu_a, mu_b = torch.tensor(ha["mu_mean"] or 0.0), torch.tensor(hb["mu_mean"] or 0.0)
        assert torch.allclose(mu_a, mu_b, atol=1e-5)
    assert a["best_accuracy"] == b["best_accuracy"] and a["steps"] == b["steps"]
    lr = load_run(single).config.lr
    for p, q in zip(weights(batched), weights(single), strict=True):
        apart = ~torch.isclose(p, q, rtol=1e-4, atol=atol)
        assert int(apart.sum()) <= int(stray * p.numel()), f"{int(apart.sum())} of {p.numel()}"
        assert (p - q).abs().max() <= lr or not apart.any()


def train_both(tmp_path: Path, configs: list[TrainConfig]) -> list:
    """Train ``configs`` as single runs (``single<seed>``), then as one batched group
    (``b<seed>``); returns the batched results."""
    for c in configs:
        train(c, tmp_path / f"single{c.seed}", progress=False)
    return train_batched(configs, [tmp_path / f"b{c.seed}" for c in configs])


def assert_same_runs(
    tmp_path: Path, configs: list[TrainConfig], atol: float = 1e-6, stray: float = 0.0
) -> None:
    """Every batched run of :func:`train_both` is its single run, to float tolerance."""
    for c in configs:
        assert_same_run(tmp_path / f"b{c.seed}", tmp_path / f"single{c.seed}", atol, stray)


@pytest.mark.parametrize(
    "model",
    [
        HamConfig(glances=3),
        HamConfig(glances=2, policy="random", core="mlp", combiner="mul"),
        HamConfig(
            glances=2,
            combiner="concat1",
            bias=False,
            lstm_activation="relu",
            std_activation="sigmoid",
            truncate_bptt=True,
            forget_bias=0.5,
        ),
        HamConfig(glances=1, combiner="add"),
        HamConfig(glances=3, core="mlp"),
        HamConfig(glances=3, first_glance="learned"),
        HamConfig(glances=2, first_glance="learned", std_activation="sigmoid"),
        HamConfig(glances=2, policy="random", first_glance="learned"),  # random: nothing learned
    ],  # fmt: skip
    ids=[
        "full",
        "rloc-mlp-mul",
        "code-options",
        "one-glance-add",
        "mlp",
        "first-learned",
        "first-learned-sigmoid",
        "rloc-first-learned",
    ],
)
def test_batched_equals_single_runs(tmp_path, model):
    configs = [tiny(s, model=model) for s in range(3)]
    results = train_both(tmp_path, configs)
    assert [r["steps"] for r in results] == [8, 8, 8]
    assert_same_runs(tmp_path, configs)
    # different seeds stay different runs: the stacking mixes nothing
    assert metrics(tmp_path / "b0")["history"][-1]["train_loss"] != pytest.approx(
        metrics(tmp_path / "b1")["history"][-1]["train_loss"]
    )


CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU (run on one)")


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=CUDA)])
def test_runs_of_other_rates_losses_and_evaluations_share_a_batch(tmp_path, device):
    # a sweep: each run its own learning-rate schedule, loss, normalization, evaluation and
    # BPTT truncation, one model
    configs = [
        tiny(0, steps=6),
        tiny(1, steps=6, lr=3e-3, lr_step=2, lr_decay=0.5, beta=1.5, eval_policy="sample"),
        tiny(2, steps=6, lr_min=2e-3, eval_every=3, eval_batches=3, log_every=1),
        tiny(3, steps=6, classification_reduction="mean", beta=0.8),
        tiny(4, steps=6, reinforce_reduction="sum", normalization="l1"),
        tiny(6, steps=6, classification_glances="all"),
        tiny(7, steps=6, reward_glances="all", reward_discount=0.9),
        tiny(8, steps=6, reward_discount=0.5),
        tiny(9, steps=6, glance_reduction="mean", reward_glances="all", reward_discount=0.9),
        tiny(5, steps=6, model=HamConfig(glances=3, truncate_bptt=True)),
    ]
    configs = [replace(c, device=device) for c in configs]
    assert len({batched.shape_key(c) for c in configs}) == 1
    train_both(tmp_path, configs)
    assert_same_runs(tmp_path, configs, 1e-5 if device == "cuda" else 1e-6)
    steps = [[h["step"] for h in metrics(tmp_path / f"b{c.seed}")["history"]] for c in configs]
    assert steps[1] == [0, 2, 4, 6] and steps[2] == [0, 3, 6]


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=CUDA)])
def test_runs_of_other_momenta_and_policy_rates_share_a_batch(tmp_path, device):
    # a sweep of the optimizer's settings: momentum (none, plain, Nesterov), the location
    # network's rate, one model
    configs = [
        tiny(0, steps=6),
        tiny(1, steps=6, momentum=0.0, nesterov=False),
        tiny(2, steps=6, momentum=0.5, nesterov=False),
        tiny(3, steps=6, policy_lr_scale=0.3),
        tiny(4, steps=6, momentum=0.95, policy_lr_scale=3.0, lr=2e-3),
        tiny(5, steps=6, policy_lr_scale=0.0),  # the policy kept as it is
    ]
    configs = [replace(c, device=device) for c in configs]
    assert len({batched.shape_key(c) for c in configs}) == 1
    train_both(tmp_path, configs)
    atol = 1e-5 if device == "cuda" else 1e-6
    assert_same_runs(tmp_path, configs, atol)
    for c in configs:  # each checkpoint's optimizer holds its single run's buffers (none at 0)
        a, b = (load_run(tmp_path / f"{x}{c.seed}").optimizer.state_dict()["state"]
                for x in ("b", "single"))  # fmt: skip
        assert a.keys() == b.keys() and (len(a) == 0) == (c.momentum == 0)
        for k in a:
            assert torch.allclose(a[k]["momentum_buffer"], b[k]["momentum_buffer"], atol=atol)
    kept = load_run(tmp_path / "b5").agent.location.state_dict()
    with torch.random.fork_rng():
        torch.manual_seed(5)  # run 5's initial weights
        start = HapticAttentionModel(configs[5].model).location.state_dict()
    assert all(torch.equal(kept[k].cpu(), start[k]) for k in start)


@pytest.mark.parametrize(
    "kw",
    [
        {"policy_lr_scale": 0.5},
        {"optimizer": "adam"},
        {"momentum": 0.0, "nesterov": False},
        {"nesterov": False},
    ],
    ids=["policy-lr-scale", "adam", "no-momentum", "plain-momentum"],
)
def test_batched_optimizers_equal_single_runs(tmp_path, kw):
    configs = [tiny(s, steps=6, **kw) for s in range(2)]
    train_both(tmp_path, configs)
    # Adam divides by the root of the squared gradients' average: a weight whose gradient is
    # rounding noise moves by up to lr either way (measured: 13 of 524,288 LSTM weights, 2e-5)
    atol = 1e-4 if kw.get("optimizer") == "adam" else 1e-6
    assert_same_runs(tmp_path, configs, atol)


def test_the_portable_path_equals_single_runs(tmp_path, monkeypatch):
    # without oneDNN and the fused SGD (what CUDA runs: one bmm per layer for all runs, the
    # foreach SGD steps) the numbers are the single runs' too
    monkeypatch.setattr(stacked_ham, "_LINEAR_ONEDNN", None)
    monkeypatch.setattr(batched, "_FUSED_SGD", None)
    configs = [tiny(s) for s in range(2)]
    train_both(tmp_path, configs)
    assert_same_runs(tmp_path, configs)


@pytest.mark.parametrize(
    "policy,first,device",
    [("learned", "random", "cpu"), ("random", "random", "cpu"), ("learned", "learned", "cpu"),
     pytest.param("learned", "random", "cuda", marks=CUDA),
     pytest.param("learned", "learned", "cuda", marks=CUDA)],
    ids=["learned", "random", "first-learned", "learned-cuda", "first-learned-cuda"],
)  # fmt: skip
def test_runs_of_other_glance_counts_share_a_batch(tmp_path, policy, first, device):
    # a Table 1 column's runs in one model that steps 4 glances: each run's loss, draws and
    # evaluations its own glances' (the others computed and left out); a 2-glance run goes on
    # alone after the others finished (the model then steps 2 glances)
    counts = (2, 4, 3, 2)
    configs = [tiny(s, steps=6 + 2 * (s == 0), device=device, eval_policy="sample",
                    model=HamConfig(glances=g, policy=policy, first_glance=first))
               for s, g in enumerate(counts)]  # fmt: skip
    assert len({batched.shape_key(c) for c in configs}) == 3
    assert len({batched.shape_key(c, glances=False) for c in configs}) == 1
    one = replace(configs[0], model=HamConfig(glances=1, policy=policy))
    assert batched.shape_key(one, glances=False) != batched.shape_key(configs[0], glances=False)
    train_both(tmp_path, configs)
    assert_same_runs(tmp_path, configs, 1e-5 if device == "cuda" else 1e-6)
    for c in configs:
        history = metrics(tmp_path / f"b{c.seed}")["history"]
        assert len(history[-1]["accuracy_per_glance"]) == c.model.glances


def test_runs_with_pose_noise_equal_single_runs(tmp_path):
    # each run draws its noise from its own object stream, as its single run: one sigma per run
    # (none for one), and a run of fewer glances that stops drawing after its last
    configs = [tiny(0, pose_noise=0.05), tiny(1, pose_noise=0.2),
               tiny(2, model=HamConfig(glances=2), pose_noise=0.1), tiny(3)]  # fmt: skip
    train_both(tmp_path, configs)
    assert_same_runs(tmp_path, configs)
    quiet = train(tiny(0), tmp_path / "quiet", progress=False)  # run 0 without its noise
    assert (
        quiet["history"][-1]["train_loss"] != metrics(tmp_path / "b0")["history"][-1]["train_loss"]
    )


@pytest.mark.parametrize("policy", ["mean", "sample"])
def test_the_batched_evaluation_under_pose_noise_equals_each_runs_own(
    tmp_path, monkeypatch, policy
):
    monkeypatch.setattr(batched, "_EVAL_ROWS", 16)  # 5 batches of 8 in passes of 2 batches
    configs = [tiny(s, eval_batches=5, eval_policy=policy, pose_noise=0.1 * s) for s in range(3)]
    outs = [tmp_path / f"b{s}" for s in range(3)]
    group = BatchedRuns(_open_runs(configs, outs), outs)
    group.step()
    for i, got in zip([0, 1, 2], group.evaluate([0, 1, 2]), strict=True):
        r = group.runs[i]
        want = evaluate(r.agent, r.env, 5, seed=stream_seed(i, 2), policy=policy).to_dict()
        got = got.to_dict()
        for key in ("path_length", "mu_mean", "pose_spread", "pose_spread_within_object"):
            assert torch.allclose(
                torch.tensor(got.pop(key)), torch.tensor(want.pop(key)), atol=1e-5
            )
        assert got == want


@pytest.mark.parametrize(
    "model,policy",
    [
        (HamConfig(glances=3), "mean"),
        (HamConfig(glances=3), "sample"),
        (HamConfig(glances=2, policy="random", core="mlp"), "mean"),
        (HamConfig(glances=3, first_glance="learned"), "mean"),
        (HamConfig(glances=3, first_glance="learned"), "sample"),
    ],  # fmt: skip
    ids=["learned-mean", "learned-sample", "random", "first-learned-mean", "first-learned-sample"],
)
def test_the_batched_evaluation_equals_each_runs_own(tmp_path, monkeypatch, model, policy):
    # 5 evaluation batches of 8 in passes of 2 batches (16 rows): the poses of every batch are
    # drawn from the run's own generator in the single evaluation's order
    monkeypatch.setattr(batched, "_EVAL_ROWS", 16)
    configs = [tiny(s, model=model, eval_batches=5, eval_policy=policy) for s in range(3)]
    outs = [tmp_path / f"b{s}" for s in range(3)]
    group = BatchedRuns(_open_runs(configs, outs), outs)
    group.step()  # weights apart from their initial ones
    for idx in ([0, 1, 2], [2, 0]):  # all the group's runs (the stack itself), and a subset
        for i, got in zip(idx, group.evaluate(idx), strict=True):
            r = group.runs[i]
            want = evaluate(r.agent, r.env, 5, seed=stream_seed(i, 2), policy=policy).to_dict()
            got = got.to_dict()
            for key in ("path_length", "mu_mean", "pose_spread", "pose_spread_within_object"):
                a, b = got.pop(key), want.pop(key)
                if key == "mu_mean":  # the random policy has no mode
                    assert (a is None) == (b is None) == (model.policy == "random")
                if a is not None:
                    assert torch.allclose(torch.tensor(a), torch.tensor(b), atol=1e-5)
            assert got == want  # accuracies, confusion counts, per object
    accuracies = [r.accuracy_per_glance for r in group.evaluate([0, 1, 2])]
    assert accuracies[0] != accuracies[1] or accuracies[0] != accuracies[2]


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU (run on one)")
@pytest.mark.parametrize("kw", [{}, {"optimizer": "adam"}], ids=["sgd", "adam"])
def test_cuda_batched_equals_single_runs(tmp_path, kw):
    # the CUDA path (one bmm per layer for all runs, foreach optimizer steps) against single
    # runs on the same GPU
    configs = [tiny(s, device="cuda", **kw) for s in range(3)]
    train_both(tmp_path, configs)
    if kw.get("optimizer") == "adam":
        # on an H100 one element of core.gates.weight's 524,288 moved 1.19e-4 apart at the first
        # step: Adam's first update is lr * g / (|g| + eps), and a g near eps rounds its own way
        # in a bmm; the same single run on the CPU and on CUDA ends 1.6e-3 apart in half of its
        # tactile.where weights (docs/batched.md)
        assert_same_runs(tmp_path, configs, 1e-4, stray=1e-5)
    else:
        assert_same_runs(tmp_path, configs, 1e-5)


def test_the_onednn_path_equals_single_runs(tmp_path, monkeypatch):
    # batches of 16: the CPU's per-run oneDNN products (the tiny runs' 8 rows go to bmm)
    if stacked_ham._LINEAR_ONEDNN is None:
        pytest.skip("this torch has no oneDNN linear")
    calls = []

    def linear(*args):
        calls.append(args[1].shape)
        return onednn(*args)

    onednn = stacked_ham._LINEAR_ONEDNN
    monkeypatch.setattr(stacked_ham, "_LINEAR_ONEDNN", linear)
    monkeypatch.setattr(stacked_ham, "_PER_RUN_ONEDNN", True)  # the AMD path on any CPU
    configs = [tiny(s, batch_size=16, steps=4) for s in range(2)]
    train_both(tmp_path, configs)
    assert (1024, 256) in calls  # the gates' first glance: the weight's g columns alone
    assert (1024, 512) in calls
    assert_same_runs(tmp_path, configs)


def assert_compiled() -> None:
    """The cell's backward ran compiled, not the eager fallback; where this machine cannot
    compile (no working C++ compiler), the test skips: the fallback is what it then runs."""
    fn = stacked_ham._COMPILED["backward"]
    if isinstance(fn, str):
        pytest.skip(f"torch.compile cannot run here: {fn}")
    assert callable(fn)


@pytest.mark.parametrize(
    "sigmoid_tanh,compiled", [(True, False), (False, True)], ids=["amd-tanh", "compiled"]
)
def test_the_cell_paths_equal_single_runs(tmp_path, monkeypatch, sigmoid_tanh, compiled):
    # the LSTM cell's tanh as 2 sigmoid(2x) - 1 (the AMD path), and its backward compiled by
    # torch.compile (what the paper's size runs on the CPU), on any CPU
    monkeypatch.setattr(stacked_ham, "_SIGMOID_TANH", sigmoid_tanh)
    if compiled:
        monkeypatch.setattr(stacked_ham, "_COMPILE_MIN", 0)
        monkeypatch.setattr(stacked_ham, "_COMPILED", {})
    configs = [tiny(s, steps=4) for s in range(2)]
    train_both(tmp_path, configs)
    assert_same_runs(tmp_path, configs)
    if compiled:
        assert_compiled()


_NO_COMPILER = """
import warnings, torch
from ham.learn import stacked_ham
stacked_ham._COMPILE_MIN = 0
g = torch.Generator().manual_seed(0)
dh, dc1, tc, cell = (torch.randn(2, 3, 8, generator=g) for _ in range(4))
act = torch.rand(2, 3, 4, 8, generator=g)
want = stacked_ham._cell_backward(dh, dc1, act, tc, cell)
weight = torch.randn(3, 16, 5, generator=g)
with warnings.catch_warnings(record=True) as seen:
    warnings.simplefilter("always")
    got = [stacked_ham._backward(dh, dc1, act, tc, cell) for _ in range(2)]
    halves = [stacked_ham._compiled("halves", stacked_ham._halves, stacked_ham._halves_eager,
                                "the batched gates' transpose", weight) for _ in range(2)]
for g in got:
    assert all(torch.equal(a, b) for a, b in zip(g, want, strict=True))
for h in halves:
    assert torch.equal(h, stacked_ham._halves(weight))
for w in seen:
    if "batched" in str(w.message):
        print("WARNING", w.message)
"""


def test_a_machine_without_a_compiler_runs_the_cell_eager(tmp_path):
    # a real failed compile: inductor's C++ compiler is /bin/false (and its cache is empty)
    env = dict(os.environ, CXX="/bin/false", TORCHINDUCTOR_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=str(Path(batched.__file__).parents[2]))  # fmt: skip
    r = subprocess.run([sys.executable, "-c", _NO_COMPILER], capture_output=True, text=True,
                       env=env, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    # one warning each, one line, for two calls; the numbers are the eager expressions'
    assert len(lines) == 2, r.stdout
    assert lines[0].startswith("WARNING the batched LSTM cell runs eager (torch.compile failed: ")
    assert lines[1].startswith(
        "WARNING the batched gates' transpose runs eager (torch.compile failed: "
    )
    assert all("C++ compiler" in line for line in lines)


def test_the_gates_forward_in_halves_gives_the_whole_products_numbers(tmp_path, monkeypatch):
    """The gates' forward as two products of half the outputs on the weights transposed once
    per step (what 6 glances and more take on the CPU): the group's numbers are those of one
    product (to float rounding: MKL may sum a product of 8 rows in another order), and each
    run is its single run to float tolerance."""
    configs = [tiny(s, steps=4) for s in range(2)]
    train_batched(configs, [tmp_path / f"whole{c.seed}" for c in configs])  # 3 glances: whole
    calls = []
    halves = stacked_ham._Layer.halves

    def counted(layer):
        calls.append(tuple(layer.weight.shape))
        return halves(layer)

    monkeypatch.setattr(stacked_ham._Layer, "halves", counted)
    monkeypatch.setattr(stacked_ham, "_SPLIT_GLANCES", 3)
    train_both(tmp_path, configs)
    # the gates (2 runs, 1024 outputs), at every glance of each training step (the first
    # glance's g reads the halves' first rows)
    assert calls == [(2, 1024, 512)] * (4 * 3)
    for c in configs:
        assert_same_run(tmp_path / f"b{c.seed}", tmp_path / f"whole{c.seed}", atol=1e-7)
    assert_same_runs(tmp_path, configs)


def test_a_runs_numbers_do_not_depend_on_its_batch_mates(tmp_path):
    """Bit for bit, not to tolerance (one torch thread, as the grid's workers): seed 0 as a model
    of its own, seeds 0 and 1 as a model of two, and both in a model of five with another seed
    and runs of another normalization and loss reduction. The fused SGD rounds its vector loop
    and its scalar tail differently, so over whole stacks a run's 2-element biases rounded by
    their place in the stack (docs/batched.md)."""
    assert torch.get_num_threads() == 1  # conftest: with more, MKL splits one run's products
    pair = [tiny(0), tiny(1)]
    crowd = [tiny(2), tiny(0, normalization="l1"), tiny(0), tiny(1),
             tiny(1, classification_reduction="mean")]  # fmt: skip
    train_batched([tiny(0)], [tmp_path / "alone"])
    train_batched(pair, [tmp_path / "p0", tmp_path / "p1"])
    train_batched(crowd, [tmp_path / f"c{i}" for i in range(5)])
    for p, c in (("p0", "c2"), ("p1", "c3"), ("alone", "p0")):
        for x, y in zip(weights(tmp_path / p), weights(tmp_path / c), strict=True):
            assert torch.equal(x, y)
        a, b = metrics(tmp_path / p), metrics(tmp_path / c)
        assert [h["train_loss"] for h in a["history"]] == [h["train_loss"] for h in b["history"]]


def test_each_run_has_the_directory_of_a_single_run(tmp_path):
    configs = [tiny(s, steps=4) for s in (0, 5)]
    train(configs[0], tmp_path / "single", progress=False)
    train_batched(configs, [tmp_path / "b0", tmp_path / "b5"])
    single = tmp_path / "single"
    for name in ("b0", "b5"):
        out = tmp_path / name
        assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in single.iterdir())
        assert list((out / "tb").iterdir())
        assert set(metrics(out)) == set(metrics(single))
    assert (tmp_path / "b0/config.json").read_text() == (single / "config.json").read_text()
    assert json.loads((tmp_path / "b5/config.json").read_text())["seed"] == 5
    # a checkpoint holds one run's weights, not the stack
    ck = torch.load(tmp_path / "b0/checkpoint.pt", weights_only=False)
    ref = torch.load(single / "checkpoint.pt", weights_only=False)
    for k, v in ck["model"].items():
        assert v.untyped_storage().nbytes() == ref["model"][k].untyped_storage().nbytes()
    assert ck["optimizer"]["param_groups"] == ref["optimizer"]["param_groups"]
    # its momentum buffers too: the run's own, each of its parameter's size
    assert ck["optimizer"]["state"].keys() == ref["optimizer"]["state"].keys()
    for k, st in ck["optimizer"]["state"].items():
        buf, ref_buf = st["momentum_buffer"], ref["optimizer"]["state"][k]["momentum_buffer"]
        assert buf.shape == ref_buf.shape
        assert buf.untyped_storage().nbytes() == ref_buf.untyped_storage().nbytes()
    # a batched run continues as a single run
    resume(tmp_path / "b0", steps=6, progress=False)
    resume(single, steps=6, progress=False)
    assert_same_run(tmp_path / "b0", single)


def test_a_diverged_run_stops_alone(tmp_path):
    configs = [tiny(s, steps=6) for s in range(3)]
    outs = [tmp_path / f"b{s}" for s in range(3)]
    runs = _open_runs(configs, outs)
    with torch.no_grad():  # run 1's weights diverged: its first loss is NaN
        runs[1].agent.core.gates.weight.fill_(float("nan"))
    results = BatchedRuns(runs, outs).train()
    assert isinstance(results[1], str)
    assert results[1].startswith("training diverged at step 1: the loss is nan")
    assert metrics(outs[1])["steps"] == 0  # its directory keeps its last checkpoint
    for s in (0, 2):
        train(configs[s], tmp_path / f"single{s}", progress=False)
        assert results[s]["steps"] == 6
        assert_same_run(outs[s], tmp_path / f"single{s}")


def test_an_adam_update_beyond_float32_stops_its_run_alone(tmp_path):
    """Adam at lr 3e38 (within float32) makes an update that float32 cannot hold: torch raised a
    RuntimeError that ended the whole group; now that run diverges alone, as ``ham train``
    says for a single run."""
    configs = [tiny(s, steps=4, optimizer="adam", lr=lr) for s, lr in ((0, 1e-3), (1, 3e38))]
    outs = [tmp_path / "b0", tmp_path / "b1"]
    results = train_batched(configs, outs)
    assert results[1] == (
        "training diverged at step 1: the optimizer's update overflows float32 (lr 3e+38)"
    )
    train(configs[0], tmp_path / "single0", progress=False)
    assert_same_run(outs[0], tmp_path / "single0", atol=1e-4)  # Adam's, as the tests above
    with pytest.raises(HamError, match=r"^training diverged at step 1: the optimizer's update"):
        train(configs[1], tmp_path / "single1", progress=False)
    assert not (tmp_path / "single1").exists()  # failed at its first step: no run left


class _HostReads(TorchDispatchMode):
    """The operators that read a tensor's value back to the host (``item``, ``bool``) or make a
    tensor of Python values (``torch.tensor``): on a GPU each is a wait or a copy."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: list[str] = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        if func.overloadpacket.__name__ in ("_local_scalar_dense", "lift_fresh", "nonzero"):
            self.seen.append(func.overloadpacket.__name__)
        return func(*args, **(kwargs or {}))


def test_the_device_step_asks_the_host_nothing(tmp_path, monkeypatch):
    # on a glance table (the online simulator iterates to each glance's contact), a group that
    # takes every per-run path: other glance counts (a run past its last glance draws nothing),
    # normalizations, betas, reductions, rates, BPTT truncations and a spread augmentation
    table = _small_table(tmp_path)
    configs = [tiny(0, table=table),
               tiny(1, table=table, model=HamConfig(glances=2, truncate_bptt=True)),
               tiny(2, table=table, normalization="l1", beta=0.5, lr=0.01),
               tiny(3, table=table, classification_reduction="sum", momentum=0.5),
               tiny(4, table=table, spread_augment=0.005)]  # fmt: skip
    assert_device_step_asks_nothing(tmp_path, monkeypatch, configs)


def assert_device_step_asks_nothing(tmp_path: Path, monkeypatch, configs: list) -> None:
    """A group of ``configs``' second device step (the first makes the group's constants)
    reads nothing back to the host, makes no tensor of Python values, and flags every run
    finite."""
    outs = [tmp_path / f"b{c.seed}" for c in configs]
    group = BatchedRuns(_open_runs(configs, outs), outs)
    group.step()  # the first step makes the group's constants
    reads: list[str] = []
    monkeypatch.setattr(torch.Tensor, "tolist", lambda t: reads.append("tolist") or [])
    with _HostReads() as host:
        flags = group._device_step([group.runs[i] for i in group.active])
    assert host.seen + reads == []
    assert flags.shape == (2, len(configs)) and bool(flags.all())


@pytest.mark.parametrize(
    "model",
    [HamConfig(glances=1), HamConfig(glances=3, policy="random"), HamConfig(glances=3, core="mlp"),
     HamConfig(glances=3, combiner="mul"), HamConfig(glances=3, combiner="concat1"),
     HamConfig(glances=3, combiner="add"), HamConfig(glances=3, first_glance="learned"),
     HamConfig(glances=3, std_activation="sigmoid"), "compiled-cell"],
    ids=["1-glance", "rloc", "mlp", "mul", "concat1", "add", "first-learned", "sigmoid",
         "compiled-cell"],
)  # fmt: skip
def test_every_shape_of_the_paper_grid_steps_without_asking_the_host(tmp_path, monkeypatch, model):
    # what a CUDA graph of the whole grid needs: each of its models' device step (Table 1's
    # variants at their glance counts, Table 2's combiners; the APPLE study's first glance; the
    # paper-size compiled cell) reads nothing back and makes no tensor of Python values
    compiled = model == "compiled-cell"
    if compiled:
        monkeypatch.setattr(stacked_ham, "_COMPILE_MIN", 0)
        model = HamConfig(glances=3)
    table = _small_table(tmp_path)
    assert_device_step_asks_nothing(tmp_path, monkeypatch,
                                    [tiny(s, table=table, model=model) for s in range(2)])  # fmt: skip
    if compiled:
        assert_compiled()


@pytest.mark.parametrize("compiled", [False, True], ids=["eager", "compiled-cell"])
def test_resume_of_a_batched_group_is_bit_identical(tmp_path, monkeypatch, compiled):
    if compiled:  # the paper's size takes the compiled cell backward
        monkeypatch.setattr(stacked_ham, "_COMPILE_MIN", 0)
    # runs at their own momentum and location-network rate (per-run optimizer state; the
    # last one keeps none) and glance count
    own = ({}, {"momentum": 0.5, "nesterov": False, "policy_lr_scale": 0.3},
           {"momentum": 0.0, "nesterov": False, "model": HamConfig(glances=2)})  # fmt: skip
    full = [tiny(s, **kw) for s, kw in enumerate(own)]
    train_batched(full, [tmp_path / f"full{c.seed}" for c in full])
    half = [tiny(s, steps=4, **kw) for s, kw in enumerate(own)]
    outs = [tmp_path / f"part{c.seed}" for c in half]
    train_batched(half, outs)
    assert metrics(outs[0])["steps"] == 4
    train_batched(full, outs)  # continues from the checkpoints
    for c in full:
        a, b = tmp_path / f"full{c.seed}", tmp_path / f"part{c.seed}"
        assert metrics(a) == metrics(b)
        for p, q in zip(weights(a), weights(b), strict=True):
            assert torch.equal(p, q)
    if compiled:
        assert_compiled()


def test_stop_at_perfect(tmp_path):
    # one glance, batches of one object, one evaluation batch: accuracy is 0 or 1
    configs = [tiny(s, model=HamConfig(glances=1), steps=6, batch_size=1, eval_batches=1)
               for s in (0, 1)]  # fmt: skip
    outs = [tmp_path / "s0", tmp_path / "s1"]
    results = train_batched(configs, outs, stop_at_perfect=True)
    stopped, going = results[1], results[0]
    assert stopped["best_accuracy"] == 1.0 and stopped["stopped_at_perfect"] == 0
    assert stopped["steps"] == 0 and metrics(outs[1])["stopped_at_perfect"] == 0
    assert going["best_accuracy"] < 1.0 and going["steps"] == 6
    assert "stopped_at_perfect" not in metrics(outs[0])
    assert is_finished(outs[1], 6) and is_finished(outs[0], 6)
    again = train_batched(configs, outs, stop_at_perfect=True)  # nothing left to train
    assert again[1]["steps"] == 0 and metrics(outs[1]) == stopped
    # without the option nothing stops
    plain = train_batched(configs, [tmp_path / "p0", tmp_path / "p1"])
    assert [r["steps"] for r in plain] == [6, 6]
    # the reproduce report marks the stopped run (and only it)
    root = tmp_path / "grid"
    for name, key in (("s0", "full-concat2-g1-s0"), ("s1", "full-concat2-g1-s1")):
        (root / "runs").mkdir(parents=True, exist_ok=True)
        (tmp_path / name).rename(root / "runs" / key)
    jobs = [Job(f"full-concat2-g1-s{s}", "full", "concat2", 1, s, {}) for s in (0, 1)]
    stopped = stopped_at_perfect(root, jobs)
    assert stopped == {"full-concat2-g1-s1": 0}
    report = render_report("table1", PROFILES["smoke"], [], [], [], None, "batched",
                           stopped=stopped, steps=6)  # fmt: skip
    assert "- `full-concat2-g1-s1`: best accuracy 1.000 at step 0 of 6" in report
    assert "full-concat2-g1-s0" not in report


def test_each_run_folder_is_held_while_the_batch_trains(tmp_path, monkeypatch):
    """As ``train`` and ``resume`` hold their folder, a batch holds each of its runs': a
    ``ham train --resume`` of one of them at the same time is refused, and the other way round;
    a batch that did not start leaves no folder it made."""
    from ham.world.files import folder_lock

    configs = [tiny(s, steps=4) for s in (0, 5)]
    outs = [tmp_path / "b0", tmp_path / "b5"]
    outs[1].mkdir()
    with folder_lock(outs[1]):  # another process resuming b5 (flock: per open file)
        with pytest.raises(HamError, match="run folder '.*b5' is in use by another ham process"):
            train_batched(configs, outs)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b5"] and not any(outs[1].iterdir())
    # a batch refused for its configs leaves none of the folders it made
    with pytest.raises(HamError, match="differ in more than seed"):
        train_batched([tiny(0), tiny(1, batch_size=4)], [tmp_path / "x", tmp_path / "y"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b5"]
    # while the batch trains, each run's folder is held: train() into it is refused
    seen = []
    real = batched.train_groups

    def train_and_try(groups, progress=False):
        with pytest.raises(HamError, match="is in use by another ham process"):
            train(configs[0], outs[0], progress=False)
        seen.append(True)
        return real(groups, progress)

    monkeypatch.setattr(batched, "train_groups", train_and_try)
    train_batched(configs, outs)
    assert seen and all(is_finished(o, 4) for o in outs)


def test_refused_configs(tmp_path):
    with pytest.raises(HamError, match="learner 'info' cannot be batched; accepted: hybrid"):
        train_batched([tiny(0, learner="info")], [tmp_path / "a"])
    # the stacked HAM has the lstm and mlp cores only (the transformer was a KeyError)
    with pytest.raises(HamError, match="core 'transformer' cannot be batched; accepted: lstm"):
        train_batched([tiny(0, model=HamConfig(core="transformer"))], [tmp_path / "a"])
    with pytest.raises(HamError, match="first_glance 'own' cannot be batched; accepted: random, "):
        train_batched([tiny(0, model=HamConfig(first_glance="own"))], [tmp_path / "a"])
    with pytest.raises(HamError, match="first_glance 'learned' with 1 glance cannot be batched"):
        train_batched([tiny(0, model=HamConfig(glances=1, first_glance="learned"))],
                      [tmp_path / "a"])  # fmt: skip
    one = {"model": HamConfig(glances=1)}  # no pose to choose: not with runs of 3 glances
    for kw in ({"optimizer": "adam"}, {"batch_size": 4}, {"beta": 0.0}, one):  # one per group
        with pytest.raises(HamError, match="differ in more than seed, steps, lr, lr_decay"):
            train_batched([tiny(0), tiny(1, **kw)], [tmp_path / "a", tmp_path / "b"])
    with pytest.raises(HamError, match="share a directory"):
        train_batched([tiny(0), tiny(1)], [tmp_path / "a", tmp_path / "a"])
    train_batched([tiny(0, steps=2)], [tmp_path / "c"])
    with pytest.raises(HamError, match="holds another run"):
        train_batched([tiny(1, steps=2)], [tmp_path / "c"])
    # a run of the same seed at another rate is another run: not resumed as this one
    with pytest.raises(HamError, match="holds another run"):
        train_batched([tiny(0, steps=4, lr=1e-3)], [tmp_path / "c"])
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


SMALL_GRID = ["reproduce", "table1", "--profile", "smoke", "--glances", "2", "--variants", "full",
              "rloc", "--seeds", "2", "--quiet", "--json"]  # fmt: skip
SMALL_GRID_KEYS = ("full-concat2-g2-s0", "full-concat2-g2-s1", "rloc-concat2-g2-s0",
                   "rloc-concat2-g2-s1")  # fmt: skip


@pytest.fixture(scope="module")
def batched_grid(tmp_path_factory):
    """A small Table 1 grid on the batched executor (4 runs: 2 variants x 2 seeds)."""
    from tests.conftest import run_ham

    out = tmp_path_factory.mktemp("batched-grid")
    r = run_ham(*SMALL_GRID, "--executor", "batched", "--workers", "1", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["ran"] == 4
    return out


def test_reproduce_batched_executor_matches_local(batched_grid, tmp_path, ham_cli, ham_main):
    common = [*SMALL_GRID, "--workers", "1"]
    loc = ham_cli(*common, "--out", str(tmp_path / "l"))
    assert loc.returncode == 0, loc.stderr
    for key in SMALL_GRID_KEYS:
        assert_same_run(batched_grid / "runs" / key, tmp_path / "l/runs" / key)
    t_b = json.loads((batched_grid / "table1.json").read_text())
    t_l = json.loads((tmp_path / "l/table1.json").read_text())
    assert t_b["2"]["full"]["mean"] == pytest.approx(t_l["2"]["full"]["mean"])
    # finished runs are skipped by every executor
    again = ham_main(*common, "--executor", "batched", "--out", str(batched_grid))
    assert json.loads(again.stdout)["skipped"] == 4
    bad = ham_main(*common, "--stop-at-perfect", "--out", str(tmp_path / "x"))
    assert bad.returncode == 2
    assert "ham: error: --stop-at-perfect needs --executor batched or ray-batched" in bad.stderr
    bad = ham_main(*common, "--executor", "batched", "--ray-address", "auto", "--out",
                  str(tmp_path / "x"))  # fmt: skip
    assert bad.returncode == 2
    assert "--ray-address 'auto': accepted only with --executor ray or ray-batched" in bad.stderr
    assert not (tmp_path / "x").exists()


def test_groups_are_shapes_in_plan_order_in_near_equal_batches():
    from types import SimpleNamespace

    from ham.experiments.executors import group_jobs

    def job(seed, **kw):
        return SimpleNamespace(config=tiny(seed, **kw).to_dict(), seed=seed)

    sweep = [job(s, lr=lr) for lr in (1e-3, 2e-3, 4e-3) for s in range(4)]  # one shape
    two = [job(s) for s in range(3)] + [job(s, batch_size=4) for s in range(3)]  # two shapes
    assert [[j.seed for j in g] for g in group_jobs(sweep)] == [
        [0, 1, 2, 3, 0, 1],
        [2, 3, 0, 1, 2, 3],
    ]
    assert [len(g) for g in group_jobs(sweep[:10])] == [10]  # at most 10 runs by default
    assert [len(g) for g in group_jobs(sweep * 2)] == [8, 8, 8]
    assert [len(g) for g in group_jobs(sweep, batch_runs=5)] == [5, 5, 2]
    assert [len(g) for g in group_jobs(sweep, batch_runs=12)] == [12]
    assert [len(g) for g in group_jobs(two)] == [3, 3]
    assert [len(g) for g in group_jobs(two + [job(9, steps=4)])] == [3, 3, 1]  # steps: apart
    column = [job(s, model=HamConfig(glances=g)) for g in (1, 2, 3, 4) for s in range(2)]
    assert [len(g) for g in group_jobs(column)] == [2, 2, 2, 2]
    # runs of other glance counts in one model, but one glance (no pose to choose) apart
    merged = group_jobs(column, merge_glances=True)
    assert [[j.config["model"]["glances"] for j in g] for g in merged] == [
        [1, 1],
        [2, 2, 3, 3, 4, 4],
    ]
    wide = [job(s, model=HamConfig(glances=g)) for g in (2, 3, 4) for s in range(4)]
    assert [len(g) for g in group_jobs(wide)] == [4, 4, 4]
    assert [len(g) for g in group_jobs(wide, merge_glances=True)] == [12]  # one model a shape
    assert [len(g) for g in group_jobs(wide, batch_runs=5, merge_glances=True)] == [5, 5, 2]


SWEEP = """\
name = "sweep"
seeds = 2

[table]
grid = 11

[base]
steps = 4
batch_size = 8
eval_every = 2
eval_batches = 2
model.glances = 2

[axes]
lr = [1e-3, 3e-3]
beta = [0.4, 1.0]
"""


def test_a_grid_sweep_of_rates_and_betas_is_one_batched_model(tmp_path, ham_cli):
    (tmp_path / "sweep.toml").write_text(SWEEP)
    r = ham_cli("reproduce", "grid", str(tmp_path / "sweep.toml"), "--executor", "batched",
                "--workers", "2", "--json", "--out", str(tmp_path / "o"))  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["ran"] == 8
    # one model, not one per worker (the grouping keeps the numbers the same on any machine)
    assert "1 batched model(s) for 2 workers: --batch-runs N spreads" in r.stderr
    runs = sorted((tmp_path / "o/runs").iterdir())
    assert len(runs) == 8
    for run in runs:  # 4 cells x 2 seeds, one model
        timing = json.loads((run / "timing.json").read_text())
        assert timing["batched_runs"] == 8 and "cpu" in timing["environment"]
    configs = {json.loads((run / "config.json").read_text())["lr"] for run in runs}
    assert configs == {1e-3, 3e-3}


def test_merge_glances_trains_a_grid_of_glance_counts_as_one_model(tmp_path, ham_cli, ham_main):
    grid = SWEEP.replace("model.glances = 2\n", "").replace(
        "beta = [0.4, 1.0]", "model.glances = [2, 3]"
    )
    (tmp_path / "g.toml").write_text(grid)
    args = ["reproduce", "grid", str(tmp_path / "g.toml"), "--executor", "batched", "--workers",
            "1", "--json"]  # fmt: skip
    r = ham_cli(*args, "--merge-glances", "--out", str(tmp_path / "o"))
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["ran"] == 8
    runs = sorted((tmp_path / "o/runs").iterdir())
    for run in runs:  # 2 rates x 2 glance counts x 2 seeds, one model
        assert json.loads((run / "timing.json").read_text())["batched_runs"] == 8
    glances = {json.loads((run / "config.json").read_text())["model"]["glances"] for run in runs}
    assert glances == {2, 3}
    bad = ham_main(*args[:3], "--merge-glances", "--out", str(tmp_path / "x"))
    assert bad.returncode == 2
    assert "ham: error: --merge-glances needs --executor batched or ray-batched" in bad.stderr
    assert not (tmp_path / "x").exists()


def assert_same_grid(r: subprocess.CompletedProcess, out: Path, batched_grid: Path) -> None:
    """The small grid run into ``out`` (``r``: its command) ran all 4 runs, each the batched
    executor's own to the bit."""
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["ran"] == 4
    for key in SMALL_GRID_KEYS:
        ours, theirs = out / "runs" / key, batched_grid / "runs" / key
        assert metrics(ours)["history"] == metrics(theirs)["history"]
        for p, q in zip(weights(ours), weights(theirs), strict=True):
            assert torch.equal(p, q), key


def test_ray_batched_executor_matches_batched(batched_grid, tmp_path, ham_cli):
    """Ray hands each worker a batched model: the same groups, the same numbers, to the bit."""
    pytest.importorskip("ray")
    r = ham_cli(*SMALL_GRID, "--executor", "ray-batched", "--batch-runs", "2", "--out",
                str(tmp_path / "r"))  # fmt: skip
    assert_same_grid(r, tmp_path / "r", batched_grid)
    assert "Executor: ray-batched" in (tmp_path / "r/report.md").read_text()


def test_the_executor_trains_groups_together(batched_grid, tmp_path, ham_cli):
    """--groups-together 2: the grid's two batched models (full, rloc) in one worker, each step
    of both launched before either is read back: on a CPU the same runs, to the bit."""
    r = ham_cli(*SMALL_GRID, "--executor", "batched", "--workers", "1", "--groups-together",
                "2", "--out", str(tmp_path / "t"))  # fmt: skip
    assert_same_grid(r, tmp_path / "t", batched_grid)


def test_batches_trained_together_resume_and_fail_alone(tmp_path):
    # two batches of other shapes together: a run that diverges leaves its batch alone, the
    # others end as trained alone; a second call resumes the unfinished ones to the bit
    shapes = [[tiny(0, steps=6), tiny(1, steps=6, lr=3e38)],
              [tiny(2, steps=6, model=HamConfig(glances=2))]]  # fmt: skip
    outs = [[tmp_path / f"t{c.seed}" for c in cs] for cs in shapes]
    results = batched.train_batched_together(list(zip(shapes, outs, strict=True)))
    assert isinstance(results[0][1], str) and "diverged" in results[0][1]
    assert [r["steps"] for r in (results[0][0], results[1][0])] == [6, 6]
    for cs in shapes:
        for c in cs[:1]:
            train_batched([c], [tmp_path / f"alone{c.seed}"])
            assert_same_run(tmp_path / f"t{c.seed}", tmp_path / f"alone{c.seed}")
    kept = [[shapes[0][0]], shapes[1]]  # the run that diverged left out
    half = [[replace(c, steps=4) for c in cs] for cs in kept]
    halves = [[tmp_path / f"h{c.seed}" for c in cs] for cs in half]
    batched.train_batched_together(list(zip(half, halves, strict=True)))
    batched.train_batched_together(list(zip(kept, halves, strict=True)))  # from step 4
    for c in (shapes[0][0], shapes[1][0]):
        a, b = tmp_path / f"h{c.seed}", tmp_path / f"t{c.seed}"
        assert metrics(a) == metrics(b)
        assert all(torch.equal(p, q) for p, q in zip(weights(a), weights(b), strict=True))
    with pytest.raises(HamError, match="^two runs of the batches share a directory"):
        batched.train_batched_together(
            [([tiny(0)], [tmp_path / "x"]), ([tiny(1)], [tmp_path / "x"])]
        )
    with pytest.raises(HamError, match="^no batches to train"):
        batched.train_batched_together([])
    for bad, says in (("abc", r"^batches = 'abc'; accepted: a list of \(configs, outs\) pairs"),
                      ([([tiny(0)],)], r"^batch 0 = \(\[TrainConfig"),
                      ([("abc", ["x"])], r"^configs = 'abc'; accepted: a list of TrainConfig"),
                      ([([tiny(0)], [3])], r"^outs = \[3\]; accepted: a list of paths")):  # fmt: skip
        with pytest.raises(HamError, match=says):
            batched.train_batched_together(bad)
    with pytest.raises(HamError, match="^train_batched: progress = nan; accepted: true or false"):
        train_batched([tiny(0)], [tmp_path / "x"], progress=float("nan"))
    assert not (tmp_path / "x").exists()


def test_batches_trained_together_load_their_table_once(tmp_path, monkeypatch):
    table = _small_table(tmp_path)
    made = []
    real = batched.make_source
    monkeypatch.setattr(batched, "make_source", lambda *a: made.append(a[0]) or real(*a))
    shapes = [[tiny(0, table=table, steps=2)], [tiny(1, table=table, steps=2, batch_size=4)],
              [tiny(2, steps=2)], [tiny(3, steps=2)]]  # fmt: skip
    batched.train_batched_together([(cs, [tmp_path / f"b{cs[0].seed}"]) for cs in shapes])
    assert made == [table, None, None]  # the online simulator: a source per batch, as before


def test_nan_weights_stop_their_run_alone(tmp_path):
    # one glance: the location heads take no part in the loss, so NaN there shows only in the
    # weights check after the update (the loss stays finite)
    configs = [tiny(s, model=HamConfig(glances=1), steps=4) for s in range(2)]
    outs = [tmp_path / f"b{s}" for s in range(2)]
    runs = _open_runs(configs, outs)
    with torch.no_grad():
        runs[0].agent.location.mu.weight[0, 0] = float("nan")
    results = BatchedRuns(runs, outs).train()
    assert results[0] == "training diverged at step 1: NaN/inf in the weights location.mu.weight"
    train(configs[1], tmp_path / "single1", progress=False)
    assert_same_run(outs[1], tmp_path / "single1")


def _small_table(tmp_path: Path) -> str:
    # a graph needs a glance table: the online simulator's glance asks the host
    path = tmp_path / "t5.h5"
    return str(path if path.exists() else build_table(WorldConfig(), 5, path, progress=False))


def _graph_group(tmp_path: Path, tag: str, cuda_graph: bool, device: str = "cpu") -> list:
    # runs at their own rates, momenta (one without) and location-network scales, one of
    # fewer steps (the group's stack changes when it leaves: a new graph), one of 2 glances
    own = ({}, {"lr": 0.01, "momentum": 0.5, "nesterov": False, "policy_lr_scale": 0.3},
           {"momentum": 0.0, "nesterov": False, "steps": 5},
           {"model": HamConfig(glances=2)})  # fmt: skip
    table = _small_table(tmp_path)
    configs = [tiny(s, device=device, table=table, **kw) for s, kw in enumerate(own)]
    outs = [tmp_path / f"{tag}{s}" for s in range(len(configs))]
    train_batched(configs, outs, cuda_graph=cuda_graph)
    return outs


def test_the_graphed_step_is_the_eager_step(tmp_path, monkeypatch):
    # on a CPU the graph's replay is a call of the device step: the protocol (warm-up, the rates
    # as a tensor filled before each replay, a new graph for each new stack) gives the eager
    # step's numbers to the bit
    calls = []
    graphed = BatchedRuns._graphed_step
    monkeypatch.setattr(BatchedRuns, "_graphed_step", lambda g, runs: calls.append(
        g._graph_state.replay is not None) or graphed(g, runs))  # fmt: skip
    eager, graph = _graph_group(tmp_path, "e", False), _graph_group(tmp_path, "g", True)
    # replays: steps 1-5 of all four runs, 6-8 without the 5-step run; two warm-up steps each
    assert calls.count(True) == (5 - 2) + (3 - 2)
    for a, b in zip(eager, graph, strict=True):
        assert metrics(a) == metrics(b)
        for p, q in zip(weights(a), weights(b), strict=True):
            assert torch.equal(p, q)


class _Calls(TorchDispatchMode):
    """Each operator dispatched, with its arguments as a graph would freeze them: a tensor by
    its shape and dtype (its values are read at every replay), anything else by value."""

    def __init__(self) -> None:
        super().__init__()
        self.calls: list[tuple] = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        def frozen(a):
            if isinstance(a, torch.Tensor):
                return ("tensor", tuple(a.shape), a.dtype)
            if isinstance(a, list | tuple):
                return tuple(frozen(x) for x in a)
            return a if isinstance(a, int | float | bool | str | type(None)) else type(a)

        kwargs = kwargs or {}
        self.calls.append((str(func), frozen(args), frozen(sorted(kwargs.items()))))
        return func(*args, **kwargs)


@pytest.mark.parametrize("first", ["random", "learned"])
@pytest.mark.parametrize("cuda_graph", [True, False], ids=["graphed", "eager"])
def test_a_graph_would_replay_the_steps_own_numbers(tmp_path, cuda_graph, first):
    # a graph replays the operators of the step it captured, numbers included: two later steps
    # must dispatch the same operators with the same arguments but for tensors' values (a rate
    # passed as a number, as the eager step passes it, would be frozen at the captured step)
    table = str(build_table(WorldConfig(), 5, tmp_path / "t.h5", progress=False))
    configs = [tiny(s, table=table, **kw) for s, kw in enumerate(
        ({"model": HamConfig(glances=3, first_glance=first)},
         {"lr": 0.01, "policy_lr_scale": 0.3, "model": HamConfig(glances=3, first_glance=first)},
         {"model": HamConfig(glances=2, first_glance=first)}))]  # fmt: skip
    outs = [tmp_path / f"b{c.seed}" for c in configs]
    group = BatchedRuns(_open_runs(configs, outs), outs, cuda_graph=cuda_graph)
    steps = []
    for _ in range(batched._GRAPH_WARMUP + 3):
        with _Calls() as calls:
            group._device_step([group.runs[i] for i in group.active])
        steps.append(calls.calls)
        for i in group.active:  # as step(): the next step's rates
            group.runs[i].step += 1
    assert (steps[-1] == steps[-2]) is cuda_graph


def test_evaluation_draws_are_drawn_once(tmp_path):
    # a run's evaluation seeds its generators anew each time, so its draws (first glance, later
    # glances, pose noise) are the same at every evaluation: kept after the first, a second
    # evaluation draws nothing and counts the same (the counts equal the single run's: above)
    configs = [tiny(0), tiny(1, pose_noise=0.05), tiny(2, eval_policy="sample")]
    outs = [tmp_path / f"b{c.seed}" for c in configs]
    group = BatchedRuns(_open_runs(configs, outs), outs)
    first = group.evaluate([0, 1, 2])
    with _Calls() as calls:
        again = group.evaluate([0, 1, 2])
    drawn = [c[0] for c in calls.calls if c[0].startswith(("aten.uniform_", "aten.normal_"))]
    assert drawn == [] and again == first
    with _Calls() as calls:  # a run's own draws, not another's
        alone = group.evaluate([1])
    drawn = [c[0] for c in calls.calls if c[0].startswith(("aten.uniform_", "aten.normal_"))]
    assert drawn == [] and alone == first[1:2]


def _two_groups(tmp_path: Path, tag: str, device: str = "cpu", cuda_graph: bool = False):
    # two shapes (3 and 2 glances), one with a run of fewer steps (it leaves its group early)
    kw = {"device": device, "table": _small_table(tmp_path)}
    shapes = [[tiny(0, **kw), tiny(1, steps=5, **kw)],
              [tiny(2, model=HamConfig(glances=2, policy="random"), **kw)]]  # fmt: skip
    outs = [[tmp_path / f"{tag}{c.seed}" for c in cs] for cs in shapes]
    return [BatchedRuns(_open_runs(cs, os_), os_, cuda_graph=cuda_graph)
            for cs, os_ in zip(shapes, outs, strict=True)], [o for os_ in outs for o in os_]  # fmt: skip


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not torch.cuda.is_available(), reason="needs CUDA"))])  # fmt: skip
def test_groups_trained_together_are_each_trained_alone(tmp_path, device):
    # every round launches each group's step before reading any back (on a GPU each group on its
    # own stream): each group's numbers are its own
    alone, outs_alone = _two_groups(tmp_path, "a", device)
    results_alone = [g.train() for g in alone]
    together, outs = _two_groups(tmp_path, "t", device, cuda_graph=device == "cuda")
    results = batched.train_groups(together)
    assert [[r["steps"] for r in rs] for rs in results] == [[8, 5], [8]]
    assert [[r["steps"] for r in rs] for rs in results_alone] == [[8, 5], [8]]
    for a, b in zip(outs_alone, outs, strict=True):
        if device == "cpu":
            assert metrics(a)["history"] == metrics(b)["history"]
            assert all(torch.equal(p, q) for p, q in zip(weights(a), weights(b), strict=True))
        else:
            assert_same_run(b, a, 1e-5)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_graphed_step_equals_the_eager_step(tmp_path):
    eager, graph = (
        _graph_group(tmp_path, "e", False, "cuda"),
        _graph_group(tmp_path, "g", True, "cuda"),
    )
    for a, b in zip(eager, graph, strict=True):
        ma, mb = metrics(a), metrics(b)
        assert [h["accuracy"] for h in ma["history"]] == [h["accuracy"] for h in mb["history"]]
        for p, q in zip(weights(a), weights(b), strict=True):
            assert torch.allclose(p, q, rtol=1e-4, atol=1e-5)


def test_a_graph_is_refused_on_the_online_simulator(tmp_path):
    # its glance iterates to each contact on the host: a capture would fail mid-step (seen on
    # an H100), so it is refused before any run is written
    configs = [tiny(s) for s in range(2)]
    outs = [tmp_path / f"b{s}" for s in range(2)]
    with pytest.raises(HamError, match=r"^a CUDA graph on the online fast simulator; accepted: "
                       r"runs on a glance table \(--table\), or the eager step"):  # fmt: skip
        train_batched(configs, outs, cuda_graph=True)
    assert not any(o.exists() for o in outs)


def test_a_graph_is_refused_with_adam(tmp_path):
    configs = [tiny(s, optimizer="adam") for s in range(2)]
    with pytest.raises(HamError, match="optimizer 'adam' with a CUDA graph; accepted: sgd"):
        train_batched(configs, [tmp_path / f"b{s}" for s in range(2)], cuda_graph=True)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_graph_on_the_command_line(tmp_path, ham_cli):
    # the small grid on CUDA, batched, eager and replayed as graphs: the same runs
    common = [*SMALL_GRID, "--executor", "batched", "--workers", "1", "--device", "cuda"]
    for name, extra in (("e", []), ("g", ["--cuda-graph"])):
        r = ham_cli(*common, *extra, "--out", str(tmp_path / name))
        assert r.returncode == 0, r.stderr
    for key in SMALL_GRID_KEYS:
        for p, q in zip(weights(tmp_path / "e/runs" / key), weights(tmp_path / "g/runs" / key),
                        strict=True):  # fmt: skip
            assert torch.allclose(p, q, rtol=1e-4, atol=1e-5)
