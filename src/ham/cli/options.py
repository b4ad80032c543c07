"""Options shared by the ``ham`` subcommands: the world a command runs in, numbers, JSON output."""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
from dataclasses import replace

from ham.errors import HamError
from ham.world.glance import POSE_PRESETS, check_pose_dims
from ham.world.sensor import READOUTS


def finite_float(text: str) -> float:
    """argparse type: a float; NaN and inf pass through so the glance check can name them."""
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None


def set_threads(threads: int | None) -> None:
    """``torch.set_num_threads(threads)`` after checking ``--threads`` (``None``: torch's
    choice): more threads than this machine's cores only slow torch down, and a huge count
    overflows torch's int."""
    if threads is None:
        return
    cores = os.cpu_count() or 1
    if not 1 <= threads <= cores:
        raise HamError(
            f"--threads {threads}; accepted: an integer from 1 to {cores} (this machine's cores)"
        )
    import torch

    torch.set_num_threads(threads)


def command_line(args: argparse.Namespace) -> str:
    """The command as the user ran it (``ham.cli.main.main`` keeps its argv), for tables' records."""
    argv = getattr(args, "_ham_argv", None)
    return "ham " + shlex.join(sys.argv[1:] if argv is None else argv)


def add_objects_file_option(p: argparse.ArgumentParser) -> None:
    """``--objects-file FILE``: register the user's own objects before the command runs."""
    p.add_argument(
        "--objects-file",
        metavar="FILE",
        help="a .py file that registers your own objects (ham.world.objects.register), or a "
        ".json/.toml list of polylines/heightmaps; recorded in tables and runs (docs/world.md)",
    )


def load_objects_file_arg(args: argparse.Namespace) -> dict | None:
    """Register ``--objects-file``'s objects; its record (name, sha256, source), or ``None``."""
    path = getattr(args, "objects_file", None)
    if path is None:
        return None
    from ham.world.objects import load_objects_file

    return load_objects_file(path)


def objects_from_args(
    args: argparse.Namespace, objects: str | None = None
) -> tuple[str, dict | None]:
    """The object set and the objects-file record of ``--objects`` / ``--objects-file``.

    Without ``--objects`` the set is the file's objects when a file is given, else ``paper``.
    """
    from ham.world.objects import load_objects, resolve_set

    record = load_objects_file_arg(args)
    objects = objects or getattr(args, "objects", None)
    if objects is None:
        objects = ",".join(load_objects(record)) if record else "paper"
    elif record is not None:
        # Record names, not ids: another objects file loaded first would shift the file's ids.
        objects = ",".join(o.name for o in resolve_set(objects))
    return objects, record


def add_world_options(
    p: argparse.ArgumentParser, *, objects: bool = True, cache: bool = True
) -> None:
    """Options that build a :class:`ham.world.config.WorldConfig` (paper defaults); ``cache``:
    also ``--cache-dir`` (commands that use a preset's glance table)."""
    if objects:
        p.add_argument(
            "--objects",
            default=None,
            help="object set: paper (default; with --objects-file: the file's objects), mhsb, "
            "all, or a comma list of names/ids",
        )
        add_objects_file_option(p)
    add_world_preset_option(p, cache=cache)
    p.add_argument(
        "--simulator",
        default=None,
        help="fast (default), mujoco, or one a --simulator-file registers (default with a file: "
        "its simulator)",
    )
    p.add_argument(
        "--simulator-file",
        metavar="FILE",
        help="a .py file that registers your own simulator (ham.world.simulators."
        "register_simulator), e.g. a sensor of your own; recorded in tables and runs (docs/world.md)",
    )
    p.add_argument(
        "--sensor",
        default=None,
        choices=READOUTS,
        help="read-out: taxels (default; edges are lines) or gazebo (MuJoCo only: contact points "
        "spread by a 5 mm Gaussian, the paper's plugin: edges are blobs)",
    )
    p.add_argument(
        "--pose",
        default=None,
        choices=POSE_PRESETS,
        help="pose mapping: paper (phi = q*pi/2, default) or authors (phi = q*0.3pi, pivot shift)",
    )
    p.add_argument(
        "--pose-dims",
        default=None,
        metavar="DIMS",
        help="pose dimensions the glance takes, a comma list in the order x,y,phi,phi_y "
        "(default: x,phi, the paper's; y or phi_y pick the extended glance)",
    )
    add_sensor_options(p)


