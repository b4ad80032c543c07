"""A learned stop: after each glance the agent says classify-now or glance-again.

The stop head (``HamConfig.stop``) gives a logit ``d_s`` after glance ``s``: stop there when
``d_s > 0`` (``p_s = sigmoid(d_s)`` when sampled); at glance ``S`` (the most allowed) it stops
anyway. It reads the classifier's confidence (``HamConfig.stop_input = "confidence"``,
:class:`ham.model.agent.StopHead`) or the core output (``"core"``, the first version). An episode that stops at glance ``T`` is answered by the classifier's
output after glance ``T`` and pays ``glance_cost`` per glance:

``R = 1[argmax pi(. | tau_{1:T}) = o] - glance_cost * T``

Three ways to train the stop head (``TrainConfig.stop_learner``):

* ``value`` (default): the head's logit ``d_s`` is a regression of the actual reward difference
  classify-now vs continue, by backward induction over the played episode as in Longstaff and
  Schwartz's least-squares optimal stopping. Training plays all ``S`` glances (the stop does not
  change the glances), so the payoff of stopping at every ``s`` is known,
  ``g_s = 1[argmax pi(. | tau_{1:s}) = o] - glance_cost * s``. With ``W_S = g_S`` (forced) and
  ``W_s = g_s`` if the greedy head stops at ``s`` (``d_s > 0``) else ``W_{s+1}``, the target
  of ``d_s`` is ``g_s - W_{s+1}`` for ``s < S``: ``L_stop = mean_{s < S, b} (d_s - (g_s -
  W_{s+1}))^2``. Every glance gets its own counterfactual, no sampling, no shared baseline.
* ``hindsight``: the same regression with the best later payoff as the value of continuing,
  ``W_{s+1} = max_{t > s} g_t``. Training samples its poses, evaluation takes the mean poses,
  whose later glances are better than the samples': the greedy continuation of ``value`` is
  that of the sampling policy and undervalues going on (docs/learners.md); the best later
  payoff is an upper bound on any policy's continuation.
* ``reinforce`` (the first version): the decisions are sampled and trained by REINFORCE on ``R``
  with the batch's mean return as baseline, ``L_stop = -mean_b (R - mean R) * sum_{s <= min(T,
  S-1)} log P(decision_s)``: one noisy return credits all decisions of an episode.

The classifier is trained after every glance by the info learner (:mod:`ham.learn.info_loss`),
so it can answer at any ``T``. Evaluation stops greedily (``p_s > 1/2``, i.e. ``d_s > 0``) and
reports the accuracy at the stop and the mean number of glances: the curve accuracy vs glances
over several costs, beside the planner's ``N*`` (:mod:`ham.learn.planners`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch.nn import functional as F

from ham.errors import HamError
from ham.model.agent import Episode

#: How the stop head is trained (``TrainConfig.stop_learner``).
STOP_LEARNERS: tuple[str, ...] = ("value", "hindsight", "reinforce")


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


def stop_payoffs(episode: Episode, glance_cost: float) -> torch.Tensor:
    """``g_s = 1[answer after glance s is right] - glance_cost * s`` ``(S, B)`` (detached)."""
    s = episode.logits.shape[0]
    right = (episode.logits.detach().argmax(-1) == episode.objects).to(episode.logits.dtype)
    glance = torch.arange(1, s + 1, device=right.device, dtype=right.dtype).view(-1, 1)
    return right - glance_cost * glance


def stop_loss(
    episode: Episode,
    glance_cost: float,
    generator: torch.Generator | None = None,
    learner: str = "value",
) -> StopLoss:
    """The stop head's loss of ``episode`` by ``learner`` (``value`` or ``reinforce``; see the
    module's docstring); ``generator`` draws the decisions of ``reinforce`` (``value`` draws
    nothing)."""
    if episode.stop_logits is None:
        raise HamError("the model has no stop head; accepted: HamConfig(stop=True) (--stop)")
    if not (math.isfinite(glance_cost) and glance_cost >= 0):
        raise HamError(f"glance_cost = {glance_cost!r}; accepted: a finite number >= 0")
    if learner in ("value", "hindsight"):
        return _value_stop_loss(episode, glance_cost, hindsight=learner == "hindsight")
    if learner != "reinforce":
        raise HamError(f"stop learner {learner!r}; accepted: one of {', '.join(STOP_LEARNERS)}")
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


def _value_stop_loss(episode: Episode, glance_cost: float, hindsight: bool = False) -> StopLoss:
    """Least-squares regression of classify-now minus continue (module docstring)."""
    d = episode.stop_logits  # (S, B)
    s = d.shape[0]
    g = stop_payoffs(episode, glance_cost)
    greedy = d.detach() > 0
    target = torch.zeros_like(g)
    w = g[-1]  # W_S: the last glance always stops
    for t in range(s - 2, -1, -1):
        target[t] = g[t] - w
        w = torch.maximum(g[t], w) if hindsight else torch.where(greedy[t], g[t], w)
    total = ((d[:-1] - target[:-1]) ** 2).mean() if s > 1 else d.sum() * 0
    stop_at, _ = stop_glances(d, greedy=True)
    idx = torch.arange(d.shape[1], device=d.device)
    return StopLoss(total, stop_at, g[stop_at - 1, idx])
