"""Speed of the fast extended glance g: (x, y, phi, phi_y) -> (p, h) on one core, beside MuJoCo.

Run: ``.venv/bin/python benchmarks/bench_glance4d.py`` (``--batch``, ``--mujoco-n``). Prints a
table of glances/s per second of CPU time (``time.process_time``: a shared machine's other
processes do not count), all measured in the same run: the extended glance on
height-field objects at uniform random 4-D poses, with the default pad (4 read-out points per
taxel along u, staggered in v: 1024 per glance), with one point per taxel (``supersample = 1``: 256)
and with the isotropic grid (``rows_per_taxel = 4``: 4096); the default pad with its back's rim
sampled only at the housing's 3 points per side (``rim_samples = 3``, the cost of the rim points)
and with its points on the taxels' centre lines (``stagger = False``, the cost of the stagger);
the paper's line glance (64 points) on
the paper's objects; and MuJoCo's glances/s on one thread, the reference of the ratio.

Objects: the ``curvature2d`` set when it is registered, else dome, saddle, bowl, cylinders along x
and y and a pyramid defined here. MuJoCo: on the same objects at the same 4-D poses (its height-field
glances, ``ham.world.mujoco_sim``).
Target (issue 12): >= 100k glances/s on one core (torch.set_num_threads(1)).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from ham.world import objects
from ham.world.extended_glance import ExtendedSimulator
from ham.world.glance import FastSimulator
from ham.world.objects import HapticObject
from ham.world.sensor import SensorConfig

_H = 0.03


def local_objects() -> list[HapticObject]:
    """Height-field stand-ins for the curvature2d set (9 x 9 cm bases)."""

    def pyramid(x, y):
        return np.maximum(0.005, 0.045 - np.maximum(np.abs(x), np.abs(y)))

    return [
        HapticObject.from_surface("b_dome", lambda x, y: _H - 3.0 * (x**2 + y**2)),
        HapticObject.from_surface("b_saddle", lambda x, y: _H + 3.0 * (x**2 - y**2)),
        HapticObject.from_surface("b_bowl", lambda x, y: 0.015 + 3.0 * (x**2 + y**2)),
        HapticObject.from_surface("b_cyl_x", lambda x, y: 0.02 + np.sqrt(0.05**2 - y**2) - 0.04),
        HapticObject.from_surface("b_cyl_y", lambda x, y: 0.02 + np.sqrt(0.05**2 - x**2) - 0.04),
        HapticObject.from_surface("b_pyramid", pyramid),
    ]


def best_rate(fn, n_items: int, repeats: int = 3) -> float:
    """Items per second of the process's CPU time (one thread): on a shared machine, time taken
    by other processes is not counted; the best of ``repeats`` runs after a warm-up."""
    fn()  # warm-up: workspace, caches
    best = float("inf")
    for _ in range(repeats):
        t = time.process_time()
        fn()
        best = min(best, time.process_time() - t)
    return n_items / max(best, 1e-9)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--batch", type=int, default=16384, help="glances per call")
    ap.add_argument("--mujoco-n", type=int, default=200, help="MuJoCo glances to time")
    args = ap.parse_args()
    torch.set_num_threads(1)
    if "curvature2d" in objects.OBJECT_SETS:
        objs, source = objects.resolve_set("curvature2d"), "curvature2d"
    else:
        objs, source = local_objects(), "local stand-ins (curvature2d not registered)"
    g = torch.Generator().manual_seed(0)
    n = args.batch
    ids = torch.randint(0, len(objs), (n,), generator=g)
    q = [torch.rand(n, generator=g) * 2 - 1 for _ in range(4)]  # x, phi, y, phi_y

    rows = []
    for label, sim in (
        ("extended, default pad (1024 points)", ExtendedSimulator(objs)),
        ("extended, default pad, back's rim at the housing's 3 points", ExtendedSimulator(objs, rim_samples=3)),
        ("extended, default pad, points on the taxels' centre lines", ExtendedSimulator(objs, stagger=False)),
        ("extended, supersample 1 (256 points)", ExtendedSimulator(objs, SensorConfig(supersample=1))),
        ("extended, rows_per_taxel 4 (4096 points)", ExtendedSimulator(objs, rows_per_taxel=4)),
    ):  # fmt: skip
        rows.append((label, best_rate(lambda sim=sim: sim.glance(ids, *q), n)))
    paper = objects.resolve_set("paper")
    line = FastSimulator(paper)
    pid = ids % len(paper)
    rows.append(
        (
            "paper line glance, paper objects (64)",
            best_rate(lambda: line.glance(pid, q[0], q[1]), n),
        )
    )

    mj_note = "MuJoCo, same objects, 4-D poses"
    try:
        from ham.world.mujoco_sim import MujocoSimulator
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise SystemExit(f"MuJoCo is not available: {exc}") from None
    m = args.mujoco_n
    # The reference: MuJoCo's own height-field glances (hfield tiles, one contact per taxel) at
    # the same 4-D poses on the same objects.
    mj = MujocoSimulator(objs, threads=1)
    sl = [t[:m] for t in q]
    mj_rate = best_rate(lambda: mj.glance(ids[:m], sl[0], sl[1], sl[2], sl[3]), m, 1)
    mj.close()
    rows.append((mj_note, mj_rate))

    print(f"objects: {source}; {n:,} glances per call at uniform random poses; 1 torch thread")
    print(f"| {'simulator':<62} | {'glances/s':>11} | {'x MuJoCo':>9} | {'x 100k':>7} |")
    print(f"|{'-' * 64}|{'-' * 13}|{'-' * 11}|{'-' * 9}|")
    for label, rate in rows:
        print(f"| {label:<62} | {rate:>11,.0f} | {rate / mj_rate:>9,.0f} | {rate / 1e5:>7.2f} |")


if __name__ == "__main__":
    main()
