"""The Myrmex tactile sensor array: geometry, foam read-out, and the paper's normalization.

Geometry (section "The Tactile Sensor Array - Myrmex"): 16 x 16 taxels at 5 mm pitch cover an
8 x 8 cm (64 cm^2) sensitive face. Other pads come from :class:`SensorConfig` (``taxels`` N per
side, ``pitch``): an image is then ``N x N``, flattened to ``N^2`` values. The pad pose is its
face centre ``(x, z)`` and a rotation ``phi`` about the y axis (right-hand rule: positive ``phi``
lowers the pad's +u end).

Image orientation: ``pressure[..., i, j]`` has row ``i`` along the pad's y axis and column ``j``
along the pad's own x axis ``u`` (the world x axis when ``phi = 0``); column 0 is at
``u = -(N - 1) pitch / 2`` (-37.5 mm), column N - 1 at ``+(N - 1) pitch / 2``. Because every
object is extruded along y and at least as deep (9 cm) as the pad is wide (8 cm; checked by
:func:`ham.world.glance.check_pad`), all N rows of a raw image are equal.

Read-out: the sensitive face is covered by a compliant foam of thickness ``foam_thickness``.
Each point of the face is a spring (a Winkler foundation): its pressure is
``foam_stiffness * c`` where ``c`` is the local compression, the depth by which the object
pushes into the foam along the pad's direction of motion. A taxel reads the mean pressure over
its 5 mm cell, averaged over ``supersample`` points across the cell, so that a thin edge shows
as a line one or two taxels wide along the whole contact, as the real sensor shows it, not as
the two blobs of the paper's Gazebo plugin. Options reproduce that plugin's Gaussian spread
(sigma 5 mm) and the real sensor's 12-bit cells.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Literal

import numpy as np
import torch

from ham.errors import HamError, check_types

#: Most cells per side: a 128 x 128 image is 16,384 values per glance (64 KB), and a 201 x 201
#: table of one object 2.6 GB; beyond that tables and networks stop being practical.
MAX_TAXELS = 128
#: How a pad reads its contacts (MuJoCo): its taxels (edges are lines) or the paper's Gazebo
#: plugin (a few contact points spread by a 5 mm Gaussian: edges are blobs).
READOUTS: tuple[str, ...] = ("taxels", "gazebo")
#: Stiffer foam than this is rigid within float32's resolution of z (2 N on 64 cm^2 compresses it
#: 0.3 nm, below the ~4 nm spacing of float32 heights near 4.5 cm).
MAX_FOAM_STIFFNESS = 1e12
#: Most pressure a taxel may read (Pa): far beyond any material (diamond fails near 1e11 Pa), and
#: small enough that the L2 norm of a 128 x 128 image stays finite in float32 (beyond it the
#: normalized image would silently be all zeros).
MAX_PRESSURE = 1e15

Normalization = Literal["l2", "l1", "none"]
NORMALIZATIONS: tuple[str, ...] = ("l2", "l1", "none")


@dataclass(frozen=True)
class SensorConfig:
    """The Myrmex pad and its foam (paper defaults; the foam is our model, see module doc).

    Attributes:
        taxels: cells per side (16); an integer 2..``MAX_TAXELS``.
        pitch: cell pitch (m), 5 mm; finite and > 0. The pad's edge is ``taxels * pitch``.
        foam_stiffness: pressure per metre of compression (Pa/m). 4e7 Pa/m presses a flat face
            7.8 um deep at 2 N and lets a 27-degree ramp edge carry 2 N within about 0.8 mm;
            calibrated so that the MuJoCo backend sinks as deep on the flat box
            (``ham.world.mujoco_sim.calibrate_foam_stiffness``).
        foam_thickness: the foam's depth (m); when an object compresses it fully, it meets the
            rigid pad and the glance stops there.
        housing_thickness: the rigid pad body behind the foam (m); its sides stop a steeply
            tilted pad before the foam touches.
        supersample: read-out points across each cell along u.
        spread_sigma: if set (m), spread the image with a Gaussian of this sigma, like the
            paper's Gazebo plugin (0.005); ``None`` for the foam's own sharp image.
        quantize_bits: if set, quantize each cell to this many bits like the real sensor (12).
        full_scale: pressure (Pa) at the top quantization level.
    """

    taxels: int = 16
    pitch: float = 0.005
    foam_stiffness: float = 4.0e7
    foam_thickness: float = 0.003
    housing_thickness: float = 0.01
    supersample: int = 4
    spread_sigma: float | None = None
    quantize_bits: int | None = None
    full_scale: float = 20_000.0

    def __post_init__(self) -> None:
        check_types(self)
        if not (
            isinstance(self.taxels, (int, np.integer))
            and not isinstance(self.taxels, bool)
            and 2 <= self.taxels <= MAX_TAXELS
        ):
            raise HamError(
                f"taxels = {self.taxels!r}; accepted: an integer 2..{MAX_TAXELS} (cells per side)"
            )
        object.__setattr__(self, "taxels", int(self.taxels))  # NumPy ints: JSON-ready
        _positive("pitch", self.pitch)
        _positive("foam_stiffness", self.foam_stiffness)
        _at_most("foam_stiffness", self.foam_stiffness, MAX_FOAM_STIFFNESS, "Pa/m (rigid beyond)")
        _positive("foam_thickness", self.foam_thickness)
        # fully compressed foam presses with stiffness * thickness: the most a taxel reads
        if self.foam_stiffness * self.foam_thickness > MAX_PRESSURE:
            raise HamError(
                f"foam_stiffness * foam_thickness = {self.foam_stiffness:g} Pa/m * "
                f"{self.foam_thickness:g} m (the pressure of fully compressed foam); accepted: at "
                f"most {MAX_PRESSURE:g} Pa"
            )
        h = self.housing_thickness
        if (
            isinstance(h, bool)
            or not isinstance(h, (int, float))
            or not (math.isfinite(h) and h >= 0)
        ):
            raise HamError(f"housing_thickness = {self.housing_thickness} must be >= 0 (m)")
        _positive("supersample", self.supersample, integer=True)
        if self.spread_sigma is not None:
            _positive("spread_sigma", self.spread_sigma)
            # wider than the pad, the blur leaves a flat smear: no image left to read
            _at_most("spread_sigma", self.spread_sigma, self.size, "m (the pad's edge)")
        if self.quantize_bits is not None and not (
            isinstance(self.quantize_bits, int)
            and not isinstance(self.quantize_bits, bool)
            and 1 <= self.quantize_bits <= 32
        ):
            raise HamError(f"quantize_bits = {self.quantize_bits!r}; accepted: None or 1..32")
        _positive("full_scale", self.full_scale)

    @property
    def size(self) -> float:
        """Edge length of the sensitive face (m): 16 x 5 mm = 8 cm."""
        return self.taxels * self.pitch

    @property
    def pressure_dim(self) -> int:
        """Values in a flattened image: ``taxels^2`` (256)."""
        return int(self.taxels) ** 2

    @property
    def shape(self) -> tuple[int, int]:
        """Shape of one image: ``(taxels, taxels)``."""
        return (int(self.taxels), int(self.taxels))

    def describe(self) -> str:
        """``16 x 16 taxels at 5 mm (8 cm pad)``: for messages."""
        return (
            f"{self.taxels} x {self.taxels} taxels at {self.pitch * 1000:g} mm "
            f"({self.size * 100:g} cm pad)"
        )

    @property
    def taxel_area(self) -> float:
        """Area of one cell (m^2)."""
        return self.pitch * self.pitch

    def to_dict(self) -> dict:
        return asdict(self)


def _at_most(name: str, value: float, top: float, unit: str) -> None:
    if value > top:
        raise HamError(f"{name} = {value!r}; accepted: a positive number <= {top:g} {unit}")


def _positive(name: str, value: float, *, integer: bool = False) -> None:
    ok = isinstance(value, (int, float)) and math.isfinite(value) and value > 0
    if integer:
        ok = ok and float(value).is_integer()
    if not ok:
        kind = "a positive integer" if integer else "a positive number"
        raise HamError(f"{name} = {value!r}; accepted: {kind}")


class Myrmex:
    """The pad's geometry and read-out. One component, so another sensor model can stand in.

    The glance controller asks the sensor two things: where its sensitive face samples the
    world (:meth:`sample_u`) and what image a compression field makes (:meth:`image`).
    """

    def __init__(self, config: SensorConfig | None = None) -> None:
        self.config = config or SensorConfig()

    def taxel_u(self) -> np.ndarray:
        """Cell centres along the pad's u axis (m), column order."""
        c = self.config
        return (np.arange(c.taxels) + 0.5) * c.pitch - 0.5 * c.size

    def sample_u(self) -> np.ndarray:
        """Read-out points along u (m): ``supersample`` evenly inside each cell, column-major."""
        c = self.config
        k = np.arange(c.taxels * c.supersample)
        return (k + 0.5) * (c.pitch / c.supersample) - 0.5 * c.size

    def image(self, compression: torch.Tensor) -> torch.Tensor:
        """Pressure image (Pa), ``(B, N, N)``, from the compression ``(B, N * S)`` at sample_u."""
        c = self.config
        cols = compression.reshape(compression.shape[0], c.taxels, c.supersample).mean(-1)
        img = (c.foam_stiffness * cols).unsqueeze(1).expand(-1, c.taxels, -1).contiguous()
        return self.postprocess(img)

    def postprocess(self, pressure: torch.Tensor) -> torch.Tensor:
        """The optional Gaussian spread and quantization, applied to any raw image (B, N, N)."""
        c = self.config
        if c.spread_sigma is not None:
            pressure = gaussian_spread(pressure, c.spread_sigma / c.pitch)
        if c.quantize_bits is not None:
            pressure = quantize(pressure, c.quantize_bits, c.full_scale)
        return pressure