def add_world_preset_option(p: argparse.ArgumentParser, *, cache: bool = True) -> None:
    """``--world NAME`` (a world preset, :data:`ham.world.config.WORLD_PRESETS`) and
    ``--cache-dir DIR`` (where preset tables are kept)."""
    from ham.world.config import WORLD_PRESETS

    p.add_argument(
        "--world",
        default=None,
        metavar="PRESET",
        help=f"a world preset: {', '.join(WORLD_PRESETS)} (docs/world.md, 'World presets'); "
        "explicit world options (--simulator, --sensor, --pose, sensor options) override its fields",
    )
    if cache:
        p.add_argument(
            "--cache-dir",
            default=None,
            metavar="DIR",
            help="where a preset's glance table is built once and kept (default $HAM_CACHE_DIR or "
            "~/.cache/ham)",
        )


def preset_from_args(args: argparse.Namespace) -> dict | None:
    """The ``--world`` preset (refused by name when unknown), or ``None``."""
    from ham.world.config import world_preset

    name = getattr(args, "world", None)
    if name is None and getattr(args, "cache_dir", None) is not None:
        raise HamError(
            f"--cache-dir {args.cache_dir!r} without --world; accepted: --cache-dir with --world "
            "PRESET (it keeps the preset's glance table)"
        )
    return None if name is None else world_preset(name)


def add_sensor_options(p: argparse.ArgumentParser, *, geometry_only: bool = False) -> None:
    """The pad's options, one per :class:`ham.world.sensor.SensorConfig` field (paper defaults):
    ``--taxels N --pitch M`` and the foam/read-out options (``geometry_only``: only the first two)."""
    from dataclasses import fields

    from ham.cli.config_args import add_config_options
    from ham.world.sensor import SensorConfig

    group = p.add_argument_group("sensor (SensorConfig; the Myrmex pad, paper defaults)")
    names = {f.name for f in fields(SensorConfig)}
    add_config_options(
        group, SensorConfig, skip=names - {"taxels", "pitch"} if geometry_only else ()
    )


def sensor_changes_from_args(args: argparse.Namespace) -> dict:
    """The pad's geometry the user gave: ``--taxels`` / ``--pitch`` (SensorConfig fields)."""
    return {k: getattr(args, k) for k in ("taxels", "pitch") if getattr(args, k, None) is not None}


def sensor_from_args(args: argparse.Namespace):
    """The :class:`ham.world.sensor.SensorConfig` of the sensor options given (defaults else)."""
    from ham.cli.config_args import overrides
    from ham.world.sensor import SensorConfig

    return SensorConfig(**overrides(args, SensorConfig))


# ------------------------------------------------------------------------------------------------


def world_from_args(args: argparse.Namespace, objects: str | None = None):
    """The :class:`ham.world.config.WorldConfig` of the world options: ``--world``'s preset (if
    given) with every explicitly given option replacing the preset's field; paper defaults else."""
    from ham.world.config import world_from_table

    objects, record = objects_from_args(args, objects)
    preset = preset_from_args(args)
    base = preset["world"] if preset else {}
    sim_record, simulator = simulator_from_args(args)
    simulator = simulator or base.get("simulator", "fast")
    readout = args.sensor or base.get("mujoco", {}).get("readout", "taxels")
    pose = args.pose or base.get("pose", "paper")
    mujoco = {}
    if readout == "gazebo":
        if simulator != "mujoco":
            given = f" (world {args.world!r})" if preset else ""
            raise HamError(
                f"--sensor gazebo{given} needs --simulator mujoco (got {simulator!r}): the fast "
                "model has no contact points to spread; for a Gazebo-like blur use --spread-sigma "
                "0.005, or --sensor taxels"
            )
        mujoco["readout"] = "gazebo"
    table = {
        "objects": objects,
        "simulator": simulator,
        "pose": pose,
        "mujoco": mujoco,
        "objects_file": record,
        "simulator_file": sim_record,
    }
    dims = getattr(args, "pose_dims", None)
    if dims is not None:
        table["pose_dims"] = list(check_pose_dims(dims, "--pose-dims"))
    world = world_from_table(table)
    return replace(world, sensor=sensor_from_args(args))


def simulator_from_args(args: argparse.Namespace) -> tuple[dict | None, str | None]:
    """``--simulator-file``'s record (its simulators registered) and the simulator to use: the
    ``--simulator`` given, else the file's one simulator, else ``None`` (the default's).

    An unknown ``--simulator`` is refused here, before anything is written."""
    from ham.world import simulators

    path = getattr(args, "simulator_file", None)
    name = getattr(args, "simulator", None)
    record = None
    if path is not None:
        record = simulators.read_simulator_file(path)
        name = simulators.file_simulator(record, name, "--simulator", "--simulator-file")
    elif name is not None and name not in simulators.simulator_names():
        raise simulators.unknown_simulator(name)
    return record, name


def print_json(obj) -> None:
    json.dump(obj, sys.stdout, indent=None, allow_nan=True)
    sys.stdout.write("\n")
