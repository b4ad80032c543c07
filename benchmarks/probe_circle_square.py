"""Can a classifier learn ap_gym's CircleSquare-v0 from its glimpses at all? (docs/learners.md)

Collects episodes of 16 glimpses from ``CircleSquare-v0`` (5 x 5 px, 28 x 28 images) with no
learned policy: a random walk of the registered relative moves (0.2) or uniformly random
teleported glimpses; then trains only a classifier on them, supervised (cross-entropy after
every glance, Adam 1e-3, batches of 64), with the HAM's glance network (what 64, where 64,
two dense layers of 128) and a core (LSTM or the causal transformer of ``ham.model.core``),
and reports the held-out accuracy after glances 1, 8 and 16. The glimpse goes in ``l2``
(normalized), ``none`` (as is) or ``centered`` (minus its mean, x10, plus the mean: what
``ham train --glimpse centered`` feeds). If this cannot get above chance, no policy can.

    PYTHONPATH=src python benchmarks/probe_circle_square.py --moves teleport --glimpse centered \
        --core lstm --updates 2000
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from ham.learn.ap_adapter import CENTER_GAIN, TELEPORT_STEP, import_ap_gym
from ham.model.core import make_core

GLANCES, BATCH, ENVS, TEST = 16, 64, 256, 2048


def collect(moves: str, batches: int, seed: int) -> tuple[torch.Tensor, ...]:
    """``batches * 256`` episodes: glimpses ``(S, N, 25)``, positions ``(S, N, 2)``, labels."""
    import gymnasium as gym

    ap_gym = import_ap_gym()
    cfg = gym.spec("CircleSquare-v0").kwargs["image_perception_config"]
    changes = {"prefetch": False}
    if moves == "teleport":
        changes["max_step_length"] = TELEPORT_STEP
    env = ap_gym.make_vec("CircleSquare-v0", num_envs=ENVS,
                          image_perception_config=dataclasses.replace(cfg, **changes))  # fmt: skip
    rng = np.random.default_rng(seed)
    glimpses, positions, labels = [], [], []
    for _ in range(batches):
        obs, _ = env.reset(seed=int(rng.integers(1 << 30)))
        g, p = [obs["glimpse"].reshape(ENVS, -1)], [obs["glimpse_pos"].copy()]
        for s in range(GLANCES - 1):
            if moves == "teleport":  # toward a uniform target, reached in one step
                action = (rng.uniform(-1, 1, (ENVS, 2)) - obs["glimpse_pos"]) / TELEPORT_STEP
            else:
                action = rng.uniform(-1, 1, (ENVS, 2))
            obs, _, _, _, info = env.step(
                {"action": action.astype(np.float32), "prediction": np.zeros((ENVS, 2), np.float32)}
            )
            g.append(obs["glimpse"].reshape(ENVS, -1))
            p.append(obs["glimpse_pos"].copy())
            if s == 0:
                labels.append(np.asarray(info["prediction"]["target"]))
        glimpses.append(np.stack(g))
        positions.append(np.stack(p))
    env.close()
    return (torch.tensor(np.concatenate(glimpses, 1)), torch.tensor(np.concatenate(positions, 1)),
            torch.tensor(np.concatenate(labels)).long())  # fmt: skip


def transform(g: torch.Tensor, glimpse: str) -> torch.Tensor:
    if glimpse == "l2":
        return g / g.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    if glimpse == "centered":
        mean = g.mean(-1, keepdim=True)
        return torch.cat([(g - mean) * CENTER_GAIN, mean], -1)
    return g


class Classifier(nn.Module):
    def __init__(self, inputs: int, core: str, width: int = 128) -> None:
        super().__init__()
        self.what = nn.Linear(inputs, 64)
        self.where = nn.Linear(2, 64)
        self.combine = nn.Sequential(nn.Linear(128, width), nn.ReLU(), nn.Linear(width, width),
                                     nn.ReLU())  # fmt: skip
        self.core = make_core(core, width, width)
        self.head = nn.Linear(width, 2)

    def forward(self, g: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        x = self.combine(torch.cat([F.relu(self.what(g)), F.relu(self.where(p))], -1))
        state, out = self.core.initial_state(g.shape[1], g), []
        for s in range(g.shape[0]):
            tau, state = self.core(x[s], state)
            out.append(self.head(tau))
        return torch.stack(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--moves", choices=("walk", "teleport"), default="teleport")
    ap.add_argument("--glimpse", choices=("l2", "none", "centered"), default="centered")
    ap.add_argument("--core", default="lstm")
    ap.add_argument("--updates", type=int, default=2000)
    ap.add_argument("--batches", type=int, default=40, help="of 256 episodes (16 glimpses each)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    g, p, y = collect(args.moves, args.batches, args.seed)
    touch = (g.amax(-1) > 0.97).any(0).float().mean().item()
    print(f"{args.moves}: {y.numel()} episodes, {touch:.3f} of them see the object (> 0.97)")
    x = transform(g, args.glimpse)
    torch.manual_seed(args.seed)
    model = Classifier(x.shape[-1], args.core)
    opt = torch.optim.Adam(model.parameters(), 1e-3)
    n = y.numel() - TEST
    gen = torch.Generator().manual_seed(args.seed)
    t0 = time.perf_counter()
    for u in range(1, args.updates + 1):
        idx = torch.randint(0, n, (BATCH,), generator=gen)
        logits = model(x[:, idx], p[:, idx])
        loss = F.cross_entropy(logits.reshape(-1, 2), y[idx].repeat(GLANCES))
        opt.zero_grad()
        loss.backward()
        opt.step()
        if u % max(1, args.updates // 4) == 0:
            with torch.no_grad():
                acc = (model(x[:, n:], p[:, n:]).argmax(-1) == y[n:]).float().mean(1)
            print(f"{args.core} {args.glimpse} update {u}: held-out accuracy after glance 1 "
                  f"{acc[0]:.3f}, 8 {acc[7]:.3f}, 16 {acc[15]:.3f} "
                  f"({time.perf_counter() - t0:.0f} s)")  # fmt: skip


if __name__ == "__main__":
    main()
