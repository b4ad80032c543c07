"""A robot's pose errors (docs/sim_to_real.md): live accuracy against `--pad-pose-noise`, for
each way of fine-tuning, from runs of docs/examples/sim_to_real.py.

    PYTHONPATH=src python docs/results/sim_to_real/pose_error.py OUT.json RUN ...

Each RUN: an OUT folder of `sim_to_real.py SIM_RUN OUT --grid G [--calibrate K]
[--pad-pose-noise S] --seed N --json` (its `live.json`). Runs are grouped by grid and
`--calibrate` (a line each) and by the pose error (the x axis); prints a Markdown table (mean ±
s.e.m. over the seeds), OUT.json keeps every run's numbers, OUT.png draws the lines.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from ham.experiments.reproduce import format_mean_sem, mean_sem  # noqa: E402
from ham.world.files import write_json  # noqa: E402

# summarize.py beside this file: its command line and figure, shared
sys.path.insert(0, str(Path(__file__).resolve().parent))
from summarize import read_runs, save_figure  # noqa: E402


def method(run: dict) -> str:
    grid = run["grid"] if isinstance(run["grid"], int) else "x".join(map(str, run["grid"]))
    name = f"{grid} x {grid}" if isinstance(run["grid"], int) else grid
    k = run.get("calibrate")
    return f"{name} recorded" + ("" if k is None else f", calibrated {k} x {k}")


def main(argv: list[str] | None = None) -> int:
    args, runs = read_runs(__doc__, argv)
    for r in runs:
        r["pad_pose_noise"] = r.get("pad_pose_noise", 0.0)
    methods = sorted({method(r) for r in runs})
    noises = sorted({r["pad_pose_noise"] for r in runs})
    rows: dict[str, dict] = {m: {} for m in methods}
    print("| fine-tuned on | " + " | ".join(f"pose error {n:g}" for n in noises) + " |")
    print("|---|" + "---|" * len(noises))
    for m in methods:
        cells = []
        for n in noises:
            mine = [r for r in runs if method(r) == m and r["pad_pose_noise"] == n]
            if not mine:
                cells.append("")
                continue
            after, before = mean_sem(r["after"] for r in mine), mean_sem(r["before"] for r in mine)
            rows[m][str(n)] = {"after": after, "before": before,
                               "seeds": sorted(r["seed"] for r in mine)}  # fmt: skip
            cells.append(format_mean_sem(*after))
        print(f"| {m} | " + " | ".join(cells) + " |")
    # one number per seed: every method's runs of a seed start from the same run
    b = [mean_sem({r["seed"]: r["before"] for r in runs if r["pad_pose_noise"] == n}.values())
         for n in noises]  # fmt: skip
    print("| trained in simulation only | " + " | ".join(format_mean_sem(*v) for v in b) + " |")
    write_json(args.out, {"command": " ".join(["python", *sys.argv]), "runs": runs,
                          "by_method": rows})  # fmt: skip
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    for m in methods:
        at = [n for n in noises if str(n) in rows[m]]
        ax.errorbar(at, [rows[m][str(n)]["after"][0] for n in at],
                    yerr=[rows[m][str(n)]["after"][1] for n in at], marker="o", capsize=3,
                    label=f"fine-tuned: {m}")  # fmt: skip
    ax.errorbar(noises, [v[0] for v in b], yerr=[v[1] for v in b], marker="o", capsize=3,
                label="trained in simulation only")  # fmt: skip
    ax.set_xlabel("the robot's pose error (std, normalized units per pose dim)")
    save_figure(fig, ax, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
