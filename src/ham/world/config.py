"""The haptic world: a set of objects, the Myrmex pad, the pose mapping and a simulator.

``WorldConfig`` is the one config object for everything a glance depends on; it is saved beside
every table and run. ``make_simulator`` builds the simulator it names:

* ``fast``: the vectorized foam-contact model (:class:`ham.world.glance.FastSimulator`), CPU or CUDA;
* ``mujoco``: the MuJoCo physics engine (:mod:`ham.world.mujoco_sim`), when installed.

Third parties add a simulator with :func:`register_simulator`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field

from ham.errors import HamError
from ham.world import objects as _objects
from ham.world.glance import FastSimulator, GlanceConfig, PoseConfig, Simulator
from ham.world.objects import HapticObject
from ham.world.sensor import SensorConfig


@dataclass(frozen=True)
class WorldConfig:
    """Objects, sensor, pose mapping, glance rule and simulator (paper defaults).

    ``mujoco`` holds :class:`ham.world.mujoco_sim.MujocoConfig` overrides (e.g. ``{"readout": "gazebo"}``)
    for the MuJoCo simulator; the fast simulator ignores it.

    ``objects_file`` records the user's objects file (``--objects-file``) as
    ``{"name", "sha256", "source"}`` (:func:`ham.world.objects.read_objects_file`): a world loaded
    from a table or run (:meth:`from_dict`) and a world resolved in any process
    (:meth:`resolve_objects`) registers the same objects from the recorded text, hash verified.
    """

    objects: str = "paper"
    simulator: str = "fast"
    sensor: SensorConfig = field(default_factory=SensorConfig)
    pose: PoseConfig = field(default_factory=PoseConfig)
    glance: GlanceConfig = field(default_factory=GlanceConfig)
    mujoco: dict = field(default_factory=dict)
    objects_file: dict | None = None

    def __post_init__(self) -> None:
        if self.objects_file is not None:
            _objects.check_record(self.objects_file)

    def register_objects(self) -> list[str]:
        """Register the recorded objects file's objects (once per process); their names."""
        if self.objects_file is None:
            return []
        return _objects.load_objects(self.objects_file)

    def resolve_objects(self) -> list[HapticObject]:
        # A world may arrive pickled in a fresh worker process: register before resolving.
        self.register_objects()
        return _objects.resolve_set(self.objects)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> WorldConfig:
        """The world saved by :meth:`to_dict`; registers its recorded objects file's objects."""
        try:
            world = cls(
                objects=d.get("objects", "paper"),
                simulator=d.get("simulator", "fast"),
                sensor=SensorConfig(**d.get("sensor", {})),
                pose=PoseConfig(**d.get("pose", {})),
                glance=GlanceConfig(**d.get("glance", {})),
                mujoco=dict(d.get("mujoco", {})),
                objects_file=d.get("objects_file"),
            )
        except TypeError as exc:
            raise HamError(f"world config has an unknown field: {exc}") from None
        world.register_objects()
        return world


SimulatorFactory = Callable[..., Simulator]
_SIMULATORS: dict[str, SimulatorFactory] = {}


def register_simulator(name: str, factory: SimulatorFactory) -> None:
    """Make ``factory(objects, sensor, pose, glance, device=...)`` available under ``name``."""
    _SIMULATORS[name] = factory


def simulator_names() -> list[str]:
    return ["fast", "mujoco", *[n for n in _SIMULATORS if n not in ("fast", "mujoco")]]


def make_simulator(
    config: WorldConfig | None = None, *, device: str = "cpu", **kwargs
) -> Simulator:
    """The simulator ``config.simulator`` over ``config``'s objects."""
    config = config or WorldConfig()
    objs = config.resolve_objects()
    name = config.simulator
    if name == "fast":
        return FastSimulator(
            objs, config.sensor, config.pose, config.glance, device=device, **kwargs
        )
    if name == "mujoco" and name not in _SIMULATORS:
        try:
            from ham.world.mujoco_sim import MujocoSimulator
        except ImportError as exc:  # pragma: no cover - depends on the installation
            raise HamError(f"simulator 'mujoco' is not available: {exc}") from None
        return MujocoSimulator(
            objs, config.sensor, config.pose, config.glance, **{**config.mujoco, **kwargs}
        )
    if name in _SIMULATORS:
        return _SIMULATORS[name](
            objs, config.sensor, config.pose, config.glance, device=device, **kwargs
        )
    raise HamError(f"unknown simulator {name!r}; accepted: {', '.join(simulator_names())}")
