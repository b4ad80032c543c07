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
``trough``, ``step`` and ``double_ridge``. The paper's next world adds objects whose top varies in
x and y (height fields, :meth:`HapticObject.from_surface`): the set ``curvature2d`` (ids 8..16:
flats of two heights, cylinders along x and y, dome, saddle, bowl, pyramid, cone) and the set
``composite`` (ids 17..28; 16 x 16 cm bases whose four 8 x 8 cm slots carry an edge, a flat, a
bump and a dimple in 12 arrangements) with its splits ``composite:train`` (= ``composite``) and
``composite:test`` (ids 29..40: the same arrangements built with other geometry; object i of each
split is arrangement i). Height fields also come from grey-scale images
(:meth:`HapticObject.from_image`) and the tops of triangle meshes (:meth:`HapticObject.from_mesh`). Users add their own with :func:`register`
and the constructors :meth:`HapticObject.from_function`, :meth:`HapticObject.from_polyline`
and :meth:`HapticObject.from_heightmap`, in their own program or in an *objects file*
(``--objects-file FILE`` on the command line, :func:`load_objects_file`): a self-contained Python
file that registers objects, or a JSON/TOML list of polylines and heightmaps. A world records the
file's name, sha256 and text (:func:`read_objects_file`), so a table or run built from it
re-registers the same objects wherever it is loaded (:func:`load_objects`), in any process.
"""

from __future__ import annotations

import functools
import itertools
import json
import math
import re
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ham.errors import HamError, brief, checked_arguments
from ham.world import recorded_file

#: Edge length of every block (m): "Building blocks ... 9 x 9 cm each".
BLOCK_SIZE = 0.09
#: Height of every block (m). The paper says only "the same height"; we use half the edge.
BLOCK_HEIGHT = 0.045
#: Largest width and depth (m) of a user's object: objects stand 0.3 m apart in the MuJoCo scene,
#: so a block up to 20 cm wide stays out of the pad's reach in the neighbouring zone.
MAX_SIZE = 0.2
#: Smallest width and depth (m): a millimetre, a little below the pad's read-out spacing (1.25
#: mm). A block of 1e-300 m made the fast simulator's search for narrow peaks a window of 10**296
#: samples (and the extended glance an index out of range).
MIN_SIZE = 0.001
#: The block height limit (m): no surface point above the block's 9 cm edge.
MAX_HEIGHT = BLOCK_SIZE
#: Samples of a height function checked by :meth:`HapticObject.from_function` (the simulators'
#: height maps and outlines use the same count).
PROFILE_SAMPLES = 4097

HeightFn = Callable[[np.ndarray], np.ndarray]
#: A vectorized surface ``h(x, y)`` (metres) over two arrays of the same shape (local frame).
SurfaceFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
#: Samples per side of a surface ``h(x, y)`` checked by :meth:`HapticObject.from_surface`.
SURFACE_SAMPLES = 513

# A name is one token: usable in comma lists, HDF5 paths and file names, and never an id.
_NAME = re.compile(r"[^\W\d][\w.+-]*")
_NAME_RULE = (
    "accepted: a letter or '_' first, then letters, digits, '_', '-', '.', '+' "
    "(no ',', ':', '/', spaces; not a number)"
)


def check_name(name: object) -> str:
    """``name`` if it can name an object, else a :class:`HamError` naming it."""
    if not isinstance(name, str):
        raise HamError(f"object name {name!r} is a {type(name).__name__}; {_NAME_RULE}")
    if not _NAME.fullmatch(name) or len(name) > 64:
        raise HamError(f"object name {name!r}; {_NAME_RULE}, at most 64 characters")
    if name in OBJECT_SETS or name == "all":
        raise HamError(f"object name {name!r} is the name of an object set; choose another name")
    return name


def _check_size(name: str, what: str, value: object) -> float:
    ok = isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool)
    if not ok or not (math.isfinite(value) and MIN_SIZE <= value <= MAX_SIZE):
        raise HamError(
            f"object {name!r}: {what} = {value!r}; accepted: a number in [{MIN_SIZE}, "
            f"{MAX_SIZE}] (m)"
        )
    return float(value)


@dataclass(frozen=True, eq=False)
class HapticObject:
    """A rigid block described by its height profile along x.

    Attributes:
        name: stable registry name (see :func:`check_name`).
        profile: vectorized ``h(x)`` in metres for a 1-D array ``x`` in ``[-width/2, width/2]``
            (local frame), returning an array of the same shape.
        width: extent along x (m); the block occupies ``[-width/2, width/2]``.
        depth: extent along y (m); the shape is constant along y.
        height: the block's maximum height (m), used for plots and scene sizes.
        vertices: exact profile vertices ``(N, 2)`` as ``(x, z)`` when the profile is piecewise
            linear; ``None`` for curved profiles, which are sampled by :meth:`outline`.
        description: one line for ``ham objects``.
        surface_fn: ``h(x, y)`` for an object whose top varies in y too (the paper's next world:
            :meth:`from_surface`, :meth:`from_height_field`); ``None`` for the paper's objects,
            whose ``profile`` is extruded along y. For such an object ``profile`` is the section
            at ``y = 0``, and only glance models of the extended glance may touch it
            (:attr:`varies_in_y`).
    """

    name: str
    profile: HeightFn
    width: float = BLOCK_SIZE
    depth: float = BLOCK_SIZE
    height: float = BLOCK_HEIGHT
    vertices: np.ndarray | None = field(default=None, repr=False)
    description: str = ""
    surface_fn: SurfaceFn | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        check_name(self.name)
        if not callable(self.profile):
            raise HamError(f"object {self.name!r}: profile {self.profile!r} is not a function")
        _check_size(self.name, "width", self.width)
        _check_size(self.name, "depth", self.depth)
        h = self.height
        number = isinstance(h, (int, float, np.integer, np.floating)) and not isinstance(h, bool)
        if not (number and math.isfinite(h) and 0 < h <= MAX_HEIGHT):
            raise HamError(
                f"object {self.name!r}: height = {h!r}; accepted: a number in (0, {MAX_HEIGHT}] (m)"
            )
        if not isinstance(self.description, str) or "\n" in self.description:
            raise HamError(
                f"object {self.name!r}: description {self.description!r}; accepted: one line of text"
            )
        if self.surface_fn is not None and not callable(self.surface_fn):
            raise HamError(
                f"object {self.name!r}: surface_fn {brief(self.surface_fn)} is not a function"
            )
        v = None if self.vertices is None else _as_reals(self.vertices)
        if self.vertices is not None and not (
            not isinstance(v, str)
            and v.ndim == 2
            and v.shape[1] == 2
            and len(v) >= 2
            and np.isfinite(v).all()
        ):  # the MuJoCo scene and outline() read them as the top's exact polyline
            raise HamError(
                f"object {self.name!r}: vertices {brief(self.vertices)}; accepted: None or N >= 2 "
                "finite points (x, z) (HapticObject.from_polyline makes them from a polyline)"
            )

    @property
    def varies_in_y(self) -> bool:
        """Whether the top varies in y (a height field), not a profile extruded along y."""
        return self.surface_fn is not None

    def surface(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Surface height (m) at local ``(x, y)`` (arrays of one shape): the top on the base
        ``[-width/2, width/2] x [-depth/2, depth/2]``, 0 (the table) beside it. For the paper's
        objects this is ``profile(x)`` for every y on the block."""
        x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        hw, hd = 0.5 * self.width, 0.5 * self.depth
        inside = (np.abs(x) <= hw) & (np.abs(y) <= hd)
        xc = np.clip(x, -hw, hw).reshape(-1)
        if self.surface_fn is None:
            h = np.asarray(self.profile(xc), dtype=np.float64)
        else:
            yc = np.clip(y, -hd, hd).reshape(-1)
            h = np.asarray(self.surface_fn(xc, yc), dtype=np.float64)
        return np.where(inside, h.reshape(x.shape), 0.0)

    def height_field(self, nx: int = 257, ny: int | None = None) -> np.ndarray:
        """The top sampled on ``ny x nx`` points spanning the base, edges included: array
        ``(ny, nx)``, row ``j`` at ``y = -depth/2 + j * depth / (ny - 1)``."""
        ny = nx if ny is None else ny
        xs = np.linspace(-0.5 * self.width, 0.5 * self.width, nx)
        ys = np.linspace(-0.5 * self.depth, 0.5 * self.depth, ny)
        gx, gy = np.meshgrid(xs, ys)
        return self.surface(gx, gy)

    def height_at(self, x: np.ndarray) -> np.ndarray:
        """Surface height (m) at local positions ``x``: the profile on the block, 0 (table) beside it."""
        x = np.asarray(x)
        half = 0.5 * self.width
        inside = (x >= -half) & (x <= half)
        # The profile is only ever asked about 1-D arrays: flatten, then restore the shape.
        h = np.asarray(self.profile(np.clip(x, -half, half).reshape(-1))).reshape(x.shape)
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
    @checked_arguments
    def from_function(
        cls,
        name: str,
        profile: HeightFn,
        *,
        width: float = BLOCK_SIZE,
        depth: float = BLOCK_SIZE,
        description: str = "",
    ) -> HapticObject:
        """An object from a vectorized height function ``h(x)`` (metres, local frame).

        ``profile`` takes a 1-D array of positions and returns their heights, an array of the same
        shape (``lambda x: np.full_like(x, 0.03)`` for a flat top, not ``lambda x: 0.03``). It is
        checked on :data:`PROFILE_SAMPLES` points across the block: finite, in
        ``[0, MAX_HEIGHT]``, not 0 everywhere.
        """
        check_name(name)
        if not callable(profile):
            raise HamError(f"object {name!r}: profile {profile!r} is not a function of x")
        width = _check_size(name, "width", width)
        _check_size(name, "depth", depth)
        xs = np.linspace(-0.5 * width, 0.5 * width, PROFILE_SAMPLES)
        try:
            out = profile(xs.copy())
        except Exception as exc:  # noqa: BLE001 - the user's function: any failure is bad input
            msg = " ".join(str(exc).split())
            raise HamError(
                f"object {name!r}: profile h(x) failed on an array x of shape {xs.shape}: "
                f"{type(exc).__name__}: {msg}"
            ) from None
        hs = _real_heights(name, "profile h(x)", out)
        if hs.shape != xs.shape:
            raise HamError(
                f"object {name!r}: profile h(x) returned shape {hs.shape} for x of shape "
                f"{xs.shape}; accepted: a vectorized function returning one height per x "
                "(e.g. np.full_like(x, 0.03), not 0.03)"
            )
        _check_heights(name, xs, hs)
        return cls(name, profile, width, depth, float(hs.max()), None, description)

    @classmethod
    @checked_arguments
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
        check_name(name)
        pts = _as_reals(points)
        if isinstance(pts, str) or pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
            got = pts if isinstance(pts, str) else f"shape {pts.shape}"
            raise HamError(f"object {name!r}: polyline must be N >= 2 points (x, z), got {got}")
        if not np.all(np.isfinite(pts[:, 0])):
            bad = pts[~np.isfinite(pts[:, 0]), 0][0]
            raise HamError(f"object {name!r}: polyline x = {bad}; accepted: finite numbers (m)")
        if np.any(np.diff(pts[:, 0]) < 0):
            i = int(np.argmax(np.diff(pts[:, 0]) < 0))
            raise HamError(
                f"object {name!r}: polyline x must be non-decreasing left to right, "
                f"got x = {pts[i, 0]:.6g} then {pts[i + 1, 0]:.6g}"
            )
        width = _check_size(name, "width (last x - first x)", float(pts[-1, 0] - pts[0, 0]))
        _check_size(name, "depth", depth)
        _check_heights(name, pts[:, 0], pts[:, 1])
        centre = 0.5 * (pts[0, 0] + pts[-1, 0])
        pts = pts - np.array([centre, 0.0])
        return cls(
            name, _polyline_profile(pts), width, depth, float(pts[:, 1].max()), pts, description
        )

    @classmethod
    @checked_arguments
    def from_surface(
        cls,
        name: str,
        surface: SurfaceFn,
        *,
        width: float = BLOCK_SIZE,
        depth: float = BLOCK_SIZE,
        description: str = "",
    ) -> HapticObject:
        """An object whose top is the vectorized height field ``h(x, y)`` (metres, local frame).

        ``surface`` takes two arrays of one shape and returns their heights, an array of that
        shape. It is checked on :data:`SURFACE_SAMPLES` x :data:`SURFACE_SAMPLES` points across
        the base: finite, in ``[0, MAX_HEIGHT]``, not 0 everywhere.
        """
        check_name(name)
        if not callable(surface):
            raise HamError(f"object {name!r}: surface {surface!r} is not a function of (x, y)")
        width = _check_size(name, "width", width)
        depth = _check_size(name, "depth", depth)
        xs = np.linspace(-0.5 * width, 0.5 * width, SURFACE_SAMPLES)
        ys = np.linspace(-0.5 * depth, 0.5 * depth, SURFACE_SAMPLES)
        gx, gy = (g.reshape(-1) for g in np.meshgrid(xs, ys))
        try:
            out = surface(gx.copy(), gy.copy())
        except Exception as exc:  # noqa: BLE001 - the user's function: any failure is bad input
            raise HamError(
                f"object {name!r}: surface h(x, y) failed on arrays of shape {gx.shape}: "
                f"{type(exc).__name__}: {recorded_file.one_line(exc)}"
            ) from None
        hs = _real_heights(name, "surface h(x, y)", out)
        if hs.shape != gx.shape:
            raise HamError(
                f"object {name!r}: surface h(x, y) returned shape {hs.shape} for x, y of shape "
                f"{gx.shape}; accepted: a vectorized function returning one height per (x, y)"
            )
        _check_heights(name, gx, hs, gy)

        def section(x: np.ndarray) -> np.ndarray:
            return surface(x, np.zeros_like(x))

        return cls(name, section, width, depth, float(hs.max()), None, description, surface)

    @classmethod
    @checked_arguments
    def from_height_field(
        cls,
        name: str,
        heights: Sequence[Sequence[float]] | np.ndarray,
        *,
        width: float = BLOCK_SIZE,
        depth: float = BLOCK_SIZE,
        description: str = "",
    ) -> HapticObject:
        """An object from heights (m) on an even ``(ny, nx)`` grid spanning the base (row ``j``
        at ``y = -depth/2 + j * depth / (ny - 1)``), bilinear between samples."""
        check_name(name)
        hs = _as_reals(heights)
        if isinstance(hs, str) or hs.ndim != 2 or min(hs.shape) < 2:
            got = hs if isinstance(hs, str) else f"shape {hs.shape}"
            raise HamError(
                f"object {name!r}: height field must be a 2-D array (ny, nx) of heights (m) "
                f"with ny, nx >= 2, got {got}"
            )
        width = _check_size(name, "width", width)
        depth = _check_size(name, "depth", depth)
        ny, nx = hs.shape
        xs = np.linspace(-0.5 * width, 0.5 * width, nx)
        ys = np.linspace(-0.5 * depth, 0.5 * depth, ny)
        gx, gy = np.meshgrid(xs, ys)
        _check_heights(name, gx.reshape(-1), hs.reshape(-1), gy.reshape(-1))
        table = hs.copy()

        def surface(x: np.ndarray, y: np.ndarray) -> np.ndarray:
            tx = np.clip((np.asarray(x) + 0.5 * width) / width * (nx - 1), 0, nx - 1)
            ty = np.clip((np.asarray(y) + 0.5 * depth) / depth * (ny - 1), 0, ny - 1)
            i = np.minimum(tx.astype(np.int64), nx - 2)
            j = np.minimum(ty.astype(np.int64), ny - 2)
            wx, wy = tx - i, ty - j
            top = table[j, i] * (1 - wx) + table[j, i + 1] * wx
            bottom = table[j + 1, i] * (1 - wx) + table[j + 1, i + 1] * wx
            return top * (1 - wy) + bottom * wy

        return cls.from_surface(name, surface, width=width, depth=depth, description=description)

    @classmethod
    @checked_arguments
    def from_image(
        cls,
        name: str,
        image: str | Path | np.ndarray,
        *,
        width: float = BLOCK_SIZE,
        depth: float = BLOCK_SIZE,
        height: float = BLOCK_HEIGHT,
        description: str = "",
    ) -> HapticObject:
        """An object from a grey-scale image: grey level ``g`` in ``[0, 1]`` becomes the height
        ``g * height`` (black = the table, white = ``height``), bilinear between pixels.

        ``image`` is a PNG file or an array ``(rows, cols)`` of grey levels in ``[0, 1]`` (an
        RGB/RGBA array or PNG is accepted when its colour channels are equal and it is opaque).
        The picture spans the base as seen from above: its columns run along +x (``width``), its
        top row lies at ``y = +depth/2`` and its bottom row at ``y = -depth/2``.
        """
        check_name(name)
        what = "image"
        if isinstance(image, (str, Path)):
            what = f"image {str(image)!r}"
            grey = _read_png(name, Path(image))
        else:
            grey = _as_reals(image, bools=True)  # a bool mask is an image of 0 and 1
            if isinstance(grey, str):
                raise HamError(
                    f"object {name!r}: image of {grey}; accepted: a PNG file "
                    "or an array (rows, cols) of grey levels in [0, 1]"
                )
        grey = _grey_levels(name, what, grey)
        h = height
        number = isinstance(h, (int, float, np.integer, np.floating)) and not isinstance(h, bool)
        if not (number and math.isfinite(h) and 0 < h <= MAX_HEIGHT):
            raise HamError(
                f"object {name!r}: image height = {h!r}; accepted: a number in "
                f"(0, {MAX_HEIGHT}] (m), the height of white"
            )
        # Row 0 of a picture is its top: the far side of the base, +y.
        return cls.from_height_field(
            name, grey[::-1] * float(h), width=width, depth=depth, description=description
        )

    @classmethod
    @checked_arguments
    def from_mesh(
        cls,
        name: str,
        mesh: str | Path | object,
        *,
        scale: float = 1.0,
        pitch: float = 0.0005,
        description: str = "",
    ) -> HapticObject:
        """An object whose top is the top of a triangle mesh (an STL/OBJ/PLY file or a
        ``trimesh.Trimesh``), seen from above.

        The mesh is scaled by ``scale`` (mesh units to metres: 0.001 for a file in mm), its
        lowest point set on the table and its x-y bounding box centred on the base, which it spans
        (``width`` x ``depth``). The top ``h(x, y)`` is the highest point of any triangle above
        ``(x, y)``, sampled every ``pitch`` metres (:func:`mesh_top`), bilinear between samples;
        a point of the base under no triangle is the table (0).
        """
        check_name(name)
        for what, value, top in (("scale", scale, math.inf), ("pitch", pitch, 0.01)):
            ok = isinstance(value, (int, float, np.integer, np.floating))
            if not ok or isinstance(value, bool) or not (math.isfinite(value) and 0 < value <= top):
                raise HamError(
                    f"object {name!r}: mesh {what} = {value!r}; accepted: a finite number > 0"
                    + (f" and <= {top} (m)" if math.isfinite(top) else "")
                )
        tris = _mesh_triangles(name, mesh) * float(scale)
        lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
        width = _check_size(name, "mesh width (x extent * scale)", float(hi[0] - lo[0]))
        depth = _check_size(name, "mesh depth (y extent * scale)", float(hi[1] - lo[1]))
        tris = tris - np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2]])
        nx = max(2, math.ceil(width / pitch) + 1)
        ny = max(2, math.ceil(depth / pitch) + 1)
        if nx * ny > MAX_FIELD_SAMPLES:
            raise HamError(
                f"object {name!r}: mesh pitch = {pitch!r} m gives {ny} x {nx} samples over "
                f"{width:.4g} x {depth:.4g} m; accepted: at most {MAX_FIELD_SAMPLES} samples "
                "(a larger pitch)"
            )
        xs = np.linspace(-0.5 * width, 0.5 * width, nx)
        ys = np.linspace(-0.5 * depth, 0.5 * depth, ny)
        top = mesh_top(tris, xs, ys)
        return cls.from_height_field(name, top, width=width, depth=depth, description=description)

    @classmethod
    @checked_arguments
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
        check_name(name)
        hs = _as_reals(heights)
        if isinstance(hs, str) or hs.ndim != 1 or len(hs) < 2:
            got = hs if isinstance(hs, str) else f"shape {hs.shape}"
            raise HamError(
                f"object {name!r}: heightmap must be a 1-D list of >= 2 heights (m), got {got}"
            )
        width = _check_size(name, "width", width)
        xs = np.linspace(-0.5 * width, 0.5 * width, len(hs))
        return cls.from_polyline(name, np.stack([xs, hs], 1), depth=depth, description=description)


