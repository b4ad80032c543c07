"""The ``ham`` command line: one subcommand per job.

World commands live here; other concerns add theirs through ``add_commands(subparsers)`` in
their own module (listed in ``_COMMAND_MODULES``). Errors a user can cause end with one line on
stderr naming the bad value and what is accepted, and exit status 2: never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import math
import os
import re
import sys
from collections.abc import Sequence
from pathlib import Path

from ham import __version__
from ham.cli.options import (  # noqa: F401
    add_objects_file_option,
    add_world_options,
    command_line,
    finite_float,
    load_objects_file_arg,
    preset_from_args,
    print_json,
    world_from_args,
)
from ham.errors import HamError, too_large
from ham.world.files import check_output

PNG = (".png",)
HDF5 = (".h5", ".hdf5")

# Modules that add subcommands; a missing optional one is skipped.
_COMMAND_MODULES = (
    "ham.cli.agent",
    "ham.cli.baselines",
    "ham.cli.mujoco_cmds",
    "ham.cli.reproduce",
    "ham.cli.envs",
)


# --------------------------------------------------------------------------- objects
def _object_from_file(args: argparse.Namespace):
    """The one object of ``--image`` or ``--mesh`` (registered in this process only)."""
    from ham.world import objects

    if args.set is not None:
        raise HamError("--set with --image/--mesh; accepted: one of them (the file is the set)")
    if not args.name:
        raise HamError("--image/--mesh needs --name NAME for the object")
    if args.image:
        size = {k: getattr(args, k) for k in ("width", "depth", "height")}
        obj = objects.HapticObject.from_image(
            args.name,
            args.image,
            description=f"from image {Path(args.image).name}",
            **{k: v for k, v in size.items() if v is not None},
        )
    else:
        grid = {k: getattr(args, k) for k in ("scale", "pitch")}
        obj = objects.HapticObject.from_mesh(
            args.name,
            args.mesh,
            description=f"from mesh {Path(args.mesh).name}",
            **{k: v for k, v in grid.items() if v is not None},
        )
    objects.register(obj)
    return [obj]


def _exported(objs: list, spec: str, name: str | None) -> list:
    """The objects ``--export`` writes: a built-in object's copy could never load beside the
    original (names are unique), so it needs a new name (``--name``, one object)."""
    from dataclasses import replace

    from ham.world import objects

    if name is not None and [o.name for o in objs] != [name]:  # --image/--mesh: named already
        if len(objs) != 1:
            raise HamError(f"--name {name!r} renames the one exported object; --set {spec!r} "
                           f"has {len(objs)}; accepted: --set of one object")  # fmt: skip
        if objects.check_name(name) in objects.names():
            raise HamError(f"--name {name!r} is registered already ({objects.origin(name)}); "
                           "accepted: a new name")  # fmt: skip
        objs = [replace(objs[0], name=name)]
    built_in = [o.name for o in objs if o.name in objects.names()
                and objects.origin(o.name) == "built-in"]  # fmt: skip
    if built_in:
        raise HamError(
            f"--export of built-in object {built_in[0]!r}: its copy could never load beside it "
            "(names are unique); accepted: one built-in object with --name NEW, or your own "
            "objects (--image, --mesh, --objects-file)"
        )
    return objs


def cmd_objects(args: argparse.Namespace) -> int:
    from ham.world import objects

    if args.out:
        check_output(args.out, PNG)
    if args.export:
        check_output(args.export, (".json",), what="--export")
    if args.image and args.mesh:
        raise HamError("--image and --mesh; accepted: one of them")
    for flag, needs, given in (
        ("--name", "--image, --mesh or --export", args.image or args.mesh or args.export),
        ("--width", "--image", args.image),
        ("--depth", "--image", args.image),
        ("--height", "--image", args.image),
        ("--scale", "--mesh", args.mesh),
        ("--pitch", "--mesh", args.mesh),
        ("--samples", "--export", args.export),
        ("--view", "--out", args.out),
    ):
        if getattr(args, flag[2:]) is not None and not given:
            raise HamError(f"{flag} applies only with {needs}; accepted: {needs} {flag} ...")
    load_objects_file_arg(args)
    if args.image or args.mesh:
        objs = _object_from_file(args)
        spec = objs[0].name
    else:
        spec = "all" if args.set is None else args.set
        objs = objects.resolve_set(spec)
    member = objects.set_membership()
    rows = [
        {
            "id": objects.object_id(o.name),
            "name": o.name,
            "width": o.width,
            "depth": o.depth,
            "height": o.height,
            "varies_in_y": o.varies_in_y,
            "sets": member.get(o.name, []),
            "description": o.description,
            "origin": objects.origin(o.name),
        }
        for o in objs
    ]
    splits = objects.splits_of(spec)
    if args.out:
        from ham.world.drawing import draw_objects, draw_objects_3d

        view = args.view or "auto"
        if view == "auto":
            view = "3d" if any(o.varies_in_y for o in objs) else "side"
        if view == "3d":
            draw_objects_3d(objs, args.out, title=f"Objects {spec}: top h(x, y) (cm)")
        else:
            draw_objects(objs, args.out)
    if args.export:
        samples = 129 if args.samples is None else args.samples
        objects.write_objects_file(_exported(objs, spec, args.name), args.export, samples=samples)
    if args.json:
        print_json(rows)
    else:
        for r in rows:
            mark = "" if r["origin"] == "built-in" else f" [{r['origin']}]"
            size = f"{r['width'] * 100:g} x {r['depth'] * 100:g} cm"
            print(
                f"{r['id']:>3}  {r['name']:<13} {size:<11} h {r['height'] * 100:4.2f} cm  "
                f"{r['description']}{mark}"
            )
        for split, names in splits.items():
            print(f"split {split}: {len(names)} objects: {', '.join(names)}")
        if splits:
            print(
                "(object i of each split is an instance of class i: train on one, score on the other)"
            )
        for what, path in (("wrote", args.out), ("wrote", args.export)):
            if path:
                print(f"{what} {path}")
    return 0


# --------------------------------------------------------------------------- glance
def cmd_glance(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from ham.world import objects
    from ham.world.config import make_simulator
    from ham.world.glance import POSE_DIMS

    if args.out:
        check_output(args.out, PNG)
    world = world_from_args(args)  # registers --objects-file's objects first
    obj = objects.get(args.object)
    if args.objects is not None and obj not in world.resolve_objects():
        raise HamError(f"--object {args.object!r} is not in --objects {args.objects!r}")
    world = replace(world, objects=obj.name)
    # A y or phi_y given takes the extended glance, whatever --pose-dims says.
    asked = {"y": args.y != 0, "phi_y": args.phi_y != 0}
    dims = [d for d in POSE_DIMS if d in world.pose_dims or asked.get(d, False)]
    world = replace(world, pose_dims=tuple(dims))
    sim = make_simulator(world)
    extra = {"q_y": [args.y], "q_phi_y": [args.phi_y]} if world.extended else {}
    result = sim.glance([0], [args.x], [args.phi], **extra)
    data = result.to_json(0)
    data.update(object=obj.name, object_id=objects.object_id(obj.name), simulator=sim.name)
    data["q"] = [args.x, args.phi]
    data.update(q_y=args.y, q_phi_y=args.phi_y, pose_dims=list(world.pose_dims))
    if args.out:
        from ham.world.drawing import draw_glance

        draw_glance(obj, data, world.sensor.size, args.out)
    if args.json:
        print_json(data)
    else:
        if world.extended:
            print(
                f"{obj.name} at q = (x {args.x:+.3f}, y {args.y:+.3f}, phi {args.phi:+.3f}, "
                f"phi_y {args.phi_y:+.3f}) -> x = {data['x'] * 100:.2f} cm, "
                f"y = {data['y'] * 100:.2f} cm, phi = {math.degrees(data['phi']):.1f} deg, "
                f"phi_y = {math.degrees(data['phi_y']):.1f} deg: force {data['force']:.3f} N, "
                f"height {data['height'] * 100:.3f} cm, contact {data['contact']}, "
                f"blocked {data['blocked']}"
            )
        else:
            print(
                f"{obj.name} at q = ({args.x:+.3f}, {args.phi:+.3f}) -> x = {data['x'] * 100:.2f} "
                f"cm, phi = {math.degrees(data['phi']):.1f} deg: force {data['force']:.3f} N, "
                f"z {data['z'] * 100:.3f} cm, contact {data['contact']}, blocked {data['blocked']}"
            )
        if args.out:
            print(f"wrote {args.out}")
    return 0


# --------------------------------------------------------------------------- table
def cmd_table_build(args: argparse.Namespace) -> int:
    from ham.world.table import build_table

    check_output(args.out, HDF5)
    world = world_from_args(args)
    preset = preset_from_args(args)
    grid = args.grid if args.grid is not None else preset["grid"] if preset else "201"
    if preset is None:
        out = build_table(world, grid, args.out, progress=not args.quiet,
                          command=command_line(args), compression=args.compression)  # fmt: skip
    else:  # a preset's table is built once into the cache, then copied
        import shutil

        from ham.world.cache import cached_table
        from ham.world.files import atomic_write

        if isinstance(grid, str) and not grid.isdigit():
            raise HamError(f"--grid {grid!r} with --world; accepted: one number of poses per axis")
        if args.compression is not None:
            raise HamError(f"--compression {args.compression} with --world: a preset's table "
                           "is the paper's (x, phi) kind, stored uncompressed; leave it out")  # fmt: skip
        cached = cached_table(world, int(grid), args.cache_dir, progress=not args.quiet,
                              command=command_line(args))  # fmt: skip
        out = atomic_write(args.out, lambda tmp: shutil.copyfile(cached, tmp))
        print(f"from the cache: {cached}")
    print(f"wrote {out}")
    return 0


def cmd_table_info(args: argparse.Namespace) -> int:
    from ham.world.table import verify_table

    info = verify_table(args.file)  # a corrupt table is refused, not described
    if args.json:
        print_json(info.to_dict())
        return 0
    print(f"{info.path}: {len(info.objects)} objects x {_grid_text(info)} glances")
    print(f"  objects:   {', '.join(info.objects)}")
    print(f"  simulator: {info.simulator.get('simulator', '?')}  source: {info.source}")
    readout = info.simulator.get("readout")
    if isinstance(readout, dict):  # a calibrated table (ham table calibrate)
        from ham.world.calibration import Readout, describe

        fitted = Readout.from_dict(readout, info.path)
        print(f"  read-out:  {describe(fitted)}, on {info.simulator.get('recorded')}")
    from ham.world.sensor import SensorConfig

    print(f"  sensor:    {SensorConfig(**info.sensor).describe()}")
    print(f"  pose:      {info.world.get('pose')}")
    for key in ("objects_file", "simulator_file"):
        record = info.world.get(key)
        if record:
            what = key.replace("_", " ") + ":"
            print(f"  {what} {record.get('name')} (sha256 {record.get('sha256')})")
    print(f"  ham {info.ham_version}, created {info.created}")
    print(f"  command:   {info.command}")
    print(f"  checksum:  sha256 {info.checksum} (verified)")
    if info.record_checksum:
        print(f"  record:    sha256 {info.record_checksum} (attributes, force/height/contact)")
    return 0


def _grid_text(info) -> str:
    """``201 x 201`` (the paper's), or ``21 x 21 x 9 x 9 (x,y,phi,phi_y)`` for other pose grids."""
    text = " x ".join(map(str, info.grid_shape))
    if tuple(info.pose_dims) != ("x", "phi"):
        text += f" ({','.join(info.pose_dims)})"
    return text


def cmd_table_verify(args: argparse.Namespace) -> int:
    from ham.world.table import verify_table

    info = verify_table(args.file)
    print(
        f"ok {args.file}: {len(info.objects)} objects x {_grid_text(info)} glances, "
        "finite non-negative pressures, checksum sha256 matches"
        + (", and the record checksum" if info.record_checksum else "")
    )
    return 0


def cmd_table_show(args: argparse.Namespace) -> int:
    import numpy as np

    from ham.world.drawing import draw_table_grid
    from ham.world.table import GlanceTable, grid_values

    check_output(args.out, PNG)
    table = GlanceTable.load(args.file)
    names = table.objects
    key = args.object
    if key.isdigit():
        if int(key) >= len(names):
            raise HamError(f"object {key} not in table; accepted: 0..{len(names) - 1} or {names}")
        oi = int(key)
    elif key in names:
        oi = names.index(key)
    else:
        raise HamError(f"object {key!r} not in table; accepted: {names} or 0..{len(names) - 1}")
    top = min(table.grid, 25)  # more panels than grid points repeat; more than 25 is unreadable
    if not 2 <= args.n <= top:
        raise HamError(
            f"--n {args.n}; accepted: an integer 2..{top} (this table's grid is {table.grid})"
        )
    q = grid_values(table.grid)
    pick = np.round(np.linspace(0, table.grid - 1, args.n)).astype(int)
    p = table.pressure[oi].numpy()[np.ix_(pick, pick)]
    draw_table_grid(p, (q[pick], q[pick]), f"{names[oi]}: glances from {args.file}", args.out)
    print(f"wrote {args.out}")
    return 0


def cmd_table_import(args: argparse.Namespace) -> int:
    from ham.world.table import import_authors

    check_output(args.out, HDF5)
    out = import_authors(args.file, args.out, axes=args.axes, command=command_line(args))
    print(f"wrote {out}")
    return 0


def cmd_table_import_recorded(args: argparse.Namespace) -> int:
    from ham.world.table import import_recorded

    check_output(args.out, HDF5)
    files = args.file[0] if len(args.file) == 1 else args.file
    out = import_recorded(files, args.out, pose_dims=args.pose_dims,
                          compression=args.compression, command=command_line(args))  # fmt: skip
    print(f"wrote {out}")
    return 0


def cmd_table_calibrate(args: argparse.Namespace) -> int:
    from ham.world.calibration import calibrate_table, carry_readout, describe

    check_output(args.out, HDF5)
    if args.readout_from is not None:
        if args.recorded or args.kernel is not None:
            given = "recorded glances" if args.recorded else "--kernel"
            raise HamError(f"{given} with --readout-from; accepted: recorded glances to fit a "
                           "read-out to (and --kernel), or --readout-from CALIBRATED.h5 to take "
                           "one fitted before")  # fmt: skip
        out, readout = carry_readout(args.table, args.readout_from, args.out,
                                     command=command_line(args))  # fmt: skip
        print(f"{describe(readout)} (from {args.readout_from}); wrote {out}")
        return 0
    if not args.recorded:
        raise HamError("ham table calibrate needs the pad's recorded glances (GLANCES.npz), or "
                       "--readout-from CALIBRATED.h5")  # fmt: skip
    files = args.recorded[0] if len(args.recorded) == 1 else args.recorded
    kernel = 9 if args.kernel is None else args.kernel
    out, readout = calibrate_table(args.table, files, args.out, kernel=kernel,
                                   command=command_line(args))  # fmt: skip
    print(f"{describe(readout)}; wrote {out}")
    return 0


# --------------------------------------------------------------------------- demo
def cmd_demo(args: argparse.Namespace) -> int:
    from ham.experiments.demo import run_demo
    from ham.world.files import check_output_dir

    check_output_dir(args.out)
    run_demo(Path(args.out), quick=args.quick)
    return 0


# --------------------------------------------------------------------------- parser
class HamArgumentParser(argparse.ArgumentParser):
    """argparse with the CLI's error style: one line ``ham: error: ...``, exit 2, no usage dump.

    Subparsers inherit the class, so every subcommand answers the same way. Values that start
    with a minus sign and read as numbers (``-0.5``, ``-1e-3``, ``-inf``, ``-nan``) are values,
    not options: ``--x -inf`` reaches the range check instead of "expected one argument".
    """

    _NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|infinity|nan)$", re.I)

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = self._NUMBER

    def error(self, message: str):  # type: ignore[override]
        where = self.prog.removeprefix("ham").strip()
        one_line = " ".join(message.split())
        self.exit(2, f"ham: error: {where + ': ' if where else ''}{one_line}\n")


