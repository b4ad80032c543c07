"""From simulation to a pad of its own: record a few glances, fine-tune on them, explore live.

    python docs/examples/sim_to_real.py SIM_RUN OUT [--grid 11] [--steps 1000] [--episodes 640]
        [--sensor gazebo|taxels] [--seed 0] [--pose-noise 0] [--policy-lr-scale S]
        [--calibrate K [--record-objects A,B] | --readout-from CALIBRATED.h5] [--sim-grid 21]
        [--pad-pose-noise 0] [--json]

SIM_RUN: a run trained in simulation (e.g. `make demo`'s runs/demo/ham; any objects and pose
dims MuJoCo can glance: the paper's, or the next world's height fields with poses x, y, ...).
The "real" pad is MuJoCo here, over the run's objects and poses, with the Gazebo plugin's
read-out by default (a few contact points, each spread by 5 mm: a world the fast simulator's
runs read poorly); for a real pad, replace `Pad.glance` with your robot's. The loop, each step a
function of ham's:

1. SIM_RUN explores the pad live (`Explorer`): `--episodes` episodes, each of a hidden object
   drawn from `--seed`, every glance the pad's at the pose the agent asks for (with
   `--pad-pose-noise S`, a robot that misses it: Gaussian errors of S normalized units on each
   pose dim, kept within -1..1; the same errors in every live exploration of a seed).
2. The pad records `--grid` poses per pose dim (one number, or one per dim: 9,5) of glances per
   object, with their contact heights
   (`record_glances`: OUT/recorded.npz, resumable), imported as a glance table
   (`import_recorded`: OUT/recorded.h5).
3. SIM_RUN fine-tuned on that table (`train` with `init_from`: OUT/fine_tuned, `--steps` steps,
   `--pose-noise` on each training glance's pose, `--policy-lr-scale` the location network's
   rate against the rest's, SIM_RUN's other settings). With `--calibrate K` it is fine-tuned
   instead on SIM_RUN's own table carried onto the pad by a K x K read-out fitted to the
   recorded glances (`calibrate_table`: OUT/calibrated.h5); a run trained online gets a table
   of its world first, `--sim-grid` points per pose dim (OUT/simulated.h5). `--record-objects`
   records only those objects: the read-out fitted to them carries the others too.
   `--readout-from CALIBRATED.h5` records nothing: SIM_RUN's table is carried onto the pad by
   the read-out fitted before (another run's OUT/calibrated.h5, the same pad; `carry_readout`).
4. The fine-tuned run explores the pad live, on the same hidden objects.

Prints the accuracy after the last glance before and after (`--json`: also into OUT/live.json);
each step's output stays in OUT, and a second call reuses it (an interrupted recording resumes);
a second call with another SIM_RUN or other arguments (but `--episodes` and `--json`) is refused
(OUT/made_by.json), not answered with the first call's files.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from ham.errors import HamError
from ham.learn.explorer import Explorer
from ham.learn.train import read_run_config, train
from ham.world.calibration import calibrate_table, carry_readout, describe
from ham.world.config import WorldConfig, make_simulator
from ham.world.files import write_json
from ham.world.poses import result_height, simulate, world_pose_dims
from ham.world.recorder import record_glances
from ham.world.table import build_table, grid_shape_for, import_recorded, table_info


class Pad:
    """The pad on the robot: MuJoCo over the run's objects and poses (swap in your robot).
    ``pose_noise``: the robot's pose error, Gaussian, per normalized pose dim (0: none)."""

    def __init__(self, world: WorldConfig, sensor: str, pose_noise: float = 0.0) -> None:
        self.world = replace(world, simulator="mujoco", mujoco={"readout": sensor})
        self.names = [o.name for o in self.world.resolve_objects()]
        self.sim = make_simulator(self.world)
        self.pose_noise, self.errors = pose_noise, torch.Generator()

    def reseed(self, seed: int) -> None:
        """Restart the pose errors (the same errors for the same seed)."""
        self.errors.manual_seed(seed)

    def glance(self, ids: torch.Tensor, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Move to the normalized poses ``q`` ``(B, k)`` over objects ``ids`` (missed by the
        pose error), press to 2 N: the raw images ``(B, N, N)`` and the contact heights
        ``(B,)`` (m)."""
        if self.pose_noise > 0:
            error = torch.randn(q.shape, generator=self.errors, dtype=torch.float64)
            q = (q.double() + self.pose_noise * error).clamp(-1.0, 1.0)
        r = simulate(self.sim, ids, q, world_pose_dims(self.world))
        return r.pressure, result_height(r)


def run_world(run: Path) -> WorldConfig:
    """The world a run trained in: its glance table's, or its online world."""
    config = read_run_config(run)
    if config.table is None:
        return config.world
    return WorldConfig.from_dict(table_info(config.table).world)


def explore(run: Path, pad: Pad, hidden: torch.Tensor, seed: int) -> float:
    """``run`` driven by the pad's live glances on the ``hidden`` objects: its accuracy."""
    explorer = Explorer.from_run(run, episodes=len(hidden), seed=seed)
    pad.reseed(seed)  # before and after fine-tuning: the same pose errors
    if explorer.objects != pad.names:
        raise HamError(f"the run classifies {explorer.objects}, the pad's world holds "
                       f"{pad.names}; accepted: a run of the pad's objects")  # fmt: skip
    reads_height = explorer.agent.config.height_input
    q = explorer.reset()
    while q is not None:
        image, height = pad.glance(hidden, q)
        q = explorer.observe(image, height if reads_height else None)
    return (explorer.prediction == hidden).double().mean().item()


#: the arguments OUT's files depend on (not --episodes or --json: only the live episodes)
MADE_BY = ("grid", "steps", "sensor", "seed", "pose_noise", "policy_lr_scale", "calibrate",
           "sim_grid", "pad_pose_noise", "record_objects", "readout_from")  # fmt: skip


def check_made_by(args: argparse.Namespace) -> None:
    """OUT/made_by.json: the run and arguments OUT's files were made with. A rerun reuses
    them, so a rerun with others is refused, not answered with the first call's files."""
    made_by = {"sim_run": str(args.sim_run.resolve()),
               **{k: str(getattr(args, k)) if isinstance(getattr(args, k), Path)
                  else getattr(args, k) for k in MADE_BY}}  # fmt: skip
    path = args.out / "made_by.json"
    if path.exists():
        before = json.loads(path.read_text())
        if before != made_by:
            changed = ", ".join(f"{k}: {before.get(k)!r} -> {v!r}" for k, v in made_by.items()
                                if before.get(k) != v)  # fmt: skip
            raise HamError(f"{str(args.out)!r} was made with other arguments ({changed}); "
                           "accepted: the same SIM_RUN and arguments, or another OUT")  # fmt: skip
    else:
        args.out.mkdir(parents=True, exist_ok=True)
        write_json(path, made_by)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sim_run", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--grid", default="11", help="recorded poses per pose dim: one number for "
                    "all (default 11), or one per dim, e.g. 9,5 (x, phi)")  # fmt: skip
    ap.add_argument("--steps", type=int, default=1000, help="fine-tuning steps (default 1000)")
    ap.add_argument("--episodes", type=int, default=640, help="live episodes (default 640)")
    ap.add_argument("--sensor", choices=["gazebo", "taxels"], default="gazebo")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--pose-noise",
        type=float,
        default=0.0,
        help="fine-tuning: Gaussian noise on each glance's pose (normalized units)",
    )
    ap.add_argument("--policy-lr-scale", type=float, default=None,
                    help="fine-tuning: the location network's learning rate relative to the "
                    "rest's (default SIM_RUN's; 0: the simulation's policy kept)")  # fmt: skip
    ap.add_argument("--calibrate", type=int, default=None, metavar="K",
                    help="fine-tune on SIM_RUN's table carried onto the pad by a K x K read-out "
                    "fitted to the recorded glances, not on the recorded glances alone")  # fmt: skip
    ap.add_argument("--record-objects", default=None, metavar="A,B",
                    help="with --calibrate: record only these objects (default all)")  # fmt: skip
    ap.add_argument("--readout-from", type=Path, default=None, metavar="CALIBRATED",
                    help="record nothing: fine-tune on SIM_RUN's table carried by the read-out "
                    "of this calibrated table (fitted before, the same pad)")  # fmt: skip
    ap.add_argument("--sim-grid", default="21", help="with --calibrate, a run trained online: "
                    "its world's table, points per pose dim (default 21)")  # fmt: skip
    ap.add_argument("--pad-pose-noise", type=float, default=0.0, metavar="S",
                    help="the robot's pose error: Gaussian, S normalized units per pose dim, "
                    "while recording and live (default 0)")  # fmt: skip
    ap.add_argument("--json", action="store_true", help="also write OUT/live.json")
    args = ap.parse_args(argv)

    if not (args.pad_pose_noise >= 0 and np.isfinite(args.pad_pose_noise)):
        raise HamError(f"--pad-pose-noise {args.pad_pose_noise}; accepted: a finite number >= 0")
    pad = Pad(run_world(args.sim_run), args.sensor, args.pad_pose_noise)
    dims = world_pose_dims(pad.world)
    shape = grid_shape_for(args.grid, dims)  # a bad --grid refused before the pad is touched
    recorded_names = pad.names
    if args.record_objects is not None:
        recorded_names = args.record_objects.split(",")
        if args.calibrate is None:
            raise HamError("--record-objects without --calibrate; accepted: it with --calibrate "
                           "(fine-tuning on the recorded glances alone needs every object)")  # fmt: skip
        if not recorded_names or not set(recorded_names) <= set(pad.names):
            raise HamError(f"--record-objects {args.record_objects!r}; accepted: a comma list "
                           f"of the run's objects: {','.join(pad.names)}")  # fmt: skip
    if args.readout_from is not None and (args.calibrate or args.record_objects):
        raise HamError("--readout-from with --calibrate or --record-objects; accepted: one way to "
                       "a calibrated table: a read-out fitted to recorded glances, or one fitted "
                       "before")  # fmt: skip
    check_made_by(args)
    hidden = torch.randint(len(pad.names), (args.episodes,),
                           generator=torch.Generator().manual_seed(args.seed))  # fmt: skip
    before = explore(args.sim_run, pad, hidden, args.seed)

    def glance(name: str, q: np.ndarray):  # one glance at a time, as a robot records them
        image, height = pad.glance(torch.tensor([pad.names.index(name)]), torch.tensor(q)[None])
        return image[0].numpy(), float(height[0])

    recorded = args.out / "recorded.npz"  # a rerun asks the pad nothing: it is recorded
    pad.reseed(args.seed + 1)  # the recording's pose errors (another stream than the live ones)
    if args.readout_from is None:
        record_glances(glance, recorded_names, args.grid, recorded, pose_dims=dims,
                       heights=True, progress=False)  # fmt: skip
    table = args.out / "recorded.h5"
    if not table.exists() and recorded_names == pad.names and args.readout_from is None:
        import_recorded(recorded, table, pose_dims=dims)
    if args.calibrate is not None or args.readout_from is not None:
        simulated = read_run_config(args.sim_run).table
        if simulated is None:  # trained online: a table of its world
            simulated = args.out / "simulated.h5"
            if not simulated.exists():
                build_table(run_world(args.sim_run), args.sim_grid, simulated, progress=False)
        table = args.out / "calibrated.h5"
        if not table.exists() and args.readout_from is not None:
            _, readout = carry_readout(simulated, args.readout_from, table)
            print(f"{describe(readout)} (from {args.readout_from})")
        elif not table.exists():
            _, readout = calibrate_table(simulated, recorded, table, kernel=args.calibrate)
            print(describe(readout))
    tuned = args.out / "fine_tuned"
    if not (tuned / "metrics.json").exists():
        config = replace(read_run_config(args.sim_run), table=str(table.resolve()),
                         init_from=str(args.sim_run), steps=args.steps,
                         pose_noise=args.pose_noise)  # fmt: skip
        if args.policy_lr_scale is not None:
            config = replace(config, policy_lr_scale=args.policy_lr_scale)
        train(config, tuned, progress=False)
    after = explore(tuned, pad, hidden, args.seed)
    print(f"{args.episodes} live episodes on the pad (MuJoCo, {args.sensor} read-out): "
          f"{before:.3f} trained in simulation, {after:.3f} fine-tuned on "
          + (f"{' x '.join(map(str, shape))} recorded glances per object "
             if args.readout_from is None else "its table carried by a read-out fitted before ")
          + f"({args.steps} steps{', calibrated' if args.calibrate else ''})")  # fmt: skip
    if args.json:
        grid = int(args.grid) if args.grid.isdigit() else list(shape)
        kept = ("steps", "episodes", "sensor", "seed", "pose_noise", "policy_lr_scale",
                "calibrate", "pad_pose_noise", "record_objects")  # fmt: skip
        readout_from = None if args.readout_from is None else str(args.readout_from)
        write_json(args.out / "live.json", {"before": before, "after": after, "grid": grid,
                                            **{k: getattr(args, k) for k in kept},
                                            "readout_from": readout_from})  # fmt: skip
    return 0


if __name__ == "__main__":
    try:
        raise SystemExit(main())
    except HamError as exc:
        raise SystemExit(f"sim_to_real: error: {exc}") from None
