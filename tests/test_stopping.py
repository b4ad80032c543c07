"""The learned stop: classify-now or glance-again after each glance (ham.learn.stopping)."""

from __future__ import annotations

import math

import pytest
import torch

from ham.errors import HamError
from ham.learn.environment import HapticEnv
from ham.learn.stopping import stop_glances, stop_loss, stop_payoffs
from ham.learn.train import TrainConfig, load_run, train
from ham.model.agent import Episode, HamConfig, HapticAttentionModel, StopHead
from ham.world.config import WorldConfig
from ham.world.source import make_source


def test_stop_glances_take_the_first_stop_and_force_the_last():
    logits = torch.tensor([[-9.0, 9.0, -9.0], [9.0, -9.0, -9.0], [-9.0, -9.0, -9.0]])  # (S=3, B=3)
    at, decide = stop_glances(logits, greedy=True)
    assert at.tolist() == [2, 1, 3]  # episode 2 never stops early: the last glance is forced
    assert decide[-1].tolist() == [1.0, 1.0, 1.0]


def _hand_episode(stop_logits: list[list[float]]) -> Episode:
    """Three glances of two episodes (objects 0 and 1): episode 0 is right from glance 2 on,
    episode 1 only at glance 3."""
    ans0, ans1 = torch.tensor([5.0, 0.0]), torch.tensor([0.0, 5.0])  # logits answering 0 / 1
    logits = torch.stack(
        [torch.stack([ans1, ans0]), torch.stack([ans0, ans0]), torch.stack([ans0, ans1])]
    )  # (S=3, B=2, K=2)
    return Episode(
        objects=torch.tensor([0, 1]),
        locations=torch.zeros(3, 2, 2),
        logits=logits,
        baselines=torch.zeros(3, 2),
        policy=None,
        stop_logits=torch.tensor(stop_logits, requires_grad=True),
    )


def test_stop_payoffs_are_the_answer_minus_the_glances_paid():
    g = stop_payoffs(_hand_episode([[0.0, 0.0]] * 3), 0.1)
    assert torch.allclose(g, torch.tensor([[-0.1, -0.1], [0.8, -0.2], [0.7, 0.7]]))


def test_the_value_stop_regresses_classify_now_minus_continue_by_backward_induction():
    # glance 2: episode 0 stops greedily (d > 0), episode 1 goes on
    episode = _hand_episode([[-1.0, -1.0], [1.0, -1.0], [0.0, 0.0]])
    loss = stop_loss(episode, 0.1)
    # targets: glance 2: g_2 - W_3 = (0.8 - 0.7, -0.2 - 0.7); glance 1: g_1 - W_2 with
    # W_2 = g_2 where the head stops at 2 (episode 0) else W_3 (episode 1)
    target = torch.tensor([[-0.1 - 0.8, -0.1 - 0.7], [0.1, -0.9]])
    d = episode.stop_logits.detach()[:2]
    assert torch.allclose(loss.total, ((d - target) ** 2).mean())
    assert loss.stop_at.tolist() == [2, 3]
    assert torch.allclose(loss.ret, torch.tensor([0.8, 0.7]))
    loss.total.backward()
    assert episode.stop_logits.grad[-1].abs().sum() == 0  # the forced last stop has no target
    with pytest.raises(HamError, match="stop learner 'guess'"):
        stop_loss(episode, 0.1, learner="guess")


def test_the_stop_head_reads_the_classifier_s_confidence_in_nats():
    logits = torch.tensor([[0.0, 0.0, 0.0, 0.0], [math.log(297.0), 0.0, 0.0, 0.0], [1e4, 0, 0, 0]])
    x = StopHead.confidence(logits)
    assert torch.allclose(x[0], torch.tensor([-math.log(0.75), math.log(4)]))  # uniform: unsure
    assert torch.allclose(x[1, 0], torch.tensor(-math.log(0.01)))  # 1 - max pi = 3 / 300
    assert x[2].tolist() == [StopHead.cap, 0.0]  # certain beyond float32: capped, finite


