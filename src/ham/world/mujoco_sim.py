"""Physics-engine glances with MuJoCo, beside the fast foam model (section "Scenario and Experimental Setup").

The paper's data came from a physics engine (Gazebo with ODE). This module performs the same
low-level glance (section "Haptic Control of the Simulated Myrmex") in MuJoCo, behind the same
interface as :class:`ham.world.glance.FastSimulator`, so that ``ham glance --simulator mujoco`` and
``ham table build --simulator mujoco`` work unchanged.

Scene (one model for the whole object set, like the paper's Fig. "Gazebo Simulation"):

* the table is a plane at ``z = 0``; object ``i`` stands on it centred at world
  ``x = i * object_spacing`` (0.3 m apart: no pad pose reaches a neighbour);
* every object is built from its own description (:meth:`HapticObject.outline`): the solid under
  the profile is cut into *convex* vertical slabs (maximal runs of profile segments whose slope does
  not increase, split at vertical steps), because MuJoCo collides convex geoms only. A slab with a
  flat top is an exact ``box`` primitive; any other slab is an exact convex prism ``mesh``. The four
  paper objects are each one convex slab (the box a box, the ramps and the convex curve one prism
  each); concave MHSB shapes become several slabs. Curved profiles are sampled densely and
  simplified to ``curve_tolerance`` (20 um) before meshing;
* an object whose top varies in y (a height field, issue 12: :attr:`HapticObject.varies_in_y`) is
  a MuJoCo ``hfield`` sampled every ``hfield_spacing`` (2 mm, an even number of cells so that the
  centre lines are sampled), standing on a base down to the table, so its sides are vertical; a
  flat top is an exact ``box``. (A ``mesh`` would be its convex hull: a saddle or a bowl would have
  to be cut into convex pieces.) MuJoCo collides a taxel with every triangle prism of the field
  it reaches; each taxel keeps only its deepest contact (``hfield_contacts``), else a taxel near a
  vertex would be a dozen springs (docs/crosscheck_curvature2d.md). With ``taxel_model =
  "foam"`` that one contact pushes with the cell's mean foam compression instead of the sphere's
  depth (:class:`MujocoConfig`), so a point under a cell is as soft as on the foam;
* the pad (section "The Tactile Sensor Array - Myrmex") hangs from a massless carriage on one slide
  joint along z. Its pose ``(x, phi)`` (or the extended glance's ``(x, y, phi, phi_y)``, rotation
  ``R_y(phi) R_x(phi_y)`` as in :mod:`ham.world.extended_glance`) is *pinned*: it is written into
  the carriage position and the pad orientation of the thread's own model copy, so the only degree
  of freedom is the height.
  Gravity is off (the "hand of god" plugin of the paper). The sensitive face is a 16 x 16 grid of
  sphere geoms (``taxels`` read-out), one contact per taxel, whose bottoms form the face; behind
  them is the rigid housing (a box from ``foam_thickness`` to ``foam_thickness +
  housing_thickness``, as in the fast model) on a separate welded body, so that its contacts stop
  the pad but are not sensed.

Glance (force-controlled and dynamic): the pad starts at rest ``clearance`` (50 um) above the
first touch, computed from the same geometry (on a height field or tilted about x: found with
MuJoCo's own collision test, lifted until clear and bisected to 5 um), and is pushed down by a force actuator on the slide
joint; the joint's viscous damping limits the approach speed and vanishes at rest. Every
``check_every`` steps the controller reads the summed normal force ``S`` of the taxels (a touch
sensor) and the vertical part ``F_z`` of their contact force (a contact sensor), and pushes with
``F = 2 N * F_z / S``, so that at rest the *summed normal force* on the cells, not just its vertical
part, is the paper's 2 N. The glance ends when the pad has settled (speed below ``settle_speed`` and
``|S - 2 N|`` within ``settle_tolerance``), when the rigid housing holds the pad while the taxels
feel less than 2 N (``blocked``, as in the fast model), or at ``max_steps`` (flagged: ``blocked`` and
``info["status"] == 2``). A diverging step (bad-acceleration warning, non-finite state, pad thrown 5 cm,
a contact arena too full to hold every contact) is flagged ``unstable`` (status 3) with no contact; ``on_failure="raise"`` turns either into a
:class:`HamError`. Nothing can hang: every glance stops after ``max_steps``. MuJoCo's own warnings
go to this module's logger, once per kind (stderr), not to stdout and a MUJOCO_LOG.TXT in the
working folder, where its default handler puts them.

Read-outs:

* ``taxels``: each sphere's summed contact normal force divided by the cell area (Pa). An edge
  shows as the line a real Myrmex shows.
* ``gazebo``: the paper's Gazebo plugin. The sensitive face is one thin box, so the engine reports
  only a few contact points (box-box clipping; ``multiccd`` for meshes); each contact's normal force
  is spread over the taxel centres by a Gaussian of sigma ``gazebo_sigma`` (5 mm) around its point,
  what falls past the pad's border is lost. An edge shows as the paper's blobs.

Contact model: frictionless (``condim = 1``: with x and phi pinned, friction would only add
hysteresis to the height), MuJoCo's soft contacts with ``solref = (time constant, damping ratio)``
and a constant impedance ``d`` (``solimp = (d, d, width)``), so each contact is a linear spring at
rest. For this one-DOF pad the force at rest is ``3 m / ((1 - d) tc^2 dr^2)`` per metre of
penetration (``m`` the pad mass; ``3 m`` is MuJoCo's diagonal approximation of the inverse inertia);
the pad mass is therefore derived from the physical ``contact_stiffness`` (N/m per taxel), and every
contact set relaxes with the same time constant whether 16 or 256 taxels touch.
:func:`calibrate_foam_stiffness` measures the depth on the flat box and returns the fast model's
``foam_stiffness`` that presses the same depth.
"""

from __future__ import annotations

import contextlib
import copy
import logging
import math
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from typing import Literal

import mujoco
import numpy as np
import torch

from ham.errors import HamError, check_types
from ham.world.glance import (
    GlanceConfig,
    GlanceResult,
    PoseConfig,
    as_action,
    as_object_ids,
    check_foam,
    check_pad,
)
from ham.world.objects import HapticObject
from ham.world.sensor import READOUTS, Myrmex, SensorConfig

Readout = Literal["taxels", "gazebo"]
FailureMode = Literal["flag", "raise"]
HfieldContacts = Literal["deepest", "all"]
TaxelModel = Literal["sphere", "foam"]

# Status codes of one glance (``GlanceResult.info["status"]``).
SETTLED, BLOCKED, STEP_LIMIT, UNSTABLE = 0, 1, 2, 3
STATUS_NAMES: tuple[str, ...] = ("settled", "blocked", "step_limit", "unstable")
#: The taxel spheres' radius (m) in a scene of the paper's kind of objects.
PAPER_TAXEL_RADIUS = 0.005
#: A glance whose pad leaves its start height by more than this (m) has diverged.
_DIVERGED = 0.05
#: The ``foam`` taxels' contact margin, in taxel radii (:func:`scene_xml`).
FOAM_MARGIN = 0.3

_log = logging.getLogger(__name__)
#: MuJoCo warnings already logged in this process (their text up to the simulation time)
_WARNED: set[str] = set()
_WARNED_LOCK = threading.Lock()


def _log_warning(message: str) -> None:
    """A MuJoCo warning ('Nan, Inf or huge value in QACC ... The simulation is unstable'), logged
    once per kind on stderr: MuJoCo's own handler prints it to stdout (into a ``--json`` output)
    and appends it to a MUJOCO_LOG.TXT in the working folder, a file no command should leave.
    The glances it concerns are flagged already (``unstable``, status 3)."""
    kind = message.split(" Time =")[0].strip()
    with _WARNED_LOCK:
        if kind in _WARNED:
            return
        _WARNED.add(kind)
    _log.warning("MuJoCo: %s (its glances are flagged unstable)", kind)


@contextlib.contextmanager
def _warnings_to_log():
    """MuJoCo's warnings to :func:`_log_warning` while a batch runs (the handler is global to
    the process: the one before is restored after)."""
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(_log_warning)
    try:
        yield
    finally:
        mujoco.set_mju_user_warning(previous)


