"""The batched evaluation's operators and CPU time, its first evaluation (each run's draws made)
against the later ones (the draws kept: ``BatchedRuns._eval_draws``).

Every evaluation seeds a run's generators anew, so its draws are the same each time; the first
evaluation draws them (one small draw per batch and glance, each an operator: on a GPU a kernel
launch), the later ones reuse them. Prints, per glance count and evaluation policy, the
operators each evaluation dispatches (counted with a ``TorchDispatchMode``) and its CPU time
(one thread), for evaluations 1-3 of one group of ``--runs`` paper-model runs.

    PYTHONPATH=src python benchmarks/bench_eval_draws.py --table TABLE [--runs 10]
        [--glances 3 10] [--policies mean sample]
"""

import argparse
import tempfile
import time
from pathlib import Path

import torch
from torch.utils._python_dispatch import TorchDispatchMode

from ham.learn.batched import BatchedRuns, _open_runs
from ham.learn.train import TrainConfig
from ham.model.agent import HamConfig


class _Count(TorchDispatchMode):
    def __init__(self) -> None:
        super().__init__()
        self.n = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.n += 1
        return func(*args, **(kwargs or {}))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--table", required=True, help="a glance table (ham table build)")
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--glances", type=int, nargs="+", default=[3, 10])
    p.add_argument("--policies", nargs="+", default=["mean", "sample"])
    args = p.parse_args()
    torch.set_num_threads(1)
    print(f"{args.runs} runs, the paper's model, 100 evaluation batches each, CPU time")
    print("glances  eval policy  evaluation  operators  ms (counting)")
    for glances in args.glances:
        for policy in args.policies:
            with tempfile.TemporaryDirectory() as d:
                configs = [TrainConfig(model=HamConfig(glances=glances), seed=s,
                                       table=args.table, eval_policy=policy)
                           for s in range(args.runs)]  # fmt: skip
                outs = [Path(d) / str(s) for s in range(args.runs)]
                group = BatchedRuns(_open_runs(configs, outs), outs)
                for k in range(3):
                    with _Count() as count:
                        t0 = time.process_time()
                        group.evaluate(list(range(args.runs)))
                        ms = 1000 * (time.process_time() - t0)
                    print(f"{glances:>7}  {policy:>11}  {k + 1:>10}  {count.n:>9,}  {ms:>13.0f}")


if __name__ == "__main__":
    main()
