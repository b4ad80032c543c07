"""``ham envs``: the Gymnasium / ap_gym environments, both directions.

* ``ham envs list [--json]``: our environment ids, and ap_gym's active classification
  environments with a glimpse, marked offline (data built locally) or hub (downloads);
* ``ham envs check [--table FILE] [--glances S]``: Gymnasium's environment checker on
  ``ham/HapticGlance-v0`` and ``ham/HapticGlanceAP-v0`` (dense and ``-sparse``), then one
  random-policy episode through ``ap_gym.make`` and ``ap_gym.make_vec``;
* ``ham envs bench``: environment steps per second.

The HAM trains on ap_gym environments through ``ham train --env ap_gym:ENV_ID`` (a regular run,
:mod:`ham.learn.ap_adapter`); :func:`parse_max_step_length` reads its ``--max-step-length``.

``ham.cli.main`` adds them through :func:`add_commands`; each returns an exit code and raises
:class:`ham.errors.HamError` for bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

from ham.cli.options import add_objects_file_option, objects_from_args, set_threads
from ham.errors import HamError


def add_commands(subparsers) -> None:
    """Add ``envs list``, ``envs check`` and ``envs bench`` to an argparse subparsers object."""
    p = subparsers.add_parser(
        "envs",
        help="Gymnasium / ap_gym environments: list, check, bench",
        description="Our world for other agents (ham/HapticGlance-v0, ham/HapticGlanceAP-v0 and "
        "-sparse) and our agent for other worlds (ap_gym active classification environments).",
    )
    sub = p.add_subparsers(dest="envs_command", metavar="{list,check,bench}")
    p.set_defaults(func=cmd_list, json=False)

    q = sub.add_parser("list", help="the environment ids (ours and ap_gym's classification ones)")
    q.add_argument("--json", action="store_true", help="print JSON")
    q.set_defaults(func=cmd_list)

    q = sub.add_parser("check", help="Gymnasium's env checker and random episodes via ap_gym")
    q.add_argument("--table", metavar="FILE", help="glance table (default: online fast simulator)")
    q.add_argument("--glances", type=int, default=3, help="glances per episode (default 3)")
    q.add_argument(
        "--num-envs", type=int, default=8, help="sub-environments of make_vec (default 8)"
    )
    from ham.cli.options import add_sensor_options

    add_sensor_options(q, geometry_only=True)  # the online world's pad (a table has its own)
    q.add_argument("--objects", default=None, help="online object set (default: paper)")
    add_objects_file_option(q)
    q.add_argument("--simulator-file", metavar="FILE",
                   help="a .py file that registers your own simulator: the online world's "
                   "(docs/world.md)")  # fmt: skip
    q.set_defaults(func=cmd_check)

    q = sub.add_parser("bench", help="environment steps per second (ours, and one ap_gym env)")
    q.add_argument("--num-envs", type=int, nargs="+", default=[64, 1024], help="(64 1024)")
    q.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    q.set_defaults(func=cmd_bench)


# --------------------------------------------------------------------------- list
def ap_gym_classification_envs() -> list[dict]:
    """ap_gym's registered image classification environments (not ``-sparse``, not aliases),
    each with ``offline``: whether its data is built locally (no hub download)."""
    import gymnasium as gym

    from ham.learn.ap_adapter import import_ap_gym

    import_ap_gym()
    from ap_gym.envs.registration import DEPRECATED_ENV_IDS

    rows = []
    for env_id, spec in gym.registry.items():
        cfg = (spec.kwargs or {}).get("image_perception_config")
        if cfg is None or "-sparse" in env_id or env_id in DEPRECATED_ENV_IDS:
            continue
        dataset = type(cfg.dataset).__name__
        if "Localization" in str(spec.entry_point) or "NoPrediction" in env_id:
            continue
        if "Search" in env_id:  # localization (regression), not classification
            continue
        rows.append(
            {
                "id": env_id,
                "dataset": dataset,
                "offline": "Huggingface" not in dataset,
                # the adapter feeds glimpse and position only: an inverted-label flag is lost
                "adapter": not getattr(cfg, "randomly_invert_labels", False),
            }
        )
    return rows


def cmd_list(args: argparse.Namespace) -> int:
    import ham.envs

    ours = [
        {"id": ham.envs.ENV_ID, "kind": "gymnasium", "reward": "1 at the end if right"},
        {"id": ham.envs.AP_ENV_ID, "kind": "ap_gym", "reward": "-normalized CE, every step"},
        {"id": ham.envs.AP_SPARSE_ENV_ID, "kind": "ap_gym", "reward": "-normalized CE, last step"},
    ]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            theirs = ap_gym_classification_envs()
    except HamError as exc:
        theirs, note = [], str(exc)
    else:
        note = None
    if args.json:
        json.dump({"ham": ours, "ap_gym": theirs, "note": note}, sys.stdout)
        sys.stdout.write("\n")
        return 0
    print("our world for other agents (import ham.envs; gym.make / ap_gym.make, make_vec):")
    for r in ours:
        print(f"  {r['id']:<32} {r['kind']:<9} reward: {r['reward']}")
    print("our agent for other worlds (ham train --env ap_gym:ENV_ID):")
    if note:
        print(f"  {note}")
    for r in theirs:
        where = "offline" if r["offline"] else "hub (needs a download)"
        note_ = "" if r["adapter"] else "  (its inverted_label input is not fed to the HAM)"
        print(f"  ap_gym:{r['id']:<36} {where}{note_}")
    return 0


# --------------------------------------------------------------------------- check
def check_all(
    table: str | None = None, glances: int = 3, num_envs: int = 8, world: dict | None = None
) -> list[str]:
    """Run the checks of ``ham envs check``; returns one line per passed check, raises on failure.

    ``world``: the online world's dict (sub-environments in other processes rebuild it, objects
    file included).
    """
    import gymnasium as gym
    import numpy as np
    from gymnasium.utils.env_checker import check_env

    import ham.envs
    from ham.learn.ap_adapter import import_ap_gym

    ap_gym = import_ap_gym()
    from ham.envs import ap

    kw = {"glances": glances, "table": table}
    if world is not None:
        kw["world"] = world
    lines = []
    for name, env in (
        (ham.envs.ENV_ID, ham.envs.HapticGlanceEnv(**kw)),
        (ham.envs.AP_ENV_ID, ap.HapticGlanceAPEnv(**kw)),
        (ham.envs.AP_SPARSE_ENV_ID, ap.make_sparse_env(**kw)),
    ):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            check_env(env, skip_render_check=False)
        lines.append(f"gymnasium check_env: {name} passed")
    for env_id in (ham.envs.AP_ENV_ID, ham.envs.AP_SPARSE_ENV_ID):
        env = ap_gym.make(env_id, **kw)
        obs, info = env.reset(seed=0)
        rewards, steps, done = [], 0, False
        while not done:
            obs, r, terminated, truncated, info = env.step(env.action_space.sample())
            rewards.append(float(r))
            steps += 1
            done = terminated or truncated
        lines.append(
            f"ap_gym.make({env_id}): random episode, {steps} steps, rewards "
            f"{', '.join(f'{x:.3f}' for x in rewards)}"
        )
        venv = ap_gym.make_vec(env_id, num_envs=num_envs, **kw)
        obs, info = venv.reset(seed=0)
        total = np.zeros(num_envs)
        for _ in range(glances):
            obs, r, terminated, truncated, info = venv.step(venv.action_space.sample())
            total += r
        assert terminated.all(), "the vector episodes should end after `glances` steps"
        obs, r, terminated, truncated, info = venv.step(venv.action_space.sample())
        assert not terminated.any() and venv.observation_space.contains(obs)
        lines.append(
            f"ap_gym.make_vec({env_id}, num_envs={num_envs}): random episodes, mean return "
            f"{total.mean():.3f}; auto-reset ok"
        )
        venv.close()
    plain = gym.make_vec(ham.envs.ENV_ID, num_envs=num_envs, **kw)
    plain.reset(seed=0)
    for _ in range(glances):
        obs, r, terminated, truncated, info = plain.step(plain.action_space.sample())
    lines.append(
        f"gym.make_vec({ham.envs.ENV_ID}, num_envs={num_envs}): random predictions right "
        f"{r.mean():.3f} of the time (chance {1 / len(plain.objects):.3f})"
    )
    return lines


def cmd_check(args: argparse.Namespace) -> int:
    if args.table is not None and not Path(args.table).exists():
        raise HamError(f"glance table {args.table!r} does not exist")
    if args.num_envs < 1:
        raise HamError(f"--num-envs {args.num_envs}; accepted: an integer >= 1")
    from ham.cli.options import sensor_changes_from_args

    world = None
    changes = sensor_changes_from_args(args)
    if changes and args.table is not None:
        raise HamError("--taxels/--pitch set the online world's pad; a --table has its own")
    if args.table is not None and args.objects is not None:
        raise HamError(f"--objects {args.objects!r} chooses the online world's objects; the table "
                       f"{args.table!r} has its own: give one of them")  # fmt: skip
    if args.table is not None and args.simulator_file is not None:
        raise HamError(f"--simulator-file {args.simulator_file!r} is the online world's; the "
                       f"table {args.table!r} has its own: give one of them")  # fmt: skip
    if changes or args.objects is not None or args.objects_file is not None or args.simulator_file:
        from ham.cli.options import simulator_from_args
        from ham.world.config import WorldConfig
        from ham.world.sensor import SensorConfig

        objects, record = objects_from_args(args)
        sim_record, simulator = simulator_from_args(args)
        world = WorldConfig(
            objects=objects,
            objects_file=record,
            sensor=SensorConfig(**changes),
            simulator=simulator or "fast",
            simulator_file=sim_record,
        ).to_dict()
    for line in check_all(args.table, args.glances, args.num_envs, world):
        print(line)
    return 0


# --------------------------------------------------------------------------- bench
def steps_per_second(make, n: int, steps: int) -> float:
    """Environment steps per second (sub-environment steps for vector envs) of random actions."""
    import time

    env = make(n)
    env.reset(seed=0)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(8)]
    t = time.perf_counter()
    for i in range(steps):
        out = env.step(actions[i % 8])
        if n == 1 and out[2]:
            env.reset()
    dt = time.perf_counter() - t
    env.close()
    return steps * n / dt


def cmd_bench(args: argparse.Namespace) -> int:
    import gymnasium as gym

    import ham.envs
    from ham.learn.ap_adapter import import_ap_gym

    set_threads(args.threads)
    if any(n < 1 for n in args.num_envs):
        raise HamError(f"--num-envs {args.num_envs}; accepted: integers >= 1")
    ap_gym = import_ap_gym()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rows = [
            (
                f"{ham.envs.ENV_ID} (single)",
                steps_per_second(lambda n: gym.make(ham.envs.ENV_ID), 1, 300),
            )
        ]
        for n in args.num_envs:
            rows.append(
                (
                    f"{ham.envs.ENV_ID} x {n}",
                    steps_per_second(lambda n: gym.make_vec(ham.envs.ENV_ID, num_envs=n), n, 60),
                )
            )
            rows.append(
                (
                    f"{ham.envs.AP_ENV_ID} x {n}",
                    steps_per_second(
                        lambda n: ap_gym.make_vec(ham.envs.AP_ENV_ID, num_envs=n), n, 60
                    ),
                )
            )
        env_id = "CircleSquare-s15-nograd-v0"
        rows.append(
            (
                f"ap_gym {env_id} x 64",
                steps_per_second(lambda n: ap_gym.make_vec(env_id, num_envs=n), 64, 15),
            )
        )
    print(
        f"{'environment (online fast simulator)':<44} {'steps/s':>10}  (torch threads: {args.threads})"
    )
    for name, v in rows:
        print(f"{name:<44} {v:>10,.0f}")
    return 0


# --------------------------------------------------------------------------- ham train --env
def parse_max_step_length(text: str | None) -> float | None:
    """``None``, ``teleport`` or a number > 0 (for ``--max-step-length``)."""
    from ham.learn.ap_adapter import TELEPORT_STEP

    if text is None:
        return None
    if text == "teleport":
        return TELEPORT_STEP
    try:
        return float(text)
    except ValueError:
        raise HamError(
            f"--max-step-length {text!r}; accepted: a number > 0 or 'teleport'"
        ) from None