def _need_action(parser: argparse.ArgumentParser, dest: str, metavar: str) -> None:
    """A command group given without its action: one line naming the accepted actions."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            parser.error(f"{metavar} missing; accepted: {', '.join(action.choices)}")
    parser.error(f"{metavar} missing")  # pragma: no cover


def build_parser() -> argparse.ArgumentParser:
    parser = HamArgumentParser(
        prog="ham",
        description="The Haptic Attention Model: haptic glances, glance tables, training, reproduction.",
    )
    parser.add_argument("--version", action="version", version=f"ham {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("objects", help="list the objects (and draw them)")
    p.add_argument(
        "--set",
        help="paper, mhsb, curvature2d, composite, composite:train, composite:test, "
        "all (default) or names/ids",
    )
    p.add_argument("--json", action="store_true")
    p.add_argument("--out", help="PNG: side profiles, or shaded 3-D tops (see --view)")
    p.add_argument(
        "--view", choices=("auto", "side", "3d"), default=None,
        help="--out picture: side profiles or 3-D tops (auto, the default: 3-D when an object "
        "varies in y)",
    )  # fmt: skip
    p.add_argument("--image", help="one object from a grey-scale PNG (needs --name)")
    p.add_argument("--mesh", help="one object from the top of an STL/OBJ/PLY mesh (needs --name)")
    p.add_argument("--name", help="the --image/--mesh object's name")
    p.add_argument("--width", type=finite_float, help="--image: x extent (m; 0.09)")
    p.add_argument("--depth", type=finite_float, help="--image: y extent (m; 0.09)")
    p.add_argument("--height", type=finite_float, help="--image: white's height (m; 0.045)")
    p.add_argument("--scale", type=finite_float, help="--mesh: metres per mesh unit (1)")
    p.add_argument("--pitch", type=finite_float, help="--mesh: sample step (m; 0.0005)")
    p.add_argument(
        "--export", help="write the objects as a self-contained JSON objects file (height_field)"
    )
    p.add_argument("--samples", type=int, help="--export: samples along the longer side (129)")
    add_objects_file_option(p)
    p.set_defaults(func=cmd_objects)

    p = sub.add_parser("glance", help="one haptic glance: lower the pad until 2 N, read the image")
    p.add_argument("--object", required=True, help="object name or id")
    p.add_argument(
        "--x", type=finite_float, required=True, help="normalized position q_x in [-1, 1]"
    )
    p.add_argument(
        "--phi", type=finite_float, required=True, help="normalized angle q_phi in [-1, 1]"
    )
    p.add_argument(
        "--y",
        type=finite_float,
        default=0.0,
        help="normalized position q_y in [-1, 1] (default 0; not 0: the extended glance)",
    )
    p.add_argument(
        "--phi-y",
        type=finite_float,
        default=0.0,
        help="normalized tilt about x, q_phi_y in [-1, 1] (default 0; not 0: the extended glance)",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="print the result as JSON (raw pressure; height, y, phi_y)",
    )
    p.add_argument("--out", help="PNG: the pad over the profile and its N x N image")
    add_world_options(p, cache=False)
    p.set_defaults(func=cmd_glance)

    t = sub.add_parser("table", help="glance tables (the paper's pre-recorded data set)")
    tsub = t.add_subparsers(dest="table_command", metavar="ACTION")
    t.set_defaults(func=lambda args: _need_action(t, "table_command", "ACTION"))
    p = tsub.add_parser("build", help="record a grid x grid table of glances per object")
    p.add_argument("--grid", default=None,
                   help="poses per axis, 2..2001 (default 201, or the --world preset's), or one "
                   "per pose dim, e.g. 21,21,9,9 with --pose-dims x,y,phi,phi_y")  # fmt: skip
    p.add_argument("--compression", default=None, choices=("gzip", "lzf", "none"),
                   help="of a table over other pose dims than x,phi (format 2): none writes a "
                   "memory-mappable file (default gzip)")  # fmt: skip
    p.add_argument("--out", required=True, help="HDF5 file to write (atomically), .h5 or .hdf5")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_world_options(p)
    p.set_defaults(func=cmd_table_build)
    p = tsub.add_parser("info", help="describe a table")
    p.add_argument("file")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_table_info)
    p = tsub.add_parser(
        "verify", help="check a table: structure, finite non-negative pressures, checksum"
    )
    p.add_argument("file")
    p.set_defaults(func=cmd_table_verify)
    p = tsub.add_parser("show", help="draw a grid of a table's images for one object")
    p.add_argument("file")
    p.add_argument("--object", required=True, help="name or index in the table")
    p.add_argument("--n", type=int, default=7, help="poses per axis, 2..25 (default 7)")
    p.add_argument("--out", required=True, help="PNG")
    p.set_defaults(func=cmd_table_show)
    p = tsub.add_parser("import-authors", help="convert the authors' HDF5 data set to a table")
    p.add_argument("file")
    p.add_argument("--out", required=True, help="HDF5 table to write, .h5 or .hdf5")
    p.add_argument("--axes", default="x,phi", help="order of their first two axes: x,phi or phi,x")
    p.set_defaults(func=cmd_table_import)
    p = tsub.add_parser("import-recorded",
                        help="recorded glances (a real pad's, another simulator's) as a table: an "
                        ".npz of one (G_x, G_phi, N, N) array per object over the paper's (x, phi) "
                        "grid, or over --pose-dims")  # fmt: skip
    p.add_argument("file", nargs="+", help=".npz: an array per object, named by it, in class "
                   "order (NAME.height: its contact heights, m, optional); "
                   "ham.world.recorder.record_glances writes one; several files: their objects "
                   "in turn")  # fmt: skip
    p.add_argument("--out", required=True, help="HDF5 table to write, .h5 or .hdf5")
    p.add_argument("--pose-dims", default="x,phi", metavar="DIMS",
                   help="the arrays' grid axes, in order: a subset of x,y,phi,phi_y (default x,phi; "
                   "e.g. x,y,phi,phi_y: arrays (G_x, G_y, G_phi, G_phi_y, N, N))")  # fmt: skip
    p.add_argument("--compression", default=None, choices=("gzip", "lzf", "none"),
                   help="of a table over other pose dims than x,phi or a grid that is not "
                   "square (format 2; default gzip)")  # fmt: skip
    p.set_defaults(func=cmd_table_import_recorded)

    p = tsub.add_parser("calibrate",
                        help="a simulator's table carried onto a pad: a read-out (a k x k "
                        "convolution and an offset) fitted to the pad's recorded glances, applied "
                        "to every glance of the table")  # fmt: skip
    p.add_argument("table", help="the simulator's glance table (HDF5)")
    p.add_argument("recorded", nargs="*", help=".npz of the pad's recorded glances, as "
                   "import-recorded reads them: some or all of the table's objects, over a grid "
                   "of its pose dims")  # fmt: skip
    p.add_argument("--out", required=True, help="HDF5 table to write, .h5 or .hdf5")
    p.add_argument("--kernel", type=int, default=None, metavar="K",
                   help="the read-out's kernel side, odd (default 9; 1: a gain and an offset)")  # fmt: skip
    p.add_argument("--readout-from", default=None, metavar="CALIBRATED",
                   help="no fit: the read-out of a table calibrate wrote before (the same pad, "
                   "other objects)")  # fmt: skip
    p.set_defaults(func=cmd_table_calibrate)

    p = sub.add_parser("demo", help="the main job on built-in defaults (what `make demo` runs)")
    p.add_argument("--out", default="runs/demo", help="output folder (default runs/demo)")
    p.add_argument("--quick", action="store_true", help="seconds instead of minutes (for tests)")
    p.set_defaults(func=cmd_demo)

    for name in _COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:
                raise
            continue
        module.add_commands(sub)
    return parser


def _known_failure(exc: Exception) -> str | None:
    """One line for a failure that is not a bug of ours, else None: the user's own code (a
    plugin's core failing in training, past the check at build time), or a request too large
    for this machine (:func:`ham.errors.too_large`)."""
    from ham.world.recorded_file import raised_in

    return raised_in(exc) or too_large(exc)


def _empty_option(args: argparse.Namespace, argv: list[str]) -> str | None:
    """The first option or argument given an empty value (``--table ''``, ``--out=``, ``ham
    evaluate ''``): never meaningful in this CLI, and a command that reads ``if args.table:``
    would take it as not given. (No option's default is empty.)"""
    for dest, value in vars(args).items():
        if value == "" or (isinstance(value, list) and "" in value):
            flag = "--" + dest.replace("_", "-")
            given = any(tok == flag or tok.startswith(flag + "=") for tok in argv)
            return flag if given else dest.upper()
    return None


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    args._ham_argv = argv  # what tables record as their command (ham.cli.options.command_line)
    if not getattr(args, "func", None):
        _need_action(parser, "command", "COMMAND")
    empty = _empty_option(args, argv)
    if empty is not None:
        print(f"ham: error: {empty} ''; accepted: a value (an empty one reads as not given)",
              file=sys.stderr)  # fmt: skip
        return 2
    try:
        return int(args.func(args) or 0)
    except HamError as exc:
        # one line, whatever a wrapped library message held (h5py's span several)
        print(f"ham: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # `ham objects | head`: the reader left, which is no error of ours
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no 2nd one at exit
        return 141  # as a command killed by SIGPIPE
    except OSError as exc:  # a file the user named that the checks did not foresee: still one line
        print(f"ham: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - the failures named below; any other is a bug of ours
        message = _known_failure(exc)
        if message is None:
            raise
        print(f"ham: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("ham: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
