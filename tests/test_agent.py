"""The HAM's parts: shapes, parameter counts, the truncated Gaussian, detaches, the environment."""

from __future__ import annotations

import math

import pytest
import torch

from ham.errors import HamError
from ham.learn.environment import HapticEnv
from ham.model.agent import HamConfig, HapticAttentionModel, count_parameters
from ham.model.core import LSTMCore, MLPCore
from ham.model.location_net import LocationNetwork, truncated_normal, uniform_locations
from ham.model.policy import UniformPolicy
from ham.model.tactile_net import TactileNetwork
from ham.world.config import WorldConfig, make_simulator
from ham.world.source import OnlineSource, TableSource, make_source


@pytest.fixture(scope="module")
def env() -> HapticEnv:
    source, _ = make_source(None, WorldConfig())
    return HapticEnv(source, batch_size=8, seed=3)


# --------------------------------------------------------------------------- parameter counts
def test_parameter_count_default_and_authors_layout():
    # Ours: the authors' LSTM model plus a bias on every dense layer (docs/agent.md).
    assert count_parameters(HapticAttentionModel(HamConfig())) == 643_081
    # Without the dense biases: exactly the authors' LSTM model (docs/sources.md): 642,432.
    assert count_parameters(HapticAttentionModel(HamConfig(bias=False))) == 642_432


def test_parameter_count_parts():
    m = HapticAttentionModel(HamConfig(bias=False))
    assert count_parameters(m.tactile) == 256 * 64 + 2 * 64 + 128 * 256 + 256 * 256
    assert count_parameters(m.core) == 4 * 256 * (256 + 256) + 4 * 256
    assert count_parameters(m.location) == 4 * 256
    assert count_parameters(m.classifier) == 256 * 4
    assert count_parameters(m.baseline) == 256
    assert "total" in m.describe()


def test_random_policy_has_no_location_network():
    m = HapticAttentionModel(HamConfig(policy="random"))
    assert isinstance(m.location, UniformPolicy) and count_parameters(m.location) == 0
    assert count_parameters(m) == 643_081 - 4 * 256 - 4


def test_he_normal_init_zero_bias():
    torch.manual_seed(0)
    m = HapticAttentionModel(HamConfig())
    w = m.core.gates.weight
    assert w.std().item() == pytest.approx(math.sqrt(2 / w.shape[1]), rel=0.05)
    for mod in m.modules():
        if isinstance(mod, torch.nn.Linear) and mod.bias is not None:
            assert torch.count_nonzero(mod.bias) == 0


@pytest.mark.parametrize(
    "kw",
    [
        {"glances": 0},
        {"core": "gru"},
        {"combiner": "film"},
        {"policy": "greedy"},
        {"std_activation": "exp"},
        {"lstm_activation": "sigmoid"},
        {"n_objects": 1},
    ],
)
def test_bad_config_raises_ham_error(kw):
    with pytest.raises(HamError):
        HamConfig(**kw)


# --------------------------------------------------------------------------- tactile network, core
@pytest.mark.parametrize(
    "combiner, width", [("concat2", 256), ("concat1", 256), ("add", 64), ("mul", 64)]
)
def test_combiners(combiner, width):
    net = TactileNetwork(combiner=combiner)
    g = net(torch.rand(5, 256), torch.rand(5, 2))
    assert g.shape == (5, width) and net.out_features == width
    assert (g >= 0).all()  # every combiner of ReLU features is non-negative


def test_add_and_mul_need_equal_widths():
    with pytest.raises(HamError, match="what_units == where_units"):
        TactileNetwork(combiner="mul", what_units=64, where_units=32)


def test_lstm_and_mlp_core():
    lstm, mlp = LSTMCore(10, 16), MLPCore(10, 16)
    x = torch.rand(3, 10)
    h, state = lstm(x, lstm.initial_state(3, x))
    assert h.shape == (3, 16) and len(state) == 2
    h, state = mlp(x, mlp.initial_state(3, x))
    assert h.shape == (3, 16) and state == ()
    relu = LSTMCore(10, 16, activation="relu")
    assert relu(x, relu.initial_state(3, x))[0].shape == (3, 16)


def _grad_of_first_glance(config: HamConfig) -> torch.Tensor:
    torch.manual_seed(0)
    m = HapticAttentionModel(config)
    p = torch.rand(config.glances, 4, 256, requires_grad=True)
    q = torch.rand(config.glances, 4, 2) * 2 - 1
    m.replay(p, q).logits[-1].sum().backward()
    return p.grad[0]


def test_full_bptt_reaches_the_first_glance():
    assert _grad_of_first_glance(HamConfig(glances=3)).abs().sum() > 0


def test_truncated_bptt_and_mlp_core_see_only_the_last_glance():
    assert _grad_of_first_glance(HamConfig(glances=3, truncate_bptt=True)).abs().sum() == 0
    assert _grad_of_first_glance(HamConfig(glances=3, core="mlp")).abs().sum() == 0


# --------------------------------------------------------------------------- location network
def test_truncated_normal_stays_in_range_and_is_finite():
    g = torch.Generator().manual_seed(0)
    mu = torch.tensor([-1.0, 1.0, 0.0, 0.999, -0.5, 0.0]).repeat(2000, 1)
    sigma = torch.tensor([1e-6, 1e-3, 50.0, 0.01, 0.3, 1e-9]).repeat(2000, 1)
    q = truncated_normal(mu, sigma, g)
    assert torch.isfinite(q).all()
    assert (q.abs() <= 1).all()
    assert not q.requires_grad
    # A diverged network's NaN parameters still give valid poses (the loss then shows the NaN).
    nan = torch.full((3, 2), float("nan"))
    assert torch.isfinite(truncated_normal(nan, torch.ones(3, 2), g)).all()