def gaussian_spread(pressure: torch.Tensor, sigma_taxels: float) -> torch.Tensor:
    """Spread each cell's pressure over its neighbours with a Gaussian (sigma in cells).

    Like the Gazebo plugin, what spreads past the pad's border is lost; the kernel is normalized
    so that an interior point keeps its total.
    """
    radius = max(1, int(math.ceil(3 * sigma_taxels)))
    xs = torch.arange(-radius, radius + 1, dtype=pressure.dtype, device=pressure.device)
    k = torch.exp(-0.5 * (xs / sigma_taxels) ** 2)
    k = k / k.sum()
    img = pressure.unsqueeze(1)  # (B, 1, H, W)
    img = torch.nn.functional.conv2d(img, k.view(1, 1, -1, 1), padding=(radius, 0))
    img = torch.nn.functional.conv2d(img, k.view(1, 1, 1, -1), padding=(0, radius))
    return img.squeeze(1)


def gaussian_spread_rows(
    pressure: torch.Tensor, sigma_taxels: torch.Tensor, max_sigma: float
) -> torch.Tensor:
    """:func:`gaussian_spread` with a sigma of its own for each image: ``pressure (B, N, N)``,
    ``sigma_taxels (B,)`` in cells, at most ``max_sigma`` (the kernels' reach; a sigma of 0
    leaves its image as it is)."""
    radius = max(1, int(math.ceil(3 * max_sigma)))
    xs = torch.arange(-radius, radius + 1, dtype=pressure.dtype, device=pressure.device)
    s = sigma_taxels.to(pressure.dtype).clamp_min(1e-6).unsqueeze(1)  # 1e-6: a delta kernel
    k = torch.exp(-0.5 * (xs / s) ** 2)
    k = k / k.sum(-1, keepdim=True)
    b = pressure.shape[0]
    img = pressure.unsqueeze(0)  # (1, B, H, W): each image a channel with its own kernel
    img = torch.nn.functional.conv2d(img, k.view(b, 1, -1, 1), padding=(radius, 0), groups=b)
    img = torch.nn.functional.conv2d(img, k.view(b, 1, 1, -1), padding=(0, radius), groups=b)
    return img.squeeze(0)


