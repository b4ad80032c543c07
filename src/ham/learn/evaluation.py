"""Evaluation (section "Experiments"): accuracies on fresh balanced batches, and the pose heat map.

"In order to measure the performance after a certain number of training steps, the training is
stopped. This is followed by estimation of the mean classification accuracy of 100 newly generated
batches, using the currently available policy." We report, over ``batches`` balanced batches:

* ``accuracy``: the arg-max class after the last glance (Eq classify);
* ``accuracy_per_glance``: the same after each glance ``s = 1..S`` of the same episodes;
* ``accumulated_accuracy_per_glance``: the arg-max of the softmax outputs averaged over glances
  ``1..s`` (the paper's averaged output, column ``<pi_MLP>`` of Table 1);
* ``confusion``: after each glance, the counts of true object (row) x arg-max class (column);
* ``per_object_accuracy``: per true object, the accuracy after the last glance (``None`` for an
  object no episode showed: ap_gym's labels follow its data and need not be balanced).

``policy`` says how the location policy acts during evaluation: ``mean`` (default) takes the
mode of its distribution (:meth:`ham.model.policy.LocationDistribution.mode`: the mean pose
``mu`` of the paper's Gaussian), the policy with training "stopped" (the authors' RAM code
evaluates this way); ``sample`` draws poses as in training. The first glance is random either way;
a policy without a mode (the random-location policy) samples either way. Evaluation draws from its own generator, so it
never disturbs the training's random streams.

:func:`heatmap_data` bins the last glance's pose per object into 20 x 20 cells over many batches
and collects the policy's modes (the learned means ``mu_x, mu_phi``) that chose it (the paper's
heat maps).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass

import torch

from ham.errors import HamError, check_integer, checked_arguments
from ham.learn.environment import HapticEnv
from ham.learn.stopping import stop_glances
from ham.model.agent import HapticAttentionModel
from ham.model.location_net import uniform_locations


@dataclass
class EvalResult:
    accuracy: float
    accuracy_per_glance: list[float]
    accumulated_accuracy_per_glance: list[float]
    batches: int
    episodes: int
    #: per object, the mean ``(mu_x, mu_phi)`` (the policy's mode) that chose the last glance
    #: (``None``: a policy without a mode, or one glance)
    mu_mean: list[list[float]] | None = None
    #: ``confusion[s][o][p]``: episodes of true object ``o`` classified ``p`` after glance ``s+1``
    confusion: list[list[list[int]]] | None = None
    #: per true object, the accuracy after the last glance (``None``: no episode of it)
    per_object_accuracy: list[float | None] | None = None
    #: the objects' (classes') names, in class order
    objects: list[str] | None = None
    #: mean path of an episode: the summed distance between consecutive poses ``q`` (in the
    #: normalized action units of ``[-1, 1]^2``; the paper's "jumpy" trajectories cost this)
    path_length: float | None = None
    #: with a learned stop (greedy, ``p > 1/2``): accuracy at the stop and mean glances used
    stop_accuracy: float | None = None
    mean_glances: float | None = None
    #: per glance, how far the poses ``q`` asked for (``Episode.locations``; with relative
    #: actions, the moves) spread over the episodes: the standard deviation of
    #: each pose coordinate over all episodes, root-mean-squared over the coordinates (a
    #: uniform pose in ``[-1, 1]``: 1/sqrt(3) = 0.577; a fixed sequence of glances: 0)
    pose_spread: list[float] | None = None
    #: the same within each true object (pooled over the objects): what spreads the poses
    #: beyond the object itself, e.g. what the earlier glances of the episode felt
    pose_spread_within_object: list[float] | None = None

    def to_dict(self) -> dict:
        return asdict(self)


EVAL_POLICIES: tuple[str, ...] = ("mean", "sample")
#: Heat-map bins per axis: finer than the 201-point glance table's grid shows nothing new.
MAX_BINS = 201


def path_lengths(locations: torch.Tensor) -> torch.Tensor:
    """Per episode, the summed distance between consecutive poses: ``(S, B, k)`` -> ``(B,)``."""
    if locations.shape[0] < 2:
        return locations.new_zeros(locations.shape[1])
    return (locations[1:] - locations[:-1]).norm(dim=-1).sum(0)


def pose_sums(locations: torch.Tensor, objects: torch.Tensor, k: int) -> torch.Tensor:
    """Per glance and true object, the episodes' count, summed poses and summed squared poses:
    ``locations (..., S, B, d)`` of episodes of ``objects (B,)`` -> ``(..., S, k, 1 + 2 d)``
    in float64 (summed over evaluation batches, :func:`pose_spreads` reads them)."""
    q = locations.double()
    x = torch.cat([torch.ones_like(q[..., :1]), q, q * q], -1)
    out = x.new_zeros(*x.shape[:-2], k, x.shape[-1])
    return out.index_add_(x.dim() - 2, objects, x)


def pose_spreads(sums: torch.Tensor) -> tuple[list[float], list[float]]:
    """:attr:`EvalResult.pose_spread` and :attr:`EvalResult.pose_spread_within_object` from
    :func:`pose_sums` ``(S, k, 1 + 2 d)``."""
    d = (sums.shape[-1] - 1) // 2
    n, s1, s2 = sums[..., 0], sums[..., 1 : 1 + d], sums[..., 1 + d :]
    total = n.sum(-1)[:, None]  # (S, 1)
    var = s2.sum(1) / total - (s1.sum(1) / total) ** 2  # (S, d)
    within = (s2 - s1**2 / n.clamp_min(1)[..., None]).sum(1) / total
    return (
        var.mean(-1).clamp_min(0).sqrt().tolist(),
        within.mean(-1).clamp_min(0).sqrt().tolist(),
    )


def check_evaluation(batches: int, policy: str, seed: int = 0) -> None:
    """An evaluation's ``batches`` (>= 1), ``policy`` (:data:`EVAL_POLICIES`) and ``seed``
    (>= 0), as every evaluation here and a grid's ``evaluate`` list take them."""
    if policy not in EVAL_POLICIES:
        raise HamError(f"policy {policy!r}; accepted: {', '.join(EVAL_POLICIES)}")
    check_integer("batches", batches, 1)
    check_integer("seed", seed)