@dataclass(frozen=True)
class MujocoConfig:
    """Every parameter of the MuJoCo glance in one place (values discussed in docs/crosscheck.md).

    Attributes:
        readout: ``taxels`` (16 x 16 sphere taxels, one contact each: edges are lines) or
            ``gazebo`` (the paper's plugin: few contact points spread by a Gaussian: blobs).
        taxel_radius: radius of each sphere taxel (m); its bottom lies on the face. ``None``
            (default): 5 mm in a scene of the paper's kind of objects, which keeps the bumps
            between neighbours (0.67 mm deep) and the bulge at tilted contacts small; half the
            pitch (2.5 mm) in a scene with height fields, so that the rim taxels end at the
            face's rim as the fast model's face does (docs/crosscheck_curvature2d.md).
        contact_stiffness: equilibrium force per metre of penetration of one taxel contact (N/m).
            250 N/m is the fast model's default foam (1e7 Pa/m over a 5 x 5 mm cell).
        contact_time_constant: MuJoCo's ``solref[0]``: the time constant (s) with which every
            contact relaxes; at least two time steps.
        damping_ratio: ``solref[1]``; 1 is critical damping.
        impedance: MuJoCo's constraint impedance ``d`` (``solimp = (d, d, width, 0.5, 2)``),
            constant over penetration so that each contact is a linear spring.
        impedance_width: ``solimp[2]`` (m), irrelevant while ``d`` is constant.
        solref: explicit ``solref`` for the taxel contacts, overriding the values above.
        solimp: explicit ``solimp`` (5 numbers) for the taxel contacts.
        housing_stiffness: the same as ``contact_stiffness`` for each contact of the rigid housing.
        gazebo_stiffness: the same for each contact of the ``gazebo`` face, which has only a few
            contacts (4 on a flat top): 64 taxels' worth, so a flat top sinks about as deep.
        gazebo_sigma: Gaussian spread of each contact in the ``gazebo`` read-out (m), 5 mm.
        joint_damping: viscous damping of the pad's slide joint (N s/m): it limits the approach
            speed to ``2 N / joint_damping`` and vanishes at rest, so the equilibrium is unchanged.
        timestep: simulation step (s).
        approach_speed: initial downward speed (m/s) at the start height.
        clearance: the pad starts this far (m) above the first touch computed from geometry.
        check_every: steps between two controller updates and settle checks.
        settle_speed: the pad has settled when slower than this (m/s)...
        settle_tolerance: ...and the summed normal force is within this fraction of 2 N.
        max_steps: step limit of every glance; a glance that reaches it is flagged.
        threads: worker threads for a batch (``None``: all cores).
        object_spacing: distance (m) between neighbouring objects on the table.
        curve_tolerance: curved profiles are simplified to polylines within this distance (m).
        hfield_spacing: grid spacing (m) of the MuJoCo height field that carries an object whose
            top varies in y (:attr:`HapticObject.varies_in_y`); MuJoCo joins the samples by two
            triangles per cell.
        hfield_contacts: ``deepest`` (default) keeps one contact per taxel on a height field,
            its deepest; ``all`` keeps every contact MuJoCo makes with the field's triangle
            prisms (up to a dozen per taxel, each a full spring; for comparison only). The
            ``gazebo`` face always keeps all of its contact points, as the plugin read them.
        taxel_model: ``sphere`` (default, the paper set's): each taxel is one sphere contact, a
            spring of ``contact_stiffness`` on the sphere's penetration, as if the whole cell were
            pressed as deep as its deepest point. ``foam``: each taxel's one contact (its
            deepest, found with a margin of ``0.3 taxel_radius``) is a spring of
            ``contact_stiffness`` on the cell's *mean* vertical compression, read from the
            object's surface at ``foam_points`` x ``foam_points`` points of the cell (the
            Winkler foam of the fast model): a point under the cell presses it only where it
            is, so the pad sinks as deep as on the foam (docs/crosscheck_curvature2d.md, "What
            was tried"). Needs the ``taxels`` read-out; MuJoCo still finds the contacts, the
            housing and the dynamics.
        foam_points: points per cell side of the ``foam`` taxel model (8: 64 per cell; 4 puts
            a ridge on a cell border between points: see "What was tried").

    The pad mass is not a free parameter: MuJoCo's soft-contact force at rest is
    ``3 m / ((1 - d) * timeconst^2 * dampratio^2)`` per metre of penetration for this one-DOF pad
    (``3 m`` from MuJoCo's diagonal approximation of the inverse inertia), so :attr:`pad_mass` is
    the mass that gives ``contact_stiffness``. Stiffer contacts (housing, gazebo face) raise the
    impedance ``d`` instead (:meth:`impedance_for`), keeping one time constant for all contacts.
    """

    readout: Readout = "taxels"
    taxel_radius: float | None = None
    contact_stiffness: float = 1000.0
    contact_time_constant: float = 0.006
    damping_ratio: float = 1.0
    impedance: float = 0.1
    impedance_width: float = 0.001
    solref: tuple[float, float] | None = None
    solimp: tuple[float, float, float, float, float] | None = None
    housing_stiffness: float = 4_000.0
    gazebo_stiffness: float = 1_000.0
    gazebo_sigma: float = 0.005
    joint_damping: float = 40.0
    timestep: float = 0.0025
    approach_speed: float = 0.0
    clearance: float = 5.0e-5
    check_every: int = 2
    settle_speed: float = 2.0e-4
    settle_tolerance: float = 0.005
    max_steps: int = 200
    threads: int | None = None
    object_spacing: float = 0.3
    curve_tolerance: float = 2.0e-5
    hfield_spacing: float = 2.0e-3
    hfield_contacts: HfieldContacts = "deepest"
    on_failure: FailureMode = "flag"
    taxel_model: TaxelModel = "sphere"
    foam_points: int = 8

    def __post_init__(self) -> None:
        check_types(self)
        if self.readout not in READOUTS:
            raise HamError(f"readout = {self.readout!r}; accepted: {', '.join(READOUTS)}")
        if self.on_failure not in ("flag", "raise"):
            raise HamError(f"on_failure = {self.on_failure!r}; accepted: flag, raise")
        if self.hfield_contacts not in ("deepest", "all"):
            raise HamError(f"hfield_contacts = {self.hfield_contacts!r}; accepted: deepest, all")
        if self.taxel_model not in ("sphere", "foam"):
            raise HamError(f"taxel_model = {self.taxel_model!r}; accepted: sphere, foam")
        if self.taxel_model == "foam" and (
            self.readout != "taxels" or self.hfield_contacts != "deepest"
        ):
            raise HamError(
                f"taxel_model = 'foam' with readout = {self.readout!r}, hfield_contacts = "
                f"{self.hfield_contacts!r}; accepted: readout = 'taxels', hfield_contacts = 'deepest'"
            )
        if self.taxel_radius is not None and not (
            isinstance(self.taxel_radius, (int, float))
            and math.isfinite(self.taxel_radius)
            and self.taxel_radius > 0
        ):
            raise HamError(
                f"taxel_radius = {self.taxel_radius!r}; accepted: None (by the scene) or a "
                "positive number (m)"
            )
        for name in (
            "contact_stiffness",
            "contact_time_constant",
            "damping_ratio",
            "impedance_width",
            "housing_stiffness",
            "gazebo_stiffness",
            "gazebo_sigma",
            "timestep",
            "settle_speed",
            "settle_tolerance",
            "object_spacing",
            "curve_tolerance",
            "hfield_spacing",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise HamError(f"{name} = {v!r}; accepted: a positive number")
        if not (isinstance(self.joint_damping, (int, float)) and self.joint_damping >= 0):
            raise HamError(f"joint_damping = {self.joint_damping!r}; accepted: >= 0 (N s/m)")
        if self.contact_time_constant < 2 * self.timestep:
            raise HamError(
                f"contact_time_constant = {self.contact_time_constant} must be at least two time steps "
                f"(timestep = {self.timestep}); accepted: >= {2 * self.timestep}"
            )
        if (
            self.housing_stiffness < self.contact_stiffness
            or self.gazebo_stiffness < self.contact_stiffness
        ):
            raise HamError(
                "housing_stiffness and gazebo_stiffness must be >= contact_stiffness (N/m)"
            )
        if not (isinstance(self.impedance, (int, float)) and 0 < self.impedance < 1):
            raise HamError(f"impedance = {self.impedance!r}; accepted: 0 < d < 1")
        if not (isinstance(self.approach_speed, (int, float)) and 0 <= self.approach_speed < 1):
            raise HamError(
                f"approach_speed = {self.approach_speed!r}; accepted: 0 <= speed < 1 (m/s)"
            )
        if not (isinstance(self.clearance, (int, float)) and 0 <= self.clearance < 0.05):
            raise HamError(f"clearance = {self.clearance!r}; accepted: 0 <= clearance < 0.05 (m)")
        for name in ("check_every", "max_steps", "foam_points"):
            v = getattr(self, name)
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
                raise HamError(f"{name} = {v!r}; accepted: a positive integer")
        if self.threads is not None and not (
            isinstance(self.threads, int)
            and not isinstance(self.threads, bool)
            and self.threads >= 1
        ):
            raise HamError(f"threads = {self.threads!r}; accepted: None (all cores) or >= 1")
        if self.solref is not None and len(self.solref) != 2:
            raise HamError(f"solref = {self.solref!r}; accepted: None or 2 numbers")
        if self.solimp is not None and len(self.solimp) != 5:
            raise HamError(f"solimp = {self.solimp!r}; accepted: None or 5 numbers")

    def resolved(self, objects: list[HapticObject], sensor: SensorConfig) -> MujocoConfig:
        """This configuration with ``taxel_radius`` set for a scene of ``objects``."""
        if self.taxel_radius is not None:
            return self
        fields_ = any(o.varies_in_y for o in objects)
        return replace(self, taxel_radius=0.5 * sensor.pitch if fields_ else PAPER_TAXEL_RADIUS)

    @property
    def pad_mass(self) -> float:
        """The pad mass (kg) that makes a taxel contact ``contact_stiffness`` N/m stiff at rest."""
        tc, dr, d = self.contact_time_constant, self.damping_ratio, self.impedance
        return self.contact_stiffness * (1.0 - d) * (tc * dr) ** 2 / 3.0

    def impedance_for(self, stiffness: float) -> float:
        """The impedance ``d`` that makes a contact ``stiffness`` N/m stiff (same mass and solref)."""
        return 1.0 - (1.0 - self.impedance) * self.contact_stiffness / stiffness

    def taxel_solref(self) -> tuple[float, float]:
        """``solref`` of the taxel contacts (and, with its own impedance, every pad contact)."""
        if self.solref is not None:
            return tuple(float(v) for v in self.solref)  # type: ignore[return-value]
        return (self.contact_time_constant, self.damping_ratio)

    def taxel_solimp(self) -> tuple[float, ...]:
        if self.solimp is not None:
            return tuple(float(v) for v in self.solimp)
        return self.solimp_for(self.contact_stiffness)

    def solimp_for(self, stiffness: float) -> tuple[float, ...]:
        d = self.impedance_for(stiffness)
        return (d, d, self.impedance_width, 0.5, 2.0)

    def to_dict(self) -> dict:
        return asdict(self)


# --------------------------------------------------------------------------- geometry
def simplify_polyline(points: np.ndarray, tolerance: float) -> np.ndarray:
    """Ramer-Douglas-Peucker: the fewest vertices of ``points`` (N, 2) within ``tolerance``."""
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) <= 2:
        return pts
    keep = np.zeros(len(pts), dtype=bool)
    keep[0] = keep[-1] = True
    stack = [(0, len(pts) - 1)]
    while stack:
        a, b = stack.pop()
        if b <= a + 1:
            continue
        seg = pts[b] - pts[a]
        rel = pts[a + 1 : b] - pts[a]
        length = float(np.hypot(*seg))
        if length == 0.0:
            dist = np.hypot(rel[:, 0], rel[:, 1])
        else:
            dist = np.abs(seg[0] * rel[:, 1] - seg[1] * rel[:, 0]) / length
        k = int(np.argmax(dist))
        if dist[k] > tolerance:
            keep[a + 1 + k] = True
            stack.append((a, a + 1 + k))
            stack.append((a + 1 + k, b))
    return pts[keep]


