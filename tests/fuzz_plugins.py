"""A sweep of odd values out of the user's own code: ``python -m tests.fuzz_plugins [PART ...]``.

The CLI sweep (tests/fuzz_cli.py) gives odd values to options; this one gives them to what a
user's file hands back to the package, where no option parser stands guard: each field of a
simulator file's glance (and its ``describe()``), a plugin core's ``tau``, a plugin policy's
poses, ``log_prob`` and ``entropy``, a plugin learner's loss parts and reward, and an objects
file's height function. Each case is a small file written
from a template with one value replaced (NaN, inf, a float64 or complex tensor, PyTorch's
``meta`` device, a NumPy array, ...), run through the real CLI in this process
(:func:`tests.fuzz_cli._call`), and held against what the contract says of that value:

* ``refuse``: the first command exits 2 with one ``ham: error:`` line and leaves no file;
* ``take``: every command exits 0 (a value the contract accepts, e.g. float64 heights, 0/1 integer
  flags, a result that requires grad);
* ``either``: 0, or 2 in one line with nothing left (a value that makes training diverge).

A traceback, another exit code, or an outcome the contract does not allow is flagged. By hand,
not in CI (minutes); tests/test_fuzz_plugins.py runs a few cases of each part. Examples::

    python -m tests.fuzz_plugins                 # every part
    python -m tests.fuzz_plugins simulator core  # two parts
    python -m tests.fuzz_plugins --list
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from tests.fuzz_cli import _call, answer_flag

#: a short training run: 2 steps, 2 glances, one evaluation batch
TRAIN = ["--glances", "2", "--steps", "2", "--batch-size", "8", "--eval-every", "2",
         "--eval-batches", "1", "--no-progress"]  # fmt: skip


@dataclass(frozen=True)
class Case:
    part: str
    name: str
    files: dict[str, str]  # file name -> text, written to the call's folder
    commands: list[list[str]]  # run in order while they exit 0
    expect: str  # refuse | take | either


# --------------------------------------------------------------------------- simulator files
_SIMULATOR = """import dataclasses, torch
from ham.world.config import make_simulator
from ham.world.simulators import register_simulator

class Odd:
    name = "odd"
    def __init__(self, objects, sensor, pose, glance, device="cpu", world=None):
        world = dataclasses.replace(world, simulator="fast", simulator_file=None)
        self.fast = make_simulator(world, device=device)
        self.objects = self.fast.objects
    def glance(self, object_ids, q_x, q_phi, **kwargs):
        r = self.fast.glance(object_ids, q_x, q_phi, **kwargs)
        return dataclasses.replace(r, {field}=MAKE(r.{field}))
    def describe(self):
        return DESCRIBE(self.fast.describe())

