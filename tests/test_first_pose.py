"""The first glance's own pose distribution (``--first-glance own``, ham.model.policy.FirstPose):
its parameters, what trains them, its learning rate, replay and resume, the CLI, and that it
learns where the ``learned`` first glance cannot."""

from __future__ import annotations

import json
import math

import pytest
import torch

from ham.errors import HamError
from ham.learn.info_loss import info_loss
from ham.learn.train import (
    GlanceRecorder,
    Run,
    TrainConfig,
    resume,
    train,
    train_step,
)
from ham.model.agent import HamConfig, HapticAttentionModel
from ham.model.policy import FirstPose
from ham.world.config import WorldConfig
from tests.conftest import ok, one_line_error


def tiny(**kw) -> TrainConfig:
    model = kw.pop("model", HamConfig(glances=3, first_glance="own", first_pose_grid=2))
    base = dict(model=model, steps=6, batch_size=8, eval_every=2, eval_batches=2, seed=5,
                learner="info", optimizer="adam", lr=3e-3)  # fmt: skip
    base.update(kw)
    return TrainConfig(**base)


def test_the_mixture_starts_on_a_grid_over_the_poses():
    fp = FirstPose(dims=2, grid=2)
    assert fp.components == 4
    centres = torch.tanh(fp.mean).detach().double()
    assert torch.allclose(
        centres,
        torch.tensor([[-0.5, -0.5], [-0.5, 0.5], [0.5, -0.5], [0.5, 0.5]], dtype=torch.float64),
        atol=1e-6,
    )
    assert torch.allclose(fp.log_sigma.exp(), torch.full((4, 2), 0.5))
    one = FirstPose(dims=2, grid=1)
    assert torch.tanh(one.mean).tolist() == [[0.0, 0.0]] and one.log_sigma.exp().tolist() == [
        [1.0, 1.0]
    ]
    with pytest.raises(HamError):
        FirstPose(grid=0)


def test_the_first_pose_s_log_prob_is_the_component_s_and_the_pose_s():
    fp = FirstPose(dims=2, grid=2)
    with torch.no_grad():
        fp.weight.copy_(torch.tensor([0.0, 1.0, 2.0, 3.0]))
    g = torch.Generator().manual_seed(0)
    dist = fp.distribution(500, g)
    q = dist.sample(g)
    c = dist.choice
    log_w = torch.log_softmax(fp.weight, -1)[c]
    mu, sigma = torch.tanh(fp.mean)[c], fp.log_sigma.exp()[c] + fp.sigma_min
    expected = -torch.log(sigma) - 0.5 * ((q - mu) / sigma) ** 2 - 0.5 * math.log(2 * math.pi)
    assert torch.allclose(dist.log_prob(q), expected.sum(-1) + log_w)
    # components are drawn by their weights; greedy takes the heaviest's mean
    share = torch.bincount(c, minlength=4).double() / 500
    assert share[3] > share[2] > share[0]
    greedy = fp.distribution(3, greedy=True)
    assert greedy.choice.tolist() == [3, 3, 3]
    assert torch.equal(greedy.mode(), torch.tanh(fp.mean)[3].detach().expand(3, 2))


def test_an_own_first_glance_is_chosen_and_trained_by_the_policy_term_only(env):
    torch.manual_seed(0)
    model = HapticAttentionModel(HamConfig(glances=3, first_glance="own", first_pose_grid=2))
    episode = model(env, env.sample_objects(), torch.Generator().manual_seed(0))
    b = episode.objects.shape[0]
    assert tuple(episode.policy.batch_shape) == (3, b)  # glance 1 is the policy's too
    assert episode.first_choice.shape == (b,) and episode.first_baseline.shape == (b,)
    loss = info_loss(episode)
    params = dict(model.named_parameters())
    for part, owners in (("policy", ("location.", "first_pose.")), ("critic", ("baseline.",)),
                         ("classification", ("tactile.", "core.", "classifier."))):  # fmt: skip
        grads = torch.autograd.grad(getattr(loss, part), list(params.values()),
                                    retain_graph=True, allow_unused=True)  # fmt: skip
        reached = {n for n, gr in zip(params, grads, strict=True)
                   if gr is not None and bool(gr.abs().sum() > 0)}  # fmt: skip
        assert reached and all(n.startswith(owners) for n in reached), (part, reached)
        if part == "policy":  # mean, sigma and weights of the first pose all learn
            assert {"first_pose.mean", "first_pose.log_sigma", "first_pose.weight"} <= reached
    # greedy: every episode's first pose is the heaviest component's mean
    greedy = model(env, episode.objects, None, greedy=True)
    assert torch.equal(greedy.locations[0], greedy.locations[0][:1].expand(b, 2))


def test_the_other_first_glances_build_no_first_pose_and_keep_their_weights():
    torch.manual_seed(3)
    before = HapticAttentionModel(HamConfig(glances=3, first_glance="learned")).state_dict()
    torch.manual_seed(3)
    own = HapticAttentionModel(HamConfig(glances=3, first_glance="own")).state_dict()
    assert set(own) - set(before) == {
        "first_pose.mean",
        "first_pose.log_sigma",
        "first_pose.weight",
    }
    for name, w in before.items():  # created last, drawing no random numbers
        assert torch.equal(w, own[name]), name
    assert not any(
        n.startswith("first_pose") for n in HapticAttentionModel(HamConfig()).state_dict()
    )


