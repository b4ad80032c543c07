"""The simulators a world may name: ``fast``, ``mujoco``, and your own (``--simulator-file``).

A simulator of your own is a factory ``factory(objects, sensor, pose, glance, device=...)`` (and
``world=...``, the WorldConfig, when it has that parameter) that returns a
:class:`ham.world.glance.Simulator` (``name``, ``objects``, ``glance``, ``describe``);
:func:`register_simulator` makes it available under a name. From the command line, a
*simulator file* (a self-contained ``.py`` file that calls ``register_simulator``) is given with
``--simulator-file FILE.py``: a world keeps the file's record (name, sha256, text:
:attr:`ham.world.config.WorldConfig.simulator_file`), so a table built with it, a run trained
online with it and a grid's worker processes run the same code wherever they load the world.

This is the way to a sensor of your own: a simulator that wraps the fast one and reads its
contacts out otherwise (docs/plugins/binary_pad.py: taxels that only say touched or not).

Every glance of a registered simulator is checked (:class:`CheckedSimulator`): the result must be
a :class:`ham.world.glance.GlanceResult` with one ``N x N`` image per glance (``N`` the pad's
taxels) of pressures in ``[0, MAX_PRESSURE]`` Pa, one finite number per glance in ``force``,
``z``, ``height`` and the pose fields (``z`` and ``height`` within the pad's reach of the
objects' tops, :func:`ham.world.glance.height_bound`), and 0/1 ``contact`` and ``blocked``; real tensors on the
CPU or a GPU of any dtype, taken as the built-in simulators give them (float32, bool, detached).
Any failure of the user's code is one line naming the file and its line.
"""

from __future__ import annotations

import inspect
import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import torch

from ham.errors import HamError, check_new_name, checked_arguments
from ham.world import recorded_file, registering
from ham.world.glance import GlanceResult, height_bound
from ham.world.sensor import MAX_PRESSURE

#: The simulators of the package itself; no file or program may register these names.
BUILT_IN: tuple[str, ...] = ("fast", "mujoco")
SUFFIXES: tuple[str, ...] = (".py",)

SimulatorFactory = Callable[..., object]
_SIMULATORS: dict[str, SimulatorFactory] = {}
#: name -> the simulator file that registered it (absent: registered by a program)
_ORIGIN: dict[str, str] = {}
#: sha256 of a simulator file -> the names it registered: a process runs each file once.
_LOADED: dict[str, tuple[str, ...]] = {}
#: while a simulator file runs: its name (recorded as the origin of what it registers)
_LOADING: list[str] = []


@checked_arguments
def register_simulator(name: str, factory: SimulatorFactory) -> None:
    """Make ``factory(objects, sensor, pose, glance, device=..., **kwargs)`` the simulator ``name``.

    The factory returns an object with ``name``, ``objects``, ``glance(object_ids, q_x, q_phi,
    q_y=None, q_phi_y=None)`` -> :class:`ham.world.glance.GlanceResult` and ``describe()`` ->
    dict. Names are letters, digits and ``_ . -``; ``fast``, ``mujoco`` and names registered
    already are refused.
    """
    check_new_name("simulator", name, (*BUILT_IN, *_SIMULATORS))
    if not callable(factory):
        raise HamError(
            f"simulator {name!r}: factory {factory!r}; accepted: a callable "
            "factory(objects, sensor, pose, glance, device=...) returning a simulator"
        )
    _SIMULATORS[name] = factory
    if _LOADING:
        _ORIGIN[name] = _LOADING[-1]


def simulator_names() -> list[str]:
    """``fast``, ``mujoco`` and the registered simulators, in registration order."""
    return [*BUILT_IN, *_SIMULATORS]


def unknown_simulator(name: object) -> HamError:
    """The error for a simulator name nothing registered."""
    return HamError(
        f"unknown simulator {name!r}; accepted: {', '.join(simulator_names())}, or a simulator "
        "of your own registered by a simulator file (--simulator-file FILE.py, "
        "WorldConfig(simulator_file=ham.world.simulators.read_simulator_file(FILE)))"
    )


