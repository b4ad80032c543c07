"""Batched groups side by side: K processes, each training one batched group of N runs, at once.

``ham reproduce --executor batched --workers K`` runs K groups at a time; on a GPU they share it
(the paper-gazebo grid ran 15 groups on one H200). ``bench_batched.py`` times one group alone;
this measures what K groups get together. For each K and glance count: K spawned processes
(one torch thread each, as the executor's workers) build a group of N paper-model runs (seeds
0..N-1) on one glance table, warm up, wait for each other, then each trains ``--steps`` steps;
the aggregate seed-steps per second is ``K * N * steps`` over the slowest process's wall-clock
time. Prints, per glance count, each K's aggregate against K = 1 (K groups' throughput over one
group's), with ``--singles`` the same processes training their N runs one by one beside it
(the local executor's workers: batched against single runs on the whole machine), and the
paper grid's projected hours at the best K (ms per run-step interpolated
linearly in G, as ``bench_batched.py`` does; evaluations left out: their share is printed by
``bench_batched.py``).

    PYTHONPATH=src python benchmarks/bench_side_by_side.py --table TABLE [--device cuda]
        [--groups 1 2] [--glances 3 10] [--runs 10] [--steps 10] [--singles] [--json]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import tempfile
import time
from pathlib import Path

from bench_batched import grid_hours  # this folder: the paper grid's hours, as it costs them


def _worker(args: tuple, barrier, results) -> None:
    glances, runs, steps, table, device, slot, singles = args
    import torch

    torch.set_num_threads(1)
    from ham.learn.batched import BatchedRuns, _open_runs
    from ham.learn.environment import HapticEnv
    from ham.learn.train import Run, TrainConfig, stream_seed, train_step
    from ham.model.agent import HamConfig

    configs = [TrainConfig(model=HamConfig(glances=glances), seed=s, table=table, device=device)
               for s in range(runs)]  # fmt: skip
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    with tempfile.TemporaryDirectory() as tmp:
        outs = [Path(tmp) / str(s) for s in range(runs)]
        group = BatchedRuns(_open_runs(configs, outs), outs)  # writes nothing until train()
        if singles:  # the same runs one by one (a worker of the local executor)
            source = group.runs[0].env.source
            runs_ = [Run.create(c, HapticEnv(source, c.batch_size, c.normalization,
                                             stream_seed(c.seed, 0), torch.device(device)))
                     for c in configs]  # fmt: skip

            def step() -> None:
                for r in runs_:
                    train_step(r)
        else:
            step = group.step
        for _ in range(3):  # warm up (the compiled cell, CUDA kernels)
            step()
        sync()
        barrier.wait()
        t0 = time.perf_counter()
        for _ in range(steps):
            step()
        sync()
        results[slot] = time.perf_counter() - t0


def measure(
    k: int, glances: int, runs: int, steps: int, table: str, device: str, singles: bool = False
) -> dict:
    """K groups (or K workers of single runs) side by side: the aggregate seed-steps per
    second."""
    ctx = mp.get_context("spawn")
    barrier, results = ctx.Barrier(k), ctx.Manager().dict()
    procs = [ctx.Process(target=_worker, args=((glances, runs, steps, table, device, i, singles),
                                                barrier, results))
             for i in range(k)]  # fmt: skip
    for p in procs:
        p.start()
    for p in procs:
        p.join()
    if len(results) != k:
        raise SystemExit(f"{k - len(results)} of {k} worker(s) failed (exit codes "
                         f"{[p.exitcode for p in procs]})")  # fmt: skip
    wall = max(results.values())
    return {"groups": k, "glances": glances, "runs": runs, "steps": steps, "singles": singles,
            "wall_s": wall, "seed_steps_per_s": k * runs * steps / wall,
            "ms_per_run_step": 1000 * wall / (k * runs * steps)}  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--table", required=True, help="a glance table (ham table build)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--groups", type=int, nargs="+", default=[1, 2])
    p.add_argument("--glances", type=int, nargs="+", default=[3, 10])
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--singles", action="store_true",
                   help="also each process's N runs one by one (the local executor's workers)")  # fmt: skip
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    if not Path(args.table).is_file():
        raise SystemExit(f"--table {args.table!r}: no such file; accepted: a glance table")
    if any(k < 1 for k in args.groups) or args.runs < 1 or args.steps < 1:
        raise SystemExit("--groups, --runs and --steps: accepted: integers >= 1")
    kinds = (False, True) if args.singles else (False,)
    rows = [measure(k, g, args.runs, args.steps, args.table, args.device, s)
            for g in args.glances for k in args.groups for s in kinds]  # fmt: skip
    batched = [r for r in rows if not r["singles"]]
    best = {g: min(r["ms_per_run_step"] for r in batched if r["glances"] == g)
            for g in args.glances}  # fmt: skip
    one = {g: next((r["ms_per_run_step"] for r in batched if r["glances"] == g
                    and r["groups"] == 1), None) for g in args.glances}  # fmt: skip
    single = {(r["glances"], r["groups"]): r["ms_per_run_step"] for r in rows if r["singles"]}
    unit = "GPU-hours" if args.device.startswith("cuda") else "CPU-hours (wall-clock)"
    hours = grid_hours([{"glances": g, "ms": ms} for g, ms in best.items()], "ms")
    if args.json:
        print(json.dumps({"device": args.device, "rows": rows, "grid_hours_best": hours}, indent=1))
        return
    print(
        f"{args.runs} runs per group, the paper's model, batch 64, on {args.device}, "
        f"{os.cpu_count()} CPUs; {args.steps} steps per group after 3 of warm-up, wall-clock"
    )
    print("glances  groups  seed-steps/s  ms per run-step  vs one group"
          + ("  single runs: seed-steps/s  batched vs single" if args.singles else ""))  # fmt: skip
    for r in batched:
        base = one[r["glances"]]
        vs = f"{base / r['ms_per_run_step']:.2f}x" if base else "-"
        line = (f"{r['glances']:>7}  {r['groups']:>6}  {r['seed_steps_per_s']:>12.1f}  "
                f"{r['ms_per_run_step']:>15.2f}  {vs:>12}")  # fmt: skip
        ms = single.get((r["glances"], r["groups"]))
        if ms is not None:
            line += f"  {1000 / ms:>25.1f}  {ms / r['ms_per_run_step']:>16.2f}x"
        print(line)
    print(
        f"paper grid's training steps at the best number of groups per glance count "
        f"(interpolated linearly in G from G = {', '.join(map(str, args.glances))}; "
        f"evaluations not counted): {hours:,.2f} {unit}"
    )


if __name__ == "__main__":
    main()
