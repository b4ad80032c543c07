"""A learned stop: after each glance the agent says classify-now or glance-again.

The stop head (``HamConfig.stop``) reads the core output after glance ``s`` and gives
``p_s = sigmoid(w . tau_{1:s})``, the probability to stop there; at glance ``S`` (the most
allowed) it stops anyway. An episode that stops at glance ``T`` is answered by the classifier's
output after glance ``T`` and pays ``glance_cost`` per glance:

``R = 1[argmax pi(. | tau_{1:T}) = o] - glance_cost * T``

The stop decisions are trained by REINFORCE on ``R`` with the batch's mean return as baseline:
``L_stop = -mean_b (R - mean R) * sum_{s <= min(T, S-1)} log P(decision_s)``. The classifier is
trained after every glance by the info learner (:mod:`ham.learn.info_loss`), so it can answer at
any ``T``. Evaluation stops greedily (``p_s > 1/2``) and reports the accuracy at the stop and the
mean number of glances: the curve accuracy vs glances over several costs, beside the planner's
``N*`` (:mod:`ham.learn.planners`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch.nn import functional as F

from ham.errors import HamError
from ham.model.agent import Episode


@dataclass
class StopLoss:
    """The stop head's loss (scalar), and per episode the stop glance ``T`` (1-based) and ``R``."""

    total: torch.Tensor
    stop_at: torch.Tensor
    ret: torch.Tensor


def stop_glances(
    stop_logits: torch.Tensor, generator: torch.Generator | None = None, greedy: bool = False
) -> tuple[torch.Tensor, torch.Tensor]:
    """The decisions of ``stop_logits`` ``(S, B)``: sampled from ``generator``, or greedy
    (``p > 1/2``). Returns the stop glance ``T`` ``(B,)`` (1-based; ``S`` when no stop) and the
    decisions ``(S, B)`` (1: stop)."""
    p = torch.sigmoid(stop_logits.detach())
    if greedy:
        decide = (p > 0.5).to(p.dtype)
    else:
        u = torch.rand(p.shape, generator=generator, device=p.device, dtype=p.dtype)
        decide = (u < p).to(p.dtype)
    decide[-1] = 1.0  # the last allowed glance always stops
    stop_at = decide.argmax(0) + 1  # the first stop
    return stop_at, decide


def stop_loss(
    episode: Episode, glance_cost: float, generator: torch.Generator | None = None
) -> StopLoss:
    """REINFORCE of the stop decisions of ``episode`` (see the module's docstring)."""
    if episode.stop_logits is None:
        raise HamError("the model has no stop head; accepted: HamConfig(stop=True) (--stop)")
    if not (math.isfinite(glance_cost) and glance_cost >= 0):
        raise HamError(f"glance_cost = {glance_cost!r}; accepted: a finite number >= 0")
    logits = episode.stop_logits  # (S, B)
    s, b = logits.shape
    stop_at, decide = stop_glances(logits, generator)
    idx = torch.arange(b, device=logits.device)
    answer = episode.logits[stop_at - 1, idx].detach().argmax(-1)
    ret = (answer == episode.objects).to(logits.dtype) - glance_cost * stop_at.to(logits.dtype)
    # log P of the decisions actually taken: glances 1..min(T, S-1) (the last one is forced)
    glance = torch.arange(1, s + 1, device=logits.device).view(-1, 1)
    taken = (glance <= stop_at.view(1, -1)) & (glance < s)
    log_p = -F.binary_cross_entropy_with_logits(logits, decide, reduction="none")
    log_p = (log_p * taken).sum(0)
    total = -((ret - ret.mean()).detach() * log_p).mean()
    return StopLoss(total, stop_at, ret)
