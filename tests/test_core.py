"""The cores: the transformer over the glances so far (shapes, causality, the masked
full-sequence transformer it equals, bad options, a model and a resumed run with it)."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from ham.errors import HamError
from ham.model.agent import HamConfig, HapticAttentionModel
from ham.model.core import CORES, TransformerCore, glance_position, make_core


def _steps(core: nn.Module, g: torch.Tensor) -> torch.Tensor:
    state = core.initial_state(g.shape[1], g)
    out = []
    for s in range(g.shape[0]):
        tau, state = core(g[s], state)
        out.append(tau)
    return torch.stack(out)


def test_transformer_is_registered_with_its_shapes():
    assert {"lstm", "mlp", "transformer"} <= set(CORES)
    torch.manual_seed(0)
    core = make_core("transformer", 10, 16, layers=3, heads=2)
    assert isinstance(core, TransformerCore) and len(core.blocks) == 3
    g = torch.randn(5, 4, 10)
    state = core.initial_state(4, g)
    assert [tuple(t.shape) for t in state] == [(4, 0, 16)] * 3
    tau, state = core(g[0], state)
    assert tau.shape == (4, 16) and [tuple(t.shape) for t in state] == [(4, 1, 16)] * 3
    assert _steps(core, g).shape == (5, 4, 16)


def test_transformer_is_causal_and_remembers():
    """Glance s's output depends on glances 1..s and on nothing later."""
    torch.manual_seed(0)
    core = make_core("transformer", 10, 16)
    g = torch.randn(6, 3, 10)
    base = _steps(core, g)
    later = g.clone()
    later[3] += 1.0  # change glance 4
    out = _steps(core, later)
    assert torch.equal(out[:3], base[:3])
    assert not torch.allclose(out[3:], base[3:])  # glance 4 and every one after it see it
    earlier = g.clone()
    earlier[0] += 1.0  # the last glance still sees the first
    assert not torch.allclose(_steps(core, earlier)[-1], base[-1])


def test_stepwise_transformer_equals_the_masked_full_sequence():
    """One glance at a time with the cached layer inputs = a causal mask over the sequence."""
    torch.manual_seed(1)
    core = make_core("transformer", 7, 8, layers=2, heads=2)
    g = torch.randn(5, 3, 7)
    x = core.embed(g) + torch.stack([glance_position(s, 8, g) for s in range(5)])[:, None]
    mask = torch.triu(torch.ones(5, 5, dtype=torch.bool), diagonal=1)  # True: may not attend
    x = x.transpose(0, 1)  # (B, S, D)
    for block in core.blocks:
        h = block.norm1(x)
        x = x + block.attention(h, h, h, attn_mask=mask, need_weights=False)[0]
        x = x + block.mlp(block.norm2(x))
    full = core.norm(x).transpose(0, 1)
    assert torch.allclose(_steps(core, g), full, atol=1e-5)


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(layers=0), "transformer layers = 0"),
        (dict(heads=3), "transformer heads = 3"),
    ],
)
def test_bad_transformer_options(kw, match):
    with pytest.raises(HamError, match=match):
        make_core("transformer", 10, 16, **kw)
    with pytest.raises(HamError, match="transformer_layers = 0"):
        HamConfig(core="transformer", transformer_layers=0)


def test_a_model_plays_and_trains_with_the_transformer_core():
    from ham.learn.environment import HapticEnv
    from ham.world.config import WorldConfig
    from ham.world.source import make_source

    source, _ = make_source(None, WorldConfig())
    env = HapticEnv(source, batch_size=4, seed=0)
    torch.manual_seed(0)
    model = HapticAttentionModel(HamConfig(glances=3, core="transformer", hidden_units=32))
    episode = model(env, env.sample_objects(), torch.Generator().manual_seed(0))
    assert episode.logits.shape == (3, 4, 4) and episode.policy.mu.shape == (2, 4, 2)
    episode.logits.sum().backward()
    assert model.core.embed.weight.grad.abs().sum() > 0


def test_transformer_run_with_epochs_resumes_bit_identically(tmp_path):
    from ham.learn.train import TrainConfig, load_run, resume, train

    def config(steps):
        model = HamConfig(glances=3, core="transformer", hidden_units=32, first_glance="learned")
        return TrainConfig(model=model, steps=steps, batch_size=8, eval_every=2, eval_batches=2,
                           seed=3, learner="info", optimizer="adam", lr=3e-3, epochs=3)  # fmt: skip

    full = train(config(6), tmp_path / "full", progress=False)
    train(config(4), tmp_path / "half", progress=False)
    assert resume(tmp_path / "half", steps=6, progress=False) == full
    a, b = load_run(tmp_path / "full"), load_run(tmp_path / "half")
    for (n, p), (_, q) in zip(
        a.agent.state_dict().items(), b.agent.state_dict().items(), strict=True
    ):
        assert torch.equal(p, q), n