MAKE, DESCRIBE = {make}, {describe}
register_simulator("odd", Odd)
"""
_FIELDS = ("pressure", "force", "z", "height", "x", "phi", "y", "phi_y", "contact", "blocked")
_NUMBERS = ("force", "z", "height", "x", "phi", "y", "phi_y")
#: (name, MAKE, expectation per field: pressure, the other numbers, contact/blocked)
_GLANCE_VALUES = [
    ("nan", "lambda v: torch.full_like(v.float(), float('nan'))", "refuse", "refuse", "refuse"),
    ("inf", "lambda v: torch.full_like(v.float(), float('inf'))", "refuse", "refuse", "refuse"),
    ("-inf", "lambda v: torch.full_like(v.float(), -float('inf'))", "refuse", "refuse", "refuse"),
    # 3e38 m of force, x or phi make the inputs overflow: training diverges, in one line
    ("3e38", "lambda v: torch.full_like(v.float(), 3e38)", "refuse", "either", "refuse"),
    ("1e30x", "lambda v: v.float() * 1e30 + 1e30", "refuse", "take", "refuse"),
    ("1e-45x", "lambda v: v.float() * 1e-45 + 1e-45", "take", "take", "refuse"),
    ("-1-v", "lambda v: -v.float() - 1", "refuse", "take", "refuse"),
    ("float64", "lambda v: v.double()", "take", "take", "take"),
    ("float16", "lambda v: v.half()", "take", "take", "take"),
    ("int64", "lambda v: v.long()", "take", "take", "take"),
    ("bool", "lambda v: v.bool()", "take", "take", "take"),
    ("complex", "lambda v: v.to(torch.complex64)", "refuse", "refuse", "refuse"),
    ("grad", "lambda v: v.float().requires_grad_()", "take", "take", "take"),
    ("meta", "lambda v: v.to('meta')", "refuse", "refuse", "refuse"),
    ("numpy", "lambda v: v.numpy()", "refuse", "refuse", "refuse"),
    ("list", "lambda v: v.tolist()", "refuse", "refuse", "refuse"),
    ("short", "lambda v: v[:1]", "refuse", "refuse", "refuse"),
    ("zeros", "lambda v: torch.zeros_like(v)", "take", "take", "take"),
    ("transposed", "lambda v: v.transpose(-1, -2) if v.dim() == 3 else v.flip(0).flip(0)",
     "take", "take", "take"),
]  # fmt: skip

#: heights (z, height) beyond the pad's reach of the objects' tops (ham.world.glance.height_bound;
#: "bool" makes every height above the table 1 m)
_HEIGHTS, _OUT_OF_REACH = ("z", "height"), ("3e38", "1e30x", "-1-v", "bool")


#: what describe() returns instead of the fast simulator's dict d: (name, DESCRIBE, expectation)
_DESCRIPTIONS = [
    ("int-key", "lambda d: {**d, 1: 2}", "refuse"),
    ("tuple-key", "lambda d: {(1, 2): 3}", "refuse"),
    ("none", "lambda d: None", "refuse"),
    ("text", "lambda d: 'fast'", "refuse"),
    ("nan", "lambda d: {**d, 'x': float('nan')}", "take"),
    ("tensor", "lambda d: {**d, 'x': torch.tensor(1.0)}", "take"),
    ("set", "lambda d: {**d, 'x': {'y': {1, 2}}}", "take"),
    ("empty", "lambda d: {}", "take"),
]


def _simulator_cases() -> list[Case]:
    build = ["table", "build", "--simulator-file", "odd.py", "--grid", "5", "--out", "t.h5",
             "--quiet"]  # fmt: skip
    train = ["train", "--table", "t.h5", *TRAIN, "--height-input", "--out", "run"]
    online = ["train", "--online", "--simulator-file", "odd.py", *TRAIN, "--height-input",
              "--out", "run2"]  # fmt: skip
    cases = []
    for field in _FIELDS:
        for name, make, pressure, numbers, flags in _GLANCE_VALUES:
            expect = pressure if field == "pressure" else numbers if field in _NUMBERS else flags
            if field in _HEIGHTS and name in _OUT_OF_REACH:
                expect = "refuse"
            text = _SIMULATOR.format(field=field, make=make, describe="lambda d: d")
            cases.append(Case("simulator", f"{field}={name}", {"odd.py": text},
                              [build, train, online], expect))  # fmt: skip
    # the extended glance (x, y, phi, phi_y) -> (image, height): y, phi_y and height carry values
    build4 = ["table", "build", "--simulator-file", "odd.py", "--pose-dims", "x,y,phi,phi_y",
              "--grid", "2,2,2,2", "--out", "t.h5", "--quiet"]  # fmt: skip
    train4 = ["train", "--table", "t.h5", *TRAIN, "--height-input", "--out", "run"]
    for field in ("pressure", "y", "phi_y", "height"):
        for name, make, pressure, numbers, _ in _GLANCE_VALUES:
            if name not in ("nan", "float64", "complex", "grad", "short"):
                continue
            text = _SIMULATOR.format(field=field, make=make, describe="lambda d: d")
            expect = pressure if field == "pressure" else numbers
            cases.append(Case("simulator", f"4d-{field}={name}", {"odd.py": text},
                              [build4, train4], expect))  # fmt: skip
    for name, describe, expect in _DESCRIPTIONS:
        text = _SIMULATOR.format(field="z", make="lambda v: v", describe=describe)
        cases.append(Case("simulator", f"describe={name}", {"odd.py": text}, [build, online],
                          expect))  # fmt: skip
    return cases


# --------------------------------------------------------------------------- plugin cores
_CORE = """import torch
from torch import nn
from ham.model.core import register_core

class Odd(nn.Module):
    def __init__(self, input_size, hidden_size):
        super().__init__()
        self.hidden_size, self.cell = hidden_size, nn.GRUCell(input_size, hidden_size)
    def initial_state(self, batch, like):
        return (like.new_zeros(batch, self.hidden_size),)
    def forward(self, g, state):
        h = self.cell(g, state[0])
        return MAKE(h), (h,)

