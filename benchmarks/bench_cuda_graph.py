"""The batched step captured once as a CUDA graph and replayed, beside the eager step.

On a GPU one batched group's step is bound by launching its ~1,400 kernels (10 glances) from
Python, not by the GPU's arithmetic (docs/batched.md); a replayed graph launches them all at
once. For each glance count: two groups of N runs of the paper's model (seeds 0..N-1) on one
glance table, at a constant learning rate (``lr_decay`` 1: a graph replays the rate it was
captured with; the paper's schedule needs the rate as a tensor on the device, not built yet).
Group E steps eagerly (:meth:`BatchedRuns.step`). Group G takes the same warm-up steps eagerly
(on a side stream, as capturing wants), then its device step (:meth:`BatchedRuns._device_step`:
no sync and no tensor of Python values, which tests/test_batched.py checks) is captured as one
``torch.cuda.CUDAGraph`` with both generators of every run registered, and replayed; each
replayed step then reads the flags back (loss and weights finite), the step's one sync, as
:meth:`BatchedRuns.step` does. The two groups' steps alternate. Prints ms per step eager and
replayed (wall clock, the GPU synchronized) and their ratio; after the steps, how far G's
weights are from E's (the graph is the eager step: equal but for the GPU's atomic sums) and
whether their generators' states are equal; one evaluation of all N runs, per run; the paper
grid's projected GPU-hours one group after another, eager and replayed (``bench_batched.py``'s
projection, evaluations eager in both).

    PYTHONPATH=src python benchmarks/bench_cuda_graph.py --table TABLE [--glances 3 10]
        [--runs 10] [--steps 30] [--warmup 3]

Without CUDA (``--device cpu``) the device step is called where it would be replayed: a check
of the protocol (the weights and generators must then be equal to the bit), not of a graph.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import torch
from bench_batched import grid_hours

from ham.learn.batched import BatchedRuns, _open_runs
from ham.learn.train import TrainConfig
from ham.model.agent import HamConfig


def group(glances: int, runs: int, table: str, device: str, out: Path) -> BatchedRuns:
    configs = [TrainConfig(model=HamConfig(glances=glances), seed=s, table=table, device=device,
                           lr_decay=1.0) for s in range(runs)]  # fmt: skip
    outs = [out / str(s) for s in range(runs)]
    return BatchedRuns(_open_runs(configs, outs), outs)  # writes nothing until train()


class Replayed:
    """A group whose device step is one captured graph (CUDA), or is called (CPU)."""

    def __init__(self, g: BatchedRuns, warmup: int) -> None:
        self.g, self.runs = g, [g.runs[i] for i in g.active]
        self.graph = None
        if not self.runs[0].env.device.type == "cuda":
            for _ in range(warmup):
                g.step()
            return
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):  # lazy initializations happen outside the capture
            for _ in range(warmup):
                g.step()
        torch.cuda.current_stream().wait_stream(side)
        self.graph = torch.cuda.CUDAGraph()
        for r in self.runs:  # their draws advance them at every replay, as the eager step's
            self.graph.register_generator_state(r.env.generator)
            self.graph.register_generator_state(r.policy_generator)
        with torch.cuda.graph(self.graph):
            self.flags = g._device_step(self.runs)

    def step(self) -> None:
        if self.graph is None:
            flags = self.g._device_step(self.runs)
        else:
            self.graph.replay()
            flags = self.flags
        loss_ok, weights_ok = flags.tolist()
        if not (all(loss_ok) and all(weights_ok)):
            raise RuntimeError("a run diverged in the replayed step")
        for r in self.runs:
            r.step += 1


def measure(glances: int, args, tmp: Path) -> dict:
    cuda = args.device.startswith("cuda")
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    eager = group(glances, args.runs, args.table, args.device, tmp / f"e{glances}")
    for _ in range(args.warmup):
        eager.step()
    t0 = time.perf_counter()
    replayed = Replayed(group(glances, args.runs, args.table, args.device, tmp / f"g{glances}"),
                        args.warmup)  # fmt: skip
    sync()
    capture_s = time.perf_counter() - t0
    t_eager, t_graph = [], []
    for _ in range(args.steps):  # alternating: both see the same machine
        sync()
        t0 = time.perf_counter()
        eager.step()
        sync()
        t1 = time.perf_counter()
        replayed.step()
        sync()
        t_eager.append(t1 - t0)
        t_graph.append(time.perf_counter() - t1)
    drift = max((eager.stacked[n] - replayed.g.stacked[n]).abs().max().item()
                for n in eager.stacked)  # fmt: skip
    same_generators = all(
        torch.equal(a.env.generator.get_state(), b.env.generator.get_state())
        and torch.equal(a.policy_generator.get_state(), b.policy_generator.get_state())
        for a, b in zip(eager.runs, replayed.runs, strict=True)
    )
    sync()
    t0 = time.perf_counter()
    eager.evaluate(list(range(args.runs)))  # each run's 100 batches (the config's eval_batches)
    sync()
    eval_s = time.perf_counter() - t0
    e, g = statistics.median(t_eager), statistics.median(t_graph)
    return {
        "glances": glances,
        "eager_ms_per_run_step": 1000 * e / args.runs,
        "graph_ms_per_run_step": 1000 * g / args.runs,
        "ratio": e / g,
        "drift": drift,
        "same_generators": same_generators,
        "capture_s": capture_s,
        "eval_ms": 1000 * eval_s / args.runs,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--table", required=True, help="a glance table (ham table build)")
    p.add_argument("--glances", type=int, nargs="+", default=[3, 10])
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--steps", type=int, default=30, help="timed steps of each group")
    p.add_argument("--warmup", type=int, default=3, help="eager steps before the capture")
    p.add_argument("--device", default="cuda", help="cuda, or cpu (a check of the protocol)")
    args = p.parse_args()
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        raise SystemExit("no CUDA here; accepted: --device cpu (a check of the protocol)")
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        rows = [measure(g, args, Path(tmp)) for g in args.glances]
    what = "replayed graph" if args.device.startswith("cuda") else "device step called (CPU)"
    print(f"{args.runs} runs, batch 64, the paper's model, lr constant, on {args.device}; "
          f"eager step vs {what}; median of {args.steps} alternating steps, wall clock")  # fmt: skip
    print("glances  eager ms/run-step  graph ms/run-step  ratio  weights apart  generators  "
          "capture s  eval ms/run")  # fmt: skip
    for r in rows:
        print(f"{r['glances']:>7}  {r['eager_ms_per_run_step']:>17.2f}  "
              f"{r['graph_ms_per_run_step']:>17.2f}  {r['ratio']:>5.2f}  {r['drift']:>13.2e}  "
              f"{'equal' if r['same_generators'] else 'APART':>10}  {r['capture_s']:>9.1f}  "
              f"{r['eval_ms']:>11.1f}")  # fmt: skip
    eager = grid_hours(rows, "eager_ms_per_run_step", "eval_ms")
    graph = grid_hours(rows, "graph_ms_per_run_step", "eval_ms")
    unit = "GPU-hours" if args.device.startswith("cuda") else "CPU-hours"
    print(f"paper grid, one group after another (ms/step linear in G from G = "
          f"{', '.join(map(str, args.glances))}; evaluations eager): {eager:,.2f} {unit} eager, "
          f"{graph:,.2f} replayed ({eager / graph:.2f}x)")  # fmt: skip
    if args.device == "cpu" and not all(r["drift"] == 0 and r["same_generators"] for r in rows):
        raise SystemExit("the called device step is not the eager step: the protocol is broken")


if __name__ == "__main__":
    main()