def test_truncated_normal_equals_resampling_in_distribution():
    g = torch.Generator().manual_seed(1)
    mu, sigma = 0.7, 0.6
    q = truncated_normal(torch.full((200_000,), mu), torch.full((200_000,), sigma), g)
    # Reference: resample N(mu, sigma) until inside [-1, 1] (rejection).
    x = torch.randn(800_000, generator=g) * sigma + mu
    ref = x[x.abs() <= 1][:200_000]
    assert q.mean().item() == pytest.approx(ref.mean().item(), abs=0.005)
    assert q.std().item() == pytest.approx(ref.std().item(), abs=0.005)
    assert (q > 0.9).float().mean().item() == pytest.approx(
        (ref > 0.9).float().mean().item(), abs=0.005
    )


def test_truncated_normal_is_seeded():
    mu, sigma = torch.zeros(10, 2), torch.ones(10, 2)
    a = truncated_normal(mu, sigma, torch.Generator().manual_seed(5))
    b = truncated_normal(mu, sigma, torch.Generator().manual_seed(5))
    assert torch.equal(a, b)


def test_location_network_detaches_the_core_and_bounds_its_outputs():
    net = LocationNetwork(16)
    tau = torch.rand(4, 16, requires_grad=True)
    mu, sigma = net(tau)
    assert mu.shape == sigma.shape == (4, 2)
    assert (mu.abs() <= 1).all() and (sigma > 0).all()
    (mu.sum() + sigma.sum()).backward()
    assert tau.grad is None  # the core output enters detached
    assert net.mu.weight.grad is not None
    sig = LocationNetwork(16, std_activation="sigmoid")
    assert (sig(tau)[1] < 1 + sig.sigma_min).all()


def test_uniform_locations():
    q = uniform_locations(10_000, torch.Generator().manual_seed(0))
    assert q.shape == (10_000, 2) and (q.abs() <= 1).all()
    assert q.mean().abs().max() < 0.03


# --------------------------------------------------------------------------- episodes
def test_episode_shapes_and_first_glance_random(env):
    torch.manual_seed(0)
    m = HapticAttentionModel(HamConfig(glances=4))
    objects = env.sample_objects()
    ep = m(env, objects, torch.Generator().manual_seed(0))
    assert ep.locations.shape == (4, 8, 2)
    assert ep.logits.shape == (4, 8, 4)
    assert ep.baselines.shape == (4, 8)
    assert ep.policy.batch_shape == (3, 8) and ep.policy.mode().shape == (3, 8, 2)
    assert ep.policy.trainable
    assert not ep.locations.requires_grad
    # The first glance is uniform: the same draw as uniform_locations from the same seed.
    assert torch.equal(ep.locations[0], uniform_locations(8, torch.Generator().manual_seed(0)))


def test_random_policy_episode(env):
    m = HapticAttentionModel(HamConfig(glances=3, policy="random"))
    ep = m(env, env.balanced_objects(0), torch.Generator().manual_seed(0))
    assert ep.policy.batch_shape == (2, 8) and not ep.policy.trainable
    assert ep.policy.mode() is None  # no mode: the random policy samples when evaluated too
    assert ep.locations.shape == (3, 8, 2)


def test_same_seed_same_numbers(env):
    out = []
    for _ in range(2):
        torch.manual_seed(7)
        m = HapticAttentionModel(HamConfig(glances=3))
        ep = m(env, env.balanced_objects(0), torch.Generator().manual_seed(7))
        out.append(ep.logits)
    assert torch.equal(out[0], out[1])


# --------------------------------------------------------------------------- environment
def test_environment_batches(env):
    a = HapticEnv(env.source, batch_size=64, seed=11)
    b = HapticEnv(env.source, batch_size=64, seed=11)
    ids = a.sample_objects()
    assert torch.equal(ids, b.sample_objects())
    assert ids.dtype == torch.long and ids.min() >= 0 and ids.max() < 4
    assert not torch.equal(ids, a.sample_objects())  # a fresh batch every step
    counts = torch.bincount(a.balanced_objects(3), minlength=4)
    assert (counts == 16).all()


def test_environment_state_round_trip(env):
    a = HapticEnv(env.source, batch_size=16, seed=2)
    state = a.state_dict()
    first = a.sample_objects()
    a.load_state_dict(state)
    assert torch.equal(first, a.sample_objects())


def test_glances_are_l2_normalized(env):
    q = uniform_locations(8, torch.Generator().manual_seed(0))
    p = env.glance(env.balanced_objects(0), q)
    norms = p.norm(dim=-1)
    assert p.shape == (8, 256)
    assert torch.all(((norms - 1).abs() < 1e-5) | (norms == 0))


def test_bad_environment_arguments(env):
    with pytest.raises(HamError, match="normalization"):
        HapticEnv(env.source, normalization="max")
    with pytest.raises(HamError, match="batch_size"):
        HapticEnv(env.source, batch_size=0)


def test_table_source_matches_online_at_grid_points(tmp_path):
    from ham.world.table import GlanceTable, build_table

    world = WorldConfig()
    path = build_table(world, 5, tmp_path / "t.h5", progress=False)
    table = TableSource(GlanceTable.load(path))
    online = OnlineSource(make_simulator(world))
    grid = torch.linspace(-1, 1, 5)
    ids = torch.arange(4).repeat_interleave(25)
    qx = grid.repeat_interleave(5).repeat(4)
    qp = grid.repeat(20)
    assert torch.allclose(table.lookup(ids, qx, qp), online.lookup(ids, qx, qp), atol=1e-3)
    # Off the grid: the closest grid point (the paper's lookup).
    near = table.lookup(ids, (qx + 0.1).clamp(-1, 1), qp)
    assert torch.equal(near, table.lookup(ids, qx, qp))
