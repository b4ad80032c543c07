"""Our runs of docs/grids/apple_mhsb.toml beside the APPLE study's released curves, by environment steps.

python docs/results/apple_mhsb/summarize.py RUNS_OUT OUT_DIR

RUNS_OUT is the --out folder of docs/grids/apple_mhsb.toml or apple_mhsb_loss.toml
(runs/<variant>-s<seed>/metrics.json); OUT_DIR gets summary.json, table.md,
accuracy_vs_env_steps.png and training_accuracy.png (each seed's training accuracy); --variants V ... keeps only those variants. Our numbers: the
evaluation during training (10 batches of 64 episodes, mean poses), the grid's final evaluations
(50 batches), and how steady training is: each seed's training accuracy (the last glance's
reward on the training batches, sampled poses) averaged over the evaluations in the second half
of its run; mean, s.e.m. and count over seeds (ham.experiments.reproduce.mean_sem). APPLE's
numbers are quoted, not computed here (below).
"""

import argparse
import json
import math
import re
from pathlib import Path

from ham.experiments.reproduce import format_mean_sem, mean_sem

# APPLE's released evaluation curves on HAMTactileClassification-v0 ("MHSB"), final-glance
# accuracy, mean over their seeds, read off github.com/TimSchneider42/apple at
# data/HAMTactileClassification-v0/<agent>/eval_final.csv (commit 4b1d71f) at the row nearest to
# each point; their rows lie every ~20,000 environment steps (102,000 for ham_long).
APPLE = {
    "APPLE SAC": {23_277: 0.811, 63_766: 0.900, 104_256: 0.954, 205_480: 0.992, 995_028: 0.989},
    "APPLE CrossQ": {23_277: 0.759, 63_766: 0.893, 104_256: 0.967, 205_480: 0.997, 995_028: 1.000},
    "APPLE random actions": {
        23_277: 0.714,
        63_766: 0.821,
        104_256: 0.911,
        205_480: 0.990,
        995_028: 1.000,
    },
    "APPLE HAM": {20_447: 0.485, 61_262: 0.462, 102_077: 0.509, 204_113: 0.501, 1_000_000: 0.677},
    # ham_long/eval_final.csv: the same agent for 5,000,000 steps
    "APPLE HAM, 5M run": {1_019_624: 0.682, 2_039_207: 0.867, 3_058_791: 0.970, 4_996_000: 0.978},
}
POINTS = (32_000, 64_000, 96_000, 192_000, 496_000, 1_000_000)  # multiples of 16,000
NAME = re.compile(r"^(?P<variant>.+)-s(?P<seed>\d+)$")
LABEL = {
    "ham": "ours: the paper's HAM (hybrid loss)",
    "ham-first-learned": "ours: the paper's HAM, first glance learned",
    "random-locations": "ours: random locations",
    # docs/grids/apple_mhsb_loss.toml: APPLE's classification loss, one part at a time
    "ham-mean-loss": "ours: the paper's HAM, loss a batch mean",
    "ham-mean-loss-first-learned": "ours: the paper's HAM, loss a batch mean, first glance learned",
    "ham-all-glances": "ours: the paper's HAM, every glance's prediction trained",
    "ham-apple-loss": "ours: the paper's HAM with APPLE's loss (every glance, batch mean)",
    "ham-apple-loss-first-learned": "ours: APPLE's loss and first glance learned",
    "ham-apple-loss-first-learned-apple-lr": "ours: APPLE's loss, first glance and lr schedule",
    "ham-apple-reward": "ours: the paper's HAM with APPLE's reward (every glance, gamma 0.99)",
    "ham-apple-loss-first-learned-apple-reward": "ours: APPLE's loss, first glance and reward",
    "ham-apple-loss-first-learned-apple-reward-apple-lr": "ours: APPLE's loss, first glance, "
    "reward and lr schedule",
    "ham-apple-reward-beta-0.04": "ours: the paper's HAM with APPLE's reward, beta 0.04",
    "ham-apple-loss-first-learned-apple-reward-beta-0.04": "ours: APPLE's loss, first glance and "
    "reward, beta 0.04",
    "ham-apple-loss-first-learned-apple-reward-3M": "ours: APPLE's loss, first glance and "
    "reward, 3M steps",
    "ham-separate-encoders": "ours: the paper's HAM with separate encoders",
    "ham-apple-loss-first-learned-separate-encoders": "ours: APPLE's loss and first glance, "
    "separate encoders",
    "ham-apple-loss-first-learned-apple-reward-separate-encoders": "ours: APPLE's loss, first "
    "glance, reward and separate encoders",
    "ham-apple-loss-first-learned-apple-reward-beta-0.04-separate-encoders": "ours: APPLE's "
    "loss, first glance, reward and separate encoders, beta 0.04",
    "ham-apple-all": "ours: APPLE's loss, first glance, reward, step means and separate encoders",
    "ham-apple-all-3M": "ours: APPLE's loss, first glance, reward, step means and separate "
    "encoders, 3M steps",
    "info-early": "ours: info learner (its first 32k evaluated every 800)",
    "info": "ours: info learner",
}


def at(history: list[dict], env_steps: int) -> float:
    """The accuracy of the last evaluation at or before ``env_steps``."""
    rows = [h for h in history if h["env_steps"] <= env_steps]
    return rows[-1]["accuracy"]


