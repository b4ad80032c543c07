"""The batched training environment: objects to classify and the glances on them.

Section "Training": "for each training step, a new batch of size 64 is generated, where the
to-be-classified objects are uniformly chosen from the set of all four available objects"; there is
no fixed training set. :class:`HapticEnv` draws such batches from its own seeded
``torch.Generator`` and answers glances ``q = (q_x, q_phi) in [-1, 1]^2`` with normalized
pressure vectors (L2 by default, the paper; L1 as in the authors' code).

Glances come from a :class:`ham.world.source.GlanceSource`. Evaluation uses balanced batches (:meth:`HapticEnv.balanced_objects`).
"""

from __future__ import annotations

import torch

from ham.errors import HamError
from ham.world.sensor import NORMALIZATIONS, normalize
from ham.world.source import GlanceSource


class HapticEnv:
    """Batches of objects and their normalized glances.

    Args:
        source: where glances come from.
        batch_size: objects per batch (64, the paper).
        normalization: ``l2`` (paper), ``l1`` (authors' code) or ``none``.
        seed: seeds the generator of the training batches' objects.
        device: where batches live (the source's device).
    """

    def __init__(
        self,
        source: GlanceSource,
        batch_size: int = 64,
        normalization: str = "l2",
        seed: int = 0,
        device: str | torch.device = "cpu",
    ) -> None:
        if not (isinstance(batch_size, int) and batch_size >= 1):
            raise HamError(f"batch_size = {batch_size!r}; accepted: an integer >= 1")
        if normalization not in NORMALIZATIONS:
            raise HamError(
                f"normalization {normalization!r}; accepted: {', '.join(NORMALIZATIONS)}"
            )
        self.source = source
        self.n_objects = source.n_objects
        self.pressure_dim = source.pressure_dim
        self.batch_size = batch_size
        self.normalization = normalization
        self.device = torch.device(device)
        self.generator = torch.Generator(device=self.device)
        self.generator.manual_seed(int(seed))

    @property
    def objects(self) -> list:
        """The objects' names, in class order."""
        return list(self.source.objects)

    def sample_objects(self) -> torch.Tensor:
        """A fresh training batch: object ids drawn uniformly, ``(B,)`` long."""
        return torch.randint(
            self.n_objects, (self.batch_size,), generator=self.generator, device=self.device
        )

    def balanced_objects(self, batch_index: int = 0) -> torch.Tensor:
        """Evaluation batch ``batch_index``: ids cycle 0, 1, .., K-1, so every object appears
        equally often (exactly when ``K`` divides the batch size, else over consecutive batches)."""
        start = batch_index * self.batch_size
        return torch.arange(start, start + self.batch_size, device=self.device) % self.n_objects

    def glance(self, object_ids: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
        """Normalized pressure vectors ``(B, N^2)`` (256) for the poses ``q`` ``(B, 2)`` in ``[-1, 1]``."""
        pressure = self.source.lookup(object_ids, q[:, 0], q[:, 1])
        return normalize(pressure.to(self.device, torch.float32), self.normalization)

    # ---------------------------------------------------------------- checkpoints
    def state_dict(self) -> dict:
        return {"generator": self.generator.get_state()}

    def load_state_dict(self, state: dict) -> None:
        self.generator.set_state(state["generator"])
