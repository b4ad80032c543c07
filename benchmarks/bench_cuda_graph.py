"""The batched step replayed as one CUDA graph, beside the eager step.

On a GPU one batched group's step is bound by launching its ~1,400 kernels (10 glances) from
Python, not by the GPU's arithmetic (docs/batched.md); a replayed graph launches them at once.
For each glance count: two groups of N runs of the paper's model (seeds 0..N-1) on one glance
table, one stepped eagerly (``BatchedRuns``), one with ``cuda_graph=True``
(:meth:`BatchedRuns._graphed_step`: after two eager warm-up steps the device step is captured
once, with both generators of every run registered and the learning rates read from the device,
then replayed). Both take the warm-up and capture steps untimed, then alternate ``--steps``
timed steps. Prints ms per step eager and replayed (wall clock, the GPU synchronized) and their
ratio; after the steps, how far the graph group's weights are from the eager group's (the same
step: equal but for the GPU's atomic sums and the rate's float32 rounding) and whether their
generators' states are equal; the time to warm up and capture; one evaluation of all N runs,
per run, the first (each run's draws made) and a later one (kept: ``--eval-policy sample``
makes them count); and the paper grid's projected GPU-hours one group after another, eager and replayed
(``bench_batched.py``'s projection; evaluations eager in both). Then, at each glance count,
``--together K`` groups, replayed, each on its own CUDA stream, stepped as ``train_groups`` steps
them (every group launched before any is read back): ms per run-step against one replayed group,
the overlap that one process can get from one GPU, and the grid projected with it.

    PYTHONPATH=src python benchmarks/bench_cuda_graph.py --table TABLE [--glances 3 10]
        [--runs 10] [--steps 30] [--together 8]

Without CUDA (``--device cpu``) the device step is called where a graph would be replayed: a
check of the protocol (weights and generators then equal to the bit), not of a graph.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import torch
from bench_batched import grid_hours

from ham.learn.batched import _GRAPH_WARMUP, BatchedRuns, _open_runs
from ham.learn.train import TrainConfig
from ham.model.agent import HamConfig


def group(glances: int, args, out: Path, cuda_graph: bool) -> BatchedRuns:
    configs = [TrainConfig(model=HamConfig(glances=glances), seed=s, table=args.table,
                           device=args.device, eval_policy=args.eval_policy)
               for s in range(args.runs)]  # fmt: skip
    outs = [out / str(s) for s in range(args.runs)]
    return BatchedRuns(_open_runs(configs, outs), outs, cuda_graph=cuda_graph)


def measure(glances: int, args, tmp: Path) -> dict:
    cuda = args.device.startswith("cuda")
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    eager = group(glances, args, tmp / f"e{glances}", False)
    graphed = group(glances, args, tmp / f"g{glances}", True)
    for _ in range(_GRAPH_WARMUP + 1):
        eager.step()
    sync()
    t0 = time.perf_counter()
    for _ in range(_GRAPH_WARMUP + 1):  # the warm-up steps, then the capture (and its replay)
        graphed.step()
    sync()
    capture_s = time.perf_counter() - t0
    t_eager, t_graph = [], []
    for _ in range(args.steps):  # alternating: both see the same machine
        sync()
        t0 = time.perf_counter()
        eager.step()
        sync()
        t1 = time.perf_counter()
        graphed.step()
        sync()
        t_eager.append(t1 - t0)
        t_graph.append(time.perf_counter() - t1)
    drift = max((eager.stacked[n] - graphed.stacked[n]).abs().max().item()
                for n in eager.stacked)  # fmt: skip
    same_generators = all(
        torch.equal(a.env.generator.get_state(), b.env.generator.get_state())
        and torch.equal(a.policy_generator.get_state(), b.policy_generator.get_state())
        for a, b in zip(eager.runs, graphed.runs, strict=True)
    )
    evals = []  # the first evaluation makes each run's draws, the later ones reuse them
    for _ in range(2):
        sync()
        t0 = time.perf_counter()
        eager.evaluate(list(range(args.runs)))  # each run's eval_batches (100)
        sync()
        evals.append(time.perf_counter() - t0)
    e, g = statistics.median(t_eager), statistics.median(t_graph)
    return {
        "glances": glances,
        "eager_ms_per_run_step": 1000 * e / args.runs,
        "graph_ms_per_run_step": 1000 * g / args.runs,
        "ratio": e / g,
        "drift": drift,
        "same_generators": same_generators,
        "capture_s": capture_s,
        "first_eval_ms": 1000 * evals[0] / args.runs,
        "eval_ms": 1000 * evals[1] / args.runs,
    }


def together(g: int, args, tmp: Path) -> tuple[float, float]:
    """ms per run-step of one replayed group and of ``--together`` groups stepped together,
    at ``g`` glances."""
    cuda = args.device.startswith("cuda")
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    groups = [group(g, args, tmp / f"k{g}-{k}", True) for k in range(args.together)]
    for k, grp in enumerate(groups):  # other seeds in each group
        for r in grp.runs:
            r.env.generator.manual_seed(1000 * k + r.config.seed)
        grp.use_own_stream()
    out = []
    for live in (groups[:1], groups):
        for _ in range(_GRAPH_WARMUP + 1):  # warm-up and capture
            for grp in live:
                grp.step()
        sync()
        t0 = time.perf_counter()
        for _ in range(args.steps):
            for grp in live:
                grp.launch()
            for grp in live:
                grp.land()
        sync()
        out.append(1000 * (time.perf_counter() - t0) / (args.steps * args.runs * len(live)))
    return out[0], out[1]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--table", required=True, help="a glance table (ham table build)")
    p.add_argument("--glances", type=int, nargs="+", default=[3, 10])
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--steps", type=int, default=30, help="timed steps of each group")
    p.add_argument("--device", default="cuda", help="cuda, or cpu (a check of the protocol)")
    p.add_argument("--together", type=int, default=8, help="groups stepped together (0: none)")
    p.add_argument(
        "--eval-policy",
        choices=("mean", "sample"),
        default="mean",
        help="the evaluations' poses (sample: the paper-gazebo preset's)",
    )
    args = p.parse_args()
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        raise SystemExit("no CUDA here; accepted: --device cpu (a check of the protocol)")
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        rows = [measure(g, args, Path(tmp)) for g in args.glances]
        for r in rows if args.together > 1 else ():
            r["one_ms_per_run_step"], r["together_ms_per_run_step"] = together(
                r["glances"], args, Path(tmp)
            )
    what = "replayed graph" if args.device.startswith("cuda") else "device step called (CPU)"
    print(f"{args.runs} runs, batch 64, the paper's model, on {args.device}; "
          f"eager step vs {what}; median of {args.steps} alternating steps, wall clock")  # fmt: skip
    print("glances  eager ms/run-step  graph ms/run-step  ratio  weights apart  generators  "
          "warm-up and capture s  eval ms/run, first / later")  # fmt: skip
    for r in rows:
        print(f"{r['glances']:>7}  {r['eager_ms_per_run_step']:>17.2f}  "
              f"{r['graph_ms_per_run_step']:>17.2f}  {r['ratio']:>5.2f}  {r['drift']:>13.2e}  "
              f"{'equal' if r['same_generators'] else 'APART':>10}  {r['capture_s']:>21.1f}  "
              f"{r['first_eval_ms']:>11.1f} / {r['eval_ms']:.1f}")  # fmt: skip
    eager = grid_hours(rows, "eager_ms_per_run_step", "eval_ms")
    graph = grid_hours(rows, "graph_ms_per_run_step", "eval_ms")
    unit = "GPU-hours" if args.device.startswith("cuda") else "CPU-hours"
    print(f"paper grid, one group after another (ms/step linear in G from G = "
          f"{', '.join(map(str, args.glances))}; evaluations eager): {eager:,.2f} {unit} eager, "
          f"{graph:,.2f} replayed ({eager / graph:.2f}x)")  # fmt: skip
    if args.together > 1:
        for r in rows:
            one, many = r["one_ms_per_run_step"], r["together_ms_per_run_step"]
            print(f"{args.together} groups of {args.runs} runs at {r['glances']} glances, "
                  f"replayed on their own streams, stepped together: {many:.3f} ms per "
                  f"run-step against {one:.3f} for one group alone ({one / many:.2f}x its "
                  "throughput)")  # fmt: skip
        both = grid_hours(rows, "together_ms_per_run_step", "eval_ms")
        print(f"paper grid, {args.together} groups at a time replayed on their own streams "
              f"(evaluations eager, one group after another): {both:,.2f} {unit} "
              f"({eager / both:.2f}x the eager groups one after another)")  # fmt: skip
    if args.device == "cpu" and not all(r["drift"] == 0 and r["same_generators"] for r in rows):
        raise SystemExit("the called device step is not the eager step: the protocol is broken")


if __name__ == "__main__":
    main()
