"""Milliseconds per HAM training step, and the overhead over the bare network.

For G = 3 and 10 glances: the full training step (fresh batch, S glances from the glance source,
location sampling, hybrid loss, backward, SGD step, NaN checks) against the bare network's
forward + backward on the same batch's recorded glances (``HapticAttentionModel.replay``: no
environment, no sampling), measured interleaved in the same run. Target ratio <= 1.3.

    .venv/bin/python benchmarks/bench_train.py [--table FILE] [--threads 1] [--repeats 30]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import torch
from torch.nn import functional as F

from ham.learn.train import Run, TrainConfig, train_step
from ham.model.agent import HamConfig


def bare_step(run: Run, pressures: torch.Tensor, locations: torch.Tensor, objects: torch.Tensor):
    """The network alone: forward over recorded glances, a loss touching every head, backward."""
    episode = run.agent.replay(pressures, locations)
    loss = F.cross_entropy(episode.logits[-1], objects) + episode.baselines.square().mean()
    if episode.policy is not None and episode.policy.trainable:
        loss = loss - episode.policy.log_prob(locations[1:]).mean()
    run.optimizer.zero_grad(set_to_none=True)
    loss.backward()


def measure(glances: int, table: str | None, device: str, repeats: int) -> dict:
    config = TrainConfig(model=HamConfig(glances=glances), table=table, device=device)
    run = Run.create(config)
    # One recorded batch for the bare network: the glances a real episode took.
    objects = run.env.sample_objects()
    with torch.no_grad():
        episode = run.agent(run.env, objects, run.policy_generator)
    locations = episode.locations
    pressures = torch.stack([run.env.glance(objects, q) for q in locations])

    def sync():
        if device.startswith("cuda"):
            torch.cuda.synchronize()

    for _ in range(5):  # warm up both
        train_step(run)
        bare_step(run, pressures, locations, objects)
    t_train, t_bare = [], []
    for _ in range(repeats):  # interleaved, so both see the same machine load
        sync()
        t0 = time.perf_counter()
        train_step(run)
        sync()
        t1 = time.perf_counter()
        bare_step(run, pressures, locations, objects)
        sync()
        t2 = time.perf_counter()
        t_train.append(1000 * (t1 - t0))
        t_bare.append(1000 * (t2 - t1))
    train_ms, bare_ms = statistics.median(t_train), statistics.median(t_bare)
    return {
        "glances": glances,
        "source": "table" if table else "online",
        "device": device,
        "train_step_ms": train_ms,
        "bare_forward_backward_ms": bare_ms,
        "ratio": train_ms / bare_ms,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--glances", type=int, nargs="+", default=[3, 10])
    ap.add_argument("--table", help="glance table (default: online fast simulator)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    rows = [measure(g, args.table, args.device, args.repeats) for g in args.glances]
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    print(f"HAM training step, batch 64, {rows[0]['source']} glances, {args.device}, "
          f"{args.threads} thread(s), median of {args.repeats}")  # fmt: skip
    print(f"{'glances':>7}  {'train step ms':>13}  {'bare fwd+bwd ms':>15}  {'ratio':>5}")
    for r in rows:
        print(f"{r['glances']:>7}  {r['train_step_ms']:>13.2f}  "
              f"{r['bare_forward_backward_ms']:>15.2f}  {r['ratio']:>5.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
