"""Gather `ham evaluate --json` outputs of the #12 runs into a summary JSON and markdown rows.

python docs/results/next_world/summarize.py RUNS_DIR OUT.json --command SCRIPT [--objects DESC]
Run directories are named <prefix>_<dims>_<variant>_s<seed>; each holds eval_train.json and,
for composite, eval_test.json. Mean ± s.e.m. (standard deviation with ddof=1 over sqrt(seeds)).
"""

import argparse
import json
import math
import os
import re
from pathlib import Path

NAME = re.compile(
    r"^(?P<prefix>.+?)_(?P<dims>xyphiphi_y|xyphi|xy)_(?P<variant>info|random|hybrid)_s(?P<seed>\d+)$"
)
DIMS = {"xy": "x,y", "xyphi": "x,y,phi", "xyphiphi_y": "x,y,phi,phi_y"}
LABEL = {"info": "learned (info)", "hybrid": "learned (hybrid)", "random": "random (info)"}


def mean_sem(rows: list[list[float]]) -> tuple[list[float], list[float]]:
    n = len(rows)
    mean = [sum(col) / n for col in zip(*rows, strict=True)]
    if n < 2:
        return mean, [0.0] * len(mean)
    sem = [
        math.sqrt(sum((v - m) ** 2 for v in col) / (n - 1)) / math.sqrt(n)
        for col, m in zip(zip(*rows, strict=True), mean, strict=True)
    ]
    return mean, sem


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("runs", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--command", required=True)
    p.add_argument("--objects", default="")
    a = p.parse_args()
    groups: dict[tuple[str, str, str], dict[int, list[float]]] = {}
    steps = set()
    for run in sorted(a.runs.iterdir()):
        m = NAME.match(run.name)
        if not m:
            continue
        for split, fname in (("train", "eval_train.json"), ("composite:test", "eval_test.json")):
            f = run / fname
            if not f.exists() or f.stat().st_size == 0:
                continue
            d = json.loads(f.read_text())
            steps.add(d["steps"])
            key = (DIMS[m["dims"]], m["variant"], split)
            groups.setdefault(key, {})[int(m["seed"])] = d["accuracy_per_glance"]
    runs = {}
    order = {"x,y": 0, "x,y,phi": 1, "x,y,phi,phi_y": 2}
    vorder = {"info": 0, "hybrid": 1, "random": 2}
    for (dims, variant, split), per in sorted(
        groups.items(), key=lambda kv: (order[kv[0][0]], vorder[kv[0][1]], kv[0][2] != "train")
    ):
        seeds = sorted(per)
        mean, sem = mean_sem([per[s] for s in seeds])
        runs[f"{dims}|{variant}|{split}"] = {
            "seeds": seeds,
            "per_seed": [per[s] for s in seeds],
            "mean": mean,
            "sem": sem,
        }
        cells = []
        for i, (m_, s_) in enumerate(zip(mean, sem, strict=True)):
            c = f"{m_:.3f} ± {s_:.3f}" if len(seeds) > 1 else f"{m_:.3f}"
            cells.append(f"({c})" if variant == "hybrid" and i < len(mean) - 1 else c)
        print(f"| {dims} | {LABEL[variant]} | {split} | {len(seeds)} | " + " | ".join(cells) + " |")
    summary = {
        "command": a.command,
        "objects": a.objects,
        "steps": sorted(steps),
        "evaluation": "ham evaluate DIR --batches 50 --seed 12345 (800 episodes, mean poses);"
        " composite also --objects composite:test",
        "runs": runs,
    }
    tmp = a.out.with_suffix(".tmp")
    tmp.write_text(json.dumps(summary, indent=1) + "\n")
    os.replace(tmp, a.out)


if __name__ == "__main__":
    main()