@contextmanager
def _evaluating(
    agent: HapticAttentionModel, env: HapticEnv, seed: int
) -> Iterator[torch.Generator]:
    """The agent in eval mode (its mode restored after) and a generator seeded by ``seed`` on
    the world's device: the set-up shared by every evaluation here, so that one seed gives the
    same episodes in each."""
    generator = torch.Generator(device=env.device)
    generator.manual_seed(int(seed))
    was_training = agent.training
    agent.eval()
    try:
        yield generator
    finally:
        agent.train(was_training)


def _batch_range(batches: int, progress: bool, desc: str) -> Iterable[int]:
    """``range(batches)``, with a progress bar on stderr when ``progress`` (the CLI's long
    evaluations; training's periodic evaluations pass none)."""
    if not progress:
        return range(batches)
    from tqdm.auto import tqdm

    return tqdm(range(batches), desc=desc, unit="batch", leave=False)


@torch.no_grad()
@checked_arguments
def evaluate(
    agent: HapticAttentionModel,
    env: HapticEnv,
    batches: int = 100,
    seed: int = 0,
    policy: str = "mean",
    progress: bool = False,
) -> EvalResult:
    """Accuracies of ``agent`` on ``batches`` balanced batches of ``env`` (poses seeded by ``seed``;
    ``progress``: a progress bar)."""
    check_evaluation(batches, policy, seed)
    glances, k = agent.config.glances, env.n_objects
    correct = torch.zeros(glances, device=env.device)
    accumulated = torch.zeros(glances, device=env.device)
    counts = torch.arange(1, glances + 1, device=env.device).view(-1, 1, 1)
    confusion = torch.zeros(glances * k * k, dtype=torch.long, device=env.device)
    offsets = torch.arange(glances, device=env.device).view(-1, 1) * (k * k)
    mu_sum = torch.zeros(k, len(agent.config.pose_dims), device=env.device, dtype=torch.float64)
    n_obj = torch.zeros(k, device=env.device, dtype=torch.float64)
    path = torch.zeros((), device=env.device, dtype=torch.float64)
    stop_correct = torch.zeros((), device=env.device, dtype=torch.float64)
    stop_glances_sum = torch.zeros((), device=env.device, dtype=torch.float64)
    width = 1 + 2 * len(agent.config.pose_dims)  # pose_sums: count, sums, sums of squares
    poses = torch.zeros(glances, k, width, device=env.device, dtype=torch.float64)
    with _evaluating(agent, env, seed) as generator:
        for b in _batch_range(batches, progress, "evaluate"):
            objects = env.balanced_objects(b)
            episode = agent(env, objects, generator, greedy=policy == "mean")
            predicted = episode.logits.argmax(-1)  # (S, B)
            correct += (predicted == objects).sum(1)
            path += path_lengths(episode.locations).sum().double()
            poses += pose_sums(episode.locations, objects, k)
            if episode.stop_logits is not None:
                at, _ = stop_glances(episode.stop_logits, greedy=True)
                answer = predicted[at - 1, torch.arange(objects.shape[0], device=env.device)]
                stop_correct += (answer == objects).sum().double()
                stop_glances_sum += at.sum().double()
            confusion += torch.bincount(
                (offsets + objects * k + predicted).flatten(), minlength=glances * k * k
            )
            averaged = episode.logits.softmax(-1).cumsum(0) / counts
            accumulated += (averaged.argmax(-1) == objects).sum(1)
            mode = episode.policy.mode() if episode.policy is not None else None
            if mode is not None:
                mu_sum.index_add_(0, objects, mode[-1].double())
                n_obj += torch.bincount(objects, minlength=k)
    stop = (stop_correct, stop_glances_sum) if agent.config.stop else None
    return eval_result(
        env, batches, correct, accumulated, confusion, mu_sum, n_obj, path, poses, stop
    )


