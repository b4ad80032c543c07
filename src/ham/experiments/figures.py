"""Figures of a training run: training curve, pose heat map, confusion matrix (PNG, matplotlib Agg).

* :func:`plot_training_curve`: accuracy after the last glance, after each glance and the
  accumulated (averaged-output) accuracy over training steps, from ``metrics.json``
  (the paper's Figs "Classification Accuracy");
* :func:`plot_heatmap`: per object, the last glance's pose binned 20 x 20 over
  ``(x, phi)`` with the learned mean ``(mu_x, mu_phi)`` marked (the paper's heat maps);
* :func:`plot_confusion`: true object x predicted class after a glance, from an evaluation
  (``ham evaluate``, or an evaluation in ``metrics.json``'s history).

Every PNG is written atomically (a temporary file, then renamed).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ham.errors import HamError  # noqa: E402
from ham.world.drawing import save_figure  # noqa: E402

DPI = 120  # the run's figures: a little finer than the world's drawings (110)


def plot_training_curve(metrics: dict, out_png: str | os.PathLike) -> Path:
    """Accuracy over training from a run's metrics (``metrics.json``): a HAM's over training
    steps, a ``ham sb3`` baseline's over environment steps (its evaluations and the final one)."""
    history = metrics.get("history") or []
    baseline = "algo" in metrics  # a ham sb3 run
    if baseline and (not history or history[-1]["env_steps"] != metrics["env_steps"]):
        history = [*history, metrics]  # the final evaluation, at the run's last step
    if not history:
        raise HamError("the metrics hold no evaluation history to plot")
    steps = np.array([h["env_steps" if baseline else "step"] for h in history])
    per_glance = np.array([h["accuracy_per_glance"] for h in history])
    glances = per_glance.shape[1]
    fig, ax = plt.subplots(figsize=(7, 4.2))
    cmap = plt.get_cmap("viridis")
    for s in range(glances - 1):
        ax.plot(steps, per_glance[:, s], color=cmap(s / max(glances - 1, 1)), lw=0.8, alpha=0.6,
                label=f"after glance {s + 1}" if glances <= 6 or s in (0, glances - 2) else None)  # fmt: skip
    ax.plot(steps, per_glance[:, -1], color="k", lw=2, label=f"after the last glance ({glances})")
    if baseline:
        ax.plot(steps, [h["average_accuracy"] for h in history], color="tab:red", lw=1.2,
                ls="--", label="averaged over the glances")  # fmt: skip
        ax.set_title(f"{metrics['algo'].upper()} on {metrics['env']}, {glances} glances")
        ax.set_xlabel("environment steps (glances)")
    else:
        accumulated = np.array([h["accumulated_accuracy_per_glance"] for h in history])
        ax.plot(steps, accumulated[:, -1], color="tab:red", lw=1.2, ls="--",
                label="accumulated (averaged output)")  # fmt: skip
        cfg = metrics.get("config", {}).get("model", {})
        ax.set_title(
            f"HAM, {glances} glances, {cfg.get('core', 'lstm')} core, "
            f"{cfg.get('policy', 'learned')} policy"
        )
        ax.set_xlabel("training step")
    best = metrics.get("best_accuracy")
    if best is not None:
        ax.axhline(best, color="gray", lw=0.6, ls=":")
        ax.text(steps[-1], best, f"best {best:.3f}", ha="right", va="bottom", fontsize=8)
    # the HAM's evaluation batches hold each object equally often; a baseline's episodes draw them
    ax.set_ylabel(
        "accuracy (" + ("evaluation episodes" if baseline else "balanced evaluation") + ")"
    )
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    return save_figure(fig, out_png, dpi=DPI, tight=False)


def plot_heatmap(heatmap_data: dict, out_png: str | os.PathLike) -> Path:
    """One panel per object: where the last glance went, and the learned mean pose; for other
    pose dims than the paper's ``(x, phi)`` every 2-D projection (:func:`plot_projections`)."""
    if heatmap_data.get("projections"):
        return plot_projections(heatmap_data, out_png)
    try:
        counts = np.asarray(heatmap_data["counts"], dtype=float)
        names = list(heatmap_data["objects"])
    except KeyError as exc:
        raise HamError(f"heat map data lacks {exc}") from None
    k = counts.shape[0]
    phi_deg = math.degrees(heatmap_data.get("phi_scale", math.pi / 2))
    extent = (-1, 1, -phi_deg, phi_deg)  # x: q_x; y: phi in degrees
    cols = min(k, 4)
    rows = math.ceil(k / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 3.0 * rows + 0.5), squeeze=False)
    mu = heatmap_data.get("mu_mean")
    mu_std = heatmap_data.get("mu_std")
    for o in range(rows * cols):
        ax = axes[o // cols][o % cols]
        if o >= k:
            ax.axis("off")
            continue
        total = counts[o].sum()
        frac = counts[o] / total if total else counts[o]
        # counts[o][i][j]: q_x bin i, q_phi bin j -> image rows = phi, columns = x
        im = ax.imshow(frac.T, origin="lower", extent=extent, aspect="auto", cmap="magma")
        if mu is not None:
            mx, mp = mu[o]
            sx, sp = mu_std[o] if mu_std is not None else (0.0, 0.0)
            ax.errorbar(mx, mp * phi_deg, xerr=sx, yerr=sp * phi_deg, fmt="x", color="cyan",
                        ms=8, mew=2, capsize=3, label="mean $\\mu$")  # fmt: skip
        ax.set_title(f"{o}: {names[o]}", fontsize=10)
        ax.set_xlabel("x (normalized)")
        if o % cols == 0:
            ax.set_ylabel("phi (degrees)")
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03)
    glances = heatmap_data.get("glances", "?")
    fig.suptitle(
        f"pose of the last glance ({glances} glances, {heatmap_data.get('policy', '')} policy, "
        f"{heatmap_data.get('batches', '?')} batches; accuracy {heatmap_data.get('accuracy', float('nan')):.3f})",
        fontsize=10,
    )
    fig.tight_layout()
    return save_figure(fig, out_png, dpi=DPI, tight=False)


