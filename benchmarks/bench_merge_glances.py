"""A Table 1 column's runs of 2-10 glances: one batched model per glance count vs one model.

``ham reproduce ... --executor batched --merge-glances`` trains runs of other glance counts (2 or
more) as one model that steps its longest run's glances (``batched.shape_key(config,
glances=False)``). This measures what that costs or saves: the paper's model at 2, 3, 4, 6, 8
and 10 glances, ``--runs`` seeds each (Table 1's full-model column but its 1-glance row, which
stays a model of its own), as one group per glance count stepped one after another (what
``--executor batched --workers 1`` runs) and as one merged group, interleaved in one process, one
torch thread. Prints the ms per step of all the runs each way, their ratio, each repeat's ratio,
and the operators each way dispatches a step that are not views (a GPU's kernel launches).

    PYTHONPATH=src python benchmarks/bench_merge_glances.py [--table TABLE] [--runs 10]
        [--glances 2 3 4 6 8 10] [--repeats 4] [--device cuda] [--cuda-graph] [--json]

On CUDA the times are wall-clock with the GPU synchronized; on a CPU the process's CPU time.
With ``--cuda-graph`` every group's step is replayed as one CUDA graph (``BatchedRuns(...,
cuda_graph=True)``; the kernels are counted in an eager warm-up step before the capture).
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import torch
from profile_batched import _Count  # this folder: the dispatcher's count of a step

from ham.learn.batched import _GRAPH_WARMUP, BatchedRuns, _open_runs
from ham.learn.train import TrainConfig
from ham.model.agent import HamConfig


def _group(configs: list[TrainConfig], tmp: str, name: str, cuda_graph: bool) -> BatchedRuns:
    outs = [Path(tmp) / f"{name}-{k}" for k in range(len(configs))]
    # writes nothing until train()
    return BatchedRuns(_open_runs(configs, outs), outs, cuda_graph=cuda_graph)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--table", default=None, help="a glance table (default: online simulator)")
    p.add_argument("--runs", type=int, default=10, help="seeds per glance count")
    p.add_argument("--glances", type=int, nargs="+", default=[2, 3, 4, 6, 8, 10])
    p.add_argument("--repeats", type=int, default=4)
    p.add_argument("--device", default="cpu")
    p.add_argument("--cuda-graph", action="store_true", help="each step replayed as a graph")
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    torch.set_num_threads(1)
    cuda = args.device.startswith("cuda")
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    clock = time.perf_counter if cuda else time.process_time
    configs = {g: [TrainConfig(model=HamConfig(glances=g), seed=s, table=args.table,
                               device=args.device) for s in range(args.runs)]
               for g in args.glances}  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        apart = [_group(c, tmp, f"g{g}", args.cuda_graph) for g, c in configs.items()]
        merged = _group([c for cs in configs.values() for c in cs], tmp, "merged",
                        args.cuda_graph)  # fmt: skip

        def step_apart() -> None:
            for group in apart:
                group.step()

        kernels = []
        # warm up both (buffers, compiled kernels; with graphs: the eager steps and the
        # capture); the kernels counted in the second step (eager either way)
        for w in range(_GRAPH_WARMUP + 1 if args.cuda_graph else 2):
            for step in (step_apart, merged.step):
                if w != 1:
                    step()
                    continue
                with _Count() as count:
                    step()
                kernels.append(count.kernels)
        t_apart, t_merged = [], []
        for _ in range(args.repeats):  # interleaved: both see the same machine load
            sync()
            t0 = clock()
            step_apart()
            sync()
            t1 = clock()
            merged.step()
            sync()
            t2 = clock()
            t_apart.append(t1 - t0)
            t_merged.append(t2 - t1)
    a, m = statistics.median(t_apart), statistics.median(t_merged)
    out = {
        "device": args.device,
        "cuda_graph": args.cuda_graph,
        "glances": args.glances,
        "runs_per_glance_count": args.runs,
        "ms_per_step_apart": 1000 * a,
        "ms_per_step_merged": 1000 * m,
        "ratio": a / m,
        "repeat_ratios": sorted(x / y for x, y in zip(t_apart, t_merged, strict=True)),
        "kernels_apart": kernels[0],
        "kernels_merged": kernels[1],
    }
    if args.json:
        print(json.dumps(out, indent=1))
        return
    what = "wall-clock (GPU synchronized)" if cuda else "CPU time of the process"
    graphs = ", each step replayed as a CUDA graph" if args.cuda_graph else ""
    print(f"glances {args.glances}, {args.runs} runs each, on {args.device}{graphs}, {what}, "
          f"median of {args.repeats} interleaved repeats")  # fmt: skip
    print(f"a step of all {args.runs * len(args.glances)} runs: {out['ms_per_step_apart']:.1f} ms "
          f"as {len(args.glances)} models, {out['ms_per_step_merged']:.1f} ms as one "
          f"(apart / merged {out['ratio']:.2f}; each repeat "
          f"{' '.join(f'{r:.2f}' for r in out['repeat_ratios'])}); operators not views a step: "
          f"{kernels[0]:,} apart, {kernels[1]:,} merged")  # fmt: skip


if __name__ == "__main__":
    main()
