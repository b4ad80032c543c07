"""The low-level haptic glance: ``g: (x, phi) -> p`` (section "Haptic Control of the Simulated Myrmex").

At a pose ``(x, phi)`` the pad is lowered along z, orientation and x held fixed, until the summed
force on its 16 x 16 cells (N x N: :class:`ham.world.sensor.SensorConfig`) reaches 2 N (312.5 Pa
over 64 cm^2); then it reads its image.

Poses come from the agent's normalized action ``q = (q_x, q_phi) in [-1, 1]^2``:

* ``x = q_x * zone_half_width`` within the object's exploration zone (default: the block, so the
  pad centre is always above it), then shifted by ``-pivot_offset * sin(phi)``
  (0 in the paper; the authors' code rotates about a point 6.8 cm above the face);
* ``phi = q_phi * phi_max`` with ``phi_max = pi/2`` (paper) or ``0.3 pi`` (authors' code).

The fast simulator solves the stop height exactly. Each read-out point ``k`` of the face touches the
surface when the pad centre is at height ``e_k``; below it the foam there is compressed by
``e_k - z``. The summed force ``F(z) = c0 * sum_k max(0, e_k - z)`` is piecewise linear and convex in
``z``, so Newton's method from below lands on the root exactly after at most one step per
breakpoint: no step-size artifacts.

Near ``|phi| = pi/2`` the face is almost vertical and a rigid part may stop the descent first: the
pad body behind the foam (when the foam is compressed through its whole thickness) or the sides of
its housing. The glance then ends at that height with whatever the foam feels there, possibly
nothing: ``blocked`` is set, ``force`` is below 2 N, and ``contact`` says whether the face felt
anything at all. Every glance terminates: the table under the objects always stops the pad.
"""

from __future__ import annotations

import math
import threading
from dataclasses import asdict, dataclass, field
from typing import Protocol

import numpy as np
import torch

from ham.errors import HamError, check_types
from ham.world.objects import MAX_HEIGHT, HapticObject
from ham.world.sensor import Myrmex, SensorConfig

#: Authors' exploration-zone widths (m) for the paper objects, from their Gazebo code.
AUTHORS_ZONE_WIDTHS: dict[str, float] = {
    "box": 0.18,
    "ramp_up": 0.13,
    "convex": 0.14,
    "ramp_down": 0.11,
}


#: The pose mappings ``PoseConfig.preset`` knows: the paper's and the authors' code's.
POSE_PRESETS: tuple[str, ...] = ("paper", "authors")

#: The pose dimensions of the extended glance in canonical order (the paper's Discussion:
#: ``g: (x, phi_x, phi_y) -> (p, h)``, with y added): ``phi`` is the paper's tilt (phi_x, about the
#: y axis), ``phi_y`` tilts about the x axis. The paper's glance uses ``("x", "phi")``.
POSE_DIMS: tuple[str, ...] = ("x", "y", "phi", "phi_y")
#: The paper's pose dimensions, the default of :attr:`ham.world.config.WorldConfig.pose_dims`.
PAPER_POSE_DIMS: tuple[str, ...] = ("x", "phi")


def check_pose_dims(dims: object, what: str = "pose_dims") -> tuple[str, ...]:
    """``dims`` as a tuple if it is a non-empty subset of :data:`POSE_DIMS` in canonical order
    (a comma string ``"x,y,phi,phi_y"`` or a sequence of names), else a :class:`HamError`."""
    rule = f"accepted: a non-empty subset of {','.join(POSE_DIMS)} in that order"
    if isinstance(dims, str):
        dims = tuple(p.strip() for p in dims.split(","))
    if not isinstance(dims, (tuple, list)) or not dims:
        raise HamError(f"{what} = {dims!r}; {rule}")
    for d in dims:
        if d not in POSE_DIMS:
            raise HamError(f"{what}: unknown pose dimension {d!r}; {rule}")
    dims = tuple(dims)
    if len(set(dims)) != len(dims) or list(dims) != sorted(dims, key=POSE_DIMS.index):
        raise HamError(f"{what} = {','.join(dims)!r}; {rule} (each once)")
    return dims


