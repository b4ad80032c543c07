"""Sensors from the config: every shape follows ``SensorConfig(taxels, pitch)``.

glance -> table -> train -> evaluate -> environments with an 8 x 8 pad (10 mm pitch) and a
32 x 32 pad (2.5 mm pitch), through the real CLI where it exists; the validation of the pad; a
table refuses a model that reads another sensor.
"""

from __future__ import annotations

import json
import math
import warnings

import gymnasium as gym
import h5py
import numpy as np
import pytest
import torch

import ham.envs  # noqa: F401 - registers ham/HapticGlance-v0
from ham.cli.main import main as cli_main
from ham.errors import HamError
from ham.world.config import WorldConfig, make_simulator
from ham.world.drawing import draw_table_grid
from ham.world.glance import GlanceConfig
from ham.world.sensor import MAX_TAXELS, SensorConfig, normalize
from ham.world.table import GlanceTable, build_table, table_info

from .conftest import run_ham, run_ham_inprocess

PADS = [(8, 0.01), (32, 0.0025)]
GRID = 5


def _ok(proc) -> str:
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def _refused(proc, *words: str) -> str:
    """A user error: exit 2, one line ``ham: error: ...`` naming ``words``, no traceback."""
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ham: error: "), proc.stderr
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


# --------------------------------------------------------------------------- validation
@pytest.mark.parametrize("taxels", [1, 0, -4, MAX_TAXELS + 1])
def test_taxels_must_be_an_integer_2_to_128(taxels):
    with pytest.raises(HamError, match=r"taxels = .*accepted: an integer 2\.\.128"):
        SensorConfig(taxels=taxels)


@pytest.mark.parametrize("taxels", [2.5, 8.0, True, "8", None])
def test_taxels_of_another_type_are_refused_by_type(taxels):
    with pytest.raises(HamError, match=r"^taxels = .*; accepted: an integer$"):
        SensorConfig(taxels=taxels)


@pytest.mark.parametrize("pitch", [0.0, -0.005])
def test_pitch_must_be_positive(pitch):
    with pytest.raises(HamError, match="pitch = .*accepted: a positive number"):
        SensorConfig(pitch=pitch)


@pytest.mark.parametrize("pitch", [math.nan, math.inf, "0.005"])
def test_pitch_must_be_a_finite_number(pitch):
    with pytest.raises(HamError, match="^pitch = .*; accepted: a finite number$"):
        SensorConfig(pitch=pitch)


def test_fully_compressed_foam_may_press_at_most_1e15_pa():
    """Beyond it no material holds, and a 16 x 16 image's L2 norm overflows float32 (its
    normalized image would be all zeros): refused, the largest accepted glances finite."""
    with pytest.raises(HamError, match=r"^foam_stiffness \* foam_thickness = 1e\+12 Pa/m \* 1001 m "
                       r"\(the pressure of fully compressed foam\); accepted: at most 1e\+15 Pa$"):  # fmt: skip
        SensorConfig(foam_stiffness=1e12, foam_thickness=1001.0)
    # nor may the stop force on one taxel (an edge pressed by a single cell) press beyond it
    stiff = SensorConfig(foam_stiffness=1e12, foam_thickness=1000.0)
    with pytest.raises(HamError, match=r"^force_threshold = 2\.6e\+10 N on one 5 mm taxel presses "
                       r"1\.04e\+15 Pa; accepted: at most 1e\+15 Pa \(force_threshold <= "
                       r"2\.5e\+10 N\)$"):  # fmt: skip
        WorldConfig(sensor=stiff, glance=GlanceConfig(force_threshold=2.6e10))
    WorldConfig(sensor=stiff, glance=GlanceConfig(force_threshold=2.5e10))
    world = WorldConfig(sensor=stiff)
    r = make_simulator(world).glance(torch.arange(3), torch.zeros(3), torch.zeros(3))
    assert (
        torch.isfinite(normalize(r.pressure)).all()
        and normalize(r.pressure).norm(dim=-1).min() > 0.99
    )


