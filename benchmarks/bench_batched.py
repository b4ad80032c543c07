"""Seed-steps per second: N runs trained as one batched model vs the same N runs one by one.

For each glance count (3 and 10 by default): N = 10 runs of the paper's model (seeds 0..9)
as single runs (:func:`ham.learn.train.train_step`, one after another) and as one batched group
(:class:`ham.learn.batched.BatchedRuns`), measured interleaved in the same process (both see the
same machine load), one torch thread (as a worker of the local pool). The times are the
process's CPU time (on a shared machine wall-clock time counts the other jobs' share; the
wall-clock ratio is printed beside). Also one evaluation (100 batches) of a single run and the
batched group's evaluation of all N runs at once (:meth:`BatchedRuns.evaluate`), per run. Prints
the step's ratio, the ratio of a whole run (50,000 steps and 250 evaluations), and the projected
CPU-hours of
the full paper grid (Table 1: 7 glance counts x 3 trained variants x 10 seeds, Table 2: 3 more
combiners x 10 seeds at 3 glances; 50,000 steps and 250 evaluations each), with ms/step at
the other glance counts interpolated linearly in G from the measured ones, and every variant
costed as the full model (the MLP core is cheaper: an upper bound).

    PYTHONPATH=src python benchmarks/bench_batched.py [--table TABLE] [--runs 10] [--glances 3 10]
        [--repeats 4] [--device cuda] [--first-glance learned]

``--first-glance learned``: the model's first glance chosen by its policy (the APPLE study's
HAM; batched since it reads the heads' biases at ``tau_0``, docs/batched.md).

With ``--device cuda`` the times are wall-clock (the GPU synchronized before each reading: CPU
time says nothing there) and the projection is in GPU-hours, one batched group after another.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

import ham.learn.stacked_ham as stacked_ham
from ham.learn.batched import BatchedRuns, _open_runs
from ham.learn.environment import HapticEnv
from ham.learn.evaluation import evaluate
from ham.learn.train import Run, TrainConfig, stream_seed, train_step
from ham.model.agent import HamConfig
from ham.world.devices import cpu_info

TABLE1_GLANCES = (1, 2, 3, 4, 6, 8, 10)
STEPS, EVALS, SEEDS = 50_000, 250, 10


def measure(glances: int, runs: int, repeats: int, table: str | None, device: str = "cpu",
            first_glance: str = "random") -> dict:  # fmt: skip
    model = HamConfig(glances=glances, first_glance=first_glance)
    configs = [TrainConfig(model=model, seed=s, table=table, device=device)
               for s in range(runs)]  # fmt: skip
    cuda = device.startswith("cuda")
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    with tempfile.TemporaryDirectory() as tmp:
        outs = [Path(tmp) / str(s) for s in range(runs)]
        group = BatchedRuns(_open_runs(configs, outs), outs)  # writes nothing until train()
        # the single runs glance on the same (one) table in memory, each with its own
        # environment seeded as Run.create seeds it
        source = group.runs[0].env.source
        singles = [Run.create(c, HapticEnv(source, c.batch_size, c.normalization,
                                           stream_seed(c.seed, 0), torch.device(device)))
                   for c in configs]  # fmt: skip
        for _ in range(2):  # warm up both
            group.step()
            for r in singles:
                train_step(r)
        t_single, t_batched, c_single, c_batched = [], [], [], []
        for _ in range(repeats):  # interleaved: both see the same machine load
            sync()
            t0, c0 = time.perf_counter(), time.process_time()
            for r in singles:
                train_step(r)
            sync()
            t1, c1 = time.perf_counter(), time.process_time()
            group.step()
            sync()
            t2, c2 = time.perf_counter(), time.process_time()
            t_single.append(t1 - t0)
            t_batched.append(t2 - t1)
            c_single.append(c1 - c0)
            c_batched.append(c2 - c1)
        sync()
        c0, t0 = time.process_time(), time.perf_counter()
        evaluate(singles[0].agent, singles[0].env, 100, seed=2)
        sync()
        c_eval = (time.perf_counter() - t0) if cuda else (time.process_time() - c0)
        c0, t0 = time.process_time(), time.perf_counter()
        group.evaluate(list(range(runs)))  # each run's 100 batches (the config's eval_batches)
        sync()
        c_group = (time.perf_counter() - t0) if cuda else (time.process_time() - c0)
    wall_single, wall_batched = statistics.median(t_single), statistics.median(t_batched)
    if cuda:  # the GPU's work is not this process's CPU time
        single, batched = wall_single, wall_batched
    else:
        single, batched = statistics.median(c_single), statistics.median(c_batched)
    return {
        "glances": glances,
        "runs": runs,
        "single_ms_per_run_step": 1000 * single / runs,
        "batched_ms_per_run_step": 1000 * batched / runs,
        "single_seed_steps_per_s": runs / single,
        "batched_seed_steps_per_s": runs / batched,
        "ratio": single / batched,
        # each repeat's own ratio (its two halves ran back to back): the spread of the machine
        "repeat_ratios": sorted(
            s / b
            for s, b in zip(
                t_single if cuda else c_single, t_batched if cuda else c_batched, strict=True
            )
        ),
        "wall_ratio": wall_single / wall_batched,
        "eval_ms": 1000 * c_eval,
        "batched_eval_ms": 1000 * c_group / runs,  # per run
        "eval_ratio": c_eval * runs / c_group,
        # a whole run: STEPS steps and EVALS evaluations
        "run_ratio": (STEPS * single / runs + EVALS * c_eval)
        / (STEPS * batched / runs + EVALS * c_group / runs),
    }


def grid_hours(rows: list[dict], key: str, eval_key: str | None = None) -> float:
    """CPU-hours of the paper grid with ms/step ``key`` and ms/evaluation ``eval_key``
    (``None``: evaluations not counted), interpolated linearly in G."""
    g = [r["glances"] for r in rows]
    ms = [r[key] for r in rows]
    ev = [0.0 if eval_key is None else r[eval_key] for r in rows]
    if len(rows) == 1:
        fit = lambda x, y: lambda G: y[0] * G / x[0]  # noqa: E731 - proportional to G
    else:
        fit = lambda x, y: np.poly1d(np.polyfit(x, y, 1))  # noqa: E731
    step, evaluation = fit(g, ms), fit(g, ev)
    runs = {G: 3 * SEEDS for G in TABLE1_GLANCES}
    runs[3] += 3 * SEEDS  # Table 2's mul, concat1, add (concat2 is Table 1's full model)
    ms_total = sum(n * (STEPS * step(G) + EVALS * evaluation(G)) for G, n in runs.items())
    return ms_total / 3.6e6


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--glances", type=int, nargs="+", default=[3, 10])
    p.add_argument("--repeats", type=int, default=4)
    p.add_argument("--table", default=None, help="a glance table (default: online simulator)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--device", default="cpu", help="cpu or cuda (wall-clock times on cuda)")
    p.add_argument("--products", choices=("auto", "onednn", "bmm"), default="auto",
                   help="the batched CPU products: auto (by the CPU: oneDNN on AMD with AVX-512), one oneDNN "
                   "product per run, or one MKL bmm for all runs")  # fmt: skip
    p.add_argument("--first-glance", choices=("random", "learned"), default="random",
                   help="random (the paper) or chosen by the policy")  # fmt: skip
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    if args.products != "auto":
        stacked_ham._PER_RUN_ONEDNN = args.products == "onednn"
    products = "oneDNN per run" if stacked_ham._PER_RUN_ONEDNN else "bmm"
    vendor = cpu_info("vendor_id")
    rows = [measure(g, args.runs, args.repeats, args.table, args.device, args.first_glance)
            for g in args.glances]  # fmt: skip
    cuda = args.device.startswith("cuda")
    unit = "GPU-hours" if cuda else "CPU-hours"
    before = grid_hours(rows, "single_ms_per_run_step", "eval_ms")
    after = grid_hours(rows, "batched_ms_per_run_step", "batched_eval_ms")
    if args.json:
        key = "grid_gpu_hours" if cuda else "grid_cpu_hours"
        print(json.dumps({"device": args.device, "cpu_vendor": vendor, "products": products,
                          "first_glance": args.first_glance,
                          "rows": rows, key: [before, after]}, indent=1))  # fmt: skip
        return
    print(f"{args.runs} runs, {args.threads} torch thread(s), batch 64, the paper's model "
          f"(first glance {args.first_glance}), on {args.device} ({vendor or 'CPU vendor unknown'}; CPU products: {products})")  # fmt: skip
    clock = "wall-clock time (GPU synchronized)" if cuda else "CPU time per process"
    print(f"{clock}, median of {args.repeats} interleaved repeats; load average "
          f"{os.getloadavg()[0]:.1f} at the end")  # fmt: skip
    print("glances  single ms/run-step  batched ms/run-step  seed-steps/s single  batched  ratio"
          "  (wall-clock ratio)  each repeat's ratio, lowest to highest")  # fmt: skip
    for r in rows:
        spread = " ".join(f"{x:.2f}" for x in r["repeat_ratios"])
        print(f"{r['glances']:>7}  {r['single_ms_per_run_step']:>18.1f}  "
              f"{r['batched_ms_per_run_step']:>19.1f}  {r['single_seed_steps_per_s']:>19.1f}  "
              f"{r['batched_seed_steps_per_s']:>7.1f}  {r['ratio']:>5.2f}  "
              f"({r['wall_ratio']:.2f})  {spread}")  # fmt: skip
    evals = ", ".join(f"G={r['glances']}: {r['eval_ms']:.0f} / {r['batched_eval_ms']:.0f} ms "
                      f"({r['eval_ratio']:.2f}x)" for r in rows)  # fmt: skip
    print(f"one evaluation of 100 batches per run, single / batched: {evals}")
    runs = ", ".join(f"G={r['glances']}: {r['run_ratio']:.2f}x" for r in rows)
    print(f"a whole run ({STEPS:,} steps, {EVALS} evaluations), batched vs single: {runs}")
    print(
        f"paper grid ({7 * 3 * SEEDS + 3 * SEEDS} runs x 50,000 steps + 250 evaluations; ms/step interpolated linearly "
        f"in G from G = {', '.join(map(str, args.glances))}; every variant costed as the full "
        f"model): {before:,.1f} {unit} one by one, {after:,.1f} batched ({before / after:.2f}x)"
    )


if __name__ == "__main__":
    main()
