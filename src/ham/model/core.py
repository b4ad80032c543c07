"""The core network: integrates the glance features over the glance sequence.

Section "The Haptic Attention Model": an LSTM with hidden states of 256 units turns the glance
features ``g_1 .. g_s`` into the accumulated feature ``tau_{1:s}`` that the classifier, the location
network and the baseline read. The ablation of section "Experiments" replaces it by one dense
ReLU layer of the same size (the MLP core), which sees only the current glance.

Options from the authors' code (docs/sources.md, "The network"):

* ``activation="relu"``: ReLU instead of tanh for the cell input and the cell output;
* ``truncate_bptt=True``: the state enters each step detached from the graph, as in the authors'
  code, which runs the LSTM one glance at a time with the state fed back from outside the graph:
  the loss then reaches only the last glance's step (no backpropagation through time).

Beyond the paper, ``transformer`` (:class:`TransformerCore`): causal self-attention over the
glance tokens so far, the core of the APPLE study's best agents and of the MuJoCo follow-up.

The LSTM cell is written out (one dense layer over ``[g, h]`` with one bias vector, gates in the
order input, forget, cell, output), as in Keras/TensorFlow, so its parameter count matches the
authors' model (``4 * 256 * (256 + 256) + 4 * 256`` = 525,312).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn

from ham.errors import HamError, check_new_name, checked_arguments

ACTIVATIONS: tuple[str, ...] = ("tanh", "relu")

State = tuple[torch.Tensor, ...]


class LSTMCore(nn.Module):
    """``(h_s, c_s) = LSTM(g_s, (h_{s-1}, c_{s-1}))``; the output is ``h_s``."""

    def __init__(
        self,
        input_size: int,
        hidden_size: int = 256,
        activation: str = "tanh",
        truncate_bptt: bool = False,
        forget_bias: float = 1.0,
    ) -> None:
        super().__init__()
        if activation not in ACTIVATIONS:
            raise HamError(f"LSTM activation {activation!r}; accepted: {', '.join(ACTIVATIONS)}")
        self.hidden_size = hidden_size
        self.truncate_bptt = truncate_bptt
        self.forget_bias = forget_bias
        self.act = torch.tanh if activation == "tanh" else torch.relu
        self.gates = nn.Linear(input_size + hidden_size, 4 * hidden_size)

    def initial_state(self, batch: int, like: torch.Tensor) -> State:
        z = like.new_zeros(batch, self.hidden_size)
        return (z, z)

    def forward(self, g: torch.Tensor, state: State) -> tuple[torch.Tensor, State]:
        h, c = state
        if self.truncate_bptt:
            h, c = h.detach(), c.detach()
        i, f, u, o = self.gates(torch.cat([g, h], dim=-1)).chunk(4, dim=-1)
        c = torch.sigmoid(f + self.forget_bias) * c + torch.sigmoid(i) * self.act(u)
        h = torch.sigmoid(o) * self.act(c)
        return h, (h, c)


class MLPCore(nn.Module):
    """The memory-less ablation: ``tau_s = relu(W g_s + b)``; it keeps no state."""

    def __init__(self, input_size: int, hidden_size: int = 256, bias: bool = True) -> None:
        super().__init__()
        self.hidden_size = hidden_size
        self.dense = nn.Linear(input_size, hidden_size, bias=bias)

    def initial_state(self, batch: int, like: torch.Tensor) -> State:
        return ()

    def forward(self, g: torch.Tensor, state: State) -> tuple[torch.Tensor, State]:
        return torch.relu(self.dense(g)), state


class _Block(nn.Module):
    """One pre-norm transformer layer for the newest token: it attends to the layer's inputs of
    all glances so far (itself included), then a ReLU MLP; both residual."""

    def __init__(self, width: int, heads: int, ff_units: int, bias: bool) -> None:
        super().__init__()
        self.norm1 = nn.LayerNorm(width)
        self.attention = nn.MultiheadAttention(width, heads, bias=bias, batch_first=True)
        self.norm2 = nn.LayerNorm(width)
        self.mlp = nn.Sequential(
            nn.Linear(width, ff_units, bias=bias), nn.ReLU(), nn.Linear(ff_units, width, bias=bias)
        )

    def forward(self, x: torch.Tensor, history: torch.Tensor) -> torch.Tensor:
        """``x`` (B, D) the newest token, ``history`` (B, t, D) the inputs of glances 1..t."""
        q, kv = self.norm1(x)[:, None], self.norm1(history)
        x = x + self.attention(q, kv, kv, need_weights=False)[0][:, 0]
        return x + self.mlp(self.norm2(x))


def glance_position(index: int, width: int, like: torch.Tensor) -> torch.Tensor:
    """The sinusoidal encoding of glance ``index`` (0-based) ``(width,)``: the glance's place in
    the sequence (the where-input already says where it was)."""
    i = torch.arange(0, width, 2, dtype=like.dtype, device=like.device)
    angle = index / torch.pow(torch.tensor(10000.0, dtype=like.dtype), i / width)
    out = like.new_zeros(width)
    out[0::2] = torch.sin(angle)
    out[1::2] = torch.cos(angle[: width // 2])
    return out


class TransformerCore(nn.Module):
    """Causal self-attention over the glances so far: ``tau_{1:s} = T(g_1 .. g_s)[s]``.

    Each glance feature ``g_s`` becomes a token (a dense layer to ``hidden_size`` plus the
    sinusoidal encoding of ``s``); ``layers`` pre-norm layers let the newest token attend to the
    tokens of glances ``1..s``; the output is its final layer-normed state. Run one glance at a
    time, the state holds every layer's inputs so far (``layers`` tensors ``(B, s, D)``): the
    same numbers as a masked (causal) transformer over the whole sequence, since a token never
    sees later ones.
    """

    def __init__(
        self,
        input_size: int,
        hidden_size: int = 128,
        layers: int = 2,
        heads: int = 4,
        ff_units: int | None = None,
        bias: bool = True,
    ) -> None:
        super().__init__()
        if not (isinstance(layers, int) and layers >= 1):
            raise HamError(f"transformer layers = {layers!r}; accepted: an integer >= 1")
        if not (isinstance(heads, int) and heads >= 1 and hidden_size % heads == 0):
            raise HamError(
                f"transformer heads = {heads!r}; accepted: an integer >= 1 dividing the core "
                f"width {hidden_size}"
            )
        self.hidden_size = hidden_size
        self.embed = nn.Linear(input_size, hidden_size, bias=bias)
        ff = ff_units or 2 * hidden_size
        self.blocks = nn.ModuleList(_Block(hidden_size, heads, ff, bias) for _ in range(layers))
        self.norm = nn.LayerNorm(hidden_size)

    def initial_state(self, batch: int, like: torch.Tensor) -> State:
        empty = like.new_zeros(batch, 0, self.hidden_size, dtype=torch.float32)
        return tuple(empty for _ in self.blocks)

    def forward(self, g: torch.Tensor, state: State) -> tuple[torch.Tensor, State]:
        x = self.embed(g) + glance_position(state[0].shape[1], self.hidden_size, g)
        new_state = []
        for block, past in zip(self.blocks, state, strict=True):
            history = torch.cat([past, x[:, None]], dim=1)
            new_state.append(history)
            x = block(x, history)
        return self.norm(x), tuple(new_state)


#: name -> factory ``(input_size, hidden_size, **options) -> core``; ``HamConfig.core`` is a key.
#: A core is a module with ``initial_state(batch, like) -> State`` and
#: ``forward(g, state) -> (tau, state)``, ``tau`` of ``hidden_size`` features.
CORES: dict[str, Callable[..., nn.Module]] = {}


@checked_arguments
def register_core(name: str):
    """Decorator: make a core factory available as ``HamConfig(core=name)`` (``--core name``).

    The factory is called as ``factory(input_size, hidden_size, activation=...,
    truncate_bptt=..., forget_bias=..., bias=..., layers=..., heads=...)`` and may ignore the options it has no use for.
    Names are letters, digits and ``_ . -``; a name registered already is refused.
    """
    check_new_name("core", name, CORES)

    def add(factory: Callable[..., nn.Module]) -> Callable[..., nn.Module]:
        check_new_name("core", name, CORES)  # again: registered since
        CORES[name] = factory
        return factory

    return add


@register_core("lstm")
def _lstm(input_size: int, hidden_size: int, *, activation: str, truncate_bptt: bool,
          forget_bias: float, **_) -> LSTMCore:  # fmt: skip
    return LSTMCore(input_size, hidden_size, activation, truncate_bptt, forget_bias)


@register_core("mlp")
def _mlp(input_size: int, hidden_size: int, *, bias: bool, **_) -> MLPCore:
    return MLPCore(input_size, hidden_size, bias)


@register_core("transformer")
def _transformer(input_size: int, hidden_size: int, *, layers: int, heads: int, bias: bool,
                 **_) -> TransformerCore:  # fmt: skip
    return TransformerCore(input_size, hidden_size, layers, heads, bias=bias)


def make_core(
    kind: str,
    input_size: int,
    hidden_size: int = 256,
    *,
    activation: str = "tanh",
    truncate_bptt: bool = False,
    forget_bias: float = 1.0,
    bias: bool = True,
    layers: int = 2,
    heads: int = 4,
) -> nn.Module:
    """The core registered as ``kind`` (``lstm``, ``mlp``, or one of :func:`register_core`)."""
    try:
        factory = CORES[kind]
    except KeyError:
        raise HamError(f"core {kind!r}; accepted: {', '.join(CORES)}") from None
    return factory(
        input_size, hidden_size, activation=activation, truncate_bptt=truncate_bptt,
        forget_bias=forget_bias, bias=bias, layers=layers, heads=heads,
    )  # fmt: skip