@dataclass(frozen=True)
class PoseConfig:
    """Mapping from the normalized action ``q`` to the metric pad pose.

    Attributes:
        phi_max: ``phi = q_phi * phi_max``; ``pi/2`` (paper) or ``0.3 pi`` (authors' code).
        zone_half_width: ``x = q_x * zone_half_width`` (m); ``None``: half the object's width.
        pivot_offset: x shift ``-pivot_offset * sin(phi)`` (m); 0 (paper), 0.068 (authors).
        authors_zones: use the authors' per-object zone widths where they define one.
    """

    phi_max: float = math.pi / 2
    zone_half_width: float | None = None
    pivot_offset: float = 0.0
    authors_zones: bool = False

    def __post_init__(self) -> None:
        check_types(self)
        if not (math.isfinite(self.phi_max) and 0 < self.phi_max <= math.pi / 2):
            raise HamError(f"phi_max = {self.phi_max!r}; accepted: 0 < phi_max <= pi/2")
        if self.zone_half_width is not None and not (
            math.isfinite(self.zone_half_width) and self.zone_half_width > 0
        ):
            raise HamError(f"zone_half_width = {self.zone_half_width!r}; accepted: None or > 0 (m)")
        if not math.isfinite(self.pivot_offset):
            raise HamError(f"pivot_offset = {self.pivot_offset!r}; accepted: a finite number (m)")

    @classmethod
    def preset(cls, name: str) -> PoseConfig:
        """``paper`` (default) or ``authors`` (phi = q * 0.3 pi, pivot shift, per-object zones)."""
        if name == "paper":
            return cls()
        if name == "authors":
            return cls(phi_max=0.3 * math.pi, pivot_offset=0.068, authors_zones=True)
        raise HamError(f"pose preset {name!r}; accepted: {', '.join(POSE_PRESETS)}")

    def half_width(self, obj: HapticObject) -> float:
        if self.authors_zones and obj.name in AUTHORS_ZONE_WIDTHS:
            return 0.5 * AUTHORS_ZONE_WIDTHS[obj.name]
        return self.zone_half_width if self.zone_half_width is not None else 0.5 * obj.width

    def half_depth(self, obj: HapticObject) -> float:
        """``y = q_y * half_depth``: half the object's depth (the zone spans the base in y)."""
        return 0.5 * obj.depth

    def extended_pose(self, q_x, q_y, q_phi, q_phi_y, half_x, half_y):
        """Metric ``(x, y, phi, phi_y)`` of the face centre for normalized actions (tensors) and
        the zones' half widths ``half_x``, ``half_y``: ``x = q_x * half_x``, ``y = q_y * half_y``,
        ``phi = q_phi * phi_max``, ``phi_y = q_phi_y * phi_max``. The authors' pivot sits
        ``pivot_offset`` above the face centre, along the pad's normal
        ``n = (sin phi cos phi_y, sin phi_y, cos phi cos phi_y)``: rotating about it shifts x by
        ``-p sin(phi) cos(phi_y)`` and y by ``-p sin(phi_y)`` (with ``phi_y = 0`` the line
        glance's shift bit for bit: cos 0 = 1 exactly)."""
        phi = q_phi * self.phi_max
        phi_y = q_phi_y * self.phi_max
        p = self.pivot_offset
        x = q_x * half_x
        y = q_y * half_y
        if p != 0:
            x = x - p * torch.sin(phi) * torch.cos(phi_y)
            y = y - p * torch.sin(phi_y)
        return x, y, phi, phi_y


@dataclass(frozen=True)
class GlanceConfig:
    """The controller's stop rule: the summed force on the cells reaches ``force_threshold`` (N)."""

    force_threshold: float = 2.0
    housing_samples: int = 6

    def __post_init__(self) -> None:
        check_types(self)
        if not (math.isfinite(self.force_threshold) and self.force_threshold > 0):
            raise HamError(f"force_threshold = {self.force_threshold!r}; accepted: > 0 (N)")
        if not (isinstance(self.housing_samples, int) and self.housing_samples >= 2):
            raise HamError(f"housing_samples = {self.housing_samples!r}; accepted: an integer >= 2")