# ------------------------------------------------------------------------------------------------
def read_simulator_file(path: str | Path) -> dict:
    """The record of the simulator file ``path``: ``{"name", "sha256", "source"}`` (nothing runs)."""
    return recorded_file.read_record(
        path,
        "simulator file",
        SUFFIXES,
        "a .py file that calls ham.world.simulators.register_simulator",
    )


def check_record(record: object) -> dict:
    """``record`` if it is a complete simulator-file record whose text has its sha256, else an error."""
    return recorded_file.check_record(record, "simulator file", "simulator_file", SUFFIXES)


def load_simulator_file(record: dict) -> list[str]:
    """Run the simulator file of ``record`` (verified) once per process; the names it registered.

    A file that fails, registers no simulator, or registers objects (they belong in an objects
    file, which a world records) leaves the registries as they were.
    """
    record = check_record(record)
    name, sha = record["name"], record["sha256"]
    if sha in _LOADED:
        return list(_LOADED[sha])
    _LOADING.append(name)
    try:
        added = registering.run_registering(
            "simulator file", record, "ham_simulator_file", {"simulator": _SIMULATORS},
            "no simulator", "a file that calls ham.world.simulators.register_simulator(NAME, factory)",
        )["simulator"]  # fmt: skip
    finally:
        _LOADING.pop()
        for n in [n for n in _ORIGIN if n not in _SIMULATORS]:  # rolled back
            del _ORIGIN[n]
    _LOADED[sha] = tuple(added)
    return list(added)


def file_simulator(record: dict, name: str | None, setting: str, file_setting: str) -> str:
    """The simulator a world with the simulator file ``record`` glances with: ``name`` when the
    file registers it; no ``name``, the file's one simulator. A HamError otherwise, in the words
    of the caller's settings (``setting``: ``--simulator``; ``file_setting``: ``--simulator-file``)
    — a file nothing uses is refused, not ignored."""
    names = load_simulator_file(record)
    where = f"{file_setting} {record['name']!r}"
    if name is None and len(names) > 1:
        raise HamError(
            f"{where} registers {', '.join(names)}; accepted: {setting} naming one of them"
        )
    if name is not None and name not in names:
        raise HamError(
            f"{setting} {name!r} is not one {where} registers; accepted: "
            f"{' or '.join(repr(n) for n in names)} (or no {file_setting})"
        )
    return name or names[0]


def make_registered(
    name: str, objects: list, sensor, pose, glance, world=None, **kwargs
) -> CheckedSimulator:
    """The registered simulator ``name`` over ``objects``, its glances checked. A factory with a
    parameter ``world`` is given the :class:`ham.world.config.WorldConfig` too (its pose dims,
    its other fields: e.g. to build the built-in glance of that world and read it out anew)."""
    factory = _SIMULATORS.get(name)
    if factory is None:
        raise unknown_simulator(name)
    what, where = _who(name)
    if world is not None and _takes_world(factory):
        kwargs["world"] = world
    sim = recorded_file.call(what, where, factory, list(objects), sensor, pose, glance, **kwargs)
    return CheckedSimulator(sim, name, sensor)


def _takes_world(factory) -> bool:
    try:
        return "world" in inspect.signature(factory).parameters
    except (TypeError, ValueError):  # a callable without a signature (a builtin)
        return False


def _who(name: str) -> tuple[str, str]:
    """How errors name the code of simulator ``name``: its file, or the simulator itself."""
    if name in _ORIGIN:
        return "simulator file", _ORIGIN[name]
    return "simulator", name


_REPEATED_GLANCES = 8  # how many of a simulator's first glances are glanced again
#: The tensors of a GlanceResult that a registered simulator's glance is checked for.
_RESULT_FIELDS = ("pressure", "force", "z", "contact", "blocked", "x", "phi", "y", "phi_y",
                  "height")  # fmt: skip
