"""The off-policy learner (``--learner sac``): the truncated Gaussian's exact density and its
reparametrized sample, what each loss trains, the replay buffer, a real run on ap_gym that
checkpoints and resumes bit-identically, and the options it refuses."""

from __future__ import annotations

import json
import math

import pytest
import torch

from ham.errors import HamError
from ham.learn.off_policy import (
    ReplayBuffer,
    SacState,
    sac_losses,
    truncated_log_prob,
    truncated_rsample,
)
from ham.learn.train import GlanceRecorder, TrainConfig, load_run, resume, train
from ham.model.agent import HamConfig, HapticAttentionModel
from tests.conftest import one_line_error

CS15 = "ap_gym:CircleSquare-s15-nograd-v0"


# --------------------------------------------------------------------------- the density
@pytest.mark.parametrize("mu, sigma", [(0.0, 0.3), (0.9, 0.5), (-1.0, 0.05), (0.2, 5.0)])
def test_truncated_density_integrates_to_one_and_the_sample_follows_it(mu, sigma):
    grid = torch.linspace(-1, 1, 20001, dtype=torch.float64)[:, None]
    m = torch.full_like(grid, mu)
    s = torch.full_like(grid, sigma)
    density = truncated_log_prob(grid, m, s).exp()
    assert torch.trapezoid(density, grid[:, 0]).item() == pytest.approx(1.0, abs=1e-4)
    # the sample's mean is the density's mean
    g = torch.Generator().manual_seed(0)
    n = 20000
    q, logp = truncated_rsample(torch.full((n, 1), mu), torch.full((n, 1), sigma), g)
    assert q.min() >= -1 and q.max() <= 1
    mean = torch.trapezoid(density * grid[:, 0], grid[:, 0]).item()
    assert q.mean().item() == pytest.approx(mean, abs=4 * q.std().item() / math.sqrt(n) + 1e-3)
    assert torch.allclose(logp, truncated_log_prob(q, torch.full_like(q, mu),
                                                   torch.full_like(q, sigma)))  # fmt: skip


@pytest.mark.parametrize("m, s", [(0.0, 0.3), (0.7, 0.8), (-2.0, 1.5)])
def test_squashed_density_integrates_to_one_and_matches_its_sample(m, s):
    from ham.model.policy import SquashedGaussian

    x = torch.linspace(-1 + 1e-6, 1 - 1e-6, 400001, dtype=torch.float64)[:, None]
    d = SquashedGaussian(torch.full_like(x, m), torch.full_like(x, s))
    assert torch.trapezoid(d.log_prob(x).exp(), x[:, 0]).item() == pytest.approx(1.0, abs=1e-3)
    big = SquashedGaussian(torch.full((5000, 2), m), torch.full((5000, 2), s))
    q, logp = big.rsample(torch.Generator().manual_seed(2))
    inside = q.abs().max(-1).values < 0.999  # float32's atanh near +-1 is coarse
    assert torch.allclose(logp[inside], big.log_prob(q)[inside], atol=1e-3)
    assert q.abs().max() <= 1
    assert torch.allclose(big.mode(), torch.tanh(torch.full((5000, 2), m)))
    assert q.mean().item() == pytest.approx(torch.tanh(m + s * torch.randn(200000)).mean().item(),
                                            abs=0.03)  # fmt: skip


def test_truncated_sample_stops_moving_with_the_mean_as_sigma_grows():
    """Why the sac learner's policy is the squashed Gaussian: the truncated Gaussian's
    reparametrized sample forgets its mean when its spread is wide, the squashed one does not."""
    from ham.model.policy import SquashedGaussian

    for sigma, expect_small in ((0.2, False), (20.0, True)):
        mu = torch.zeros(1000, 1, requires_grad=True)
        q, _ = truncated_rsample(mu, torch.full((1000, 1), sigma), torch.Generator().manual_seed(0))
        (g,) = torch.autograd.grad(q.sum(), [mu])
        assert (g.mean().item() < 0.01) == expect_small, (sigma, g.mean())
    m = torch.zeros(1000, 1, requires_grad=True)
    q, _ = SquashedGaussian(m, torch.full((1000, 1), 20.0)).rsample(
        torch.Generator().manual_seed(0)
    )
    (g,) = torch.autograd.grad(q.sum(), [m])
    assert g.mean().item() > 0.01


def test_rsample_is_differentiable_in_the_mean_and_the_spread():
    mu = torch.tensor([[0.1, -0.4]], requires_grad=True)
    sigma = torch.tensor([[0.2, 0.7]], requires_grad=True)
    q, logp = truncated_rsample(mu, sigma, torch.Generator().manual_seed(1))
    gm, gs = torch.autograd.grad(q.sum(), [mu, sigma])
    assert bool((gm > 0).all()) and bool(torch.isfinite(gs).all()) and bool((gs != 0).any())
    assert logp.shape == (1,)


