"""Options shared by the ``ham`` subcommands: the world a command runs in, numbers, JSON output."""

from __future__ import annotations

import argparse
import json
import shlex
import sys

from ham.errors import HamError


def finite_float(text: str) -> float:
    """argparse type: a float; NaN and inf pass through so the glance check can name them."""
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None


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


def add_world_options(p: argparse.ArgumentParser, *, objects: bool = True) -> None:
    """Options that build a :class:`ham.world.config.WorldConfig` (paper defaults)."""
    if objects:
        p.add_argument(
            "--objects",
            default=None,
            help="object set: paper (default; with --objects-file: the file's objects), mhsb, "
            "all, or a comma list of names/ids",
        )
        add_objects_file_option(p)
    p.add_argument("--simulator", default="fast", help="fast (default) or mujoco")
    p.add_argument(
        "--sensor",
        default="taxels",
        choices=("taxels", "gazebo"),
        help="read-out: taxels (default; edges are lines) or gazebo (MuJoCo only: contact points "
        "spread by a 5 mm Gaussian, the paper's plugin: edges are blobs)",
    )
    p.add_argument(
        "--pose",
        default="paper",
        choices=("paper", "authors"),
        help="pose mapping: paper (phi = q*pi/2, default) or authors (phi = q*0.3pi, pivot shift)",
    )
    p.add_argument("--foam-stiffness", type=finite_float, default=None, help="Pa per m")
    p.add_argument(
        "--spread-sigma",
        type=finite_float,
        default=None,
        help="Gaussian spread (m) like the paper's Gazebo plugin, e.g. 0.005",
    )
    p.add_argument("--quantize-bits", type=int, default=None, help="e.g. 12, like the real sensor")
    add_sensor_options(p)


# --- sensor geometry (--taxels, --pitch): one block, applied through sensor_changes_from_args ---
def add_sensor_options(p: argparse.ArgumentParser) -> None:
    """``--taxels N --pitch M``: the pad's cells per side and their pitch (paper: 16, 0.005 m)."""
    p.add_argument(
        "--taxels",
        type=int,
        default=None,
        metavar="N",
        help="taxels per side of the pad, 2..128 (default 16: a 16 x 16 image)",
    )
    p.add_argument(
        "--pitch",
        type=finite_float,
        default=None,
        metavar="M",
        help="taxel pitch in m (default 0.005); the pad is N * M wide, at most the objects' "
        "depth (9 cm)",
    )


def sensor_changes_from_args(args: argparse.Namespace) -> dict:
    """The :class:`ham.world.sensor.SensorConfig` fields ``--taxels``/``--pitch`` set."""
    changes = {}
    if getattr(args, "taxels", None) is not None:
        changes["taxels"] = args.taxels
    if getattr(args, "pitch", None) is not None:
        changes["pitch"] = args.pitch
    return changes


# ------------------------------------------------------------------------------------------------


def world_from_args(args: argparse.Namespace, objects: str | None = None):
    from dataclasses import replace

    from ham.world.config import WorldConfig
    from ham.world.glance import PoseConfig
    from ham.world.sensor import SensorConfig

    objects, record = objects_from_args(args, objects)

    sensor = SensorConfig()
    changes = {}
    if args.foam_stiffness is not None:
        changes["foam_stiffness"] = args.foam_stiffness
    if args.spread_sigma is not None:
        changes["spread_sigma"] = args.spread_sigma
    if args.quantize_bits is not None:
        changes["quantize_bits"] = args.quantize_bits
    changes.update(sensor_changes_from_args(args))
    sensor = replace(sensor, **changes)
    mujoco = {}
    if args.sensor == "gazebo":
        if args.simulator != "mujoco":
            raise HamError(
                f"--sensor gazebo needs --simulator mujoco (got {args.simulator!r}): the fast "
                "model has no contact points to spread; for a Gazebo-like blur use --spread-sigma 0.005"
            )
        mujoco["readout"] = "gazebo"
    return WorldConfig(
        objects=objects,
        simulator=args.simulator,
        sensor=sensor,
        pose=PoseConfig.preset(args.pose),
        mujoco=mujoco,
        objects_file=record,
    )


def print_json(obj) -> None:
    json.dump(obj, sys.stdout, indent=None, allow_nan=True)
    sys.stdout.write("\n")
