"""The location policy's mean sigma (normalized pose units) of each run's final checkpoint.

    python docs/results/plugin_no_baseline/sigma.py runs/plugin_no_baseline/runs

10 batches of the run's own environment, poses sampled with a generator seeded 0.
"""

import sys
from pathlib import Path

import torch

from ham.learn.train import load_run

for d in sorted(Path(sys.argv[1]).iterdir()):
    run = load_run(d)
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():
        sigma = [
            run.agent(run.env, run.env.sample_objects(), generator).policy.sigma.mean()
            for _ in range(10)
        ]
    print(d.name, f"{torch.stack(sigma).mean():.4f}")
