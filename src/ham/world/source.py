"""Glance sources: where a batch of glances comes from.

* :class:`TableSource`: a pre-recorded glance table, the closest grid point (the paper's way);
* :class:`OnlineSource`: the fast simulator itself, at the exact pose (no grid; beyond the paper).

Both answer ``lookup(object_ids, q_x, q_phi)`` with raw pressure images on CPU or CUDA.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol, runtime_checkable

import torch

from ham.world.config import WorldConfig, make_simulator


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
    """Glances looked up in a :class:`ham.world.table.GlanceTable`: the closest grid point (the paper)."""

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
        from ham.world.table import GlanceTable

        t = GlanceTable.load(table, device=str(device))
        return TableSource(t), t.world
    world = world or WorldConfig()
    return OnlineSource(make_simulator(world, device=str(device))), world