def late_training(history: list[dict]) -> float:
    """The mean training accuracy (``train_reward``) of the evaluations in the second half of
    the run."""
    half = history[-1]["env_steps"] / 2
    rows = [h["train_reward"] for h in history if h["env_steps"] > half]
    return sum(rows) / len(rows)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("runs_out", type=Path)
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("--variants", nargs="+", metavar="V", help="only these variants")
    args = ap.parse_args()
    unknown = set(args.variants or ()) - set(LABEL)
    if unknown:
        ap.error(f"--variants {' '.join(sorted(unknown))}: unknown; accepted: {', '.join(LABEL)}")
    runs: dict[str, list[dict]] = {}
    for metrics in sorted(args.runs_out.glob("runs/*/metrics.json")):
        match = NAME.match(metrics.parent.name)
        if args.variants and match["variant"] not in args.variants:
            continue
        m = json.loads(metrics.read_text())
        finals = {}
        for f in metrics.parent.glob("eval_*_seed12345.json"):
            e = json.loads(f.read_text())
            finals[e["eval_policy"]] = e["accuracy"]
        runs.setdefault(match["variant"], []).append(
            {"seed": int(match["seed"]), "history": m["history"], "finals": finals, "metrics": m}
        )
    summary = {}
    for variant, rs in runs.items():
        hist = [r["history"] for r in rs]
        summary[variant] = {
            "seeds": [r["seed"] for r in rs],
            "env_steps": min(h[-1]["env_steps"] for h in hist),
            "at": {p: mean_sem([at(h, p) for h in hist]) for p in POINTS},
            # the trainer's own: the first evaluation at or above the level
            "to_0.95": [r["metrics"]["env_steps_to_0.95"] for r in rs],
            "to_0.99": [r["metrics"]["env_steps_to_0.99"] for r in rs],
            "final_mean_poses": mean_sem([r["finals"]["mean"] for r in rs]),
            "final_sampled_poses": mean_sem([r["finals"]["sample"] for r in rs]),
            "late_training_accuracy": [late_training(h) for h in hist],
        }
    args.out_dir.mkdir(parents=True, exist_ok=True)
    (args.out_dir / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")

    head = " | ".join(f"{p // 1000}k" for p in POINTS)
    lines = [
        f"| agent | {head} | env steps to 0.95 | to 0.99 | final (50 batches): mean poses / "
        "sampled | training accuracy, 2nd half (per seed) |",
        "|---" * (len(POINTS) + 5) + "|",
    ]
    for variant in LABEL:
        if variant not in summary:
            continue
        s = summary[variant]
        last = s["env_steps"]
        cells = " | ".join(format_mean_sem(*s["at"][p]) if p <= last else "" for p in POINTS)
        reach = [
            "/".join("-" if v is None else f"{v / 1000:g}k" for v in s[k])
            for k in ("to_0.95", "to_0.99")
        ]
        final = f"{format_mean_sem(*s['final_mean_poses'])} / {format_mean_sem(*s['final_sampled_poses'])}"
        late = " / ".join(f"{v:.3f}" for v in s["late_training_accuracy"])
        lines.append(f"| {LABEL[variant]} | {cells} | {reach[0]} | {reach[1]} | {final} | {late} |")
    (args.out_dir / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 6))
    colors = {}
    for variant, rs in sorted(runs.items(), key=lambda kv: list(LABEL).index(kv[0])):
        # drop the evaluation before training (0 steps: not on a log axis); the info run draws on
        # from where info-early ends, in its colour
        start = 32_000 if variant == "info" and "info-early" in runs else 1
        rows = [[h for h in r["history"] if h["env_steps"] >= start] for r in rs]
        xs = [h["env_steps"] for h in rows[0]]
        ms = [mean_sem([r[i]["accuracy"] for r in rows]) for i in range(len(xs))]
        mean = [m for m, _, _ in ms]
        sem = [0.0 if math.isnan(e) else e for _, e, _ in ms]
        label = None if variant == "info" else f"{LABEL[variant]} ({len(rs)} seeds)"
        color = colors.get("info-early") if variant == "info" else None
        (line,) = ax.plot(xs, mean, label=label, color=color)
        colors[variant] = line.get_color()
        ax.fill_between(
            xs,
            [m - e for m, e in zip(mean, sem, strict=True)],
            [m + e for m, e in zip(mean, sem, strict=True)],
            color=line.get_color(),
            alpha=0.2,
        )
    for name, pts in APPLE.items():
        ax.plot(list(pts), list(pts.values()), "o--", ms=4, lw=1, label=f"{name} (released curve)")
    ax.set_xscale("log")
    ax.set_xlabel("environment steps (glances)")
    ax.set_ylabel("accuracy after the 10th glance")
    ax.set_ylim(0.2, 1.02)
    ax.set_title(
        "The paper's task at 10 glances: ours (paper-gazebo) and APPLE's (MHSB)", fontsize=10
    )
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(args.out_dir / "accuracy_vs_env_steps.png", dpi=120, bbox_inches="tight")
    plt.close(fig)

    # how steady training is: each seed's training accuracy, one panel per variant
    shown = [v for v in LABEL if v in runs and v != "info-early"]
    cols = 2 if len(shown) > 1 else 1
    rows = math.ceil(len(shown) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 2.2 * rows), sharey=True,
                             squeeze=False)  # fmt: skip
    for ax, variant in zip(axes.flat, shown, strict=False):
        for r in sorted(runs[variant], key=lambda r: r["seed"]):
            rows_ = [h for h in r["history"] if h["env_steps"] > 0]
            ax.plot([h["env_steps"] for h in rows_], [h["train_reward"] for h in rows_], lw=0.8,
                    label=f"seed {r['seed']}")  # fmt: skip
        ax.set_title(LABEL[variant].removeprefix("ours: "), fontsize=8)
        ax.set_xscale("log")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
    for ax in axes.flat[len(shown) :]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.supxlabel("environment steps (glances)", fontsize=9)
    fig.supylabel("training accuracy (sampled poses)", fontsize=9)
    fig.tight_layout()
    fig.savefig(args.out_dir / "training_accuracy.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
