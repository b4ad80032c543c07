"""``ham reproduce``: the paper's tables and figures from one command (see :mod:`ham.experiments.reproduce`),
and ``ham reproduce grid FILE``: any grid of runs from a TOML/JSON file (:mod:`ham.experiments.grid`)."""

from __future__ import annotations

import argparse
import json
import sys

from ham.cli.config_args import add_config_options, overrides
from ham.cli.options import (
    add_objects_file_option,
    add_world_preset_option,
    command_line,
    objects_from_args,
    preset_from_args,
)
from ham.errors import HamError
from ham.experiments.executors import EXECUTORS, BatchedOptions
from ham.experiments.reproduce import PROFILES, TARGETS, TRAINED_VARIANTS, reproduce

GRID = "grid"


def add_commands(subparsers) -> None:
    p = subparsers.add_parser(
        "reproduce",
        help="reproduce the paper's Table 1, Table 2 and figures, or run a grid file",
        description="Plan the paper's grid of training runs, run what is not finished in OUT "
        "(locally or on Ray), and write tables, figures and OUT/report.md. "
        "`ham reproduce grid FILE` runs any grid of runs from a TOML or JSON file (docs/grids.md).",
    )
    p.add_argument("target", choices=(*TARGETS, GRID))
    p.add_argument(
        "file", nargs="?", metavar="FILE", help="with grid: the grid file (.toml, .json)"
    )
    p.add_argument(
        "--profile",
        default=None,
        choices=tuple(PROFILES),
        help="paper: the full protocol (50k steps, 10 seeds); quick: the same grid, reduced, "
        "<= 30 min on 2 cores; smoke: seconds (default quick; not with grid)",
    )
    p.add_argument(
        "--seeds",
        type=int,
        default=None,
        help="override the profile's seed count (grid: run seeds 0..N-1 in every cell)",
    )
    p.add_argument(
        "--steps",
        type=int,
        default=None,
        help="override the profile's training steps per run (its evaluation interval stays; "
        "not with grid: the grid file names its steps)",
    )
    p.add_argument(
        "--glances",
        type=int,
        nargs="+",
        default=None,
        metavar="N",
        help="only these glance counts in Table 1 and the figures (default: the paper's 1 2 3 4 6 8 10)",
    )
    p.add_argument(
        "--variants",
        nargs="+",
        default=None,
        choices=tuple(TRAINED_VARIANTS),
        help="only these trained variants in Table 1 and the figures (default: all; the averaged "
        "MLP column is scored on the mlp runs)",
    )
    p.add_argument(
        "--executor",
        default="local",
        choices=EXECUTORS,
        help="local: a process pool of single runs; ray: single runs as Ray tasks; batched: "
        "runs of one shape (seeds, and runs that differ only in the learning-rate schedule, "
        "momentum, beta, loss reductions, normalization, BPTT truncation or evaluation "
        "settings) as batched models, on a process pool; ray-batched: those batched models as "
        "Ray tasks (default: local)",
    )
    p.add_argument(
        "--ray-address",
        default=None,
        help="ray executors: a running Ray cluster (default: start a local one)",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        help="runs (or batched groups) at once: the local and batched executors' processes, "
        "the CPUs of a Ray started here (default: all cores)",
    )
    add_config_options(
        p.add_argument_group("batched executors (--executor batched or ray-batched)"),
        BatchedOptions,
    )
    p.add_argument("--device", default=None, help="cpu or cuda (default cpu; grid: the file's)")
    p.add_argument(
        "--retries", type=int, default=1, help="re-runs of a failed, not diverged, run (default 1)"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--out", required=True, help="output folder; finished runs in it are skipped")
    p.add_argument(
        "--objects",
        default=None,
        help="object set (default: paper; with --objects-file: the file's objects)",
    )
    add_objects_file_option(p)
    add_world_preset_option(p)
    p.set_defaults(func=cmd_reproduce)


def cmd_reproduce(args: argparse.Namespace) -> int:
    if args.target == GRID:
        return cmd_grid(args)
    if args.file is not None:
        raise HamError(f"FILE {args.file!r} goes with `ham reproduce grid FILE`, not {args.target}")
    if args.target == "table2":  # always the four combiners at 3 glances: nothing to cut
        given = [f"--{k}" for k in ("glances", "variants") if getattr(args, k) is not None]
        if given:
            raise HamError(
                f"{' and '.join(given)} cut Table 1 and the figures; accepted with table1, "
                "figures or all (Table 2 is the four combiners at 3 glances)"
            )
    from ham.world.config import WorldConfig

    objects, record = objects_from_args(args)
    preset = preset_from_args(args)
    world = WorldConfig(objects=objects, objects_file=record)
    if preset is not None:
        from dataclasses import replace

        from ham.world.config import world_from_table

        world = replace(world_from_table(preset["world"]), objects=objects, objects_file=record)
    summary = reproduce(
        args.target,
        args.profile or "quick",
        args.out,
        seeds=args.seeds,
        steps=args.steps,
        executor=args.executor,
        workers=args.workers,
        ray_address=args.ray_address,
        device=args.device or "cpu",
        retries=args.retries,
        progress=not args.quiet,
        command=command_line(args),
        glances=args.glances,
        variants=args.variants,
        world=world,
        batched=BatchedOptions(**overrides(args, BatchedOptions)),
        eval_policy=preset["eval_policy"] if preset else None,
        table_cache=preset is not None,
        cache_dir=args.cache_dir,
    )
    _print_summary(args, summary, [f"{n}.md" for n in ("table1", "table2") if n in summary])
    return _failures(summary)


def _print_summary(args: argparse.Namespace, summary: dict, files: list[str]) -> None:
    if args.json:
        json.dump(summary, sys.stdout, default=str)
        print()
        return
    print(f"ran {summary['ran']} run(s), skipped {summary['skipped']} finished")
    for name in [*files, "report.md"]:
        print(f"wrote {args.out}/{name}")


def cmd_grid(args: argparse.Namespace) -> int:
    from ham.experiments.grid_run import run_grid

    if args.file is None:
        raise HamError("ham reproduce grid needs a grid FILE (.toml or .json); see docs/grids.md")
    given = [
        f"--{k}"
        for k in ("profile", "steps", "glances", "variants")
        if getattr(args, k) is not None
    ]
    if given:
        raise HamError(f"{', '.join(given)} apply to the paper's tables, not to a grid file")
    if args.objects is not None or args.objects_file is not None or args.world is not None:
        raise HamError(
            "--objects/--objects-file/--world apply to the paper's tables; a grid file names its "
            "world in its [world] table (preset = NAME, objects = ...; docs/grids.md)"
        )
    summary = run_grid(
        args.file,
        args.out,
        seeds=args.seeds,
        executor=args.executor,
        workers=args.workers,
        ray_address=args.ray_address,
        device=args.device,
        retries=args.retries,
        progress=not args.quiet,
        command=command_line(args),
        batched=BatchedOptions(**overrides(args, BatchedOptions)),
        cache_dir=args.cache_dir,
    )
    _print_summary(args, summary, ["results.json"])
    return _failures(summary)


def _failures(summary: dict) -> int:
    failures = summary["failures"]
    if failures:
        for f in failures:
            print(f"ham: run {f['key']} failed: {f.get('error')}", file=sys.stderr)
        return 1
    return 0