MAKE = {make}
register_core("odd")(lambda input_size, hidden_size, **_: Odd(input_size, hidden_size))
"""
_TAU_VALUES = [
    ("nan", "lambda h: h * float('nan')", "either"),
    ("inf", "lambda h: h + float('inf')", "either"),
    ("3e38", "lambda h: h * 3e38", "either"),
    ("float64", "lambda h: h.double()", "refuse"),
    ("float16", "lambda h: h.half()", "refuse"),
    ("bfloat16", "lambda h: h.bfloat16()", "refuse"),
    ("int64", "lambda h: h.long()", "refuse"),
    ("complex", "lambda h: h.to(torch.complex64)", "refuse"),
    ("meta", "lambda h: h.to('meta')", "refuse"),
    ("numpy", "lambda h: h.detach().numpy()", "refuse"),
    ("short", "lambda h: h[:, :-3]", "refuse"),
    ("first-two", "lambda h: h[:2]", "refuse"),
    ("detached", "lambda h: h.detach()", "take"),
    ("transposed", "lambda h: h.t().contiguous().t()", "take"),
]


def _core_cases() -> list[Case]:
    train = ["train", "--online", "--plugin", "p.py", "--core", "odd", *TRAIN, "--out", "run"]
    return [Case("core", name, {"p.py": _CORE.format(make=make)}, [train], expect)
            for name, make, expect in _TAU_VALUES]  # fmt: skip


# --------------------------------------------------------------------------- plugin policies
_POLICY = """import torch
from ham.model.policy import LocationPolicy, TruncatedGaussian, register_policy

class Dist(TruncatedGaussian):
    def sample(self, generator):
        return MAKE(TruncatedGaussian.sample(self, generator))
    def mode(self):
        return MAKE(self.mu.clamp(-1, 1))
    def log_prob(self, q):
        return LOG_PROB(TruncatedGaussian.log_prob(self, q))
    def entropy(self):
        return ENTROPY(TruncatedGaussian.entropy(self))

@register_policy("odd")
class Odd(LocationPolicy):
    @classmethod
    def from_config(cls, config):
        return cls()
    def distribution(self, tau):
        return Dist(torch.tanh(tau[:, :2]), torch.nn.functional.softplus(tau[:, 2:4]) + 0.05)

MAKE, LOG_PROB, ENTROPY = {make}, {log_prob}, {entropy}
"""
_POSE_VALUES = [
    ("nan", "lambda q: q * float('nan')", "refuse"),
    ("outside", "lambda q: q * 3 + 2", "refuse"),
    ("float64", "lambda q: q.double()", "refuse"),
    ("float16", "lambda q: q.half()", "refuse"),
    ("int64", "lambda q: q.long()", "refuse"),
    ("bool", "lambda q: q > 0", "refuse"),
    ("complex", "lambda q: q.to(torch.complex64)", "refuse"),
    ("meta", "lambda q: q.to('meta')", "refuse"),
    ("grad", "lambda q: q.detach().requires_grad_()", "refuse"),
    ("numpy", "lambda q: q.numpy()", "refuse"),
    ("short", "lambda q: q[:1]", "refuse"),
    ("edges", "lambda q: q.sign()", "take"),
    ("transposed", "lambda q: q.t().contiguous().t() if q.dim() == 2 else q", "take"),
]


#: what log_prob and entropy return instead: (name, MAKE, expectation for log_prob, entropy)
_DENSITY_VALUES = [
    ("nan", "lambda v: v * float('nan')", "either", "take"),  # entropy: trains nothing here
    ("float64", "lambda v: v.double()", "take", "take"),
    ("int64", "lambda v: v.long()", "refuse", "refuse"),
    ("complex", "lambda v: v.to(torch.complex64)", "refuse", "refuse"),
    ("meta", "lambda v: v.to('meta')", "refuse", "refuse"),
    ("detached", "lambda v: v.detach()", "refuse", "take"),  # REINFORCE would train nothing
    ("numpy", "lambda v: v.detach().numpy()", "refuse", "refuse"),
    ("scalar", "lambda v: v.sum()", "refuse", "refuse"),
]


def _policy_cases() -> list[Case]:
    same = "lambda v: v"
    variants = [(name, {"make": make, "log_prob": same, "entropy": same}, expect)
                for name, make, expect in _POSE_VALUES]  # fmt: skip
    for name, make, log_prob, entropy in _DENSITY_VALUES:
        variants.append((f"log_prob={name}", {"make": same, "log_prob": make, "entropy": same},
                         log_prob))  # fmt: skip
        variants.append((f"entropy={name}", {"make": same, "log_prob": same, "entropy": make},
                         entropy))  # fmt: skip
    cases = []
    for name, parts, expect in variants:
        for source in (["--online"], ["--table", "TABLE"]):
            train = ["train", *source, "--plugin", "p.py", "--policy", "odd", *TRAIN,
                     "--out", "run"]  # fmt: skip
            cases.append(Case("policy", f"{name}{source[0]}", {"p.py": _POLICY.format(**parts)},
                              [train], expect))  # fmt: skip
    return cases


# --------------------------------------------------------------------------- plugin learners
_LEARNER = """import dataclasses, torch
from ham.learn.hybrid_loss import hybrid_loss
from ham.learn.learners import register_learner

