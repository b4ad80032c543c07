"""Reference policies on a glance table, computed exactly: random, grid, infogain and oracle.

A glance table makes the world deterministic and finite: object ``k`` at grid pose ``p`` gives
one image. An observer who knows the poses and sees the images can only confuse objects whose
images agree at every glance so far, so its knowledge after a glance sequence is the *consistent
set* ``S`` (the Bayes posterior is uniform on ``S`` under the uniform prior over objects), and the
best classifier is right with probability ``1 / |S|``. Each pose splits ``S`` into the classes
of objects with equal images (:class:`Partitions`); poses with the same split are one action.
Everything below is exact dynamic programming over consistent sets (``2^K`` of them), not Monte
Carlo:

* ``random``: poses drawn uniformly from ``[-1, 1]^k`` (``k`` pose dims: 2 on the paper's
  ``(x, phi)`` table, up to 4 on a format-2 table) and looked up at the nearest grid point,
  as the random-location model (pi_rloc) draws them; the Bayes accuracy of any classifier of such
  glances (the exact version of :mod:`ham.experiments.random_glance_bound`).
* ``grid``: a fixed systematic sweep, the same ``G`` poses for every object (:func:`sweep`).
* ``infogain``: greedy expected information gain: each glance takes the pose whose split of the
  current consistent set leaves the least expected entropy ``sum_c |c|/|S| log|c|``.
* ``oracle``: a perfect planner: ``max`` over poses of the expected accuracy after ``G`` glances,
  and ``N*``, the smallest expected number of glances that identifies the object (up to objects
  no pose tells apart).

``first="random"`` makes the first glance uniform, as the HAM's is (its location network acts
from glance 2 on), so learned policies can be judged against planners with the same handicap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache, lru_cache

import numpy as np
import torch

from ham.errors import HamError
from ham.model.policy import sweep  # the grid policy's poses: one definition for both

POLICIES: tuple[str, ...] = ("random", "grid", "infogain", "oracle")
FIRST: tuple[str, ...] = ("planned", "random")
#: Consistent sets are bit masks over objects: 2^K states.
MAX_OBJECTS = 20
#: The grid sweep lists its poses: beyond this many glances it would take minutes and gigabytes.
MAX_SWEEP = 1_000_000
#: The random policy's chain is squared as a dense matrix up to this many consistent sets.
MAX_DENSE_SETS = 1024


@dataclass(frozen=True)
class Partitions:
    """How each distinct pose action splits the objects.

    Attributes:
        labels: ``(U, K)`` int: objects with equal labels give equal images at that action.
        weight: ``(U,)`` probability of the action under uniform poses (nearest grid point).
        pose: ``(U, k)`` one grid pose (normalized, one column per pose dim) that realizes the
            action: ``(q_x, q_phi)`` on the paper's table.
        grid_action: the action index of every grid pose, shaped like the table's pose lattice
            (``(grid, grid)`` on the paper's table, ``(g_1, .., g_k)`` on a k-D one).
    """

    labels: np.ndarray
    weight: np.ndarray
    pose: np.ndarray
    grid_action: np.ndarray

    @property
    def n_objects(self) -> int:
        return self.labels.shape[1]

    @classmethod
    def from_table(
        cls, table, tolerance: float = 1e-6, height: bool = False, chunk: int = 4096
    ) -> Partitions:
        """Split each grid pose's objects by their L2-normalized images (the agent's input):
        two images are equal when they differ by at most ``tolerance`` in L2 norm. ``height``:
        the glances' contact heights tell objects apart too (the HAM's ``height_input``: the
        image and ``h / MAX_HEIGHT`` must both agree within ``tolerance``).

        Any pose lattice held in memory: the paper's ``(x, phi)`` square or a format-2 table
        over ``k`` pose dims (the planners see grid poses, not what they mean); ``chunk`` grid
        poses are compared at a time (memory)."""
        from ham.world.sensor import normalize
        from ham.world.table import grid_values

        if not (math.isfinite(tolerance) and tolerance >= 0):
            raise HamError(f"tolerance = {tolerance!r}; accepted: a finite number >= 0")
        k, g = table.n_objects, table.grid
        dims = tuple(getattr(table, "pose_dims", ("x", "phi")))
        shape = tuple(getattr(table, "grid_shape", (g, g)))
        if table.pressure is None:
            raise HamError(
                f"a streamed table over pose grid {'x'.join(map(str, shape))} "
                f"({','.join(dims)}); the exact planners accept a table held in memory "
                "(a smaller grid)"
            )
        if k > MAX_OBJECTS:
            raise HamError(
                f"the table has {k} objects; exact planners accept at most {MAX_OBJECTS}"
            )
        n_poses = int(np.prod(shape))
        images = table.pressure.reshape(k, n_poses, *table.pressure.shape[-2:])
        if height and not table.knows_heights:
            raise HamError(
                "height = True on a table that does not know every glance's contact height "
                "(NaN: imported without heights); accepted: height = False, or a table with "
                "heights"
            )
        heights = table.height.reshape(k, n_poses, 1) if height else None
        labels = np.empty((n_poses, k), dtype=np.int64)
        for start in range(0, n_poses, chunk):
            sl = slice(start, start + chunk)
            p = normalize(images[:, sl].double(), "l2")  # (K, c, D)
            if height:
                from ham.world.objects import MAX_HEIGHT

                p = torch.cat([p, heights[:, sl].double().to(p.device) / MAX_HEIGHT], -1)
            p = p.transpose(0, 1)  # (c, K, D)
            same = (torch.cdist(p, p) <= tolerance).cpu().numpy()  # (c, K, K)
            # label = the first object equal to this one (exact equality makes this a partition)
            labels[sl] = same.argmax(-1)
        rows, action = np.unique(labels, axis=0, return_inverse=True)
        action = action.reshape(-1)
        # The nearest grid point of a uniform q: half cells at the ends, on every axis.
        w_pose = np.ones(())
        for n in shape:
            cell = np.full(n, 2.0 / (n - 1))
            cell[[0, -1]] /= 2
            w_pose = np.multiply.outer(w_pose, cell / 2.0)
        weight = np.bincount(action, weights=w_pose.reshape(-1), minlength=len(rows))
        _, first = np.unique(action, return_index=True)  # the first pose of each action
        idx = np.unravel_index(first, shape)
        pose = np.stack([grid_values(n)[i] for n, i in zip(shape, idx, strict=True)], axis=1)
        return cls(rows, weight, pose, action.reshape(shape))

    def identifying_share(self) -> float:
        """The probability that one uniform pose tells every object apart: the weight of the
        actions whose split leaves each object alone. 0 when no single glance can identify
        every object; then only sequences (or nothing) can."""
        alone = np.array([len(np.unique(row)) == self.n_objects for row in self.labels])
        return float(self.weight[alone].sum())

    def split(self, mask: int, action: int) -> list[int]:
        """The classes (bit masks) an action splits the consistent set ``mask`` into."""
        classes: dict[int, int] = {}
        for k in range(self.n_objects):
            if mask >> k & 1:
                lab = int(self.labels[action, k])
                classes[lab] = classes.get(lab, 0) | (1 << k)
        return list(classes.values())

    def splits_of(self, mask: int) -> list[tuple[int, list[int]]]:
        """Distinct splits of ``mask`` (one action each, the first that realizes it)."""
        seen: dict[tuple[int, ...], int] = {}
        out = []
        for a in range(len(self.labels)):
            parts = self.split(mask, a)
            key = tuple(sorted(parts))
            if key not in seen:
                seen[key] = a
                out.append((a, parts))
        return out


def _size(mask: int) -> int:
    return bin(mask).count("1")


def _entropy_left(parts: list[int], size: int) -> float:
    """Expected posterior entropy (nats) after a split: ``sum_c |c|/|S| log|c|``."""
    return sum(_size(c) / size * math.log(_size(c)) for c in parts)


class Planner:
    """Exact accuracies of the reference policies on one :class:`Partitions`."""

    def __init__(self, partitions: Partitions) -> None:
        self.parts = partitions
        self.k = partitions.n_objects
        self.full = (1 << self.k) - 1

    # ------------------------------------------------------------------ one object's view
    def _mean_over_objects(self, value) -> float:
        """``value(mask_after_first_information)``: averaged over the true object."""
        return float(np.mean([value(k) for k in range(self.k)]))

    def _after(self, mask: int, action: int, k: int) -> int:
        """The consistent set after seeing object ``k``'s image at ``action``."""
        lab = self.parts.labels[action]
        keep = 0
        for j in range(self.k):
            if mask >> j & 1 and lab[j] == lab[k]:
                keep |= 1 << j
        return keep

    # ------------------------------------------------------------------ policies
    def random(self, glances: int) -> float:
        """Bayes accuracy of ``glances`` uniform random poses: exact expectation over poses.

        For the true object ``k`` the consistent set is a Markov chain over the sets reachable
        from all objects (a glance keeps the set or shrinks it); the accuracy is the chain's
        distribution after ``glances`` steps, weighted by ``1 / |S|``, without recursion: sparse
        steps, or, with more glances than sets (up to :data:`MAX_DENSE_SETS` of them), the
        matrix power by squaring, ``O(n^3 log G)``."""
        return self._mean_over_objects(lambda k: self._random_one(k, glances))

    def _random_one(self, k: int, glances: int) -> float:
        w = self.parts.weight / self.parts.weight.sum()  # 1 - 7e-14 on a 201 x 201 grid: rounding
        masks = [self.full]
        index = {self.full: 0}
        src: list[int] = []
        dst: list[int] = []
        prob: list[float] = []
        for i, mask in enumerate(masks):  # breadth first: the loop sees the sets it appends
            row: dict[int, float] = {}  # the few sets this one can shrink to, and how likely
            for a in range(len(w)):
                after = self._after(mask, a, k)
                if after not in index:
                    index[after] = len(masks)
                    masks.append(after)
                row[index[after]] = row.get(index[after], 0.0) + float(w[a])
            src += [i] * len(row)
            dst += list(row)
            prob += list(row.values())
        n = len(masks)
        src_a, dst_a, prob_a = np.array(src), np.array(dst), np.array(prob)
        dist = np.zeros(n)
        dist[0] = 1.0
        if glances > n and n <= MAX_DENSE_SETS:  # by squaring, kept stochastic: rounding
            step = np.zeros((n, n))  # would otherwise grow with the glances
            np.add.at(step, (src_a, dst_a), prob_a)
            step /= step.sum(1, keepdims=True)
            g = glances
            while g:
                if g & 1:
                    dist = dist @ step
                    dist /= dist.sum()
                step = step @ step
                step /= step.sum(1, keepdims=True)
                g >>= 1
        else:  # step by step (sparse); a distribution that no longer changes is final
            for _ in range(glances):
                after = np.bincount(dst_a, weights=dist[src_a] * prob_a, minlength=n)
                if np.array_equal(after, dist):
                    break
                dist = after
        inverse_size = np.array([1.0 / _size(m) for m in masks])
        return float(dist @ inverse_size)

    def grid(self, glances: int) -> float:
        """Bayes accuracy of the fixed sweep :func:`sweep` (the same poses for every object)."""
        from ham.world.table import nearest_index

        if glances > MAX_SWEEP:
            raise HamError(
                f"glances = {glances} for the grid sweep; accepted: 1..{MAX_SWEEP} (its poses "
                "are listed one by one)"
            )
        shape = self.parts.grid_action.shape
        poses = torch.from_numpy(sweep(glances, len(shape)))
        idx = tuple(nearest_index(poses[:, j], n).numpy() for j, n in enumerate(shape))
        actions = self.parts.grid_action[idx]

        def one(k: int) -> float:
            mask = self.full
            for a in actions:
                mask = self._after(mask, int(a), k)
            return 1.0 / _size(mask)

        return self._mean_over_objects(one)

    def _greedy_action(self, mask: int) -> int:
        best, best_h = 0, math.inf
        size = _size(mask)
        for a, parts in self.parts.splits_of(mask):
            h = _entropy_left(parts, size)
            if h < best_h - 1e-12:
                best, best_h = a, h
        return best

    def infogain(self, glances: int, first: str = "planned") -> float:
        """Accuracy of greedy expected-information-gain glances (ties: the first action)."""
        greedy = lru_cache(maxsize=None)(self._greedy_action)

        @cache
        def acc(mask: int, k: int, g: int) -> float:
            after = self._after(mask, greedy(mask), k) if g else mask
            if after == mask:  # no glance left, or the greedy pose splits nothing: it never will
                return 1.0 / _size(mask)
            return acc(after, k, g - 1)

        return self._with_first(acc, glances, first)

    def oracle(self, glances: int, first: str = "planned") -> float:
        """The best expected accuracy any policy reaches with ``glances`` glances (exact)."""

        @cache
        def best(mask: int, g: int) -> float:
            size = _size(mask)
            # A glance that splits nothing can be left out, and each one that splits shrinks the
            # set on every path: more than size - 1 glances cannot help (recursion depth <= K).
            g = min(g, size - 1)
            if g == 0:
                return 1.0 / size
            return max(
                sum(_size(c) / size * best(c, g - 1) for c in parts)
                for _, parts in self.parts.splits_of(mask)
            )

        if first == "planned":
            return best(self.full, glances)
        return self._with_first(lambda m, k, g: best(m, g), glances, first)

    def _with_first(self, acc, glances: int, first: str) -> float:
        if first not in FIRST:
            raise HamError(f"first = {first!r}; accepted: {', '.join(FIRST)}")
        if glances < 1:
            raise HamError(f"glances = {glances!r}; accepted: an integer >= 1")
        if first == "planned":
            return self._mean_over_objects(lambda k: acc(self.full, k, glances))
        w = self.parts.weight
        return self._mean_over_objects(
            lambda k: sum(
                w[a] * acc(self._after(self.full, a, k), k, glances - 1) for a in range(len(w))
            )
        )

    # ------------------------------------------------------------------ glances to identify
    def expected_glances(self, policy: str = "oracle", first: str = "planned") -> float:
        """Expected glances until the consistent set cannot shrink any more: ``N*`` for the
        ``oracle`` (optimal over all adaptive policies), the greedy planner's for ``infogain``;
        with ``first="random"`` the first glance is uniform and counts as one."""
        if policy not in ("oracle", "infogain"):
            raise HamError(f"policy = {policy!r}; accepted: oracle, infogain")
        if first not in FIRST:
            raise HamError(f"first = {first!r}; accepted: {', '.join(FIRST)}")

        @cache
        def cost(mask: int) -> float:
            splits = [(a, p) for a, p in self.parts.splits_of(mask) if len(p) > 1]
            if not splits:
                return 0.0  # identified, or no pose tells these objects apart
            size = _size(mask)
            if policy == "infogain":
                parts = self.parts.split(mask, self._greedy_action(mask))
                return 1 + sum(_size(c) / size * cost(c) for c in parts)
            return 1 + min(sum(_size(c) / size * cost(c) for c in p) for _, p in splits)

        if first == "planned":
            return cost(self.full)
        w = self.parts.weight
        return 1 + self._mean_over_objects(
            lambda k: sum(w[a] * cost(self._after(self.full, a, k)) for a in range(len(w)))
        )

    def accuracy(self, policy: str, glances: int, first: str = "planned") -> float:
        """Expected accuracy of ``policy`` after ``glances`` glances."""
        if not (isinstance(glances, int) and glances >= 1):
            raise HamError(f"glances = {glances!r}; accepted: an integer >= 1")
        if policy == "random":
            return self.random(glances)
        if policy == "grid":
            return self.grid(glances)
        if policy == "infogain":
            return self.infogain(glances, first)
        if policy == "oracle":
            return self.oracle(glances, first)
        raise HamError(f"policy = {policy!r}; accepted: {', '.join(POLICIES)}")
