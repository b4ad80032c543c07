"""The batched training environment: objects to classify and the glances on them.

Section "Training": "for each training step, a new batch of size 64 is generated, where the
to-be-classified objects are uniformly chosen from the set of all four available objects"; there is
no fixed training set. :class:`HapticEnv` draws such batches from its own seeded
``torch.Generator`` and answers glances ``q = (q_x, q_phi) in [-1, 1]^2`` with normalized
pressure vectors (L2 by default, the paper; L1 as in the authors' code).

Glances come from a :class:`GlanceSource`:

* :class:`TableSource`: a pre-recorded glance table, the closest grid point (the paper's way);
* :class:`OnlineSource`: the fast simulator itself, at the exact pose (no grid; beyond the paper).

Both run on CPU or CUDA. Evaluation uses balanced batches (:meth:`HapticEnv.balanced_objects`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol, runtime_checkable

import torch

from ham.errors import HamError
from ham.sensor import NORMALIZATIONS, normalize
from ham.world import WorldConfig, make_simulator


@runtime_checkable
class GlanceSource(Protocol):
    """Anything that answers batches of glances with raw pressure images."""

    n_objects: int
    objects: list

    def lookup(
        self, object_ids: torch.Tensor, q_x: torch.Tensor, q_phi: torch.Tensor
    ) -> torch.Tensor:
        """Raw pressure ``(B, 16, 16)`` for objects ``(B,)`` at normalized poses ``(B,)``."""
        ...


class OnlineSource:
    """Glances simulated on demand by a simulator (``FastSimulator``: CPU or CUDA, no grid)."""

    def __init__(self, simulator) -> None:
        self.simulator = simulator
        self.objects = [o.name for o in simulator.objects]
        self.n_objects = len(self.objects)

    def lookup(
        self, object_ids: torch.Tensor, q_x: torch.Tensor, q_phi: torch.Tensor
    ) -> torch.Tensor:
        return self.simulator.glance(object_ids, q_x, q_phi).pressure


class TableSource:
    """Glances looked up in a :class:`ham.table.GlanceTable`: the closest grid point (the paper)."""

    def __init__(self, table) -> None:
        self.table = table
        self.objects = list(table.objects)
        self.n_objects = len(self.objects)

    def lookup(
        self, object_ids: torch.Tensor, q_x: torch.Tensor, q_phi: torch.Tensor
    ) -> torch.Tensor:
        # The environment's own actions are always in range: skip the per-call validation.
        return self.table.lookup(object_ids, q_x, q_phi, check=False)


def make_source(
    table: str | Path | None = None,
    world: WorldConfig | None = None,
    device: str | torch.device = "cpu",
) -> tuple[GlanceSource, WorldConfig]:
    """A glance table's source when ``table`` is given, else the online simulator of ``world``."""
    if table is not None:
        from ham.table import GlanceTable

        t = GlanceTable.load(table, device=str(device))
        return TableSource(t), t.world
    world = world or WorldConfig()
    return OnlineSource(make_simulator(world, device=str(device))), world


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
        self.batch_size = batch_size
        self.normalization = normalization
        self.device = torch.device(device)
        self.generator = torch.Generator(device=self.device)
        self.generator.manual_seed(int(seed))

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
        """Normalized pressure vectors ``(B, 256)`` for the poses ``q`` ``(B, 2)`` in ``[-1, 1]``."""
        pressure = self.source.lookup(object_ids, q[:, 0], q[:, 1])
        return normalize(pressure.to(self.device, torch.float32), self.normalization)

    # ---------------------------------------------------------------- checkpoints
    def state_dict(self) -> dict:
        return {"generator": self.generator.get_state()}

    def load_state_dict(self, state: dict) -> None:
        self.generator.set_state(state["generator"])