@dataclass
class GlanceResult:
    """What one batch of glances returns; arrays share the batch dimension B.

    Attributes:
        pressure: ``(B, N, N)`` raw pressure image (Pa), not normalized (N = ``taxels``, 16).
        force: ``(B,)`` summed force on the cells at the end of the glance (N).
        z: ``(B,)`` height of the face centre at the end of the glance (m, table at 0).
        contact: ``(B,)`` whether the sensitive face touched anything.
        blocked: ``(B,)`` whether a rigid part stopped the pad before the force threshold.
        x: ``(B,)`` face centre x in the object's frame (m).
        phi: ``(B,)`` rotation about y (rad).
        y: ``(B,)`` face centre y (m); zeros for the paper's glance (``None`` given: zeros).
        phi_y: ``(B,)`` rotation about x (rad); zeros for the paper's glance.
        height: ``(B,)`` the contact height h of the extended glance ``g -> (p, h)``: the face
            centre's height at the end of the glance (m), i.e. ``z`` (``None`` given: ``z``).
    """

    pressure: torch.Tensor
    force: torch.Tensor
    z: torch.Tensor
    contact: torch.Tensor
    blocked: torch.Tensor
    x: torch.Tensor
    phi: torch.Tensor
    info: dict = field(default_factory=dict)
    y: torch.Tensor | None = None
    phi_y: torch.Tensor | None = None
    height: torch.Tensor | None = None

    def __post_init__(self) -> None:
        # Simulators of the paper's glance give no y, phi_y or height: the pose centre, no tilt.
        if self.y is None:
            self.y = torch.zeros_like(self.x)
        if self.phi_y is None:
            self.phi_y = torch.zeros_like(self.phi)
        if self.height is None:
            self.height = self.z

    def numpy(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k).detach().cpu().numpy() for k in _FIELDS}

    def to_json(self, i: int = 0) -> dict:
        """Glance ``i`` as a JSON-ready dict (raw pressure as N nested lists of N)."""
        return {
            "pressure": self.pressure[i].double().cpu().tolist(),
            "force": float(self.force[i]),
            "z": float(self.z[i]),
            "height": float(self.height[i]),
            "contact": bool(self.contact[i]),
            "blocked": bool(self.blocked[i]),
            "x": float(self.x[i]),
            "y": float(self.y[i]),
            "phi": float(self.phi[i]),
            "phi_y": float(self.phi_y[i]),
        }


class Simulator(Protocol):
    """Anything that performs batches of haptic glances on a fixed list of objects."""

    name: str
    objects: list[HapticObject]

    def glance(self, object_ids, q_x, q_phi, q_y=None, q_phi_y=None) -> GlanceResult: ...

    def describe(self) -> dict: ...


def glance_at(sim: Simulator, object_ids, q, dims=PAPER_POSE_DIMS) -> GlanceResult:
    """Glances of ``sim`` at normalized poses ``q`` (B, k) whose columns are the pose dimensions
    ``dims`` (a subset of :data:`POSE_DIMS` in canonical order); the others are 0 (pose centre,
    no tilt). ``q_y``/``q_phi_y`` are passed only when ``dims`` has them, so that a simulator of
    the paper's glance takes ``dims = ("x", "phi")``."""
    dims = check_pose_dims(dims, "dims")
    qt = torch.as_tensor(q)
    if qt.dim() == 1 and len(dims) == 1:
        qt = qt[:, None]
    if qt.dim() != 2 or qt.shape[1] != len(dims):
        raise HamError(
            f"q of shape {tuple(qt.shape)} for dims {','.join(dims)}; accepted: (B, {len(dims)})"
        )
    cols = {d: qt[:, i] for i, d in enumerate(dims)}
    zero = torch.zeros(qt.shape[0], dtype=qt.dtype if qt.is_floating_point() else torch.float64)
    extra = {f"q_{d}": cols[d] for d in ("y", "phi_y") if d in cols}
    return sim.glance(object_ids, cols.get("x", zero), cols.get("phi", zero), **extra)


# --------------------------------------------------------------------------- input checks
def as_action(name: str, q, device: torch.device | str = "cpu") -> torch.Tensor:
    """``q`` as a float64 1-D tensor, refusing NaN and values outside [-1, 1] with a clear error."""
    t = torch.as_tensor(q, dtype=torch.float64, device=device).reshape(-1)
    if not bool((t.abs() <= 1).all()):  # one pass in the common case; NaN fails ``<=`` too
        bad = ~torch.isfinite(t) | (t.abs() > 1)
        v = t[bad][0].item()
        raise HamError(f"{name} = {v!r} is outside the accepted range [-1, 1]")
    return t


def refuse_extended_pose(q_y, q_phi_y, device: torch.device | str = "cpu") -> None:
    """The paper's glance takes ``q_y``/``q_phi_y`` only as ``None`` or 0; else a clear error."""
    for name, q in (("q_y", q_y), ("q_phi_y", q_phi_y)):
        if q is not None and bool((as_action(name, q, device) != 0).any()):
            raise HamError(
                f"{name} = {q!r} is not 0: the paper's glance (pose x, phi) takes no {name[2:]}; "
                "accepted: pose_dims with y or phi_y, which pick the extended glance "
                "(--pose-dims x,y,phi,phi_y)"
            )


def as_object_ids(ids, n_objects: int, device: torch.device | str = "cpu") -> torch.Tensor:
    t = torch.as_tensor(ids, device=device)
    if t.is_floating_point() or t.dtype == torch.bool:
        raise HamError(f"object ids must be integers, got dtype {t.dtype}")
    t = t.reshape(-1).long()
    bad = (t < 0) | (t >= n_objects)
    if bool(bad.any()):
        raise HamError(f"object id {int(t[bad][0])} out of range; accepted: 0..{n_objects - 1}")
    return t