def test_a_replayed_episode_keeps_the_components_it_played(env):
    torch.manual_seed(0)
    model = HapticAttentionModel(HamConfig(glances=3, first_glance="own", first_pose_grid=3))
    recorder = GlanceRecorder(env)
    played = model(recorder, env.sample_objects(), torch.Generator().manual_seed(1))
    again = model.replay(
        torch.stack(recorder.pressures), torch.stack(recorder.where), played=played
    )
    assert torch.equal(again.first_choice, played.first_choice)
    q = played.locations[played.chosen]
    assert torch.allclose(again.policy.log_prob(q), played.policy.log_prob(q))


def test_the_first_pose_learns_at_its_own_rate():
    run = Run.create(tiny(first_pose_lr_scale=5.0, policy_lr_scale=0.3, lr_step=1_000_000))
    try:
        train_step(run)
        rest, location, first = run.optimizer.param_groups
        assert rest["lr"] == pytest.approx(3e-3)
        assert location["lr"] == pytest.approx(9e-4) and first["lr"] == pytest.approx(1.5e-2)
        assert {id(p) for p in first["params"]} == {
            id(p) for p in run.agent.first_pose.parameters()
        }
        assert {id(p) for p in location["params"]} == {
            id(p) for p in run.agent.location.parameters()
        }
    finally:
        run.close()


@pytest.mark.parametrize(
    "kw",
    [{"first_pose_lr_scale": 0.0}, {"first_pose_lr_scale": float("nan")},
     {"first_pose_lr_scale": True},
     {"first_pose_lr_scale": 2.0, "model": HamConfig(glances=3, first_glance="learned")}],
)  # fmt: skip
def test_bad_first_pose_configs(kw):
    with pytest.raises(HamError):
        tiny(**kw)


@pytest.mark.parametrize("kw", [{"first_pose_grid": 0}, {"first_pose_grid": 2.5},
                                {"first_pose_grid": 2, "first_glance": "learned"}])  # fmt: skip
def test_bad_first_pose_grid(kw):
    with pytest.raises(HamError):
        HamConfig(**kw)


def test_an_own_first_glance_resumes_bit_identically(tmp_path):
    full = train(tiny(steps=6), tmp_path / "full", progress=False)
    train(tiny(steps=4), tmp_path / "half", progress=False)
    resumed = resume(tmp_path / "half", steps=6, progress=False)
    assert full["history"] == resumed["history"]
    a = torch.load(tmp_path / "full" / "checkpoint.pt", weights_only=False)["model"]
    b = torch.load(tmp_path / "half" / "checkpoint.pt", weights_only=False)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert a["first_pose.weight"].shape == (4,)


def test_own_first_glance_through_the_cli(tmp_path, ham_cli, ham_main):
    out = tmp_path / "run"
    ok(ham_cli("train", "--learner", "info", "--optimizer", "adam", "--glances", "3",
               "--batch-size", "8", "--steps", "3", "--first-glance", "own",
               "--first-pose-grid", "2", "--first-pose-lr-scale", "4", "--stop",
               "--glance-cost", "0.1", "--eval-every", "3", "--eval-batches", "2",
               "--no-progress", "--out", str(out)))  # fmt: skip
    m = json.loads((out / "metrics.json").read_text())
    assert m["config"]["model"]["first_glance"] == "own"
    assert m["config"]["model"]["first_pose_grid"] == 2
    assert m["config"]["first_pose_lr_scale"] == 4.0
    assert m["stop_accuracy"] is not None
    err = one_line_error(ham_main("train", "--learner", "info", "--first-pose-grid", "2",
                                 "--steps", "1", "--out", str(tmp_path / "bad")))  # fmt: skip
    assert "first_pose_grid" in err and not (tmp_path / "bad").exists()
    err = one_line_error(ham_main("train", "--learner", "info", "--first-glance", "learned",
                                 "--first-pose-lr-scale", "3", "--steps", "1",
                                 "--out", str(tmp_path / "bad")))  # fmt: skip
    assert "first_pose_lr_scale" in err


def _first_sigma(first_glance: str, table: str, steps: int = 150) -> float:
    """The first pose's largest sigma after ``steps`` of the recipe's schedule on ``table``."""
    model = HamConfig(glances=3, first_glance=first_glance)
    from ham.learn.train import model_for_source

    c = TrainConfig(model=model_for_source(model, table, WorldConfig()), table=table,
                    learner="info", optimizer="adam", lr=3e-3, batch_size=16, steps=steps,
                    lr_step=100, lr_decay=0.6, policy_lr_scale=0.3, seed=0)  # fmt: skip
    run = Run.create(c)
    try:
        for _ in range(steps):
            train_step(run)
        dist, _ = run.agent.first_glance(1)
        return float(dist.sigma.detach().max())
    finally:
        run.close()


def test_the_own_first_pose_narrows_where_the_learned_one_cannot(tmp_path, ham_cli):
    """On a real table (the paper's objects, a coarse grid) 150 steps of the recipe's schedule:
    the ``learned`` first glance's sigma stays near ``softplus(0) = 0.69`` (Adam moves its bias
    by at most ~lr a step), the own first pose's narrows well below its start (1.0)."""
    table = tmp_path / "paper.h5"
    ok(ham_cli("table", "build", "--objects", "paper", "--grid", "41", "--out", str(table)))
    learned = _first_sigma("learned", str(table))
    own = _first_sigma("own", str(table))
    assert learned > 0.6, (learned, own)
    assert own < 0.5, (learned, own)
