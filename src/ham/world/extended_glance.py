"""The extended glance ``g: (x, y, phi, phi_y) -> (p, h)`` on height-field objects.

The paper's Discussion names it: a glance that also returns the contact height h, and for objects
whose curvature is two-dimensional "two orientation parameters instead of one". The pad is posed
at ``(x, y)`` with tilts ``phi`` (the paper's, about the y axis) and ``phi_y`` (about the x axis)
and lowered along -z until the summed force reaches 2 N, as in :mod:`ham.world.glance`; it returns
its N x N image and ``height``, the face centre's height at the stop.

Pose (normalized ``q in [-1, 1]^4``; :class:`ham.world.glance.PoseConfig`): ``x`` as in the
paper's glance (zone half width, the authors' pivot shift ``-p sin(phi) cos(phi_y)``),
``y = q_y * depth / 2 + p sin(phi_y)`` ... with ``p = 0`` (paper) simply ``q_y * depth / 2``,
``phi = q_phi * phi_max``, ``phi_y = q_phi_y * phi_max``. The face point at pad coordinates
``(u, v)`` lies at ``d = R_y(phi) R_x(phi_y) (u, v, 0)`` from the face centre::

    d = (u cos(phi) - v sin(phi_y) sin(phi),  v cos(phi_y),  -u sin(phi) - v sin(phi_y) cos(phi))

and touches the surface when the centre is at ``e = h(x + d_x, y + d_y) - d_z``. The stop height
solves ``c0 * sum_k max(0, e_k - z) = 2 N`` exactly (:func:`ham.world.glance.solve_stop_height`).

Model (:class:`ExtendedSimulator`):

* **Surfaces.** Each object's ``surface(x, y)`` is sampled once on a grid (``grid_step``, 0.2 mm,
  across the base, edges included) and read bilinearly; an object that does not vary in y (the
  paper's, extruded) is sampled like the line glance, ``resolution`` (4096) intervals along x and
  exactly constant in y. Beside the base the table (0) is read: the block's sides are vertical.
  An optional per-row object pose ``(yaw, dx, dy)`` rotates the object by ``yaw`` about z and
  shifts its centre to ``(dx, dy)`` under the pad (random object pose per episode).
* **Read-out points.** ``sensor.supersample`` (4) points per taxel along u, as the line glance,
  and ``rows_per_taxel`` (default 1) along v: 64 x 16 = 1024 points. With one row the points are
  *staggered* (``stagger``, default): a taxel's 4 points, evenly spaced along u, lie at 4
  different v too (one per quarter of the cell, ``STAGGER``), so an edge or a rim contact inside
  a taxel row presses 1-3 of its points, where points on the taxel's centre line read all or
  nothing (docs/crosscheck_curvature2d.md: the images' correlation with the converged foam's
  rose from 0.939-0.947 to >= 0.966 per object at the same cost). The columns are stored
  phase-major (all taxels' first points, then the second ...), so the per-point v offset is a
  (B, R, S, 1) term. With ``rows_per_taxel = supersample`` the grid is isotropic (4096 points,
  ~4x slower; not staggered). A taxel reads the mean compression over its points times the foam
  stiffness.
* **Rigid stops** (as the line glance): the pad body behind the foam (a point compressed through
  the whole foam stops the pad) and the housing's four sides, sampled on
  ``housing_edge_samples`` (3) points along each edge (corners included) by ``housing_samples``
  (6) along the pad normal from the foam's back to the housing's back. And the pad's back (the
  foam's back) where a block's edge meets it: where each rim line of the face crosses each edge
  line of the base, and the base's corners under the face (:meth:`ExtendedSimulator._edge_points`,
  20 points). The base's sides are vertical, so over a rim line the block is highest where the
  line leaves the base, often between the samples: without these points a pad tilted over a
  block's edge or corner sank its back up to 2.5 mm into the block (docs/crosscheck_curvature2d.md,
  "Which model is off"). The line glance has no such points (the paper's world is unchanged): on
  extruded objects the two differ where the line glance's back passes through a block's end.
* **Narrow features.** Points sample the surface every ``pitch / supersample`` (1.25 mm) along u
  and ``pitch / rows_per_taxel`` (5 mm) along v. The line glance's *feature points* (narrow peaks
  of an extruded profile, :meth:`ham.world.glance.FastSimulator._set_features`) are carried over
  as lines along y: in each row of points, the point whose cell the line crosses is raised to it,
  so the pad stops on a spike or a trough's lip as in the line glance. A height field's own narrow
  ridges and spikes are not searched for: one narrower than the spacing can fall between points
  and go unfelt, and an edge tilted against the pad is felt late by up to one spacing times the
  tilt's sine (for an isotropic 1.25 mm grid: ``rows_per_taxel = 4``).

Speed (one core): every ``(B, K)`` step is one vectorized pass without boolean temporaries, the
coordinates are outer sums of per-row u and v terms (no ``(B, K)`` rotation), the bilinear
coefficients are four float32 tables read with int64 indices (index_select converts int32
ones first), and the temporaries live in a
per-thread workspace reused across chunks and calls (numbers in docs/world.md).
"""

from __future__ import annotations

import math
import threading
from dataclasses import asdict

import numpy as np
import torch

from ham.errors import HamError
from ham.world.glance import (
    FastSimulator,
    GlanceConfig,
    GlanceResult,
    PoseConfig,
    _Workspace,
    as_action,
    as_object_ids,
    check_foam,
    solve_stop_height,
)
from ham.world.objects import HapticObject
from ham.world.sensor import Myrmex, SensorConfig