def height_bound(sensor: SensorConfig) -> float:
    """The farthest from the table (m) a glance's face centre can end: the tallest object's top
    (``MAX_HEIGHT``) plus the pad's edge and depth (foam and housing), the most by which any
    point of a tilted pad can stand above or below its face centre. The envs' height
    observation spans ``[-bound, bound]``; a simulator file that reports more is refused."""
    return MAX_HEIGHT + sensor.size + sensor.foam_thickness + sensor.housing_thickness


def check_pad(sensor: SensorConfig, glance: GlanceConfig, objects: list[HapticObject]) -> None:
    """Refuse a pad that does not fit the world, with one line naming the limit.

    * the pad must be no wider than the objects are deep (9 cm): every model here takes all N
      rows of the face as lying on the object (objects are extruded along y), so a wider pad
      would read rows over empty space as pressed;
    * its foam must carry the stop force on a flat top without being compressed through:
      ``force_threshold / (foam_stiffness * size^2) < foam_thickness`` (a pad of at least 4.1 mm
      at the defaults), else every glance would end on the rigid pad, blocked.
    """
    flat2d = [o.name for o in objects if o.varies_in_y]
    if flat2d:
        raise HamError(
            f"object {flat2d[0]!r} varies in y (a height field); the paper's glance model takes "
            "objects extruded along y only; accepted: the paper's objects, profiles and polylines "
            "(the extended glance, ham.world.extended_glance, takes height fields)"
        )
    depth = min(o.depth for o in objects)
    if sensor.size > depth * (1 + 1e-9):
        narrow = min(objects, key=lambda o: o.depth)
        raise HamError(
            f"the pad ({sensor.describe()}) is wider than object {narrow.name!r} is deep "
            f"({depth * 100:g} cm); accepted: taxels * pitch <= {depth:g} m"
        )
    check_foam(sensor, glance)


def check_foam(sensor: SensorConfig, glance: GlanceConfig) -> None:
    """Refuse a pad whose foam cannot carry the stop force on a flat top (see :func:`check_pad`)."""
    flat = glance.force_threshold / (sensor.foam_stiffness * sensor.size**2)
    if flat >= sensor.foam_thickness:
        least = math.sqrt(glance.force_threshold / (sensor.foam_stiffness * sensor.foam_thickness))
        raise HamError(
            f"the pad ({sensor.describe()}) is too small to carry {glance.force_threshold:g} N on "
            f"its {sensor.foam_thickness * 1000:g} mm foam; accepted: taxels * pitch > {least:.4g} m"
        )


# --------------------------------------------------------------------------- fast simulator
#: A peak counts as narrow (:meth:`FastSimulator._set_features`) when the surface falls faster than
#: this slope on both sides within one read-out spacing (1: steeper than 45 degrees on average).
FEATURE_SLOPE = 1.0


