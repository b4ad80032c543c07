"""The batched training environment: objects to classify and the glances on them.

Section "Training": "for each training step, a new batch of size 64 is generated, where the
to-be-classified objects are uniformly chosen from the set of all four available objects"; there is
no fixed training set. :class:`HapticEnv` draws such batches from its own seeded
``torch.Generator`` and answers glances ``q = (q_x, q_phi) in [-1, 1]^2`` with normalized
pressure vectors (L2 by default, the paper; L1 as in the authors' code). Beyond the paper:
``q in [-1, 1]^k`` over the world's pose dims, the contact height ``h`` with each glance
(:meth:`HapticEnv.glance_height`), a random object pose per episode (``object_pose``), and
actuation noise: each glance made a little off the pose the agent chose (``pose_noise``).

Glances come from a :class:`ham.world.source.GlanceSource`. Evaluation uses balanced batches (:meth:`HapticEnv.balanced_objects`).
"""

from __future__ import annotations

import math

import torch

from ham.errors import HamError
from ham.world.sensor import check_normalization, gaussian_spread_rows, normalize
from ham.world.source import GlanceSource, ObjectPoseConfig

# keeps the evaluation batches' noise seeds apart from their object-pose seeds
_NOISE_STREAM = 2**40


def check_pose_noise(pose_noise) -> None:
    """A pose noise (standard deviation, normalized pose units): a number 0..1."""
    v = pose_noise
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v <= 1:
        raise HamError(f"pose_noise = {v!r}; accepted: a number 0..1 (normalized pose units)")