def test_numpy_taxels_are_stored_as_int():
    s = SensorConfig(taxels=np.int64(8), pitch=0.01)
    assert type(s.taxels) is int and s.pressure_dim == 64 and s.shape == (8, 8)
    json.dumps(s.to_dict())


def test_the_pad_must_fit_the_objects_and_carry_the_force():
    # 16 x 6 mm = 9.6 cm is wider than the 9 cm deep blocks: rows would hang over empty space.
    with pytest.raises(HamError, match=r"wider than object 'box' is deep \(9 cm\)"):
        make_simulator(WorldConfig(sensor=SensorConfig(pitch=0.006)))
    # 16 x 0.2 mm = 3.2 mm: 2 N on it would compress the 3 mm foam through.
    with pytest.raises(HamError, match=r"too small to carry 2 N.*taxels \* pitch > 0\.004082"):
        make_simulator(WorldConfig(sensor=SensorConfig(pitch=0.0002)))
    # A stiffer foam is offered only when one within the accepted range would carry the force:
    # a 16 um pad needs 2.6e12 Pa/m, above the 1e12 cap, so only the size is named.
    with pytest.raises(HamError, match=r"foam_stiffness in 6\.51e\+07 \.\. 1e\+12 Pa/m$"):
        WorldConfig(sensor=SensorConfig(pitch=0.0002))
    with pytest.raises(HamError, match=r"taxels \* pitch > 0\.004082 m$"):
        WorldConfig(sensor=SensorConfig(pitch=1e-6))
    # The limits themselves: 9 cm wide and 128 taxels are accepted.
    make_simulator(WorldConfig(sensor=SensorConfig(taxels=18, pitch=0.005)))
    make_simulator(WorldConfig(sensor=SensorConfig(taxels=128, pitch=0.0005)))


@pytest.mark.parametrize(
    "flags, words",
    [
        (["--taxels", "1"], ["taxels = 1", "2..128"]),
        (["--taxels", "200"], ["taxels = 200"]),
        (["--pitch", "0"], ["pitch = 0.0"]),
        (["--pitch", "nan"], ["--pitch", "'nan' is not a finite number"]),  # refused by the parser
        (["--pitch", "0.02"], ["wider than object", "<= 0.09 m"]),
        (["--taxels", "2", "--pitch", "0.001"], ["too small", "> 0.004082 m"]),
    ],
)
def test_cli_refuses_bad_pads_in_one_line(tmp_path, capsys, flags, words):
    # The CLI's own entry point in-process (the subprocess path is checked below).
    for argv in (
        ["glance", "--object", "box", "--x", "0", "--phi", "0", *flags],
        ["table", "build", "--grid", "3", "--out", str(tmp_path / "t.h5"), "--quiet", *flags],
        ["train", "--online", "--out", str(tmp_path / "run"), *flags],
    ):
        try:
            code = cli_main(argv)
        except SystemExit as exc:  # argparse's own refusals exit from the parser
            code = exc.code
        assert code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("ham: error: ")
        assert all(w in err[0] for w in words), err[0]
    assert not list(tmp_path.iterdir())  # no table, no partial file, no run directory


def test_cli_subprocess_refuses_a_bad_pad(tmp_path):
    out = tmp_path / "t.h5"
    _refused(run_ham("table", "build", "--grid", "3", "--out", str(out), "--taxels", "1"),
             "taxels = 1")  # fmt: skip
    assert not list(tmp_path.iterdir())


