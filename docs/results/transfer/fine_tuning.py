"""Fine-tuning against training from scratch in the new world: the accuracy during training.

    PYTHONPATH=src python docs/results/transfer/fine_tuning.py OUT.json GRID_OUT FT_OUT

GRID_OUT: the folder of `ham reproduce grid docs/grids/transfer.toml` (its ``TARGET-learned-sS``
runs are the from-scratch curves); FT_OUT: the folder of the fine-tuned runs, named
``SOURCE-to-TARGET-sS`` (`ham train --init-from GRID_OUT/runs/SOURCE-learned-sS --table
TARGET_TABLE --seed S ...`, docs/results/transfer.md). Each run's evaluations (metrics.json's
history: 100 balanced batches at step 0 and every 250 steps) give the mean ± s.e.m. over the
seeds at each step; step 0 of a fine-tuned run is its source's weights on the target's glances.
OUT.json keeps every run's curve and the means; OUT.png draws them, one panel per target world.
A Markdown table is printed.
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

NAME = re.compile(r"^(?P<source>.+)-to-(?P<target>.+)-s(?P<seed>\d+)$")
SHOWN = (250, 500, 1000, 2000, 3000)


def _curve(run: Path) -> dict[int, float]:
    history = json.loads((run / "metrics.json").read_text())["history"]
    return {int(r["step"]): float(r["accuracy"]) for r in history}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("grid_out", type=Path)
    ap.add_argument("ft_out", type=Path)
    args = ap.parse_args(argv)

    curves: dict[str, dict[int, dict[int, float]]] = {}  # label -> seed -> step -> accuracy
    targets: dict[str, str] = {}
    for d in sorted(args.ft_out.iterdir()):
        m = NAME.match(d.name)
        if not (m and (d / "metrics.json").is_file()):
            continue
        label = f"{m['source']} -> {m['target']}"
        seed = int(m["seed"])
        curves.setdefault(label, {})[seed] = _curve(d)
        targets[label] = m["target"]
        scratch = args.grid_out / "runs" / f"{m['target']}-learned-s{seed}"
        curves.setdefault(f"scratch -> {m['target']}", {})[seed] = _curve(scratch)
        targets[f"scratch -> {m['target']}"] = m["target"]

    means = {}
    for label, seeds in curves.items():
        steps = sorted(set.intersection(*(set(c) for c in seeds.values())))
        means[label] = {s: dict(zip(("mean", "sem", "n"), mean_sem(c[s] for c in seeds.values()),
                                    strict=True)) for s in steps}  # fmt: skip
    write_json(args.out, {
        "command": "PYTHONPATH=src python docs/results/transfer/fine_tuning.py " + " ".join(
            map(str, (args.out, args.grid_out, args.ft_out))),
        "curves": curves,
        "means": means,
    })  # fmt: skip

    worlds = sorted(set(targets.values()))
    fig, axes = plt.subplots(1, len(worlds), figsize=(5.6 * len(worlds), 4.2), squeeze=False)
    for ax, world in zip(axes[0], worlds, strict=True):
        for label in sorted(k for k, t in targets.items() if t == world):
            steps = sorted(means[label])
            m = [means[label][s]["mean"] for s in steps]
            e = [means[label][s]["sem"] for s in steps]
            line = ax.plot(steps, m, marker=".", label=label.split(" -> ")[0])[0]
            ax.fill_between(steps, [a - b for a, b in zip(m, e, strict=True)],
                            [a + b for a, b in zip(m, e, strict=True)],
                            color=line.get_color(), alpha=0.2)  # fmt: skip
        ax.set_title(f"trained on {world}'s glances (2 glances, 3 seeds)")
        ax.set_xlabel("training steps in this world")
        ax.set_ylabel("accuracy (100 balanced batches)")
        ax.set_ylim(0.2, 1.0)
        ax.legend(title="starting from", loc="lower right")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    png = args.out.with_suffix(".png")
    fig.savefig(png, dpi=110)
    print(f"wrote {args.out} and {png}", file=sys.stderr)

    print("| target, starting from | 0 | " + " | ".join(f"{s:,}" for s in SHOWN) + " |")
    print("|---|---|" + "---|" * len(SHOWN))
    for label in sorted(means, key=lambda k: (targets[k], k)):
        row = [means[label].get(s) for s in (0, *SHOWN)]
        cells = ["—" if c is None else format_mean_sem(c["mean"], c["sem"], c["n"]) for c in row]
        print(f"| {targets[label]}, {label.split(' -> ')[0]} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
