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

The LSTM cell is written out (one dense layer over ``[g, h]`` with one bias vector, gates in the
order input, forget, cell, output), as in Keras/TensorFlow, so its parameter count matches the
authors' model (``4 * 256 * (256 + 256) + 4 * 256`` = 525,312).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn

from ham.errors import HamError

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


#: name -> factory ``(input_size, hidden_size, **options) -> core``; ``HamConfig.core`` is a key.
#: A core is a module with ``initial_state(batch, like) -> State`` and
#: ``forward(g, state) -> (tau, state)``, ``tau`` of ``hidden_size`` features.
CORES: dict[str, Callable[..., nn.Module]] = {}


def register_core(name: str):
    """Decorator: make a core factory available as ``HamConfig(core=name)`` (``--core name``).

    The factory is called as ``factory(input_size, hidden_size, activation=...,
    truncate_bptt=..., forget_bias=..., bias=...)`` and may ignore the options it has no use for.
    """

    def add(factory: Callable[..., nn.Module]) -> Callable[..., nn.Module]:
        if name in CORES:
            raise HamError(f"core {name!r} is registered already")
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


def make_core(
    kind: str,
    input_size: int,
    hidden_size: int = 256,
    *,
    activation: str = "tanh",
    truncate_bptt: bool = False,
    forget_bias: float = 1.0,
    bias: bool = True,
) -> nn.Module:
    """The core registered as ``kind`` (``lstm``, ``mlp``, or one of :func:`register_core`)."""
    try:
        factory = CORES[kind]
    except KeyError:
        raise HamError(f"core {kind!r}; accepted: {', '.join(CORES)}") from None
    return factory(
        input_size, hidden_size, activation=activation, truncate_bptt=truncate_bptt,
        forget_bias=forget_bias, bias=bias,
    )  # fmt: skip