# --------------------------------------------------------------------------- the pipeline
def test_build_table_with_an_8_x_8_pad(tmp_path):
    # Used to end in "ValueError: cannot reshape array of size ... into shape (...,16,16)".
    world = WorldConfig(sensor=SensorConfig(taxels=8, pitch=0.01))
    path = build_table(world, 3, tmp_path / "t8.h5", progress=False)
    table = GlanceTable.load(path)
    assert table.pressure.shape == (4, 3, 3, 8, 8) and table.pressure_dim == 64
    assert table.info.sensor == world.sensor.to_dict()
    with h5py.File(path) as f:
        assert json.loads(f.attrs["sensor"])["taxels"] == 8
    sim = make_simulator(world)
    direct = sim.glance([2], [1.0], [-1.0]).pressure
    assert np.array_equal(table.lookup([2], [1.0], [-1.0]).numpy(), direct.numpy())


@pytest.mark.parametrize("taxels, pitch", PADS)
def test_glance_table_train_evaluate_env_follow_the_pad(tmp_path, taxels, pitch):
    n, pad = taxels, ["--taxels", str(taxels), "--pitch", str(pitch)]
    # glance (CLI): an N x N image, summed force 2 N on the flat box, drawn
    png = tmp_path / "glance.png"
    out = _ok(run_ham_inprocess("glance", "--object", "box", "--x", "0", "--phi", "0", "--json",
                      "--out", str(png), *pad))  # fmt: skip
    g = json.loads(out.splitlines()[0])
    p = np.asarray(g["pressure"])
    assert p.shape == (n, n) and png.stat().st_size > 0
    assert abs(p.sum() * pitch * pitch - 2.0) < 1e-3 and g["force"] == pytest.approx(2.0, abs=1e-4)

    # table (CLI): records the sensor, images N x N
    table = tmp_path / "t.h5"
    _ok(
        run_ham_inprocess(
            "table", "build", "--grid", str(GRID), "--out", str(table), "--quiet", *pad
        )
    )
    info = table_info(table)
    assert (
        info.sensor["taxels"] == n and info.sensor["pitch"] == pitch and info.pressure_dim == n * n
    )
    loaded = GlanceTable.load(table)
    assert loaded.pressure.shape == (4, GRID, GRID, n, n)
    draw_table_grid(loaded.pressure[0].numpy(), (np.zeros(GRID), np.zeros(GRID)), "t",
                    tmp_path / "grid.png")  # fmt: skip

    # train from the table and online (CLI): the model reads N^2 values
    few = ["--steps", "2", "--eval-every", "1", "--eval-batches", "1", "--batch-size", "8",
           "--glances", "2", "--no-progress"]  # fmt: skip
    run_t, run_o = tmp_path / "from_table", tmp_path / "online"
    _ok(run_ham_inprocess("train", "--table", str(table), "--out", str(run_t), *few))
    _ok(run_ham_inprocess("train", "--online", "--out", str(run_o), *few, *pad))
    for run in (run_t, run_o):
        model = json.loads((run / "config.json").read_text())["model"]
        assert model["pressure_dim"] == n * n and model["n_objects"] == 4
    world = json.loads((run_o / "config.json").read_text())["world"]
    assert world["sensor"]["taxels"] == n and world["sensor"]["pitch"] == pitch

    # evaluate (CLI)
    ev = json.loads(_ok(run_ham_inprocess("evaluate", str(run_t), "--batches", "1", "--json")))
    assert len(ev["accuracy_per_glance"]) == 2 and 0 <= ev["accuracy"] <= 1

    # environments: from the table and online, observation N x N, rendered 128 px wide
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        online = WorldConfig(sensor=SensorConfig(taxels=n, pitch=pitch))
        for kw in ({"table": str(table)}, {"world": online}, {"world": online.to_dict()}):
            env = gym.make("ham/HapticGlance-v0", glances=2, render_mode="rgb_array", **kw)
            assert env.observation_space["pressure"].shape == (n, n)
            obs, _ = env.reset(seed=0)
            assert obs["pressure"].shape == (n, n)
            obs, reward, terminated, _, _ = env.step(
                {"pose": np.zeros(2, np.float32), "prediction": 0}
            )
            assert obs["pressure"].shape == (n, n) and env.observation_space.contains(obs)
            assert env.render().shape == (128, 128, 3)
            env.close()
        venv = gym.make_vec("ham/HapticGlance-v0", num_envs=3, glances=2, world=online)
        obs, _ = venv.reset(seed=0)
        assert obs["pressure"].shape == (3, n, n)
        venv.close()


