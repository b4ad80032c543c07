"""The haptic world: a set of objects, the Myrmex pad, the pose mapping and a simulator.

``WorldConfig`` is the one config object for everything a glance depends on; it is saved beside
every table and run. ``make_simulator`` builds the simulator it names:

* ``fast``: the vectorized foam-contact model, CPU or CUDA: the paper's line glance
  (:class:`ham.world.glance.FastSimulator`), or the extended glance on height fields
  (:class:`ham.world.extended_glance.ExtendedSimulator`) when ``pose_dims`` has ``y`` or
  ``phi_y`` or an object varies in y;
* ``mujoco``: the MuJoCo physics engine (:mod:`ham.world.mujoco_sim`), when installed;
* a simulator of your own (:mod:`ham.world.simulators`): registered by a program with
  :func:`register_simulator`, or by a simulator file (``--simulator-file FILE.py``) that the
  world records (``simulator_file``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

from ham.errors import HamError, check_known_fields, check_types
from ham.world import objects as _objects
from ham.world import simulators as _simulators
from ham.world.extended_glance import ExtendedSimulator
from ham.world.glance import (
    PAPER_POSE_DIMS,
    FastSimulator,
    GlanceConfig,
    PoseConfig,
    Simulator,
    check_pose_dims,
)
from ham.world.objects import HapticObject
from ham.world.sensor import MAX_FOAM_STIFFNESS, MAX_PRESSURE, SensorConfig
from ham.world.simulators import register_simulator, simulator_names

__all__ = ["WorldConfig", "make_simulator", "register_simulator", "simulator_names"]


@dataclass(frozen=True)
class WorldConfig:
    """Objects, sensor, pose mapping, glance rule and simulator (paper defaults).

    ``mujoco`` holds :class:`ham.world.mujoco_sim.MujocoConfig` overrides (e.g. ``{"readout": "gazebo"}``)
    for the MuJoCo simulator; the fast simulator ignores it.

    ``pose_dims`` are the pose dimensions the agent controls, a subset of
    :data:`ham.world.glance.POSE_DIMS` in canonical order (``x, y, phi, phi_y``); the paper's
    ``("x", "phi")`` by default. Dimensions not enabled are 0 (pose centre, no tilt). :meth:`to_dict`
    leaves the default out, so the paper's world saves the same dict as before the extended glance.

    ``objects_file`` records the user's objects file (``--objects-file``) as
    ``{"name", "sha256", "source"}`` (:func:`ham.world.objects.read_objects_file`): a world loaded
    from a table or run (:meth:`from_dict`) and a world resolved in any process
    (:meth:`resolve_objects`) registers the same objects from the recorded text, hash verified.

    ``simulator_file`` records a simulator file (``--simulator-file``,
    :func:`ham.world.simulators.read_simulator_file`) in the same way; ``simulator`` must name one
    of the simulators it registers. :meth:`to_dict` leaves it out when there is none.
    """

    objects: str = "paper"
    simulator: str = "fast"
    sensor: SensorConfig = field(default_factory=SensorConfig)
    pose: PoseConfig = field(default_factory=PoseConfig)
    glance: GlanceConfig = field(default_factory=GlanceConfig)
    mujoco: dict = field(default_factory=dict)
    objects_file: dict | None = None
    pose_dims: tuple[str, ...] = PAPER_POSE_DIMS
    simulator_file: dict | None = None

    def register_objects(self) -> list[str]:
        """Register the recorded objects file's objects (once per process); their names."""
        if self.objects_file is None:
            return []
        return _objects.load_objects(self.objects_file)

    def register_simulators(self) -> list[str]:
        """Register the recorded simulator file's simulators (once per process); their names."""
        if self.simulator_file is None:
            return []
        return _simulators.load_simulator_file(self.simulator_file)

    def __post_init__(self) -> None:
        check_types(self)
        if self.objects_file is not None:
            _objects.check_record(self.objects_file)
        if self.simulator_file is not None:
            _simulators.file_simulator(
                self.simulator_file, self.simulator, "world simulator", "simulator file"
            )
        object.__setattr__(self, "pose_dims", check_pose_dims(self.pose_dims, "world pose_dims"))
        # The foam must carry the glance's stop force on the whole face before it is compressed
        # through: softer, and even the flat box blocks the pad with no 2 N reading.
        s, need = self.sensor, self.glance.force_threshold
        volume = s.foam_thickness * s.size**2  # 0.0 for a pad of 1e-300 m: none carries it
        lowest = need / volume if volume > 0 else math.inf
        if s.foam_stiffness < lowest:
            least_size = (need / (s.foam_thickness * s.foam_stiffness)) ** 0.5
            # no stiffness can help a pad that needs more than the most we accept: name only size
            stiffer = (
                f", or foam_stiffness in {lowest:.3g} .. {MAX_FOAM_STIFFNESS:g} Pa/m"
                if lowest <= MAX_FOAM_STIFFNESS
                else ""
            )
            raise HamError(
                f"foam_stiffness = {s.foam_stiffness:g} Pa/m: the pad ({s.describe()}) is too "
                f"small to carry {need:g} N on its {s.foam_thickness * 1000:g} mm foam; accepted: "
                f"taxels * pitch > {least_size:.4g} m{stiffer}"
            )
        # the stop force on a single taxel (an edge or a point pressed by one cell) is the most
        # pressure a read-out of contact forces (MuJoCo's) may give: beyond MAX_PRESSURE an
        # image's norm overflows float32
        if need / s.pitch**2 > MAX_PRESSURE:
            raise HamError(
                f"force_threshold = {need:g} N on one {s.pitch * 1000:g} mm taxel presses "
                f"{need / s.pitch**2:.3g} Pa; accepted: at most {MAX_PRESSURE:g} Pa "
                f"(force_threshold <= {MAX_PRESSURE * s.pitch**2:.3g} N)"
            )

    def resolve_objects(self) -> list[HapticObject]:
        # A world may arrive pickled in a fresh worker process: register before resolving.
        self.register_objects()
        return _objects.resolve_set(self.objects)

    @property
    def extended(self) -> bool:
        """Whether glances need the extended glance: y or phi_y enabled, or a height field."""
        if {"y", "phi_y"} & set(self.pose_dims):
            return True
        return any(o.varies_in_y for o in self.resolve_objects())

    def to_dict(self) -> dict:
        d = asdict(self)
        d["pose_dims"] = list(self.pose_dims)
        if self.pose_dims == PAPER_POSE_DIMS:  # the paper's world: the dict saved before
            del d["pose_dims"]
        if self.simulator_file is None:  # likewise: the dict saved before simulator files
            del d["simulator_file"]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> WorldConfig:
        """The world saved by :meth:`to_dict`; unknown keys and wrong types are refused by name;
        registers its recorded objects file's objects."""
        check_known_fields(cls, d, "world")
        parts = {}
        for name, kind in (
            ("sensor", SensorConfig),
            ("pose", PoseConfig),
            ("glance", GlanceConfig),
        ):
            sub = d.get(name, {})
            check_known_fields(kind, sub, f"world {name}")
            try:
                parts[name] = kind(**sub)
            except TypeError as exc:  # e.g. a string where a number belongs
                raise HamError(f"world {name} {sub!r}: {exc}") from None
        mujoco = d.get("mujoco", {})
        if not isinstance(mujoco, dict):
            raise HamError(f"world mujoco = {mujoco!r}; accepted: a dict of MujocoConfig fields")
        world = cls(
            objects=d.get("objects", "paper"),
            simulator=d.get("simulator", "fast"),
            mujoco=dict(mujoco),
            objects_file=d.get("objects_file"),
            pose_dims=d.get("pose_dims", PAPER_POSE_DIMS),
            simulator_file=d.get("simulator_file"),
            **parts,
        )
        world.register_objects()
        return world