# --------------------------------------------------------------------------- the buffer
def test_replay_buffer_overwrites_the_oldest_and_round_trips():
    buf = ReplayBuffer(5)
    for i in range(3):  # 3 batches of 2: the first episode is overwritten
        buf.add(objects=torch.tensor([2 * i, 2 * i + 1]), x=torch.arange(2.0)[:, None] + 10 * i,
                heights=None)  # fmt: skip
    assert buf.size == 5 and buf.next == 1
    assert buf.data["objects"].tolist() == [5, 1, 2, 3, 4]
    assert "heights" not in buf.data
    other = ReplayBuffer(5)
    other.load_state_dict(buf.state_dict())
    g1, g2 = torch.Generator().manual_seed(3), torch.Generator().manual_seed(3)
    a, b = buf.sample(7, g1), other.sample(7, g2)
    assert all(torch.equal(a[k], b[k]) for k in a)
    with pytest.raises(HamError, match="replay_size = 4"):
        ReplayBuffer(4).load_state_dict(buf.state_dict())
    with pytest.raises(HamError, match="replay_size = 0"):
        ReplayBuffer(0)


# --------------------------------------------------------------------------- what trains what
@pytest.mark.parametrize(
    "first_glance, critic_trains_core", [("random", False), ("learned", False), ("random", True)]
)
def test_the_parts_train_disjoint_weights(first_glance, critic_trains_core):
    """The classification reaches the tactile network, the core and the classifier; the actor's
    loss only the location network; the critic's only the critic (and, with
    ``critic_trains_core``, the tactile network and the core); the temperature's only
    ``log alpha``; nothing reaches the baseline head."""
    from ham.learn.environment import HapticEnv
    from ham.world.config import WorldConfig
    from ham.world.source import make_source

    source, _ = make_source(None, WorldConfig())
    env = HapticEnv(source, batch_size=4, seed=0)
    model = HamConfig(glances=3, first_glance=first_glance, policy="squashed")
    config = TrainConfig(model=model, learner="sac", optimizer="adam", replay_size=16, seed=1)
    torch.manual_seed(0)
    agent = HapticAttentionModel(config.model)
    sac = SacState(agent, config, torch.device("cpu"))
    objects = env.sample_objects()
    rec = GlanceRecorder(env)
    with torch.no_grad():
        played = agent(rec, objects, torch.Generator().manual_seed(0))
    sac.buffer.add(pressures=torch.stack(rec.pressures, 1), where=torch.stack(rec.where, 1),
                   locations=played.locations.transpose(0, 1), objects=objects)  # fmt: skip
    loss = sac_losses(agent, sac, sac.buffer.sample(4, sac.generator), 0.9, critic_trains_core)
    params = {f"agent.{n}": p for n, p in agent.named_parameters()}
    params.update({f"critic.{n}": p for n, p in sac.critic.named_parameters()})
    params["log_alpha"] = sac.log_alpha

    def owner(name: str) -> str:
        part = name.split(".")[1] if name.startswith("agent.") else name.split(".")[0]
        return {"tactile": "encoder", "core": "encoder"}.get(part, part)

    expected = {"classification": {"encoder", "classifier"}, "actor": {"location"},
                "critic": {"critic", "encoder"} if critic_trains_core else {"critic"},
                "alpha": {"log_alpha"}}  # fmt: skip
    for part, owners in expected.items():
        grads = torch.autograd.grad(
            getattr(loss, part), list(params.values()), retain_graph=True, allow_unused=True
        )
        reached = {owner(n) for n, g in zip(params, grads, strict=True)
                   if g is not None and bool(g.abs().sum() > 0)}  # fmt: skip
        assert reached == owners, (part, reached)
    assert torch.equal(loss.total, loss.classification + loss.actor)
    assert all(p.requires_grad for p in sac.critic.parameters())  # unfrozen after the actor


# --------------------------------------------------------------------------- a real run
def _config(**kw) -> TrainConfig:
    from ham.learn.ap_adapter import ApGymConfig
    from ham.learn.train import fit_to_ap_gym

    model = HamConfig(glances=3, hidden_units=32, combine_units=32, what_units=16,
                      where_units=16, policy="squashed")  # fmt: skip
    base = dict(model=model, steps=4, batch_size=4, eval_every=2, eval_batches=1, seed=3,
                learner="sac", optimizer="adam", lr=3e-3, gamma=0.9, replay_batch=6,
                sac_updates=2, replay_size=10)  # fmt: skip
    base.update(kw)
    env = ApGymConfig(CS15, actions="relative", glimpse="centered")
    return fit_to_ap_gym(TrainConfig(normalization="none", **base), env)


