"""Where a miss's whereabouts get lost: what the location network reads after a first glimpse
that missed, and how its second pose moves with where the miss was.

    PYTHONPATH=src python docs/results/cs15_search/where.py OUT.json LABEL=RUN_DIR [...]

For ap_gym's ``CircleSquare-s15-nograd-v0`` (search.py's module doc: a miss is a glimpse of all
zeros, so after it the network's input differs between episodes only by where the glimpse was).
Each run (a ``ham train`` folder, its final checkpoint) plays search.py's 100 balanced batches at
its mean poses; on the episodes whose first glimpse missed, with ``w`` where glimpse 1 was
(``[-1, 1]^2``), ``tau`` what the location network read after it (the classifier's core output,
or the policy's own encoder's with ``--encoders separate``) and ``mu`` the mean pose it chose
for glance 2:

- ``where_in_tau``: how much of ``w`` a linear read-out of ``tau`` recovers (R^2, ridge,
  cross-fitted on even and odd batches; 1: ``tau`` tells where the miss was);
- ``tau_spread``: ``tau``'s spread over the misses (root of the summed variances;
  ``tau_spread_misses``) over its spread over all episodes (``tau_spread_all``) (0: every miss
  leaves the same ``tau``);
- ``gain``: the location network's Jacobian ``d mu / d tau`` at the misses (Frobenius norm,
  mean): how strongly the second pose follows its input;
- ``mu_spread``: ``mu``'s spread over the misses (root of the summed variances; 0: one pose
  whatever the miss);
- ``mu_from_w``: how much of ``mu`` a quadratic function of ``w`` explains (R^2, cross-fitted);
- ``away``: search.py's ``away`` of glance 2 after a miss (> 0: past the centre).

Writes OUT.json (per run, and the mean over the runs of a label) and OUT.png: the two spreads
per label; labels ``NAME@STEP`` (one run's checkpoints along the way) as lines over the steps.
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch
from search import BATCHES, SEED, away_from, record_glimpses, summary

from ham.learn.train import load_run


def r2_cross_fitted(x: np.ndarray, y: np.ndarray, half: np.ndarray, ridge: float = 1e-3) -> float:
    """R^2 of ``y`` ``(N, d)`` by a ridge regression on ``x`` ``(N, f)`` fitted on one half of the
    episodes and scored on the other, both ways, pooled over the columns of ``y``."""
    pred = np.zeros_like(y)
    for fit in (0, 1):
        a, b = half == fit, half != fit
        mean, scale = x[a].mean(0), x[a].std(0) + 1e-8
        xa = np.c_[(x[a] - mean) / scale, np.ones(a.sum())]
        xb = np.c_[(x[b] - mean) / scale, np.ones(b.sum())]
        coef = np.linalg.solve(xa.T @ xa + ridge * len(xa) * np.eye(xa.shape[1]), xa.T @ y[a])
        pred[b] = xb @ coef
    return float(1 - ((y - pred) ** 2).sum() / ((y - y.mean(0)) ** 2).sum())


def spread(x: np.ndarray) -> float:
    """The root of the summed variances of the rows of ``x`` ``(N, f)``."""
    return float(np.sqrt(x.var(0).sum()))


def measure(run_dir: str) -> dict:
    """The module doc's measures for one run."""
    run = load_run(run_dir)
    env, agent = run.env, run.agent
    read: list[tuple[torch.Tensor, torch.Tensor]] = []
    choose = agent.next_distribution

    def recording(tau, q, logits=None, glance=None, position=None):
        dist = choose(tau, q, logits, glance, position)
        if glance == 1:
            read.append((tau.detach().clone(), dist.mu.detach().clone()))
        return dist

    agent.next_distribution = recording
    felt = record_glimpses(env)
    generator = torch.Generator(device=env.device)
    generator.manual_seed(SEED)
    agent.eval()
    taus, mus, wheres, hits, halves = [], [], [], [], []
    try:
        with torch.no_grad():
            for b in range(BATCHES):
                read.clear()
                felt.clear()
                objects = env.balanced_objects(b)
                agent(env, objects, generator, greedy=True)
                wheres.append(felt[0][0])
                hits.append(felt[0][1])
                taus.append(read[0][0])
                mus.append(read[0][1])
                halves.append(torch.full((env.batch_size,), b % 2))
        tau, mu = torch.cat(taus), torch.cat(mus)
        w, hit, half = torch.cat(wheres).numpy(), torch.cat(hits).numpy(), torch.cat(halves)
        miss = ~hit
        for m in agent.location.modules():  # the gradient to tau, which the policy detaches
            if hasattr(m, "trains_input"):
                m.trains_input = True
        x = tau[torch.from_numpy(miss)].clone().requires_grad_(True)
        out = agent.location.distribution_at(x, 1).mu
        rows = [torch.autograd.grad(out[:, i].sum(), x, retain_graph=True)[0] for i in (0, 1)]
        gain = torch.stack(rows, 1).flatten(1).norm(dim=1).mean()  # (misses, 2, f) -> (misses,)
    finally:
        run.close()
    tau_np, mu_np, half_np = tau.numpy(), mu.numpy(), half.numpy()
    wm, tm, mm, hm = w[miss], tau_np[miss], mu_np[miss], half_np[miss]
    quad = np.c_[wm, wm**2, wm[:, :1] * wm[:, 1:]]
    return {
        "steps": run.step,
        "misses": int(miss.sum()),
        "where_in_tau": r2_cross_fitted(tm, wm, hm),
        "tau_spread": spread(tm) / spread(tau_np),
        "tau_spread_misses": spread(tm),
        "tau_spread_all": spread(tau_np),
        "gain": float(gain),
        "mu_spread": spread(mm),
        "mu_from_w": r2_cross_fitted(quad, mm, hm),
        "away": float(away_from(wm, mm).mean()),
    }