def object_polyline(obj: HapticObject, tolerance: float = 2.0e-5) -> np.ndarray:
    """The object's top as an exact polyline (x, z): its vertices, or a curve simplified to ``tolerance``."""
    if obj.vertices is not None:
        return np.asarray(obj.vertices, dtype=np.float64)
    return simplify_polyline(obj.outline(4097), tolerance)


def convex_slabs(polyline: np.ndarray, eps: float = 1e-12) -> list[np.ndarray]:
    """Cut the solid under ``polyline`` (down to z = 0) into convex slabs.

    Returns a list of top polylines, one per slab, each spanning a run of segments whose slope does
    not increase from left to right (a concave-down run: its hypograph is convex). Vertical segments
    (steps) separate slabs; slabs of zero height are dropped.
    """
    pts = np.asarray(polyline, dtype=np.float64)
    slabs: list[list[np.ndarray]] = []
    current: list[np.ndarray] = []
    last_slope = math.inf
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        dx = b[0] - a[0]
        if dx <= eps:  # a vertical step ends the slab
            if current:
                slabs.append(current)
            current, last_slope = [], math.inf
            continue
        slope = (b[1] - a[1]) / dx
        if current and slope > last_slope + 1e-9:  # concave corner: a new slab
            slabs.append(current)
            current = []
        if not current:
            current = [a]
        current.append(b)
        last_slope = slope
    if current:
        slabs.append(current)
    out = []
    for s in slabs:
        arr = np.asarray(s)
        if arr[:, 1].max() > eps:
            out.append(arr)
    return out


def _fmt(values) -> str:
    return " ".join(f"{float(v):.9g}" for v in np.ravel(values))


#: Cells a side of each ``hfield`` tile of a height-field object (:func:`_hfield_xml`).
HFIELD_TILE_CELLS = 4


def hfield_samples(obj: HapticObject, spacing: float) -> np.ndarray:
    """The object's top on the grid of the MuJoCo height field: ``(ny, nx)`` samples (edges
    included, row ``j`` at ``y = -depth/2 + j * depth / (ny - 1)``), at most ``spacing`` apart.

    The number of cells is even along each side, so the centre lines are sampled: a ridge or apex
    there (a pyramid's) stays sharp instead of being cut off between two samples."""
    nx = 2 * max(1, int(math.ceil(obj.width / (2 * spacing) - 1e-9))) + 1
    ny = 2 * max(1, int(math.ceil(obj.depth / (2 * spacing) - 1e-9))) + 1
    return obj.height_field(nx, ny)


def _hfield_xml(obj: HapticObject, index: int, x0: float, spacing: float) -> tuple[str, str]:
    """(asset xml, worldbody xml) for an object whose top varies in y: MuJoCo ``hfield`` tiles.

    MuJoCo rescales each field's elevation data to [0, 1] and stacks it on a box ``base`` deep, so
    a field's geom stands at its lowest sample ``h_min`` with elevation range ``h_max - h_min`` and
    a base down to the table: the block's sides stay vertical. The top is cut into tiles of
    :data:`HFIELD_TILE_CELLS` cells a side (sharing their border samples), because the engine's
    broad phase then skips the tiles below a taxel: a third of the time of one field for the
    same surface. A flat top, or a flat tile, is an exact ``box``.
    """
    hs = hfield_samples(obj, spacing)
    lo, hi = float(hs.min()), float(hs.max())
    if hi - lo <= 1e-9 * max(hi, 1e-3):  # a flat top: one box
        size = _fmt([0.5 * obj.width, 0.5 * obj.depth, 0.5 * hi])
        pos = _fmt([x0, 0.0, 0.5 * hi])
        return (
            "",
            f'<geom name="obj{index}_box" class="object" type="box" size="{size}" pos="{pos}"/>',
        )
    ny, nx = hs.shape
    xs = np.linspace(-0.5 * obj.width, 0.5 * obj.width, nx)
    ys = np.linspace(-0.5 * obj.depth, 0.5 * obj.depth, ny)
    cuts_x = np.unique(np.r_[np.arange(0, nx - 1, HFIELD_TILE_CELLS), nx - 1])
    cuts_y = np.unique(np.r_[np.arange(0, ny - 1, HFIELD_TILE_CELLS), ny - 1])
    assets, geoms = [], []
    for a, (i0, i1) in enumerate(zip(cuts_x[:-1], cuts_x[1:], strict=True)):
        for b, (j0, j1) in enumerate(zip(cuts_y[:-1], cuts_y[1:], strict=True)):
            name = f"obj{index}_hfield_{a}_{b}"
            tile = hs[j0 : j1 + 1, i0 : i1 + 1]
            lo, hi = float(tile.min()), float(tile.max())
            cx, hx = 0.5 * (xs[i0] + xs[i1]), 0.5 * (xs[i1] - xs[i0])
            cy, hy = 0.5 * (ys[j0] + ys[j1]), 0.5 * (ys[j1] - ys[j0])
            if hi - lo <= 1e-9 * max(hi, 1e-3):
                size = _fmt([hx, hy, 0.5 * hi])
                pos = _fmt([x0 + cx, cy, 0.5 * hi])
                geoms.append(
                    f'<geom name="{name}" class="object" type="box" size="{size}" pos="{pos}"/>'
                )
                continue
            # MJCF lists the rows from +y down to -y (the first row is the image's top).
            elevation = _fmt(np.flipud((tile - lo) / (hi - lo)))
            base = max(lo, 1e-3)  # down to the table (MuJoCo wants > 0; nothing reaches below)
            size = _fmt([hx, hy, hi - lo, base])
            assets.append(
                f'<hfield name="{name}" nrow="{tile.shape[0]}" ncol="{tile.shape[1]}" '
                f'size="{size}" elevation="{elevation}"/>'
            )
            geoms.append(
                f'<geom name="{name}" class="object" type="hfield" hfield="{name}" '
                f'pos="{_fmt([x0 + cx, cy, lo])}"/>'
            )
    return "\n".join(assets), "\n".join(geoms)