def test_a_diverged_sac_run_is_a_divergence(tmp_path):
    """A NaN loss of the sac learner is a :class:`DivergedError` as the other learners' are (a
    plain HamError before: a grid retried the run, which diverged again)."""
    pytest.importorskip("ap_gym")
    from ham.errors import DivergedError

    with pytest.raises(DivergedError, match=r"^the sac learner diverged: its \w+ loss is nan"):
        train(_config(lr=1e30), tmp_path / "r", progress=False)
    assert not (tmp_path / "r").exists()  # at its first step: no run left


def test_sac_run_on_ap_gym_checkpoints_and_resumes_bit_identically(tmp_path):
    pytest.importorskip("ap_gym")
    full = train(_config(), tmp_path / "full", progress=False)
    train(_config(steps=2), tmp_path / "half", progress=False)
    resumed = resume(tmp_path / "half", steps=4, progress=False)
    assert resumed == full  # every float of the history
    assert full["env_steps"] == 4 * 4 * 3
    assert full["config"]["learner"] == "sac"
    a, b = load_run(tmp_path / "full"), load_run(tmp_path / "half")
    try:
        assert a.sac.buffer.size == 10  # 4 batches of 4 episodes, the oldest overwritten
        for (n, p), (_, q) in zip(a.agent.state_dict().items(), b.agent.state_dict().items(),
                                  strict=True):  # fmt: skip
            assert torch.equal(p, q), n
        sa, sb = a.sac.state_dict(), b.sac.state_dict()
        for part in ("critic", "target"):
            for n, p in sa[part].items():
                assert torch.equal(p, sb[part][n]), (part, n)
        assert torch.equal(sa["log_alpha"], sb["log_alpha"])
        assert sa["log_alpha"].item() != math.log(0.1)  # the temperature was tuned
        assert all(torch.equal(v, sb["buffer"]["data"][k]) for k, v in sa["buffer"]["data"].items())
        # the baseline head is not the sac learner's: untouched since the initial weights
        torch.manual_seed(3)
        init = HapticAttentionModel(a.config.model)
        assert torch.equal(init.baseline.dense.weight, a.agent.baseline.dense.weight)
        assert not torch.equal(init.location.mu.weight, a.agent.location.mu.weight)
    finally:
        a.close()
        b.close()


# --------------------------------------------------------------------------- refused
@pytest.mark.parametrize(
    "kw, match",
    [
        ({"model": HamConfig(policy="random")}, "policy = 'random' with learner 'sac'"),
        ({"move_cost": 0.3}, "move_cost = 0.3 with learner 'sac'"),
        ({"entropy_coef": 0.01}, "entropy_coef = 0.01 with learner 'sac'"),
        ({"epochs": 2}, "epochs = 2 with learner 'sac'"),
        ({"reward_glances": "all"}, "reward_glances = 'all' with learner 'sac'.*--learner hybrid"),
        ({"reward_discount": 0.99}, "reward_discount = 0.99 with learner 'sac'"),
        ({"glance_reduction": "mean"}, "glance_reduction = 'mean' with learner 'sac'"),
        ({"model": HamConfig(stop=True)}, "a learned stop"),
        ({"replay_batch": 0}, "replay_batch = 0"),
        ({"replay_size": 2.5}, "replay_size = 2.5"),
        ({"sac_updates": True}, "sac_updates = True"),
        ({"target_tau": 0.0}, "target_tau = 0.0"),
        ({"target_tau": 1.5}, "target_tau = 1.5"),
        ({"init_alpha": -1.0}, "init_alpha = -1.0"),
        ({"target_entropy": float("nan")}, "target_entropy = nan"),
        ({"critic_trains_core": 1}, "critic_trains_core = 1"),
    ],
)
def test_bad_sac_options_are_refused_by_name(kw, match):
    with pytest.raises(HamError, match=match):
        TrainConfig(**{"learner": "sac", **kw})


def test_cli_refuses_bad_sac_options_in_one_line(ham_cli, tmp_path):
    r = ham_cli("train", "--learner", "sac", "--replay-batch", "0", "--out", str(tmp_path / "r"))
    assert "replay_batch = 0" in one_line_error(r)
    r = ham_cli("train", "--learner", "sac", "--policy", "random", "--out", str(tmp_path / "r"))
    assert "policy = 'random'" in one_line_error(r)
    assert not (tmp_path / "r").exists()


def test_config_round_trip_and_older_configs_load():
    c = TrainConfig(learner="sac", replay_batch=8, target_entropy=-1.5)
    assert TrainConfig.from_dict(json.loads(json.dumps(c.to_dict()))) == c
    old = TrainConfig().to_dict()
    for name in ("replay_size", "replay_batch", "sac_updates", "target_tau", "init_alpha",
                 "target_entropy", "critic_trains_core"):  # fmt: skip
        old.pop(name)
    assert TrainConfig.from_dict(old) == TrainConfig()  # written before the sac learner
