"""Simulator files: a user's own simulator (a sensor of their own) from a file, no package edit.

``--simulator-file FILE.py`` registers it; tables and runs keep the file's text, so the real CLI
in other processes loads them after the file is gone. The example is the one the docs ship:
docs/plugins/binary_pad.py, whose taxels read 5 kPa where the fast model's read over 1 kPa.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from ham.errors import HamError
from ham.world import objects, simulators
from ham.world.config import WorldConfig, make_simulator
from tests.conftest import ok, one_line_error, registries_restored, run_ham, run_ham_inprocess

PAD = Path(__file__).parents[1] / "docs/plugins/binary_pad.py"
TRAIN = ("--glances", "2", "--steps", "2", "--batch-size", "8", "--eval-every", "2",
         "--eval-batches", "2", "--seed", "3", "--no-progress")  # fmt: skip


def _pressures(path: Path) -> np.ndarray:
    with h5py.File(path) as f:
        return np.stack([f[f"objects/{n}/pressure"][...] for n in ("box", "ramp_up", "convex")])


def test_a_table_built_with_the_binary_pad_is_the_fast_table_thresholded(tmp_path):
    (tmp_path / "pad.py").write_text(PAD.read_text())
    ok(run_ham("table", "build", "--simulator-file", "pad.py", "--grid", "9", "--out", "b.h5",
               "--quiet", cwd=tmp_path))  # fmt: skip
    ok(run_ham_inprocess("table", "build", "--grid", "9", "--out", "f.h5", "--quiet",
                         cwd=tmp_path))  # fmt: skip
    binary, fast = _pressures(tmp_path / "b.h5"), _pressures(tmp_path / "f.h5")
    assert np.array_equal(binary, np.where(fast > 1000.0, 5000.0, 0.0).astype(np.float32))
    assert 0 < (binary > 0).mean() < (fast > 0).mean()  # some taxels on, fewer than touched
    (tmp_path / "pad.py").unlink()  # the table keeps the text
    r = ok(run_ham_inprocess("table", "info", "b.h5", cwd=tmp_path))
    assert "simulator: binary" in r.stdout and "simulator file: pad.py (sha256" in r.stdout
    # the table trains with nothing else given (lookups need no simulator)
    ok(run_ham_inprocess("train", "--table", "b.h5", *TRAIN, "--out", "r", cwd=tmp_path))


def test_an_online_run_keeps_the_file_and_loads_without_it(tmp_path):
    (tmp_path / "pad.py").write_text(PAD.read_text())
    ok(run_ham_inprocess("train", "--online", "--simulator-file", "pad.py", *TRAIN, "--out", "r",
                         cwd=tmp_path))  # fmt: skip
    (tmp_path / "pad.py").unlink()
    world = json.loads((tmp_path / "r" / "config.json").read_text())["world"]
    assert (world["simulator"], world["simulator_file"]["name"]) == ("binary", "pad.py")
    # another process: the real CLI registers the recorded text
    r = ok(run_ham("evaluate", "r", "--batches", "2", "--json", cwd=tmp_path))
    assert 0 <= json.loads(r.stdout)["accuracy"] <= 1
    ok(run_ham_inprocess("train", "--resume", "r", "--steps", "4", "--no-progress", cwd=tmp_path))
    assert json.loads((tmp_path / "r" / "metrics.json").read_text())["steps"] == 4
    line = one_line_error(run_ham_inprocess("train", "--resume", "r", "--simulator-file",
                                            "pad.py", "--no-progress", cwd=tmp_path))  # fmt: skip
    assert "remove --simulator-file" in line


def test_the_same_simulator_file_and_seed_give_the_same_numbers(tmp_path):
    for out in ("a", "b"):
        ok(run_ham_inprocess("train", "--online", "--simulator-file", str(PAD), *TRAIN,
                             "--out", out, cwd=tmp_path))  # fmt: skip
    a, b = (json.loads((tmp_path / d / "metrics.json").read_text())["history"] for d in "ab")
    assert a == b


_HEAD = (PAD.read_text().split("register_simulator(")[0]
         + "import torch\nfrom ham.world.glance import GlanceResult\n")  # fmt: skip


def _glance_returning(expr: str) -> str:
    """The binary pad whose glance returns ``expr`` (``r`` is its checked-in result)."""
    return _HEAD + (
        "class Bad(BinaryPad):\n"
        "    def glance(self, object_ids, q_x, q_phi, **kwargs):\n"
        "        r = BinaryPad.glance(self, object_ids, q_x, q_phi, **kwargs)\n"
        f"        return {expr}\n"
        "register_simulator('bad', Bad)\n"
    )


BAD = {
    "missing.py": (None, "simulator file 'missing.py' does not exist"),
    "mine.txt": ("x = 1\n", "accepted: a .py file that calls ham.world.simulators.register_sim"),
    "empty.py": ("x = 1\n", "registers no simulator"),
    "syntax.py": ("def f(:\n", "syntax error at line 1"),
    "builtin.py": (
        _HEAD + "register_simulator('fast', BinaryPad)\n",
        "simulator 'fast' is registered already",
    ),  # fmt: skip
    "name.py": (
        _HEAD + "register_simulator('a b', BinaryPad)\n",
        "simulator name 'a b'; accepted: letters, digits",
    ),  # fmt: skip
    "factory.py": (_HEAD + "register_simulator('x', 3)\n", "factory 3; accepted: a callable"),
    "objects.py": (
        _HEAD + "register_simulator('x', BinaryPad)\n"
        "from ham.world.objects import HapticObject, register\n"
        "register(HapticObject.from_polyline('simfile_obj', [(-0.045, 0.0), (0.045, 0.04)]))\n",
        "registers objects ['simfile_obj']; accepted: objects in an objects file",
    ),
    "two.py": (
        _HEAD + "register_simulator('one', BinaryPad)\nregister_simulator('two', BinaryPad)\n",
        "registers one, two; accepted: --simulator naming one of them",
    ),  # fmt: skip
    "shape.py": (
        _glance_returning("dataclasses.replace(r, pressure=r.pressure[:, :3])"),
        "simulator 'bad' returned pressure (81, 3, 16) for 81 glances; accepted: a "
        "tensor (81, 16, 16)",
    ),  # fmt: skip
    "negative.py": (
        _glance_returning("dataclasses.replace(r, pressure=r.pressure - 1)"),
        "returned a pressure of -1.0 Pa; accepted: finite values in [0, 1e+15] Pa",
    ),  # fmt: skip
    "nan.py": (
        _glance_returning("dataclasses.replace(r, pressure=r.pressure * float('nan'))"),
        "returned a pressure of nan Pa",
    ),  # fmt: skip
    "force.py": (
        _glance_returning("dataclasses.replace(r, force=r.force[:1])"),
        "returned force (1,) for 81 glances; accepted: a tensor (81,)",
    ),  # fmt: skip
    "huge.py": (
        _glance_returning("dataclasses.replace(r, pressure=torch.full_like(r.pressure, 2.0**60))"),
        "returned a pressure of 1.152921504606847e+18 Pa; accepted: finite values in [0, 1e+15]",
    ),  # fmt: skip
    "complex.py": (
        _glance_returning("dataclasses.replace(r, force=r.force.to(torch.complex64))"),
        "returned force of torch.complex64; accepted: real numbers",
    ),  # fmt: skip
    "z.py": (
        _glance_returning("dataclasses.replace(r, z=r.z * float('inf'))"),
        "returned z inf m; accepted: finite heights within 0.183 m of the table",
    ),  # fmt: skip
    "z_high.py": (  # 5 m above the table: beyond any pad's reach of the objects' tops
        _glance_returning("dataclasses.replace(r, z=r.z + 5)"),
        "returned z 5.0",
    ),  # fmt: skip
    "pose.py": (
        _glance_returning("dataclasses.replace(r, phi=r.phi / 0.0)"),
        "returned phi -inf; accepted: finite numbers",
    ),  # fmt: skip
    "contact.py": (
        _glance_returning("dataclasses.replace(r, contact=r.contact.float() / 2)"),
        "returned contact 0.5; accepted: booleans (or 0 / 1)",
    ),  # fmt: skip
    "meta.py": (
        _glance_returning("dataclasses.replace(r, height=r.height.to('meta'))"),
        "returned height (81,) on the meta device (no data) for 81 glances; accepted: a tensor "
        "(81,) on the CPU or a GPU",
    ),  # fmt: skip
    "result.py": (_glance_returning("r.pressure"), "returned a Tensor; accepted: a GlanceResult"),
    "raises.py": (_glance_returning("1 / 0"), "raised ZeroDivisionError at line {line}"),
    "noisy.py": (
        _glance_returning(
            "dataclasses.replace(r, pressure=r.pressure + torch.rand_like(r.pressure))"
        ),
        "simulator 'bad' gave another pressure when glancing object 0 at q_x = -1, q_phi = -1 "
        "again; accepted: the same glance for the same object and pose",
    ),  # fmt: skip
}


#: the files whose loading fails (the others load, and fail when the CLI uses them)
LOAD_FAILS = ("empty.py", "syntax.py", "builtin.py", "name.py", "factory.py", "objects.py")


@pytest.mark.parametrize("name", list(BAD))
def test_a_bad_simulator_file_is_one_line_and_leaves_nothing(tmp_path, name):
    text, expected = BAD[name]
    if "{line}" in expected:  # the file's own line that raised
        expected = expected.format(line=text.splitlines().index("        return 1 / 0") + 1)
    if text is not None:
        (tmp_path / name).write_text(text.replace("import torch\n", "import dataclasses, torch\n"))
    before = (dict(simulators._SIMULATORS), objects.names(), dict(simulators._LOADED))
    line = one_line_error(run_ham_inprocess("table", "build", "--simulator-file", name, "--grid",
                                            "9", "--out", "t.h5", "--quiet", cwd=tmp_path))  # fmt: skip
    assert expected in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ([name] if text is not None else [])
    # the Python API rolls back too (run_ham_inprocess would restore the registries anyway)
    if name in LOAD_FAILS:
        record = simulators.read_simulator_file(tmp_path / name)
        with pytest.raises(HamError):
            simulators.load_simulator_file(record)
    assert (dict(simulators._SIMULATORS), objects.names(), dict(simulators._LOADED)) == before


def test_a_glance_of_other_real_types_is_taken_as_the_built_in_types(tmp_path):
    """float64 or integer numbers, 0/1 integer flags, a result that requires grad (a
    differentiable simulator): checked, then float32 and bool, detached, as the fast glance's."""
    (tmp_path / "typed.py").write_text(_glance_returning(
        "dataclasses.replace(r, pressure=r.pressure.double().requires_grad_(True), "
        "force=r.force.double(), z=r.z.half(), contact=r.contact.long(), "
        "blocked=r.blocked.to(torch.uint8), phi=r.phi.requires_grad_(True))"
    ).replace("import torch\n", "import dataclasses, torch\n"))  # fmt: skip
    record = simulators.read_simulator_file(tmp_path / "typed.py")
    ids, q = torch.tensor([0, 1, 2]), torch.tensor([-0.5, 0.0, 0.5])
    with registries_restored():
        simulators.load_simulator_file(record)
        world = WorldConfig(simulator="bad", simulator_file=record)
        sim = make_simulator(world)
        r = sim.glance(ids, q, q)
        b = type(sim.inner).__mro__[1].glance(sim.inner, ids, q, q)  # the binary pad's own
    for field in ("pressure", "force", "z", "phi", "contact", "blocked"):
        got, want = getattr(r, field), getattr(b, field)
        assert got.dtype == want.dtype and not got.requires_grad, field
        assert torch.equal(got, want) or field == "z" and torch.allclose(got, want, atol=1e-4)