def world_differences(a: dict, b: dict) -> list[str]:
    """How world ``b`` differs from world ``a`` (two :meth:`WorldConfig.to_dict` dicts, e.g. two
    glance tables' ``world``), one ``"key: A -> B"`` a differing field, nested fields dotted
    (``sensor.spread_sigma: None -> 0.005``); a field only one has counts as ``None`` in the
    other (an empty dict has no fields: ``mujoco = {}`` against ``{"readout": "gazebo"}`` is
    ``mujoco.readout: None -> 'gazebo'``)."""

    def flat(d: dict, prefix: str = "") -> dict:
        out = {}
        for k, v in d.items():
            if isinstance(v, dict):
                out.update(flat(v, f"{prefix}{k}."))
            else:
                out[f"{prefix}{k}"] = v
        return out

    fa, fb = flat(a), flat(b)
    return [f"{k}: {fa.get(k)!r} -> {fb.get(k)!r}" for k in sorted(fa.keys() | fb.keys())
            if fa.get(k) != fb.get(k)]  # fmt: skip


def make_simulator(
    config: WorldConfig | None = None, *, device: str = "cpu", **kwargs
) -> Simulator:
    """The simulator ``config.simulator`` over ``config``'s objects.

    ``fast`` is the paper's line glance, or the extended glance when ``config.extended``
    (``pose_dims`` with y or phi_y, or an object that varies in y). A registered simulator (its
    simulator file registered first, in any process) has its glances checked
    (:class:`ham.world.simulators.CheckedSimulator`).
    """
    config = config or WorldConfig()
    objs = config.resolve_objects()
    config.register_simulators()  # a world may arrive pickled in a fresh worker process
    name = config.simulator
    if name == "fast" and config.extended:
        return ExtendedSimulator(
            objs, config.sensor, config.pose, config.glance, device=device, **kwargs
        )
    if name == "fast":
        return FastSimulator(
            objs, config.sensor, config.pose, config.glance, device=device, **kwargs
        )
    if name == "mujoco":
        try:
            from ham.world.mujoco_sim import MujocoSimulator
        except ImportError as exc:  # pragma: no cover - depends on the installation
            raise HamError(f"simulator 'mujoco' is not available: {exc}") from None
        return MujocoSimulator(
            objs, config.sensor, config.pose, config.glance, **{**config.mujoco, **kwargs}
        )
    return _simulators.make_registered(
        name, objs, config.sensor, config.pose, config.glance, world=config, device=device, **kwargs
    )


