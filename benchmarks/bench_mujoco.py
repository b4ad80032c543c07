"""Glances per second of the MuJoCo simulator, and the projected time of the paper's glance table.

The paper's pre-recorded data set is a 201 x 201 grid of poses per object (section "Classification
Task"; docs/sources.md), 4 x 201 x 201 = 161,604 glances. This benchmark times MuJoCo glances on a
seeded random sample of that grid (all phi, so steep tilts are included in their true share), on
one thread and on all cores, beside the fast simulator, and prints the projection.

    .venv/bin/python benchmarks/bench_mujoco.py              # taxels read-out, 2000 glances
    .venv/bin/python benchmarks/bench_mujoco.py --readout gazebo --n 1000

Target (issue 3): the whole table in <= 10 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch

from ham.world.glance import FastSimulator
from ham.world.mujoco_sim import STATUS_NAMES, MujocoSimulator
from ham.world.objects import resolve_set
from ham.world.sensor import SensorConfig

GRID = 201


def sample_grid(n: int, n_objects: int, seed: int = 0):
    """``n`` poses drawn without replacement from the n_objects x 201 x 201 table grid."""
    rng = np.random.default_rng(seed)
    flat = rng.choice(n_objects * GRID * GRID, size=n, replace=False)
    ids, rest = np.divmod(flat, GRID * GRID)
    ix, ip = np.divmod(rest, GRID)
    q = np.linspace(-1.0, 1.0, GRID)
    return ids, q[ix], q[ip]


def time_glances(sim, ids, qx, qp, batch: int) -> tuple[float, object]:
    sim.glance(ids[:8], qx[:8], qp[:8])  # warm-up: threads, model copies
    t0 = time.perf_counter()
    results = [
        sim.glance(ids[i : i + batch], qx[i : i + batch], qp[i : i + batch])
        for i in range(0, len(ids), batch)
    ]
    return time.perf_counter() - t0, results


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--n", type=int, default=2000, help="glances to time per configuration")
    ap.add_argument("--batch", type=int, default=512, help="glances per simulator call")
    ap.add_argument("--readout", default="taxels", choices=["taxels", "gazebo"])
    ap.add_argument("--objects", default="paper")
    args = ap.parse_args()
    torch.set_num_threads(1)
    objs = resolve_set(args.objects)
    total = len(objs) * GRID * GRID
    ids, qx, qp = sample_grid(args.n, len(objs))
    cores = os.cpu_count() or 1
    rows = []

    fast = FastSimulator(objs, SensorConfig(foam_stiffness=4.0e7))
    dt, _ = time_glances(fast, ids, qx, qp, args.batch)
    rows.append(("fast (torch, CPU)", torch.get_num_threads(), args.n / dt, None))

    for threads in sorted({1, cores}):
        sim = MujocoSimulator(objs, readout=args.readout, threads=threads)
        dt, results = time_glances(sim, ids, qx, qp, args.batch)
        status = np.concatenate([r.info["status"].numpy() for r in results])
        steps = np.concatenate([r.info["steps"].numpy() for r in results])
        rows.append((f"mujoco {args.readout}", threads, args.n / dt, (status, steps)))
        sim.close()

    print(
        f"MuJoCo glance benchmark: {args.n} poses sampled from the {len(objs)} x {GRID} x {GRID} grid "
        f"({total:,} glances), {cores} cores"
    )
    print(
        f"{'simulator':<20} {'threads':>7} {'glances/s':>11} {'table time':>11} {'x slower than fast':>19}"
    )
    fast_rate = rows[0][2]
    for name, threads, rate, _ in rows:
        secs = total / rate
        print(
            f"{name:<20} {threads:>7} {rate:>11.1f} {secs / 60:>9.2f} m {fast_rate / rate:>19.1f}"
        )
    for name, threads, _, extra in rows[1:]:
        status, steps = extra
        counts = ", ".join(
            f"{STATUS_NAMES[k]} {np.mean(status == k):.1%}" for k in range(len(STATUS_NAMES))
        )
        print(
            f"{name} ({threads} threads): steps per glance mean {steps.mean():.1f}, "
            f"median {np.median(steps):.0f}, max {steps.max()}; {counts}"
        )
    best = max(r[2] for r in rows[1:])
    verdict = "meets" if total / best <= 600 else "misses"
    print(
        f"projected table on {cores} cores: {total / best / 60:.2f} min ({verdict} the <= 10 min target)"
    )


if __name__ == "__main__":
    main()