def test_the_simulator_a_world_names_is_checked(tmp_path):
    line = one_line_error(run_ham_inprocess("table", "build", "--simulator", "binary", "--grid",
                                            "9", "--out", "t.h5", cwd=tmp_path))  # fmt: skip
    assert "unknown simulator 'binary'; accepted: fast, mujoco, or" in line
    assert "--simulator-file FILE.py" in line
    line = one_line_error(run_ham_inprocess("table", "build", "--simulator", "fast",
                                            "--simulator-file", str(PAD), "--grid", "9",
                                            "--out", "t.h5", cwd=tmp_path))  # fmt: skip
    assert "--simulator 'fast' is not one --simulator-file" in line and "accepted: 'binary'" in line
    assert list(tmp_path.iterdir()) == []
    record = simulators.read_simulator_file(PAD)
    with registries_restored():
        with pytest.raises(HamError, match=r"world simulator 'fast' is not one simulator file "
                           r"'binary_pad.py' registers; accepted: 'binary' \(or no simulator file\)"):  # fmt: skip
            WorldConfig(simulator_file=record)
        world = WorldConfig(simulator="binary", simulator_file=record)
        assert WorldConfig.from_dict(world.to_dict()) == world
        assert "simulator_file" not in WorldConfig().to_dict()  # the paper's world as before
        altered = {**record, "source": record["source"] + "\n"}
        with pytest.raises(HamError, match="recorded sha256 .* the record was altered"):
            WorldConfig.from_dict({**world.to_dict(), "simulator_file": altered})