class FastSimulator:
    """The vectorized foam-contact model, exact in the stop height; CPU or CUDA via torch.

    Object surfaces are evaluated on a fine uniform height map (``resolution`` intervals across
    each block, linear between samples): exact for polylines whose vertices fall on the map
    (all built-in ones), sub-micrometre for curved profiles.

    Peaks narrower than the read-out spacing (a 0.6 mm spike) are not left between two read-out
    points: their *feature points* raise the touch height of the cell they fall in
    (:meth:`_set_features`; ``features`` counts them per object). The paper's objects have none.

    Speed (one CPU core, large batches: ~0.6-0.9 M glances/s on a loaded 2-core VM): every
    ``(B, K)`` step is one vectorized pass without boolean temporaries (comparisons write float
    masks; the table beside each block is a padded map cell, not a ``where``), the temporaries
    live in a per-thread workspace reused across chunks and calls (~13 MB), and the images are
    written straight into the output, whose first touch (1 KB per glance) is then a large part
    of the time.
    """

    name = "fast"

    def __init__(
        self,
        objects: list[HapticObject],
        sensor: SensorConfig | None = None,
        pose: PoseConfig | None = None,
        glance: GlanceConfig | None = None,
        *,
        device: torch.device | str = "cpu",
        resolution: int = 4096,
        chunk: int = 8192,
    ) -> None:
        if not objects:
            raise HamError("a simulator needs at least one object")
        self.objects = list(objects)
        self.myrmex = Myrmex(sensor)
        self.sensor = self.myrmex.config
        self.pose = pose or PoseConfig()
        self.glance_config = glance or GlanceConfig()
        check_pad(self.sensor, self.glance_config, self.objects)
        self.device = torch.device(device)
        self.chunk = chunk
        self.resolution = resolution
        # float32 throughout: positions to ~10 nm; the force solve runs relative to each row's
        # first touch, so compressions (micrometres) keep full precision.
        f64 = dict(dtype=torch.float32, device=self.device)
        # Height maps: block's width sampled at resolution + 1 points, read as map coordinate
        # t in [0, n] (n = resolution); any x outside the block reads the table (height 0).
        widths = {o.width for o in self.objects}
        self._uniform_width = widths.pop() if len(widths) == 1 else None
        self._x0 = torch.tensor([-0.5 * o.width for o in self.objects], **f64)
        self._dx = torch.tensor([o.width / resolution for o in self.objects], **f64)
        maps = []
        for o in self.objects:
            xs = np.linspace(-0.5 * o.width, 0.5 * o.width, resolution + 1)
            maps.append(np.asarray(o.profile(xs), dtype=np.float64))
        self._set_features(np.stack(maps))
        maps = torch.tensor(np.stack(maps), **f64)
        # Cell i of an object (t in [i, i + 1)) holds (h_i, h_i+1 - h_i): h = h_i + w * dh.
        # Padding makes the table beside the block a lookup too, with no mask: a zero cell for
        # t in [-1, 0) and, past the end, one cell that gives the end height (as cell n - 1 at
        # w = 1 gives it) at t = n exactly and 0 at the next float32 up, to which any larger t
        # is clamped (dh * w = -h exactly: w is a power of two).
        n = resolution
        self._t_hi = float(np.nextafter(np.float32(n), np.float32(np.inf)))
        step = self._t_hi - n
        h, dh = maps[:, :-1], maps[:, 1:] - maps[:, :-1]
        h_end = h[:, -1:] + dh[:, -1:]
        zero = torch.zeros_like(h_end)
        self._map_h = torch.cat([zero, h, h_end], 1).reshape(-1).contiguous()
        self._map_dh = torch.cat([zero, dh, -h_end / step], 1).reshape(-1).contiguous()
        self._half = torch.tensor([self.pose.half_width(o) for o in self.objects], **f64)
        s = self.sensor
        self._u = torch.tensor(self.myrmex.sample_u(), **f64)[None, :]
        # Housing sides: u = +-L/2, v from the foam's back to the housing's back (v points into the pad).
        v = torch.linspace(
            s.foam_thickness,
            s.foam_thickness + s.housing_thickness,
            self.glance_config.housing_samples,
            **f64,
        )
        half = 0.5 * s.size
        self._hu = torch.cat([torch.full_like(v, -half), torch.full_like(v, half)])[None, :]
        self._hv = torch.cat([v, v])[None, :]
        # Force per metre of compression at one read-out point: every row feels the same profile.
        self._c0 = s.foam_stiffness * s.taxels * s.taxel_area / s.supersample
        # The sensor's raw image written straight into the output (else: Myrmex.image, copied).
        self._direct_image = (
            type(self.myrmex) is Myrmex and s.spread_sigma is None and s.quantize_bits is None
        )

    # ------------------------------------------------------------------ geometry
    def heights(self, ids: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """Surface height (m) of objects ``ids`` (B,) at local x (B, K): height map, table beside.

        Evaluated in float32, like every glance.
        """
        work = _Workspace(x.numel(), x.device)
        return self._heights_(ids, x.to(torch.float32, copy=True), work, "h")

    def _heights_(
        self, ids: torch.Tensor, t: torch.Tensor, work: _Workspace, out: str
    ) -> torch.Tensor:
        """:meth:`heights` at positions ``t`` (B, K), float32, overwritten; result in ``out``.

        The temporaries are the workspace's ``f``, ``i`` and ``d`` buffers.
        """
        n = self.resolution
        if self._uniform_width is not None:  # common case: no per-glance parameter gathers
            t.add_(0.5 * self._uniform_width).mul_(n / self._uniform_width)
        else:
            t.sub_(self._x0[ids, None]).div_(self._dx[ids, None])
        t.clamp_(-1.0, self._t_hi)
        i = torch.floor(t, out=work.get("f", t.shape))
        w = t.sub_(i)
        # Padded cell index: object ids[b] owns cells [ids * (n + 2), (ids + 1) * (n + 2)).
        idx = work.get("i", t.shape, torch.int32).copy_(i)  # exact: i holds small integers
        idx = idx.add_((ids * (n + 2) + 1).to(torch.int32)[:, None]).view(-1)
        h = torch.index_select(self._map_h, 0, idx, out=work.get(out, (idx.numel(),)))
        dh = torch.index_select(self._map_dh, 0, idx, out=work.get("d", (idx.numel(),)))
        return h.add_(dh.mul_(w.view(-1))).view(t.shape)

    def poses(self, ids: torch.Tensor, q_x: torch.Tensor, q_phi: torch.Tensor):
        """Metric ``(x, phi)`` of the face centre for normalized actions."""
        phi = q_phi * self.pose.phi_max
        x = q_x * self._half[ids] - self.pose.pivot_offset * torch.sin(phi)
        return x, phi

    # ------------------------------------------------------------------ glance
    def glance(self, object_ids, q_x, q_phi, q_y=None, q_phi_y=None) -> GlanceResult:
        """A batch of glances on ``object_ids`` (B,) at normalized poses ``q_x``, ``q_phi`` (B,).

        ``q_y`` and ``q_phi_y`` (the extended glance's pose) must be ``None`` or 0: this is the
        paper's line glance, whose pad rows all lie on the object at y = 0; other poses take the
        extended glance (:class:`ham.world.extended_glance.ExtendedSimulator`).
        """
        refuse_extended_pose(q_y, q_phi_y, self.device)
        ids = as_object_ids(object_ids, len(self.objects), self.device)
        qx = as_action("q_x", q_x, self.device).float()
        qp = as_action("q_phi", q_phi, self.device).float()
        try:
            ids, qx, qp = torch.broadcast_tensors(ids, qx, qp)
        except RuntimeError:
            raise HamError(
                f"object ids, q_x and q_phi must have equal lengths (or length 1), "
                f"got {len(ids)}, {len(qx)}, {len(qp)}"
            ) from None
        x, phi = self.poses(ids, qx, qp)
        n, taxels = len(ids), self.sensor.taxels
        f32 = dict(dtype=torch.float32, device=self.device)
        out = GlanceResult(
            pressure=torch.empty(n, taxels, taxels, **f32),
            force=torch.empty(n, **f32),
            z=torch.empty(n, **f32),
            contact=torch.empty(n, dtype=torch.bool, device=self.device),
            blocked=torch.empty(n, dtype=torch.bool, device=self.device),
            x=x,
            phi=phi,
        )
        # One set of (chunk, K) buffers for all chunks and calls: fresh multi-megabyte
        # temporaries would cost page faults that take as long as the arithmetic.
        work = self._workspace(min(n, self.chunk))
        for i in range(0, n, self.chunk):
            self._glance_into(out, slice(i, i + self.chunk), ids, x, phi, work)
        torch.gt(out.force, 0, out=out.contact)
        return out

    def _workspace(self, rows: int) -> _Workspace:
        """This thread's workspace for ``rows`` glances per chunk, kept between calls."""
        size = rows * max(self._u.shape[1], self._hu.shape[1])
        cache = self.__dict__.setdefault("_work", {})
        work = cache.get(threading.get_ident())
        if work is None or work.size < size:
            if len(cache) >= 8:  # threads come and go: drop the others' buffers
                cache.clear()
            work = cache[threading.get_ident()] = _Workspace(size, self.device)
        return work

    def _glance_into(self, out: GlanceResult, sl: slice, ids, x, phi, work: _Workspace) -> None:
        """Glances ``sl`` of the batch, written into ``out``'s rows ``sl``."""
        s, g = self.sensor, self.glance_config
        ids, x, phi = ids[sl], x[sl, None], phi[sl]
        cos, sin = torch.cos(phi)[:, None], torch.sin(phi)[:, None]
        # Read-out point k of the face sits at (x + u cos phi, z - u sin phi); it touches the
        # surface when the face centre is at e_k = h(x + u cos phi) + u sin phi.
        u = self._u
        shape = (len(ids), u.shape[1])
        e = self._heights_(ids, torch.mul(u, cos, out=work.get("t", shape)).add_(x), work, "e")
        e.add_(torch.mul(u, sin, out=work.get("f", shape)))
        if self._feat_x is not None:
            self._add_features(e, ids, x, cos, sin)
        top = e.amax(1)
        e.sub_(top[:, None])  # relative to the first touch: small numbers, float32-exact enough
        z_force = solve_stop_height(e, g.force_threshold / self._c0, work)
        # Rigid parts: the pad behind the foam (foam fully compressed) and the housing's sides.
        hu, hv = self._hu, self._hv
        shape = (len(ids), hu.shape[1])
        t = torch.mul(hu, cos, out=work.get("t", shape)).add_(x)
        t.add_(torch.mul(hv, sin, out=work.get("f", shape)))
        e_h = self._heights_(ids, t, work, "a")
        e_h.add_(torch.mul(hu, sin, out=work.get("t", shape)))
        e_h.sub_(torch.mul(hv, cos, out=work.get("t", shape)))
        z_block = e_h.amax(1).sub_(top).clamp_min_(-s.foam_thickness)
        z_rel = torch.maximum(z_force, z_block)
        torch.add(top, z_rel, out=out.z[sl])
        torch.gt(z_block, z_force, out=out.blocked[sl])
        compression = e.sub_(z_rel[:, None]).clamp_(0, s.foam_thickness)
        torch.mul(compression.sum(1), self._c0, out=out.force[sl])
        if self._direct_image:  # Myrmex.image, written straight into the output
            v = compression.view(-1, s.taxels, s.supersample)
            if s.supersample <= 8:
                # The mean over each cell's read-out points summed as torch's CPU mean sums so
                # few (in order, then / S; bit-identical), but as S - 1 strided adds: a
                # reduction over 4 values costs several times more.
                cols = work.get("d", v.shape[:2]).copy_(v[..., 0])
                for k in range(1, s.supersample):
                    cols.add_(v[..., k])
                cols = cols.div_(s.supersample)
            else:
                cols = v.mean(-1)
            out.pressure[sl] = cols.mul_(s.foam_stiffness)[:, None, :]
        else:
            out.pressure[sl] = self.myrmex.image(compression)

    # ------------------------------------------------------------------ narrow features
    def _set_features(self, maps: np.ndarray) -> None:
        """Find each object's narrow peaks, which the read-out points could step over.

        The read-out points sample the surface every ``W = pitch / supersample`` (1.25 mm): a peak
        narrower than that (a 0.6 mm spike) can fall between two of them and go unfelt, and the
        pad then sinks through it. A map sample is *narrow* when the surface falls by more than
        ``FEATURE_SLOPE * W`` within ``W`` on both sides (table beside the block at 0): everywhere
        else some point within ``W`` stands at most ``W`` lower, so sampling misses at most as
        much height as on a 45-degree slope. Of the narrow samples we keep those where a linear
        function can peak (run ends and concave kinks): the *feature points*. The paper's four
        objects have none (their corners fall on one side only, the ramps' by 0.5 W), so their
        glances take the plain path, bit for bit.
        """
        s = self.sensor
        spacing = s.pitch / s.supersample
        n = maps.shape[1] - 1
        feats = []
        for o, hs in zip(self.objects, maps, strict=True):
            dx = o.width / n
            m = max(1, int(round(spacing / dx)))
            padded = np.concatenate([np.zeros(m), hs, np.zeros(m)])  # the table beside the block
            win = np.lib.stride_tricks.sliding_window_view(padded, m)
            left = win[: len(hs)].min(1)  # samples i - m .. i - 1
            right = win[m + 1 : m + 1 + len(hs)].min(1)  # samples i + 1 .. i + m
            drop = FEATURE_SLOPE * spacing
            narrow = (hs - left > drop) & (hs - right > drop)
            nb = np.concatenate([[False], narrow, [False]])
            hp = np.concatenate([[0.0], hs, [0.0]])
            end = ~nb[:-2] | ~nb[2:]
            kink = hs - 0.5 * (hp[:-2] + hp[2:]) > 1e-12
            keep = np.flatnonzero(narrow & (end | kink))
            xs = np.linspace(-0.5 * o.width, 0.5 * o.width, n + 1)
            feats.append((xs[keep], hs[keep]))
        f = max(len(x) for x, _ in feats)
        self.features = [len(x) for x, _ in feats]
        if f == 0:
            self._feat_x = self._feat_h = None
            return
        fx = np.zeros((len(feats), f))
        fh = np.full((len(feats), f), -np.inf)  # padding: never the highest point of a cell
        for i, (x, h) in enumerate(feats):
            fx[i, : len(x)], fh[i, : len(h)] = x, h
        f32 = dict(dtype=torch.float32, device=self.device)
        self._feat_x, self._feat_h = torch.tensor(fx, **f32), torch.tensor(fh, **f32)
        self._has_features = torch.tensor([len(x) > 0 for x, _ in feats], device=self.device)

    def _add_features(self, e: torch.Tensor, ids, x, cos, sin) -> None:
        """Raise each read-out point's touch height ``e`` (B, K) to the highest feature point in
        its cell: the cell's foam meets a narrow peak there before its own sample touches."""
        s = self.sensor
        spacing = s.pitch / s.supersample
        # Only the rows on objects with feature points (often a minority of a mixed batch).
        rows = self._has_features[ids].nonzero().squeeze(1)
        if len(rows) == 0:
            return
        all_rows = len(rows) == len(ids)
        if not all_rows:
            ids, x, cos, sin = ids[rows], x[rows], cos[rows], sin[rows]
        # Feature point (x_f, h_f) lies on the face at u_f = (x_f - x) / cos phi and touches it
        # when the face centre is at h_f + u_f sin phi, like a read-out point.
        u = (self._feat_x[ids] - x) / cos
        ef = self._feat_h[ids] + u * sin
        cell = torch.floor((u + 0.5 * s.size) / spacing)
        inside = (cell >= 0) & (cell < e.shape[1])  # NaN/inf (a vertical pad) fall outside
        ef = torch.where(inside, ef, -torch.inf)
        cell = torch.where(inside, cell, 0).long()
        if all_rows:
            e.scatter_reduce_(1, cell, ef, "amax")
        else:
            e.index_copy_(0, rows, e.index_select(0, rows).scatter_reduce_(1, cell, ef, "amax"))

    def describe(self) -> dict:
        return {
            "simulator": self.name,
            "objects": [o.name for o in self.objects],
            "sensor": self.sensor.to_dict(),
            "pose": asdict(self.pose),
            "glance": asdict(self.glance_config),
            "height_map_resolution": self.resolution,
        }


_FIELDS = ("pressure", "force", "z", "contact", "blocked", "x", "phi", "y", "phi_y", "height")


class _Workspace:
    """Named flat float32 (or int32) buffers of ``size`` elements, reused across chunks."""

    def __init__(self, size: int, device: torch.device) -> None:
        self.size, self.device, self._bufs = size, device, {}

    def get(self, name: str, shape: tuple, dtype: torch.dtype = torch.float32) -> torch.Tensor:
        """The first ``prod(shape)`` elements of buffer ``name``, viewed as ``shape``."""
        buf = self._bufs.get(name)
        if buf is None or buf.dtype != dtype:
            buf = self._bufs[name] = torch.empty(self.size, dtype=dtype, device=self.device)
        return buf.as_strided(shape, _contiguous_strides(shape))


def _contiguous_strides(shape: tuple) -> tuple:
    if len(shape) == 2:  # the common case, kept cheap
        return (shape[1], 1)
    strides, step = [], 1
    for n in reversed(shape):
        strides.append(step)
        step *= n
    return tuple(reversed(strides))


def solve_stop_height(
    e: torch.Tensor, target: float, work: _Workspace | None = None, z0: torch.Tensor | None = None
) -> torch.Tensor:
    """The height z with ``sum_k max(0, e_k - z) = target`` for each row of ``e`` (B, K).

    Newton's method on the convex, decreasing, piecewise-linear left side, started below the
    root (where one point alone carries the target), moves up monotonically and is exact once the
    active set stops changing: at most K iterations, usually 3-6.

    ``work``: a workspace for the temporaries (its ``t``, ``d``, ``f`` and ``a`` buffers).
    ``z0``: another lower bound of the root (B,), if known: e.g. the root over a subset of the
    points (any subset's root lies below: its force is never more at the same height).
    """
    if work is None:
        work = _Workspace(e.numel(), e.device)
    # Two lower bounds of the root: one point carries everything, or all points press equally.
    z = torch.maximum(e.amax(1) - target, (e.sum(1) - target) / e.shape[1])
    if z0 is not None:
        z = torch.maximum(z, z0)
    rows, ez, zz = None, e, z
    spare = ("f", "a")  # the rows still moving are copied back and forth between these
    copies = 0
    for _ in range(e.shape[1] + 1):
        # The active set as a float mask written by the comparison itself (a bool mask and its
        # conversion cost far more on CPU); the sums stay in e's dtype.
        act = torch.gt(ez, zz[:, None], out=work.get("t", ez.shape, e.dtype))
        s = torch.mul(ez, act, out=work.get("d", ez.shape, e.dtype)).sum(1)
        z_new = (s - target) / act.sum(1).clamp_min_(1)
        moved = z_new > zz
        zz = torch.maximum(zz, z_new)
        if rows is None:
            z = zz
        else:
            z.index_copy_(0, rows, zz)
        keep = moved.nonzero().squeeze(1)
        if len(keep) == 0:
            break
        # Iterate on the rows still moving only, once at most half of them are: copying nearly
        # all rows costs more than another step on the few that have converged (a converged
        # row's step finds the same active set and the same z: the result does not change).
        if 2 * len(keep) <= len(zz):
            rows = keep if rows is None else rows.index_select(0, keep)
            dst = work.get(spare[copies % 2], (len(keep), e.shape[1]), e.dtype)
            ez, zz = torch.index_select(ez, 0, keep, out=dst), zz.index_select(0, keep)
            copies += 1
    return z
