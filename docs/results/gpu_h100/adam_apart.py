"""Adam, batched vs single runs on CUDA: each parameter's largest difference, beside a single
run on CUDA vs the same run on the CPU (Adam's own sensitivity to float rounding)."""

import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import torch

sys.path.insert(0, "tests")
from ham.learn.train import load_run, train
from test_batched import tiny, train_both


def worst(pairs):
    out = []
    for tag, a, b in pairs:
        for (n, p), (_, q) in zip(a.named_parameters(), b.named_parameters(), strict=True):
            diff = (p.detach().cpu() - q.detach().cpu()).abs()
            out.append((diff.max().item(), n, tag, (diff > 1e-4).sum().item(), p.numel()))
    out.sort(reverse=True)
    return "; ".join(f"{n} {t} {m:.2e} ({k}/{s} > 1e-4)" for m, n, t, k, s in out[:4])


device = "cuda" if torch.cuda.is_available() else "cpu"
for kw in ({"optimizer": "adam"}, {}):
    for steps in (1, 8):
        with tempfile.TemporaryDirectory() as d:
            d = Path(d)
            configs = [tiny(s, device=device, steps=steps, **kw) for s in range(3)]
            train_both(d, configs)
            for c in configs:
                train(replace(c, device="cpu"), d / f"cpu{c.seed}", progress=False)
            bs = [
                (
                    f"s{c.seed}",
                    load_run(d / f"b{c.seed}").agent,
                    load_run(d / f"single{c.seed}").agent,
                )
                for c in configs
            ]
            cs = [
                (
                    f"s{c.seed}",
                    load_run(d / f"cpu{c.seed}").agent,
                    load_run(d / f"single{c.seed}").agent,
                )
                for c in configs
            ]
            name = kw.get("optimizer", "sgd")
            print(f"{device} {name} steps {steps} batched vs single: {worst(bs)}", flush=True)
            print(
                f"{device} {name} steps {steps} single on cpu vs on {device}: {worst(cs)}",
                flush=True,
            )