def quantize(pressure: torch.Tensor, bits: int, full_scale: float) -> torch.Tensor:
    """Quantize to ``2**bits`` levels over ``[0, full_scale]`` Pa; the top level saturates like the ADC."""
    top = 2**bits - 1
    levels = torch.clamp(torch.round(pressure * (top / full_scale)), 0, top)
    return levels * (full_scale / top)


def check_normalization(kind: object) -> str:
    """``kind``, one of :data:`NORMALIZATIONS`, or a :class:`HamError` naming it."""
    if kind not in NORMALIZATIONS:
        raise HamError(f"normalization {kind!r}; accepted: {', '.join(NORMALIZATIONS)}")
    return kind


def normalize(pressure: torch.Tensor | np.ndarray, kind: str = "l2") -> torch.Tensor | np.ndarray:
    """Flatten each image to N^2 values and scale it to unit norm (the paper: L2; authors' code: L1).

    An all-zero image (no contact) stays all zero: never NaN.
    Works on torch tensors and NumPy arrays of shape (..., N, N); returns (..., N^2) (256).
    """
    check_normalization(kind)
    if isinstance(pressure, np.ndarray):
        return normalize(torch.from_numpy(np.ascontiguousarray(pressure)), kind).numpy()
    flat = pressure.reshape(*pressure.shape[:-2], -1)
    if kind == "none":
        return flat
    norm = flat.norm(p=2 if kind == "l2" else 1, dim=-1, keepdim=True)
    # a norm of 0 (no contact, or pressures so small their squares underflow) divides by inf:
    # 0. The select runs on the norms, not the images (one pass over the images, not two)
    return flat / torch.where(norm > 0, norm, torch.inf)