_FLAGS = ("contact", "blocked")
#: fields that are heights above the table (m), bounded by :func:`ham.world.glance.height_bound`
_HEIGHTS = ("z", "height")


def _close(a: torch.Tensor, b: torch.Tensor, scale: float | None = None) -> bool:
    """Equal up to float noise of another batch size (1e-5 of the largest value, ``scale``)."""
    a, b = a.detach().cpu().double(), b.detach().cpu().double()
    if scale is None:
        scale = float(a.abs().max()) if a.numel() else 0.0
    return bool(torch.allclose(a, b, rtol=1e-5, atol=max(1e-5 * scale, 1e-12)))


def _head(v, k: int, n: int):
    """The first ``k`` of the ``n`` rows of a glance argument: a tensor, array or list of one
    value per glance is cut; a tuple of them (``object_pose`` ``(yaw, dx, dy)``) is cut in each
    part; a number, a value for all glances or ``None`` stays as it is."""
    if isinstance(v, (tuple, list)) and any(isinstance(x, (torch.Tensor, tuple, list)) for x in v):
        return type(v)(_head(x, k, n) for x in v)
    if getattr(v, "ndim", 1) and hasattr(v, "__len__") and len(v) == n:
        return v[:k]
    return v


def _first_off(a: torch.Tensor, b: torch.Tensor) -> int:
    """The first batch row in which ``a`` and ``b`` are not :func:`_close` (for the message)."""
    scale = float(a.detach().abs().max()) if a.numel() else 0.0
    return next((i for i in range(len(a)) if not _close(a[i], b[i], scale)), 0)


