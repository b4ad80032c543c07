"""Summarize the pose-noise grids (docs/grids/pose_noise*.toml) into pose_noise.json and a figure.

    python docs/results/pose-noise/summarize.py RUNS_DIR [RUNS_DIR ...]

RUNS_DIR: the `runs/` folders of `ham reproduce grid` (keys `noise{sigma}-g{G}-s{seed}`,
`rloc-noise{sigma}-g{G}-s{seed}`, and `p50k-noise{sigma}-g{G}-s{seed}` for runs of the paper's
50,000 steps, cells `full50k-...`). Per cell: each seed's best accuracy within the steps run, the
mean ± s.e.m., the best so far at 2,000 / 4,000 / 10,000 steps; beside them the noiseless runs of
the same world and protocol (the first 10,000 steps of protocol50k.json's taxel cells, 3 seeds)
and the paper's Table 1. The figure: accuracy against sigma, one line per glance count.
"""

import json
import math
import os
import re
import sys
from pathlib import Path

HERE = Path(__file__).parent
PROTOCOL = HERE.parent / "paper-gazebo" / "protocol50k.json"
PAPER = {
    "full": {1: 0.547, 2: 0.831, 3: 0.910, 4: 0.942},
    "rloc": {1: 0.547, 2: 0.753, 3: 0.858, 4: 0.917},
}
STEPS = (2000, 4000, 10000, 20000, 50000)
KEY = re.compile(
    r"(?P<long>p50k-)?(?P<rloc>rloc-)?noise(?P<sigma>[0-9.]+)-g(?P<g>\d+)-s(?P<seed>\d+)$"
)


def _mean_sem(xs: list[float]) -> tuple[float, float]:
    n = len(xs)
    mean = sum(xs) / n
    sem = math.sqrt(sum((x - mean) ** 2 for x in xs) / (n - 1) / n) if n > 1 else 0.0
    return round(mean, 4), round(sem, 4)


def cells(dirs: list[str]) -> dict:
    runs: dict = {}
    for root in dirs:
        for d in sorted(Path(root).iterdir()):
            m = KEY.match(d.name)
            if not m or not (d / "metrics.json").exists():
                continue
            metrics = json.loads((d / "metrics.json").read_text())
            kind = ("rloc" if m["rloc"] else "full") + ("50k" if m["long"] else "")
            runs.setdefault((kind, float(m["sigma"]), int(m["g"])), []).append(metrics)
    out = {}
    for (kind, sigma, g), ms in sorted(runs.items()):
        best = [round(m["best_accuracy"], 4) for m in ms]
        mean, sem = _mean_sem(best)
        so_far = {
            str(s): round(
                sum(max(e["accuracy"] for e in m["history"] if e["step"] <= s) for m in ms)
                / len(ms),
                4,
            )
            for s in STEPS
            if s <= max(m["steps"] for m in ms)
        }
        out[f"{kind}-noise{sigma}-g{g}"] = {
            "kind": kind, "sigma": sigma, "glances": g,
            "seeds": [m["config"]["seed"] for m in ms], "steps": [m["steps"] for m in ms],
            "best": best, "best_mean": mean, "best_sem": sem, "best_so_far_by_step": so_far,
        }  # fmt: skip
    return out


def noiseless() -> dict:
    """sigma = 0: protocol50k.json's taxel cells (the same world and evaluation), their first
    10,000 steps."""
    stored = json.loads(PROTOCOL.read_text())["cells"]
    out = {}
    for kind, fmt in (("full", "taxels-g{g}"), ("rloc", "taxels-rloc-g{g}")):
        for g in (1, 2, 3, 4):
            c = stored.get(fmt.format(g=g))
            if c is not None:
                so_far = {s: c["best_so_far_by_step"][s] for s in map(str, STEPS[:3])}
                out[f"{kind}-noise0.0-g{g}"] = {
                    "kind": kind, "sigma": 0.0, "glances": g, "seeds": c["seeds"],
                    "best_so_far_by_step": so_far, "source": f"protocol50k.json {fmt.format(g=g)}",
                }  # fmt: skip
    return out


def plot(data: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    lines = {}  # (kind, glances) -> [(sigma, best in 10,000 steps)], the 10k-step cells only
    for c in data.values():
        if c["kind"] in PAPER:
            lines.setdefault((c["kind"], c["glances"]), []).append(
                (c["sigma"], c["best_so_far_by_step"]["10000"])
            )
    drawn = sorted(key for key, pts in lines.items() if len(pts) >= 2)
    for k, (kind, g) in enumerate(drawn):
        pts = sorted(lines[kind, g])
        color, style = f"C{k}", "-" if kind == "full" else ":"
        label = f"{'learned' if kind == 'full' else 'random locations'}, {g} glance{'s' * (g > 1)}"
        ax.plot(*zip(*pts, strict=True), style, marker="o", color=color, label=label)
        ax.axhline(PAPER[kind][g], color=color, ls="--", lw=0.8)
        for c in data.values():  # the same cell run to the paper's 50,000 steps: an open marker
            if c["kind"] == kind + "50k" and c["glances"] == g:
                ax.plot(c["sigma"], c["best_mean"], "o", mfc="none", color=color, ms=9,
                        label=f"{label}, 50,000 steps")  # fmt: skip
    ax.set_xlabel("pose noise sigma (normalized pose units; the range is [-1, 1])")
    ax.set_ylabel("best accuracy (sampled poses), 10,000 steps")
    ax.set_title(
        "Table 1 under actuation noise, paper-gazebo taxel world (dashed: the paper)", fontsize=10
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.02, 0.5))
    tmp = out.with_suffix(".png.tmp")
    fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png")
    os.replace(tmp, out)


def main() -> None:
    data = {**noiseless(), **cells(sys.argv[1:])}
    path = HERE / "pose_noise.json"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps({"paper": PAPER, "cells": data}, indent=1) + "\n")
    os.replace(tmp, path)
    plot(data, HERE / "pose_noise.png")
    for name, c in data.items():
        print(name, c.get("best"), c.get("best_mean"), c.get("best_sem"), c["best_so_far_by_step"])


if __name__ == "__main__":
    main()
