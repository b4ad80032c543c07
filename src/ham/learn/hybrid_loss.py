"""The paper's hybrid loss (section "Training", Eq update_weights) and the baseline loss (Eq baseline).

For a batch of episodes with reward ``r = 1`` if the arg-max class after the last glance is
right, else 0 (section "Methods"):

``L = -log pi(o | tau_{1:S})                                     (classification, cross-entropy)
      - beta * sum_{s=2..S} (r - b_{s-1}) * sum_{x, phi} log N(q_s; mu_s, sigma_s)   (REINFORCE)``

combined over the batch as :func:`hybrid_loss` describes. ``log N`` is the location policy's
``log_prob`` (:mod:`ham.model.policy`): the loss reads no parameter of the policy itself, so any
registered policy trains through it. For the paper's Gaussian its gradient with respect to the
policy's outputs is the paper's update:
``-beta * (r - b) * (zeta_mu_x + zeta_mu_phi + zeta_sigma_x + zeta_sigma_phi)`` with the characteristic eligibilities ``zeta_mu = (q - mu) / sigma^2`` (Eq reinforce_mean) and
``zeta_sigma = ((q - mu)^2 - sigma^2) / sigma^3`` (Eq reinforce_std): autograd of the Gaussian's
log density gives exactly these (``tests/test_hybrid_loss.py`` checks it). ``b_{s-1} =
b(tau_{1:s-1})`` is the baseline read from the same core output that chose the pose ``q_s``.

The baseline is trained separately with ``L_b = sum_{s=1..S} (R_s - b(tau_{1:s}))^2`` (Eq
baseline). With the reward only at the end of the episode and no discount within it, the return
``R_s`` seen from every sub-sequence ``1..s`` is the episode's reward ``r`` (Eq total_reward).

Beyond the paper (the APPLE study's HAM), :func:`returns` gives the general case: a reward
``r_s`` for the prediction after every glance and returns discounted by ``gamma`` within the
episode, ``R_s = sum_{t=s..S} gamma^(t-s) r_t`` (Eq total_reward). The pose ``q_{s+1}``, chosen
from ``tau_{1:s}``, is credited with ``R_s`` and its baseline ``b(tau_{1:s})`` learns ``R_s``;
``r_s`` does not depend on ``q_{s+1}``, but it is known from ``tau_{1:s}``, so the baseline
takes it out of the advantage (APPLE credits an action with the reward of the prediction made
beside it the same way). A learned first glance, chosen before any prediction, is credited with
``gamma * R_1``.

What is detached from what, all explicit below or in the modules:

* the sampled poses ``q`` carry no gradient (``.detach()`` here; they are drawn detached);
* the advantage ``r - b`` is detached: REINFORCE does not train the baseline;
* the baseline reads the core output detached (:class:`ham.model.baseline.Baseline`): ``L_b`` does not
  train the core; the location network reads it detached too (:class:`ham.model.location_net.LocationNetwork`);
* a policy without trainable parameters (``random``) has no REINFORCE term at all.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch.nn import functional as F

from ham.errors import HamError
from ham.model.agent import Episode
from ham.model.policy import LocationDistribution

REDUCTIONS: tuple[str, ...] = ("sum", "mean")
#: Which predictions the classification term trains: the one after the last glance (the paper),
#: or the one after every glance, averaged over the glances (the APPLE study's HAM; ap_gym scores
#: a prediction at every step).
CLASSIFICATION_GLANCES: tuple[str, ...] = ("last", "all")
#: Which predictions earn a reward: the one after the last glance (the paper), or the one after
#: every glance (the APPLE study's HAM, ``classification_binary_reward``).
REWARD_GLANCES: tuple[str, ...] = ("last", "all")


@dataclass
class HybridLoss:
    """The loss to minimize (``total``) and its parts, each a scalar tensor; ``reward`` is (B,)."""

    total: torch.Tensor
    classification: torch.Tensor
    reinforce: torch.Tensor
    baseline: torch.Tensor
    reward: torch.Tensor


def glance_cross_entropy(logits: torch.Tensor, objects: torch.Tensor) -> torch.Tensor:
    """``-log pi(o | tau_{1:s})`` after every glance ``s``: ``(S, B)`` from logits ``(S, B, K)``."""
    s, b, k = logits.shape
    return F.cross_entropy(logits.reshape(s * b, k), objects.repeat(s), reduction="none").reshape(
        s, b
    )


def reward(logits: torch.Tensor, objects: torch.Tensor) -> torch.Tensor:
    """``r = 1`` if the arg-max class is the true object, else 0 (B,)."""
    return (logits.argmax(-1) == objects).to(logits.dtype)


def returns(
    logits: torch.Tensor, objects: torch.Tensor, reward_glances: str, discount: float
) -> torch.Tensor:
    """``R_s = sum_{t=s..S} gamma^(t-s) r_t`` seen from every sub-sequence ``tau_{1:s}``, ``(S,
    B)`` (Eq total_reward within one episode): ``r_t`` is :func:`reward` of the prediction after
    glance ``t`` with ``reward_glances="all"``; with ``"last"`` only the last prediction is
    rewarded (``R_s = gamma^(S-s) r``); the paper's, with no discount, is ``r`` seen ``S``
    times (a view: no more work than the paper's loss)."""
    logits = logits.detach()
    if reward_glances == "last" and discount == 1:
        return reward(logits[-1], objects).expand(logits.shape[:2])
    if reward_glances == "last":
        rewards = [logits.new_zeros(objects.shape)] * (logits.shape[0] - 1)
        rewards.append(reward(logits[-1], objects))
    else:
        rewards = list(reward(logits, objects[None]).unbind(0))
    out = [rewards[-1]]
    for r in reversed(rewards[:-1]):  # R_s = r_s + gamma R_{s+1}
        out.append(r + discount * out[-1])
    return torch.stack(out[::-1])


def reinforce_term(
    q: torch.Tensor, policy: LocationDistribution, advantage: torch.Tensor
) -> torch.Tensor:
    """``-mean_b sum_s advantage * log pi(q)`` with ``log pi(q) = sum_{x, phi} log N(q; mu,
    sigma)`` for the Gaussian policy: its gradient in ``mu`` and ``sigma`` is ``-advantage *
    zeta_mu`` and ``-advantage * zeta_sigma`` per element / B."""
    q = q.detach()  # no gradient flows into the sampled poses
    advantage = advantage.detach()  # the baseline is not trained by REINFORCE
    log_n = policy.log_prob(q)  # summed over the x and phi streams: (S-1, B)
    return -(advantage * log_n).sum(0).mean()


def hybrid_loss(
    episode: Episode,
    beta: float | torch.Tensor = 0.4,
    classification_reduction: str = "sum",
    reinforce_reduction: str = "mean",
    classification_glances: str = "last",
    reward_glances: str = "last",
    reward_discount: float = 1.0,
    glance_reduction: str = "sum",
) -> HybridLoss:
    """The hybrid loss of ``episode`` with location weight ``beta`` (0.4), plus the baseline loss.

    ``total = classification + beta * reinforce + baseline``. Through the detaches above the
    three parts train disjoint weights: classification the tactile network, core and classifier;
    REINFORCE only the location heads; the baseline loss only the baseline layer.

    How the episodes of a batch combine (Eq update_weights is written for one episode):
    ``classification_reduction="sum"`` adds the episodes' classification updates;
    ``reinforce_reduction="mean"`` averages their REINFORCE updates (the Monte-Carlo estimate of
    the policy gradient ``E[(r - b) zeta]``). The baseline's loss is a mean over the batch ("the
    mean-squared error") and a sum over the sub-sequences (Eq baseline). The parts train disjoint
    weights, so each reduction only scales its own part's step; docs/agent.md has the measurements
    behind these defaults.

    ``classification_glances="all"`` trains the prediction after every glance, not only after
    the last: the cross-entropy of each glance's logits, averaged over the glances (so the last
    glance's prediction gets 1/S of the weight it has with ``"last"``). The reward stays the last
    prediction's.

    ``reward_glances="all"`` rewards the prediction after every glance and ``reward_discount``
    (gamma) discounts the returns within the episode (:func:`returns`); the paper's ``"last"``
    with 1.0 gives every sub-sequence the episode's reward ``r``. ``HybridLoss.reward`` stays
    the last prediction's ``r`` either way.

    ``glance_reduction`` combines an episode's glances in the REINFORCE term and the baseline
    loss: ``"sum"`` (the paper: Eq update_weights sums over the poses, Eq baseline over the
    sub-sequences) or ``"mean"`` (the APPLE study's HAM: its policy and value losses are means
    over the steps), each sum divided by its number of terms.
    """
    for name, value, accepted in (
        ("classification_reduction", classification_reduction, REDUCTIONS),
        ("reinforce_reduction", reinforce_reduction, REDUCTIONS),
        ("classification_glances", classification_glances, CLASSIFICATION_GLANCES),
        ("reward_glances", reward_glances, REWARD_GLANCES),
        ("glance_reduction", glance_reduction, REDUCTIONS),
    ):
        if value not in accepted:
            raise HamError(f"{name} {value!r}; accepted: {', '.join(accepted)}")
    if isinstance(reward_discount, bool) or not (
        isinstance(reward_discount, (int, float)) and 0 <= reward_discount <= 1
    ):
        raise HamError(f"reward_discount {reward_discount!r}; accepted: a number in [0, 1]")
    objects = episode.objects
    last = episode.logits[-1]
    # -sum_o y_o log pi(o) per episode
    if classification_glances == "last":
        classification = F.cross_entropy(last, objects, reduction=classification_reduction)
    else:
        every = glance_cross_entropy(episode.logits, objects).mean(0)  # (B,)
        classification = every.sum() if classification_reduction == "sum" else every.mean()
    r = reward(last.detach(), objects)
    ret = returns(episode.logits, objects, reward_glances, reward_discount)  # (S, B)
    first_ret = reward_discount * ret[0]  # the learned first glance: no prediction before it
    # Eq baseline over every sub-sequence 1..S, target its return R_s.
    squares = (ret - episode.baselines) ** 2
    if glance_reduction == "sum":
        baseline = squares.sum(0).mean()
        if episode.first_baseline is not None:  # a learned first glance: b(tau_0) too
            baseline = baseline + ((first_ret - episode.first_baseline) ** 2).mean()
    else:
        if episode.first_baseline is not None:
            squares = torch.cat([((first_ret - episode.first_baseline) ** 2)[None], squares])
        baseline = squares.mean(0).mean()
    policy = episode.policy
    # (a tensor beta, one per run of a batched model, is never 0: batched.shape_key)
    if policy is None or not policy.trainable or (not torch.is_tensor(beta) and beta == 0):
        reinforce = last.new_zeros(())
    else:
        # q_{s+1} earns R_s, against b(tau_{1:s}); a learned first glance gamma * R_1
        earned = ret[:-1]
        if episode.first_baseline is not None:
            earned = torch.cat([first_ret[None], earned])
        advantage = earned - episode.values()
        reinforce = reinforce_term(episode.locations[episode.chosen], policy, advantage)
        if reinforce_reduction == "sum":
            reinforce = reinforce * objects.shape[0]
        if glance_reduction == "mean":
            reinforce = reinforce / advantage.shape[0]
    total = classification + beta * reinforce + baseline
    return HybridLoss(total, classification, reinforce, baseline, r)
