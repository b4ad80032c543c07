"""Every run of a transfer grid evaluated on every world's glance table (sim-to-sim transfer).

    PYTHONPATH=src python docs/results/transfer/transfer.py OUT.json GRID_OUT [--more DIR ...]
        [--batches 100]

GRID_OUT is the folder of `ham reproduce grid docs/grids/transfer.toml --out GRID_OUT`. Its runs
are named ``WORLD-POLICY-sSEED``; ``--more`` names folders of more runs so named, trained
otherwise (e.g. with ``--spread-augment``): more rows. Each run is loaded onto each world's
table (the table the grid's runs of that world record) with ``load_run(DIR,
transfer_table=TABLE)``, as `ham evaluate DIR --transfer-table TABLE` does, and evaluated on
``--batches`` balanced batches (seed 12345, the CLI's, the run's own evaluation policy: mean
poses). OUT.json keeps each run's accuracy after each glance on each table, the mean ± s.e.m.
over the seeds (after the last glance, and after the first, random one) and how each table's
world differs from each other's; OUT.png beside it draws the two matrices (learned and random
locations) of the last glance: trained on (rows) against evaluated on (columns). Markdown
tables of both are printed.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from ham.experiments.reproduce import format_mean_sem, mean_sem  # noqa: E402
from ham.learn.evaluation import evaluate  # noqa: E402
from ham.learn.train import load_run, read_run_config  # noqa: E402
from ham.world.files import write_json  # noqa: E402

NAME = re.compile(r"^(?P<world>.+)-(?P<policy>learned|random)-s(?P<seed>\d+)$")
WORLDS = ("fast", "fast-spread", "mujoco", "mujoco-gazebo")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("grid_out", type=Path)
    ap.add_argument("--more", type=Path, nargs="*", default=[],
                    help="folders of more runs named TRAINING-POLICY-sSEED (e.g. the "
                         "--spread-augment runs): more rows, evaluated on the grid's worlds")  # fmt: skip
    ap.add_argument("--batches", type=int, default=100)
    args = ap.parse_args(argv)

    runs = {}
    for folder in (args.grid_out / "runs", *args.more):
        for d in sorted(folder.iterdir()):
            m = NAME.match(d.name)
            if m and (d / "checkpoint.pt").is_file():
                runs[d] = (m["world"], m["policy"], int(m["seed"]))
    glances = {read_run_config(d).model.glances for d in runs}
    tables = {}
    for d, (world, _, _) in runs.items():
        if world in WORLDS:
            tables.setdefault(world, read_run_config(d).table)
    worlds = [w for w in WORLDS if w in tables]  # the columns
    more = {w for w, _, _ in runs.values()} - set(worlds)
    natural = [[int(t) if t.isdigit() else t for t in re.split(r"(\d+)", w)] for w in more]
    trained = worlds + [w for _, w in sorted(zip(natural, more, strict=True))]  # the rows

    accuracy: dict = {}
    differences: dict = {}
    for d, (world, policy, seed) in runs.items():
        for other in worlds:
            run = load_run(d, transfer_table=tables[other])
            try:
                r = evaluate(
                    run.agent, run.env, args.batches, seed=12345, policy=run.config.eval_policy
                )
            finally:
                run.close()
            at = accuracy.setdefault(policy, {}).setdefault(world, {}).setdefault(other, {})
            at[seed] = r.accuracy_per_glance  # the last: the run's accuracy
            differences.setdefault(world, {})[other] = run.transfer
            print(f"{d.name} on {other}: {r.accuracy:.4f}", file=sys.stderr, flush=True)

    def cells_at(glance: int) -> dict:
        """mean, sem, n over the seeds of the accuracy after ``glance`` (-1: the last)."""
        return {
            policy: {
                world: {
                    other: dict(
                        zip(
                            ("mean", "sem", "n"),
                            mean_sem(a[glance] for a in seeds.values()),
                            strict=True,
                        )
                    )
                    for other, seeds in row.items()
                }  # fmt: skip
                for world, row in rows.items()
            }
            for policy, rows in accuracy.items()
        }

    cells, first = cells_at(-1), cells_at(0)
    write_json(args.out, {
        "command": "PYTHONPATH=src python docs/results/transfer/transfer.py " + " ".join(
            [str(args.out), str(args.grid_out), *(["--more", *map(str, args.more)] if args.more
             else []), "--batches", str(args.batches)]),
        "tables": tables,
        "differences": differences,
        "accuracy_per_glance": accuracy,
        "cells": cells,
        "cells_after_glance_1": first,
    })  # fmt: skip

    fig, axes = plt.subplots(1, len(cells), figsize=(5.2 * len(cells), 4.4), squeeze=False)
    for ax, (policy, rows) in zip(axes[0], sorted(cells.items()), strict=True):
        shown = [w for w in trained if w in rows]
        grid = [[rows[w][o]["mean"] for o in worlds] for w in shown]
        ax.imshow(grid, vmin=0.25, vmax=1.0, cmap="viridis", aspect="auto")
        for i, row in enumerate(grid):
            for j, v in enumerate(row):
                ax.text(j, i, f"{v:.3f}", ha="center", va="center",
                        color="black" if v > 0.7 else "white", fontsize=10)  # fmt: skip
        ax.set_xticks(range(len(worlds)), worlds, rotation=30, ha="right")
        ax.set_yticks(range(len(shown)), shown)
        ax.set_xlabel("evaluated on the glances of")
        ax.set_ylabel("trained on")
        n = rows[worlds[0]][worlds[0]]["n"]
        g = "/".join(map(str, sorted(glances)))
        ax.set_title(f"{policy} locations, {g} glances (mean of {n} seeds)")
    fig.tight_layout()
    png = args.out.with_suffix(".png")
    fig.savefig(png, dpi=110)
    print(f"wrote {args.out} and {png}", file=sys.stderr)

    for what, table in (("", cells), (", after the first (random) glance", first)):
        for policy, rows in sorted(table.items()):
            _markdown(f"{policy} locations{what}", rows, worlds, trained)
    return 0


def _markdown(title: str, rows: dict, worlds: list[str], trained: list[str]) -> None:
    print(f"\n{title}: trained on (rows), evaluated on (columns)\n")
    print("| trained on | " + " | ".join(worlds) + " |")
    print("|---|" + "---|" * len(worlds))
    for w in (w for w in trained if w in rows):
        c = rows[w]
        print(f"| {w} | " + " | ".join(format_mean_sem(c[o]["mean"], c[o]["sem"], c[o]["n"])
                                       for o in worlds) + " |")  # fmt: skip


if __name__ == "__main__":
    raise SystemExit(main())
