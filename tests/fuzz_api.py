"""A sweep of odd values over the public Python functions: ``python -m tests.fuzz_api [FN ...]``.

The Python API's counterpart of tests/fuzz_cli.py, and like it not a test module: it runs by
hand (a few minutes). Each function starts from a valid call on a small table (3 x 3) and a
2-step run; each of its parameters is given each value of ``ODD`` in turn, one call per value,
in a fresh working folder. The training loop and the executors are replaced by a sentinel, so
that an accepted call is recorded as accepted instead of training. A call is flagged when

* it raises anything but a :class:`ham.errors.HamError` (an AttributeError deep inside),
* its HamError spans more than one line,
* it is refused and leaves files in its working folder,
* it accepts a value no parameter means (NaN, inf, bytes, a bare ``object()``).

The exit code is the number of flagged calls. Examples::

    python -m tests.fuzz_api
    python -m tests.fuzz_api build_table reproduce
    python -m tests.fuzz_api --list
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import inspect
import math
import shutil
import sys
import tempfile
import traceback
from collections.abc import Callable
from pathlib import Path

import numpy as np

#: odd values given to every parameter in turn
ODD: list = [math.nan, math.inf, -1, 0, 1.5, "abc", "", None, True, [], {}, object(),
             np.int64(2), "/", b"x", 10**30, 1e300, 3e38, 1e-300]  # fmt: skip


class Accepted(Exception):
    """Raised by the sentinel in place of training: the call passed every check."""


def _never_meant(value) -> bool:
    if isinstance(value, float) and not math.isfinite(value):
        return True
    return isinstance(value, bytes) or type(value) is object


#: a flat top 2 cm high
FLAT = [[-0.04, 0.02], [0.04, 0.02]]


def _flat(x):
    return np.full_like(x, 0.02, dtype=np.float64)


def _flat_surface(x, y):
    return np.full_like(x, 0.02, dtype=np.float64)


def _observe(run) -> Callable:
    """``Explorer.observe`` on a fresh episode of ``run``'s agent (each call its first glance)."""

    def observe(pressure, height=None, pose=None, **unknown):
        from ham.learn.explorer import Explorer

        explorer = Explorer(run.agent)
        explorer.reset()
        return explorer.observe(pressure, height, pose, **unknown)

    return observe


