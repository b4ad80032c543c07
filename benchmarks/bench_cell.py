"""The LSTM cell's elementwise work of one batched glance, in the variants tried for the CPU.

N runs (10), a batch of 64, the paper's 256 units: the batched step's cell forward
(:class:`ham.learn.stacked_ham._TanhLSTMCell`: ``sigmoid`` over the four gates, ``tanh`` over ``u``
written on top) against ``sigmoid`` over the three sigmoid gates only, against the activations
computed in place on a fresh gates tensor (each timed with the gates' product that makes it, as
in the step), against the whole cell forward compiled (``torch.compile``, dynamic and static
shapes); and the cell's backward (:func:`ham.learn.stacked_ham._cell_backward`) eager and compiled.
Each variant is timed against the batched step's own, call after call (A B A B ...), one torch
thread: the median and quartiles of the per-pair ratio B/A, so the machine's swings cancel.

    PYTHONPATH=src python benchmarks/bench_cell.py [--runs 10] [--pairs 200]
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from ham.learn.stacked_ham import _cell_backward


def pairs(a, b, n: int) -> tuple[float, float, list[float]]:
    """Median ms of ``a`` and ``b`` and the quartiles of ``b / a`` over ``n`` pairs."""
    for _ in range(5):
        a()
        b()
    ta, tb = [], []
    for _ in range(n):
        t0 = time.perf_counter()
        a()
        t1 = time.perf_counter()
        b()
        t2 = time.perf_counter()
        ta.append(t1 - t0)
        tb.append(t2 - t1)
    q = statistics.quantiles([y / x for x, y in zip(ta, tb, strict=True)], n=4)
    return 1e3 * statistics.median(ta), 1e3 * statistics.median(tb), q


def cell(z: torch.Tensor, c: torch.Tensor):
    """The cell forward as one expression (for the compiler)."""
    si, sf, so = (
        torch.sigmoid(z[..., 0, :]),
        torch.sigmoid(z[..., 1, :]),
        torch.sigmoid(z[..., 3, :]),
    )
    tu = torch.tanh(z[..., 2, :])
    c1 = sf * c + si * tu
    tc = torch.tanh(c1)
    return so * tc, c1, tc


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--pairs", type=int, default=200)
    args = p.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    n, b, h = args.runs, 64, 256
    z = torch.randn(n, b, 4, h)
    c = torch.randn(n, b, h)
    x, w = torch.randn(n, b, 2 * h), 0.05 * torch.randn(n, 2 * h, 4 * h)
    keep: list[torch.Tensor] = []  # the step keeps each glance's activations for its backward

    def kept(t: torch.Tensor) -> None:
        keep.append(t)
        if len(keep) > 10:
            keep.pop(0)

    def cell_from(act: torch.Tensor):  # the cell after its activations, as the step's
        si, sf, tu, so = act.unbind(-2)
        c1 = torch.addcmul(sf * c, si, tu)
        return so * torch.tanh(c1), c1

    def step_cell():  # as _TanhLSTMCell.forward
        act = torch.sigmoid(z)
        torch.tanh(z[..., 2, :], out=act[..., 2, :])
        return cell_from(act)

    def three_sigmoids():
        act = torch.empty_like(z)
        torch.sigmoid(z[..., :2, :], out=act[..., :2, :])
        torch.sigmoid(z[..., 3, :], out=act[..., 3, :])
        torch.tanh(z[..., 2, :], out=act[..., 2, :])
        return cell_from(act)

    def product_then_step_activations():
        g = torch.bmm(x, w).view(n, b, 4, h)
        act = torch.sigmoid(g)
        torch.tanh(g[..., 2, :], out=act[..., 2, :])
        kept(act)

    def product_then_in_place():
        g = torch.bmm(x, w).view(n, b, 4, h)
        g[..., :2, :].sigmoid_()
        g[..., 3, :].sigmoid_()
        g[..., 2, :].tanh_()
        kept(g)

    dynamic, static = torch.compile(cell, dynamic=True), torch.compile(cell, dynamic=False)
    dh, dc = torch.randn(n, b, h), torch.randn(n, b, h)
    act, tc = torch.rand(n, b, 4, h), torch.rand(n, b, h)
    backward = torch.compile(_cell_backward, dynamic=True)
    cases = [
        ("cell forward: sigmoid on the three sigmoid gates only", step_cell, three_sigmoids),
        ("cell forward: compiled, dynamic shapes", step_cell, lambda: dynamic(z, c)),
        ("cell forward: compiled, static shapes", step_cell, lambda: static(z, c)),
        ("gates' product + activations: in place on the gates",
         product_then_step_activations, product_then_in_place),
        ("cell backward: compiled (the step's) against eager",
         lambda: _cell_backward(dh, dc, act, tc, c), lambda: backward(dh, dc, act, tc, c)),
    ]  # fmt: skip
    print(f"{n} runs x 64 x 256 units, 1 torch thread; A = the batched step's own variant, "
          f"{args.pairs} pairs A B")  # fmt: skip
    print(f"{'B':58s} {'A ms':>6s} {'B ms':>6s}  B/A median (quartiles)")
    for name, a, bb in cases:
        ta, tb, q = pairs(a, bb, args.pairs)
        print(f"{name:58s} {ta:6.3f} {tb:6.3f}  {q[1]:.3f} ({q[0]:.3f}-{q[2]:.3f})")


if __name__ == "__main__":
    main()