#: Most pixels (rows x cols) of an image object, and most samples of a mesh's top: beyond that the
#: bilinear surface only costs memory (a 1025 x 1025 field is 8 MB).
MAX_FIELD_SAMPLES = 1025 * 1025


def _read_png(name: str, path: Path) -> np.ndarray:
    """The pixels of the PNG ``path`` as floats in [0, 1] (matplotlib's reader)."""
    import matplotlib.image as mpimg

    if path.suffix.lower() != ".png":
        raise HamError(f"object {name!r}: image {str(path)!r}; accepted: a .png file")
    if not path.is_file():
        raise HamError(f"object {name!r}: image {str(path)!r} does not exist")
    try:
        pixels = mpimg.imread(path, format="png")
    except Exception as exc:  # noqa: BLE001 - any failure of the reader is a bad file
        raise HamError(
            f"object {name!r}: cannot read image {str(path)!r} as a PNG: {recorded_file.one_line(exc)}"
        ) from None
    # matplotlib reads every PNG (8- or 16-bit, grey or colour) as floats in [0, 1]
    return np.asarray(pixels, dtype=np.float64)


def _grey_levels(name: str, what: str, pixels: np.ndarray) -> np.ndarray:
    """``(rows, cols)`` grey levels in [0, 1] from a grey, or grey-valued opaque RGB(A), array."""
    rule = "accepted: grey levels in [0, 1], an array (rows, cols) or a grey RGB(A) image"
    if pixels.ndim == 3 and pixels.shape[2] in (3, 4):
        if pixels.shape[2] == 4:
            alpha = pixels[..., 3]
            if np.any(alpha != alpha.flat[0]) or alpha.flat[0] not in (1.0, 255.0):
                raise HamError(f"object {name!r}: {what} has transparent pixels; {rule}, opaque")
            pixels = pixels[..., :3]
        rgb = pixels
        if np.any(rgb[..., 0] != rgb[..., 1]) or np.any(rgb[..., 0] != rgb[..., 2]):
            i = np.unravel_index(int(np.argmax(np.any(rgb != rgb[..., :1], axis=2))), rgb.shape[:2])
            raise HamError(
                f"object {name!r}: {what} has colour at row {i[0]}, column {i[1]} "
                f"(RGB {tuple(float(v) for v in rgb[i])}); {rule}, not colour"
            )
        pixels = rgb[..., 0]
    if pixels.ndim != 2 or min(pixels.shape) < 2:
        raise HamError(f"object {name!r}: {what} of shape {pixels.shape}; {rule}, >= 2 x 2 pixels")
    if pixels.size > MAX_FIELD_SAMPLES:
        raise HamError(
            f"object {name!r}: {what} has {pixels.shape[0]} x {pixels.shape[1]} pixels; "
            f"accepted: at most {MAX_FIELD_SAMPLES} pixels (e.g. 1025 x 1025)"
        )
    bad = ~np.isfinite(pixels) | (pixels < 0) | (pixels > 1)
    if np.any(bad):
        i = np.unravel_index(int(np.argmax(bad)), pixels.shape)
        raise HamError(
            f"object {name!r}: {what} grey level {float(pixels[i]):.6g} at row {i[0]}, "
            f"column {i[1]}; {rule}"
        )
    return pixels


