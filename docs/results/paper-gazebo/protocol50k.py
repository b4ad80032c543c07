"""Add cells to protocol50k.json from the run folders of `ham reproduce` (the paper's protocol).

    python docs/results/paper-gazebo/protocol50k.py CELL RUN_DIR [RUN_DIR ...]
e.g. `protocol50k.py preset-g3 runs/gz-paper/runs/full-concat2-g3-s*`: per seed the best and the
final accuracy, the steps run (a run stopped at a perfect evaluation ends early), mean ± s.e.m.
of the best, and the mean over the seeds of the best accuracy so far at a few steps (a stopped
run keeps its best, 1.000, from its stop on), and the curve a plot draws (`mean_curve`: each
evaluation's mean accuracy over the seeds), so that figures outlive the run folders.

    python docs/results/paper-gazebo/protocol50k.py plot OUT.png TITLE LABEL:PAPER:GLOB [...]

draws each cell's accuracy during training (the mean over the seeds of every evaluation, the runs
matched by the glob GLOB) with the paper's number PAPER as a dashed line of the same colour. A
spec written `avg=LABEL:PAPER:GLOB` draws the accuracy of the outputs averaged over the glances
(the paper's <pi_MLP>) instead. GLOB written `cell=NAME` draws the `mean_curve` stored in
protocol50k.json's cell NAME (for a cell whose run folders are gone).

    python docs/results/paper-gazebo/protocol50k.py poses TABLE RUN_DIR [RUN_DIR ...]

prints, per run, where its last glance goes at its last evaluation (the mean location per object)
and how many of the objects one glance there tells apart (the Bayes accuracy of that single glance
on the glance table TABLE, exact images).

    python docs/results/paper-gazebo/protocol50k.py swap OUT.json RUN_DIR [RUN_DIR ...]

evaluates each run with its last glance made at another pose (`ham evaluate --swap-last-pose`:
its own, another episode's of the same object, another object's, a uniform one; sampled poses,
100 batches) and writes the accuracies to OUT.json, and a bar chart of them beside it (OUT.png).

Cells of MLP-core runs also get the averaged outputs' best (`best_accumulated`, the paper's
<pi_MLP> row is scored on the same runs).
"""

import json
import math
import os
import sys
from pathlib import Path

HERE = Path(__file__).parent / "protocol50k.json"
STEPS = (2000, 4000, 10000, 20000, 30000, 40000, 50000)


def _accuracy(entry: dict, averaged: bool) -> float:
    """An evaluation's accuracy: of the last output, or of the outputs averaged over the glances."""
    return entry["accumulated_accuracy_per_glance"][-1] if averaged else entry["accuracy"]


def _mean_sem(xs: list[float]) -> tuple[float, float]:
    n = len(xs)
    mean = sum(xs) / n
    sem = math.sqrt(sum((x - mean) ** 2 for x in xs) / (n - 1)) / math.sqrt(n) if n > 1 else 0.0
    return round(mean, 4), round(sem, 4)


def _so_far(ms: list[dict], averaged: bool) -> dict:
    """The mean over the seeds of the best accuracy up to each of STEPS."""
    by_step = {}
    for s in STEPS:
        if all(m["steps"] < s and not m.get("stopped_at_perfect") for m in ms):
            continue
        so_far = [max(_accuracy(e, averaged) for e in m["history"] if e["step"] <= s) for m in ms]
        by_step[str(s)] = round(sum(so_far) / len(ms), 4)
    return by_step


def _mean_curve(ms: list[dict], averaged: bool = False) -> list[tuple[int, float]]:
    """Every evaluation's ``(step, accuracy)``, the mean over the seeds (up to the shortest run)."""
    n = min(len(m["history"]) for m in ms)
    return [
        (
            ms[0]["history"][i]["step"],
            sum(_accuracy(m["history"][i], averaged) for m in ms) / len(ms),
        )
        for i in range(n)
    ]


def cell(dirs: list[str]) -> dict:
    ms = [json.load(open(Path(d) / "metrics.json")) for d in sorted(dirs)]
    best = [round(m["best_accuracy"], 4) for m in ms]
    n = len(best)
    mean, sem = _mean_sem(best)
    out = {
        "seeds": [m["config"]["seed"] for m in ms],
        "steps": [m["steps"] for m in ms],
        "stopped_at_perfect": [m.get("stopped_at_perfect") for m in ms],
        "best": best,
        "best_mean": mean,
        "best_sem": sem,
        "final": [round(m["final_accuracy"], 4) for m in ms],
        "final_mean": round(sum(m["final_accuracy"] for m in ms) / n, 4),
        "best_so_far_by_step": _so_far(ms, averaged=False),
        # the plot's curve, so that a figure outlives the run folders: [step, mean accuracy]
        "mean_curve": [[step, round(a, 4)] for step, a in _mean_curve(ms)],
    }
    if all(m["config"]["model"]["core"] == "mlp" for m in ms):
        acc = [round(m["best_accumulated_accuracy"], 4) for m in ms]
        mean, sem = _mean_sem(acc)
        out.update(
            best_accumulated=acc,
            best_accumulated_mean=mean,
            best_accumulated_sem=sem,
            best_accumulated_so_far_by_step=_so_far(ms, averaged=True),
        )
    return out