def main(argv: list[str]) -> None:
    if len(argv) < 2 or not argv[0].endswith(".json") or any("=" not in a for a in argv[1:]):
        sys.exit(__doc__)
    runs: dict[str, list[tuple[str, dict]]] = defaultdict(list)
    for spec in argv[1:]:
        label, run_dir = spec.split("=", 1)
        runs[label].append((run_dir, measure(run_dir)))
        print(label, run_dir, json.dumps(runs[label][-1][1]))
    result = summary("where.py", argv, runs)
    out = Path(argv[0])
    out.write_text(json.dumps(result, indent=1) + "\n")
    plot(result["labels"], out.with_suffix(".png"))


def plot(labels: dict, path: Path) -> None:
    """``tau_spread_misses`` and ``mu_spread`` per label (bars: the mean; dots: the runs); labels
    ``NAME@STEP`` (a run's snapshots) as lines over the training steps in a second panel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = (("tau_spread_misses", "input's spread over misses", "tab:blue"),
            ("mu_spread", "glance 2's spread over misses", "tab:red"))  # fmt: skip
    final = [k for k in labels if "@" not in k]
    series: dict[str, list[tuple[int, dict]]] = defaultdict(list)
    for k in labels:
        if "@" in k:
            name, step = k.rsplit("@", 1)
            series[name].append((int(step), labels[k]["mean"]))
    panels = (1 if final else 0) + (1 if series else 0)
    fig, axes = plt.subplots(1, panels, figsize=(5.2 * panels, 3.6), squeeze=False)
    axes = list(axes[0])
    if final:
        ax = axes.pop(0)
        x = np.arange(len(final))
        for j, (key, name, color) in enumerate(keys):
            pos = x + (j - 0.5) * 0.38
            ax.bar(pos, [labels[k]["mean"][key] for k in final], 0.38, color=color, label=name)
            for p, k in zip(pos, final, strict=True):
                runs = [r[key] for r in labels[k]["runs"].values()]
                ax.scatter([p] * len(runs), runs, s=6, c="k", zorder=3)
        ax.set_xticks(x, final, rotation=30, ha="right", fontsize=8)
        ax.set_yscale("log")
        ax.set_ylabel("spread over first glimpses that missed")
        ax.legend(fontsize=8)
    if series:
        ax = axes.pop(0)
        for (name, points), style in zip(
            sorted(series.items()), ("-", "--", ":", "-."), strict=False
        ):
            points.sort()
            for key, label, color in keys:
                ax.plot([p for p, _ in points], [m[key] for _, m in points], style, color=color,
                        marker="o", ms=3, label=f"{name}: {label}")  # fmt: skip
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("training step")
        ax.legend(fontsize=7)
    fig.suptitle(
        "CircleSquare-s15-nograd: what the location network reads after a miss", fontsize=10
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main(sys.argv[1:])
