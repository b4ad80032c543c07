"""How many recorded glances a pad needs (docs/sim_to_real.md): a table and a figure from the
runs of docs/examples/sim_to_real.py.

    PYTHONPATH=src python docs/results/sim_to_real/summarize.py OUT.json RUN ...

Each RUN: an OUT folder of `sim_to_real.py SIM_RUN OUT --grid G --seed S --json`, holding its
`live.json` (live accuracy on the pad before and after fine-tuning). Prints a Markdown table
(mean ± s.e.m. over the seeds of each grid, and of each `--calibrate K` where runs differ in
it); OUT.json keeps every run's numbers, OUT.png draws the accuracy against the recorded
glances per object.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from ham.experiments.reproduce import format_mean_sem, mean_sem  # noqa: E402
from ham.world.files import write_json  # noqa: E402


def _way(run: dict) -> tuple:
    return run.get("calibrate"), run.get("record_objects"), run.get("readout_from")


def _suffix(way: tuple) -> str:
    """A row's name after its grid: nothing for the recorded glances alone."""
    k, only, carried = way
    if carried is not None:
        return f", read-out from {carried}"
    if k is None:
        return ""
    return f", calibrated {k} x {k}" + ("" if only is None else f" from {only}")


def _what(way: tuple) -> str:
    k, only, carried = way
    if carried is not None:
        return f"the table carried by the read-out of {Path(carried).parent.name} (none recorded)"
    if k is None:
        return "the recorded glances"
    fitted = "" if only is None else f" fitted to {only.replace(',', ', ')} only"
    return f"the table calibrated by a {k} x {k} read-out{fitted}"


def read_runs(doc: str, argv: list[str] | None) -> tuple[argparse.Namespace, list[dict]]:
    """A summary's command line (OUT.json, the RUN folders, --title) and each run's
    ``live.json``, named by its folder; this script's and pose_error.py's."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("runs", type=Path, nargs="+")
    ap.add_argument("--title", default="the pad: MuJoCo, Gazebo read-out (3 seeds)")
    args = ap.parse_args(argv)
    runs = [json.loads((r / "live.json").read_text()) | {"run": r.name} for r in args.runs]
    return args, runs


def save_figure(fig, ax, args: argparse.Namespace) -> None:
    """The live accuracy's axis, the title and legend, and OUT.png beside OUT.json."""
    ax.set_ylabel("live accuracy after the last glance")
    ax.set_title(args.title, fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.out.with_suffix(".png"), dpi=110)


def main(argv: list[str] | None = None) -> int:
    args, runs = read_runs(__doc__, argv)
    for r in runs:  # one number for every pose dim (2 here), or one per dim
        r["shape"] = [r["grid"]] * 2 if isinstance(r["grid"], int) else r["grid"]
    shapes = sorted({tuple(r["shape"]) for r in runs}, key=lambda t: (math.prod(t), t))
    # how each run was fine-tuned: on the recorded glances (None), or calibrated (--calibrate
    # K, fitted to the --record-objects only where given)
    ways = sorted({_way(r) for r in runs},
                  key=lambda w: (-1 if w[0] is None else w[0], w[1] or "", w[2] or ""))  # fmt: skip
    tuned_on = ways != [(None, None, None)]  # a column only where runs differ in it
    rows = {}
    column = " fine-tuned on |" if tuned_on else ""
    print(f"| recorded glances per object |{column} before (live) | after (live) | seeds (after) |")
    # (the grid's size per pose dim; a run over k pose dims recorded g^k glances per object)
    print("|---|---|---|---|" + ("---|" if tuned_on else ""))
    for way in ways:
        for shape in shapes:
            mine = sorted((r for r in runs if tuple(r["shape"]) == shape
                           and _way(r) == way), key=lambda r: r["seed"])  # fmt: skip
            if not mine:
                continue
            before = mean_sem(r["before"] for r in mine)
            after = mean_sem(r["after"] for r in mine)
            name = " x ".join(map(str, shape)) + _suffix(way)
            rows[name] = {"before": before, "after": after, "seeds": [r["seed"] for r in mine]}
            seeds = " / ".join(f"{r['after']:.3f}" for r in mine)
            what = f" {_what(way)} |" if tuned_on else ""
            print(f"| {' x '.join(map(str, shape))} ({math.prod(shape)}) |{what} "
                  f"{format_mean_sem(*before)} | **{format_mean_sem(*after)}** | {seeds} |")  # fmt: skip
    write_json(args.out, {"command": " ".join(["python", *sys.argv]), "runs": runs,
                          "by_grid": rows})  # fmt: skip
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    names, x = [" x ".join(map(str, t)) for t in shapes], list(range(len(shapes)))
    steps = "/".join(f"{n:,}" for n in sorted({r["steps"] for r in runs}))
    them = "the recorded glances" if tuned_on else "them"
    lines = [(way, "after", f"fine-tuned on {them}, {steps} steps" if way == (None,) * 3 else
              f"fine-tuned on {_what(way)}") for way in ways]  # fmt: skip
    for way, key, label in [*lines, (ways[0], "before", "trained in simulation only")]:
        at = [(i, f"{n}{_suffix(way)}") for i, n in zip(x, names, strict=True)]
        at = [(i, n) for i, n in at if n in rows]
        ax.errorbar([i for i, _ in at], [rows[n][key][0] for _, n in at],
                    yerr=[rows[n][key][1] for _, n in at], marker="o", capsize=3,
                    label=label)  # fmt: skip
    ax.set_xticks(x, [f"{n.replace(' ', '')}\n({math.prod(t)})" for n, t in zip(names, shapes,
                                                                            strict=True)],
                  fontsize=7)  # fmt: skip
    ax.set_xlabel("recorded glances per object: grid (count)")
    save_figure(fig, ax, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
