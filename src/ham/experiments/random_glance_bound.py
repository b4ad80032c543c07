"""How well can any classifier do from random glances? A Bayes estimate from a glance table.

    .venv/bin/python -m ham.experiments.random_glance_bound [--table FILE] [--tolerance 1e-6]

The random-location model of Table 1 (pi_rloc) glances at poses drawn uniformly from [-1, 1]^2.
The world is deterministic: object and pose fix the image. A classifier that knows the poses and
sees the images can only confuse objects whose images agree at every glance, so the best possible
accuracy with a uniform prior is the mean over objects i of 1 / |{j : images of j and i agree at
all S glances}|. Images "agree" when their L2-normalized versions (the agent's input) differ by at
most ``--tolerance`` in L2 norm; the default (1e-6: equal images) makes the result an upper bound
for any classifier of random glances, larger tolerances lower it. Estimated by Monte Carlo over
random pose sequences drawn as the agent draws them (uniform actions, nearest table entry). ``--phi-max`` restricts the angle to
|q_phi| <= that fraction, to see how much the steep tilts cost.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import torch

from ham.world.config import WorldConfig
from ham.world.sensor import normalize
from ham.world.table import GlanceTable, build_table, grid_values, nearest_index


def agreement(table: GlanceTable, tolerance: float) -> np.ndarray:
    """``(grid, grid, n, n)`` bool: do objects i and j give the same image at this pose?"""
    p = normalize(table.pressure.double(), "l2")  # (n, g, g, N^2)
    p = p.permute(1, 2, 0, 3).reshape(-1, table.n_objects, table.pressure_dim)
    d = torch.cdist(p, p)
    return (
        (d <= tolerance).reshape(table.grid, table.grid, table.n_objects, table.n_objects).numpy()
    )


def bound(same: np.ndarray, glances: int, samples: int, phi_max: float, rng) -> tuple[float, float]:
    """Monte Carlo Bayes accuracy after ``glances`` random glances, with its standard error."""
    g = same.shape[0]
    acc = np.empty(samples)
    chunk = 20_000
    for s in range(0, samples, chunk):
        n = min(chunk, samples - s)
        both = np.ones((n,) + same.shape[2:], dtype=bool)
        for _ in range(glances):
            qx = torch.from_numpy(rng.uniform(-1, 1, n))
            qp = torch.from_numpy(rng.uniform(-phi_max, phi_max, n))
            ix, ip = nearest_index(qx, g).numpy(), nearest_index(qp, g).numpy()
            both &= same[ix, ip]
        acc[s : s + n] = (1.0 / both.sum(-1)).mean(-1)
    return float(acc.mean()), float(acc.std(ddof=1) / np.sqrt(samples))


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--table", default=None, help="glance table (default: build the default world's, 201 x 201)"
    )
    ap.add_argument("--tolerance", type=float, default=1e-6)
    ap.add_argument("--samples", type=int, default=200_000)
    ap.add_argument("--glances", type=int, nargs="+", default=[1, 2, 3, 4, 6, 8, 10])
    ap.add_argument("--phi-max", type=float, nargs="+", default=[1.0, 0.6])
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = args.table
        if path is None:
            path = Path(tmp) / "table.h5"
            build_table(WorldConfig(), 201, path, progress=False)
        table = GlanceTable.load(path)
    same = agreement(table, args.tolerance)
    empty = ~table.extras["contact"].astype(bool)
    print(f"table {path if args.table else 'default world, 201 x 201'}: objects {table.objects}")
    print(
        f"tolerance {args.tolerance} (L2, normalized images); {args.samples:,} pose sequences each"
    )
    rng = np.random.default_rng(args.seed)
    g = table.grid
    q = grid_values(g)
    for f in args.phi_max:
        rows = np.abs(q) <= f + 1e-12
        share_empty = empty[:, :, rows].mean()
        print(
            f"\n|q_phi| <= {f:g} (|phi| <= {f * 90:g} deg): empty images {share_empty:.1%} of glances"
        )
        print("glances | Bayes accuracy of random glances")
        for s in args.glances:
            m, se = bound(same, s, args.samples, f, rng)
            print(f"{s:7d} | {m:.3f} +- {se:.4f}")


if __name__ == "__main__":
    main()