def test_a_simulator_registered_by_a_program_is_checked_too():
    from ham.world.glance import FastSimulator

    with registries_restored():
        simulators.register_simulator("prog", FastSimulator)
        with pytest.raises(HamError, match="simulator 'prog' is registered already"):
            simulators.register_simulator("prog", FastSimulator)
        sim = make_simulator(WorldConfig(simulator="prog"))
        r = sim.glance(torch.zeros(3, dtype=torch.long), torch.zeros(3), torch.zeros(3))
        assert r.pressure.shape == (3, 16, 16) and sim.describe()["simulator"] == "prog"
        simulators.register_simulator("broken", lambda *a, **k: object())
        with pytest.raises(HamError, match="simulator 'broken': simulator 'broken' made a object "
                           "without a glance"):  # fmt: skip
            make_simulator(WorldConfig(simulator="broken"))
    assert "prog" not in simulators.simulator_names()


def test_noise_seeded_by_object_and_pose_is_accepted_and_global_noise_is_not():
    from ham.world.glance import FastSimulator

    class Seeded(FastSimulator):  # noise as a function of object and pose: deterministic
        def glance(self, object_ids, q_x, q_phi, **kwargs):
            r = super().glance(object_ids, q_x, q_phi, **kwargs)
            g = torch.sin(1e3 * (q_x + 3 * q_phi) + torch.as_tensor(object_ids)).abs()
            return dataclasses.replace(r, pressure=r.pressure + 50.0 * g[:, None, None])

    class Global(FastSimulator):  # noise from the global random state: refused
        def glance(self, object_ids, q_x, q_phi, **kwargs):
            r = super().glance(object_ids, q_x, q_phi, **kwargs)
            return dataclasses.replace(r, z=r.z + 1e-4 * torch.rand_like(r.z))

    ids, q = torch.tensor([0, 1, 2, 3] * 5), torch.linspace(-1, 1, 20)
    with registries_restored():
        simulators.register_simulator("seeded", Seeded)
        simulators.register_simulator("global", Global)
        a = make_simulator(WorldConfig(simulator="seeded")).glance(ids, q, -q)
        b = make_simulator(WorldConfig(simulator="seeded")).glance(ids, q, -q)
        assert torch.equal(a.pressure, b.pressure)
        sim = make_simulator(WorldConfig(simulator="global"))
        with pytest.raises(HamError, match=r"simulator 'global' gave another z when glancing "
                           r"object \d at q_x = "):  # fmt: skip
            sim.glance(ids, q, -q)