def _object_xml(
    obj: HapticObject, index: int, x0: float, tolerance: float, spacing: float = 2e-3
) -> tuple[str, str]:
    """(asset xml, worldbody xml) for object ``index`` centred at world x ``x0``."""
    if obj.varies_in_y:
        return _hfield_xml(obj, index, x0, spacing)
    assets, geoms = [], []
    half_d = 0.5 * obj.depth
    for k, top in enumerate(convex_slabs(object_polyline(obj, tolerance))):
        name = f"obj{index}_slab{k}"
        xa, xb = top[0, 0], top[-1, 0]
        if np.ptp(top[:, 1]) <= 1e-12:  # a flat top: an exact box
            h = top[0, 1]
            size = _fmt([0.5 * (xb - xa), half_d, 0.5 * h])
            pos = _fmt([x0 + 0.5 * (xa + xb), 0.0, 0.5 * h])
            geoms.append(
                f'<geom name="{name}" class="object" type="box" size="{size}" pos="{pos}"/>'
            )
            continue
        ring = [tuple(p) for p in top]
        if top[-1, 1] > 0:
            ring.append((xb, 0.0))
        if top[0, 1] > 0:
            ring.append((xa, 0.0))
        verts = [(x, y, z) for (x, z) in ring for y in (-half_d, half_d)]
        assets.append(f'<mesh name="{name}" vertex="{_fmt(verts)}"/>')
        geoms.append(
            f'<geom name="{name}" class="object" type="mesh" mesh="{name}" pos="{_fmt([x0, 0, 0])}"/>'
        )
    return "\n".join(assets), "\n".join(geoms)


def scene_xml(
    objects: list[HapticObject],
    sensor: SensorConfig | None = None,
    config: MujocoConfig | None = None,
) -> str:
    """The MJCF of the whole scene: table, objects in a row, the pad (see module doc)."""
    s = sensor or SensorConfig()
    c = (config or MujocoConfig()).resolved(objects, s)
    L, f, T = s.size, s.foam_thickness, s.housing_thickness
    r = c.taxel_radius
    assets, bodies = [], []
    for i, obj in enumerate(objects):
        a, g = _object_xml(obj, i, i * c.object_spacing, c.curve_tolerance, c.hfield_spacing)
        assets.append(a)
        bodies.append(g)
    taxel_ref = _fmt(c.taxel_solref())
    taxel_imp = _fmt(c.taxel_solimp())
    housing_imp = _fmt(c.solimp_for(c.housing_stiffness))
    gazebo_imp = _fmt(c.solimp_for(c.gazebo_stiffness))
    if c.readout == "taxels":
        face = []
        for i in range(s.taxels):
            for j in range(s.taxels):
                u = (j + 0.5) * s.pitch - 0.5 * L
                y = (i + 0.5) * s.pitch - 0.5 * L
                face.append(
                    f'<geom name="taxel_{i}_{j}" class="taxel" type="sphere" size="{r:.9g}" '
                    f'pos="{_fmt([u, y, r])}"/>'
                )
        face_xml = "\n".join(face)
    else:
        face_xml = (
            f'<geom name="face" class="gazebo" type="box" size="{_fmt([L / 2, L / 2, f / 2])}" '
            f'pos="{_fmt([0, 0, f / 2])}"/>'
        )
    flags = '<flag multiccd="enable"/>' if c.readout == "gazebo" else ""
    # The foam taxel model sets each taxel contact's force per step (MujocoSimulator.
    # _one_contact_per_taxel); a margin lets a sphere carry a cell pressed off its centre
    # (0.75 r, which reaches a cell's corners, read the same on the grid but 35% slower).
    taxel_margin = f' margin="{FOAM_MARGIN * r:.9g}"' if c.taxel_model == "foam" else ""
    big = _fmt([L, L, 0.05])
    return f"""<mujoco model="ham_glance">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{c.timestep:.9g}" gravity="0 0 0" integrator="implicitfast" solver="Newton"
          iterations="50" tolerance="1e-10">{flags}</option>
  <visual><global offwidth="1280" offheight="960"/></visual>
  <default>
    <geom condim="1" friction="0 0 0"/>
    <default class="object"><geom rgba="0.76 0.6 0.42 1"/></default>
    <default class="taxel"><geom priority="1" solref="{taxel_ref}" solimp="{taxel_imp}"
        rgba="0.1 0.1 0.1 1" mass="0"{taxel_margin}/></default>
    <default class="gazebo"><geom priority="1" solref="{taxel_ref}" solimp="{gazebo_imp}"
        rgba="0.1 0.1 0.1 1" mass="0"/></default>
    <default class="housing"><geom priority="1" solref="{taxel_ref}" solimp="{housing_imp}"
        rgba="0.8 0.1 0.1 1" mass="0"/></default>
  </default>
  <asset>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.9 0.9 0.9" rgb2="0.8 0.8 0.8"
             width="256" height="256"/>
    <material name="grid" texture="grid" texrepeat="20 20"/>
    {"".join(assets)}
  </asset>
  <worldbody>
    <light pos="0 -1 1.5" dir="0 0.6 -1" directional="true"/>
    <geom name="table" type="plane" size="{len(objects) * c.object_spacing + 1:.9g} 1 0.1" material="grid"
          pos="{(len(objects) - 1) * c.object_spacing / 2:.9g} 0 0"/>
    {"".join(bodies)}
    <body name="carriage" pos="0 0 0">
      <joint name="z" type="slide" axis="0 0 1" damping="{c.joint_damping:.9g}"/>
      <body name="pad">
        <inertial pos="0 0 {f:.9g}" mass="{c.pad_mass:.9g}" diaginertia="1e-6 1e-6 1e-6"/>
        <site name="pad_zone" type="box" size="{big}" rgba="0 0 0 0"/>
        {face_xml}
        <body name="housing">
          <geom name="housing" class="housing" type="box" size="{_fmt([L / 2, L / 2, T / 2])}"
                pos="{_fmt([0, 0, f + T / 2])}"/>
          <site name="housing_zone" type="box" size="{big}" rgba="0 0 0 0"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="push" joint="z"/>
  </actuator>
  <sensor>
    <touch name="taxel_sum" site="pad_zone"/>
    <touch name="housing_sum" site="housing_zone"/>
    <contact name="pad_net" body1="pad" data="force" reduce="netforce"/>
  </sensor>
</mujoco>
"""


def build_model(
    objects: list[HapticObject],
    sensor: SensorConfig | None = None,
    config: MujocoConfig | None = None,
) -> mujoco.MjModel:
    """Compile :func:`scene_xml`; a compile error becomes a :class:`HamError`."""
    xml = scene_xml(objects, sensor, config)
    try:
        return mujoco.MjModel.from_xml_string(xml)
    except ValueError as exc:
        raise HamError(f"MuJoCo could not compile the scene: {exc}") from None


def _pad_outline(sensor: SensorConfig, config: MujocoConfig, spacing: float = 2.5e-4) -> np.ndarray:
    """Points (K, 2) in pad coordinates (u along the face, v into the pad) on the pad's boundary."""
    L, f, T = sensor.size, sensor.foam_thickness, sensor.housing_thickness
    parts = []
    # Housing rectangle u in [-L/2, L/2], v in [f, f + T].
    nu = int(math.ceil(L / spacing)) + 1
    nv = int(math.ceil(T / spacing)) + 1
    us = np.linspace(-L / 2, L / 2, nu)
    vs = np.linspace(f, f + T, nv)
    parts += [np.stack([us, np.full_like(us, f)], 1), np.stack([us, np.full_like(us, f + T)], 1)]
    parts += [
        np.stack([np.full_like(vs, -L / 2), vs], 1),
        np.stack([np.full_like(vs, L / 2), vs], 1),
    ]
    if config.readout == "taxels":
        r = config.taxel_radius
        n = max(24, int(math.ceil(2 * math.pi * r / spacing)))
        a = np.linspace(0, 2 * math.pi, n, endpoint=False)
        circle = np.stack([r * np.sin(a), r - r * np.cos(a)], 1)
        centres = (np.arange(sensor.taxels) + 0.5) * sensor.pitch - L / 2
        parts += [circle + np.array([c, 0.0]) for c in centres]
    else:
        parts += [np.stack([us, np.zeros_like(us)], 1)]
        vf = np.linspace(0, f, max(2, int(math.ceil(f / spacing)) + 1))
        parts += [
            np.stack([np.full_like(vf, -L / 2), vf], 1),
            np.stack([np.full_like(vf, L / 2), vf], 1),
        ]
    return np.concatenate(parts)


#: Lifts tried before the start height of a general glance is bracketed; each clears the deepest
#: contact found, so two or three suffice.
_MAX_LIFTS = 50
#: The start height of a general glance is found to this (m) from above, then ``clearance`` added.
_CLEAR_TOLERANCE = 5.0e-6
#: Contacts shallower than this (m) are a face laid flush against a wall, not a penetration: a
#: pad at q_phi = +-1 stands vertical beside an object's side, tilted by its float32 angle's
#: rounding (cos(pi/2) = -4e-8), so lifting never clears it. Used only once the lifts fail.
_FLUSH = 1.0e-7