def test_ap_gym_env_follows_the_pad():
    ap_gym = pytest.importorskip("ap_gym")
    world = WorldConfig(sensor=SensorConfig(taxels=8, pitch=0.01))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = ap_gym.make("ham/HapticGlanceAP-v0", glances=2, world=world)
        obs, _ = env.reset(seed=0)
        assert obs["pressure"].shape == (8, 8)
        obs, *_ = env.step(env.action_space.sample())
        assert obs["pressure"].shape == (8, 8)
        env.close()


def test_the_env_images_are_the_normalized_glances():
    world = WorldConfig(sensor=SensorConfig(taxels=32, pitch=0.0025))
    env = ham.envs.HapticGlanceEnv(world=world)
    env.reset(seed=0)
    q = np.array([[0.3, -0.2]], np.float32)
    raw = make_simulator(world).glance([0], q[:, 0], q[:, 1]).pressure
    got = env.backend.glance(np.array([0]), q)
    np.testing.assert_allclose(got.reshape(1, -1), normalize(raw, "l2").numpy(), atol=1e-7)


# --------------------------------------------------------------------------- mismatches
def test_a_table_refuses_a_model_of_another_sensor(tmp_path):
    t8 = build_table(
        WorldConfig(sensor=SensorConfig(taxels=8, pitch=0.01)),
        3,
        tmp_path / "t8.h5",
        progress=False,
    )
    t16 = build_table(WorldConfig(), 3, tmp_path / "t16.h5", progress=False)
    run = tmp_path / "run"
    _ok(run_ham_inprocess("train", "--table", str(t8), "--out", str(run), "--steps", "1", "--eval-every",
                "1", "--eval-batches", "1", "--batch-size", "4", "--no-progress"))  # fmt: skip
    # The run's model reads 8 x 8 images; point it at a 16 x 16 table: refused, by name.
    cfg = json.loads((run / "config.json").read_text())
    cfg["table"] = str(t16)
    (run / "config.json").write_text(json.dumps(cfg))
    _refused(run_ham("evaluate", str(run), "--batches", "1"),
             "the model reads 64 pressure values", "16 x 16 images (256 values)")  # fmt: skip
    # --taxels/--pitch beside a table must agree with the table's sensor.
    _refused(run_ham_inprocess("train", "--table", str(t8), "--taxels", "16", "--out", str(tmp_path / "x")),
             "--taxels 16", "taxels = 8")  # fmt: skip
    assert not (tmp_path / "x").exists()


def test_tables_without_a_sensor_attribute_read_the_worlds(tmp_path):
    # Tables written before the sensor attribute: the world's sensor (16 x 16) is the table's.
    path = build_table(WorldConfig(), 3, tmp_path / "old.h5", progress=False)
    with h5py.File(path, "a") as f:
        del f.attrs["sensor"]
        del f.attrs["record_checksum"]  # nor the record checksum, which came later still
    assert table_info(path).sensor == SensorConfig().to_dict()
    assert GlanceTable.load(path).lookup([0], [0.0], [0.0]).shape == (1, 16, 16)


def test_pad_options_beside_another_glance_source_are_refused(tmp_path, capsys):
    # An ap_gym environment brings its own glimpse: --taxels would be silently ignored.
    argv = [
        "train",
        "--env",
        "ap_gym:CircleSquare-v0",
        "--taxels",
        "8",
        "--out",
        str(tmp_path / "r"),
    ]
    assert cli_main(argv) == 2
    assert "--env ap_gym:CircleSquare-v0 brings its own glimpse" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