@pytest.mark.parametrize("stop_input", ["confidence", "core"])
def test_a_stop_head_does_not_change_the_other_weights_and_its_loss_trains_only_it(stop_input):
    torch.manual_seed(0)
    plain = HapticAttentionModel(HamConfig(glances=3))
    torch.manual_seed(0)
    with_stop = HapticAttentionModel(HamConfig(glances=3, stop=True, stop_input=stop_input))
    for name, p in plain.state_dict().items():
        assert torch.equal(p, with_stop.state_dict()[name]), name  # the same initial weights
    source, _ = make_source(None, WorldConfig())
    env = HapticEnv(source, batch_size=8, seed=0)
    episode = with_stop(env, env.sample_objects(), torch.Generator().manual_seed(0))
    assert episode.stop_logits.shape == (3, 8)
    for learner in ("value", "reinforce"):
        with_stop.zero_grad()
        loss = stop_loss(episode, 0.1, torch.Generator().manual_seed(1), learner)
        assert loss.stop_at.min() >= 1 and loss.stop_at.max() <= 3
        loss.total.backward(retain_graph=True)
        trained = {
            n
            for n, p in with_stop.named_parameters()
            if p.grad is not None and p.grad.abs().sum() > 0
        }
        assert trained and all(n.startswith("stop_head.") for n in trained), learner


def test_a_config_written_before_stop_input_loads_its_linear_head():
    assert HamConfig.from_dict({"stop": True}).stop_input == "core"
    assert HamConfig.from_dict({"stop": True, "stop_input": "confidence"}).stop_input == (
        "confidence"
    )
    assert HamConfig(stop=True).stop_input == "confidence"
    with pytest.raises(HamError, match="stop_input"):
        HamConfig(stop=True, stop_input="guess")


def test_stop_configs_and_metrics(tmp_path):
    with pytest.raises(HamError, match="learned stop \\(--stop\\) with learner 'hybrid'"):
        TrainConfig(model=HamConfig(stop=True))
    with pytest.raises(HamError, match="glance_cost = 0.1 without a learned stop"):
        TrainConfig(learner="info", glance_cost=0.1)
    with pytest.raises(HamError, match="glance_cost = -1"):
        TrainConfig(learner="info", model=HamConfig(stop=True), glance_cost=-1.0)
    config = TrainConfig(
        model=HamConfig(glances=3, stop=True), learner="info", optimizer="adam", lr=3e-3,
        glance_cost=0.1, steps=4, batch_size=8, eval_every=2, eval_batches=2,
    )  # fmt: skip
    m = train(config, tmp_path / "run", progress=False)
    assert 1 <= m["mean_glances"] <= 3 and 0 <= m["stop_accuracy"] <= 1
    assert all("mean_glances" in row for row in m["history"])
    assert load_run(tmp_path / "run").config.stop_learner == "value"
    with pytest.raises(HamError, match="stop_learner"):
        TrainConfig(learner="info", model=HamConfig(stop=True), stop_learner="guess")


def test_the_hindsight_stop_takes_the_best_later_payoff_as_the_value_of_continuing():
    # the head goes on at glance 2 in both episodes: "value" credits glance 1 with W_2 = g_3,
    # "hindsight" with the best later payoff max(g_2, g_3)
    episode = _hand_episode([[-1.0, -1.0], [-1.0, -1.0], [0.0, 0.0]])
    d = episode.stop_logits.detach()[:2]
    for learner, first in (("value", [-0.1 - 0.7, -0.1 - 0.7]), ("hindsight", [-0.9, -0.8])):
        target = torch.tensor([first, [0.1, -0.9]])
        loss = stop_loss(episode, 0.1, learner=learner)
        assert torch.allclose(loss.total, ((d - target) ** 2).mean()), learner
