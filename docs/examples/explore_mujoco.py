"""Drive a trained HAM with glances from outside, one glance at a time, as a robot's pad would
hand them in: here MuJoCo stands in for the robot (ham.learn.explorer.Explorer).

    python docs/examples/explore_mujoco.py RUN_DIR [--episodes 64] [--seed 0] [--sensor taxels|gazebo]

RUN_DIR: a run of the paper's objects (e.g. `make demo`'s runs/demo/ham). Each episode's object
is drawn at random and kept from the agent; each glance is MuJoCo's: the pad moved to the pose
the agent asks for and pressed to 2 N, its raw image (Pa) handed to the explorer, which answers
with the next pose. Prints the accuracy after the last glance.
"""

from __future__ import annotations

import argparse

import torch

from ham.errors import HamError
from ham.learn.explorer import Explorer
from ham.world.config import WorldConfig, make_simulator
from ham.world.poses import simulate, world_pose_dims


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("--episodes", type=int, default=64)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sensor", choices=["taxels", "gazebo"], default="taxels")
    args = ap.parse_args(argv)

    explorer = Explorer.from_run(args.run, episodes=args.episodes, seed=args.seed)
    # the robot's side: MuJoCo over the paper's objects, the pose mapping of the paper
    world = WorldConfig(simulator="mujoco", mujoco={"readout": args.sensor})
    names = [o.name for o in world.resolve_objects()]
    if names != explorer.objects:
        raise HamError(f"the run classifies {explorer.objects}, this example's world holds "
                       f"{names}; accepted: a run of the paper's objects")  # fmt: skip
    robot = make_simulator(world)
    hidden = torch.randint(len(names), (args.episodes,),
                           generator=torch.Generator().manual_seed(args.seed))  # fmt: skip

    q = explorer.reset()
    while q is not None:
        glance = simulate(robot, hidden, q, world_pose_dims(world))  # move, press to 2 N, read
        q = explorer.observe(glance.pressure)
    accuracy = (explorer.prediction == hidden).double().mean().item()
    print(f"{args.episodes} episodes, {explorer.glances} MuJoCo glances each ({args.sensor} "
          f"read-out): accuracy {accuracy:.3f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    try:
        raise SystemExit(main())
    except HamError as exc:
        raise SystemExit(f"explore_mujoco: error: {exc}") from None