def _rotation(phi: float, phi_y: float) -> np.ndarray:
    """The pad's rotation ``R_y(phi) R_x(phi_y)`` of issue 12's pose: a face point ``(u, v, 0)``
    goes to ``(u cos phi - v sin phi_y sin phi, v cos phi_y, -u sin phi - v sin phi_y cos phi)``
    (``R_x`` turns +v down for phi_y > 0, as ``R_y`` turns +u down for phi > 0)."""
    cp, sp, cy, sy = math.cos(phi), math.sin(phi), math.cos(phi_y), math.sin(phi_y)
    r_y = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    r_x = np.array([[1.0, 0.0, 0.0], [0.0, cy, sy], [0.0, -sy, cy]])
    return r_y @ r_x


def _quaternion(phi: float, phi_y: float) -> np.ndarray:
    """The unit quaternion (w, x, y, z) of :func:`_rotation`."""
    q = np.empty(4)
    q_y = np.array([math.cos(phi / 2), 0.0, math.sin(phi / 2), 0.0])
    q_x = np.array([math.cos(phi_y / 2), -math.sin(phi_y / 2), 0.0, 0.0])
    mujoco.mju_mulQuat(q, q_y, q_x)
    return q


def _pad_points(
    sensor: SensorConfig, config: MujocoConfig, spacing: float = 5.0e-4
) -> tuple[np.ndarray, np.ndarray]:
    """Points (K, 3) in pad coordinates on the edges and faces of the pad's boxes (housing; the
    gazebo face), and the taxel spheres' centres (N*N, 3; empty for the gazebo read-out).

    They give :meth:`MujocoSimulator.touch_estimate` its first guess; edges every ``spacing``,
    faces every 4 ``spacing``.
    """
    L, f, T = sensor.size, sensor.foam_thickness, sensor.housing_thickness
    boxes = [(f, f + T)] + ([(0.0, f)] if config.readout == "gazebo" else [])
    parts = []

    def axis_samples(a: float, b: float, step: float) -> np.ndarray:
        return np.linspace(a, b, max(2, int(math.ceil((b - a) / step)) + 1))

    for lo, hi in boxes:
        span = [(-L / 2, L / 2), (-L / 2, L / 2), (lo, hi)]
        for k in range(3):
            i, j = (a for a in range(3) if a != k)
            # The 4 edges along axis k, every ``spacing``.
            line = axis_samples(*span[k], spacing)
            for e1 in span[i]:
                for e2 in span[j]:
                    pts = np.zeros((len(line), 3))
                    pts[:, k], pts[:, i], pts[:, j] = line, e1, e2
                    parts.append(pts)
            # The 2 faces normal to axis k, every 4 ``spacing``.
            g1, g2 = np.meshgrid(
                axis_samples(*span[i], 4 * spacing), axis_samples(*span[j], 4 * spacing)
            )
            for end in span[k]:
                pts = np.zeros((g1.size, 3))
                pts[:, i], pts[:, j], pts[:, k] = g1.ravel(), g2.ravel(), end
                parts.append(pts)
    points = np.concatenate(parts)
    if config.readout != "taxels":
        return points, np.zeros((0, 3))
    r = config.taxel_radius
    c = (np.arange(sensor.taxels) + 0.5) * sensor.pitch - 0.5 * L
    cu, cv = np.meshgrid(c, c)
    centres = np.stack([cu.ravel(), cv.ravel(), np.full(cu.size, r)], 1)
    return points, centres


def _check_world(sensor: SensorConfig, glance: GlanceConfig, objects: list[HapticObject]) -> None:
    """The line glance's checks of the pad (:func:`ham.world.glance.check_pad`) for the paper's
    kind of objects; for height fields only the foam's (a pad wider than such an object reads
    nothing beside it, as a real pad would)."""
    if sensor.housing_thickness <= 0:  # a box geom needs a positive size: say so, by name
        raise HamError(
            f"housing_thickness = {sensor.housing_thickness!r} with the MuJoCo simulator; "
            "accepted: a positive number (m): the pad body is a box (0 is for the fast simulator)"
        )
    default = SensorConfig.__dataclass_fields__["supersample"].default
    if sensor.supersample != default:  # MuJoCo reads its taxel geoms' contacts: no such density
        raise HamError(
            f"supersample = {sensor.supersample!r} with the MuJoCo simulator, which reads its "
            f"taxels' contacts; accepted: the default {default} (supersample is the fast "
            "simulator's read-out density)"
        )
    lines = [o for o in objects if not o.varies_in_y]
    if lines:
        check_pad(sensor, glance, lines)
    else:
        check_foam(sensor, glance)


# --------------------------------------------------------------------------- simulator
@dataclass
class _Worker:
    model: mujoco.MjModel
    data: mujoco.MjData
    lock: threading.Lock = field(default_factory=threading.Lock)


