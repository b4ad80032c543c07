"""Glance sources: where a batch of glances comes from.

* :class:`TableSource`: a pre-recorded glance table, the closest grid point (the paper's way);
* :class:`OnlineSource`: the fast simulator itself, at the exact pose (no grid; beyond the paper).

Both answer ``glance(object_ids, q)`` with raw pressure images and the contact heights, on CPU
or CUDA: ``q`` is ``(B, k)``, one column per pose dimension of the source's ``pose_dims`` (the
world's, in canonical order ``x, y, phi, phi_y``; the paper's ``x, phi``). The paper's
two-parameter ``lookup(object_ids, q_x, q_phi)`` remains for ``(x, phi)`` sources.

An online source also takes per-row object poses ``(yaw, dx, dy)`` (the random object pose per
episode, :class:`ObjectPoseConfig`); a table holds the objects at their one recorded pose.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import torch

from ham.errors import HamError, check_types
from ham.world.config import WorldConfig, make_simulator
from ham.world.poses import PAPER_POSE_DIMS, result_height, simulate, world_pose_dims
from ham.world.sensor import SensorConfig

__all__ = [
    "PAPER_POSE_DIMS",
    "GlanceSource",
    "ObjectPoseConfig",
    "OnlineSource",
    "TableSource",
    "check_model_fits",
    "make_source",
    "result_height",
    "simulate",
    "world_pose_dims",
]


@dataclass(frozen=True)
class ObjectPoseConfig:
    """A random object pose per episode (beyond the paper; off by default): the object is turned
    by a yaw uniform in ``[-yaw_max, yaw_max]`` (rad) and shifted by ``(dx, dy)`` uniform in
    ``[-offset_max, offset_max]`` (m) under the pad, the same for every glance of the episode.

    Attributes:
        yaw_max: largest yaw (rad), 0..pi; 0: no turn.
        offset_max: largest shift along x and along y (m), 0..0.05; 0: no shift.
    """

    yaw_max: float = 0.0
    offset_max: float = 0.0

    def __post_init__(self) -> None:
        check_types(self)
        for name, top in (("yaw_max", math.pi), ("offset_max", 0.05)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v <= top:
                raise HamError(f"object pose {name} = {v!r}; accepted: a number 0..{top:g}")

    @property
    def enabled(self) -> bool:
        return self.yaw_max > 0 or self.offset_max > 0

    def check_world(self, world) -> None:
        """A :class:`HamError` when this pose is on and ``world`` (a ``WorldConfig``) cannot turn
        or shift an object: only the fast extended glance can (the line glance reads a profile
        along x; MuJoCo keeps each object at its place on the table)."""
        if not self.enabled or (world.extended and world.simulator != "mujoco"):
            return
        if world.simulator == "mujoco":
            what, accepted = "simulator 'mujoco'", "simulator 'fast' (its extended glance)"
        else:
            what = f"the line glance (pose dims {','.join(world.pose_dims)}, objects "
            what += f"{world.objects!r})"
            accepted = "the extended glance: pose dims with y or phi_y, or objects that vary in y"
        raise HamError(f"a random object pose ({self}) with {what}; accepted: {accepted}")

    def sample(self, batch: int, generator: torch.Generator, device) -> tuple[torch.Tensor, ...]:
        """``(yaw, dx, dy)``, each ``(batch,)`` float32, uniform in their ranges."""
        u = torch.rand(batch, 3, generator=generator, device=device) * 2 - 1
        scale = torch.tensor([self.yaw_max, self.offset_max, self.offset_max], device=device)
        u = u * scale
        return u[:, 0], u[:, 1], u[:, 2]

    def to_dict(self) -> dict:
        return asdict(self)


@runtime_checkable
class GlanceSource(Protocol):
    """Anything that answers batches of glances with raw pressure images and contact heights."""

    n_objects: int
    objects: list
    taxels: int
    pressure_dim: int
    pose_dims: tuple[str, ...]

    def glance(
        self, object_ids: torch.Tensor, q: torch.Tensor, object_pose=None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Raw pressure ``(B, N, N)`` and contact height ``(B,)`` (m) for objects ``(B,)`` at
        normalized poses ``q`` ``(B, k)`` (columns: ``pose_dims``)."""
        ...


class _Source:
    """What every source tells about its glances: the objects, the pad's ``N``, the pose dims,
    a description."""

    def __init__(
        self, objects: list, taxels: int, description: str, pose_dims: tuple[str, ...]
    ) -> None:
        self.objects = list(objects)
        self.n_objects = len(self.objects)
        self.taxels = int(taxels)
        self.pressure_dim = self.taxels**2
        self.description = description
        self.pose_dims = tuple(pose_dims)

    def lookup(
        self, object_ids: torch.Tensor, q_x: torch.Tensor, q_phi: torch.Tensor
    ) -> torch.Tensor:
        """Raw pressure ``(B, N, N)`` at the paper's two-parameter poses ``(q_x, q_phi)``."""
        if self.pose_dims != PAPER_POSE_DIMS:
            raise HamError(
                f"lookup(q_x, q_phi) on {self.description} with pose dims "
                f"{','.join(self.pose_dims)}; accepted: glance(ids, q) with q (B, "
                f"{len(self.pose_dims)})"
            )
        return self._lookup2(object_ids, q_x, q_phi)


class OnlineSource(_Source):
    """Glances simulated on demand by a simulator (``FastSimulator``: CPU or CUDA, no grid)."""

    def __init__(self, simulator, pose_dims: tuple[str, ...] = PAPER_POSE_DIMS) -> None:
        self.simulator = simulator
        sensor = getattr(simulator, "sensor", None) or SensorConfig()
        objects = [o.name for o in simulator.objects]
        super().__init__(
            objects, sensor.taxels, f"the online {simulator.name} simulator", pose_dims
        )

    def _lookup2(self, object_ids, q_x, q_phi) -> torch.Tensor:
        return self.simulator.glance(object_ids, q_x, q_phi).pressure

    def glance(
        self, object_ids: torch.Tensor, q: torch.Tensor, object_pose=None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        r = simulate(self.simulator, object_ids, q, self.pose_dims, object_pose)
        return r.pressure, result_height(r)


class TableSource(_Source):
    """Glances looked up in a :class:`ham.world.table.GlanceTable`: the closest grid point (the paper)."""

    def __init__(self, table) -> None:
        self.table = table
        super().__init__(
            table.objects, table.taxels, f"glance table {table.info.path!r}", table.pose_dims
        )

    def _lookup2(self, object_ids, q_x, q_phi) -> torch.Tensor:
        # The environment's own actions are always in range: skip the per-call validation.
        return self.table.lookup(object_ids, q_x, q_phi, check=False)

    def glance(
        self, object_ids: torch.Tensor, q: torch.Tensor, object_pose=None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        if object_pose is not None:
            raise HamError(
                f"a random object pose on {self.description}: a table records each object at "
                "one pose; accepted: online glances (no --table) for random object poses"
            )
        return self.table.lookup_pose(object_ids, q, check=False, height=True)


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
    return OnlineSource(make_simulator(world, device=str(device)), world_pose_dims(world)), world
