"""The information learner: classification and control trained apart, sharing one reward.

The paper's Discussion names the way out of its hybrid loss's weak spot (a 0/1 reward at the end
of the episode, one REINFORCE term for all glances): "separately train the classification and
control part of the HAM with different loss functions that share the achieved reward". Here:

* the classifier (tactile network, core, classifier head) is trained by cross-entropy after
  *every* glance, ``L_c = sum_{s=1..S} CE_s`` with ``CE_s = -log pi(o | tau_{1:s})``, so the agent
  can answer at any time;
* the location policy is trained by an advantage actor-critic on a dense reward, the
  information each glance gains: ``r_s = CE_{s-1} - CE_s`` (``CE_0 = log K``, the uniform
  guess), the drop of the classifier's cross-entropy on the true object, as ap_gym's reward;
  the return of glance ``s`` is ``R_s = sum_{t>=s} gamma^{t-s} r_t`` (with ``gamma = 1`` it
  telescopes to ``CE_{s-1} - CE_S``); the policy's glances are 2..S, or 1..S when it also
  chooses the first (``HamConfig.first_glance = "learned"``);
* the critic is the baseline head: ``V(tau_{1:s-1})`` estimates the return of the glance that
  the core output ``tau_{1:s-1}`` chooses, trained by mean squared error; advantages by GAE
  (``lambda``; ``lambda = 1`` is the Monte-Carlo return minus the critic);
* an entropy bonus keeps the policy from collapsing early (``entropy_coef``; off by default:
  the Gaussian's entropy grows without bound in ``sigma``, docs/learners.md);
* the advantages are raw, in nats (``normalize_advantage`` scales them per batch, which blows
  up the noise of a solved batch).

As in the hybrid loss the parts train disjoint weights: the policy's term only the location
network (it reads the core detached), the critic's only the baseline layer, the classification
the rest.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch.nn import functional as F

from ham.errors import HamError
from ham.learn.hybrid_loss import glance_cross_entropy
from ham.learn.hybrid_loss import reward as paper_reward
from ham.model.agent import Episode

#: Where the move cost acts (``TrainConfig.move_cost_on``; :func:`info_loss`).
MOVE_COSTS: tuple[str, ...] = ("mean", "reward", "both")
#: What a glance earns (``TrainConfig.info_reward``; :func:`glance_reward`): ``gain``, the
#: information it gains (the default, ap_gym's reward); ``hit``, the change of the 0/1 score of
#: the arg-max answer (the paper's reward, spread over the glances).
INFO_REWARDS: tuple[str, ...] = ("gain", "hit")


class GainLoss:
    """The names the training loop logs for every learner (``reinforce``, ``baseline``,
    ``reward``), for a loss of a learner rewarded by the information gained: its policy part is
    the field named by ``POLICY_PART``, its critic ``critic``, its gain ``gain`` ``(S, B)``."""

    POLICY_PART: ClassVar[str] = "policy"
    critic: torch.Tensor
    gain: torch.Tensor

    @property
    def reinforce(self) -> torch.Tensor:
        return getattr(self, self.POLICY_PART)

    @property
    def baseline(self) -> torch.Tensor:
        return self.critic

    @property
    def reward(self) -> torch.Tensor:
        """What an episode earned ``(B,)``: the information it gained, ``log K - CE_S`` (or with
        ``info_reward = "hit"`` its final 0/1 score less a uniform guess's, ``c_S - 1/K``)."""
        return self.gain.sum(0)


@dataclass
class InfoLoss(GainLoss):
    """The loss to minimize (``total``) and its parts (scalars); ``gain`` is ``(S, B)``."""

    total: torch.Tensor
    classification: torch.Tensor
    policy: torch.Tensor
    critic: torch.Tensor
    entropy: torch.Tensor
    gain: torch.Tensor


def information_gain(logits: torch.Tensor, objects: torch.Tensor) -> torch.Tensor:
    """``r_s = CE_{s-1} - CE_s`` per glance ``(S, B)`` with ``CE_0 = log K`` (detached)."""
    _, b, k = logits.shape
    ce = glance_cross_entropy(logits.detach(), objects)
    before = torch.cat([ce.new_full((1, b), math.log(k)), ce[:-1]])
    return before - ce


def hit_gain(logits: torch.Tensor, objects: torch.Tensor) -> torch.Tensor:
    """``r_s = c_s - c_{s-1}`` per glance ``(S, B)``: ``c_s = 1`` if the arg-max class after
    glance ``s`` is the true object (the paper's reward, :func:`ham.learn.hybrid_loss.reward`),
    else 0, and ``c_0 = 1/K`` (a uniform guess's expected score, as ``CE_0 = log K``). With
    ``gamma = 1`` a glance's return telescopes to ``c_S - c_{s-1}``: the paper's reward at the
    end, less what was already right before the glance."""
    _, b, k = logits.shape
    hit = paper_reward(logits.detach(), objects[None])  # (S, B)
    before = torch.cat([hit.new_full((1, b), 1.0 / k), hit[:-1]])
    return hit - before


def glance_reward(logits: torch.Tensor, objects: torch.Tensor, kind: str = "gain") -> torch.Tensor:
    """What each glance earns ``(S, B)`` (detached): :func:`information_gain` (``kind="gain"``)
    or :func:`hit_gain` (``"hit"``); :data:`INFO_REWARDS`."""
    if kind == "gain":
        return information_gain(logits, objects)
    if kind == "hit":
        return hit_gain(logits, objects)
    raise HamError(f"info_reward = {kind!r}; accepted: {', '.join(INFO_REWARDS)}")


def advantages(rewards: torch.Tensor, values: torch.Tensor, gamma: float, lam: float) -> tuple:
    """GAE over the policy's glances: ``rewards`` ``(S', B)`` what they earned,
    ``values`` ``(S', B)`` ``V`` of the states that chose them. Returns ``(advantage, return)``."""
    n = rewards.shape[0]
    adv = torch.zeros_like(rewards)
    running = torch.zeros_like(rewards[0])
    for t in range(n - 1, -1, -1):
        next_value = values[t + 1] if t + 1 < n else torch.zeros_like(values[t])
        delta = rewards[t] + gamma * next_value - values[t]
        running = delta + gamma * lam * running
        adv[t] = running
    return adv, adv + values


def _reward(episode: Episode, gain: torch.Tensor, move_cost: float) -> torch.Tensor:
    """The information gain of each glance ``(S, B)``, less ``move_cost`` times its travel."""
    if move_cost == 0:
        return gain
    q = episode.locations.detach()
    travel = torch.cat([q.new_zeros(1, q.shape[1]), (q[1:] - q[:-1]).norm(dim=-1)])  # (S, B)
    return gain - move_cost * travel


def info_loss(
    episode: Episode,
    gamma: float = 0.5,
    gae_lambda: float = 1.0,
    policy_coef: float = 1.0,
    entropy_coef: float = 0.0,
    normalize_advantage: bool = False,
    move_cost: float = 0.0,
    move_cost_on: str = "mean",
    reward_kind: str = "gain",
) -> InfoLoss:
    """The information learner's loss of ``episode`` (see the module's docstring); the
    defaults are :class:`ham.learn.train.TrainConfig`'s (docs/learners.md: why).

    ``move_cost`` makes exploration cost (the paper's Future Work: "jumpy, energy-inefficient"
    trajectories), where ``move_cost_on`` says (:data:`MOVE_COSTS`): ``mean`` (default): the
    loss gains :func:`mean_travel_penalty`; ``reward`` (the first version): the reward of glance
    ``s >= 2`` is its information gain minus ``move_cost`` times the distance ``||q_s -
    q_{s-1}||`` the pad travelled to it (normalized pose units); ``both``: the two at once.
    ``reward_kind`` is what a glance earns (:func:`glance_reward`): the information it gains
    (``gain``) or the change of the 0/1 score (``hit``)."""
    for name, v, low, high in (("gamma", gamma, 0, 1), ("gae_lambda", gae_lambda, 0, 1)):
        if not (math.isfinite(v) and low <= v <= high):
            raise HamError(f"{name} = {v!r}; accepted: {low} <= {name} <= {high}")
    objects = episode.objects
    s, b, k = episode.logits.shape
    classification = (
        F.cross_entropy(episode.logits.reshape(s * b, k), objects.repeat(s), reduction="mean") * s
    )  # a sum over glances, a mean over the batch
    gain = glance_reward(episode.logits, objects, reward_kind)
    zero = episode.logits.new_zeros(())
    policy = episode.policy
    if policy is None or not policy.trainable:
        return InfoLoss(classification, classification, zero, zero, zero, gain)
    if not (math.isfinite(move_cost) and move_cost >= 0):
        raise HamError(f"move_cost = {move_cost!r}; accepted: a finite number >= 0")
    if move_cost_on not in MOVE_COSTS:
        raise HamError(f"move_cost_on = {move_cost_on!r}; accepted: {', '.join(MOVE_COSTS)}")
    values = episode.values()  # V(tau_{1:s-1}) of the state that chose the glance q_s
    reward = _reward(episode, gain, move_cost if move_cost_on in ("reward", "both") else 0.0)
    adv, ret = advantages(reward[episode.chosen], values.detach(), gamma, gae_lambda)
    critic = ((ret.detach() - values) ** 2).sum(0).mean()
    a = adv.detach()
    if normalize_advantage and a.numel() > 1:
        a = (a - a.mean()) / (a.std() + 1e-8)
    log_p = policy.log_prob(episode.locations[episode.chosen].detach())  # (S', B)
    policy_term = -(a * log_p).sum(0).mean()
    entropy = policy.entropy().sum(0).mean()
    total = classification + policy_coef * policy_term + critic - entropy_coef * entropy
    if move_cost > 0 and move_cost_on in ("mean", "both"):
        total = total + mean_travel_penalty(episode, move_cost)
    return InfoLoss(total, classification, policy_term, critic, entropy, gain)


def mean_travel_penalty(episode: Episode, move_cost: float) -> torch.Tensor:
    """``move_cost * mean_b sum_{s >= 2} ||mu_s - q_{s-1}||``: the distance from the pose the pad
    is at to the policy's *mean* next pose, a differentiable penalty on the location network.

    Why beside (instead of) the cost in the reward: there its gradient reaches the mean only
    through REINFORCE on the sampled poses, whose travel is mostly the policy's own spread; here
    it pulls each mean pose towards where the pad is, directly, and evaluations take the means
    (docs/learners.md). The previous pose is detached: the penalty trains only the policy."""
    mu = getattr(episode.policy, "mu", None)
    if mu is None:
        raise HamError(
            f"move_cost_on = 'mean' with a {type(episode.policy).__name__} policy; accepted: a "
            "policy with a mean pose (--policy learned)"
        )
    s = episode.locations.shape[0]
    if s < 2:
        return mu.sum() * 0
    step = mu[-(s - 1) :] - episode.locations[:-1].detach()  # glances 2..S from their previous
    # sqrt(. + eps): the norm's gradient is finite when the mean sits on the previous pose
    return move_cost * (step.pow(2).sum(-1) + 1e-12).sqrt().sum(0).mean()


# --------------------------------------------------------------------------- several epochs
@dataclass
class InfoTargets:
    """What the epochs over one batch hold fixed (PPO): computed once, from the episode as
    played. ``old_log_prob``, ``advantage`` and ``target`` are ``(S', B)`` over the policy's
    glances (``None`` when no trainable policy chose them)."""

    old_log_prob: torch.Tensor | None
    advantage: torch.Tensor | None
    target: torch.Tensor | None


def info_targets(
    episode: Episode,
    gamma: float = 0.5,
    gae_lambda: float = 1.0,
    move_cost: float = 0.0,
    reward_kind: str = "gain",
) -> InfoTargets:
    """The played ``episode``'s log-probabilities of its poses, its advantages and the critic's
    targets (GAE on the reward ``reward_kind``, as :func:`info_loss`), all detached."""
    for name, v in (("gamma", gamma), ("gae_lambda", gae_lambda)):
        if not (math.isfinite(v) and 0 <= v <= 1):
            raise HamError(f"{name} = {v!r}; accepted: 0 <= {name} <= 1")
    if not (math.isfinite(move_cost) and move_cost >= 0):
        raise HamError(f"move_cost = {move_cost!r}; accepted: a finite number >= 0")
    policy = episode.policy
    if policy is None or not policy.trainable:
        return InfoTargets(None, None, None)
    with torch.no_grad():
        gain = glance_reward(episode.logits, episode.objects, reward_kind)
        reward = _reward(episode, gain, move_cost)
        adv, ret = advantages(reward[episode.chosen], episode.values(), gamma, gae_lambda)
        log_p = policy.log_prob(episode.locations[episode.chosen])
    return InfoTargets(log_p.detach(), adv.detach(), ret.detach())


def clipped_info_loss(
    episode: Episode,
    targets: InfoTargets,
    clip: float = 0.2,
    entropy_coef: float = 0.0,
    reward_kind: str = "gain",
) -> InfoLoss:
    """The information learner's loss for one more pass over a batch already played (the
    network replayed on its recorded glances, :meth:`HapticAttentionModel.replay`): the
    classification after every glance as in :func:`info_loss`; the policy term PPO's clipped
    surrogate ``-min(rho A, clip(rho, 1 - clip, 1 + clip) A)``, ``rho = pi(q) / pi_old(q)``,
    summed over the glances, a mean over the batch; the critic's MSE to the fixed targets.
    On the first pass (``rho = 1``) its gradient is :func:`info_loss`'s."""
    if not (math.isfinite(clip) and clip > 0):
        raise HamError(f"clip = {clip!r}; accepted: a finite number > 0")
    objects = episode.objects
    s, b, k = episode.logits.shape
    classification = (
        F.cross_entropy(episode.logits.reshape(s * b, k), objects.repeat(s), reduction="mean") * s
    )
    gain = glance_reward(episode.logits, objects, reward_kind)
    zero = episode.logits.new_zeros(())
    policy = episode.policy
    if targets.advantage is None or policy is None or not policy.trainable:
        return InfoLoss(classification, classification, zero, zero, zero, gain)
    values = episode.values()
    critic = ((targets.target - values) ** 2).sum(0).mean()
    ratio = torch.exp(policy.log_prob(episode.locations[episode.chosen]) - targets.old_log_prob)
    a = targets.advantage
    surrogate = torch.minimum(ratio * a, ratio.clamp(1 - clip, 1 + clip) * a)
    policy_term = -surrogate.sum(0).mean()
    entropy = policy.entropy().sum(0).mean()
    total = classification + policy_term + critic - entropy_coef * entropy
    return InfoLoss(total, classification, policy_term, critic, entropy, gain)
