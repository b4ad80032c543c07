"""Where a batched step's time goes: ``torch.profiler`` over a few steps of N runs.

Builds one group of N runs of the paper's model (seeds 0..N-1, one torch thread), takes a few
steps to warm up (and compile), then profiles ``--steps`` steps and prints the operators by
their own CPU time; with ``--shapes`` grouped by input shapes (which product is which layer).

    PYTHONPATH=src python benchmarks/profile_batched.py [--table TABLE] [--glances 10]
        [--runs 10] [--steps 4] [--shapes]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import torch
from torch.profiler import ProfilerActivity, profile

from ham.learn.batched import BatchedRuns, _open_runs
from ham.learn.train import TrainConfig
from ham.model.agent import HamConfig


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--table", default=None, help="a glance table (default: online simulator)")
    p.add_argument("--glances", type=int, default=10)
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--steps", type=int, default=4)
    p.add_argument("--rows", type=int, default=30, help="operators shown")
    p.add_argument("--shapes", action="store_true", help="group by input shapes")
    args = p.parse_args()
    torch.set_num_threads(1)
    configs = [TrainConfig(model=HamConfig(glances=args.glances), seed=s, table=args.table)
               for s in range(args.runs)]  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        outs = [Path(tmp) / str(s) for s in range(args.runs)]
        group = BatchedRuns(_open_runs(configs, outs), outs)
        for _ in range(3):  # warm up: buffers, compiled kernels
            group.step()
        with profile(activities=[ProfilerActivity.CPU], record_shapes=args.shapes) as prof:
            for _ in range(args.steps):
                group.step()
    print(f"{args.runs} runs, {args.glances} glances, {args.steps} steps profiled (divide the "
          f"times by {args.steps} for one step)")  # fmt: skip
    table = prof.key_averages(group_by_input_shape=args.shapes).table(
        sort_by="self_cpu_time_total", row_limit=args.rows, max_name_column_width=40,
        max_shapes_column_width=70,
    )  # fmt: skip
    print(table)


if __name__ == "__main__":
    main()
