"""The agent half of ``make demo``: train a HAM briefly on the demo's glance table, evaluate it,
and write its training curve, pose heat map and a short report (see :mod:`ham.experiments.demo`)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from ham.experiments.figures import plot_heatmap, plot_training_curve
from ham.learn.evaluation import evaluate, heatmap_data
from ham.learn.train import TrainConfig, load_run, resume, train
from ham.model.agent import HamConfig
from ham.world.files import write_json, write_text

#: The demo's run: the paper's network and training rule at 3 glances, shortened.
DEMO_TRAIN = TrainConfig(model=HamConfig(glances=3), steps=1500, eval_every=100, eval_batches=20)


def run_agent_demo(out: Path, table: Path, *, quick: bool = False) -> dict:
    config = replace(DEMO_TRAIN, table=str(table))
    if quick:
        config = replace(config, steps=20, eval_every=10, eval_batches=2)
    run_dir = out / "ham"
    if (run_dir / "checkpoint.pt").exists():
        metrics = resume(run_dir, steps=config.steps)  # an interrupted demo goes on
    else:
        metrics = train(config, run_dir)
    curve = plot_training_curve(metrics, out / "training_curve.png")
    run = load_run(run_dir)
    result = evaluate(run.agent, run.env, batches=10 if quick else 100, seed=12345)
    heat = heatmap_data(run.agent, run.env, batches=5 if quick else 200)
    heatmap = plot_heatmap(heat, out / "heatmap.png")
    summary = {
        "run": str(run_dir),
        "steps": metrics["steps"],
        "best_accuracy": metrics["best_accuracy"],
        "evaluation": result.to_dict(),
        "training_curve": str(curve),
        "heatmap": str(heatmap),
    }
    per = ", ".join(f"{a:.3f}" for a in result.accuracy_per_glance)
    write_text(
        out / "report.md",
        "# ham demo\n\n"
        f"Glance table `{table.name}`, then a HAM "
        f"with {config.model.glances} glances trained for {metrics['steps']} steps "
        f"(seed {config.seed}) and evaluated on {result.episodes} fresh balanced episodes.\n\n"
        f"- accuracy after the last glance: **{result.accuracy:.3f}** (paper, 3 glances: 0.910)\n"
        f"- accuracy after each glance: [{per}]\n"
        f"- best accuracy during training: {metrics['best_accuracy']:.3f}\n\n"
        "![training curve](training_curve.png)\n\n![heat map](heatmap.png)\n\n"
        "Glances on each object: "
        + " ".join(f"![{p.stem}]({p.name})" for p in sorted(out.glob("glance_*.png")))
        + "\n",
        what="report",
    )
    write_json(out / "evaluation.json", summary)
    print(f"HAM: accuracy {result.accuracy:.3f} after {config.model.glances} glances")
    return {"agent": summary}
