"""Tried before `ham table calibrate`, not kept: fine-tuning on the recorded glances spread over
the simulator's grid by interpolation (docs/sim_to_real.md).

    PYTHONPATH=src python docs/results/sim_to_real/interpolated.py MODE SIM_RUN RECORDED OUT \
        [--seed 0] [--steps 1000] [--episodes 640]

SIM_RUN: a run of the paper's world trained on a (x, phi) glance table; RECORDED: an OUT folder
of `docs/examples/sim_to_real.py SIM_RUN ... --grid G` (its `recorded.npz`, the pad's G x G
glances per object). MODE:

- `interp`: the recorded images interpolated multilinearly onto the simulator table's grid;
- `residual`: the simulator's table (scaled to the pad's unit by the ratio of their largest
  pressures, per object) plus the pad-minus-simulator difference at the recorded poses,
  interpolated the same way, read as no less than 0.

Both keep the recorded contact heights, interpolated. SIM_RUN is fine-tuned on the table (OUT/
fine.h5; `--steps`, as sim_to_real.py) and explores the pad live on the hidden objects of
`--seed`, as sim_to_real.py's runs do; prints and writes OUT/live.json.
"""

from __future__ import annotations

import argparse
import importlib.util
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import torch

from ham.learn.train import read_run_config, train
from ham.world.files import write_json
from ham.world.table import grid_values, import_recorded

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "sim_to_real.py"


def linear(values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """The matrix ``(len(at), len(values))`` of 1-D linear interpolation from ``values``."""
    return np.stack([np.interp(at, values, column) for column in np.eye(len(values))], 1)


def spread(a: np.ndarray, grid: int) -> np.ndarray:
    """``a`` ``(G, G, ...)`` over the recorded grid, multilinearly onto ``grid x grid`` points."""
    w = linear(grid_values(a.shape[0]), grid_values(grid))
    return np.einsum("ia,jb,ab...->ij...", w, w, a)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=["interp", "residual"])
    ap.add_argument("sim_run", type=Path)
    ap.add_argument("recorded", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--episodes", type=int, default=640)
    args = ap.parse_args(argv)
    spec = importlib.util.spec_from_file_location("sim_to_real", EXAMPLE)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)

    config = read_run_config(args.sim_run)
    args.out.mkdir(parents=True, exist_ok=True)
    arrays = {}
    with np.load(args.recorded / "recorded.npz") as rec, h5py.File(config.table) as sim:
        names = [n for n in rec.files if not n.startswith("__") and not n.endswith(".height")]
        grid = int(sim.attrs["grid"])
        for n in names:
            pad = rec[n].astype(np.float64)
            g = pad.shape[0]
            if args.mode == "interp":
                image = spread(pad, grid)
            else:
                table = sim[f"objects/{n}/pressure"][...].astype(np.float64)
                scale = pad.max() / table.max()  # the pad's unit against the simulator's
                at = np.rint((grid_values(g) + 1) / 2 * (grid - 1)).astype(int)
                image = scale * table + spread(pad - scale * table[np.ix_(at, at)], grid)
            arrays[n] = np.clip(image, 0, None).astype(np.float32)
            arrays[f"{n}.height"] = spread(rec[f"{n}.height"].astype(np.float64), grid).astype(
                np.float32
            )
    np.savez(args.out / "fine.npz", **arrays)
    table = args.out / "fine.h5"
    if not table.exists():
        import_recorded(args.out / "fine.npz", table)
    tuned = args.out / "fine_tuned"
    if not (tuned / "metrics.json").exists():
        train(replace(config, table=str(table.resolve()), init_from=str(args.sim_run),
                      steps=args.steps), tuned, progress=False)  # fmt: skip
    pad = example.Pad(example.run_world(args.sim_run), "gazebo")
    hidden = torch.randint(len(pad.names), (args.episodes,),
                           generator=torch.Generator().manual_seed(args.seed))  # fmt: skip
    after = example.explore(tuned, pad, hidden, args.seed)
    print(f"{args.mode}, {g} x {g} recorded glances per object, seed {args.seed}: {after:.3f} live")
    write_json(args.out / "live.json", {"mode": args.mode, "grid": g, "seed": args.seed,
                                        "steps": args.steps, "after": after})  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