#: Default sampling step (m) of a height-field object's surface grid: 0.5 mm, 181 x 181 samples
#: over a 9 cm base: a dome of 16 cm radius is read within 0.2 um, a sharp edge within 0.25 mm
GRID_STEP = 5e-4
#: Points along each edge of the housing's sides (corners included), times ``housing_samples``
#: along the pad's normal: 8 x 6 = 48 rigid points.
HOUSING_EDGE_SAMPLES = 3
#: Points along each rim line of the pad's rigid back (the foam's back; corners included), every
#: 10 mm of the 8 cm face: the back's highest contact along a rim is often a smooth maximum between
#: the housing's samples (the cone's slope nearest its apex), which a 10 mm spacing reads within
#: ~0.1 mm there; with the housing's 3 per side at that depth, 24 more rigid points.
RIM_SAMPLES = 9
#: The order of the staggered read-out's v offsets within a taxel's columns (``stagger``): each of
#: the ``supersample`` points of a taxel row in its own stratum of v, neighbours far apart.
STAGGER = {2: [0, 1], 4: [1, 3, 0, 2]}
#: Points of the pad's rigid back where a block's edge meets it (:meth:`_edge_points`): 4 rim
#: lines x 4 edge lines, and the base's 4 corners.
EDGE_POINTS = 20
#: Most grid cells per object: float32 map coordinates index cells exactly below 2^24.
MAX_CELLS = 1 << 24
#: Batches of at least this many glances are computed in object order (cache locality; measured
#: on one core: 10% slower at 16-64 mixed glances, even at 256, 1.2x faster at 16,384).
SORT_MIN = 256