class HapticEnv:
    """Batches of objects and their normalized glances.

    Args:
        source: where glances come from.
        batch_size: objects per batch (64, the paper).
        normalization: ``l2`` (paper), ``l1`` (authors' code) or ``none``.
        seed: seeds the generator of the training batches' objects.
        device: where batches live (the source's device).
        object_pose: a random object pose per episode (:class:`ObjectPoseConfig`; ``None`` or
            a disabled one: the objects stay at their pose, the paper). Training batches draw
            it from the object generator; evaluation batch ``i`` from its own seed.
        pose_noise: the standard deviation of Gaussian noise on each glance's pose, in the
            normalized units (0: none, the paper). The glance is made at the noisy pose,
            clamped to ``[-1, 1]``; the caller keeps the pose it chose. Training batches draw
            the noise from the object generator (so checkpoints hold it), evaluation batch
            ``i`` from a generator of its own seed, glance after glance: the same evaluation
            episodes at every evaluation, and evaluating leaves the training stream as it was.
        augment_sigma: domain randomization of the read-out (beyond the paper): each training
            episode's images spread by a Gaussian of a sigma drawn uniformly in ``[0,
            augment_sigma]`` cells (drawn from the object generator with the batch); evaluation
            batches are the world's own glances. 0: off.
    """

    def __init__(
        self,
        source: GlanceSource,
        batch_size: int = 64,
        normalization: str = "l2",
        seed: int = 0,
        device: str | torch.device = "cpu",
        object_pose: ObjectPoseConfig | None = None,
        pose_noise: float = 0.0,
        augment_sigma: float = 0.0,
    ) -> None:
        if not (isinstance(batch_size, int) and batch_size >= 1):
            raise HamError(f"batch_size = {batch_size!r}; accepted: an integer >= 1")
        check_normalization(normalization)
        check_pose_noise(pose_noise)
        self.source = source
        self.pose_dims = tuple(getattr(source, "pose_dims", ("x", "phi")))
        self.n_objects = source.n_objects
        self.pressure_dim = source.pressure_dim
        self.batch_size = batch_size
        self.normalization = normalization
        self.device = torch.device(device)
        self.generator = torch.Generator(device=self.device)
        self.generator.manual_seed(int(seed))
        self.seed = int(seed)
        self.object_pose = object_pose if object_pose and object_pose.enabled else None
        self._pose: tuple[torch.Tensor, ...] | None = None  # the current batch's object poses
        self.pose_noise = float(pose_noise)
        self._noise = self.generator  # the current batch's pose-noise generator
        if not (isinstance(augment_sigma, (int, float)) and math.isfinite(augment_sigma)
                and augment_sigma >= 0):  # fmt: skip
            raise HamError(f"augment_sigma = {augment_sigma!r}; accepted: a finite number >= 0")
        self.augment_sigma = float(augment_sigma)
        self._sigmas: torch.Tensor | None = None  # the current training batch's spreads

    @property
    def objects(self) -> list:
        """The objects' names, in class order."""
        return list(self.source.objects)

    def sample_objects(self) -> torch.Tensor:
        """A fresh training batch: object ids drawn uniformly, ``(B,)`` long (and, with
        ``object_pose``, their poses for this episode)."""
        ids = torch.randint(
            self.n_objects, (self.batch_size,), generator=self.generator, device=self.device
        )
        if self.object_pose is not None:
            self._pose = self.object_pose.sample(len(ids), self.generator, self.device)
        self._noise = self.generator
        if self.augment_sigma > 0:
            u = torch.rand(len(ids), generator=self.generator, device=self.device)
            self._sigmas = u * self.augment_sigma
        return ids

    def balanced_objects(self, batch_index: int = 0) -> torch.Tensor:
        """Evaluation batch ``batch_index``: ids cycle 0, 1, .., K-1, so every object appears
        equally often (exactly when ``K`` divides the batch size, else over consecutive batches).
        With ``object_pose`` their poses come from a generator seeded by the batch index: the
        same evaluation batches at every evaluation."""
        start = batch_index * self.batch_size
        ids = torch.arange(start, start + self.batch_size, device=self.device) % self.n_objects
        self._sigmas = None  # evaluation: the world's own glances
        if self.object_pose is not None:
            g = self._eval_generator(batch_index)
            self._pose = self.object_pose.sample(len(ids), g, self.device)
        if self.pose_noise > 0:
            self._noise = self.eval_noise_generator(batch_index)
        return ids

    def _eval_generator(self, batch_index: int, stream: int = 0) -> torch.Generator:
        """A generator of evaluation batch ``batch_index``, seeded by the env's seed, the batch
        and ``stream`` (0: object poses, :data:`_NOISE_STREAM`: pose noise)."""
        g = torch.Generator(device=self.device)
        g.manual_seed(10_007 * (self.seed + 1) + batch_index + stream)
        return g

    def eval_noise_generator(self, batch_index: int) -> torch.Generator:
        """The pose-noise generator of evaluation batch ``batch_index``: each glance of the
        batch draws ``randn(B, k)`` from it in turn (the batched evaluation draws the same)."""
        return self._eval_generator(batch_index, _NOISE_STREAM)

    def executed(self, q: torch.Tensor, noise: torch.Tensor | None = None) -> torch.Tensor:
        """The poses the glances at ``q`` ``(B, k)`` are made at: ``q`` itself, or with
        ``pose_noise`` ``q`` plus Gaussian noise, clamped to ``[-1, 1]`` (the pad cannot leave
        its range). The noise ``randn(B, k)`` is drawn from the current batch's generator, or
        given (``noise``: drawn ahead, as the batched evaluation does)."""
        if self.pose_noise == 0:
            return q
        if noise is None:
            noise = torch.randn(q.shape, generator=self._noise, device=self.device)
        return (q + noise.to(q.dtype) * self.pose_noise).clamp(-1, 1)

    def glance_height(
        self, object_ids: torch.Tensor, q: torch.Tensor, *, exact: bool = False
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Normalized pressure vectors ``(B, N^2)`` (256) and contact heights ``(B,)`` (m) for
        the poses ``q`` ``(B, k)`` in ``[-1, 1]`` (columns: the world's pose dims), made at
        :meth:`executed` poses (``exact``: at ``q`` itself, poses already executed)."""
        pose = self._pose
        for what, drawn in (("object poses", None if pose is None else pose[0]),
                            ("spreads", self._sigmas)):  # fmt: skip
            if drawn is not None and drawn.shape[0] != object_ids.shape[0]:
                raise HamError(
                    f"{object_ids.shape[0]} objects but the batch drew {drawn.shape[0]} {what}; "
                    "accepted: the ids of the last sample_objects/balanced_objects batch"
                )
        at = q if exact else self.executed(q)
        pressure, height = self.source.glance(object_ids, at, pose)
        return self.read_out(pressure, self._sigmas), height.to(self.device, torch.float32)

    @property
    def batch_spreads(self) -> torch.Tensor | None:
        """The current training batch's read-out spreads ``(B,)`` in cells (``augment_sigma``),
        or ``None``: evaluation batches, or no augmentation."""
        return self._sigmas

    def read_out(self, pressure: torch.Tensor, spreads: torch.Tensor | None = None) -> torch.Tensor:
        """Raw images ``(B, N, N)`` as the agent reads them, ``(B, N^2)``: each spread by its
        own sigma of ``spreads`` ``(B,)`` cells (the training batch's domain randomization,
        :attr:`batch_spreads`; ``None``: as recorded), then normalized."""
        pressure = pressure.to(self.device, torch.float32)
        if spreads is not None:
            pressure = gaussian_spread_rows(pressure, spreads, self.augment_sigma)
        return normalize(pressure, self.normalization)

    def glance(
        self, object_ids: torch.Tensor, q: torch.Tensor, *, exact: bool = False
    ) -> torch.Tensor:
        """Normalized pressure vectors ``(B, N^2)`` (256) for the poses ``q`` ``(B, k)`` in
        ``[-1, 1]`` (``k = 2``, ``(q_x, q_phi)``, in the paper); ``exact`` as in
        :meth:`glance_height`."""
        return self.glance_height(object_ids, q, exact=exact)[0]

    # ---------------------------------------------------------------- checkpoints
    def state_dict(self) -> dict:
        return {"generator": self.generator.get_state()}

    def load_state_dict(self, state: dict) -> None:
        self.generator.set_state(state["generator"])
