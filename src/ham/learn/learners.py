"""Learners: what a training step minimizes, given the episode it played.

Built in (:func:`ham.learn.train.train_step` runs them): ``hybrid``, the paper's hybrid REINFORCE
loss (:mod:`ham.learn.hybrid_loss`); ``info``, the information learner
(:mod:`ham.learn.info_loss`); ``sac``, the off-policy learner (:mod:`ham.learn.off_policy`).

Your own: a function ``loss(episode, config) -> HybridLoss`` of the played
:class:`ham.model.agent.Episode` and the run's :class:`ham.learn.train.TrainConfig`, registered
with ``@register_learner("name")`` in a plugin file; ``ham train --plugin FILE.py --learner name``
trains with it, one optimizer step on ``total`` per batch, and the run keeps the file (as for
cores and policies, :mod:`ham.model.plugin`). ``reads`` names the learner options of
``TrainConfig`` it reads (``beta``, ``gamma``, ...): another learner's option set away from its
default is refused, not ignored. Example: docs/plugins/no_baseline.py (REINFORCE without the
baseline).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import torch

from ham.errors import HamError, check_new_name, checked_arguments
from ham.learn.hybrid_loss import HybridLoss
from ham.model import plugin as _plugin
from ham.world import recorded_file

BUILT_IN: tuple[str, ...] = ("hybrid", "info", "sac")
#: name -> the loss of a learner of your own (``None``: built in, train_step runs it)
LEARNERS: dict[str, Callable | None] = dict.fromkeys(BUILT_IN)
#: name -> the learner options of TrainConfig a learner of your own reads
READS: dict[str, tuple[str, ...]] = {}

#: The TrainConfig fields only some learners read (the rest read all or none of them): a value
#: away from the default with another learner is refused, not ignored.
LEARNER_OPTIONS: dict[str, tuple[str, ...]] = {
    "beta": ("hybrid",),
    "classification_reduction": ("hybrid",),
    "reinforce_reduction": ("hybrid",),
    "classification_glances": ("hybrid",),
    "reward_glances": ("hybrid",),
    "reward_discount": ("hybrid",),
    "glance_reduction": ("hybrid",),
    "gamma": ("info", "sac"),
    "gae_lambda": ("info",),
    "info_reward": ("info",),
    "entropy_coef": ("info",),
    "normalize_advantage": ("info",),
    "replay_size": ("sac",),
    "replay_batch": ("sac",),
    "sac_updates": ("sac",),
    "target_tau": ("sac",),
    "init_alpha": ("sac",),
    "target_entropy": ("sac",),
    "critic_trains_core": ("sac",),
}

_plugin.add_registry("learner", LEARNERS, "ham.learn.learners.register_learner")


@checked_arguments
def register_learner(name: str, *, reads: tuple[str, ...] = ()) -> Callable:
    """Decorator: make ``loss(episode, config) -> HybridLoss`` the learner ``name``.

    ``reads``: the learner options of ``TrainConfig`` it reads (:data:`LEARNER_OPTIONS`). Names
    are letters, digits and ``_ . -``; a name registered already is refused.
    """
    check_new_name("learner", name, LEARNERS)
    bad = [r for r in reads if r not in LEARNER_OPTIONS] if isinstance(reads, tuple) else [reads]
    if bad:
        raise HamError(
            f"learner {name!r} reads {bad[0]!r}; accepted: a tuple of learner options "
            f"({', '.join(LEARNER_OPTIONS)}); the others every learner reads"
        )

    def register(loss: Callable) -> Callable:
        if not callable(loss):
            raise HamError(
                f"learner {name!r}: {loss!r}; accepted: a function loss(episode, config)"
            )
        LEARNERS[name] = loss
        READS[name] = tuple(reads)
        return loss

    return register


def unknown_learner(name: object) -> HamError:
    """The error for a learner nothing registered."""
    return HamError(
        f"learner = {name!r}; accepted: {', '.join(LEARNERS)}, or a learner of your own "
        "registered by a plugin (--plugin FILE.py, HamConfig(plugin=ham.model.plugin."
        "read_plugin(FILE)))"
    )


def learner_loss(name: str, episode, config) -> HybridLoss:
    """The loss of the learner of your own ``name`` on ``episode``, checked: a
    :class:`HybridLoss` of real tensors on the episode's device: ``total`` a scalar with a
    gradient, the parts scalars, ``reward`` one value per episode (integer or bool rewards become
    floats); any failure is one line naming the plugin file and its line."""
    loss_fn = LEARNERS.get(name)
    if loss_fn is None:
        raise unknown_learner(name)
    code = getattr(loss_fn, "__code__", None)
    where = code.co_filename if code is not None else name
    loss = recorded_file.call("plugin", where, loss_fn, episode, config)

    def bad(text: str) -> HamError:
        return HamError(f"plugin {where!r}: learner {name!r} {text}")

    if not isinstance(loss, HybridLoss):
        raise bad(f"returned a {type(loss).__name__}; accepted: a ham.learn.hybrid_loss.HybridLoss")
    batch, device = episode.objects.shape[0], episode.logits.device
    for field in ("total", "classification", "reinforce", "baseline", "reward"):
        v, shape = getattr(loss, field), (batch,) if field == "reward" else ()
        if not (isinstance(v, torch.Tensor) and tuple(v.shape) == shape):
            got = _plugin.shape_text(v)
            accepted = f"a tensor ({batch},), one per episode" if shape else "a scalar tensor"
            raise bad(f"returned {field} {got}; accepted: {accepted}")
        if v.is_complex() or v.device != device:
            raise bad(
                f"returned {field} of {v.dtype} on {v.device}; accepted: real numbers on "
                f"{device} (the episode's)"
            )
    if loss.total.grad_fn is None:  # detached, or a leaf of its own: it would train nothing
        raise bad("returned a total with no gradient; accepted: a loss of the episode's outputs")
    if not loss.reward.is_floating_point():  # 0/1 or bool rewards: logged as the paper's are
        loss = replace(loss, reward=loss.reward.to(episode.logits.dtype))
    return loss