class CheckedSimulator:
    """A registered simulator whose every glance is checked, failures in one line.

    ``name`` is the registered name; ``sensor`` the world's pad (the images are ``N x N``,
    ``N = sensor.taxels``); ``inner`` the factory's simulator.
    """

    def __init__(self, inner, name: str, sensor) -> None:
        what, where = _who(name)
        for attr in ("glance", "describe"):
            if not callable(getattr(inner, attr, None)):
                raise HamError(
                    f"{what} {where!r}: simulator {name!r} made a {type(inner).__name__} without "
                    f"a {attr}() method; accepted: an object with glance() and describe()"
                )
        if not isinstance(getattr(inner, "objects", None), list):
            raise HamError(
                f"{what} {where!r}: simulator {name!r} has no list of objects (its .objects); "
                "accepted: the objects the factory was given"
            )
        self.inner, self.name, self.sensor = inner, name, sensor
        self.objects = inner.objects
        self._what, self._where = what, where
        self._repeated = False  # whether a glance was repeated to check determinism

    def _error(self, text: str) -> HamError:
        return HamError(f"{self._what} {self._where!r}: simulator {self.name!r} {text}")

    def glance(self, object_ids, q_x, q_phi, **kwargs):
        n = len(object_ids)
        r = recorded_file.call(
            self._what, self._where, self.inner.glance, object_ids, q_x, q_phi, **kwargs
        )
        if not isinstance(r, GlanceResult):
            raise self._error(f"returned a {type(r).__name__}; accepted: a GlanceResult")
        r = self._checked(r, n)
        if not self._repeated and n:
            self._repeated = True
            self._check_repeatable(r, object_ids, q_x, q_phi, kwargs)
        return r

    def _checked(self, r, n: int):
        """``r`` with every field checked (a tensor of the right shape, real and finite, on a
        real device; heights within :func:`ham.world.glance.height_bound`; ``contact`` and
        ``blocked`` 0/1) and in the built-in simulators' types:
        float32 numbers and bool flags, detached from any autograd graph."""
        side = self.sensor.taxels
        out = {}
        for field in _RESULT_FIELDS:
            v, shape = getattr(r, field), (n, side, side) if field == "pressure" else (n,)
            if not isinstance(v, torch.Tensor) or tuple(v.shape) != shape or v.is_meta:
                got = type(v).__name__ if not isinstance(v, torch.Tensor) else tuple(v.shape)
                where = " on the meta device (no data)" if getattr(v, "is_meta", False) else ""
                raise self._error(
                    f"returned {field} {got}{where} for {n} glances; accepted: a tensor {shape} "
                    "on the CPU or a GPU"
                )
            if v.is_complex():
                raise self._error(f"returned {field} of {v.dtype}; accepted: real numbers")
            v = v.detach()
            if field in _FLAGS:
                if v.dtype != torch.bool and bool(((v != 0) & (v != 1)).any()):
                    bad = v[(v != 0) & (v != 1)][0].item()
                    raise self._error(f"returned {field} {bad!r}; accepted: booleans (or 0 / 1)")
                out[field] = v.bool()
                continue
            v = v.float()
            if field == "pressure":
                # two reductions (NaN propagates into both), not masks over every taxel: the
                # images are most of a glance's data, and a mask cost as much as the glance
                if v.numel() and not (v.amin() >= 0 and v.amax() <= MAX_PRESSURE):
                    bad = v[~((v >= 0) & (v <= MAX_PRESSURE))][0].item()
                    raise self._error(
                        f"returned a pressure of {bad!r} Pa; accepted: finite values in "
                        f"[0, {MAX_PRESSURE:g}] Pa"
                    )
            elif field in _HEIGHTS:
                bound = height_bound(self.sensor)  # NaN fails the comparison too
                if v.numel() and not (v.abs().amax() <= bound):
                    bad = v[~(v.abs() <= bound)][0].item()
                    raise self._error(
                        f"returned {field} {bad!r} m; accepted: finite heights within "
                        f"{bound:.4g} m of the table (the tallest object's top plus the pad's size)"
                    )
            elif not bool(torch.isfinite(v).all()):
                bad = v[~torch.isfinite(v)][0].item()
                raise self._error(f"returned {field} {bad!r}; accepted: finite numbers")
            out[field] = v
        return replace(r, **out)

    def _check_repeatable(self, r, object_ids, q_x, q_phi, kwargs) -> None:
        """Glance the first few of the first batch again: the same object and pose must give
        the same glance, or a table built twice differs and a resumed online run glances
        otherwise than an uninterrupted one (noise must be a function of object and pose)."""
        n = len(object_ids)
        k = min(n, _REPEATED_GLANCES)
        again = recorded_file.call(
            self._what,
            self._where,
            self.inner.glance,
            *(_head(v, k, n) for v in (object_ids, q_x, q_phi)),
            **{key: _head(v, k, n) for key, v in kwargs.items()},
        )
        if isinstance(again, GlanceResult):
            again = self._checked(again, k)
        for field in ("pressure", "force", "z", "contact", "blocked"):
            a, b = getattr(r, field)[:k], getattr(again, field, None)
            if not isinstance(b, torch.Tensor) or b.shape != a.shape or not _close(a, b):
                i = 0 if not isinstance(b, torch.Tensor) or b.shape != a.shape else _first_off(a, b)
                obj = int(torch.as_tensor(object_ids)[i])
                pose = f"q_x = {float(q_x[i]):.4g}, q_phi = {float(q_phi[i]):.4g}"
                raise self._error(
                    f"gave another {field} when glancing object {obj} at {pose} again; "
                    "accepted: the same glance for the same object and pose (seed any noise "
                    "by them, not by a global random state)"
                )

    def describe(self) -> dict:
        d = recorded_file.call(self._what, self._where, self.inner.describe)
        if not isinstance(d, dict):
            raise self._error(f"describe() returned a {type(d).__name__}; accepted: a dict")
        out = {**d, "simulator": self.name}
        if self._what == "simulator file":
            out["simulator_file"] = self._where
        try:  # as tables record it (sorted keys; values that are no JSON written as text)
            json.dumps(out, sort_keys=True, default=str)
        except (TypeError, ValueError) as exc:
            raise self._error(
                f"describe() returned a dict that is no JSON ({exc}); accepted: a dict with text "
                "keys"
            ) from None
        return out
