"""Location policies behind one interface (ham.model.policy): the Gaussian and uniform
distributions, the registry, and a new policy that trains through the loss unchanged."""

from __future__ import annotations

import math

import pytest
import torch
from torch import nn

from ham.errors import HamError
from ham.learn.train import TrainConfig, load_run, train
from ham.model.agent import HamConfig, HapticAttentionModel
from ham.model.location_net import gaussian_log_prob, truncated_normal, uniform_locations
from ham.model.policy import (
    POLICIES,
    GaussianPolicy,
    LocationPolicy,
    TruncatedGaussian,
    Uniform,
    UniformPolicy,
    make_policy,
    register_policy,
)


def test_registry_names_the_papers_policies():
    assert POLICIES["learned"] is GaussianPolicy and POLICIES["random"] is UniformPolicy
    with pytest.raises(HamError, match="policy = 'greedy'; accepted: learned, random"):
        HamConfig(policy="greedy")
    with pytest.raises(HamError, match="registered already"):
        register_policy("learned")(UniformPolicy)


def test_gaussian_distribution_is_the_location_network():
    torch.manual_seed(0)
    net = make_policy(HamConfig())
    tau = torch.randn(6, 256)
    dist = net.distribution(tau)
    mu, sigma = net(tau)
    assert torch.equal(dist.mu, mu) and torch.equal(dist.sigma, sigma)
    q = dist.sample(torch.Generator().manual_seed(4))
    assert torch.equal(q, truncated_normal(mu, sigma, torch.Generator().manual_seed(4)))
    assert torch.equal(dist.log_prob(q), gaussian_log_prob(q, mu, sigma).sum(-1))
    assert torch.equal(dist.mode(), mu.detach()) and not dist.mode().requires_grad
    normal = torch.distributions.Normal(mu, sigma)
    assert torch.allclose(dist.entropy(), normal.entropy().sum(-1))
    assert torch.allclose(dist.log_prob(q), normal.log_prob(q).sum(-1))
    g = torch.Generator().manual_seed(1)
    assert torch.equal(dist.act(g, greedy=True), dist.mode())
    stacked = TruncatedGaussian.stack([dist, dist, dist])
    assert stacked.batch_shape == (3, 6) and stacked.log_prob(q.expand(3, 6, 2)).shape == (3, 6)


def test_uniform_distribution():
    dist = UniformPolicy().distribution(torch.zeros(5, 256))
    assert dist.batch_shape == (5,) and not dist.trainable and dist.mode() is None
    q = dist.sample(torch.Generator().manual_seed(2))
    assert torch.equal(q, uniform_locations(5, torch.Generator().manual_seed(2)))
    # no mode: greedy evaluation samples, from the same stream
    assert torch.equal(dist.act(torch.Generator().manual_seed(2), greedy=True), q)
    assert torch.allclose(dist.log_prob(q), torch.full((5,), -math.log(4.0)))
    assert torch.allclose(dist.entropy(), torch.full((5,), math.log(4.0)))
    stacked = Uniform.stack([dist, dist])
    assert stacked.batch_shape == (2, 5)
    many = stacked.sample(torch.Generator().manual_seed(0))
    assert many.shape == (2, 5, 2) and (many.abs() <= 1).all()


class StateFreeGaussian(LocationPolicy):
    """A new policy, one class: a Gaussian whose mean and spread ignore the core."""

    @classmethod
    def from_config(cls, config) -> StateFreeGaussian:
        return cls()

    def __init__(self) -> None:
        super().__init__()
        self.mu = nn.Parameter(torch.zeros(2))
        self.log_sigma = nn.Parameter(torch.full((2,), -0.5))

    def distribution(self, tau: torch.Tensor) -> TruncatedGaussian:
        shape = (tau.shape[0], 2)
        return TruncatedGaussian(
            torch.tanh(self.mu).expand(shape), self.log_sigma.exp().expand(shape)
        )


@pytest.fixture
def state_free():
    register_policy("state_free")(StateFreeGaussian)
    try:
        yield "state_free"
    finally:
        del POLICIES["state_free"]


def test_a_new_policy_is_one_class_and_trains_through_the_loss(tmp_path, state_free):
    model = HapticAttentionModel(HamConfig(glances=2, policy=state_free))
    assert isinstance(model.location, StateFreeGaussian)
    config = TrainConfig(model=HamConfig(glances=2, policy=state_free), steps=4, batch_size=8,
                         eval_every=2, eval_batches=1, seed=1, lr=0.05)  # fmt: skip
    metrics = train(config, tmp_path / "r", progress=False)
    assert metrics["steps"] == 4
    assert metrics["history"][-1]["mu_mean"] is not None  # evaluated at the policy's mode
    run = load_run(tmp_path / "r")
    # REINFORCE moved the new policy's own weights (they start at 0 and -0.5)
    assert run.agent.location.mu.abs().sum() > 0
    assert (run.agent.location.log_sigma != -0.5).any()
