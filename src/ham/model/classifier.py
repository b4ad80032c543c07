"""The classification network: a dense layer and a softmax over the objects.

Section "The Classification Network": ``pi(o | tau_{1:s})`` from the core's output; the prediction
is ``argmax_o pi(o | tau_{1:S})`` after the last glance (Eq classify). The module returns the
logits; the softmax belongs to the cross-entropy of the hybrid loss and to the evaluation.
"""

from __future__ import annotations

import torch
from torch import nn


class Classifier(nn.Module):
    """``tau -> logits`` (B, n_objects); ``softmax(logits) = pi(o | tau)``."""

    def __init__(self, input_size: int = 256, n_objects: int = 4, bias: bool = True) -> None:
        super().__init__()
        self.dense = nn.Linear(input_size, n_objects, bias=bias)

    def forward(self, tau: torch.Tensor) -> torch.Tensor:
        return self.dense(tau)
