"""The batched SGD update: why a run's small tensors are updated run by run, and what it costs.

1. Rounding: PyTorch's fused SGD (``torch._fused_sgd_``, Nesterov momentum as the paper's) on
   random weights, gradients and momentum buffers; the first two elements are updated once alone
   (a 2-element tensor: all in the kernel's scalar tail) and once at the head of longer tensors.
   Prints, per length, in how many of ``--trials`` draws their result differs from the alone one:
   where the vector loop covers them it rounds otherwise, so over a whole stack of runs a run's
   2-element bias rounded by its place in the stack (docs/batched.md, "A run's numbers and its
   batch-mates").
2. Places: a stack of ``--stack`` runs (3: a grid cell's seeds) of tensors of 1, 2, 4 (the
   baseline's, a location head's and the classifier's biases) and 100 elements per run, updated
   whole; per run, in how many draws its part differs from its update alone: which runs' numbers
   the whole-stack update moved, and which it left as they are now.
3. Cost: one update of ``--runs`` runs of the paper's model (10 glances), CPU time per update
   (median of 15 repeats of 20, one thread), the three ways interleaved in one process: every
   stacked tensor whole (before), every tensor run by run, and the tensors whose per-run size is
   not a multiple of ``ham.learn.batched._WHOLE_VECTORS`` (64) run by run (the trainer, now).

    PYTHONPATH=src python benchmarks/bench_fused_sgd.py [--runs 10] [--trials 2000] [--stack 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from ham.learn.batched import _WHOLE_VECTORS
from ham.model.agent import HamConfig, HapticAttentionModel

SGD = dict(weight_decay=0.0, momentum=0.9, lr=8e-4, dampening=0.0, nesterov=True,
           maximize=False, is_first_step=False)  # fmt: skip


def rounding(trials: int, lengths: tuple[int, ...]) -> dict[int, int]:
    def head(n: int, p0, g0, b0) -> tuple[torch.Tensor, torch.Tensor]:
        p, g, b = torch.randn(n), torch.randn(n), torch.randn(n)
        p[:2], g[:2], b[:2] = p0, g0, b0
        torch._fused_sgd_([p], [g], [b], **SGD)
        return p[:2], b[:2]

    differ = dict.fromkeys(lengths, 0)
    for _ in range(trials):
        p0, g0, b0 = torch.randn(2), torch.randn(2), torch.randn(2)
        alone = head(2, p0, g0, b0)
        for n in lengths:
            other = head(n, p0, g0, b0)
            differ[n] += not all(torch.equal(x, y) for x, y in zip(alone, other, strict=True))
    return differ


def places(trials: int, runs: int, sizes: tuple[int, ...]) -> dict[int, list[int]]:
    differ = {n: [0] * runs for n in sizes}
    for n in sizes:
        for _ in range(trials):
            p, g, b = torch.randn(runs, n), torch.randn(runs, n), torch.randn(runs, n)
            whole_p, whole_b = p.clone(), b.clone()
            torch._fused_sgd_([whole_p.view(-1)], [g.view(-1)], [whole_b.view(-1)], **SGD)
            for r in range(runs):
                alone_p, alone_b = p[r].clone(), b[r].clone()
                torch._fused_sgd_([alone_p], [g[r].clone()], [alone_b], **SGD)
                same = torch.equal(alone_p, whole_p[r]) and torch.equal(alone_b, whole_b[r])
                differ[n][r] += not same
    return differ


def cost(runs: int) -> dict[str, float]:
    shapes = [p.shape for p in HapticAttentionModel(HamConfig(glances=10)).parameters()]
    ps, gs, bs = ([torch.randn(runs, *s) for s in shapes] for _ in range(3))
    ways = {
        "whole stacks": lambda ts: ts,
        "every tensor run by run": lambda ts: [v for t in ts for v in t.unbind(0)],
        "small tensors run by run": lambda ts: [
            v for t in ts for v in (t.unbind(0) if t[0].numel() % _WHOLE_VECTORS else [t])
        ],
    }
    times: dict[str, list[float]] = {k: [] for k in ways}
    for _ in range(15):
        for name, views in ways.items():
            start = time.process_time()
            for _ in range(20):
                torch._fused_sgd_(views(ps), views(gs), views(bs), **SGD)
            times[name].append((time.process_time() - start) / 20 * 1e3)
    return {k: statistics.median(v) for k, v in times.items()}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--trials", type=int, default=2000)
    p.add_argument("--stack", type=int, default=3)
    args = p.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    lengths = (2, 4, 6, 7, 8, 12, 16, 64, 1024)
    differ = rounding(args.trials, lengths)
    print(f"first 2 elements of a fused SGD update, {args.trials} draws: differ from the "
          "2-element update when the tensor holds")  # fmt: skip
    for n in lengths:
        print(f"  {n:5d} elements: {differ[n]:5d} draws")
    print(f"a stack of {args.stack} runs updated whole, {args.trials} draws: a run's part differs "
          "from its update alone, per run (first to last)")  # fmt: skip
    for n, per_run in places(args.trials, args.stack, (1, 2, 4, 100)).items():
        print(f"  {n:5d} elements a run: {per_run}")
    times = cost(args.runs)
    base = times["whole stacks"]
    print(f"one update of {args.runs} runs (paper's model, 10 glances), ms of CPU, median of 15:")
    for name, t in times.items():
        print(f"  {name:26s} {t:6.3f}  ({t / base:.3f}x)")


if __name__ == "__main__":
    main()
