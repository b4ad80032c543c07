"""Glances at poses over any of the pose dimensions: ``q`` ``(B, k)`` in a world's ``pose_dims``.

Shared by the glance sources (:mod:`ham.world.source`) and the tables over any pose grid
(:mod:`ham.world.table`).
"""

from __future__ import annotations

import torch

from ham.errors import HamError
from ham.world.glance import PAPER_POSE_DIMS

#: Keyword of each pose dimension in ``Simulator.glance``.
_GLANCE_ARGS: dict[str, str] = {"x": "q_x", "y": "q_y", "phi": "q_phi", "phi_y": "q_phi_y"}


def world_pose_dims(world) -> tuple[str, ...]:
    """The pose dimensions of ``world`` (the paper's ``x, phi`` for a world without them)."""
    return tuple(getattr(world, "pose_dims", PAPER_POSE_DIMS))


def simulate(simulator, object_ids, q: torch.Tensor, dims: tuple[str, ...], object_pose=None):
    """``simulator.glance`` at poses ``q`` ``(B, k)``, columns in the order of ``dims``; dims not
    given are 0. ``object_pose``: per-row ``(yaw, dx, dy)`` tensors, or ``None``.

    The paper's ``(x, phi)`` pose calls ``glance(ids, q_x, q_phi)`` exactly as before."""
    if q.ndim != 2 or q.shape[1] != len(dims):
        raise HamError(
            f"poses of shape {tuple(q.shape)}; accepted: (B, {len(dims)}) for pose dims "
            f"{','.join(dims)}"
        )
    cols = {d: q[:, i] for i, d in enumerate(dims)}
    q_x = cols["x"] if "x" in cols else q.new_zeros(q.shape[0])
    q_phi = cols["phi"] if "phi" in cols else q.new_zeros(q.shape[0])
    extra = {_GLANCE_ARGS[d]: cols[d] for d in ("y", "phi_y") if d in cols}
    if object_pose is not None:
        extra["object_pose"] = object_pose
    return simulator.glance(object_ids, q_x, q_phi, **extra)


def result_height(result) -> torch.Tensor:
    """The contact height ``h`` (m) of a glance result: its ``height``, else (a simulator from
    before the extended glance) the face centre's final height ``z``, which it equals."""
    h = getattr(result, "height", None)
    return result.z if h is None else h
