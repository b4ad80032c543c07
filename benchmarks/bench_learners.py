"""Environment steps per second of each learner, and its ratio to the bare network's.

Learners: ``hybrid`` (the paper's loss, SGD), ``hybrid+separate`` (the same with
``--encoders separate``: the policy and the baseline read encoders of their own), ``info`` (the information learner's recipe: Adam,
learned first glance), ``info+stop`` (the same with a learned stop, ``--glance-cost 0.1``) and
``sac`` (the off-policy learner with the squashed policy: a fresh batch played into the replay
buffer, then its updates on replayed episodes).
Each full training step (fresh batch, S glances from the glance source, location sampling, the
learner's loss, backward, optimizer step, NaN checks) is timed against the bare network's
forward + backward on recorded glances of the same batch (``HapticAttentionModel.replay``: no
environment, no sampling; :func:`bench_train.bare_step`), all learners interleaved in one loop so
all see the same machine load. An environment step is a glance: ``batch * glances`` per step.

    .venv/bin/python benchmarks/bench_learners.py [--table FILE] [--glances 10] [--batch-size 16]
        [--threads 1] [--repeats 30] [--json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import torch
from bench_train import bare_step

from ham.learn.train import Run, TrainConfig, train_step
from ham.model.agent import HamConfig

#: the learners compared, as ``TrainConfig`` fields beyond the common ones
LEARNERS: dict[str, dict] = {
    "hybrid": {},
    "hybrid+separate": {},
    "info": {"learner": "info", "optimizer": "adam", "lr": 3e-3, "policy_lr_scale": 0.3},
    "info+stop": {
        "learner": "info",
        "optimizer": "adam",
        "lr": 3e-3,
        "policy_lr_scale": 0.3,
        "glance_cost": 0.1,
    },
    "sac": {"learner": "sac", "optimizer": "adam", "lr": 1e-3, "gamma": 0.95},
}


def make_run(name: str, glances: int, batch: int, table: str | None, device: str) -> Run:
    kw = dict(LEARNERS[name])
    model = HamConfig(
        glances=glances,
        first_glance="learned" if name.startswith("info") else "random",
        stop=name.endswith("+stop"),
        policy="squashed" if name == "sac" else "learned",
        encoders="separate" if name.endswith("+separate") else "shared",
    )
    config = TrainConfig(model=model, batch_size=batch, table=table, device=device, **kw)
    return Run.create(config)


def measure(glances: int, batch: int, table: str | None, device: str, repeats: int) -> list:
    runs = {name: make_run(name, glances, batch, table, device) for name in LEARNERS}
    recorded = {}
    for name, run in runs.items():  # one recorded batch each: the glances a real episode took
        objects = run.env.sample_objects()
        with torch.no_grad():
            episode = run.agent(run.env, objects, run.policy_generator)
        pressures = torch.stack([run.env.glance(objects, q) for q in episode.locations])
        recorded[name] = (pressures, episode.locations, objects)

    def sync():
        if device.startswith("cuda"):
            torch.cuda.synchronize()

    def timed(fn) -> float:
        sync()
        t0 = time.perf_counter()
        fn()
        sync()
        return time.perf_counter() - t0

    for _ in range(5):  # warm up all
        for name, run in runs.items():
            train_step(run)
            bare_step(run, *recorded[name])
    t_train = {name: [] for name in runs}
    t_bare = {name: [] for name in runs}
    for _ in range(repeats):  # interleaved: every learner sees the same machine load
        for name, run in runs.items():
            t_train[name].append(timed(lambda run=run: train_step(run)))
            t_bare[name].append(timed(lambda run=run, name=name: bare_step(run, *recorded[name])))
    rows = []
    per_step = batch * glances
    for name in runs:
        train_s, bare_s = statistics.median(t_train[name]), statistics.median(t_bare[name])
        rows.append(
            {
                "learner": name,
                "glances": glances,
                "batch_size": batch,
                "source": "table" if table else "online",
                "device": device,
                "train_step_ms": 1000 * train_s,
                "bare_forward_backward_ms": 1000 * bare_s,
                "env_steps_per_s": per_step / train_s,
                "bare_env_steps_per_s": per_step / bare_s,
                "ratio": train_s / bare_s,
            }
        )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--glances", type=int, default=10)
    ap.add_argument("--batch-size", type=int, default=16)
    ap.add_argument("--table", help="glance table (default: online fast simulator)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    rows = measure(args.glances, args.batch_size, args.table, args.device, args.repeats)
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    r0 = rows[0]
    print(f"learners, {r0['glances']} glances, batch {r0['batch_size']}, {r0['source']} glances, "
          f"{args.device}, {args.threads} thread(s), median of {args.repeats}")  # fmt: skip
    print(f"{'learner':>15}  {'step ms':>7}  {'env steps/s':>11}  {'bare ms':>7}  "
          f"{'bare env steps/s':>16}  {'ratio':>5}")  # fmt: skip
    for r in rows:
        print(f"{r['learner']:>15}  {r['train_step_ms']:>7.2f}  {r['env_steps_per_s']:>11.0f}  "
              f"{r['bare_forward_backward_ms']:>7.2f}  {r['bare_env_steps_per_s']:>16.0f}  "
              f"{r['ratio']:>5.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
