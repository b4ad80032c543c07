"""The stimulus material: rigid blocks whose shape varies along x only.

Each object is a 9 x 9 cm block (section "Stimulus Material" of the paper) standing on a
table at z = 0, centred at local x = 0 of its exploration zone, and extruded along y. Its
shape is described once, as a *height profile* ``h(x)`` (metres) over ``x in [-w/2, w/2]``;
outside the block the height is the table's, 0. Both simulators build the same solid from
this one description: the fast model samples ``h`` directly, the MuJoCo backend cuts the
solid into convex vertical slabs between the profile's vertices (``outline``).

The default set ``paper`` holds the paper's four objects in the paper's order:

====  ===========  ============================================================
 id   name         side profile (x left to right)
====  ===========  ============================================================
 0    box          flat top at full height, vertical sides
 1    ramp_up      straight ramp rising from the table to full height, then a
                   vertical drop (right triangle, hypotenuse facing up-left)
 2    convex       quarter ellipse rising to full height (vertical tangent at the
                   left, horizontal at the right), then a vertical drop
 3    ramp_down    mirror image of ramp_up: vertical rise, ramp descending
====  ===========  ============================================================

Four MHSB-like shapes (ids 4..7) ship for experiments beyond the paper: ``ridge``,
``trough``, ``step`` and ``double_ridge``. Users add their own with :func:`register`
and the constructors :meth:`HapticObject.from_function`, :meth:`HapticObject.from_polyline`
and :meth:`HapticObject.from_heightmap`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ham.errors import HamError

#: Edge length of every block (m): "Building blocks ... 9 x 9 cm each".
BLOCK_SIZE = 0.09
#: Height of every block (m). The paper says only "the same height"; we use half the edge.
BLOCK_HEIGHT = 0.045

HeightFn = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True, eq=False)
class HapticObject:
    """A rigid block described by its height profile along x.

    Attributes:
        name: stable registry name.
        profile: vectorized ``h(x)`` in metres for ``x`` in ``[-width/2, width/2]`` (local frame).
        width: extent along x (m); the block occupies ``[-width/2, width/2]``.
        depth: extent along y (m); the shape is constant along y.
        height: the block's maximum height (m), used for plots and scene sizes.
        vertices: exact profile vertices ``(N, 2)`` as ``(x, z)`` when the profile is piecewise
            linear; ``None`` for curved profiles, which are sampled by :meth:`outline`.
        description: one line for ``ham objects``.
    """

    name: str
    profile: HeightFn
    width: float = BLOCK_SIZE
    depth: float = BLOCK_SIZE
    height: float = BLOCK_HEIGHT
    vertices: np.ndarray | None = field(default=None, repr=False)
    description: str = ""

    def height_at(self, x: np.ndarray) -> np.ndarray:
        """Surface height (m) at local positions ``x``: the profile on the block, 0 (table) beside it."""
        x = np.asarray(x)
        half = 0.5 * self.width
        inside = (x >= -half) & (x <= half)
        h = self.profile(np.clip(x, -half, half))
        return np.where(inside, h, 0.0).astype(x.dtype if x.dtype.kind == "f" else np.float64)

    def outline(self, samples: int = 257) -> np.ndarray:
        """The top of the block as a polyline ``(N, 2)`` of ``(x, z)`` from left to right.

        Exact vertices for polylines; ``samples`` points for curved profiles. The first and last
        points lie at ``x = -width/2`` and ``x = +width/2``; vertical sides join them to the table.
        """
        if self.vertices is not None:
            return np.asarray(self.vertices, dtype=np.float64)
        xs = np.linspace(-0.5 * self.width, 0.5 * self.width, samples)
        return np.stack([xs, self.profile(xs)], axis=1)

    @classmethod
    def from_function(
        cls,
        name: str,
        profile: HeightFn,
        *,
        width: float = BLOCK_SIZE,
        depth: float = BLOCK_SIZE,
        description: str = "",
    ) -> HapticObject:
        """An object from a vectorized height function ``h(x)`` (metres, local frame)."""
        xs = np.linspace(-0.5 * width, 0.5 * width, 1001)
        hs = np.asarray(profile(xs), dtype=np.float64)
        _check_heights(name, hs)
        return cls(name, profile, width, depth, float(hs.max()), None, description)

    @classmethod
    def from_polyline(
        cls,
        name: str,
        points: Sequence[Sequence[float]] | np.ndarray,
        *,
        depth: float = BLOCK_SIZE,
        description: str = "",
    ) -> HapticObject:
        """An object whose top follows the polyline ``points`` = [(x, z), ...] from left to right.

        The polyline spans the block: its first x is ``-width/2`` and its last ``+width/2``.
        Two consecutive points with the same x make a vertical step.
        """
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
            raise HamError(
                f"object {name!r}: polyline must be N >= 2 points (x, z), got {pts.shape}"
            )
        if np.any(np.diff(pts[:, 0]) < 0):
            raise HamError(f"object {name!r}: polyline x must be non-decreasing left to right")
        _check_heights(name, pts[:, 1])
        width = float(pts[-1, 0] - pts[0, 0])
        if width <= 0:
            raise HamError(f"object {name!r}: polyline must have positive width, got {width}")
        centre = 0.5 * (pts[0, 0] + pts[-1, 0])
        pts = pts - np.array([centre, 0.0])
        return cls(
            name, _polyline_profile(pts), width, depth, float(pts[:, 1].max()), pts, description
        )

    @classmethod
    def from_heightmap(
        cls,
        name: str,
        heights: Sequence[float] | np.ndarray,
        *,
        width: float = BLOCK_SIZE,
        depth: float = BLOCK_SIZE,
        description: str = "",
    ) -> HapticObject:
        """An object from heights (m) sampled evenly across the block, joined by straight lines."""
        hs = np.asarray(heights, dtype=np.float64)
        if hs.ndim != 1 or len(hs) < 2:
            raise HamError(f"object {name!r}: heightmap must be a 1-D array of >= 2 heights")
        xs = np.linspace(-0.5 * width, 0.5 * width, len(hs))
        return cls.from_polyline(name, np.stack([xs, hs], 1), depth=depth, description=description)


def _check_heights(name: str, hs: np.ndarray) -> None:
    if not np.all(np.isfinite(hs)):
        raise HamError(f"object {name!r}: heights must be finite")
    if np.any(hs < 0):
        raise HamError(f"object {name!r}: heights must be >= 0 (the table is at z = 0)")


def _polyline_profile(pts: np.ndarray) -> HeightFn:
    """Piecewise-linear height through ``pts``; a vertical step becomes a 1 nm wide slope."""
    xs = pts[:, 0].copy()
    zs = pts[:, 1]
    # np.interp needs strictly increasing x: nudge repeated x (vertical steps) apart by 1 nm.
    for i in range(1, len(xs)):
        if xs[i] <= xs[i - 1]:
            xs[i] = xs[i - 1] + 1e-9

    def profile(x: np.ndarray) -> np.ndarray:
        return np.interp(x, xs, zs)

    return profile


# --------------------------------------------------------------------------- paper objects
_A = 0.5 * BLOCK_SIZE
_H = BLOCK_HEIGHT


def _convex(x: np.ndarray) -> np.ndarray:
    # Quarter ellipse centred at (x = +a, z = 0): z = H * sqrt(1 - ((a - x) / 2a)^2).
    t = (_A - np.asarray(x)) / (2 * _A)
    return _H * np.sqrt(np.clip(1.0 - t * t, 0.0, 1.0))


def _trough(x: np.ndarray) -> np.ndarray:
    # Concave circular-arc trough: full height at both ends, lowest (H/3) in the middle.
    t = np.asarray(x) / _A
    return _H * (1.0 - (2.0 / 3.0) * np.sqrt(np.clip(1.0 - t * t, 0.0, 1.0)))


def _builtin() -> list[HapticObject]:
    return [
        HapticObject.from_polyline(
            "box",
            [(-_A, _H), (_A, _H)],
            description="flat top, vertical sides (two 90-degree edges)",
        ),
        HapticObject.from_polyline(
            "ramp_up", [(-_A, 0.0), (_A, _H)], description="ramp rising to the right, vertical drop"
        ),
        HapticObject.from_function(
            "convex",
            _convex,
            description="convex quarter ellipse rising to the right, vertical drop",
        ),
        HapticObject.from_polyline(
            "ramp_down",
            [(-_A, _H), (_A, 0.0)],
            description="vertical rise, ramp descending to the right",
        ),
        HapticObject.from_polyline(
            "ridge",
            [(-_A, _H / 3), (0.0, _H), (_A, _H / 3)],
            description="central ridge (an edge) between two slopes",
        ),
        HapticObject.from_function("trough", _trough, description="concave circular trough"),
        HapticObject.from_polyline(
            "step",
            [(-_A, _H / 2), (0.0, _H / 2), (0.0, _H), (_A, _H)],
            description="low half on the left, a vertical step up in the middle",
        ),
        HapticObject.from_polyline(
            "double_ridge",
            [(-_A, _H / 3), (-_A / 2, _H), (0.0, _H / 3), (_A / 2, _H), (_A, _H / 3)],
            description="two ridges",
        ),
    ]


# --------------------------------------------------------------------------- registry
_REGISTRY: dict[str, HapticObject] = {}
_ORDER: list[str] = []

#: Named object sets; ``paper`` is the paper's four objects in the paper's order.
OBJECT_SETS: dict[str, tuple[str, ...]] = {
    "paper": ("box", "ramp_up", "convex", "ramp_down"),
    "mhsb": ("ridge", "trough", "step", "double_ridge"),
}


def register(obj: HapticObject, *, replace: bool = False) -> int:
    """Add ``obj`` to the registry and return its id (ids are stable: registration order)."""
    if not isinstance(obj, HapticObject):
        raise HamError(f"register() takes a HapticObject, got {type(obj).__name__}")
    if obj.name in _REGISTRY and not replace:
        raise HamError(f"object {obj.name!r} is already registered (pass replace=True)")
    if obj.name not in _REGISTRY:
        _ORDER.append(obj.name)
    _REGISTRY[obj.name] = obj
    return _ORDER.index(obj.name)


def names() -> list[str]:
    """All registered object names, in id order."""
    return list(_ORDER)


def object_id(name: str) -> int:
    """The stable registry id of ``name``."""
    if name not in _REGISTRY:
        raise HamError(f"unknown object {name!r}; known: {', '.join(_ORDER)}")
    return _ORDER.index(name)


def get(key: str | int) -> HapticObject:
    """An object by registry name or id (a string of digits counts as an id)."""
    if isinstance(key, str) and key.strip().lstrip("-").isdigit():
        key = int(key)
    if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
        if not 0 <= key < len(_ORDER):
            raise HamError(f"unknown object id {key}; accepted: 0..{len(_ORDER) - 1}")
        return _REGISTRY[_ORDER[key]]
    if isinstance(key, str) and key in _REGISTRY:
        return _REGISTRY[key]
    raise HamError(
        f"unknown object {key!r}; known: {', '.join(_ORDER)} (or an id 0..{len(_ORDER) - 1})"
    )


def resolve_set(spec: str | Sequence[str | int]) -> list[HapticObject]:
    """Objects of a named set (``paper``, ``mhsb``, ``all``) or a comma list of names/ids."""
    if isinstance(spec, str):
        if spec == "all":
            return [get(n) for n in _ORDER]
        if spec in OBJECT_SETS:
            return [get(n) for n in OBJECT_SETS[spec]]
        parts = [p.strip() for p in spec.split(",") if p.strip()]
        if not parts:
            raise HamError(
                f"empty object set {spec!r}; accepted: {', '.join(OBJECT_SETS)}, all, or names"
            )
        spec = parts
    objs = [get(k) for k in spec]
    seen = [o.name for o in objs]
    if len(set(seen)) != len(seen):
        raise HamError(f"object set lists an object twice: {seen}")
    return objs


for _obj in _builtin():
    register(_obj)
