"""Actuation noise (``pose_noise``): each glance made a little off the pose the agent chose."""

from __future__ import annotations

import pytest
import torch

from ham.errors import HamError
from ham.learn.environment import HapticEnv
from ham.learn.evaluation import evaluate
from ham.learn.train import TrainConfig, resume, train
from ham.model.agent import HamConfig, HapticAttentionModel
from ham.world.config import WorldConfig
from ham.world.source import make_source

from .conftest import one_line_error


@pytest.fixture(scope="module")
def source():
    return make_source(None, WorldConfig())[0]


def test_noise_moves_the_executed_pose_and_leaves_the_chosen_one(source):
    quiet = HapticEnv(source, batch_size=64, seed=0)
    noisy = HapticEnv(source, batch_size=64, seed=0, pose_noise=0.1)
    objects = noisy.sample_objects()
    assert torch.equal(objects, quiet.sample_objects())  # the ids come first from one stream
    q = torch.zeros(64, 2)
    executed = noisy.executed(q)
    assert torch.equal(q, torch.zeros(64, 2))  # the caller's pose is not touched
    assert 0.07 < float(executed.std()) < 0.13  # sigma 0.1 over 128 draws
    assert torch.equal(quiet.executed(q), q)
    edge = noisy.executed(torch.ones(64, 2))
    assert float(edge.max()) == 1.0 and float(edge.min()) < 1.0  # clamped to the range
    # the glance is made at the executed pose: at x = 0 the paper's objects differ along x
    assert not torch.equal(noisy.glance(objects, q), quiet.glance(objects, q))


def test_an_evaluation_batch_draws_the_same_noise_and_leaves_training_as_it_was(source):
    env = HapticEnv(source, batch_size=8, seed=3, pose_noise=0.2)
    twin = HapticEnv(source, batch_size=8, seed=3, pose_noise=0.2)
    q = torch.zeros(8, 2)
    first = env.glance(env.balanced_objects(1), q)
    ids = env.balanced_objects(1)
    again = env.glance(ids, q)
    assert torch.equal(first, again)  # evaluation batch 1: its own seed
    assert not torch.equal(again, env.glance(ids, q))  # the next glance, the next draw
    # the evaluation draws did not move the training stream: the twin evaluated nothing
    assert torch.equal(env.sample_objects(), twin.sample_objects())
    assert torch.equal(env.glance(ids, q), twin.glance(ids, q))


def test_noise_changes_an_evaluation_which_stays_repeatable(source):
    torch.manual_seed(0)
    agent = HapticAttentionModel(HamConfig(glances=2))
    quiet = HapticEnv(source, batch_size=8, seed=0)
    noisy = HapticEnv(source, batch_size=8, seed=0, pose_noise=0.5)
    a = evaluate(agent, noisy, batches=4, seed=1)
    assert a == evaluate(agent, noisy, batches=4, seed=1)
    assert a.confusion != evaluate(agent, quiet, batches=4, seed=1).confusion


def _tiny(**kw) -> TrainConfig:
    base = dict(model=HamConfig(glances=2), steps=6, batch_size=8, eval_every=3,
                eval_batches=2, seed=2, pose_noise=0.05)  # fmt: skip
    return TrainConfig(**{**base, **kw})


def test_a_noisy_run_is_repeatable_and_resumes_bit_identically(tmp_path):
    full = train(_tiny(), tmp_path / "full", progress=False)
    assert full == train(_tiny(), tmp_path / "again", progress=False)
    assert full != train(_tiny(pose_noise=0.0), tmp_path / "quiet", progress=False)
    train(_tiny(steps=3), tmp_path / "half", progress=False)
    assert resume(tmp_path / "half", steps=6, progress=False) == full
    assert full["config"]["pose_noise"] == 0.05


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        (dict(pose_noise=-0.1), "pose_noise = -0.1; accepted: a number 0..1"),
        (dict(pose_noise=2.0), "pose_noise = 2.0; accepted: a number 0..1"),
        (dict(pose_noise=True), "pose_noise = True"),
        (dict(pose_noise="0.1"), "pose_noise = '0.1'"),
    ],
)
def test_a_bad_pose_noise_is_refused(kw, match):
    with pytest.raises(HamError, match=match):
        _tiny(**kw)


def test_the_cli_refuses_a_bad_pose_noise_and_a_graphed_noisy_run(tmp_path, ham_main):
    line = one_line_error(ham_main("train", "--pose-noise", "1.5", "--out", str(tmp_path / "r")))
    assert "pose_noise = 1.5; accepted: a number 0..1" in line
    assert not (tmp_path / "r").exists()
    line = one_line_error(ham_main("train", "--env", "ap_gym:CircleSquare-v0", "--pose-noise",
                                   "0.1", "--out", str(tmp_path / "r")))  # fmt: skip
    assert "pose_noise = 0.1 with env 'ap_gym:CircleSquare-v0'" in line
    assert not (tmp_path / "r").exists()
    from ham.learn.batched import BatchedRuns, _open_runs, check_batchable
    from ham.world.table import build_table

    check_batchable(_tiny())  # batched runs draw each run's noise as its single run
    outs = [tmp_path / "b0"]
    table = str(build_table(WorldConfig(), 5, tmp_path / "t.h5", progress=False))
    with pytest.raises(HamError, match="pose_noise with a CUDA graph"):
        BatchedRuns(_open_runs([_tiny(table=table)], outs), outs, cuda_graph=True)


@pytest.mark.parametrize("bad", [float("nan"), -0.5, 1.5, "0.1", None])
def test_the_env_refuses_a_bad_pose_noise(source, bad):
    with pytest.raises(HamError, match=r"pose_noise = .*; accepted: a number 0\.\.1"):
        HapticEnv(source, batch_size=8, pose_noise=bad)
