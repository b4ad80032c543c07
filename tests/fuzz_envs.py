"""A sweep of odd values over the Gymnasium and ap_gym environments: ``python -m tests.fuzz_envs``.

The environments' counterpart of tests/fuzz_api.py (whose odd values, ``ODD``, it gives), and
like it runnable by hand; tests/test_fuzz_envs.py runs it whole (a few seconds). For each of
``ham/HapticGlance-v0``, its vector env, ``ham/HapticGlanceAP-v0`` and its vector env, on a 3 x 3
glance table:

* each constructor argument gets each odd value (:func:`tests.fuzz_api.sweep`);
* ``reset(options=...)`` gets each odd value, as the options and as the options' one key;
* each key of a step's action (the pose, the prediction) gets each odd value, arrays of the
  right shape filled with NaN, +-inf, 1e300 and 3e38 or cast to float16, int64, bool, complex and
  text, torch tensors (plain, requiring grad, on the ``meta`` device, which holds no data) and a
  ragged list, one fresh episode each.

A call is flagged when it raises anything but a :class:`ham.errors.HamError`, its HamError spans
lines, or it takes a value no action means: a non-finite number, bytes, a bare ``object()``, or
an array of booleans, complex numbers or text, a tensor without data, a ragged list. A tensor
of valid values is taken, as an agent in PyTorch hands it (its gradient is not the env's). A finite pose outside ``[-1, 1]`` is taken
(clipped, as documented); so are finite logits, however large. ``reset(seed=...)`` is left to
Gymnasium, whose ``Env.reset`` refuses a bad seed in one line of its own. The exit code is the
number of flagged calls::

    python -m tests.fuzz_envs
    python -m tests.fuzz_envs ap ap-vector
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np
import torch

from tests.fuzz_api import ODD, _never_meant, outcome, report
from tests.fuzz_api import sweep as sweep_arguments

#: array values of an action's right shape
FILLS = [np.nan, np.inf, -np.inf, 1e300, 3e38]
CASTS = [np.float16, np.int64, np.bool_, np.complex128, np.str_]
#: a list NumPy cannot make an array of
RAGGED = [[0.5], [0.5, 0.5]]


def _envs(table: Path) -> dict[str, tuple[Callable, dict, str]]:
    """name -> (class, valid keyword arguments, the key of ``reset``'s options)."""
    from ham.envs import HapticGlanceEnv, HapticGlanceVectorEnv, ap

    one, many = (
        {"glances": 2, "table": str(table)},
        {"num_envs": 2, "glances": 2, "table": str(table)},
    )
    return {
        "haptic": (HapticGlanceEnv, one, "object"),
        "haptic-vector": (HapticGlanceVectorEnv, many, "objects"),
        "ap": (ap.HapticGlanceAPEnv, one, "object"),
        "ap-vector": (ap.HapticGlanceAPVectorEnv, many, "objects"),
    }


def _never_an_action(value) -> bool:
    if _never_meant(value) or value is RAGGED or getattr(value, "is_meta", False):
        return True
    return isinstance(value, np.ndarray) and (
        value.dtype.kind in "bcUSO" or (value.dtype.kind == "f" and not np.isfinite(value).all())
    )


def _try(label: str, call: Callable, value, flags: list[str]) -> None:
    if outcome(label, call, flags) and _never_an_action(value):
        flags.append(f"FLAG {label}: accepted")


def sweep(name: str, cls: Callable, base: dict, key: str, tmp: Path) -> tuple[int, list[str]]:
    """The constructor's arguments, ``reset``'s options and each key of a step's action."""
    calls, flags = sweep_arguments(name, cls, base, tmp)
    env = cls(**base)
    for value in ODD:
        for options in (value, {key: value}):
            calls += 1
            _try(f"{name}.reset(options={options!r})", partial(env.reset, options=options),
                 value, flags)  # fmt: skip
    env.reset(seed=0)
    env.action_space.seed(0)
    action = env.action_space.sample()
    for part, valid in action.items():
        valid = np.asarray(valid)
        arrays = [np.full(valid.shape, x) for x in FILLS] + [valid.astype(t) for t in CASTS]
        tensor = torch.as_tensor(valid, dtype=torch.float32)
        tensors = [tensor, tensor.clone().requires_grad_(), tensor.to("meta")]
        for value in ODD + arrays + tensors + [RAGGED]:
            env.reset(seed=0)
            calls += 1
            label = f"{name}.step({part}={value!r})".replace("\n", "")
            _try(label, partial(env.step, {**action, part: value}), value, flags)
    env.close()
    return calls, flags


def main(argv: list[str] | None = None) -> int:
    from ham.world.config import WorldConfig
    from ham.world.table import build_table

    parser = argparse.ArgumentParser(prog="python -m tests.fuzz_envs", description=__doc__)
    parser.add_argument("envs", nargs="*", help="environments to sweep (default: all)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        table = tmp / "t3.h5"
        build_table(WorldConfig(), 3, table, progress=False)
        envs = _envs(table)
        unknown = [e for e in args.envs if e not in envs]
        if unknown:
            parser.error(f"unknown env(s) {unknown}; accepted: {', '.join(envs)}")
        return report(args.envs or list(envs), lambda n: sweep(n, *envs[n], tmp))


if __name__ == "__main__":
    sys.exit(main())