class MujocoSimulator:
    """Glances in the MuJoCo physics engine, behind the :class:`ham.world.glance.Simulator` interface.

    Args:
        objects: the object set; object ``i`` stands at world x ``i * object_spacing``. Objects
            whose top varies in y (height fields) become MuJoCo ``hfield`` geoms.
        sensor: the Myrmex geometry (taxels, pitch, foam and housing thickness); its
            ``postprocess`` (optional spread and quantization) is applied to every image.
        pose: the action-to-pose mapping, shared with the fast simulator.
        glance: the stop rule (``force_threshold``, 2 N).
        config: the engine parameters (:class:`MujocoConfig`); keyword arguments override fields
            of it, e.g. ``MujocoSimulator(objs, readout="gazebo")``.
        device: accepted for interface compatibility; MuJoCo runs on the CPU, results are CPU tensors.
    """

    name = "mujoco"

    def __init__(
        self,
        objects: list[HapticObject],
        sensor: SensorConfig | None = None,
        pose: PoseConfig | None = None,
        glance: GlanceConfig | None = None,
        *,
        config: MujocoConfig | None = None,
        device: torch.device | str = "cpu",
        **overrides,
    ) -> None:
        if not objects:
            raise HamError("a simulator needs at least one object")
        config = config or MujocoConfig()
        if overrides:
            known = set(MujocoConfig.__dataclass_fields__)
            bad = sorted(set(overrides) - known)
            if bad:
                raise HamError(
                    f"unknown MuJoCo option(s) {bad}; accepted: {', '.join(sorted(known))}"
                )
            config = replace(config, **overrides)
        if torch.device(device).type != "cpu":
            raise HamError(
                f"device = {device!r}: the MuJoCo simulator runs on the CPU; accepted: cpu"
            )
        self.objects = list(objects)
        self.myrmex = Myrmex(sensor)
        self.sensor = self.myrmex.config
        self.config = config = config.resolved(self.objects, self.sensor)
        self.pose = pose or PoseConfig()
        self.glance_config = glance or GlanceConfig()
        _check_world(self.sensor, self.glance_config, self.objects)
        # The fast simulator's pose mapping, in float32 as there (poses bit-identical).
        f32 = dict(dtype=torch.float32)
        self._half = torch.tensor([self.pose.half_width(o) for o in self.objects], **f32)
        self._half_depth = torch.tensor([self.pose.half_depth(o) for o in self.objects], **f32)
        self._fields = any(o.varies_in_y for o in self.objects)
        self.model = build_model(self.objects, self.sensor, config)
        m = self.model
        self._carriage = m.body("carriage").id
        self._pad = m.body("pad").id
        self._x_offsets = np.arange(len(self.objects)) * config.object_spacing
        self._geom_taxel = np.full(m.ngeom, -1, dtype=np.int64)
        n = self.sensor.taxels
        if config.readout == "taxels":
            for i in range(n):
                for j in range(n):
                    self._geom_taxel[m.geom(f"taxel_{i}_{j}").id] = i * n + j
        else:
            self._geom_taxel[m.geom("face").id] = 0
        # Pad geoms (taxels or face, housing): the contacts that tell whether the pad is clear.
        pad_bodies = {self._pad, m.body("housing").id}
        self._pad_geom = np.isin(m.geom_bodyid, list(pad_bodies))
        self._outline = _pad_outline(self.sensor, config)
        self._points, self._sphere_centres = _pad_points(self.sensor, config)
        # One contact per taxel on height fields; the gazebo face keeps its contact points.
        self._thin_taxels = config.readout == "taxels" and config.hfield_contacts == "deepest"
        self._foam = config.taxel_model == "foam"
        if self._foam:
            # Pad coordinates (u, v, 0) of each cell's foam points: (n * n, P * P, 3).
            p = config.foam_points
            off = ((np.arange(p) + 0.5) / p - 0.5) * self.sensor.pitch
            c = (np.arange(n) + 0.5) * self.sensor.pitch - 0.5 * self.sensor.size
            cu, cv = np.meshgrid(c, c)  # [i, j]: taxel i * n + j at (u_j, v_i)
            ou, ov = np.meshgrid(off, off)
            pts = np.zeros((n * n, p * p, 3))
            pts[:, :, 0] = cu.reshape(-1, 1) + ou.reshape(1, -1)
            pts[:, :, 1] = cv.reshape(-1, 1) + ov.reshape(1, -1)
            self._cell_points = pts
        self._threads = config.threads or os.cpu_count() or 1
        self._workers: list[_Worker] = []
        self._pool: ThreadPoolExecutor | None = None
        centres = (np.arange(n) + 0.5) * self.sensor.pitch - 0.5 * self.sensor.size
        self._taxel_u, self._taxel_y = np.meshgrid(centres, centres)  # [i, j]: y along rows

    # ------------------------------------------------------------------ poses and geometry
    def poses(self, ids: torch.Tensor, q_x: torch.Tensor, q_phi: torch.Tensor):
        """Metric ``(x, phi)`` of the face centre: the fast simulator's mapping."""
        phi = q_phi * self.pose.phi_max
        x = q_x * self._half[ids] - self.pose.pivot_offset * torch.sin(phi)
        return x, phi

    def poses4(self, ids, q_x, q_phi, q_y, q_phi_y):
        """Metric ``(x, y, phi, phi_y)`` of the face centre: the extended glance's mapping
        (:meth:`ham.world.glance.PoseConfig.extended_pose`), ``y = q_y * depth / 2`` of the
        object; with ``phi_y = 0`` it is :meth:`poses` bit for bit."""
        return self.pose.extended_pose(
            q_x, q_y, q_phi, q_phi_y, self._half[ids], self._half_depth[ids]
        )

    def first_touch(self, ids: np.ndarray, x: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """Height (m) of the face centre at which the pad's boundary first meets the surface.

        For objects extruded along y and a pad not tilted about x: the pad's outline (spheres or
        face, housing) is sampled every 0.25 mm; the start height is this plus ``clearance``, so a
        small under-estimate only costs a few steps of push-back.
        """
        uv = self._outline
        out = np.empty(len(ids))
        for k in np.unique(ids):
            sel = ids == k
            c, s = np.cos(phi[sel])[:, None], np.sin(phi[sel])[:, None]
            px = x[sel][:, None] + uv[None, :, 0] * c + uv[None, :, 1] * s
            pz = -uv[None, :, 0] * s + uv[None, :, 1] * c
            out[sel] = (self.objects[int(k)].height_at(px) - pz).max(1)
        return out

    def touch_estimate(self, obj: int, x: float, y: float, phi: float, phi_y: float) -> float:
        """A first estimate of the face-centre height of the first touch for any pose: the
        lowest point of every taxel sphere and points on the face and housing, each held above
        the surface straight below it. Exact on flat ground; on slopes a sphere touches
        higher, which :meth:`_clear_height` corrects with MuJoCo's own collision test."""
        rot = _rotation(phi, phi_y)
        o = self.objects[obj]
        pts = self._points @ rot.T
        est = float((o.surface(x + pts[:, 0], y + pts[:, 1]) - pts[:, 2]).max())
        if len(self._sphere_centres):
            c = self._sphere_centres @ rot.T
            low = c[:, 2] - self.config.taxel_radius
            est = max(est, float((o.surface(x + c[:, 0], y + c[:, 1]) - low).max()))
        return est

    def _penetration(
        self, m: mujoco.MjModel, d: mujoco.MjData, z: float, flush: float = 0.0
    ) -> float:
        """How far (m, an upper estimate) the pad at face-centre height ``z`` must rise to clear
        every contact MuJoCo's collision finds there deeper than ``flush`` (0: none); the pose is
        already set."""
        d.qpos[0] = z
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        ncon = d.ncon
        if ncon == 0:
            return 0.0
        con = d.contact
        geoms = con.geom[:ncon]
        mine = self._pad_geom[geoms[:, 0]] | self._pad_geom[geoms[:, 1]]
        dist = con.dist[:ncon]
        sel = mine & (dist < -flush)
        if not sel.any():
            return 0.0
        # A penetration p along a normal n needs a vertical lift of p / |n_z|.
        nz = np.maximum(np.abs(con.frame[:ncon, 2][sel]), 0.05)
        return float((-dist[sel] / nz).max())

    def _clear_height(
        self, m: mujoco.MjModel, d: mujoco.MjData, z: float, flush: float = 0.0
    ) -> float:
        """The lowest face-centre height (to 5 um, from above) at which the pad touches nothing
        (nothing deeper than ``flush``), starting from the estimate ``z``: lift by the
        penetration until clear, then bisect. When lifting cannot clear the pad, try again with
        flush contacts (:data:`_FLUSH`) let be."""
        start, low = z, None
        for _ in range(_MAX_LIFTS):
            lift = self._penetration(m, d, z, flush)
            if lift <= 0:
                break
            low, z = z, z + lift + 1e-6
        else:
            if flush == 0.0:
                return self._clear_height(m, d, start, _FLUSH)
            raise HamError(
                f"the MuJoCo pad found no clear start height above {z:.6f} m (a contact "
                f"{_MAX_LIFTS} lifts did not clear); accepted: a pose whose pad can be lifted "
                "clear of the object"
            )
        if low is not None:
            high = z
            while high - low > _CLEAR_TOLERANCE:
                mid = 0.5 * (low + high)
                if self._penetration(m, d, mid, flush) > 0:
                    low = mid
                else:
                    high = mid
            z = high
        return z

    # ------------------------------------------------------------------ threads
    def _ensure_workers(self) -> None:
        if self._workers:
            return
        for _ in range(self._threads):
            m = copy.copy(self.model)
            self._workers.append(_Worker(m, mujoco.MjData(m)))
        if self._threads > 1:
            self._pool = ThreadPoolExecutor(
                max_workers=self._threads, thread_name_prefix="ham-mujoco"
            )

    def close(self) -> None:
        """Stop the worker threads (also done at garbage collection)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def __del__(self) -> None:  # pragma: no cover - interpreter shutdown order varies
        try:
            self.close()
        except Exception:
            pass

    # ------------------------------------------------------------------ glance
    def _run_batch(self, ids_np, x_np, phi_np, y_np, phi_y_np, out: dict) -> None:
        """The glances of a batch, into ``out``, over the worker threads."""
        b = len(ids_np)
        if not b:
            return
        # Rows on height fields or tilted about x start from MuJoCo's own collision test.
        varies = np.array([o.varies_in_y for o in self.objects])[ids_np]
        general = varies | (phi_y_np != 0)
        z0 = np.full(b, math.nan)
        line = ~general
        if line.any():
            z0[line] = (
                self.first_touch(ids_np[line], x_np[line], phi_np[line]) + self.config.clearance
            )
        self._ensure_workers()
        bounds = np.linspace(0, b, min(self._threads, b) + 1).astype(int)
        jobs = [
            (self._workers[w], range(bounds[w], bounds[w + 1]))
            for w in range(len(bounds) - 1)
            if bounds[w + 1] > bounds[w]
        ]
        args = (ids_np, x_np, phi_np, z0, y_np, phi_y_np, general, out)
        if self._pool is None or len(jobs) == 1:
            for worker, rows in jobs:
                self._run_rows(worker, rows, *args)
        else:
            for fut in [self._pool.submit(self._run_rows, w, r, *args) for w, r in jobs]:
                fut.result()

    def glance(
        self, object_ids, q_x, q_phi, q_y=None, q_phi_y=None, *, object_pose=None
    ) -> GlanceResult:
        """A batch of glances on ``object_ids`` (B,) at normalized poses ``q_x``, ``q_phi``
        (B,) and, for the extended glance, ``q_y``, ``q_phi_y`` (B,; ``None``: 0).

        The batch is split over ``threads`` workers, each with its own model copy; results come back
        in input order. ``info`` holds ``status`` (0 settled, 1 blocked, 2 step limit, 3 unstable;
        names in ``STATUS_NAMES``) and ``steps`` per glance.
        """
        if object_pose is not None:
            raise HamError(
                "object_pose: the MuJoCo simulator keeps every object at its place on the table; "
                "accepted: None (random object poses need the fast extended simulator)"
            )
        ids = as_object_ids(object_ids, len(self.objects))
        qx = as_action("q_x", q_x)
        qp = as_action("q_phi", q_phi)
        extended = q_y is not None or q_phi_y is not None
        qy = as_action("q_y", 0.0 if q_y is None else q_y)
        qpy = as_action("q_phi_y", 0.0 if q_phi_y is None else q_phi_y)
        try:
            ids, qx, qp, qy, qpy = torch.broadcast_tensors(ids, qx, qp, qy, qpy)
        except RuntimeError:
            lengths = [len(t) for t in (ids, qx, qp)]
            names = "object ids, q_x and q_phi"
            if extended:
                lengths += [len(qy), len(qpy)]
                names = "object ids, q_x, q_phi, q_y and q_phi_y"
            raise HamError(
                f"{names} must have equal lengths (or length 1), got "
                f"{', '.join(str(v) for v in lengths)}"
            ) from None
        x, y, phi, phi_y = self.poses4(ids, qx.float(), qp.float(), qy.float(), qpy.float())
        ids_np = ids.numpy().astype(np.int64)
        x_np = x.double().numpy()
        y_np = y.double().numpy()
        phi_np = phi.double().numpy()
        phi_y_np = phi_y.double().numpy()
        b = len(ids_np)
        n = self.sensor.taxels
        out = {
            "pressure": np.zeros((b, n, n)),
            "force": np.zeros(b),
            "z": np.zeros(b),
            "steps": np.zeros(b, dtype=np.int64),
            "status": np.zeros(b, dtype=np.int64),
        }
        with _warnings_to_log():
            self._run_batch(ids_np, x_np, phi_np, y_np, phi_y_np, out)
        status = out["status"]
        failed = np.flatnonzero(status >= STEP_LIMIT)
        if len(failed) and self.config.on_failure == "raise":
            i = int(failed[0])
            where = f"q_x = {float(qx[i]):.4f}, q_phi = {float(qp[i]):.4f}"
            if extended:
                where += f", q_y = {float(qy[i]):.4f}, q_phi_y = {float(qpy[i]):.4f}"
            raise HamError(
                f"{len(failed)} MuJoCo glance(s) failed; first: object {int(ids_np[i])} at "
                f"{where}: {STATUS_NAMES[status[i]]} "
                f"after {int(out['steps'][i])} steps (max_steps = {self.config.max_steps})"
            )
        pressure = self.myrmex.postprocess(torch.from_numpy(out["pressure"]).float())
        force = torch.from_numpy(out["force"]).float()
        ok = status < UNSTABLE
        z = torch.from_numpy(out["z"]).float()
        return GlanceResult(
            pressure=pressure,
            force=force,
            z=z,
            contact=torch.from_numpy(ok & (out["force"] > 0)),
            blocked=torch.from_numpy(status != SETTLED),
            x=x.float(),
            phi=phi.float(),
            y=y.float(),
            phi_y=phi_y.float(),
            height=z.clone(),
            info={"status": torch.from_numpy(status), "steps": torch.from_numpy(out["steps"])},
        )

    def _run_rows(
        self, worker: _Worker, rows: range, ids, x, phi, z0, y, phi_y, general, out
    ) -> None:
        with worker.lock:
            for i in rows:
                p, force, z, steps, status = self._glance_one(
                    worker.model,
                    worker.data,
                    int(ids[i]),
                    float(x[i]),
                    float(phi[i]),
                    float(z0[i]),
                    y=float(y[i]),
                    phi_y=float(phi_y[i]),
                    general=bool(general[i]),
                )
                out["pressure"][i] = p
                out["force"][i] = force
                out["z"][i] = z
                out["steps"][i] = steps
                out["status"][i] = status

    def _set_pose(self, m: mujoco.MjModel, obj: int, x: float, y: float, phi: float, phi_y: float):
        m.body_pos[self._carriage] = (self._x_offsets[obj] + x, y, 0.0)
        if phi_y == 0:
            m.body_quat[self._pad] = (math.cos(phi / 2), 0.0, math.sin(phi / 2), 0.0)
        else:
            m.body_quat[self._pad] = _quaternion(phi, phi_y)

    def _glance_one(
        self,
        m: mujoco.MjModel,
        d: mujoco.MjData,
        obj: int,
        x: float,
        phi: float,
        z0: float,
        *,
        y: float = 0.0,
        phi_y: float = 0.0,
        general: bool = False,
    ):
        """One glance on the worker's own model: pose pinned, force-controlled descent, read-out.

        ``general``: ``z0`` is ignored; the start height is ``clearance`` above the first touch
        that MuJoCo's collision test finds (height fields, pads tilted about x)."""
        c = self.config
        target = self.glance_config.force_threshold
        self._set_pose(m, obj, x, y, phi, phi_y)
        if general:
            mujoco.mj_resetData(m, d)
            est = self.touch_estimate(obj, x, y, phi, phi_y)
            z0 = self._clear_height(m, d, est) + c.clearance
        mujoco.mj_resetData(m, d)
        d.qpos[0] = z0
        d.qvel[0] = -c.approach_speed
        force_cmd = target
        d.ctrl[0] = -force_cmd
        steps, status = 0, STEP_LIMIT
        h_tol = 1e-3 * target
        idle = 0  # consecutive checks with only the housing touching
        thin = self._foam or (self.objects[obj].varies_in_y and self._thin_taxels)
        while steps < c.max_steps:
            if thin:
                for _ in range(c.check_every):
                    self._step_one_contact_per_taxel(m, d, obj)
            else:
                mujoco.mj_step(m, d, nstep=c.check_every)
            steps += c.check_every
            s_sum, h_sum, fz = d.sensordata[0], d.sensordata[1], abs(d.sensordata[4])
            v = d.qvel[0]
            z = d.qpos[0]
            if (
                d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number
                or d.warning[mujoco.mjtWarning.mjWARN_CONTACTFULL].number
                or not (math.isfinite(z) and math.isfinite(v))
                or abs(z - z0) > _DIVERGED
            ):
                # A 2 N push cannot throw the pad 5 cm: the step diverged. A full contact
                # arena drops contacts, so that step's forces are wrong as well.
                status = UNSTABLE
                break
            if s_sum > 0:
                # The vertical share of the taxels' normal force sets the push: at rest S = 2 N.
                force_cmd = min(target, target * fz / s_sum)
                d.ctrl[0] = -force_cmd
            housing_holds = h_sum > h_tol and s_sum < target * (1 - c.settle_tolerance)
            idle = idle + 1 if housing_holds and s_sum == 0 else 0
            if abs(v) < c.settle_speed:
                if s_sum > 0 and abs(s_sum - target) <= c.settle_tolerance * target:
                    status = SETTLED
                    break
                if housing_holds:
                    status = BLOCKED
                    break
            if (
                idle >= 3
            ):  # the housing holds the pad and the face feels nothing: no image to wait for
                status = BLOCKED
                break
        if status == UNSTABLE:
            return np.zeros((self.sensor.taxels,) * 2), 0.0, math.nan, steps, status
        pressure, total = self._read(m, d)
        return pressure, total, float(d.qpos[0]), steps, status

    def _step_one_contact_per_taxel(self, m: mujoco.MjModel, d: mujoco.MjData, obj: int) -> None:
        """One ``mj_step`` in which each taxel keeps only its deepest contact
        (:meth:`_one_contact_per_taxel` between collision and dynamics)."""
        mujoco.mj_step1(m, d)
        self._one_contact_per_taxel(m, d, obj)
        mujoco.mj_step2(m, d)

    def _one_contact_per_taxel(self, m: mujoco.MjModel, d: mujoco.MjData, obj: int) -> bool:
        """Exclude every contact of a taxel but its deepest, and make the constraints again.

        A height field is a mesh of triangle prisms, and MuJoCo collides a sphere with each prism
        it reaches: a taxel resting near a vertex gets up to a dozen contacts, each a full spring,
        so it would be many times stiffer than its neighbours. The others are marked as MuJoCo
        marks contacts in the margin gap (``exclude = 1``) and lose their constraint address, so
        neither the solver nor the sensors count them. With the ``foam`` taxel model the kept
        contact is then set to the cell's foam (:meth:`_foam_contacts`). Returns whether any
        contact was changed; call after the position stage (``mj_step1``, ``mj_fwdPosition``).
        """
        ncon = d.ncon
        if ncon < (1 if self._foam else 2):
            return False
        con = d.contact
        geoms = con.geom[:ncon]
        tax = np.maximum(self._geom_taxel[geoms[:, 0]], self._geom_taxel[geoms[:, 1]])
        sel = np.flatnonzero(tax >= 0)
        if len(sel) < (1 if self._foam else 2):
            return False
        order = sel[np.lexsort((con.dist[sel], tax[sel]))]
        first = np.ones(len(order), dtype=bool)
        first[1:] = tax[order[1:]] != tax[order[:-1]]
        drop = order[~first]
        if self._foam:
            keep = order[first]
            depth = self._cell_compression(d, obj, tax[keep])
            # The spring acts on dist - includemargin: set it to minus the mean compression, so
            # the contact pushes with contact_stiffness times the cell's mean compression.
            margin = con.includemargin[:ncon].copy()
            margin[keep] = con.dist[keep] + depth
            con.includemargin[:ncon] = margin
            drop = np.concatenate([drop, keep[depth <= 0]])
        elif not len(drop):
            return False
        exclude = con.exclude[:ncon].copy()
        exclude[drop] = 1
        con.exclude[:ncon] = exclude
        mujoco.mj_makeConstraint(m, d)
        # The sensors read every contact with an address: clear the dropped ones'.
        address = con.efc_address[:ncon].copy()
        address[drop] = -1
        con.efc_address[:ncon] = address
        mujoco.mj_island(m, d)
        mujoco.mj_projectConstraint(m, d)
        mujoco.mj_fwdVelocity(m, d)
        return True

    def _cell_compression(self, d: mujoco.MjData, obj: int, taxels: np.ndarray) -> np.ndarray:
        """Mean vertical compression (m) of the foam over each of ``taxels``' cells: the object's
        surface above the face at the cell's ``foam_points`` x ``foam_points`` points, 0 where
        below (the fast model's foam, :mod:`ham.world.extended_glance`)."""
        rot = d.xmat[self._pad].reshape(3, 3)
        w = self._cell_points[taxels] @ rot.T + d.xpos[self._pad]
        surf = self.objects[obj].surface(w[..., 0] - self._x_offsets[obj], w[..., 1])
        return np.maximum(surf - w[..., 2], 0.0).mean(-1)

    def _read(self, m: mujoco.MjModel, d: mujoco.MjData) -> tuple[np.ndarray, float]:
        """The image (Pa) from the last step's contacts, and their summed normal force (N)."""
        n = self.sensor.taxels
        ncon = d.ncon
        if ncon == 0:
            return np.zeros((n, n)), 0.0
        con = d.contact
        geoms = con.geom[:ncon]
        adr = con.efc_address[:ncon]
        tax = np.maximum(self._geom_taxel[geoms[:, 0]], self._geom_taxel[geoms[:, 1]])
        # Contacts excluded from the constraints (one per taxel on height fields) carry no force.
        sel = (tax >= 0) & (adr >= 0) & (con.exclude[:ncon] == 0)
        if not sel.any():
            return np.zeros((n, n)), 0.0
        fn = d.efc_force[adr[sel]]
        total = float(fn.sum())
        area = self.sensor.taxel_area
        if self.config.readout == "taxels":
            img = np.bincount(tax[sel], weights=fn, minlength=n * n).reshape(n, n) / area
            return img, total
        # Gazebo plugin: each contact's normal force spread by a Gaussian around its point.
        rel = con.pos[:ncon][sel] - d.xpos[self._pad]
        rot = d.xmat[self._pad].reshape(3, 3)
        u = rel @ rot[:, 0]
        y = rel @ rot[:, 1]
        sig2 = self.config.gazebo_sigma**2
        du = self._taxel_u[None] - u[:, None, None]
        dy = self._taxel_y[None] - y[:, None, None]
        g = np.exp(-(du * du + dy * dy) / (2 * sig2)) / (2 * math.pi * sig2)
        return np.tensordot(fn, g, axes=1), total

    def settled_scene(
        self,
        object_id: int,
        q_x: float,
        q_phi: float,
        q_y: float | None = None,
        q_phi_y: float | None = None,
    ):
        """One glance on a private model copy; returns ``(model, data, result)`` at its end.

        For drawing the scene (``ham render``) or inspecting contacts; the batch workers are untouched.
        """
        extra = () if q_y is None and q_phi_y is None else ([q_y or 0.0], [q_phi_y or 0.0])
        res = self.glance([object_id], [q_x], [q_phi], *extra)  # validates the input
        m = copy.copy(self.model)
        d = mujoco.MjData(m)
        x, phi = float(res.x[0]), float(res.phi[0])
        y, phi_y = float(res.y[0]), float(res.phi_y[0])
        general = self.objects[int(object_id)].varies_in_y or phi_y != 0
        z0 = math.nan
        if not general:
            z0 = float(self.first_touch(np.array([object_id]), np.array([x]), np.array([phi]))[0])
            z0 += self.config.clearance
        self._glance_one(m, d, int(object_id), x, phi, z0, y=y, phi_y=phi_y, general=general)
        mujoco.mj_forward(m, d)
        thin = self._foam or (self.objects[int(object_id)].varies_in_y and self._thin_taxels)
        if thin and self._one_contact_per_taxel(m, d, int(object_id)):
            mujoco.mj_fwdActuation(m, d)
            mujoco.mj_fwdAcceleration(m, d)
            mujoco.mj_fwdConstraint(m, d)
            mujoco.mj_sensorAcc(m, d)
        return m, d, res

    # ------------------------------------------------------------------ description
    def describe(self) -> dict:
        c = self.config
        mj = c.to_dict()
        if not self._fields:
            # Only height fields use it: worlds of the paper's objects describe themselves (and
            # their tables' attributes) as before.
            del mj["hfield_spacing"], mj["hfield_contacts"]
        if c.taxel_model == "sphere":
            # The default taxel describes itself (and its tables' attributes) as before.
            del mj["taxel_model"], mj["foam_points"]
        return {
            "simulator": self.name,
            "engine": f"mujoco {mujoco.__version__}",
            "objects": [o.name for o in self.objects],
            "sensor": self.sensor.to_dict(),
            "pose": asdict(self.pose),
            "glance": asdict(self.glance_config),
            "mujoco": mj,
            "taxel_solref": list(c.taxel_solref()),
            "taxel_solimp": list(c.taxel_solimp()),
            "threads": self._threads,
        }

    def scene_xml(self) -> str:
        """The MJCF of this simulator's scene (for inspection or other MuJoCo tools)."""
        return scene_xml(self.objects, self.sensor, self.config)


# --------------------------------------------------------------------------- calibration
def calibrate_foam_stiffness(
    config: MujocoConfig | None = None, sensor: SensorConfig | None = None
) -> dict:
    """The fast model's ``foam_stiffness`` that presses the flat box as deep as MuJoCo does.

    Runs one MuJoCo glance on the box at its centre, flat (``q = (0, 0)``), measures the depth of
    the face below the box top (float64, settled to 1e-9 m/s), and returns ``F / (64 cm^2 * depth)``: the fast model's
    flat-face compression is ``F / (foam_stiffness * area)`` (section "The Tactile Sensor Array").
    """
    from ham.world.objects import get

    # Settle far tighter than a table glance: the depth is micrometres.
    config = replace(
        config or MujocoConfig(),
        readout="taxels",
        threads=1,
        settle_speed=1e-9,
        settle_tolerance=1e-6,
        max_steps=4000,
    )
    sensor = sensor or SensorConfig()
    box = get("box")
    sim = MujocoSimulator([box], sensor, config=config)
    sim._ensure_workers()
    w = sim._workers[0]
    z0 = (
        float(sim.first_touch(np.array([0]), np.array([0.0]), np.array([0.0]))[0])
        + config.clearance
    )
    _, force, z, steps, status = sim._glance_one(w.model, w.data, 0, 0.0, 0.0, z0)
    depth = box.height - z
    area = sensor.size**2
    return {
        "depth_m": depth,
        "force_N": force,
        "steps": steps,
        "status": STATUS_NAMES[status],
        "contact_stiffness_N_per_m": config.contact_stiffness,
        "foam_stiffness": force / (area * depth) if depth > 0 else math.nan,
    }


# --------------------------------------------------------------------------- cross-check
def image_correlation(a: torch.Tensor | np.ndarray, b: torch.Tensor | np.ndarray) -> np.ndarray:
    """Pearson correlation of each pair of images ``(B, 16, 16)``.

    A uniform image (a flat contact: spread below 1e-6 of its size) has no pattern to correlate:
    two uniform images count as 1 (the same pattern), a uniform against a patterned one as 0.
    """
    a = np.asarray(a, dtype=np.float64).reshape(len(a), -1)
    b = np.asarray(b, dtype=np.float64).reshape(len(b), -1)
    ca = a - a.mean(1, keepdims=True)
    cb = b - b.mean(1, keepdims=True)
    na, nb = np.linalg.norm(ca, axis=1), np.linalg.norm(cb, axis=1)
    flat_a = na <= 1e-6 * np.linalg.norm(a, axis=1)
    flat_b = nb <= 1e-6 * np.linalg.norm(b, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = (ca * cb).sum(1) / (na * nb)
    return np.where(flat_a & flat_b, 1.0, np.where(flat_a | flat_b, 0.0, r))


def contact_centroid(pressure: torch.Tensor | np.ndarray) -> np.ndarray:
    """Force-weighted mean column (in taxels, 0..15) of each image ``(B, 16, 16)``; NaN if empty.

    Where an edge lies within a millimetre of a cell border, two models (or one model at two read-out
    resolutions) may put its line in neighbouring columns: the correlation of the two images then
    drops towards 0 although the contact is in the same place to within one taxel. The centroid
    distance tells the two apart (docs/crosscheck.md, "How fine is either model?").
    """
    p = np.asarray(pressure, dtype=np.float64)
    cols = p.reshape(len(p), -1, p.shape[-1]).sum(1)
    total = cols.sum(1)
    j = np.arange(cols.shape[1], dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(total > 0, (cols * j).sum(1) / total, np.nan)
