"""Glance speed: vectorized vs a per-glance Python loop of the same model, table build, lookup.

Run: ``.venv/bin/python benchmarks/bench_glance.py`` (add ``--threads N`` to use more cores).
Prints a table; targets (issue 2): >= 500k glances/s per core, the 4 x 201 x 201 table in <= 5 s,
lookup >= 1M/s. Everything is measured side by side in one run: this machine is noisy.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import torch

from ham.world.config import WorldConfig, make_simulator
from ham.world.table import GlanceTable, build_table


def best_rate(fn, n_items: int, repeats: int = 3) -> float:
    fn()  # warm-up
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return n_items / best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--batch", type=int, default=262_144)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    g = torch.Generator().manual_seed(0)
    sim = make_simulator(WorldConfig())
    n = args.batch
    ids = torch.randint(0, 4, (n,), generator=g)
    qx = torch.rand(n, generator=g) * 2 - 1
    qp = torch.rand(n, generator=g) * 2 - 1

    vec = best_rate(lambda: sim.glance(ids, qx, qp), n)
    m = 300
    loop = best_rate(
        lambda: [sim.glance(ids[i : i + 1], qx[i : i + 1], qp[i : i + 1]) for i in range(m)], m
    )

    with tempfile.TemporaryDirectory() as d:
        t = time.perf_counter()
        path = build_table(WorldConfig(), 201, Path(d) / "t.h5", progress=False)
        build_s = time.perf_counter() - t
        table = GlanceTable.load(path)
        rates = {}
        for b in (640, 4096, 1_000_000):
            bi = torch.randint(0, 4, (b,), generator=g)
            bx = torch.rand(b, generator=g) * 2 - 1
            bp = torch.rand(b, generator=g) * 2 - 1
            reps = max(1, 2_000_000 // b)

            def run(bi=bi, bx=bx, bp=bp, reps=reps):
                for _ in range(reps):
                    table.lookup(bi, bx, bp, check=False)

            rates[b] = best_rate(run, b * reps)

    rows = [
        ("vectorized glances/s", f"{vec:,.0f}", f"{vec / 500_000:.2f}x of 500k target"),
        ("per-glance loop glances/s", f"{loop:,.0f}", f"vectorized is {vec / loop:,.0f}x faster"),
        (
            "4 x 201 x 201 table build (s)",
            f"{build_s:.2f}",
            f"{5.0 / build_s:.2f}x under the 5 s target",
        ),
    ]
    for b, r in rates.items():
        rows.append((f"table lookups/s (batch {b:,})", f"{r:,.0f}", f"{r / 1e6:.2f}x of 1M target"))
    print(f"torch threads: {args.threads}; batch {n:,}")
    print(f"| {'measure':<34} | {'value':>14} | {'ratio':<32} |")
    print(f"|{'-' * 36}|{'-' * 16}|{'-' * 34}|")
    for name, val, ratio in rows:
        print(f"| {name:<34} | {val:>14} | {ratio:<32} |")


if __name__ == "__main__":
    main()
