"""The learned stop: classify-now or glance-again after each glance (ham.learn.stopping)."""

from __future__ import annotations

import pytest
import torch

from ham.errors import HamError
from ham.learn.environment import HapticEnv
from ham.learn.stopping import stop_glances, stop_loss
from ham.learn.train import TrainConfig, train
from ham.model.agent import HamConfig, HapticAttentionModel
from ham.world.config import WorldConfig
from ham.world.source import make_source


def test_stop_glances_take_the_first_stop_and_force_the_last():
    logits = torch.tensor([[-9.0, 9.0, -9.0], [9.0, -9.0, -9.0], [-9.0, -9.0, -9.0]])  # (S=3, B=3)
    at, decide = stop_glances(logits, greedy=True)
    assert at.tolist() == [2, 1, 3]  # episode 2 never stops early: the last glance is forced
    assert decide[-1].tolist() == [1.0, 1.0, 1.0]


def test_a_stop_head_does_not_change_the_other_weights_and_its_loss_trains_only_it():
    torch.manual_seed(0)
    plain = HapticAttentionModel(HamConfig(glances=3))
    torch.manual_seed(0)
    with_stop = HapticAttentionModel(HamConfig(glances=3, stop=True))
    for name, p in plain.state_dict().items():
        assert torch.equal(p, with_stop.state_dict()[name]), name  # the same initial weights
    source, _ = make_source(None, WorldConfig())
    env = HapticEnv(source, batch_size=8, seed=0)
    episode = with_stop(env, env.sample_objects(), torch.Generator().manual_seed(0))
    assert episode.stop_logits.shape == (3, 8)
    loss = stop_loss(episode, 0.1, torch.Generator().manual_seed(1))
    assert loss.stop_at.min() >= 1 and loss.stop_at.max() <= 3
    loss.total.backward()
    trained = {
        n for n, p in with_stop.named_parameters() if p.grad is not None and p.grad.abs().sum() > 0
    }
    assert trained and all(n.startswith("stop_head.") for n in trained)


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
