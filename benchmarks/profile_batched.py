"""Where a batched step's time goes: ``torch.profiler`` over a few steps of N runs.

Builds one group of N runs of the paper's model (seeds 0..N-1, one torch thread), takes a few
steps to warm up (and compile), then profiles ``--steps`` steps and prints the operators by
their own CPU time; with ``--shapes`` grouped by input shapes (which product is which layer).

Then the step's floor: the matrix products' share of the step and their rate (GFLOP/s, the
profiler's count of their FLOPs), beside this CPU's rate on one large product (2048 x 2048,
one thread) and the step of the same group with every layer 8 units wide (the cost that does not
grow with the model: Python, dispatch, glance lookups, sampling). A batched step cannot be
faster than its products; how much of the rest can go is what is left to gain.

Last, the operators of one step as the dispatcher sees them (``TorchDispatchMode``: what
autograd and the composite operators finally run), and those that are not views: on a GPU
each of those is a kernel launch, so their count per step is what a launch-bound GPU pays
(the CUDA path differs a little: no compiled cell backward, no ReLUs written into records).

    PYTHONPATH=src python benchmarks/profile_batched.py [--table TABLE] [--glances 10]
        [--runs 10] [--steps 4] [--shapes] [--policy learned|random]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import torch
from torch.profiler import ProfilerActivity, profile
from torch.utils._python_dispatch import TorchDispatchMode

from ham.learn.batched import BatchedRuns, _open_runs
from ham.learn.train import TrainConfig
from ham.model.agent import HamConfig

PRODUCTS = ("aten::bmm", "aten::mm", "aten::baddbmm", "aten::addmm")
# operators that only make a view (no kernel on a GPU), as the dispatcher names them
VIEWS = {"alias", "as_strided", "chunk", "detach", "expand", "narrow", "permute", "select",
         "slice", "split", "split_with_sizes", "squeeze", "t", "transpose", "unbind",
         "unsqueeze", "view", "_unsafe_view", "view_as"}  # fmt: skip


class _Count(TorchDispatchMode):
    """Counts the operators dispatched while it is on, and those that make no view."""

    def __init__(self) -> None:
        super().__init__()
        self.ops = self.kernels = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.ops += 1
        self.kernels += func.overloadpacket.__name__ not in VIEWS
        return func(*args, **(kwargs or {}))


def group(tmp: str, args, units: int | None = None) -> BatchedRuns:
    """N runs of the paper's model (``units``: every layer that wide instead), warmed up."""
    widths = {} if units is None else dict.fromkeys(
        ("what_units", "where_units", "combine_units", "hidden_units"), units
    )  # fmt: skip
    model = HamConfig(glances=args.glances, policy=args.policy, **widths)
    configs = [TrainConfig(model=model, seed=s, table=args.table) for s in range(args.runs)]
    outs = [Path(tmp) / f"{units}-{s}" for s in range(args.runs)]
    g = BatchedRuns(_open_runs(configs, outs), outs)
    for _ in range(3):  # warm up: buffers, compiled kernels
        g.step()
    return g


def step_ms(g: BatchedRuns, steps: int) -> float:
    """Median CPU time of a step, ms."""
    times = []
    for _ in range(steps):
        t = time.process_time()
        g.step()
        times.append(time.process_time() - t)
    return 1e3 * statistics.median(times)


def sgemm_rate(n: int = 2048, calls: int = 3) -> float:
    """This CPU's GFLOP/s on one ``n x n`` product (one thread), the best of ``calls``."""
    a, b = torch.randn(n, n), torch.randn(n, n)
    c = a @ b
    best = float("inf")
    for _ in range(calls):
        t = time.perf_counter()
        torch.mm(a, b, out=c)
        best = min(best, time.perf_counter() - t)
    return 2 * n**3 / best / 1e9


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--table", default=None, help="a glance table (default: online simulator)")
    p.add_argument("--glances", type=int, default=10)
    p.add_argument("--policy", choices=("learned", "random"), default="learned")
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--steps", type=int, default=4)
    p.add_argument("--rows", type=int, default=30, help="operators shown")
    p.add_argument("--shapes", action="store_true", help="group by input shapes")
    args = p.parse_args()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        paper = group(tmp, args)
        with profile(activities=[ProfilerActivity.CPU], record_shapes=args.shapes,
                     with_flops=True) as prof:  # fmt: skip
            for _ in range(args.steps):
                paper.step()
        ms = step_ms(paper, 2 * args.steps)
        with _Count() as count:
            paper.step()
        del paper
        tiny = step_ms(group(tmp, args, units=8), 2 * args.steps)
    print(f"{args.runs} runs, {args.glances} glances, {args.steps} steps profiled (divide the "
          f"times by {args.steps} for one step)")  # fmt: skip
    events = prof.key_averages(group_by_input_shape=args.shapes)
    table = events.table(
        sort_by="self_cpu_time_total", row_limit=args.rows, max_name_column_width=40,
        max_shapes_column_width=70,
    )  # fmt: skip
    print(table)
    products = [e for e in events if e.key in PRODUCTS]
    total = sum(e.self_cpu_time_total for e in events) / 1e3 / args.steps
    prod_ms = sum(e.self_cpu_time_total for e in products) / 1e3 / args.steps
    gflop = sum(e.flops for e in products) / 1e9 / args.steps
    ops = sum(e.count for e in events if e.key.startswith("aten::")) / args.steps
    peak = sgemm_rate()
    print(f"the step, profiled: {total:.0f} ms; the products {prod_ms:.0f} ms ({prod_ms / total:.0%}"
          f"), {gflop:.1f} GFLOP at {gflop / prod_ms * 1e3:.0f} GFLOP/s; one 2048 x 2048 product "
          f"on this CPU (one thread): {peak:.0f} GFLOP/s; {ops:,.0f} ATen operators a step "
          f"(views included)")  # fmt: skip
    print(f"the step, not profiled: {ms:.0f} ms ({ms / args.runs:.1f} per run-step); with every "
          f"layer 8 units wide: {tiny:.0f} ms ({tiny / args.runs:.1f}); the products alone "
          f"{prod_ms / args.runs:.1f} ms per run-step, at that CPU rate "
          f"{gflop / peak * 1e3 / args.runs:.1f}")  # fmt: skip
    print(f"one step at the dispatcher: {count.ops:,} operators, {count.kernels:,} of them not "
          f"views ({count.kernels / args.runs:.0f} per run-step)")  # fmt: skip


if __name__ == "__main__":
    main()