@register_learner("odd")
def odd(episode, config):
    loss = hybrid_loss(episode)
    return dataclasses.replace(loss, {field}=MAKE(loss.{field}))

MAKE = {make}
"""
#: (name, MAKE, expectation for total, the logged parts, reward)
_LOSS_VALUES = [
    ("nan", "lambda v: v * float('nan')", "either", "take", "take"),
    ("3e38", "lambda v: v * 3e38 + 3e38", "either", "take", "take"),
    ("float64", "lambda v: v.double()", "take", "take", "take"),
    ("int64", "lambda v: v.long()", "refuse", "take", "take"),
    ("bool", "lambda v: v.bool()", "refuse", "take", "take"),
    ("complex", "lambda v: v.to(torch.complex64)", "refuse", "refuse", "refuse"),
    ("meta", "lambda v: v.to('meta')", "refuse", "refuse", "refuse"),
    ("detached", "lambda v: v.detach()", "refuse", "take", "take"),
    ("grad", "lambda v: v.detach().float().requires_grad_()", "refuse", "take", "take"),
    ("vector", "lambda v: v.expand(3) if v.dim() == 0 else v[:3]", "refuse", "refuse", "refuse"),
    ("number", "lambda v: 0.5", "refuse", "refuse", "refuse"),
]


def _learner_cases() -> list[Case]:
    train = ["train", "--table", "TABLE", "--plugin", "p.py", "--learner", "odd", *TRAIN,
             "--out", "run"]  # fmt: skip
    cases = []
    for field in ("total", "classification", "reward"):
        for name, make, total, parts, reward in _LOSS_VALUES:
            expect = total if field == "total" else reward if field == "reward" else parts
            text = _LEARNER.format(field=field, make=make)
            cases.append(Case("learner", f"{field}={name}", {"p.py": text}, [train], expect))
    return cases


# --------------------------------------------------------------------------- objects files
_OBJECTS = """import numpy as np, torch
from ham.world.objects import HapticObject, register

register(HapticObject.from_function("odd", {make}))
"""
_HEIGHT_VALUES = [
    ("nan", "lambda x: np.full_like(x, np.nan)", "refuse"),
    ("nan-at-one-x", "lambda x: np.where(np.abs(x - 0.0123) < 3e-5, np.nan, 0.02)", "refuse"),
    ("below-table", "lambda x: x", "refuse"),
    ("above-limit", "lambda x: np.full_like(x, 0.5)", "refuse"),
    ("complex", "lambda x: np.full_like(x, 0.02) + 0j", "refuse"),
    ("text", "lambda x: np.full(x.shape, '0.02')", "refuse"),
    ("ragged", "lambda x: [[0.02]] + [[0.0, 0.0]]", "refuse"),
    ("scalar", "lambda x: 0.02", "refuse"),
    ("fixed-length", "lambda x: np.full(257, 0.02)", "refuse"),
    ("column", "lambda x: np.full_like(x, 0.02)[:, None]", "refuse"),
    ("raises", "lambda x: 1 / 0", "refuse"),
    ("list", "lambda x: [0.02] * len(x)", "take"),
    ("tensor", "lambda x: torch.full((len(x),), 0.02)", "take"),
    ("float32", "lambda x: np.full_like(x, 0.02, dtype=np.float32)", "take"),
]


_SURFACE = """import numpy as np, torch
from ham.world.objects import HapticObject, register

