"""Where an SB3 agent's environment step goes: `ham sb3`'s wrapper vs the library's update.

One environment step of ``ham sb3 --algo sac|crossq`` (SB3's defaults: one gradient step per
environment step, batch 256) is: the agent's action (``model.predict``), the wrapper's step (the
head's prediction, the environment's own step, the observation of the episode so far, every 4th
step one Adam step of the head on 256 remembered steps) and one gradient step of the agent
(``model.train(1)``). Each part is timed alone (mean over the repeats: the head's step every 4th
environment step counts), all interleaved in one loop so all see the same machine load, by CPU
time of this process (``time.process_time``: robust to other processes on a shared machine) and
by wall time. Env steps per second = 1 / the sum of the parts.

    .venv/bin/python benchmarks/bench_sb3.py [--env ap_gym:CircleSquare-v0] [--algos sac crossq]
        [--repeats 200] [--threads 1] [--json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np
import torch

from ham.learn.sb3_agents import PredictionHead, SupervisedPrediction, make_env


def _timed(fn) -> tuple[float, float]:
    c, w = time.process_time(), time.perf_counter()
    fn()
    return time.process_time() - c, time.perf_counter() - w


def measure(env_name: str, algo: str, repeats: int, warmup: int = 300) -> dict:
    from stable_baselines3 import SAC
    from stable_baselines3.common.vec_env import DummyVecEnv

    probe = SupervisedPrediction(make_env(env_name))
    head = PredictionHead(probe.observation_space.shape[0], probe.n_classes)
    venv = DummyVecEnv([lambda: SupervisedPrediction(make_env(env_name), head)])
    if algo == "crossq":
        from sb3_contrib import CrossQ as cls
    else:
        cls = SAC
    model = cls("MlpPolicy", venv, seed=0, verbose=0, learning_starts=warmup)
    model.learn(warmup + 1)  # fill the buffer past learning_starts, build the optimizers
    env = SupervisedPrediction(make_env(env_name), head)
    obs, _ = env.reset(seed=0)
    bare = make_env(env_name)
    bare.reset(seed=0)
    zero = np.zeros(probe.n_classes, np.float32)
    parts: dict[str, list] = {"predict": [], "wrapper_step": [], "env_alone": [], "train": []}
    for _ in range(repeats):
        action = model.predict(obs, deterministic=False)[0]
        parts["predict"].append(_timed(lambda: model.predict(obs, deterministic=False)))

        def step(action=action):
            nonlocal obs
            obs, _, term, trunc, _ = env.step(action)
            if term or trunc:
                obs, _ = env.reset()

        parts["wrapper_step"].append(_timed(step))

        def bare_step(action=action):
            _, _, term, trunc, _ = bare.step({"action": action, "prediction": zero})
            if term or trunc:
                bare.reset()

        parts["env_alone"].append(_timed(bare_step))
        parts["train"].append(_timed(lambda: model.train(gradient_steps=1, batch_size=256)))
    ms = {
        name: {
            "cpu_ms": 1e3 * statistics.mean(c for c, _ in v),
            "wall_ms": 1e3 * statistics.mean(w for _, w in v),
        }
        for name, v in parts.items()
    }
    total = {k: sum(ms[p][k] for p in ("predict", "wrapper_step", "train")) for k in ms["train"]}
    return {
        "algo": algo,
        "env": env_name,
        "obs_dim": int(probe.observation_space.shape[0]),
        "parts_ms": ms,
        "env_steps_per_s_cpu": 1e3 / total["cpu_ms"],
        "env_steps_per_s_wall": 1e3 / total["wall_ms"],
        "wrapper_share_cpu": (ms["wrapper_step"]["cpu_ms"] - ms["env_alone"]["cpu_ms"])
        / total["cpu_ms"],
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", default="ap_gym:CircleSquare-v0")
    p.add_argument("--algos", nargs="+", default=["sac", "crossq"], choices=["sac", "crossq"])
    p.add_argument("--repeats", type=int, default=200)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    results = [measure(args.env, a, args.repeats) for a in args.algos]
    if args.json:
        print(json.dumps(results, indent=1))
        return
    for r in results:
        parts = ", ".join(
            f"{k} {v['cpu_ms']:.2f} ms ({v['wall_ms']:.2f} wall)" for k, v in r["parts_ms"].items()
        )
        print(
            f"{r['algo']} on {r['env']} (obs {r['obs_dim']}): "
            f"{r['env_steps_per_s_cpu']:.1f} env steps/s by CPU time, "
            f"{r['env_steps_per_s_wall']:.1f} by wall time; wrapper (without the env) "
            f"{100 * r['wrapper_share_cpu']:.1f}% of CPU; {parts}"
        )


if __name__ == "__main__":
    main()
