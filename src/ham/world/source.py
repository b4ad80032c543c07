"""Glance sources: where a batch of glances comes from.

* :class:`TableSource`: a pre-recorded glance table, the closest grid point (the paper's way);
* :class:`OnlineSource`: the fast simulator itself, at the exact pose (no grid; beyond the paper).

Both answer ``lookup(object_ids, q_x, q_phi)`` with raw pressure images on CPU or CUDA.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Protocol, runtime_checkable

import torch

from ham.errors import HamError
from ham.world.config import WorldConfig, make_simulator
from ham.world.sensor import SensorConfig


@runtime_checkable
class GlanceSource(Protocol):
    """Anything that answers batches of glances with raw pressure images."""

    n_objects: int
    objects: list
    taxels: int
    pressure_dim: int

    def lookup(
        self, object_ids: torch.Tensor, q_x: torch.Tensor, q_phi: torch.Tensor
    ) -> torch.Tensor:
        """Raw pressure ``(B, N, N)`` for objects ``(B,)`` at normalized poses ``(B,)``."""
        ...


class _Source:
    """What every source tells about its glances: the objects, the pad's ``N``, a description."""

    def __init__(self, objects: list, taxels: int, description: str) -> None:
        self.objects = list(objects)
        self.n_objects = len(self.objects)
        self.taxels = int(taxels)
        self.pressure_dim = self.taxels**2
        self.description = description


class OnlineSource(_Source):
    """Glances simulated on demand by a simulator (``FastSimulator``: CPU or CUDA, no grid)."""

    def __init__(self, simulator) -> None:
        self.simulator = simulator
        sensor = getattr(simulator, "sensor", None) or SensorConfig()
        objects = [o.name for o in simulator.objects]
        super().__init__(objects, sensor.taxels, f"the online {simulator.name} simulator")

    def lookup(
        self, object_ids: torch.Tensor, q_x: torch.Tensor, q_phi: torch.Tensor
    ) -> torch.Tensor:
        return self.simulator.glance(object_ids, q_x, q_phi).pressure


class TableSource(_Source):
    """Glances looked up in a :class:`ham.world.table.GlanceTable`: the closest grid point (the paper)."""

    def __init__(self, table) -> None:
        self.table = table
        super().__init__(table.objects, table.taxels, f"glance table {table.info.path!r}")

    def lookup(
        self, object_ids: torch.Tensor, q_x: torch.Tensor, q_phi: torch.Tensor
    ) -> torch.Tensor:
        # The environment's own actions are always in range: skip the per-call validation.
        return self.table.lookup(object_ids, q_x, q_phi, check=False)


def check_model_fits(pressure_dim: int, n_objects: int, source: GlanceSource) -> None:
    """Refuse a model (``pressure_dim`` inputs, ``n_objects`` classes) that does not fit ``source``:
    its images (``taxels^2`` values) and its objects, with one line naming both."""
    source_dim, objects = source.pressure_dim, list(source.objects)
    what = getattr(source, "description", "the glance source")
    if pressure_dim != source_dim:
        side = math.isqrt(source_dim)
        raise HamError(
            f"the model reads {pressure_dim} pressure values but {what} gives {side} x {side} "
            f"images ({source_dim} values); accepted: a model with pressure_dim = {source_dim}"
        )
    if n_objects != len(objects):
        raise HamError(
            f"the model classifies {n_objects} objects but {what} has {len(objects)} "
            f"({', '.join(objects)}); accepted: a model with n_objects = {len(objects)}"
        )


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
