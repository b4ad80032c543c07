"""A sweep of odd values over the CLI's options: ``python -m tests.fuzz_cli [COMMAND ...]``.

Not a test module (pytest collects ``test_*.py``): it takes minutes to an hour, so it runs by
hand. Each command starts from a valid argument list; each of its options (read from the argparse
parser) is given each odd value of ``ODD`` in turn, one call per value, in this process (no torch
import per call), in a fresh working folder, with a time limit per call. A call is flagged when

* an exception escapes ``ham.cli.main.main`` (a traceback),
* it exits with another code than 0 or 2,
* it exits 2 with more or less than one ``ham: error:`` line on stderr,
* it exits 2 and leaves files in its working folder (a bad input writes nothing),
* it exits 0 on a value that no option accepts (``''``, ``nan``, ``inf``, ``abc`` ...).

Calls that run past the limit are listed as slow (an accepted large value runs as asked). The
exit code is the number of flagged calls (0: none). Examples::

    python -m tests.fuzz_cli evaluate heatmap --limit 30
    python -m tests.fuzz_cli reproduce --options seeds glances
    python -m tests.fuzz_cli train evaluate --values 1000000000000000000000000000000
    python -m tests.fuzz_cli --list
"""

from __future__ import annotations

import argparse
import contextlib
import io
import multiprocessing
import os
import shlex
import shutil
import signal
import sys
import tempfile
import time
import traceback
from pathlib import Path

#: odd values given to every option in turn
ODD = ["", " ", "nan", "inf", "-inf", "1e309", "-1", "0", "-0", "1.5", "abc", "99999999999",
       "1" + "0" * 30, "/", "/dev/null", "x.h5", "{}", "é"]  # fmt: skip
#: values that no option of this CLI accepts (exit 0 on them is flagged)
NEVER_OK = {"", " ", "nan", "inf", "-inf", "1e309", "abc"}
#: options that name a file or folder: any name is one (only '' is flagged when accepted)
PATHS = {"--out", "--table", "--json", "--confusion", "--objects-file", "--simulator-file",
         "--cache-dir", "--plugin"}  # fmt: skip
#: options not swept: they pick what the base command is (their bad values are in test_bad_inputs)
SKIP = {"-h", "--help", "--resume", "--executor", "--ray-address", "--device"}


class _TimeUp(KeyboardInterrupt):
    """Raised by the per-call timer: as Ctrl-C is, which no part of ``ham`` holds (a
    reproduce run's own failures are recorded, an interrupt is not)."""


_fired = False


def _alarm(signum, frame):
    global _fired
    _fired = True
    # a call's worker processes (reproduce's pool) go too, or its pool would wait for them
    for child in multiprocessing.active_children():
        child.kill()
    raise _TimeUp


def _fixtures(root: Path) -> dict[str, str]:
    """A small table, a trained run and a grid file, made with the CLI itself."""
    from tests.conftest import ok, run_ham_inprocess

    t, run = root / "t.h5", root / "run"
    ok(run_ham_inprocess("table", "build", "--grid", "11", "--out", str(t), "--quiet"))
    ok(run_ham_inprocess("train", "--table", str(t), "--glances", "2", "--steps", "2",
                         "--out", str(run)))  # fmt: skip
    grid = root / "grid.toml"
    grid.write_text(
        'name = "fuzz"\nseeds = 1\n[table]\ngrid = 5\n[base]\nsteps = 2\n'
        'eval_every = 2\neval_batches = 1\n[axes]\n"model.glances" = [1, 2]\n'
    )
    import numpy as np

    rng = np.random.default_rng(0)  # recorded glances over (x, y, phi, phi_y), 3 x 3 x 2 x 2
    recorded = root / "rec.npz"
    np.savez(recorded, cup=rng.random((3, 3, 2, 2, 4, 4)), ball=rng.random((3, 3, 2, 2, 4, 4)),
             **{"cup.height": rng.random((3, 3, 2, 2)) * 0.01})  # fmt: skip
    calibration = root / "cal.npz"  # the pad's 3 x 3 glances of TABLE's objects
    np.savez(calibration, **{n: rng.random((3, 3, 16, 16)) for n in
                             ("box", "ramp_up", "convex", "ramp_down")})  # fmt: skip
    return {"TABLE": str(t), "RUN": str(run), "GRID": str(grid), "RECORDED": str(recorded),
            "CALIBRATION": str(calibration)}  # fmt: skip


