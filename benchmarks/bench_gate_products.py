"""The LSTM gates' products of a batched group, in the layouts tried for the CPU step.

N runs (10), a batch of 64, the paper's core (input 512 = [g, h], 1024 gate outputs): the
batched step's forward ``x W^T + b`` (one ``bmm`` per glance), its input gradient ``g W`` and its
weight gradient over G glances, against the alternatives measured in docs/batched.md ("The gates'
products looked at once more"): MKL's packed weights (and what packing them every step costs),
the forward in two halves of outputs (NT views, or NN on contiguous halves of ``W^T``, and what
transposing ``W`` every step costs; or ``W^T`` kept as the stacked master, its halves strided),
the input and weight gradients in two halves of their depth K (accumulated), and activations
stored transposed. All timed side by side in
this process, one torch thread, medians of ``--calls`` calls per round, ``--rounds`` rounds.

    PYTHONPATH=src python benchmarks/bench_gate_products.py [--runs 10] [--rounds 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

import ham.learn.stacked_ham as stacked_ham


def timed(fn, calls: int) -> float:
    """Median ms of ``calls`` calls of ``fn`` (after 3 warm-up calls)."""
    for _ in range(3):
        fn()
    times = []
    for _ in range(calls):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e3 * statistics.median(times)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--glances", type=int, default=10)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--calls", type=int, default=40)
    args = p.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    n, b, k, o, glances = args.runs, 64, 512, 1024, args.glances
    x, w, bias = torch.randn(n, b, k), 0.05 * torch.randn(n, o, k), torch.randn(n, o)
    g = torch.randn(n, b, o)
    xs, gs = torch.randn(n, glances * b, k), torch.randn(n, glances * b, o)  # the step's records
    wt = w.transpose(1, 2).contiguous()
    layer = stacked_ham._Layer(w, bias, glances)  # the batched step's gates layer, split forward
    split = layer.split_forward(x)  # not on an AMD CPU (its products are oneDNN's, per run)
    halves = (wt[..., : o // 2].contiguous(), wt[..., o // 2 :].contiguous())
    xt, gt = x.transpose(1, 2).contiguous(), g.transpose(1, 2).contiguous()
    xst, gst = xs.transpose(1, 2).contiguous(), gs.transpose(1, 2).contiguous()

    def transpose_per_run():
        out = torch.empty(n, k, o)
        for r in range(n):
            out[r].copy_(w[r].t())
        return out

    cases = {
        "forward: bmm NT + bias (one product)": lambda: torch.bmm(x, w.transpose(1, 2)).add_(
            bias.unsqueeze(1)
        ),
        "forward: halves, NT views": lambda: [
            torch.bmm(x, w[:, s].transpose(1, 2)) for s in (slice(0, o // 2), slice(o // 2, o))
        ],
        "forward: halves, NN on W^T halves": lambda: [torch.bmm(x, h) for h in halves],
        "input gradient: bmm g W": lambda: torch.bmm(g, w),
        "input gradient: two halves of K, accumulated": lambda: torch.bmm(
            g[..., : o // 2], w[:, : o // 2]
        ).baddbmm_(g[..., o // 2 :], w[:, o // 2 :]),
        "weight gradient / glance": lambda: torch.bmm(gs.transpose(1, 2), xs),
        "weight gradient / glance, halves of rows": lambda: [
            torch.bmm(gs[..., s].transpose(1, 2), xs) for s in (slice(0, o // 2), slice(o // 2, o))
        ],
        "weight gradient / glance, halves of its glances (K)": lambda: torch.bmm(
            gs[:, : glances * b // 2].transpose(1, 2), xs[:, : glances * b // 2]
        ).baddbmm_(gs[:, glances * b // 2 :].transpose(1, 2), xs[:, glances * b // 2 :]),
        "weight gradient / glance, halves of columns": lambda: [
            torch.bmm(gs.transpose(1, 2), xs[..., s]) for s in (slice(0, k // 2), slice(k // 2, k))
        ],
        "per step: W^T, 3-D .contiguous()": lambda: w.transpose(1, 2).contiguous(),
        "per step: W^T, per-run 2-D copies": transpose_per_run,
        "W^T as master: forward halves, strided": lambda: [
            torch.bmm(x, wt[..., s]) for s in (slice(0, o // 2), slice(o // 2, o))
        ],
        "W^T as master: input gradient NT": lambda: torch.bmm(g, wt.transpose(1, 2)),
        "transposed: forward W x^T": lambda: torch.bmm(w, xt),
        "transposed: input gradient W^T g^T": lambda: torch.bmm(w.transpose(1, 2), gt),
        "transposed: weight gradient / glance": lambda: torch.bmm(gst, xst.transpose(1, 2)),
    }
    compiled = torch.compile(stacked_ham._halves, dynamic=True)
    cases["per step: W^T halves, compiled (batched.py)"] = lambda: compiled(w)
    if split:
        layer.halves()
        layer.slot(x)  # the record buffers; each call copies x into the first glance's record
        cases["forward: halves + bias + record (batched.py, 6+ glances)"] = lambda: (
            stacked_ham._LayerFn.apply(layer, 0, w, bias, x)
        )
    else:
        print("(this machine's batched step keeps one forward product: not timed as batched.py)")
    per_glance = {name for name in cases if "/ glance" in name}
    mkl = getattr(torch.ops, "mkl", None)
    if mkl is not None and hasattr(mkl, "_mkl_linear") and torch.backends.mkl.is_available():
        packed = [mkl._mkl_reorder_linear_weight(w[r], b) for r in range(n)]
        cases["forward: MKL packed weights"] = lambda: [
            mkl._mkl_linear(x[r], packed[r], w[r], bias[r], b) for r in range(n)
        ]
        cases["per step: pack W (forward only)"] = lambda: [
            mkl._mkl_reorder_linear_weight(w[r], b) for r in range(n)
        ]
    same = torch.equal(
        torch.bmm(x, w.transpose(1, 2)),
        torch.cat([torch.bmm(x, w[:, : o // 2].transpose(1, 2)),
                   torch.bmm(x, w[:, o // 2 :].transpose(1, 2))], -1),
    )  # fmt: skip
    print(f"{n} runs x 64 x 512 -> 1024 gates, 1 torch thread; ms per call (per glance for the "
          f"weight gradients of {glances} glances), median of {args.calls} calls, each round")  # fmt: skip
    rounds = {name: [] for name in cases}
    for _ in range(args.rounds):
        for name, fn in cases.items():
            calls = max(2, args.calls // glances) if name in per_glance else args.calls
            ms = timed(fn, calls)
            rounds[name].append(ms / glances if name in per_glance else ms)
    flop = 2 * n * b * k * o / 1e9
    for name, ms in rounds.items():
        rate = f"{flop / min(ms) * 1e3:6.0f} GFLOP/s (best)" if "per step" not in name else ""
        print(f"{name:50s} " + " ".join(f"{m:6.2f}" for m in ms) + f"   {rate}")
    today = [sum(rounds[c][i] for c in ("forward: bmm NT + bias (one product)",
                                         "input gradient: bmm g W",
                                         "weight gradient / glance"))
             for i in range(args.rounds)]  # fmt: skip
    trans = [sum(rounds[c][i] for c in ("transposed: forward W x^T",
                                         "transposed: input gradient W^T g^T",
                                         "transposed: weight gradient / glance"))
             for i in range(args.rounds)]  # fmt: skip
    print("gates per glance, one forward product: " + " ".join(f"{m:6.2f}" for m in today))
    print("gates per glance, transposed layout:   " + " ".join(f"{m:6.2f}" for m in trans))
    print(f"halves as NT views equal to the whole product, bit for bit: {same}")


if __name__ == "__main__":
    main()
