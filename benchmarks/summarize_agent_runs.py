"""Summarize runs/ham: best accuracy (mean +- s.e. over seeds), and final checkpoints re-evaluated."""

import glob
import json
import os
import statistics
import subprocess
import sys

rows = {}
for d in sorted(glob.glob("runs/ham/g*_s*/")):
    name = os.path.basename(d.rstrip("/"))
    cfg = name.rsplit("_s", 1)[0]
    m = json.load(open(d + "metrics.json"))
    ev = {}
    for pol in ("mean", "sample"):
        out = subprocess.run(
            [
                sys.executable,
                "-m",
                "ham",
                "evaluate",
                d,
                "--json",
                "--batches",
                "100",
                "--eval-policy",
                pol,
            ],
            capture_output=True,
            text=True,
        ).stdout
        ev[pol] = json.loads(out)
    rows.setdefault(cfg, []).append((m, ev))


def ms(xs):
    return (
        f"{statistics.mean(xs):.3f} +- {statistics.stdev(xs) / len(xs) ** 0.5:.3f}"
        if len(xs) > 1
        else f"{xs[0]:.3f}"
    )


print(
    "| run | seeds | steps | best accuracy (mean poses, during training) | final: mean poses | final: sampled poses | per glance (final, sampled) |"
)
print("|---|---|---|---|---|---|---|")
for cfg, rs in rows.items():
    best = [m["best_accuracy"] for m, _ in rs]
    fm = [e["mean"]["accuracy"] for _, e in rs]
    fs = [e["sample"]["accuracy"] for _, e in rs]
    pg = [
        statistics.mean(x)
        for x in zip(*[e["sample"]["accuracy_per_glance"] for _, e in rs], strict=True)
    ]
    print(
        f"| {cfg} | {len(rs)} | {rs[0][0]['steps']} | {ms(best)} | {ms(fm)} | {ms(fs)} | {', '.join(f'{a:.3f}' for a in pg)} |"
    )
