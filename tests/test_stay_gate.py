"""The learned "stay" gate of the location policy (``--stay-gate``, HamConfig.stay_gate): the mean
next pose mixes the pad's pose and the location network's by a gate on the classifier's
confidence; the gate is created last and starts open, what trains it, replay, resume, the CLI
and bad input."""

from __future__ import annotations

import json

import pytest
import torch

from ham.errors import HamError
from ham.learn.batched import check_batchable
from ham.learn.info_loss import info_loss, mean_travel_penalty
from ham.learn.train import GlanceRecorder, TrainConfig, resume, train
from ham.model.agent import HamConfig, HapticAttentionModel
from tests.conftest import ok, one_line_error

GATED = HamConfig(glances=3, stay_gate=True)


def tiny(**kw) -> TrainConfig:
    base = dict(model=kw.pop("model", GATED), steps=6, batch_size=8, eval_every=2,
                eval_batches=2, seed=5, learner="info", optimizer="adam", lr=3e-3,
                move_cost=0.3)  # fmt: skip
    base.update(kw)
    return TrainConfig(**base)


def test_the_gate_is_created_last_and_keeps_every_other_weight():
    torch.manual_seed(3)
    before = HapticAttentionModel(HamConfig(glances=3)).state_dict()
    torch.manual_seed(3)
    gated = HapticAttentionModel(GATED).state_dict()
    assert {n for n in set(gated) - set(before)} == {
        f"stay.net.{i}.{w}" for i in (0, 2) for w in ("weight", "bias")
    }
    # it starts open: g = sigmoid(-3) in every state
    agent = HapticAttentionModel(GATED)
    assert torch.allclose(
        torch.sigmoid(agent.stay(torch.randn(6, 4))), torch.tensor(0.0474), atol=1e-4
    )
    for name, w in before.items():
        assert torch.equal(w, gated[name]), name


def test_the_mean_mixes_the_pad_s_pose_and_the_network_s(env):
    torch.manual_seed(0)
    agent = HapticAttentionModel(GATED)
    tau = torch.randn(5, 256)
    q = torch.rand(5, 2) * 2 - 1
    free = agent.location.distribution(tau)
    dist = agent.next_distribution(tau, q)
    with torch.no_grad():
        agent.stay.net[-1].weight.normal_()  # a gate that tells states apart
    dist = agent.next_distribution(tau, q)
    g = torch.sigmoid(agent.stay(agent.classifier(tau)))[:, None]
    assert g.std() > 0 and torch.allclose(dist.mu, g * q + (1 - g) * free.mu)
    assert torch.equal(dist.sigma, free.sigma)
    with torch.no_grad():  # a shut gate: the mean stays where the pad is, no travel to pay
        agent.stay.net[-1].bias.fill_(50.0)
    episode = agent(env, env.sample_objects(), None, greedy=True)
    assert torch.allclose(episode.locations[1:], episode.locations[:1].expand(2, 8, 2))
    assert float(mean_travel_penalty(episode, 1.0).detach()) < 1e-4
    plain = HapticAttentionModel(HamConfig(glances=3))
    assert torch.equal(plain.next_distribution(tau, q).mu, plain.location.distribution(tau).mu)


def test_the_gate_is_trained_by_the_policy_term_and_the_travel_penalty_only(env):
    torch.manual_seed(0)
    agent = HapticAttentionModel(GATED)
    episode = agent(env, env.sample_objects(), torch.Generator().manual_seed(0))
    loss = info_loss(episode)
    params = dict(agent.named_parameters())
    for term in (loss.policy, mean_travel_penalty(episode, 0.3)):
        grads = torch.autograd.grad(term, list(params.values()), retain_graph=True,
                                    allow_unused=True)  # fmt: skip
        reached = {n for n, gr in zip(params, grads, strict=True)
                   if gr is not None and bool(gr.abs().sum() > 0)}  # fmt: skip
        assert {"stay.net.2.weight", "stay.net.2.bias"} <= reached
        assert all(n.startswith(("location.", "stay.")) for n in reached), reached
    grads = torch.autograd.grad(loss.classification, [params["stay.net.2.weight"]],
                                allow_unused=True)  # fmt: skip
    assert grads[0] is None  # it reads the classifier's output detached


def test_a_replayed_episode_has_the_gated_distributions(env):
    torch.manual_seed(0)
    agent = HapticAttentionModel(GATED)
    recorder = GlanceRecorder(env)
    played = agent(recorder, env.sample_objects(), torch.Generator().manual_seed(1))
    again = agent.replay(
        torch.stack(recorder.pressures), torch.stack(recorder.where), played=played
    )
    assert torch.allclose(again.policy.mu, played.policy.mu)


def test_a_gated_run_resumes_bit_identically(tmp_path):
    full = train(tiny(), tmp_path / "full", progress=False)
    train(tiny(steps=4), tmp_path / "half", progress=False)
    resumed = resume(tmp_path / "half", steps=6, progress=False)
    assert full["history"] == resumed["history"]
    assert full["path_length"] is not None


@pytest.mark.parametrize(
    "make",
    [lambda: HamConfig(stay_gate=1), lambda: HamConfig(stay_gate=True, policy="random"),
     lambda: tiny(learner="sac", model=HamConfig(glances=3, stay_gate=True, policy="squashed"),
                  move_cost=0.0)],
)  # fmt: skip
def test_bad_stay_gate_configs(make):
    with pytest.raises(HamError):
        make()


def test_a_gated_run_is_not_batched():
    c = TrainConfig(model=GATED, steps=2, batch_size=8)
    with pytest.raises(HamError, match="stay_gate"):
        check_batchable(c)


def test_stay_gate_through_the_cli(tmp_path, ham_cli, ham_main):
    out = tmp_path / "run"
    ok(ham_cli("train", "--learner", "info", "--optimizer", "adam", "--glances", "3",
               "--batch-size", "8", "--steps", "2", "--stay-gate", "--move-cost", "0.3",
               "--eval-every", "2", "--eval-batches", "2", "--no-progress",
               "--out", str(out)))  # fmt: skip
    m = json.loads((out / "metrics.json").read_text())
    assert m["config"]["model"]["stay_gate"] is True
    err = one_line_error(ham_main("train", "--stay-gate", "--policy", "random", "--steps", "1",
                                 "--out", str(tmp_path / "bad")))  # fmt: skip
    assert "stay_gate" in err and not (tmp_path / "bad").exists()
