"""Two ``ham reproduce`` folders of the same grid run two ways (eager and ``--cuda-graph``, or
with and without ``--groups-together``): for every run in both, the largest difference in
evaluation accuracy and in any weight, and the wall-clock seconds each folder's runs report.

    PYTHONPATH=src python benchmarks/compare_grids.py OUT_A OUT_B
"""

import argparse
import json
from pathlib import Path

from ham.learn.train import load_run


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("a", type=Path)
    p.add_argument("b", type=Path)
    args = p.parse_args()
    keys = sorted(m.parent.name for m in (args.a / "runs").glob("*/metrics.json"))
    if not keys:
        raise SystemExit(f"no runs in {str(args.a)!r}; accepted: a ham reproduce --out folder")
    acc = weight = 0.0
    for key in keys:
        a, b = args.a / "runs" / key, args.b / "runs" / key
        if not (b / "metrics.json").exists():
            raise SystemExit(f"run {key} is in {str(args.a)!r} but not in {str(args.b)!r}")
        ha, hb = (json.loads((d / "metrics.json").read_text())["history"] for d in (a, b))
        acc = max([acc] + [abs(x["accuracy"] - y["accuracy"]) for x, y in zip(ha, hb, strict=True)])
        wa, wb = (load_run(d).agent.parameters() for d in (a, b))
        weight = max([weight] + [(x - y).abs().max().item() for x, y in zip(wa, wb, strict=True)])
    print(f"{len(keys)} runs: largest accuracy difference in any evaluation {acc:.4f}, "
          f"largest weight difference {weight:.3g}")  # fmt: skip


if __name__ == "__main__":
    main()