# ------------------------------------------------------------------------------------------------
# World presets: named worlds as data (docs/world.md, "World presets"). A preset is a WorldConfig
# table (``pose`` may name a PoseConfig preset), the glance table's grid and the evaluation the
# setting calls for. Explicit options override a preset's fields (``--world P --sensor taxels``).

#: The presets ``--world`` knows; one definition, read by the CLI, grids and reproduce.
WORLD_PRESETS: dict[str, dict] = {
    "paper-gazebo": {
        "description": "the paper's world as its Gazebo plugin saw it: MuJoCo contacts read out "
        "as a few points spread by a 5 mm Gaussian, the authors' pose mapping (phi = q * 0.3 pi, "
        "pivot shift) and exploration zones, a 201 x 201 glance table, evaluated with sampled "
        "poses (the paper: 'using the currently available policy')",
        "world": {"simulator": "mujoco", "mujoco": {"readout": "gazebo"}, "pose": "authors"},
        "grid": 201,
        "eval_policy": "sample",
    },
}


def world_preset(name: str) -> dict:
    """The preset ``name`` (a copy): ``description``, ``world``, ``grid``, ``eval_policy``."""
    import copy

    if name not in WORLD_PRESETS:
        raise HamError(f"world preset {name!r}; accepted: {', '.join(WORLD_PRESETS)}")
    return copy.deepcopy(WORLD_PRESETS[name])


def world_from_table(d: dict) -> WorldConfig:
    """A world from a table of WorldConfig fields that may name a ``preset`` (its world is the
    start; the table's other fields replace the preset's) and a pose preset (``pose = "authors"``).
    """
    if not isinstance(d, dict):
        raise HamError(f"world = {d!r}; accepted: a table of WorldConfig fields (and preset)")
    d = dict(d)
    name = d.pop("preset", None)
    base = world_preset(name)["world"] if name is not None else {}
    merged = {**base, **d}
    if isinstance(merged.get("pose"), str):
        merged["pose"] = asdict(PoseConfig.preset(merged["pose"]))
    return WorldConfig.from_dict(merged)