def stagger_order(su: int) -> list[int]:
    """The quarter (stratum of v) of each of a taxel's ``su`` points along u in the staggered
    read-out: a permutation of ``0 .. su-1`` (:data:`STAGGER`, else a stride coprime with
    ``su`` from ``su // 2 + 1`` on, so that neighbours lie far apart and no stratum repeats)."""
    if su in STAGGER:
        return list(STAGGER[su])
    step = next(k for k in range(su // 2 + 1, 2 * su) if math.gcd(k, su) == 1)
    return [(j * step) % su for j in range(su)]


def _square_rim(n: int, size: float) -> tuple[np.ndarray, np.ndarray]:
    """``(u, v)`` of ``n`` points along each side of the ``size`` square centred on 0, corners
    once: the sides u = -+size/2 over v, then v = -+size/2 over u."""
    edge = np.linspace(-0.5 * size, 0.5 * size, n)
    half = np.full(n, 0.5 * size)
    u = np.concatenate([-half, half, edge[1:-1], edge[1:-1]])
    v = np.concatenate([edge, edge, -half[1:-1], half[1:-1]])
    return u, v


def _f32_step(n: int) -> float:
    """The float32 spacing just above ``n``: the padding cell's width (see :meth:`_build_maps`)."""
    return float(np.nextafter(np.float32(n), np.float32(np.inf))) - n


def _axis_ops(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Left and right node values of the padded cells ``-1 .. n`` of an axis with ``n`` intervals,
    as matrices ``(n + 2, n + 1)`` over the ``n + 1`` node values.

    Cell -1 is the table (0 at both ends). Cell ``n`` starts at the end node and falls to 0 one
    float32 step later, so that a coordinate exactly at the end reads the end height and anything
    beyond (clamped to that next float) reads 0: vertical sides, no mask.
    """
    left = np.zeros((n + 2, n + 1))
    right = np.zeros((n + 2, n + 1))
    idx = np.arange(n)
    left[idx + 1, idx] = 1.0
    right[idx + 1, idx + 1] = 1.0
    left[n + 1, n] = 1.0
    right[n + 1, n] = 1.0 - 1.0 / _f32_step(n)
    return left, right


class ExtendedSimulator:
    """The vectorized foam-contact model of the extended glance, exact in the stop height.

    Same interface as :class:`ham.world.glance.FastSimulator` plus ``q_y``, ``q_phi_y`` and an
    optional per-row ``object_pose``; CPU or CUDA via torch. See the module doc for the model.
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
        grid_step: float = GRID_STEP,
        resolution: int = 4096,
        rows_per_taxel: int = 1,
        housing_edge_samples: int = HOUSING_EDGE_SAMPLES,
        rim_samples: int = RIM_SAMPLES,
        stagger: bool = True,
        chunk: int | None = None,
    ) -> None:
        if not objects:
            raise HamError("a simulator needs at least one object")
        if not (isinstance(grid_step, (int, float)) and 1e-5 <= grid_step <= 0.01):
            raise HamError(f"grid_step = {grid_step!r}; accepted: 1e-5 .. 0.01 (m)")
        if not (isinstance(resolution, int) and 2 <= resolution <= 1 << 16):
            raise HamError(f"resolution = {resolution!r}; accepted: an integer 2 .. 65536")
        if not (isinstance(rows_per_taxel, int) and 1 <= rows_per_taxel <= 16):
            raise HamError(f"rows_per_taxel = {rows_per_taxel!r}; accepted: an integer 1 .. 16")
        if not (isinstance(housing_edge_samples, int) and 2 <= housing_edge_samples <= 256):
            raise HamError(
                f"housing_edge_samples = {housing_edge_samples!r}; accepted: an integer 2 .. 256"
            )
        if not (isinstance(rim_samples, int) and 2 <= rim_samples <= 256):
            raise HamError(f"rim_samples = {rim_samples!r}; accepted: an integer 2 .. 256")
        if chunk is not None and not (isinstance(chunk, int) and chunk >= 1):
            raise HamError(f"chunk = {chunk!r}; accepted: None (automatic) or an integer >= 1")
        self.objects = list(objects)
        self.myrmex = Myrmex(sensor)
        self.sensor = s = self.myrmex.config
        self.pose = pose or PoseConfig()
        self.glance_config = glance or GlanceConfig()
        check_foam(self.sensor, self.glance_config)
        self.device = torch.device(device)
        self.grid_step = float(grid_step)
        self.resolution = resolution
        self.rows_per_taxel = rows_per_taxel
        f32 = dict(dtype=torch.float32, device=self.device)
        self._build_maps()
        self._build_features()
        self._half_x = torch.tensor([self.pose.half_width(o) for o in self.objects], **f32)
        self._half_y = torch.tensor([self.pose.half_depth(o) for o in self.objects], **f32)
        # Read-out points: columns along u (as the line glance), rows along v.
        # Columns phase-major: column j * T + t is taxel t's j-th point along u (T taxels), so a
        # term that varies with the point's place in its taxel (the stagger) broadcasts over T
        # contiguous values. Per taxel the values are met in the same order as u-major.
        su, nt = s.supersample, s.taxels
        self._u = torch.tensor(self.myrmex.sample_u().reshape(nt, su).T.ravel(), **f32)
        sv = rows_per_taxel
        k = np.arange(s.taxels * sv)
        self._v = torch.tensor((k + 0.5) * (s.pitch / sv) - 0.5 * s.size, **f32)
        # The staggered read-out: one row per taxel only (more rows are a 2-D grid already).
        self.stagger = bool(stagger) and su > 1 and sv == 1
        self._dv = self._dv_col = None  # (su,) and (C,): the points' v offsets (stagger)
        if self.stagger:
            perm = np.array(stagger_order(su))
            self._dv = torch.tensor(((perm + 0.5) / su - 0.5) * (s.pitch / sv), **f32)
            self._dv_col = self._dv.repeat_interleave(nt)  # (C,): per column, phase-major
        # Housing sides: u = +-L/2 over v, v = +-L/2 over u (corners once), w along the normal.
        # Each side at its two corners and its middle: the rigid stops are for steep tilts,
        # where a side lies nearly flat; fewer points, since each costs a scattered lookup.
        m = self.glance_config.housing_samples
        self.housing_edge_samples = housing_edge_samples
        hu, hv = _square_rim(housing_edge_samples, s.size)
        w = np.linspace(s.foam_thickness, s.foam_thickness + s.housing_thickness, m)
        # The back's rim lines (w = foam_thickness) more densely: the points not already there.
        self.rim_samples = rim_samples
        ru, rv = _square_rim(rim_samples, s.size)
        new = ~np.isin(ru + 1j * rv, hu + 1j * hv)
        ru, rv = ru[new], rv[new]
        self._hu = torch.tensor(np.concatenate([np.repeat(hu, m), ru]), **f32)
        self._hv = torch.tensor(np.concatenate([np.repeat(hv, m), rv]), **f32)
        back = np.full(len(ru), s.foam_thickness)
        self._hw = torch.tensor(np.concatenate([np.tile(w, len(hu)), back]), **f32)
        # The edge points (:meth:`_edge_points`) lie on the foam's back: w = foam_thickness.
        self._hw_all = torch.cat([self._hw, torch.full((EDGE_POINTS,), s.foam_thickness, **f32)])
        self._rims = torch.tensor([-0.5 * s.size, 0.5 * s.size], **f32)
        # Force per metre of compression at one read-out point.
        self._c0 = s.foam_stiffness * s.taxel_area / (s.supersample * sv)
        self._direct_image = (
            type(self.myrmex) is Myrmex and s.spread_sigma is None and s.quantize_bits is None
        )
        # Glances per chunk: about 2^20 read-out points (4 MB buffers; measured best on one
        # core among 2^17 .. 2^21): fewer and the per-call overhead of each step shows.
        self.chunk = chunk or max(64, (1 << 20) // (len(self._u) * len(self._v)))

    # ------------------------------------------------------------------ height maps
    def _build_maps(self) -> None:
        """Each object's bilinear coefficients on its padded grid, in four flat float32 tables.

        Cell ``(i, j)`` (``i = -1 .. nx``, ``j = -1 .. ny``) holds ``(a, b, c, d)`` with
        ``h = a + wx b + wy (c + wx d)`` for the cell's fractions ``wx, wy``.
        """
        coefs, meta = [], []
        base = 0
        for o in self.objects:
            if o.varies_in_y:
                nx = max(1, math.ceil(o.width / self.grid_step - 1e-9))
                ny = max(1, math.ceil(o.depth / self.grid_step - 1e-9))
                nodes = np.asarray(o.height_field(nx + 1, ny + 1), dtype=np.float64)
            else:  # extruded: the line glance's samples along x, exactly constant along y
                nx, ny = self.resolution, 1
                xs = np.linspace(-0.5 * o.width, 0.5 * o.width, nx + 1)
                row = np.asarray(o.profile(xs), dtype=np.float64)
                nodes = np.stack([row, row])
            if (nx + 2) * (ny + 2) > MAX_CELLS:
                raise HamError(
                    f"object {o.name!r}: a {nx} x {ny} cell grid is too fine (grid_step = "
                    f"{self.grid_step:g} m); accepted: at most {MAX_CELLS} cells, a larger grid_step"
                )
            # float32 samples first: the padding slopes -h/step are then exact (step: power of 2)
            nodes = nodes.astype(np.float32).astype(np.float64)
            lx, rx = _axis_ops(nx)
            ly, ry = _axis_ops(ny)
            hl, hr = nodes @ lx.T, nodes @ rx.T  # (ny + 1, nx + 2)
            c00, c10, c01, c11 = ly @ hl, ly @ hr, ry @ hl, ry @ hr  # (ny + 2, nx + 2)
            a, b, c = c00, c10 - c00, c01 - c00
            d = c11 - c10 - c01 + c00
            coefs.append(np.stack([a, b, c, d]).reshape(4, -1))
            meta.append((nx, ny, o.width, o.depth, base))
            base += (nx + 2) * (ny + 2)
        if base >= 2**31:
            raise HamError(f"{base} height-map cells in all; accepted: fewer than 2^31")
        f32 = dict(dtype=torch.float32, device=self.device)
        tables = torch.tensor(np.concatenate(coefs, axis=1), **f32)
        self._map_a, self._map_b, self._map_c, self._map_d = (t.contiguous() for t in tables)
        self._meta = meta
        nx, ny, w, dp, b0 = (torch.tensor(v, dtype=torch.float64) for v in zip(*meta, strict=True))
        dev = self.device
        self._nx = nx.to(dev, torch.float32)
        self._ny = ny.to(dev, torch.float32)
        self._scale_x = (nx / w).to(dev, torch.float32)  # cells per metre
        self._scale_y = (ny / dp).to(dev, torch.float32)
        self._off_x = (0.5 * nx).to(dev, torch.float32)  # the cell coordinate of local x = 0
        self._off_y = (0.5 * ny).to(dev, torch.float32)
        self._hi_x = torch.tensor([m[0] + _f32_step(m[0]) for m in meta], **f32)
        self._hi_y = torch.tensor([m[1] + _f32_step(m[1]) for m in meta], **f32)
        self._lo = torch.full((len(meta),), -1.0, **f32)
        # Each base's edge lines in cell coordinates (n_objects, 2), a thousandth of a cell (half
        # a micrometre) inside: x in {0, nx}, y in {0, ny}. A point computed on the line itself
        # lands a float32 rounding on either side, and beside the base the table is read.
        inset = 1e-3
        self._edge_x = torch.stack([torch.full_like(self._nx, inset), self._nx - inset], 1)
        self._edge_y = torch.stack([torch.full_like(self._ny, inset), self._ny - inset], 1)
        self._stride = torch.tensor([m[0] + 2 for m in meta], dtype=torch.float32, device=dev)
        # First cell (i, j) = (-1, -1) of each object: base + 0; (i, j) is at (j+1)(nx+2) + i+1.
        first = [m[4] + m[0] + 3 for m in meta]
        self._base = torch.tensor(first, dtype=torch.int64, device=dev)
        # Also as float32, exact below 2^24 cells in all (:meth:`_lookup_` adds it in float).
        self._float_index = base < 2**24
        self._base_f = torch.tensor(first, dtype=torch.float64).to(dev, torch.float32)
        self._uniform = len({m[:4] for m in meta}) == 1
        self.cells = [(m[0] + 2) * (m[1] + 2) for m in meta]

    def _build_features(self) -> None:
        """The line glance's narrow peaks of each extruded object (its *feature points*,
        :meth:`ham.world.glance.FastSimulator._set_features`), here lines along y; none for
        height fields. ``features`` counts them per object."""
        xs = [np.linspace(-0.5 * o.width, 0.5 * o.width, self.resolution + 1) for o in self.objects]
        maps = np.stack(
            [
                np.zeros(len(x)) if o.varies_in_y else np.asarray(o.profile(x), dtype=np.float64)
                for o, x in zip(self.objects, xs, strict=True)
            ]
        )
        FastSimulator._set_features(self, maps)  # sets features, _feat_x, _feat_h, _has_features
        if self._feat_x is not None:
            # Feature x as a cell coordinate of the object's map (as the read-out points are).
            ids = torch.arange(len(self.objects), device=self.device)
            self._feat_t = self._feat_x * self._scale_x[ids, None] + self._off_x[ids, None]

    def heights(self, ids, x, y) -> torch.Tensor:
        """Surface height (m) of objects ``ids`` (B,) at local ``(x, y)`` (B, K), float32: what
        the glance reads (bilinear on the height map, table beside the base)."""
        ids = as_object_ids(ids, len(self.objects), self.device)
        x = torch.as_tensor(x, dtype=torch.float32, device=self.device)
        y = torch.as_tensor(y, dtype=torch.float32, device=self.device)
        x, y = torch.broadcast_tensors(x, y)
        if x.dim() == 1:
            x, y = x[:, None], y[:, None]
        work = _Workspace(x.numel(), self.device)
        tx = x.mul(self._scale_x[ids, None]).add_(self._off_x[ids, None])[:, None, :]
        ty = y.mul(self._scale_y[ids, None]).add_(self._off_y[ids, None])[:, None, :]
        return self._lookup_(ids, tx, ty, work, "h").view(x.shape).clone()

    def _lookup_(self, ids, tx, ty, work: _Workspace, out: str) -> torch.Tensor:
        """Bilinear heights at cell coordinates ``tx`` (B, ...) and ``ty``, shaped like ``tx`` or
        broadcastable to it along the inner dims (``(B, R, 1)`` when y does not vary along a row;
        ``(B, R, S, 1)`` for the staggered read-out) (both overwritten); the result, shaped like
        ``tx``, in workspace buffer ``out``. Temporaries: ``i``, ``b``, ``c``, ``d``."""
        shape, yshape = tx.shape, ty.shape
        per = (-1,) + (1,) * (tx.dim() - 1)  # a per-glance value against the inner dims
        if self._uniform:
            tx.clamp_(-1.0, float(self._hi_x[0]))
            ty.clamp_(-1.0, float(self._hi_y[0]))
        else:
            # clamp_ with tensor bounds costs ~15x a scalar clamp on CPU: the lower bound (-1 for
            # every object) as a scalar, the upper one as a broadcast minimum (same values).
            torch.minimum(tx.clamp_min_(-1.0), self._hi_x[ids].view(per), out=tx)
            torch.minimum(ty.clamp_min_(-1.0), self._hi_y[ids].view(per), out=ty)
        fx = torch.floor(tx, out=work.get("b", shape))
        fy = torch.floor(ty, out=work.get("c", yshape))
        wx, wy = tx.sub_(fx), ty.sub_(fy)
        # Cell index: local (exact in float32: < 2^24 cells per object) plus the object's base,
        # added to the y term where y is broadcast along the inner dims, in float while exact.
        stride = float(self._stride[0]) if self._uniform else self._stride[ids].view(per)
        if self._float_index and fy.numel() < fx.numel():
            flat = fx.add_(fy.mul_(stride).add_(self._base_f[ids].view(per)))
            idx = work.get("i", shape, torch.int64).copy_(flat).view(-1)
        else:
            flat = fx.add_(fy, alpha=stride) if self._uniform else fx.addcmul_(fy, stride)
            idx = work.get("i", shape, torch.int64).copy_(flat)
            idx = idx.add_(self._base[ids].view(per)).view(-1)
        n = idx.numel()
        a = torch.index_select(self._map_a, 0, idx, out=work.get(out, (n,))).view(shape)
        b = torch.index_select(self._map_b, 0, idx, out=work.get("b", (n,))).view(shape)
        c = torch.index_select(self._map_c, 0, idx, out=work.get("c", (n,))).view(shape)
        d = torch.index_select(self._map_d, 0, idx, out=work.get("d", (n,))).view(shape)
        # h = a + wx b + wy (c + wx d)
        c = c.addcmul_(wx, d)
        a = a.addcmul_(wx, b)
        return a.addcmul_(wy, c)

    # ------------------------------------------------------------------ poses
    def poses(self, ids, q_x, q_y, q_phi, q_phi_y):
        """Metric ``(x, y, phi, phi_y)`` of the face centre for normalized actions
        (:meth:`ham.world.glance.PoseConfig.extended_pose`)."""
        return self.pose.extended_pose(
            q_x, q_y, q_phi, q_phi_y, self._half_x[ids], self._half_y[ids]
        )

    # ------------------------------------------------------------------ glance
    def glance(
        self, object_ids, q_x, q_phi, q_y=None, q_phi_y=None, *, object_pose=None
    ) -> GlanceResult:
        """A batch of glances on ``object_ids`` (B,) at normalized poses (B,) each (``None``: 0).

        ``object_pose``: optional ``(yaw, dx, dy)`` (B,) each (rad, m, m): the object rotated by
        ``yaw`` about z and its centre shifted to ``(dx, dy)`` under the pose frame.
        """
        dev = self.device
        ids = as_object_ids(object_ids, len(self.objects), dev)
        qs = [
            as_action(name, 0.0 if q is None else q, dev).float()
            for name, q in (("q_x", q_x), ("q_phi", q_phi), ("q_y", q_y), ("q_phi_y", q_phi_y))
        ]
        pose = None
        if object_pose is not None:
            pose = _object_pose(object_pose, dev)
        try:
            ids, qx, qp, qy, qpy, *pose_b = torch.broadcast_tensors(ids, *qs, *(pose or ()))
        except RuntimeError:
            lens = [len(t) for t in (ids, *qs, *(pose or ()))]
            raise HamError(
                "object ids, q_x, q_phi, q_y, q_phi_y (and object_pose) must have equal lengths "
                f"(or length 1), got {', '.join(map(str, lens))}"
            ) from None
        x, y, phi, phi_y = self.poses(ids, qx, qy, qp, qpy)
        n, taxels = len(ids), self.sensor.taxels
        f32 = dict(dtype=torch.float32, device=dev)
        out = GlanceResult(
            pressure=torch.empty(n, taxels, taxels, **f32),
            force=torch.empty(n, **f32),
            z=torch.empty(n, **f32),
            contact=torch.empty(n, dtype=torch.bool, device=dev),
            blocked=torch.empty(n, dtype=torch.bool, device=dev),
            x=x,
            phi=phi,
            y=y,
            phi_y=phi_y,
        )
        # The glances in object order: one object's height map (~130 kB per coefficient table at
        # 0.5 mm) stays in the cache across a chunk's gathers, where a mixed batch reads all
        # objects' maps in turn (~1.2 MB each for curvature2d: ~1.2x faster sorted). Each glance is
        # computed row by row, so the order does not change any value.
        order = self._object_order(ids)
        rows = (ids, x, y, phi, phi_y, *(pose_b if pose is not None else ()))
        if order is not None:
            rows = tuple(t.index_select(0, order) for t in rows)
        s_ids, s_x, s_y, s_phi, s_phi_y, *s_pose = rows
        work = self._workspace(min(n, self.chunk))
        for i in range(0, n, self.chunk):
            sl = slice(i, i + self.chunk)
            obj = tuple(t[sl] for t in s_pose) if s_pose else None
            dst = sl if order is None else order[sl]
            self._glance_into(
                out, dst, s_ids[sl], s_x[sl], s_y[sl], s_phi[sl], s_phi_y[sl], obj, work
            )
        torch.gt(out.force, 0, out=out.contact)
        out.height = out.z
        return out

    def _object_order(self, ids: torch.Tensor) -> torch.Tensor | None:
        """The batch's rows sorted by object (stable), or ``None`` when already in order or
        small (below :data:`SORT_MIN` glances the sort costs more than it saves)."""
        if len(self.objects) == 1 or len(ids) < SORT_MIN or not bool((ids[1:] < ids[:-1]).any()):
            return None
        return torch.argsort(ids, stable=True)

    def _workspace(self, rows: int) -> _Workspace:
        """This thread's workspace for ``rows`` glances per chunk, kept between calls."""
        size = rows * max(len(self._u) * len(self._v), len(self._hu) + EDGE_POINTS)
        cache = self.__dict__.setdefault("_work", {})
        work = cache.get(threading.get_ident())
        if work is None or work.size < size:
            if len(cache) >= 8:  # threads come and go: drop the others' buffers
                cache.clear()
            work = cache[threading.get_ident()] = _Workspace(size, self.device)
        return work

    def _frame(self, ids, x, y, phi, phi_y, obj):
        """Per-row terms of the affine map from pad coordinates to cell coordinates.

        Returns ``(tx0, ty0, xu, yu, xv, yv, xw, yw, zu, zv, zw)`` (B,): cell coordinate
        ``tx = tx0 + u xu + v xv + w xw`` (likewise ``ty``), and the point's height above the face
        centre ``-d_z = u zu + v zv + w zw`` with the sign that makes ``e = h + u zu + ...``.
        """
        cp, sp = torch.cos(phi), torch.sin(phi)
        cy, sy = torch.cos(phi_y), torch.sin(phi_y)
        # Directions of u, v and the normal w in the zone frame (x, y, z components).
        ux, uy, uz = cp, torch.zeros_like(cp), -sp
        vx, vy, vz = -sy * sp, cy, -sy * cp
        wx, wy, wz = sp * cy, sy, cp * cy
        cx, cyy = x, y
        if obj is not None:  # into the object's frame: rotate by -yaw about its shifted centre
            yaw, dx, dy = obj
            c, s = torch.cos(yaw), torch.sin(yaw)
            cx, cyy = c * (x - dx) + s * (y - dy), -s * (x - dx) + c * (y - dy)
            ux, uy = c * ux + s * uy, -s * ux + c * uy
            vx, vy = c * vx + s * vy, -s * vx + c * vy
            wx, wy = c * wx + s * wy, -s * wx + c * wy
        kx, ky = self._scale_x[ids], self._scale_y[ids]
        tx0 = cx * kx + self._off_x[ids]
        ty0 = cyy * ky + self._off_y[ids]
        return tx0, ty0, ux * kx, uy * ky, vx * kx, vy * ky, wx * kx, wy * ky, -uz, -vz, -wz

    def _glance_into(self, out: GlanceResult, dst, ids, x, y, phi, phi_y, obj, work) -> None:
        """Glances of ``ids`` at these poses, written into ``out``'s rows ``dst`` (a slice or
        an index tensor)."""
        s, g = self.sensor, self.glance_config
        b, su = len(ids), s.supersample
        tx0, ty0, xu, yu, xv, yv, xw, yw, zu, zv, zw = self._frame(ids, x, y, phi, phi_y, obj)
        u, v = self._u, self._v
        rows, cols = len(v), len(u)
        shape3 = (b, rows, cols)
        # Cell coordinates as outer sums of a u term (B, 1, C) and a v term (B, R, 1); with the
        # stagger, a v offset per phase (B, 1, S, 1) too.
        dv = self._dv
        nt = cols // su
        col_x = torch.addcmul(tx0[:, None], xu[:, None], u)
        if dv is not None:
            col_x.addcmul_(xv[:, None], self._dv_col)
        tx = work.get("t", (b, rows * cols)).view(shape3)
        torch.add(col_x[:, None, :], (xv[:, None] * v)[:, :, None], out=tx)
        if obj is None and dv is None:  # y varies along v only, one value per row (yu = 0)
            ty = torch.addcmul(ty0[:, None], yv[:, None], v, out=work.get("f", (b, rows)))
            ty = ty[:, :, None]
        elif obj is None:  # and per phase: (B, R, S, 1)
            ty = work.get("f", (b, rows * su)).view(b, rows, su, 1)
            torch.add(
                torch.addcmul(ty0[:, None], yv[:, None], v)[:, :, None, None],
                (yv[:, None] * dv)[:, None, :, None],
                out=ty,
            )
            tx = tx.view(b, rows, su, nt)
        else:
            col_y = torch.addcmul(ty0[:, None], yu[:, None], u)
            if dv is not None:
                col_y.addcmul_(yv[:, None], self._dv_col)
            ty = work.get("f", (b, rows * cols)).view(shape3)
            torch.add(col_y[:, None, :], (yv[:, None] * v)[:, :, None], out=ty)
        e = self._lookup_(ids, tx, ty, work, "e").view(shape3)
        col_z = zu[:, None] * u
        if dv is not None:
            col_z.addcmul_(zv[:, None], self._dv_col)
        e.add_(col_z[:, None, :])
        if self._feat_x is not None:
            self._add_features(e, ids, (tx0, ty0, xu, yu, xv, yv, zu, zv))
        # Heights relative to the first touch (the top): small numbers, float32-exact enough. The
        # v term (one value per row) and the top in one pass; the same top (rounding is monotone).
        row = (zv[:, None] * v)[:, :, None]  # (B, R, 1)
        top = e.amax(2, keepdim=True).add_(row).amax(1)  # (B, 1)
        e.add_(row.sub_(top[:, :, None]))
        top = top.view(b)
        e = e.view(b, -1)
        target = g.force_threshold / self._c0
        z0 = None
        if su > 1:
            # Newton from far below takes many steps over all K points: first the root over one
            # point per taxel (each taxel's highest), a lower bound found on K / su points.
            # (su - 1 strided maxima: an amax over so few inner values costs ~2.5x more)
            per = e.view(b, rows, su, nt)
            sub = work.get("g", (b, rows, nt))
            torch.maximum(per[:, :, 0], per[:, :, 1], out=sub)
            for k in range(2, su):
                sub = torch.maximum(sub, per[:, :, k], out=sub)
            sub = sub.view(b, rows * nt)
            z0 = solve_stop_height(sub, target, work)
        z_force = solve_stop_height(e, target, work, z0)
        # Rigid parts: the pad behind the foam (foam fully compressed), the housing's sides and
        # the back's points where a block's edge meets it (:meth:`_edge_points`), in one lookup.
        nh = len(self._hu)
        eu, ev = self._edge_points(ids, tx0, ty0, xu, yu, xv, yv, xw, yw)
        hshape = (b, nh + eu.shape[1])
        hu, hv, hw = work.get("u", hshape), work.get("v", hshape), self._hw_all
        hu[:, :nh], hu[:, nh:] = self._hu, eu
        hv[:, :nh], hv[:, nh:] = self._hv, ev
        tx = work.get("t", hshape)
        torch.addcmul(tx0[:, None], xu[:, None], hu, out=tx)
        tx.addcmul_(xv[:, None], hv).addcmul_(xw[:, None], hw)
        ty = work.get("f", hshape)
        torch.addcmul(ty0[:, None], yu[:, None], hu, out=ty)
        ty.addcmul_(yv[:, None], hv).addcmul_(yw[:, None], hw)
        e_h = self._lookup_(ids, tx[:, None, :], ty[:, None, :], work, "a").view(hshape)
        e_h.addcmul_(zu[:, None], hu).addcmul_(zv[:, None], hv).addcmul_(zw[:, None], hw)
        z_block = e_h.amax(1).sub_(top).clamp_min_(-s.foam_thickness)
        z_rel = torch.maximum(z_force, z_block)
        _put(out.z, dst, top.add_(z_rel))
        _put(out.blocked, dst, torch.gt(z_block, z_force))
        compression = e.sub_(z_rel[:, None]).clamp_(0, s.foam_thickness)
        _put(out.force, dst, compression.sum(1).mul_(self._c0))
        n, sv = s.taxels, self.rows_per_taxel
        if self._direct_image:  # Myrmex's read-out, per taxel over its su x sv points
            c = compression.view(b, n, sv, su, n)
            acc = work.get("d", (b, n * n)).view(b, n, n)
            # S - 1 strided adds in order: cheaper than a reduction over so few values.
            acc.copy_(c[:, :, 0, 0, :])
            for j in range(sv):
                for k in range(su):
                    if j or k:
                        acc.add_(c[:, :, j, k, :])
            _put(out.pressure, dst, acc.div_(su * sv).mul_(s.foam_stiffness))
        else:
            cells = compression.view(b, n, sv, su, n).mean((2, 3))
            _put(out.pressure, dst, self.myrmex.postprocess(cells * s.foam_stiffness))

    def _edge_points(self, ids, tx0, ty0, xu, yu, xv, yv, xw, yw):
        """Pad coordinates ``(u, v)`` (B, 20) on the pad's rigid back (the foam's back, ``w =
        foam_thickness``) where a block's edge meets it: where each of the face's four rim lines
        crosses each of the base's four edge lines, and the base's four corners under the face
        (each clamped into the face: any point of the back is rigid).

        The base's sides are vertical, so on a block whose top rises towards an edge (a flat top,
        the saddle along x) the highest point of the object over a rim line is where the line
        leaves the base: a point between the housing's samples and the read-out rows, which the
        pad's back would otherwise pass through (docs/crosscheck_curvature2d.md)."""
        half = 0.5 * self.sensor.size
        f = self.sensor.foam_thickness
        b = len(ids)
        ox, oy = torch.add(tx0, xw, alpha=f), torch.add(ty0, yw, alpha=f)  # the back's centre
        ex, ey = self._edge_x[ids][:, None, :], self._edge_y[ids][:, None, :]  # (B, 1, 2)
        side = self._rims  # (2,): -L/2, +L/2
        # Rim lines v = -+L/2, along u: tx = ox + xv v + xu u (ty likewise); the u where each
        # meets each edge line, (B, 2 rims, 4 edges); then the rims u = -+L/2, along v.
        free_u = torch.cat(
            [
                (ex - torch.addcmul(ox[:, None], xv[:, None], side)[:, :, None])
                / xu[:, None, None],
                (ey - torch.addcmul(oy[:, None], yv[:, None], side)[:, :, None])
                / yu[:, None, None],
            ],
            2,
        )
        free_v = torch.cat(
            [
                (ex - torch.addcmul(ox[:, None], xu[:, None], side)[:, :, None])
                / xv[:, None, None],
                (ey - torch.addcmul(oy[:, None], yu[:, None], side)[:, :, None])
                / yv[:, None, None],
            ],
            2,
        )
        # The base's corners on the back plane: (xu xv; yu yv) (u, v) = corner - centre.
        rx = (ex - ox[:, None, None]).expand(b, 2, 2).reshape(b, 4)
        ry = (ey - oy[:, None, None]).transpose(1, 2).expand(b, 2, 2).reshape(b, 4)
        det = (xu * yv - xv * yu)[:, None]
        fixed = side[None, :, None].expand(b, 2, 4).reshape(b, 8)
        u = torch.cat([free_u.reshape(b, 8), fixed, (rx * yv[:, None] - xv[:, None] * ry) / det], 1)
        v = torch.cat([fixed, free_v.reshape(b, 8), (xu[:, None] * ry - yu[:, None] * rx) / det], 1)
        return (
            torch.nan_to_num_(u, nan=0.0).clamp_(-half, half),
            torch.nan_to_num_(v, nan=0.0).clamp_(-half, half),
        )

    def _add_features(self, e: torch.Tensor, ids, frame) -> None:
        """Raise the touch height ``e`` (B, R, C) of the read-out point whose cell a feature line
        crosses, in each row, to the line's: the line glance's feature points, row by row. ``e``
        and the lines' heights leave out the term ``v zv``, one value per row."""
        s = self.sensor
        rows = self._has_features[ids].nonzero().squeeze(1)
        if len(rows) == 0:
            return
        tx0, ty0, xu, yu, xv, yv, zu, zv = (t[rows, None, None] for t in frame)
        ids_r = ids[rows]
        v = self._v[None, :, None]
        tf = self._feat_t[ids_r][:, None, :]  # (B', 1, F)
        # The row at v meets the line x = x_f where tx0 + u xu + v xv = t_f.
        uf = (tf - tx0 - v * xv) / xu  # (B', R, F); inf or NaN for a vertical pad: outside
        ef = self._feat_h[ids_r][:, None, :] + uf * zu
        tyf = ty0 + uf * yu + v * yv  # on the block along y?
        spacing = s.pitch / s.supersample
        cell = torch.floor((uf + 0.5 * s.size) / spacing)
        cols = e.shape[2]
        inside = (cell >= 0) & (cell < cols) & (tyf >= 0) & (tyf <= self._ny[ids_r, None, None])
        ef = torch.where(inside, ef, -torch.inf)
        cell = torch.where(inside, cell, 0).long()
        su = s.supersample
        phase = cell % su
        if self._dv is not None:
            # the point of that cell lies dv off the row's centre line: the line crosses its
            # v at u - dv xv / xu, and e carries its dv zv
            ef = ef + self._dv[phase] * (zv - zu * xv / xu)
        cell = phase * (cols // su) + cell // su  # the columns are phase-major
        sub = e.index_select(0, rows).scatter_reduce_(2, cell, ef, "amax")
        e.index_copy_(0, rows, sub)

    def describe(self) -> dict:
        return {
            "simulator": self.name,
            "model": "extended glance (height fields)",
            "objects": [o.name for o in self.objects],
            "sensor": self.sensor.to_dict(),
            "pose": asdict(self.pose),
            "glance": asdict(self.glance_config),
            "grid_step": self.grid_step,
            "height_map_resolution": self.resolution,
            "rows_per_taxel": self.rows_per_taxel,
            "stagger": self.stagger,
            **(
                {"housing_edge_samples": self.housing_edge_samples}
                if self.housing_edge_samples != HOUSING_EDGE_SAMPLES
                else {}
            ),
            **({"rim_samples": self.rim_samples} if self.rim_samples != RIM_SAMPLES else {}),
        }


def _put(target: torch.Tensor, rows, value: torch.Tensor) -> None:
    """``target[rows] = value`` for a slice or an index tensor of rows."""
    if isinstance(rows, slice):
        target[rows] = value
    else:
        target.index_copy_(0, rows, value)


def _object_pose(object_pose, device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(yaw, dx, dy)`` as three float32 1-D tensors, refusing anything else by name."""
    if not (isinstance(object_pose, (tuple, list)) and len(object_pose) == 3):
        raise HamError(
            f"object_pose = {object_pose!r}; accepted: (yaw, dx, dy), each a number or (B,) values"
        )
    out = []
    for name, t, limit in zip(("yaw", "dx", "dy"), object_pose, (None, 0.5, 0.5), strict=True):
        t = torch.as_tensor(t, dtype=torch.float64, device=device).reshape(-1)
        bad = ~torch.isfinite(t) if limit is None else ~(t.abs() <= limit)
        if bool(bad.any()):
            rule = "finite (rad)" if limit is None else f"finite, |{name}| <= {limit} m"
            raise HamError(f"object_pose {name} = {t[bad][0].item()!r}; accepted: {rule}")
        out.append(t.float())
    return tuple(out)