#: valid base commands (shell words); TABLE, RUN, GRID, RECORDED, CALIBRATION are replaced by
#: the fixtures' paths
_SHORT = "--glances 2 --steps 2 --eval-every 2 --eval-batches 1 --no-progress --out r"
BASE: dict[str, list[str]] = {
    name: shlex.split(words)
    for name, words in {
        "objects": "objects --set paper",
        "glance": "glance --object box --x 0 --phi 0 --json",
        "glance-4d": "glance --objects curvature2d --object dome --pose-dims x,y,phi,phi_y "
        "--x 0 --y 0.1 --phi 0 --phi-y 0.1 --json",
        "glance-mujoco": "glance --simulator mujoco --object box --x 0 --phi 0 --json",
        "table-build": "table build --grid 3 --out b.h5 --quiet",
        "table-build-4d": "table build --objects curvature2d --pose-dims x,y,phi,phi_y "
        "--grid 2,2,2,2 --out b.h5 --quiet",
        "train": f"train --table TABLE {_SHORT}",
        "train-online": f"train --online {_SHORT}",
        "train-env": f"train --env ap_gym:CircleSquare-v0 {_SHORT}",
        # the learners' own options are refused by the hybrid learner: each learner is a base
        "train-info": f"train --table TABLE --learner info --optimizer adam --stop "
        f"--glance-cost 0.01 {_SHORT}",
        "train-sac": f"train --table TABLE --learner sac --policy squashed --optimizer adam {_SHORT}",
        "train-probe": f"train --table TABLE --learner info --optimizer adam --first-glance probe "
        f"{_SHORT}",
        "baselines": "baselines --policy random --table TABLE --glances 1 2",
        "evaluate": "evaluate RUN --batches 1",
        "heatmap": "heatmap RUN --out h.png --batches 1 --bins 4",
        "sb3": "sb3 --algo ppo --table TABLE --glances 2 --env-steps 64 --eval-every 64 "
        """--eval-episodes 4 --algo-kwargs '{"n_steps": 32}' --no-progress --out s""",
        "reproduce-grid": "reproduce grid GRID --out r --quiet",
        "reproduce": "reproduce table1 --profile smoke --seeds 1 --steps 2 --glances 1 "
        "--variants full --out r --quiet",
        "reproduce-batched": "reproduce table1 --profile smoke --seeds 2 --steps 2 --glances 1 "
        "--variants full --executor batched --workers 1 --out r --quiet",
        "envs-check": "envs check --table TABLE --glances 2 --num-envs 2",
        "envs-bench": "envs bench --num-envs 1",
        "table-show": "table show TABLE --object 0 --n 2 --out s.png",
        "table-info": "table info TABLE",
        "table-verify": "table verify TABLE",
        "table-import-recorded": "table import-recorded RECORDED --pose-dims x,y,phi,phi_y "
        "--compression lzf --out i.h5",
        "table-calibrate": "table calibrate TABLE CALIBRATION --kernel 3 --out c.h5",
        "render": "render --object 0 --x 0 --phi 0 --out r.png --width 64 --height 64",
    }.items()
}


def _subparser(argv: list[str]) -> argparse.ArgumentParser:
    """The argparse parser of the (sub)command ``argv`` starts with."""
    from ham.cli.main import build_parser

    parser = build_parser()
    for word in argv:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs or word not in subs[0].choices:
            break
        parser = subs[0].choices[word]
    return parser


def _options(argv: list[str]) -> list[str]:
    """The options of ``argv``'s command that take a value."""
    out = []
    for action in _subparser(argv)._actions:
        flags = [f for f in action.option_strings if f.startswith("--")]
        if flags and action.nargs != 0 and flags[0] not in SKIP:
            out.append(flags[0])
    return out


def _with(argv: list[str], option: str, value: str) -> list[str]:
    """``argv`` with ``option`` given ``value`` (replaced where present, else added)."""
    if option in argv:
        i = argv.index(option)
        end = i + 1
        while end < len(argv) and not argv[end].startswith("--"):
            end += 1
        return [*argv[: i + 1], value, *argv[end:]]
    return [*argv, option, value]


def _call(argv: list[str], cwd: Path, limit: float) -> tuple[str, int | None, str]:
    """(outcome, exit code, stderr) of ``ham argv`` run in this process within ``limit`` s."""
    import torch

    from ham.cli.main import main
    from tests.conftest import registries_restored

    global _fired
    err, threads, _fired = io.StringIO(), torch.get_num_threads(), False
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, limit)
    try:
        with registries_restored(), contextlib.chdir(cwd):
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
                try:
                    rc = main(list(argv))
                except SystemExit as exc:
                    rc = exc.code if isinstance(exc.code, int) else 1
        return ("slow" if _fired else "done"), rc, err.getvalue()
    except _TimeUp:
        return "slow", None, err.getvalue()
    except BaseException:  # noqa: BLE001 - an escaped exception is what this sweep looks for
        return "traceback", None, traceback.format_exc(limit=-3)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        torch.set_num_threads(threads)