def _cases(tmp: Path, only: list[str]) -> dict[str, tuple[Callable, dict]]:
    """name -> (function, its valid keyword arguments); builds the table and run they read."""
    from ham.experiments.grid_run import run_grid
    from ham.experiments.reproduce import reproduce
    from ham.learn.ap_adapter import ApGymConfig, ApGymGlanceEnv
    from ham.learn.batched import train_batched, train_batched_together
    from ham.learn.evaluation import evaluate, heatmap_data
    from ham.learn.explorer import Explorer
    from ham.learn.learners import register_learner
    from ham.learn.sb3_agents import Sb3Config, resume_sb3, train_sb3
    from ham.learn.train import TrainConfig, fit_to_ap_gym, load_run, resume, train
    from ham.model.core import register_core
    from ham.model.policy import register_policy
    from ham.world.calibration import calibrate_table, carry_readout, fit_readout
    from ham.world.config import WorldConfig
    from ham.world.objects import HapticObject, register
    from ham.world.recorder import record_glances
    from ham.world.simulators import register_simulator
    from ham.world.table import (
        GlanceTable,
        build_table,
        import_authors,
        import_recorded,
        table_info,
        verify_table,
    )

    table = tmp / "t3.h5"
    build_table(WorldConfig(), 3, table, progress=False)
    config = TrainConfig(steps=2, batch_size=4, eval_every=2, eval_batches=1, table=str(table))
    recorded = tmp / "rec.npz"
    np.savez(recorded, box=np.zeros((3, 3, 16, 16)), cup=np.ones((3, 3, 16, 16)))
    calibration = tmp / "cal.npz"  # the pad's glances of the table's objects
    np.savez(calibration, **{n: np.arange(9 * 256.0).reshape(3, 3, 16, 16) for n in
                             ("box", "ramp_up", "convex", "ramp_down")})  # fmt: skip
    calibrated = tmp / "calibrated.h5"
    if not only or "carry_readout" in only:
        calibrate_table(table, calibration, calibrated, kernel=3)
    run_out = tmp / "run"
    (tmp / "g.toml").write_text('name = "g"\n[base]\nsteps = 2\nbatch_size = 4\n[axes]\n'
                                '"model.glances" = [1, 2]\n')  # fmt: skip
    needs_run = {"evaluate", "heatmap_data", "load_run", "resume", "Explorer",
                 "Explorer.from_run", "Explorer.observe"}  # fmt: skip
    run = None
    if not only or needs_run & set(only):
        train(config, run_out, progress=False)
        run = load_run(run_out)
    agent_env = {} if run is None else {"agent": run.agent, "env": run.env}
    sb3 = Sb3Config(algo="ppo", env="ham/HapticGlanceAP-v0", env_steps=16, eval_every=16,
                    eval_episodes=2, env_kwargs={"glances": 2, "table": str(table)},
                    algo_kwargs={"n_steps": 16, "batch_size": 16, "n_epochs": 1})  # fmt: skip
    sb3_out = tmp / "sb3"
    if not only or "resume_sb3" in only:
        train_sb3(sb3, sb3_out)
    return {
        "evaluate": (evaluate, {**agent_env, "batches": 1}),
        "Explorer": (Explorer, {**agent_env, "episodes": 2}),
        "Explorer.from_run": (Explorer.from_run, {"run": run_out}),
        "Explorer.observe": (_observe(run), {"pressure": np.zeros((16, 16))}),
        "heatmap_data": (heatmap_data, {**agent_env, "batches": 1, "bins": 3}),
        "build_table": (
            build_table,
            {"world": WorldConfig(), "grid": 3, "out": "x.h5", "progress": False},
        ),  # fmt: skip
        "GlanceTable.load": (GlanceTable.load, {"path": table}),
        "table_info": (table_info, {"path": table}),
        "verify_table": (verify_table, {"path": table}),
        "import_authors": (import_authors, {"src": tmp / "none.h5", "out": "imp.h5"}),
        "import_recorded": (import_recorded, {"src": recorded, "out": "rec.h5"}),
        "calibrate_table": (
            calibrate_table,
            {"table": table, "recorded": calibration, "out": "cal.h5", "kernel": 3},
        ),  # fmt: skip
        "carry_readout": (
            carry_readout,
            {"table": table, "calibrated": calibrated, "out": "carried.h5"},
        ),
        "fit_readout": (
            fit_readout,
            {
                "simulated": np.ones((2, 4, 4)),
                "recorded": np.arange(32.0).reshape(2, 4, 4),
                "kernel": 3,
            },
        ),  # fmt: skip
        "record_glances": (
            record_glances,
            {
                "glance": lambda name, q: np.ones((4, 4)),
                "objects": ["cup", "ball"],
                "grid": 3,
                "out": "glances.npz",
                "progress": False,
            },
        ),  # fmt: skip
        "load_run": (load_run, {"out": run_out}),
        "train": (train, {"config": config, "out": "fresh", "progress": False}),
        "train_batched": (train_batched, {"configs": [config], "outs": ["b0"]}),
        "train_batched_together": (
            train_batched_together,
            {"batches": [([config], ["b0"]), ([config], ["b1"])]},
        ),  # fmt: skip
        "resume": (resume, {"out": run_out, "progress": False}),
        "reproduce": (
            reproduce,
            {
                "target": "table2",
                "profile_name": "smoke",
                "out": "rp",
                "progress": False,
                "workers": 1,
            },
        ),  # fmt: skip
        "train_sb3": (train_sb3, {"config": sb3, "out": "s", "progress": False}),
        "resume_sb3": (resume_sb3, {"out": sb3_out, "env_steps": 32, "progress": False}),
        "ApGymGlanceEnv": (
            ApGymGlanceEnv,
            {"env_id": "CircleSquare-s15-nograd-v0", "batch_size": 2},
        ),  # fmt: skip
        "fit_to_ap_gym": (
            fit_to_ap_gym,
            {"config": config, "env": ApGymConfig("ap_gym:CircleSquare-s15-nograd-v0")},
        ),  # fmt: skip
        "HapticObject": (HapticObject, {"name": "fz", "profile": _flat}),
        "HapticObject.from_polyline": (
            HapticObject.from_polyline,
            {"name": "fz", "points": [[-0.04, 0.02], [0.04, 0.02]]},
        ),  # fmt: skip
        "HapticObject.from_surface": (
            HapticObject.from_surface,
            {"name": "fz", "surface": _flat_surface},
        ),  # fmt: skip
        "HapticObject.from_height_field": (
            HapticObject.from_height_field,
            {"name": "fz", "heights": np.full((4, 4), 0.02)},
        ),  # fmt: skip
        # registries (a valid call registers a name of the sweep's own, fz_...)
        "register": (
            register,
            {"obj": HapticObject.from_polyline("fz_reg", FLAT), "replace": True},
        ),
        "register_policy": (register_policy, {"name": "fz_policy"}),
        "register_core": (register_core, {"name": "fz_core"}),
        "register_learner": (register_learner, {"name": "fz_learner"}),
        "register_simulator": (register_simulator, {"name": "fz_sim", "factory": _flat}),
        "run_grid": (
            run_grid,
            {"grid": tmp / "g.toml", "out": "gr", "progress": False, "workers": 1},
        ),  # fmt: skip
    }