register(HapticObject.from_surface("odd", {make}))
"""
#: a height field h(x, y): the same values, on the extended glance's 4-d table
_SURFACE_VALUES = [
    ("nan", "lambda x, y: np.full_like(x, np.nan)", "refuse"),
    ("below-table", "lambda x, y: y", "refuse"),
    ("complex", "lambda x, y: np.full_like(x, 0.02) + 0j", "refuse"),
    ("text", "lambda x, y: np.full(x.shape, '0.02')", "refuse"),
    ("scalar", "lambda x, y: 0.02", "refuse"),
    ("grid", "lambda x, y: np.full((len(x), len(y)), 0.02)", "refuse"),
    ("raises", "lambda x, y: 1 / 0", "refuse"),
    ("list", "lambda x, y: [0.02] * len(x)", "take"),
    ("tensor", "lambda x, y: torch.full((len(x),), 0.02)", "take"),
    ("slope", "lambda x, y: 0.02 + 0.1 * (y + 0.045)", "take"),
]


def _objects_cases() -> list[Case]:
    cases = []
    for name, make, expect in _HEIGHT_VALUES:
        text = _OBJECTS.format(make=make)
        for simulator in ("fast", "mujoco"):
            build = ["table", "build", "--objects-file", "o.py", "--objects", "box,odd",
                     "--simulator", simulator, "--grid", "3", "--out", "t.h5", "--quiet"]  # fmt: skip
            cases.append(Case("objects", f"{name}/{simulator}", {"o.py": text}, [build], expect))
    for name, make, expect in _SURFACE_VALUES:
        text = _SURFACE.format(make=make)
        for simulator in ("fast", "mujoco"):
            build = ["table", "build", "--objects-file", "o.py", "--objects", "box,odd",
                     "--pose-dims", "x,y,phi,phi_y", "--simulator", simulator, "--grid",
                     "2,2,2,2", "--out", "t.h5", "--quiet"]  # fmt: skip
            cases.append(Case("objects", f"surface-{name}/{simulator}", {"o.py": text}, [build],
                              expect))  # fmt: skip
    return cases


PARTS = {
    "simulator": _simulator_cases,
    "core": _core_cases,
    "policy": _policy_cases,
    "learner": _learner_cases,
    "objects": _objects_cases,
}


def verdict(case: Case, results: list[tuple[str, int | None, str, list[str]]]) -> str:
    """Why ``case`` is flagged ('' when its outcome is one its contract allows). ``results``:
    per command run, (outcome, exit code, stderr, the files left after a refusal)."""
    for outcome, rc, stderr, _ in results:
        if outcome == "traceback":
            return "traceback: " + stderr.strip().splitlines()[-1]
        if outcome == "slow":
            return "slow"
        if why := answer_flag(rc, stderr):
            return why
    outcome, rc, stderr, left = results[-1]
    refused_first = rc == 2 and len(results) == 1
    if rc == 2 and left:
        return f"refused, but left {left}"
    if case.expect == "take" and rc != 0:
        return "refused a value the contract takes: " + stderr.strip()
    if case.expect == "refuse" and not refused_first:
        return "took a value the contract refuses" if rc == 0 else "refused only later"
    return ""


def run_case(case: Case, root: Path, fixtures: dict[str, str], limit: float) -> str:
    """Run ``case`` in a fresh folder under ``root``; its :func:`verdict`."""
    cwd = Path(tempfile.mkdtemp(dir=root))
    try:
        for name, text in case.files.items():
            (cwd / name).write_text(text)
        before = set(case.files)
        results = []
        for command in case.commands:
            argv = [fixtures.get(w, w) for w in command]
            outcome, rc, stderr = _call(argv, cwd, limit)
            left = sorted(p.name for p in cwd.iterdir() if p.name not in before)
            results.append((outcome, rc, stderr, left))
            if (outcome, rc) != ("done", 0):
                break
            before |= set(left)
        return verdict(case, results)
    finally:
        shutil.rmtree(cwd, ignore_errors=True)


def fixtures(root: Path) -> dict[str, str]:
    """A small glance table for the parts that train from one."""
    from tests.conftest import ok, run_ham_inprocess

    table = root / "table.h5"
    ok(run_ham_inprocess("table", "build", "--grid", "5", "--out", str(table), "--quiet"))
    return {"TABLE": str(table)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("parts", nargs="*", help=f"of {', '.join(PARTS)} (default: all)")
    parser.add_argument("--limit", type=float, default=120.0, help="seconds per call (120)")
    parser.add_argument("--list", action="store_true", help="list the cases")
    args = parser.parse_args(argv)
    unknown = [p for p in args.parts if p not in PARTS]
    if unknown:
        parser.error(f"unknown parts {unknown}; accepted: {', '.join(PARTS)}")
    cases = [c for p in args.parts or PARTS for c in PARTS[p]()]
    if args.list:
        for c in cases:
            print(f"{c.part} {c.name}: {c.expect}")
        return 0
    flagged, start = 0, time.monotonic()
    root = Path(tempfile.mkdtemp(prefix="ham-fuzz-plugins-"))
    try:
        fx = fixtures(root)
        for c in cases:
            why = run_case(c, root, fx, args.limit)
            if why:
                flagged += 1
                print(f"FLAG {c.part} {c.name} (expected: {c.expect}): {why}", flush=True)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    minutes = (time.monotonic() - start) / 60
    print(f"{len(cases)} cases in {minutes:.1f} min: {flagged} flagged")
    return min(flagged, 125)


if __name__ == "__main__":
    sys.exit(main())