def _mesh_triangles(name: str, mesh: object) -> np.ndarray:
    """The triangles ``(T, 3, 3)`` of a mesh file (through trimesh) or of a ``trimesh.Trimesh``."""
    import trimesh

    what = "mesh"
    if isinstance(mesh, (str, Path)):
        path = Path(mesh)
        what = f"mesh {str(path)!r}"
        if path.suffix.lower() not in MESH_SUFFIXES:
            raise HamError(f"object {name!r}: {what}; accepted: a {'/'.join(MESH_SUFFIXES)} file")
        if not path.is_file():
            raise HamError(f"object {name!r}: {what} does not exist")
        try:
            mesh = trimesh.load(path, force="mesh")
        except Exception as exc:  # noqa: BLE001 - any failure of the reader is a bad file
            raise HamError(
                f"object {name!r}: cannot read {what}: {recorded_file.one_line(exc)}"
            ) from None
    if not isinstance(mesh, trimesh.Trimesh):
        raise HamError(
            f"object {name!r}: mesh of type {type(mesh).__name__}; accepted: an "
            f"{'/'.join(MESH_SUFFIXES)} file or a trimesh.Trimesh"
        )
    tris = np.asarray(mesh.triangles, dtype=np.float64).reshape(-1, 3, 3)
    if len(tris) == 0:
        raise HamError(f"object {name!r}: {what} has no triangles; accepted: a triangle mesh")
    if not np.all(np.isfinite(tris)):
        raise HamError(f"object {name!r}: {what} has non-finite vertices; accepted: finite ones")
    return tris