@contextlib.contextmanager
def _sentinels():
    """The training loops (ours, batched, SB3's) and the executors raise :class:`Accepted` instead of
    running."""
    import ham.experiments.grid_run as grid_run
    import ham.experiments.reproduce as reproduce
    import ham.learn.batched as batched
    import ham.learn.sb3_agents as sb3_agents
    import ham.learn.train as train

    def stop(*args, **kwargs):
        raise Accepted

    saved = [(m, n, getattr(m, n)) for m, n in
             ((train, "train_loop"), (reproduce, "execute"), (grid_run, "execute"),
              (sb3_agents, "_learn"), (batched, "train_groups"))]  # fmt: skip
    for m, n, _ in saved:
        setattr(m, n, stop)
    try:
        yield
    finally:
        for m, n, f in saved:
            setattr(m, n, f)


def outcome(label: str, call: Callable, flags: list[str]) -> bool:
    """Run ``call``: True when it is accepted (it returns, or reaches a sentinel), False when
    refused. Appends a flag line for a refusal that is not one line of a HamError."""
    from ham.errors import HamError

    try:
        call()
    except Accepted:
        pass
    except HamError as exc:
        if "\n" in str(exc):
            flags.append(f"FLAG {label}: a message of several lines: {exc}")
        return False
    except Exception as exc:  # noqa: BLE001 - what the sweep is looking for
        where = traceback.extract_tb(exc.__traceback__)[-1]
        flags.append(f"FLAG {label}: {type(exc).__name__}: {' '.join(str(exc).split())} "
                     f"({Path(where.filename).name}:{where.lineno})")  # fmt: skip
        return False
    return True


def sweep(name: str, fn: Callable, base: dict, tmp: Path) -> tuple[int, list[str]]:
    """Every parameter of ``fn`` given every odd value; returns (calls, flag lines)."""
    # keyword parameters (not a **kwargs), and one unknown keyword, except for a dataclass,
    # whose constructor answers it with Python's own one line ("unexpected keyword argument")
    params = [name for name, p in inspect.signature(fn).parameters.items()
              if name not in ("agent", "env") and p.kind != p.VAR_KEYWORD]  # fmt: skip
    if not dataclasses.is_dataclass(fn):
        params.append("fuzz_unknown")
    calls, flags = 0, []
    for param in params:
        for value in ODD:
            work = Path(tempfile.mkdtemp(dir=tmp))
            label = f"{name}({param}={value!r})"
            calls += 1
            with contextlib.chdir(work), _sentinels():
                accepted = outcome(label, functools.partial(fn, **{**base, param: value}), flags)
            if accepted and _never_meant(value):
                flags.append(f"FLAG {label}: accepted")
            if not accepted and any(work.iterdir()):
                flags.append(f"FLAG {label}: refused, and left {sorted(work.iterdir())[:3]}")
            shutil.rmtree(work, ignore_errors=True)
    return calls, flags


def report(names: list[str], sweep_one: Callable[[str], tuple[int, list[str]]]) -> int:
    """Sweep each of ``names``, printing its flag lines and counts, then the total; returns the
    number of flagged calls (the exit code)."""
    total, flagged = 0, []
    for name in names:
        calls, flags = sweep_one(name)
        total += calls
        flagged += flags
        for line in flags:
            print(line)
        print(f"{name}: {calls} calls, {len(flags)} flagged", flush=True)
    print(f"{total} calls: {len(flagged)} flagged")
    return len(flagged)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.fuzz_api", description=__doc__)
    parser.add_argument("functions", nargs="*", help="functions to sweep (default: all)")
    parser.add_argument("--list", action="store_true", help="list the functions and exit")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        cases = _cases(tmp, args.functions)
        if args.list:
            for name, (fn, _) in cases.items():
                print(name, " ".join(inspect.signature(fn).parameters))
            return 0
        unknown = [f for f in args.functions if f not in cases]
        if unknown:
            parser.error(f"unknown function(s) {unknown}; accepted: {', '.join(cases)}")
        return report(args.functions or list(cases), lambda n: sweep(n, *cases[n], tmp))


if __name__ == "__main__":
    sys.exit(main())
