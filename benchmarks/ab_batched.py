"""The batched step of two versions of ``ham.learn.batched``, A/B in one process.

Version A is the batched trainer's modules (``src/ham/learn/batched.py`` and, where the ref has
it, ``src/ham/learn/stacked_ham.py``) at a git ref (``--ref``, default HEAD), version B the
working tree's. Each builds its own group of N runs of the paper's model (seeds 0..N-1, one
torch thread); their steps alternate A B, B A, ... so that both see the same machine load, and
the CPU time of each step is taken. Prints each version's median ms per batched step, the
median and quartiles of the per-pair ratio B/A, and how far the two groups' weights have
drifted apart (float rounding, amplified by training: ~1e-3 after 30 steps at 10 glances).

On a noisy machine this resolves a few percent where ``bench_batched.py`` (single runs
against a batched group, run by run) does not: its two halves differ by 2x and the machine's
speed drifts between them. Version A imports the rest of ``ham`` from the working tree, so
the ref must share its interfaces (the modules' own code may differ).

    PYTHONPATH=src python benchmarks/ab_batched.py [--ref HEAD~1] [--table TABLE]
        [--glances 10] [--runs 10] [--repeats 20]
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

from ham.learn.train import TrainConfig
from ham.model.agent import HamConfig

MODULE = "src/ham/learn/batched.py"
STACKED = "src/ham/learn/stacked_ham.py"  # the stacked model (in MODULE itself before 2026-12-02)


def load(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # a dataclass in it looks its module up there
    spec.loader.exec_module(module)
    return module


def show(root: Path, ref: str, path: str) -> str | None:
    """The file ``path`` at git ``ref``; ``None`` where the ref has no such file."""
    r = subprocess.run(["git", "show", f"{ref}:{path}"], cwd=root, capture_output=True, text=True)
    return r.stdout if r.returncode == 0 else None


def load_ref(tmp: Path, batched: str, stacked: str | None):
    """Version A's batched module, importing version A's stacked model (where the ref has one):
    it stands in for the working tree's in ``sys.modules`` while the module is executed."""
    (tmp / "a.py").write_text(batched)
    if stacked is None:
        return load(tmp / "a.py", "batched_a")
    (tmp / "a_stacked.py").write_text(stacked)
    name = "ham.learn.stacked_ham"
    saved = sys.modules.get(name)
    sys.modules[name] = load(tmp / "a_stacked.py", name)
    try:
        return load(tmp / "a.py", "batched_a")
    finally:
        if saved is None:
            sys.modules.pop(name, None)
        else:
            sys.modules[name] = saved


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--ref", default="HEAD", help="git ref of version A (default HEAD)")
    p.add_argument("--table", default=None, help="a glance table (default: online simulator)")
    p.add_argument("--glances", type=int, default=10)
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--repeats", type=int, default=20, help="steps of each version timed")
    args = p.parse_args()
    torch.set_num_threads(1)
    root = Path(__file__).resolve().parent.parent
    old = show(root, args.ref, MODULE)
    if old is None:
        sys.exit(f"git show {args.ref}:{MODULE} failed: no such ref or file")
    configs = [TrainConfig(model=HamConfig(glances=args.glances), seed=s, table=args.table)
               for s in range(args.runs)]  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        versions = [load_ref(Path(tmp), old, show(root, args.ref, STACKED)),
                    load(root / MODULE, "batched_b")]  # fmt: skip
        groups = []
        for j, m in enumerate(versions):
            outs = [Path(tmp) / f"{j}_{s}" for s in range(args.runs)]
            groups.append(m.BatchedRuns(m._open_runs(configs, outs), outs))
        for g in groups:  # warm up (and compile, where a version compiles)
            g.step()
            g.step()
        times: list[list[float]] = [[], []]
        for r in range(args.repeats):
            for j in (0, 1) if r % 2 == 0 else (1, 0):
                t0 = time.process_time()
                groups[j].step()
                times[j].append(time.process_time() - t0)
        drift = max((a - b).abs().max().item()
                    for a, b in zip(groups[0].stacked.values(), groups[1].stacked.values(),
                                    strict=True))  # fmt: skip
    a, b = (1000 * statistics.median(t) for t in times)
    q = statistics.quantiles([y / x for x, y in zip(*times, strict=True)], n=4)
    print(f"{args.runs} runs, {args.glances} glances, 1 torch thread, {args.repeats} steps each, "
          f"alternating; CPU time per batched step")  # fmt: skip
    print(f"A ({args.ref}): {a:.1f} ms   B (working tree): {b:.1f} ms   B/A per pair: median "
          f"{q[1]:.3f}, quartiles {q[0]:.3f}-{q[2]:.3f}   weights apart: {drift:.1e}")  # fmt: skip


if __name__ == "__main__":
    main()