def test_a_grid_names_world_files_beside_it(tmp_path):
    (tmp_path / "sims").mkdir()
    (tmp_path / "sims" / "pad.py").write_text(PAD.read_text())
    (tmp_path / "shapes.toml").write_text(
        'objects = [{ name = "simfile_wedge", polyline = [[-0.045, 0.0], [0.045, 0.03]] },\n'
        '           { name = "simfile_flat", polyline = [[-0.045, 0.01], [0.045, 0.01]] }]\n'
    )
    (tmp_path / "g.toml").write_text(
        'name = "pads"\nseeds = 1\n[table]\ngrid = 9\n'
        '[world]\nobjects_file = "shapes.toml"\n'
        "[base]\nsteps = 2\neval_every = 2\neval_batches = 2\nbatch_size = 8\n"
        '[axes]\npad = [{ name = "pressure" }, '
        '{ name = "binary", world = { simulator_file = "sims/pad.py" } }]\n'
    )
    with registries_restored():
        r = ok(run_ham_inprocess("reproduce", "grid", "g.toml", "--workers", "1", "--out", "o",
                                 "--quiet", cwd=tmp_path))  # fmt: skip
    assert "ran 2 run(s)" in r.stdout
    tables = sorted((tmp_path / "o").glob("table_9*.h5"))
    assert len(tables) == 2
    worlds = [json.loads(h5py.File(t).attrs["world"]) for t in tables]
    assert sorted(w["simulator"] for w in worlds) == ["binary", "fast"]
    assert all(w["objects"] == "simfile_wedge,simfile_flat" for w in worlds)
    assert all(w["objects_file"]["name"] == "shapes.toml" for w in worlds)
    report = (tmp_path / "o" / "report.md").read_text()  # a file by its name, not its text
    assert 'world: simulator_file="pad.py", simulator="binary"' in report
    assert "register_simulator" not in report
    (tmp_path / "g.toml").write_text((tmp_path / "g.toml").read_text().replace("sims/", "no/"))
    line = one_line_error(run_ham_inprocess("reproduce", "grid", "g.toml", "--out", "o2",
                                            cwd=tmp_path))  # fmt: skip
    assert "axis 'pad' world: simulator file" in line and "does not exist" in line


