"""The paper's figures from a reproduction's finished runs (section "Results").

* ``curves.png``: accuracy during training per number of glances (full model), mean over seeds;
* ``per_glance.png``: accuracy after each glance within one episode of the longest runs;
* ``learned_vs_random.png``: learned location policy (solid) vs random locations (dashed);
* ``heatmap_g{G}.png``: the last glance's poses per object (20 x 20 bins) of the full model;
* ``mu_evolution.png``: the learned means ``mu_x, mu_phi`` of the last glance during training,
  when the runs recorded them.
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ham.world.drawing import save_figure  # noqa: E402
from ham.world.files import write_json  # noqa: E402


def _histories(root: Path, jobs, variant: str, glances: int) -> list[list[dict]]:
    from ham.experiments.runs import run_dir

    out = []
    for j in jobs:
        if j.variant == variant and j.combiner == "concat2" and j.glances == glances:
            p = run_dir(root, j.key) / "metrics.json"
            if p.exists():
                out.append(json.loads(p.read_text()).get("history", []))
    return [h for h in out if h]


def _mean_curve(histories: list[list[dict]], key: str = "accuracy"):
    n = min(len(h) for h in histories)
    steps = np.array([r["step"] for r in histories[0][:n]])
    vals = np.array([[r[key] for r in h[:n]] for h in histories])
    return steps, vals.mean(0)


def _save_drawn(fig, ax, path: Path, curves: int, **legend) -> list[Path]:
    """``[path]`` with the figure saved when ``curves`` were drawn on ``ax``; else ``[]``
    (closed, not written: ``--variants mlp`` runs neither the full model nor random locations)."""
    if not curves:
        plt.close(fig)
        return []
    if any(not line.get_label().startswith("_") for line in ax.get_lines()):
        ax.legend(**legend)  # only labelled curves: random locations alone have none
    return [save_figure(fig, path)]


def draw_figures(root: Path, jobs, profile) -> list[Path]:
    root = Path(root)
    figs = root / "figures"
    figs.mkdir(exist_ok=True)
    written: list[Path] = []
    colors = plt.cm.viridis(np.linspace(0, 0.9, len(profile.glances)))

    fig, ax = plt.subplots(figsize=(6.4, 4))
    curves = 0
    for c, g in zip(colors, profile.glances, strict=True):
        hs = _histories(root, jobs, "full", g)
        if hs:
            ax.plot(*_mean_curve(hs), color=c, label=f"{g} glance{'s' * (g > 1)}")
            curves += 1
    ax.set(xlabel="training step", ylabel="accuracy", title="Full model: accuracy during training")
    ax.axhline(0.25, color="0.6", ls=":", lw=1)
    written += _save_drawn(fig, ax, figs / "curves.png", curves, fontsize=8)

    fig, ax = plt.subplots(figsize=(6.4, 4))
    curves = 0
    for c, g in zip(colors, profile.glances, strict=True):
        for variant, ls in (("full", "-"), ("rloc", "--")):
            hs = _histories(root, jobs, variant, g)
            if hs:
                label = f"{g} glance{'s' * (g > 1)}" if variant == "full" else None
                ax.plot(*_mean_curve(hs), color=c, ls=ls, label=label)
                curves += 1
    ax.set(
        xlabel="training step",
        ylabel="accuracy",
        title="Learned (solid) vs random (dashed) locations",
    )
    written += _save_drawn(fig, ax, figs / "learned_vs_random.png", curves, fontsize=8)

    g_max = max(profile.glances)
    fig, ax = plt.subplots(figsize=(6.4, 4))
    curves = 0
    for variant, style in (("full", "o-"), ("rloc", "s--")):
        hs = _histories(root, jobs, variant, g_max)
        if hs:
            per = np.array([h[-1]["accuracy_per_glance"] for h in hs]).mean(0)
            ax.plot(np.arange(1, len(per) + 1), per, style, label=variant)
            curves += 1
    ax.set(xlabel="glance within the episode", ylabel="accuracy after this glance",
           title=f"Accuracy of each glance ({g_max}-glance episodes, last evaluation)")  # fmt: skip
    written += _save_drawn(fig, ax, figs / "per_glance.png", curves)

    written += _heatmaps(root, jobs, profile, figs)
    mu = _mu_evolution(root, jobs, g_max, figs)
    if mu is not None:
        written.append(mu)
    return written


def _heatmaps(root: Path, jobs, profile, figs: Path) -> list[Path]:
    from ham.experiments.figures import plot_heatmap
    from ham.experiments.runs import is_finished, run_dir
    from ham.learn.evaluation import heatmap_data
    from ham.learn.train import load_run

    out = []
    for g in sorted({3, max(profile.glances)} & set(profile.glances)):
        key = next(
            (
                j.key
                for j in jobs
                if (j.variant, j.combiner, j.glances, j.seed) == ("full", "concat2", g, 0)
            ),
            None,
        )
        if key is None or not is_finished(run_dir(root, key), profile.steps):
            continue
        run = load_run(run_dir(root, key))
        data = heatmap_data(run.agent, run.env, batches=profile.heatmap_batches)
        write_json(figs / f"heatmap_g{g}.json", data)
        out.append(plot_heatmap(data, figs / f"heatmap_g{g}.png"))
    return out


def _mu_evolution(root: Path, jobs, glances: int, figs: Path) -> Path | None:
    hs = _histories(root, jobs, "full", glances)
    if not hs or "mu_mean" not in hs[0][-1] or hs[0][-1]["mu_mean"] is None:
        return None
    h = hs[0]
    steps = [r["step"] for r in h if r.get("mu_mean") is not None]
    mu = np.array([r["mu_mean"] for r in h if r.get("mu_mean") is not None])  # (T, objects, 2)
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6), sharex=True)
    for o in range(mu.shape[1]):
        axes[0].plot(steps, mu[:, o, 0], label=f"object {o}")
        axes[1].plot(steps, mu[:, o, 1], label=f"object {o}")
    axes[0].set(xlabel="training step", ylabel="mu_x (last glance)")
    axes[1].set(xlabel="training step", ylabel="mu_phi (last glance)")
    axes[0].legend(fontsize=8)
    fig.suptitle(f"Learned means during training ({glances} glances, seed 0)")
    return save_figure(fig, figs / "mu_evolution.png")
