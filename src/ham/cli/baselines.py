"""``ham baselines``: exact accuracies of reference policies on a glance table
(:mod:`ham.learn.planners`): how far from optimal is a learned policy? ``ham sb3``: the learned
baselines, Stable-Baselines3 agents (:mod:`ham.learn.sb3_agents`)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ham.errors import HamError


def add_commands(subparsers) -> None:
    from ham.learn.planners import FIRST, POLICIES

    p = subparsers.add_parser(
        "baselines",
        help="exact accuracy of random, grid, infogain and oracle policies on a glance table",
        description="Bayes accuracy after G glances of a reference policy on a glance table, "
        "computed exactly (dynamic programming over consistent object sets): random poses, a "
        "fixed grid sweep, greedy expected information gain, or the optimal planner (with N*, "
        "the fewest expected glances that identify the object).",
    )
    p.add_argument("--policy", required=True, choices=POLICIES, help="the reference policy")
    p.add_argument("--table", required=True, metavar="FILE", help="glance table (HDF5)")
    p.add_argument("--glances", type=int, nargs="+", default=[1, 2, 3, 4, 6, 8, 10],
                   metavar="G", help="glance counts (default 1 2 3 4 6 8 10)")  # fmt: skip
    p.add_argument("--first", choices=FIRST, default="planned",
                   help="planned (default) or random: the first glance uniform, as the HAM's")  # fmt: skip
    p.add_argument("--tolerance", type=float, default=1e-6,
                   help="images closer than this (L2, normalized) are equal (default 1e-6)")  # fmt: skip
    p.add_argument("--height", action="store_true",
                   help="the contact height tells objects apart too (as a HAM with --height-input)")  # fmt: skip
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_baselines)
    add_sb3_command(subparsers)


def cmd_baselines(args: argparse.Namespace) -> int:
    from ham.learn.planners import Partitions, Planner
    from ham.world.table import GlanceTable

    for g in args.glances:
        if g < 1:
            raise HamError(f"--glances {g}; accepted: integers >= 1")
    if not Path(args.table).is_file():
        raise HamError(f"glance table {args.table!r} does not exist")
    if args.first == "random" and args.policy in ("random", "grid"):
        raise HamError(f"--first random applies to infogain and oracle, not to {args.policy!r}")
    table = GlanceTable.load(args.table)
    planner = Planner(Partitions.from_table(table, args.tolerance, height=args.height))
    accuracy = {str(g): planner.accuracy(args.policy, g, args.first) for g in args.glances}
    result = {
        "policy": args.policy,
        "table": str(args.table),
        "objects": table.objects,
        "pose_dims": list(table.pose_dims),
        "grid_shape": list(table.grid_shape),
        "first": args.first,
        "tolerance": args.tolerance,
        "height": args.height,
        "distinct_actions": int(len(planner.parts.labels)),
        "identifying_share": planner.parts.identifying_share(),
        "accuracy": accuracy,
    }
    if args.policy in ("oracle", "infogain"):
        result["expected_glances_to_identify"] = planner.expected_glances(args.policy, args.first)
    if args.json:
        json.dump(result, sys.stdout)
        sys.stdout.write("\n")
        return 0
    print(
        f"{args.policy} on {args.table} ({len(table.objects)} objects, pose grid "
        f"{'x'.join(map(str, table.grid_shape))} over {','.join(table.pose_dims)}, "
        f"{result['distinct_actions']} distinct pose actions, first glance {args.first})"
    )
    print(
        f"one glance tells every object apart at {result['identifying_share']:.1%} of poses "
        "(uniform poses)"
    )
    print("| glances | accuracy |\n|---|---|")
    for g, a in accuracy.items():
        print(f"| {g} | {a:.4f} |")
    if "expected_glances_to_identify" in result:
        print(f"expected glances to identify: {result['expected_glances_to_identify']:.3f}")
    return 0


# --------------------------------------------------------------------------- sb3
def add_sb3_command(subparsers) -> None:
    from ham.learn.sb3_agents import ALGOS, Sb3Config

    d = Sb3Config()
    p = subparsers.add_parser(
        "sb3",
        help="train a Stable-Baselines3 agent (ppo, sac, crossq) as a learned baseline",
        description="Train an off-the-shelf agent on an active classification environment: the "
        "SB3 agent picks the glance, a supervised MLP head predicts (ham.learn.sb3_agents). "
        "Writes OUT/metrics.json (env_steps, final_accuracy, average_accuracy, "
        "accuracy_per_glance, history), config.json, model.zip and head.pt.",
    )
    # Flags default to None, the config's defaults filled in by cmd_sb3: --resume can then tell
    # a flag given (refused: the run keeps its config) from one left out.
    p.add_argument("--algo", choices=ALGOS, help="ppo, sac or crossq (sb3-contrib); required")
    p.add_argument("--env", metavar="ID",
                   help="ham/HapticGlanceAP-v0 (default) or ap_gym:ENV_ID")  # fmt: skip
    p.add_argument("--glances", type=int, metavar="G",
                   help="glances per episode (ham/ envs only; the env's default otherwise)")  # fmt: skip
    p.add_argument("--table", metavar="FILE",
                   help="glance table (HDF5) for ham/ envs; default: simulate online")  # fmt: skip
    p.add_argument("--env-steps", type=int, metavar="N",
                   help=f"environment steps (glances) to train for (default {d.env_steps}); "
                   "with --resume: a new, larger total")  # fmt: skip
    p.add_argument("--seed", type=int, help=f"seed (default {d.seed})")
    p.add_argument("--n-envs", type=int, help=f"parallel envs (default {d.n_envs})")
    p.add_argument("--eval-every", type=int, metavar="N",
                   help=f"env steps between evaluations (default {d.eval_every})")  # fmt: skip
    p.add_argument("--eval-episodes", type=int, metavar="N",
                   help=f"episodes per evaluation (default {d.eval_episodes})")  # fmt: skip
    p.add_argument("--algo-kwargs", metavar="JSON",
                   help='SB3 algorithm keyword arguments, e.g. \'{"n_steps": 256}\'')  # fmt: skip
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    p.add_argument("--device", help="cpu (default) or cuda[:N]: where the agent's networks run")
    p.add_argument("--out", metavar="DIR", help="output directory (must not exist)")
    p.add_argument("--resume", metavar="DIR",
                   help="continue the run in DIR from its last checkpoint (written after each "
                   "evaluation); bit-identical to a run never stopped")  # fmt: skip
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the metrics as JSON")
    p.set_defaults(func=cmd_sb3)


def _json_object(flag: str, text: str) -> dict:
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise HamError(f"{flag} {text!r}: not JSON ({exc.msg}); accepted: a JSON object") from None
    if not isinstance(value, dict):
        raise HamError(f"{flag} {text!r}; accepted: a JSON object such as '{{\"n_steps\": 64}}'")
    return value


_SB3_CONFIG_FLAGS = ("algo", "env", "glances", "table", "seed", "n_envs", "eval_every",
                     "eval_episodes", "algo_kwargs", "device")  # fmt: skip


def cmd_sb3(args: argparse.Namespace) -> int:
    import importlib.util

    from ham.cli.options import set_threads
    from ham.learn.sb3_agents import Sb3Config, resume_sb3, train_sb3

    set_threads(args.threads)
    if args.env_steps is not None and args.env_steps < 1:
        raise HamError(f"--env-steps {args.env_steps}; accepted: an integer >= 1")
    if args.resume:
        if args.out:
            raise HamError("give either --resume DIR or --out DIR, not both")
        given = [
            f"--{k.replace('_', '-')}" for k in _SB3_CONFIG_FLAGS if getattr(args, k) is not None
        ]
        if given:
            raise HamError(
                f"--resume continues the run with its own config; remove {', '.join(given)} "
                "(only --env-steps may change)"
            )
        metrics = resume_sb3(args.resume, env_steps=args.env_steps, progress=not args.no_progress)
        return _print_sb3(args, metrics, args.resume)
    if args.algo is None:
        raise HamError("ham sb3 needs --algo (ppo, sac or crossq), or --resume DIR")
    if not args.out:
        raise HamError("ham sb3 needs --out DIR (or --resume DIR)")
    d = Sb3Config()
    for k in ("env_steps", "seed", "n_envs", "eval_every", "eval_episodes", "device"):
        if getattr(args, k) is None:
            setattr(args, k, getattr(d, k))
    args.env = args.env or "ham/HapticGlanceAP-v0"
    args.algo_kwargs = args.algo_kwargs or "{}"
    for mod, pkg in (("stable_baselines3", "stable-baselines3"), ("sb3_contrib", "sb3-contrib")):
        if (mod == "stable_baselines3" or args.algo == "crossq") and not importlib.util.find_spec(
            mod
        ):
            raise HamError(f"--algo {args.algo} needs {pkg}, which is not installed")
    if Path(args.out).exists():
        raise HamError(f"--out {args.out!r} exists; accepted: a path that does not exist yet")
    ours = not args.env.startswith("ap_gym:")
    env_kwargs: dict = {}
    if args.glances is not None:
        if not ours:
            raise HamError(f"--glances applies to ham/ environments, not to {args.env!r}")
        if args.glances < 1:
            raise HamError(f"--glances {args.glances}; accepted: an integer >= 1")
        env_kwargs["glances"] = args.glances
    if args.table is not None:
        if not ours:
            raise HamError(f"--table applies to ham/ environments, not to {args.env!r}")
        if not Path(args.table).is_file():
            raise HamError(f"glance table {args.table!r} does not exist")
        env_kwargs["table"] = args.table
    config = Sb3Config(
        algo=args.algo, env=args.env, env_kwargs=env_kwargs, env_steps=args.env_steps,
        n_envs=args.n_envs, seed=args.seed, eval_episodes=args.eval_episodes,
        eval_every=args.eval_every, algo_kwargs=_json_object("--algo-kwargs", args.algo_kwargs),
        device=args.device,
    )  # fmt: skip
    metrics = train_sb3(config, args.out, progress=not args.no_progress)
    return _print_sb3(args, metrics, args.out)


def _print_sb3(args: argparse.Namespace, metrics: dict, out: str) -> int:
    """The run's summary (``--json``: its metrics without the history), and its curve beside it
    (``training_curve.png``, as ``ham train`` writes one)."""
    from ham.experiments.figures import plot_training_curve

    curve = plot_training_curve(metrics, Path(out) / "training_curve.png")
    if args.json:
        json.dump({k: v for k, v in metrics.items() if k != "history"}, sys.stdout)
        sys.stdout.write("\n")
        return 0
    per = " ".join(f"{a:.3f}" for a in metrics["accuracy_per_glance"])
    print(
        f"{metrics['algo']} on {metrics['env']}: {metrics['env_steps']} env steps, final "
        f"accuracy {metrics['final_accuracy']:.3f}, averaged {metrics['average_accuracy']:.3f} "
        f"(per glance: {per}); wrote {out} and {curve}"
    )
    return 0