def plot_projections(heatmap_data: dict, out_png: str | os.PathLike) -> Path:
    """The last glance's k-D pose as 2-D projections: one row per object (and a first row over
    all objects), one column per pair of pose dims, normalized units; the learned mean pose
    (policy mode) marked."""
    try:
        projections = heatmap_data["projections"]
        names = list(heatmap_data["objects"])
        dims = list(heatmap_data["pose_dims"])
    except KeyError as exc:
        raise HamError(f"heat map data lacks {exc}") from None
    mu = heatmap_data.get("mu_mean")
    rows, cols = len(names) + 1, len(projections)
    fig, axes = plt.subplots(
        rows, cols, figsize=(2.1 * cols + 0.6, 1.9 * rows + 0.6), squeeze=False
    )
    for j, proj in enumerate(projections):
        counts = np.asarray(proj["counts"], dtype=float)
        a, b = proj["dims"]
        for i in range(rows):
            ax = axes[i][j]
            c = counts.sum(0) if i == 0 else counts[i - 1]
            total = c.sum()
            ax.imshow((c / total if total else c).T, origin="lower", extent=(-1, 1, -1, 1),
                      aspect="equal", cmap="magma")  # fmt: skip
            if i > 0 and mu is not None and b is not None:
                m = mu[i - 1]
                ax.plot(m[dims.index(a)], m[dims.index(b)], "x", color="cyan", ms=6, mew=2)
            ax.set_xticks([])
            ax.set_yticks([])
            if i == rows - 1:
                ax.set_xlabel(f"q_{a}", fontsize=8)
            if j == 0:
                ax.set_ylabel("all" if i == 0 else names[i - 1], fontsize=7)
            if i == 0:
                ax.set_title(f"q_{a} vs q_{b}" if b else f"q_{a}", fontsize=8)
    fig.suptitle(
        f"pose of the last glance, {len(dims)}-D ({','.join(dims)}), projections "
        f"({heatmap_data.get('glances', '?')} glances, {heatmap_data.get('policy', '')} policy; "
        f"accuracy {heatmap_data.get('accuracy', float('nan')):.3f})",
        fontsize=9,
    )
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.35 / fig.get_figheight()))
    return save_figure(fig, out_png, dpi=DPI, tight=False)


def plot_confusion(
    confusion,
    objects: list[str],
    out_png: str | os.PathLike,
    *,
    title: str | None = None,
) -> Path:
    """The confusion matrix ``confusion[true][predicted]`` (counts, ``K x K``) as an image:
    each row normalized to the share of that object's episodes (the diagonal is the per-object
    accuracy), with the counts written in the cells when ``K <= 12``."""
    counts = np.asarray(confusion, dtype=float)
    k = len(objects)
    if counts.shape != (k, k):
        raise HamError(
            f"confusion matrix of shape {counts.shape}; accepted: ({k}, {k}) for {k} objects"
        )
    if not (np.isfinite(counts).all() and (counts >= 0).all()):
        raise HamError("confusion matrix with negative or non-finite counts; accepted: counts >= 0")
    shown = counts.sum(1, keepdims=True)
    share = np.divide(counts, shown, out=np.zeros_like(counts), where=shown > 0)
    size = min(2.0 + 0.7 * k, 12.0)
    fig, ax = plt.subplots(figsize=(size + 1.6, size))
    im = ax.imshow(share, cmap="Blues", vmin=0, vmax=1)
    names = [str(o) for o in objects]
    ax.set_xticks(range(k), names, rotation=45 if k > 4 else 0, ha="right" if k > 4 else "center")
    ax.set_yticks(range(k), [f"{n} ({int(c)})" for n, c in zip(names, shown[:, 0], strict=True)])
    if k <= 12:
        for i in range(k):
            for j in range(k):
                ax.text(j, i, f"{int(counts[i, j])}\n{share[i, j]:.2f}", ha="center",
                        va="center", fontsize=8,
                        color="white" if share[i, j] > 0.6 else "black")  # fmt: skip
    ax.set_xlabel("predicted")
    ax.set_ylabel("true object (episodes)")
    total = counts.sum()
    accuracy = np.trace(counts) / total if total else float("nan")
    ax.set_title(title or f"confusion matrix, accuracy {accuracy:.3f}", fontsize=10)
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03, label="share of the row")
    return save_figure(fig, out_png, dpi=DPI)  # cropped: the object names are long
