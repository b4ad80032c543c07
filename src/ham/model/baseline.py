"""The reinforcement baseline ``b(tau_{1:s}; theta_b)``: a dense layer on the core output.

Section "Training": trained separately with the mean squared error to the reward over every
sub-sequence ``1..s`` (Eq baseline). Its input is the core output *detached*: the baseline's
loss trains the baseline layer only, never the core (docs/sources.md, "The
network"). With an encoder of its own (``HamConfig.encoders = "separate"``, beyond the paper)
the baseline's loss trains that encoder too (``trains_input``).
"""

from __future__ import annotations

import torch
from torch import nn


class Baseline(nn.Module):
    """``tau -> b`` (B,), an estimate of the episode's reward from the glances so far."""

    def __init__(
        self, input_size: int = 256, bias: bool = True, trains_input: bool = False
    ) -> None:
        super().__init__()
        self.dense = nn.Linear(input_size, 1, bias=bias)
        self.trains_input = trains_input

    def forward(self, tau: torch.Tensor) -> torch.Tensor:
        if not self.trains_input:  # the core gets no gradient from Eq baseline
            tau = tau.detach()
        return self.dense(tau).squeeze(-1)