def test_gym_envs_glance_through_a_simulator_file(tmp_path):
    import gymnasium as gym

    import ham.envs  # noqa: F401 - registers the environments

    with registries_restored():
        world = WorldConfig(simulator="binary", simulator_file=simulators.read_simulator_file(PAD))
        env = gym.make("ham/HapticGlance-v0", world=world.to_dict())
        env.reset(seed=0)
        env.action_space.seed(0)
        levels = []  # one bit per taxel: an image holds 0 and at most one other (normalized) value
        for _ in range(12):
            obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
            levels.append(len(np.unique(obs["pressure"])))
            if terminated or truncated:
                env.reset()
        assert max(levels) == 2, levels  # some glances touched, none read more than one level
    ok(run_ham_inprocess("envs", "check", "--simulator-file", str(PAD), "--glances", "2",
                         "--num-envs", "2", cwd=tmp_path))  # fmt: skip
    ok(run_ham_inprocess("table", "build", "--grid", "3", "--out", "t.h5", "--quiet",
                         cwd=tmp_path))  # fmt: skip
    line = one_line_error(run_ham_inprocess("envs", "check", "--simulator-file", str(PAD),
                                            "--table", "t.h5", cwd=tmp_path))  # fmt: skip
    assert "is the online world's; the table 't.h5' has its own" in line


def test_the_binary_pad_reads_out_the_extended_glance_of_a_world_with_y(tmp_path):
    """A factory with a ``world`` parameter is given the world: the example builds the world's
    own fast glance, here the extended one (x, y, phi, phi_y on height fields)."""
    args = ["--objects", "composite:train", "--pose-dims", "x,y,phi,phi_y", "--grid", "5,5,3,3",
            "--quiet"]  # fmt: skip
    ok(run_ham_inprocess("table", "build", "--simulator-file", str(PAD), *args, "--out", "b.h5",
                         cwd=tmp_path))  # fmt: skip
    ok(run_ham_inprocess("table", "build", *args, "--out", "f.h5", cwd=tmp_path))
    with h5py.File(tmp_path / "b.h5") as b, h5py.File(tmp_path / "f.h5") as f:
        names = json.loads(f.attrs["objects"])
        binary = np.stack([b[f"objects/{n}/pressure"][...] for n in names])
        fast = np.stack([f[f"objects/{n}/pressure"][...] for n in names])
    assert np.array_equal(binary, np.where(fast > 1000.0, 5000.0, 0.0).astype(np.float32))
    assert (binary > 0).any()


def test_the_binary_pad_turns_objects_with_an_object_pose():
    """The first glances are glanced again with the object pose of their rows (a ``(yaw, dx,
    dy)`` tuple cut to them), and match the fast extended glance's thresholded."""
    ids, q = torch.arange(9), torch.linspace(-0.5, 0.5, 9)
    pose = (torch.full((9,), 0.3), torch.full((9,), 0.004), torch.zeros(9))
    world = dict(objects="curvature2d", pose_dims=("x", "y", "phi", "phi_y"))
    with registries_restored():
        record = simulators.read_simulator_file(PAD)
        simulators.load_simulator_file(record)
        pad = make_simulator(WorldConfig(**world, simulator="binary", simulator_file=record))
        r = pad.glance(ids, q, q, q_y=q, q_phi_y=q, object_pose=pose)
    fast = make_simulator(WorldConfig(**world)).glance(
        ids, q, q, q_y=q, q_phi_y=q, object_pose=pose
    )
    assert torch.equal(r.pressure, (fast.pressure > 1000.0).float() * 5000.0)
    unturned = make_simulator(WorldConfig(**world)).glance(ids, q, q, q_y=q, q_phi_y=q)
    assert not torch.equal(fast.pressure, unturned.pressure)  # the pose did turn them


def test_the_repeated_glances_take_plain_lists_too():
    """Python lists of one value per glance (q_y, q_phi_y as keywords) are cut to the repeated
    rows like tensors; a value for all glances is passed as it is."""
    from ham.world.extended_glance import ExtendedSimulator

    world = dict(objects="curvature2d", pose_dims=("x", "y", "phi", "phi_y"))
    ids, q = list(range(9)) * 2, [0.1 * (i % 5) - 0.2 for i in range(18)]
    with registries_restored():
        simulators.register_simulator("ext", ExtendedSimulator)
        r = make_simulator(WorldConfig(**world, simulator="ext")).glance(
            ids, q, q, q_y=q, q_phi_y=0.1, object_pose=(0.3, 0.0, 0.001)
        )
    fast = make_simulator(WorldConfig(**world)).glance(
        ids, q, q, q_y=q, q_phi_y=0.1, object_pose=(0.3, 0.0, 0.001)
    )
    assert torch.equal(r.pressure, fast.pressure)