def plot(out: str, title: str, cells: list[str]) -> None:
    import glob

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for k, spec in enumerate(cells):
        averaged = spec.startswith("avg=")
        label, paper, pattern = spec.removeprefix("avg=").split(":", 2)
        if pattern.startswith("cell="):  # a stored cell's curve, its run folders gone
            if averaged:
                sys.exit(f"{spec}: a stored cell keeps the last output's curve only, not avg=")
            stored = json.load(open(HERE))["cells"][pattern.removeprefix("cell=")]
            curve, seeds = stored["mean_curve"], len(stored["seeds"])
        else:
            ms = [json.load(open(Path(d) / "metrics.json")) for d in sorted(glob.glob(pattern))]
            curve, seeds = _mean_curve(ms, averaged), len(ms)
        steps, mean = zip(*curve, strict=True)
        color = f"C{k}"
        ax.plot(steps, mean, color=color, lw=1, label=f"{label} ({seeds} seeds)")
        ax.axhline(float(paper), color=color, ls="--", lw=1)
    ax.set_xlabel("training step")
    ax.set_ylabel("accuracy (sampled poses, 6,400 episodes)")
    ax.set_title(title + " (dashed: the paper's best)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    tmp = out + ".tmp"
    fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png")
    os.replace(tmp, out)
    print(out)


def poses(table_path: str, dirs: list[str]) -> None:
    import torch

    from ham.experiments.random_glance_bound import agreement
    from ham.world.table import GlanceTable, nearest_index

    table = GlanceTable.load(table_path)
    one = (1.0 / agreement(table, 1e-6).sum(-1)).mean(-1)  # (grid, grid): one glance's accuracy
    for d in sorted(dirs):
        last = json.load(open(Path(d) / "metrics.json"))["history"][-1]
        head = f"{Path(d).name} (final {last['accuracy']:.3f}): "
        if not last["mu_mean"]:  # random locations, or one glance: no learned glance
            print(head + "no learned glance")
            continue
        cells = []
        for x, phi in last["mu_mean"]:
            i, j = (int(nearest_index(torch.tensor(v), table.grid)) for v in (x, phi))
            cells.append(f"({x:+.2f}, {phi:+.2f}): {one[i, j]:.2f}")
        print(head + "; ".join(cells))


def swap(out: str, dirs: list[str]) -> None:
    """Per run, `ham evaluate RUN --swap-last-pose` (sampled poses, 100 batches, seed 12345):
    the accuracy with the last glance at its own pose, at another episode's of the same object,
    at another object's, at a uniform one; written to OUT (JSON) and printed."""
    from ham.learn.evaluation import SWAPS, last_pose_swap
    from ham.learn.train import load_run

    rows = {}
    for d in sorted(dirs):
        run = load_run(d)
        try:
            r = last_pose_swap(run.agent, run.env, 100, seed=12345, policy="sample")
        finally:
            run.close()
        rows[Path(d).name] = {"step": run.step, **r}
        print(Path(d).name, " ".join(f"{k} {r[k]:.4f}" for k in SWAPS))
    tmp = out + ".tmp"
    Path(tmp).write_text(json.dumps(rows, indent=1) + "\n")
    os.replace(tmp, out)
    swap_plot(rows, str(Path(out).with_suffix(".png")))


def swap_plot(rows: dict, out: str) -> None:
    """Bars per cell (the run names without the seed): the mean over the seeds of each swap's
    accuracy, the seeds as dots."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ham.learn.evaluation import SWAPS

    cells: dict[str, list[dict]] = {}
    for name, r in rows.items():
        cells.setdefault(name.rsplit("-s", 1)[0], []).append(r)
    fig, ax = plt.subplots(figsize=(7, 3.6))
    width = 0.8 / len(SWAPS)
    for j, swap in enumerate(SWAPS):
        for i, runs in enumerate(cells.values()):
            xs = i + (j - (len(SWAPS) - 1) / 2) * width
            ys = [r[swap] for r in runs]
            ax.bar(xs, sum(ys) / len(ys), width, color=f"C{j}", label=swap if i == 0 else None)
            ax.plot([xs] * len(ys), ys, "k.", ms=3)
    ax.set_xticks(range(len(cells)), [f"{c}\n({len(r)} seeds)" for c, r in cells.items()],
                  fontsize=8)  # fmt: skip
    ax.set_ylabel("accuracy after the last glance")
    ax.set_ylim(0, 1.05)
    ax.set_title("the last glance at its own pose or another's (sampled poses, 6,400 episodes)",
                 fontsize=9)  # fmt: skip
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=7, ncol=4, loc="lower left")
    tmp = out + ".tmp"
    fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png")
    os.replace(tmp, out)
    print(out)


def main() -> None:
    if sys.argv[1] == "plot":
        plot(sys.argv[2], sys.argv[3], sys.argv[4:])
        return
    if sys.argv[1] == "poses":
        poses(sys.argv[2], sys.argv[3:])
        return
    if sys.argv[1] == "swap":
        swap(sys.argv[2], sys.argv[3:])
        return
    name, dirs = sys.argv[1], sys.argv[2:]
    data = json.load(open(HERE))
    data["cells"][name] = cell(dirs)
    tmp = HERE.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(data, indent=1) + "\n")
    os.replace(tmp, HERE)
    print(name, json.dumps(data["cells"][name]))


if __name__ == "__main__":
    main()