def eval_result(
    env: HapticEnv,
    batches: int,
    correct: torch.Tensor,
    accumulated: torch.Tensor,
    confusion: torch.Tensor,
    mu_sum: torch.Tensor,
    n_obj: torch.Tensor,
    path: torch.Tensor,
    poses: torch.Tensor,
    stop: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> EvalResult:
    """The :class:`EvalResult` of one evaluation's counts over ``batches`` batches of ``env``:
    correct answers per glance ``(S,)``, the same of the averaged outputs ``(S,)``, the
    confusion counts ``(S * K * K,)``, the summed modes of the last policy ``(K, k)`` over
    ``n_obj`` episodes per object, the summed path lengths, the poses' :func:`pose_sums`, and
    with a learned stop its correct answers and glances used. (:mod:`ham.learn.batched`
    evaluates N runs at once and gives each its counts here.)"""
    glances, k = correct.shape[0], env.n_objects
    n = batches * env.batch_size
    per_glance = (correct / n).tolist()
    has_mu = bool(n_obj.sum() > 0)
    confusion = confusion.view(glances, k, k)
    last, shown = confusion[-1].diagonal().tolist(), confusion[-1].sum(1).tolist()
    per_object = [c / t if t else None for c, t in zip(last, shown, strict=True)]
    spread, within = pose_spreads(poses)
    return EvalResult(
        accuracy=per_glance[-1],
        accuracy_per_glance=per_glance,
        accumulated_accuracy_per_glance=(accumulated / n).tolist(),
        batches=batches,
        episodes=n,
        mu_mean=(mu_sum / n_obj.clamp_min(1)[:, None]).tolist() if has_mu else None,
        confusion=confusion.tolist(),
        per_object_accuracy=per_object,
        objects=[str(o) for o in env.objects],
        path_length=float(path / n),
        stop_accuracy=float(stop[0] / n) if stop is not None else None,
        mean_glances=float(stop[1] / n) if stop is not None else None,
        pose_spread=spread,
        pose_spread_within_object=within,
    )


@torch.no_grad()
@checked_arguments
def heatmap_data(
    agent: HapticAttentionModel,
    env: HapticEnv,
    batches: int = 1000,
    bins: int = 20,
    seed: int = 0,
    policy: str = "mean",
    progress: bool = False,
) -> dict:
    """The last glance's pose ``(q_x, q_phi)`` per object, binned ``bins x bins`` over
    ``[-1, 1]^2``, over ``batches`` balanced batches; with the mean and spread of the policy's
    mode (the learned ``mu_x, mu_phi``) and of its scale (``sigma``) that chose it (``None`` for a
    policy without them, the random one, or for one glance).

    Returns a JSON-ready dict; ``counts[o][i][j]`` counts object ``o`` with ``q_x`` in bin ``i``
    and ``q_phi`` in bin ``j``. With ``k`` pose dims (``pose_dims``) ``counts`` bins the first
    two, and ``projections`` holds every pair ``(a, b)`` of dims, ``{"dims": [a, b], "counts"}``
    (the k-D distribution's 2-D projections; one dim: its bins against a single one). ``mu_*``
    and ``sigma_mean`` have one column per pose dim.
    """
    check_evaluation(batches, policy, seed)
    if not (isinstance(bins, int) and 1 <= bins <= MAX_BINS):
        raise HamError(f"bins = {bins!r}; accepted: an integer 1..{MAX_BINS}")
    k = env.n_objects
    dims = tuple(agent.config.pose_dims)
    pairs = [(a, b) for a in range(len(dims)) for b in range(a + 1, len(dims))] or [(0, None)]
    counts = torch.zeros(len(pairs), k * bins * bins, device=env.device)
    mu_sum = torch.zeros(k, len(dims), device=env.device, dtype=torch.float64)
    mu_sq = torch.zeros_like(mu_sum)
    sigma_sum = torch.zeros_like(mu_sum)
    n_obj = torch.zeros(k, device=env.device, dtype=torch.float64)
    correct = 0.0
    has_mu = has_sigma = False
    with _evaluating(agent, env, seed) as generator:
        for b in _batch_range(batches, progress, "heat map"):
            objects = env.balanced_objects(b)
            episode = agent(env, objects, generator, greedy=policy == "mean")
            q = episode.locations[-1]
            cell = ((q + 1) * (bins / 2)).long().clamp(0, bins - 1)
            for i, (a, c) in enumerate(pairs):
                second = cell[:, c] if c is not None else torch.zeros_like(cell[:, a])
                counts[i] += torch.bincount(
                    (objects * bins + cell[:, a]) * bins + second, minlength=k * bins * bins
                )
            n_obj += torch.bincount(objects, minlength=k)
            correct += float((episode.logits[-1].argmax(-1) == objects).sum())
            mode = episode.policy.mode() if episode.policy is not None else None
            if mode is not None:
                mu = mode[-1].double()
                mu_sum.index_add_(0, objects, mu)
                mu_sq.index_add_(0, objects, mu * mu)
                has_mu = True
                scale = episode.policy.scale()
                if scale is not None:
                    sigma_sum.index_add_(0, objects, scale[-1].double())
                    has_sigma = True
    denom = n_obj.clamp_min(1)[:, None]
    mu_mean = mu_sum / denom
    mu_std = (mu_sq / denom - mu_mean**2).clamp_min(0).sqrt()
    return {
        "objects": [str(o) for o in env.objects],
        "glances": agent.config.glances,
        "policy": agent.config.policy,
        "eval_policy": policy,
        "batches": batches,
        "bins": bins,
        "range": [-1.0, 1.0],
        "phi_scale": agent.config.phi_scale,
        "pose_dims": list(dims),
        "counts": counts[0].view(k, bins, bins).long().tolist(),
        "projections": [
            {
                "dims": [dims[a], dims[c] if c is not None else None],
                "counts": counts[i].view(k, bins, bins).long().tolist(),
            }
            for i, (a, c) in enumerate(pairs)
        ]
        if dims != ("x", "phi")
        else None,  # fmt: skip
        "mu_mean": mu_mean.tolist() if has_mu else None,
        "mu_std": mu_std.tolist() if has_mu else None,
        "sigma_mean": (sigma_sum / denom).tolist() if has_sigma else None,
        "accuracy": correct / (batches * env.batch_size),
    }


#: The last glance's counterfactual poses of :func:`last_pose_swap`, in its result's order.
SWAPS: tuple[str, ...] = ("own", "same_object", "other_object", "uniform")


def swap_partners(objects: torch.Tensor, n_objects: int) -> tuple[torch.Tensor, torch.Tensor]:
    """For each episode of a batch ``objects`` ``(B,)``, an episode of the same object (the next
    one of that object, cyclically) and one of another object (the ``m``-th episode of object
    ``o`` takes the ``m``-th, cyclically, of object ``o + 1 + m mod (K - 1)``: every other object
    in turn). Every object needs two episodes in the batch, and ``K >= 2``."""
    counts = torch.bincount(objects, minlength=n_objects)
    if n_objects < 2 or int(counts.min()) < 2:
        raise HamError(
            f"a batch with {counts.tolist()} episodes per object; accepted: >= 2 objects and >= 2 "
            "episodes of each (a batch size >= 2 x the objects)"
        )
    members = [torch.nonzero(objects == o).flatten() for o in range(n_objects)]
    same = torch.empty_like(objects)
    other = torch.empty_like(objects)
    for o, idx in enumerate(members):
        same[idx] = idx.roll(-1)
        for m, i in enumerate(idx.tolist()):
            pool = members[(o + 1 + m % (n_objects - 1)) % n_objects]
            other[i] = pool[m % len(pool)]
    return same, other


def check_swappable(env) -> None:
    """A :class:`HamError` unless :func:`last_pose_swap` can replay ``env``'s glances."""
    if not isinstance(env, HapticEnv):
        raise HamError(
            f"the last pose swap on {type(env).__name__}; accepted: a haptic world (a table or "
            "the online simulator), whose glances can be replayed at chosen poses"
        )


@torch.no_grad()
def last_pose_swap(
    agent: HapticAttentionModel,
    env: HapticEnv,
    batches: int = 100,
    seed: int = 0,
    policy: str = "mean",
    progress: bool = False,
) -> dict:
    """How much the last glance's *pose* tells the classifier, beyond what is felt there.

    The episodes of :func:`evaluate` (same ``batches``, ``seed``, ``policy``) are replayed up to
    the last glance, which is then made at another pose, on the episode's own object:

    * ``own``: its own pose (the evaluation's accuracy, recomputed);
    * ``same_object``: the pose the policy chose in another episode of the same object;
    * ``other_object``: the pose the policy chose in an episode of another object;
    * ``uniform``: a uniform pose (the evaluation's generator, after the episodes).

    Where the policy sends the last glance to a pose that tells every object apart whatever the
    object, the four agree up to ``uniform``. Where the pose itself depends on the object
    (chosen from what earlier glances felt), a classifier that reads it (the "where" input) loses
    accuracy at another object's pose: ``own - other_object`` measures how much the location
    carries, the memory of the paper's MLP core, which sees only the last glance. The glances
    before the last are replayed at their recorded poses, so a core with memory keeps it. For a
    core without memory (the MLP) ``same_object`` is ``own`` exactly: it permutes the same
    (object, pose) glances among the object's episodes.
    Returns accuracies keyed by :data:`SWAPS`, with ``batches`` and ``episodes``.
    """
    check_evaluation(batches, policy, seed)
    check_swappable(env)
    k = env.n_objects
    correct = dict.fromkeys(SWAPS, 0)
    with _evaluating(agent, env, seed) as generator:
        episodes = []
        for b in _batch_range(batches, progress, "episodes"):
            objects = env.balanced_objects(b)
            episode = agent(env, objects, generator, greedy=policy == "mean")
            episodes.append((b, objects, episode.locations))
        for b in _batch_range(batches, progress, "last pose swaps"):
            _, objects, locations = episodes[b]
            env.balanced_objects(b)  # the batch's object poses again (objects varying in x, y)
            state = agent.core.initial_state(len(objects), locations[0])
            for q in locations[:-1]:
                _, state = agent.glance_step(env, objects, q, state)
            last = locations[-1]
            same, other = swap_partners(objects, k)
            uniform = uniform_locations(len(objects), generator, env.device, last.shape[-1])
            for name, q in zip(SWAPS, (last, last[same], last[other], uniform), strict=True):
                tau, _ = agent.glance_step(env, objects, q, state)
                correct[name] += int((agent.classifier(tau).argmax(-1) == objects).sum())
    n = batches * env.batch_size
    return {**{name: c / n for name, c in correct.items()}, "batches": batches, "episodes": n}