def answer_flag(rc: int | None, stderr: str) -> str:
    """'' when a command answered as the CLI must: exit 0, or exit 2 with one ``ham: error:``
    line and no traceback; else why not."""
    if rc not in (0, 2):
        return f"exit {rc}"
    lines = [ln for ln in stderr.splitlines() if ln.startswith("ham: error:")]
    if rc == 2 and (len(lines) != 1 or "Traceback" in stderr):
        return f"{len(lines)} error lines"
    return ""


def _verdict(
    option: str | int, value: str, outcome: str, rc: int | None, stderr: str, left: list[str]
) -> str:
    """Why a call is flagged ('' when it is not)."""
    if outcome == "traceback":
        return "traceback"
    if outcome == "slow":
        return ""
    if why := answer_flag(rc, stderr):
        return why
    kept = " keeps the run as saved at step " in stderr  # a diverged run: kept, and said so
    if rc == 2 and left and not kept:
        return f"left {left}"
    path = option in PATHS or isinstance(option, int)
    if rc == 0 and (value == "" if path else value in NEVER_OK):
        return "accepted"
    return ""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("commands", nargs="*", help=f"of {', '.join(BASE)} (default: all)")
    parser.add_argument("--limit", type=float, default=60.0, help="seconds per call (60)")
    parser.add_argument("--list", action="store_true", help="list each command's options")
    parser.add_argument("--options", nargs="+", metavar="NAME", help="only these (seeds: --seeds)")
    parser.add_argument("--values", nargs="+", metavar="V", help="only these values (default: ODD)")
    args = parser.parse_args(argv)
    unknown = [c for c in args.commands if c not in BASE]
    if unknown:
        parser.error(f"unknown commands {unknown}; accepted: {', '.join(BASE)}")
    commands = args.commands or list(BASE)
    if args.list:
        for c in commands:
            print(c, " ".join(_options(BASE[c])))
        return 0
    flagged, slow, calls, start = [], [], 0, time.monotonic()
    root = Path(tempfile.mkdtemp(prefix="ham-fuzz-"))
    try:
        fixtures = _fixtures(root)
        for command in commands:
            base = [fixtures.get(w, w) for w in BASE[command]]
            outcome, rc, stderr = _call(base, _fresh(root), args.limit)
            if (outcome, rc) != ("done", 0):
                print(f"{command}: the base command failed ({outcome}, exit {rc}): {stderr}")
                flagged.append((command, "base", "", stderr))
                continue
            # the fixtures' positions (a run folder, a table, a grid file) and every option
            places = [i for i, w in enumerate(BASE[command]) if w in fixtures and
                      not BASE[command][i - 1].startswith("--")]  # fmt: skip
            swept = [*places, *_options(base)]
            if args.options:
                swept = [o for o in swept if str(o).lstrip("-") in args.options]
            values = args.values or ODD
            for option in swept:
                for value in values:
                    cwd = _fresh(root)
                    if isinstance(option, int):
                        call = [*base[:option], value, *base[option + 1 :]]
                    else:
                        call = _with(base, option, value)
                    outcome, rc, stderr = _call(call, cwd, args.limit)
                    calls += 1
                    left = sorted(p.name for p in cwd.iterdir())
                    why = _verdict(option, value, outcome, rc, stderr, left)
                    if why:
                        flagged.append((command, f"{option} {value!r}", why, stderr.strip()))
                        print(f"FLAG {command} {option} {value!r}: {why}\n  {stderr.strip()}")
                    elif outcome == "slow":
                        slow.append(f"{command} {option} {value!r}")
                    shutil.rmtree(cwd, ignore_errors=True)
                print(f"{command} {option}: {len(values)} values", flush=True)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    minutes = (time.monotonic() - start) / 60
    print(f"{calls} calls in {minutes:.1f} min: {len(flagged)} flagged, {len(slow)} slow")
    for s in slow:
        print(f"slow (over {args.limit:g} s): {s}")
    return min(len(flagged), 125)


_count = 0


def _fresh(root: Path) -> Path:
    """A new empty working folder for one call."""
    global _count
    _count += 1
    path = root / f"call{_count}"
    path.mkdir()
    return path


if __name__ == "__main__":
    # as `ham render` picks in a fresh process: MuJoCo's GL backend is fixed at its first import,
    # which an earlier MuJoCo glance of this sweep would make with GLFW (no display here)
    if "DISPLAY" not in os.environ:
        os.environ.setdefault("MUJOCO_GL", "egl")
    sys.exit(main())
