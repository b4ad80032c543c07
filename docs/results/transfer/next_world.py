"""The next world's transfer (next_world.sh): a table and a figure from its runs' evaluations.

    PYTHONPATH=src python docs/results/transfer/next_world.py OUT.json RUNS

RUNS: next_world.sh's folder, with the runs ``fast-sS`` (3,000 steps on the fast simulator's
online glances), ``home-sS`` (3,000 steps on the full MuJoCo-Gazebo table), ``ft-sS``
(fine-tuned 500 steps on 25 recorded glances per object) and ``scratch-sS`` (500 steps on them
from scratch), each with ``eval_TABLE.json`` (``ham evaluate RUN --transfer-table TABLE.h5
--batches 50 --seed 12345 --json``) for the three 21 x 21 tables.
Prints a Markdown table (mean ± s.e.m. over the seeds after glances 2 and 6); OUT.json keeps
every run's accuracy per glance and the means, OUT.png draws the means per glance.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from ham.experiments.reproduce import format_mean_sem, mean_sem  # noqa: E402
from ham.world.files import write_json  # noqa: E402

ROWS = {"fast": "fast simulator, 3,000 steps",
        "home": "MuJoCo Gazebo read-out's full 21 x 21 table, 3,000 steps",
        "ft": "fine-tuned on 25 recorded glances per object, 500 steps",
        "scratch": "from scratch on them, 500 steps"}  # fmt: skip
TABLES = {"fast-taxels-21": "fast", "mujoco-taxels-21": "MuJoCo taxels",
          "mujoco-gazebo-21": "MuJoCo Gazebo read-out"}  # fmt: skip
SHOWN = (2, 6)  # glances


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("runs", type=Path)
    args = ap.parse_args(argv)
    runs: dict[str, dict[str, dict[int, list[float]]]] = {}  # row -> table -> seed -> curve
    differences = {}
    for d in sorted(args.runs.iterdir()):
        m = re.fullmatch(r"(fast|home|ft|scratch)-s(\d+)", d.name)
        if not (m and d.is_dir()):
            continue
        for table in TABLES:
            e = json.loads((d / f"eval_{table}.json").read_text())
            runs.setdefault(m[1], {}).setdefault(table, {})[int(m[2])] = e["accuracy_per_glance"]
            differences[f"{m[1]} -> {table}"] = e.get("transfer_differences")
    means = {
        row: {
            t: [mean_sem([c[g] for c in by_seed.values()]) for g in range(6)]
            for t, by_seed in tables.items()
        }  # fmt: skip
        for row, tables in runs.items()
    }
    head = " | ".join(f"{TABLES[t]}, {g} glances" for t in TABLES for g in SHOWN)
    print(f"| trained | {head} |")
    print("|---" * (1 + len(TABLES) * len(SHOWN)) + "|")
    for row in ROWS:
        if row in means:
            cells = " | ".join(format_mean_sem(*means[row][t][g - 1]) for t in TABLES
                               for g in SHOWN)  # fmt: skip
            print(f"| {ROWS[row]} ({len(runs[row]['fast-taxels-21'])} seeds) | {cells} |")
    write_json(args.out, {"command": " ".join(["python", *sys.argv]), "runs": runs,
                          "means": means, "differences": differences})  # fmt: skip
    fig, axes = plt.subplots(1, len(TABLES), figsize=(12, 3.6), sharey=True)
    for ax, table in zip(axes, TABLES, strict=True):
        for row in ROWS:
            if row in means:
                m = [v[0] for v in means[row][table]]
                s = [v[1] for v in means[row][table]]
                ax.errorbar(range(1, 7), m, yerr=s, marker="o", capsize=3, label=ROWS[row])
        ax.set_title(f"evaluated on: {TABLES[table]}")
        ax.set_xlabel("glance")
        ax.axhline(1 / 12, color="grey", lw=0.8, ls=":")
    axes[0].set_ylabel("accuracy (mean ± s.e.m.)")
    axes[0].legend(fontsize=7, loc="lower right")
    fig.suptitle(
        "composite:train, poses x, y, 6 glances: trained on (lines), evaluated on (panels)"
    )
    fig.tight_layout()
    fig.savefig(args.out.with_suffix(".png"), dpi=110)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