#: Mesh files :meth:`HapticObject.from_mesh` reads (through trimesh).
MESH_SUFFIXES = (".stl", ".obj", ".ply")


def mesh_top(triangles: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """The highest point of ``triangles`` (T, 3, 3) above each grid point: array (ny, nx), 0
    where no triangle lies above.

    A vectorized rasterization (no ray-casting library): each non-vertical triangle is the plane
    ``z = a x + b y + c`` over its projection; every grid point in its bounding box is tested with
    the three edge functions (1e-9 m tolerance, so points on shared edges and on the base's
    border are covered) and the grid keeps the highest z. Work is the summed bounding-box areas,
    done in chunks of at most 4M (point, triangle) pairs.
    """
    xs = np.asarray(xs, dtype=np.float64)
    ys = np.asarray(ys, dtype=np.float64)
    nx, ny = len(xs), len(ys)
    top = np.zeros(ny * nx)
    p0, p1, p2 = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    # signed doubled area of the projection; vertical triangles (area 0) hold no top point.
    area = (p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (p2[:, 0] - p0[:, 0]) * (
        p1[:, 1] - p0[:, 1]
    )
    keep = np.abs(area) > 1e-18
    p0, p1, p2, area = p0[keep], p1[keep], p2[keep], area[keep]
    tol = 1e-9
    lo = np.minimum(np.minimum(p0, p1), p2)
    hi = np.maximum(np.maximum(p0, p1), p2)
    i0 = np.searchsorted(xs, lo[:, 0] - tol, side="left")
    i1 = np.searchsorted(xs, hi[:, 0] + tol, side="right")
    j0 = np.searchsorted(ys, lo[:, 1] - tol, side="left")
    j1 = np.searchsorted(ys, hi[:, 1] + tol, side="right")
    wi = np.maximum(i1 - i0, 0)
    counts = wi * np.maximum(j1 - j0, 0)
    chunk = 4_000_000
    start = 0
    cum = np.cumsum(counts)
    while start < len(counts):
        base = cum[start - 1] if start else 0
        stop = max(start + 1, int(np.searchsorted(cum, base + chunk, side="right")))
        t = np.repeat(np.arange(start, stop), counts[start:stop])
        if len(t):
            k = np.arange(len(t)) - np.repeat(
                cum[start:stop] - counts[start:stop] - base, counts[start:stop]
            )
            ii = i0[t] + k % wi[t]
            jj = j0[t] + k // wi[t]
            px, py = xs[ii], ys[jj]
            a, b, c, s = p0[t], p1[t], p2[t], np.sign(area[t])
            # barycentric weights (scaled by the signed area, made positive inside)
            w0 = s * ((b[:, 0] - px) * (c[:, 1] - py) - (c[:, 0] - px) * (b[:, 1] - py))
            w1 = s * ((c[:, 0] - px) * (a[:, 1] - py) - (a[:, 0] - px) * (c[:, 1] - py))
            w2 = s * ((a[:, 0] - px) * (b[:, 1] - py) - (b[:, 0] - px) * (a[:, 1] - py))
            # edge tolerance in area units: tol times the edge length
            e = tol * np.abs(area[t]) ** 0.5 + 1e-30
            inside = (w0 >= -e) & (w1 >= -e) & (w2 >= -e)
            z = (w0 * a[:, 2] + w1 * b[:, 2] + w2 * c[:, 2]) / np.abs(area[t])
            np.maximum.at(top, (jj * nx + ii)[inside], z[inside])
        start = stop
    return top.reshape(ny, nx)


def _as_reals(values: object, bools: bool = False) -> np.ndarray | str:
    """``values`` (nested lists, an array, a tensor) as float64 when they are real numbers, else
    what they are instead, for the error: text (NumPy would parse ``"0.01"``), complex numbers
    (they would lose their imaginary part with only a warning), bools (unless ``bools``: a mask is
    an image of 0 and 1), or no array at all (ragged lists, a tensor that requires grad)."""
    try:
        a = np.asarray(values)
    except Exception as exc:  # noqa: BLE001 - the user's value: any failure is bad input
        if "inhomogeneous" in str(exc):
            return f"a ragged {type(values).__name__} (rows of different lengths)"
        return f"{type(values).__name__} that is no array: {recorded_file.one_line(exc)}"
    if a.dtype.kind not in "iuf" + ("b" if bools else ""):
        kinds = {"c": "complex values", "U": "text values", "S": "text values", "b": "bool values"}
        return kinds.get(a.dtype.kind, f"a {type(values).__name__}")
    return a.astype(np.float64)


def _real_heights(name: str, what: str, out: object) -> np.ndarray:
    """The heights a user's function returned, as float64, or a HamError naming what came back."""
    hs = _as_reals(out)
    if isinstance(hs, str):
        raise HamError(f"object {name!r}: {what} returned {hs}; accepted: real heights (m)")
    return hs


def _check_heights(name: str, xs: np.ndarray, hs: np.ndarray, ys: np.ndarray | None = None) -> None:
    """Heights inside the block: finite, ``0 <= h <= MAX_HEIGHT``, and not all 0 (no block)."""
    rule = f"accepted: finite heights in [0, {MAX_HEIGHT}] m"
    for bad, what in (
        (~np.isfinite(hs), "is not finite"),
        (hs < 0, "is below the table (z = 0)"),
        (hs > MAX_HEIGHT, f"is above the block height limit {MAX_HEIGHT} m"),
    ):
        if np.any(bad):
            i = int(np.argmax(bad))
            at = f"x = {xs[i]:.6g}" + ("" if ys is None else f", y = {ys[i]:.6g}")
            raise HamError(f"object {name!r}: height {hs[i]:.6g} at {at} m {what}; {rule}")
    if not np.any(hs > 0):
        raise HamError(f"object {name!r}: every height is 0 (no block); {rule}, not all 0")


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


# --------------------------------------------------------------------------- curvature2d
# The paper's next world: tops that curve in x and y. Every object stands on a 9 x 9 cm base
# (wider than the 8 cm pad) and on a plinth of at least 2 cm, so that a glance feels the top.
_P = 0.02  # plinth (m)


def _arc(t: np.ndarray, radius: float) -> np.ndarray:
    """A circular arc of ``radius`` over ``t``, 0 at ``|t| = a`` (the base's edge)."""
    return np.sqrt(np.clip(radius**2 - t**2, 0.0, None)) - math.sqrt(radius**2 - _A**2)


#: The bowl: a spherical cap of this radius (m) and depth (m) sunk into a flat top at this height.
#: A deep bowl (once a sphere of R = 7 cm over the whole base) holds the flat 8 cm pad on its rim:
#: every glance was a corner of the pad on a steep wall, stopped by the foam bottoming out or the
#: housing, where MuJoCo's and the fast model's rims differ (docs/crosscheck_curvature2d.md). In
#: this one the pad rests on the flat ring around the bowl or inside it on a gentle slope.
BOWL_RADIUS, BOWL_DEPTH, BOWL_TOP = 0.035, 0.006, 0.035


def _bowl(x, y):
    sphere = (BOWL_RADIUS**2 + BOWL_DEPTH**2) / (2 * BOWL_DEPTH)  # the cap's sphere radius
    r2 = x**2 + y**2
    cap = BOWL_TOP - BOWL_DEPTH + sphere - np.sqrt(np.clip(sphere**2 - r2, 0.0, None))
    return np.where(r2 < BOWL_RADIUS**2, cap, BOWL_TOP)


def _curvature2d() -> list[tuple[str, Callable[[], HapticObject]]]:
    r_cyl, r_dome, k_saddle, slope = 0.06, 0.07, 0.015 / _A**2, 0.5
    corner = math.sqrt(r_dome**2 - 2 * _A**2)  # the dome's sphere at the base's corners

    def flat(h: float):
        return lambda x, y: np.full_like(x, h)

    spec = [
        ("flat_low", flat(0.03), "flat top at 3 cm (differs from flat_high only in height)"),
        ("flat_high", flat(0.05), "flat top at 5 cm (differs from flat_low only in height)"),
        (
            "cylinder_x",
            lambda x, y: _P + _arc(y, r_cyl) + 0 * x,
            "half cylinder, axis along x (R = 6 cm): curved in y, straight in x",
        ),
        (
            "cylinder_y",
            lambda x, y: _P + _arc(x, r_cyl) + 0 * y,
            "half cylinder, axis along y (R = 6 cm): curved in x, straight in y",
        ),
        (
            "dome",
            lambda x, y: _P + np.sqrt(np.clip(r_dome**2 - x**2 - y**2, 0, None)) - corner,
            "spherical dome (R = 7 cm), convex in x and y",
        ),
        (
            "saddle",
            lambda x, y: 0.04 + k_saddle * (x**2 - y**2),
            "saddle: rises along x, falls along y (1.5 cm at the edges' midpoints)",
        ),
        (
            "bowl",
            _bowl,
            "shallow spherical bowl (7 cm across, 6 mm deep) sunk into a flat top at 3.5 cm",
        ),
        (
            "pyramid",
            lambda x, y: _P + slope * (_A - np.maximum(np.abs(x), np.abs(y))),
            "square pyramid (26.6 deg faces): four ridges meeting at an apex",
        ),
        (
            "cone",
            lambda x, y: _P + slope * np.clip(_A - np.hypot(x, y), 0, None),
            "round cone (26.6 deg) on the plinth: a point, no ridges",
        ),
    ]
    return [
        (n, functools.partial(HapticObject.from_surface, n, f, description=d)) for n, f, d in spec
    ]


# --------------------------------------------------------------------------- composite
#: Edge of a composite object's square base (m): four 8 x 8 cm slots, each the pad's size.
COMPOSITE_SIZE = 0.16
#: Local features of a composite object, one per slot: letter -> what it is.
COMPOSITE_FEATURES = {
    "E": "edge (a ridge along y)",
    "F": "flat",
    "V": "convex bump",
    "C": "concave dimple",
}
#: The four slots (letters of a code, in order) and their centres (m).
COMPOSITE_SLOTS = {
    "NW": (-0.04, 0.04),
    "NE": (0.04, 0.04),
    "SW": (-0.04, -0.04),
    "SE": (0.04, -0.04),
}


def composite_codes() -> list[str]:
    """The 12 arrangements: the even permutations of ``EFVC`` over the slots NW, NE, SW, SE.

    Every object carries each feature once, so one glance at a slot tells only that slot's feature
    (3 arrangements remain); two slots determine the arrangement (the odd completion is not in
    the set). Listed in lexicographic order of the permutations.
    """
    codes = []
    for perm in itertools.permutations(range(4)):
        inversions = sum(perm[i] > perm[j] for i in range(4) for j in range(i + 1, 4))
        if inversions % 2 == 0:
            codes.append("".join("EFVC"[k] for k in perm))
    return codes


@dataclass(frozen=True)
class _FeatureSizes:
    """One instance's geometry (m): the plinth, the features' sizes and their shift in a slot."""

    plinth: float
    ridge_height: float
    ridge_half_width: float
    ridge_half_length: float
    bump_height: float
    bump_radius: float
    dimple_depth: float
    dimple_radius: float
    shift: tuple[float, float]


#: Instance 1 (``composite:train``) and instance 2 (``composite:test``): same arrangements,
#: other plinth, feature sizes and positions within the slots.
_INSTANCES = {
    1: _FeatureSizes(0.020, 0.015, 0.015, 0.030, 0.015, 0.028, 0.012, 0.028, (0.0, 0.0)),
    2: _FeatureSizes(0.025, 0.012, 0.012, 0.026, 0.011, 0.024, 0.010, 0.025, (0.004, -0.003)),
}


_FEATURE_WORDS = {"E": "edge", "F": "flat", "V": "bump", "C": "dimple"}


def _composite_surface(code: str, s: _FeatureSizes) -> SurfaceFn:
    features = list(zip(code, COMPOSITE_SLOTS.values(), strict=True))

    def surface(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        h = np.full(np.shape(x), s.plinth)
        for letter, (cx, cy) in features:
            u, v = x - cx - s.shift[0], y - cy - s.shift[1]
            if letter == "E":
                ridge = s.ridge_height * np.clip(1 - np.abs(u) / s.ridge_half_width, 0, None)
                h = h + np.where(np.abs(v) <= s.ridge_half_length, ridge, 0.0)
            elif letter == "V":
                h = h + s.bump_height * np.clip(1 - (u**2 + v**2) / s.bump_radius**2, 0, None)
            elif letter == "C":
                h = h - s.dimple_depth * np.clip(1 - (u**2 + v**2) / s.dimple_radius**2, 0, None)
        return h

    return surface


def composite_name(code: str, instance: int) -> str:
    """``comp_<code>_<instance>``, e.g. ``comp_EFVC_1``."""
    return f"comp_{code}_{instance}"


def _composite() -> list[tuple[str, Callable[[], HapticObject]]]:
    out = []
    for instance, sizes in _INSTANCES.items():
        for code in composite_codes():
            where = ", ".join(
                f"{slot} {_FEATURE_WORDS[code[i]]}" for i, slot in enumerate(COMPOSITE_SLOTS)
            )
            split = "train" if instance == 1 else "test"
            name = composite_name(code, instance)
            make = functools.partial(
                HapticObject.from_surface,
                name,
                _composite_surface(code, sizes),
                width=COMPOSITE_SIZE,
                depth=COMPOSITE_SIZE,
                description=f"instance {instance} ({split}): {where}",
            )
            out.append((name, make))
    return out


# --------------------------------------------------------------------------- registry
_REGISTRY: dict[str, HapticObject] = {}
_ORDER: list[str] = []
#: Where each registered object came from, for error messages: "built-in", an objects file, ...
_ORIGIN: dict[str, str] = {}
#: Objects files loaded in this process: sha256 -> the names they registered (loading is idempotent).
_FILES: dict[str, tuple[str, ...]] = {}
#: Built-in objects registered by name and built on first use (:func:`get`): name -> constructor.
_LAZY: dict[str, Callable[[], HapticObject]] = {}
#: While an objects file runs: (its name, its sha256, the names it registered so far).
_LOADING: tuple[str, str, list[str]] | None = None

#: Named object sets; ``paper`` is the paper's four objects in the paper's order.
OBJECT_SETS: dict[str, tuple[str, ...]] = {
    "paper": ("box", "ramp_up", "convex", "ramp_down"),
    "mhsb": ("ridge", "trough", "step", "double_ridge"),
}
#: Named splits of a set (``SET:SPLIT`` in :func:`resolve_set`): lists of one length whose
#: i-th objects are instances of one class (label i), so a classifier trained on one split
#: is scored on the other.
SET_SPLITS: dict[str, dict[str, tuple[str, ...]]] = {}


@checked_arguments
def register(obj: HapticObject, *, replace: bool = False) -> int:
    """Add ``obj`` to the registry and return its id (ids are stable: registration order).

    An objects file may only add new names (``replace`` is refused there): a table or run that
    records the file must mean the same objects wherever it is loaded.
    """
    known = obj.name in _REGISTRY or obj.name in _LAZY
    if known and (not replace or _LOADING is not None):
        raise HamError(
            f"object name {obj.name!r} is already registered "
            f"({_ORIGIN.get(obj.name, 'by the program')}); choose another name"
            + (
                f"; this file (sha256 {_LOADING[1][:12]}) may only add new names"
                if _LOADING
                else " or pass replace=True"
            )
        )
    if _LOADING is not None:
        _LOADING[2].append(obj.name)
        _ORIGIN[obj.name] = f"objects file {_LOADING[0]!r}"
    else:
        _ORIGIN[obj.name] = "by the program"
    if not known:
        _ORDER.append(obj.name)
    _LAZY.pop(obj.name, None)
    _REGISTRY[obj.name] = obj
    return _ORDER.index(obj.name)


def unregister_since(before: set[str]) -> None:
    """Remove every object registered after :func:`names` was ``before`` (a failed plugin's)."""
    _unregister([n for n in _ORDER if n not in before])


def _unregister(added: list[str]) -> None:
    """Leave the registry as it was before ``added`` (the last ids) were registered."""
    for n in added:
        _REGISTRY.pop(n, None)
        _ORIGIN.pop(n, None)
        _ORDER.remove(n)
    for sha in [s for s, got in _FILES.items() if set(got) & set(added)]:
        del _FILES[sha]


def origin(name: str) -> str:
    """Where the registered object ``name`` came from: ``built-in``, an objects file, ..."""
    get(name)
    return _ORIGIN.get(name, "by the program")


def names() -> list[str]:
    """All registered object names, in id order."""
    return list(_ORDER)


def object_id(name: str) -> int:
    """The stable registry id of ``name``."""
    if name not in _REGISTRY and name not in _LAZY:
        raise HamError(f"unknown object {name!r}; known: {', '.join(_ORDER)}")
    return _ORDER.index(name)


def get(key: str | int) -> HapticObject:
    """An object by registry name or id (a string of digits counts as an id)."""
    if isinstance(key, str) and key.strip().lstrip("-").isdigit():
        key = int(key)
    if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
        if not 0 <= key < len(_ORDER):
            raise HamError(f"unknown object id {key}; accepted: 0..{len(_ORDER) - 1}")
        key = _ORDER[key]
    if isinstance(key, str) and key in _LAZY:
        _REGISTRY[key] = _LAZY.pop(key)()
    if isinstance(key, str) and key in _REGISTRY:
        return _REGISTRY[key]
    raise HamError(
        f"unknown object {key!r}; known: {', '.join(_ORDER)} (or an id 0..{len(_ORDER) - 1})"
    )


def set_names() -> list[str]:
    """What :func:`resolve_set` accepts by name: the sets, their ``SET:SPLIT`` splits, ``all``."""
    splits = [f"{s}:{p}" for s, parts in SET_SPLITS.items() for p in parts]
    return [*OBJECT_SETS, *splits, "all"]


def set_membership() -> dict[str, list[str]]:
    """name -> the named sets and splits that hold it (``all`` left out)."""
    out: dict[str, list[str]] = {}
    for set_name in set_names()[:-1]:
        for n in _set_members(set_name):
            out.setdefault(n, []).append(set_name)
    return out


def _set_members(set_name: str) -> tuple[str, ...]:
    if set_name in OBJECT_SETS:
        return OBJECT_SETS[set_name]
    base, _, split = set_name.partition(":")
    return SET_SPLITS[base][split]


def splits_of(spec: object) -> dict[str, tuple[str, ...]]:
    """The splits ``SET:SPLIT`` -> names of the set ``spec`` names (``composite`` or one of its
    splits); empty for other sets and lists."""
    if not isinstance(spec, str):
        return {}
    base = spec.partition(":")[0]
    return {f"{base}:{k}": v for k, v in SET_SPLITS.get(base, {}).items()}


def resolve_set(spec: str | Sequence[str | int]) -> list[HapticObject]:
    """Objects of a named set (``paper``, ``mhsb``, ``curvature2d``, ``composite``, ``all``), a
    split ``SET:SPLIT`` (``composite:train``, ``composite:test``) or a comma list of names/ids."""
    if isinstance(spec, str):
        if spec == "all":
            return [get(n) for n in _ORDER]
        if spec in OBJECT_SETS:
            return [get(n) for n in OBJECT_SETS[spec]]
        if ":" in spec and "," not in spec:
            set_name, _, split = spec.partition(":")
            if split in SET_SPLITS.get(set_name, {}):
                return [get(n) for n in SET_SPLITS[set_name][split]]
            raise HamError(
                f"unknown object set split {spec!r}; accepted: "
                + ", ".join(f"{s}:{p}" for s, parts in SET_SPLITS.items() for p in parts)
            )
        parts = [p.strip() for p in spec.split(",") if p.strip()]
        if not parts:
            raise HamError(
                f"empty object set {spec!r}; accepted: {', '.join(set_names())}, or names"
            )
        if len(parts) == 1 and parts[0] not in _ORDER and not parts[0].lstrip("-").isdigit():
            # one unknown word: it may have been meant as a set, so name the sets too
            raise HamError(
                f"unknown object set or object {parts[0]!r}; accepted: a set "
                f"({', '.join(set_names())}) or object names/ids ({', '.join(_ORDER)})"
            )
        spec = parts
    objs = [get(k) for k in spec]
    seen = [o.name for o in objs]
    if len(set(seen)) != len(seen):
        raise HamError(f"object set lists an object twice: {seen}")
    return objs


# --------------------------------------------------------------------------- objects files
OBJECTS_FILE_SUFFIXES = (".py", ".json", ".toml")


def read_objects_file(path: str | Path) -> dict:
    """The record of an objects file: ``{"name", "sha256", "source"}`` (nothing is registered).

    The record is what a world keeps (:attr:`ham.world.config.WorldConfig.objects_file`): the
    file's text itself, so that any process can register the same objects with :func:`load_objects`.
    """
    return recorded_file.read_record(
        path, "objects file", OBJECTS_FILE_SUFFIXES,
        "a .py file that registers objects, or a .json/.toml list of polylines and heightmaps",
    )  # fmt: skip


def check_record(record: object) -> dict:
    """``record`` if it is a complete objects-file record whose text has its sha256, else an error."""
    return recorded_file.check_record(record, "objects file", "objects_file", OBJECTS_FILE_SUFFIXES)


def load_objects(record: dict) -> list[str]:
    """Register the objects of an objects-file record (verified); returns their names in id order.

    Idempotent per file content (sha256): a process that already loaded it registers nothing
    again. A file that fails, registers nothing, or takes a name already in use registers nothing.
    """
    global _LOADING
    record = check_record(record)
    name, sha = record["name"], record["sha256"]
    if sha in _FILES:
        return list(_FILES[sha])
    if _LOADING is not None:
        raise HamError(f"objects file {name!r}: objects files cannot load other objects files")
    added: list[str] = []
    _LOADING = (name, sha, added)
    try:
        if Path(name).suffix.lower() == ".py":
            _run_python(name, record["source"])
        else:
            _register_data(name, record["source"])
        if not added:
            raise HamError(
                f"objects file {name!r} registers no objects; accepted: a file that calls "
                "ham.world.objects.register(HapticObject.from_function/from_polyline/"
                "from_heightmap(...))"
            )
    except BaseException:
        _unregister(added)
        raise
    finally:
        _LOADING = None
    for n in added:
        _ORIGIN[n] = f"objects file {name!r} (sha256 {sha[:12]})"
    _FILES[sha] = tuple(added)
    return list(added)


def load_objects_file(path: str | Path) -> dict:
    """Read the objects file ``path``, register its objects, and return its record."""
    record = read_objects_file(path)
    load_objects(record)
    return record


def _run_python(name: str, source: str) -> None:
    recorded_file.run_python("objects file", name, source, "ham_objects_file")


def _register_data(name: str, source: str) -> None:
    """JSON/TOML: ``objects = [{name, polyline | heightmap | height_field, width?, depth?,
    description?}, ...]``; a path to an image or mesh is refused (only this text is recorded)."""
    try:
        data = json.loads(source) if name.lower().endswith(".json") else tomllib.loads(source)
    except (ValueError, tomllib.TOMLDecodeError) as exc:
        raise HamError(
            f"objects file {name!r} is not valid: {recorded_file.one_line(exc)}"
        ) from None
    entries = data.get("objects") if isinstance(data, dict) else None
    shapes = ("polyline", "heightmap", "height_field")
    if not isinstance(entries, list):
        raise HamError(
            f"objects file {name!r}: accepted: a top-level list 'objects' of tables "
            "{name, polyline | heightmap | height_field, width, depth, description}"
        )
    allowed = {"name", *shapes, "width", "depth", "description"}
    for i, e in enumerate(entries):
        if not isinstance(e, dict) or "name" not in e:
            raise HamError(f"objects file {name!r}: objects[{i}] needs a name")
        for key in ("image", "mesh"):
            if key in e:
                raise HamError(
                    f"objects file {name!r}: objects[{i}] ({e['name']!r}) names the {key} file "
                    f"{e[key]!r}; a world records only the objects file's text, so a path to "
                    "another file would not travel with a table or run; accepted: the heights "
                    "embedded as height_field (ham.world.objects.write_objects_file, or "
                    f"`ham objects --{key} FILE --name NAME --export OUT.json`)"
                )
        unknown = sorted(set(e) - allowed)
        shape = [k for k in shapes if k in e]
        if unknown or len(shape) != 1:
            raise HamError(
                f"objects file {name!r}: objects[{i}] ({e['name']!r}) has "
                + (f"unknown keys {unknown}" if unknown else f"shape keys {shape}")
                + f"; accepted: one of {', '.join(shapes)}, and "
                + f"{sorted(allowed - set(shapes))}"
            )
        kw = {k: e[k] for k in ("depth", "description") if k in e}
        try:
            if "polyline" in e:
                if "width" in e:
                    raise HamError(f"object {e['name']!r}: a polyline's width is its x span")
                obj = HapticObject.from_polyline(e["name"], e["polyline"], **kw)
            elif "heightmap" in e:
                obj = HapticObject.from_heightmap(
                    e["name"], e["heightmap"], width=e.get("width", BLOCK_SIZE), **kw
                )
            else:
                obj = HapticObject.from_height_field(
                    e["name"], e["height_field"], width=e.get("width", BLOCK_SIZE), **kw
                )
            register(obj)
        except HamError as exc:
            raise HamError(f"objects file {name!r}: {exc}") from None


def objects_file_entry(obj: HapticObject, samples: int = 129) -> dict:
    """An objects-file entry for ``obj``: its top as ``height_field``, ``samples`` points along
    the longer side of its base (spacing kept equal along the shorter), rounded to 0.1 um.

    This embeds any object (an image's, a mesh's, a function's) in a self-contained JSON/TOML
    objects file (:func:`write_objects_file`); between samples the file's object is bilinear.
    """
    if not isinstance(samples, int) or isinstance(samples, bool) or not 2 <= samples <= 1025:
        raise HamError(f"height field samples = {samples!r}; accepted: an integer 2..1025")
    longer = max(obj.width, obj.depth)
    nx = max(2, round((samples - 1) * obj.width / longer) + 1)
    ny = max(2, round((samples - 1) * obj.depth / longer) + 1)
    field = np.round(obj.height_field(nx, ny), 7)
    entry = {"name": obj.name, "height_field": field.tolist(), "width": obj.width}
    entry["depth"] = obj.depth
    if obj.description:
        entry["description"] = obj.description
    return entry


def write_objects_file(objs: Sequence[HapticObject], path: str | Path, samples: int = 129) -> Path:
    """Write ``objs`` as a self-contained JSON objects file of ``height_field`` entries
    (atomically); ``--objects-file PATH`` then registers them in any process."""
    from ham.world.files import check_output, write_text

    p = check_output(path, (".json",), what="objects file")
    if not objs:
        raise HamError("write_objects_file: no objects; accepted: one or more HapticObjects")
    entries = [objects_file_entry(o, samples) for o in objs]
    text = json.dumps({"objects": entries}, separators=(",", ":")) + "\n"
    return write_text(p, text, what="objects file")


for _obj in _builtin():
    register(_obj)
    _ORIGIN[_obj.name] = "built-in"
# The paper's next world, registered after the 8 line objects so that their ids stay.
# They are built (and checked) on first use: checking 33 surfaces on 513 x 513 points costs
# about 0.8 s, which every `ham` command would pay at import.
_c2d = _curvature2d()
_comp = _composite()
for _name, _make in _c2d + _comp:
    _LAZY[_name] = _make
    _ORDER.append(_name)
    _ORIGIN[_name] = "built-in"
OBJECT_SETS["curvature2d"] = tuple(n for n, _ in _c2d)
SET_SPLITS["composite"] = {
    "train": tuple(composite_name(c, 1) for c in composite_codes()),
    "test": tuple(composite_name(c, 2) for c in composite_codes()),
}
OBJECT_SETS["composite"] = SET_SPLITS["composite"]["train"]
del _c2d, _comp, _name, _make
