"""A global search for the first pose (``HamConfig.first_glance = "probe"``, beyond the paper).

The stop can end an episode after one glance only where the first pose tells every object
apart; on the paper's table such poses are few and lie in narrow bands that a policy gradient
from one Gaussian does not find (docs/learners.md, "A learned stop"). Here the first pose is
searched on a lattice (:class:`ham.model.policy.ProbedFirstPose`), scored by the classifier
itself:

1. warm-up (``TrainConfig.probe_warmup`` steps): first glances drawn uniformly among the
   lattice's candidates, so the classifier learns what one glance at each of them says;
2. a round every ``probe_every`` steps: each surviving candidate is probed, one glance of every
   object at it (``K`` glances, counted as environment steps), scored by the classifier after
   that single glance: the objects it answers wrong, then its mean cross-entropy on the true
   object (``probe_score``); the best ``probe_keep`` of them survive (successive halving). Between rounds training's first glances are drawn among the
   survivors, so the classifier keeps learning exactly the candidates still in the race, and a
   candidate's next score says how well it can be told apart once trained on;
3. when one candidate is left it is committed: every later first glance is there, and training
   makes the classifier sure of it.

The probes draw no random numbers and train nothing: with the rest of the run's state in the
checkpoint (the search's buffers are the model's) a resumed run is bit-identical.
"""

from __future__ import annotations

import math

import torch
from torch.nn import functional as F

from ham.model.agent import HapticAttentionModel

#: How a round ranks its candidates (``TrainConfig.probe_score``; :func:`rank`).
PROBE_SCORES: tuple[str, ...] = ("errors", "ce")


def survivors(n: int, keep: float) -> int:
    """Candidates left after a round on ``n`` of them: ``ceil(keep * n)``, at least 1 and
    fewer than ``n`` (every round halves, for ``keep = 0.5``)."""
    return max(1, min(n - 1, math.ceil(keep * n)))


def probe_schedule(candidates: int, keep: float) -> list[int]:
    """The candidates probed in each round until one is left (``[N, ..., 2]``; empty for 1)."""
    rounds, n = [], candidates
    while n > 1:
        rounds.append(n)
        n = survivors(n, keep)
    return rounds


def probe_glances(candidates: int, keep: float, n_objects: int) -> int:
    """Environment steps the whole search spends: every round one glance per object and
    surviving candidate."""
    return n_objects * sum(probe_schedule(candidates, keep))


def probe_scores(
    agent: HapticAttentionModel, env, poses: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The classifier after one glance of every object of ``env`` at each of ``poses`` ``(M,
    k)`` (``M * K`` glances; no gradient): ``(M,)`` its mean cross-entropy on the true object
    and ``(M,)`` the number of objects it answers wrong."""
    k = env.n_objects
    m = poses.shape[0]
    device = env.device
    objects = torch.arange(k, device=device).repeat(m)  # pose-major: pose i, objects 0..K-1
    q = poses.to(device).repeat_interleave(k, 0)
    with torch.no_grad():
        tau, _ = agent.glance_step(env, objects, q, agent.core.initial_state(len(objects), q))
        logits = agent.classifier(tau)
        ce = F.cross_entropy(logits, objects, reduction="none")
        wrong = (logits.argmax(-1) != objects).to(ce.dtype)
    return ce.reshape(m, k).mean(1), wrong.reshape(m, k).sum(1)


def rank(ce: torch.Tensor, wrong: torch.Tensor, score: str) -> torch.Tensor:
    """Candidate indices, best first: by ``score`` (:data:`PROBE_SCORES`); ``errors``: fewest
    wrong answers, then the lower cross-entropy; ``ce``: the lower cross-entropy. Ties: the
    lower index.

    Why errors first: a pose where two objects press the same image caps the answers at
    ``K - 1`` right, whatever the training, while its cross-entropy sits near its floor
    (``log 2 / 2`` for one pair of 4) and is steady; a pose that tells all apart, still being
    learned, can be right on every object at a higher and noisier cross-entropy (measured:
    the ``ce`` rule dropped the band that tells the paper's 4 objects apart in one seed of
    three, docs/learners.md)."""
    order = torch.argsort(ce.cpu(), stable=True)
    if score == "errors":
        order = order[torch.argsort(wrong.cpu()[order], stable=True)]
    return order


def probe_due(step: int, warmup: int, every: int, search) -> bool:
    """A round is due before training step ``step + 1`` (``step`` steps done)."""
    if bool(search.committed) or step < warmup:
        return False
    return (step - warmup) % every == 0


def probe_round(agent: HapticAttentionModel, env, keep: float, score: str = "errors") -> dict:
    """One round of successive halving on the surviving candidates of ``agent.first_probe``:
    probe them, keep the best ``keep`` share (:func:`rank` by ``score``), commit when one is
    left. Returns what the round did (for the log)."""
    search = agent.first_probe
    idx = search.alive.nonzero()[:, 0]
    ce, wrong = probe_scores(agent, env, search.candidates[idx])
    search.probes += len(idx) * env.n_objects
    order = rank(ce, wrong, score)
    kept = idx[order[: survivors(len(idx), keep)].to(idx.device)]
    search.alive.zero_()
    search.alive[kept] = True
    if len(kept) == 1:
        search.pose.copy_(search.candidates[kept[0]])
        search.committed.fill_(True)
    best = order[0]
    return {
        "probed": len(idx),
        "kept": len(kept),
        "ce": float(ce[best]),
        "wrong": float(wrong[best]),
    }
