"""A trained run on another world's glances (``ham evaluate DIR --transfer-table FILE``,
``load_run(..., transfer_table=)``): the run's weights, normalization and policy, the glances of
another table of the same objects and pose dims, and the differences of the two worlds named;
and the read-out's domain randomization (``TrainConfig.spread_augment``) that the transfer
measurements led to."""

from __future__ import annotations

import json
import re
import shutil
from dataclasses import replace

import numpy as np
import pytest
import torch

from ham.errors import HamError
from ham.learn.environment import HapticEnv
from ham.learn.evaluation import evaluate
from ham.learn.train import TrainConfig, load_run, make_env, resume, train
from ham.model.agent import HamConfig
from ham.world.config import WorldConfig, world_differences
from ham.world.sensor import SensorConfig, gaussian_spread, gaussian_spread_rows, normalize
from ham.world.source import make_source
from ham.world.table import build_table


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """The run's own table, the same world read out with the Gazebo plugin's spread, the same
    world on a coarser grid, and a run trained briefly on the first."""
    d = tmp_path_factory.mktemp("transfer")
    own = build_table(WorldConfig(), 11, d / "own.h5", progress=False)
    spread = WorldConfig(sensor=SensorConfig(spread_sigma=0.005))
    w = {
        "own": own,
        "spread": build_table(spread, 11, d / "spread.h5", progress=False),
        "coarse": build_table(WorldConfig(), 7, d / "coarse.h5", progress=False),
        "run": d / "run",
    }
    config = TrainConfig(model=HamConfig(glances=2), table=str(own), steps=20, batch_size=16,
                         eval_every=10, eval_batches=2)  # fmt: skip
    train(config, w["run"], progress=False)
    return w


def _episode_logits(run, seed: int = 3) -> torch.Tensor:
    objects = run.env.balanced_objects(0)
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        return run.agent.eval()(run.env, objects, g, greedy=True).logits


def test_world_differences_name_each_field_that_differs() -> None:
    a = WorldConfig().to_dict()
    b = WorldConfig(sensor=SensorConfig(spread_sigma=0.005), simulator="mujoco").to_dict()
    assert world_differences(a, a) == []
    assert world_differences(a, b) == ["sensor.spread_sigma: None -> 0.005",
                                       "simulator: 'fast' -> 'mujoco'"]  # fmt: skip
    assert world_differences({"grid": [3, 3]}, {}) == ["grid: [3, 3] -> None"]
    gazebo = WorldConfig(simulator="mujoco", mujoco={"readout": "gazebo"}).to_dict()
    assert world_differences(a, gazebo) == ["mujoco.readout: None -> 'gazebo'",
                                            "simulator: 'fast' -> 'mujoco'"]  # fmt: skip


def test_the_runs_own_glances_from_a_copy_give_its_own_evaluation(world, tmp_path) -> None:
    copy = shutil.copy(world["own"], tmp_path / "copy.h5")
    own, moved = load_run(world["run"]), load_run(world["run"], transfer_table=str(copy))
    assert own.transfer is None and moved.transfer == []
    assert moved.step == own.step == 20
    a = evaluate(own.agent, own.env, batches=3, seed=7)
    b = evaluate(moved.agent, moved.env, batches=3, seed=7)
    assert a == b


def test_another_read_out_is_evaluated_with_the_runs_weights_and_normalization(world) -> None:
    own = load_run(world["run"])
    run = load_run(world["run"], transfer_table=str(world["spread"]))
    assert run.transfer == ["sensor.spread_sigma: None -> 0.005"]
    assert run.config.normalization == own.config.normalization
    # the same as the run's agent on an environment made from the other table by hand
    by_hand = make_env(replace(own.config, table=str(world["spread"])))
    assert evaluate(run.agent, run.env, 3, seed=7) == evaluate(own.agent, by_hand, 3, seed=7)
    # and not the run's own glances
    assert not torch.equal(_episode_logits(run), _episode_logits(own))


def test_a_coarser_grid_is_named_and_the_checkpoint_still_guards_its_own_table(world) -> None:
    run = load_run(world["run"], transfer_table=str(world["coarse"]))
    assert run.transfer == ["grid: [11, 11] -> [7, 7]"]
    assert evaluate(run.agent, run.env, 2, seed=1).episodes == 2 * 16
    with pytest.raises(HamError, match="is not the run's table"):
        load_run(world["run"], table=str(world["coarse"]))  # --table: the run's own, moved


def test_an_online_run_on_a_table(world, tmp_path) -> None:
    config = TrainConfig(model=HamConfig(glances=2), table=None, steps=2, batch_size=8,
                         eval_every=2, eval_batches=1)  # fmt: skip
    train(config, tmp_path / "online", progress=False)
    run = load_run(tmp_path / "online", transfer_table=str(world["own"]))
    assert run.transfer == ["grid: 'online' -> [11, 11]"]
    assert 0.0 <= evaluate(run.agent, run.env, 2, seed=1).accuracy <= 1.0


def test_the_cli_prints_and_records_the_transfer(world, ham_cli, tmp_path) -> None:
    r = ham_cli("evaluate", str(world["run"]), "--batches", "2", "--json",
                "--transfer-table", str(world["spread"]))  # fmt: skip
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["transfer_table"] == str(world["spread"].resolve())
    assert d["transfer_differences"] == ["sensor.spread_sigma: None -> 0.005"]
    r = ham_cli("evaluate", str(world["run"]), "--batches", "2",
                "--transfer-table", str(world["spread"]))  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "(its world against the run's: sensor.spread_sigma: None -> 0.005)" in r.stdout
    png = tmp_path / "h.png"
    r = ham_cli("heatmap", str(world["run"]), "--out", str(png), "--batches", "2",
                "--transfer-table", str(world["spread"]))  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert f"on the glances of {world['spread'].resolve()}" in r.stdout and png.is_file()


# ------------------------------------------------------------------ domain randomization
def test_a_spread_of_its_own_per_image():
    torch.manual_seed(0)
    images = torch.rand(5, 16, 16) * 1000
    same = gaussian_spread_rows(images, torch.full((5,), 1.0), 1.0)
    assert torch.allclose(same, gaussian_spread(images, 1.0), atol=1e-3, rtol=1e-6)
    sigmas = torch.tensor([0.0, 0.5, 1.0, 0.0, 0.25])
    each = gaussian_spread_rows(images, sigmas, 1.0)
    assert torch.equal(each[0], images[0]) and torch.equal(each[3], images[3])  # sigma 0
    for i in (1, 2, 4):
        wide = gaussian_spread_rows(images[i : i + 1], sigmas[i : i + 1], 1.0)
        assert torch.allclose(each[i], wide[0], atol=1e-3)
        assert not torch.allclose(each[i], images[i])


def test_spread_augment_spreads_training_glances_only(world):
    source, table_world = make_source(str(world["own"]), WorldConfig())
    sigma = 0.005 / table_world.sensor.pitch
    plain = HapticEnv(source, batch_size=8, seed=3)
    augmented = HapticEnv(source, batch_size=8, seed=3, augment_sigma=sigma)
    q = torch.zeros(8, 2)
    ids = augmented.sample_objects()
    assert augmented._sigmas.shape == (8,) and float(augmented._sigmas.max()) <= sigma
    raw, _ = source.glance(ids, q, None)
    by_hand = normalize(gaussian_spread_rows(raw, augmented._sigmas, sigma), "l2")
    assert torch.equal(augmented.glance(ids, q), by_hand)
    assert not torch.equal(by_hand, normalize(raw, "l2"))
    with pytest.raises(HamError, match="4 objects but the batch drew 8 spreads"):
        augmented.glance(ids[:4], q[:4])  # not the batch the spreads were drawn for
    # evaluation batches: the world's own glances
    ids = augmented.balanced_objects(0)
    assert torch.equal(augmented.glance(ids, q), plain.glance(plain.balanced_objects(0), q))


def test_a_run_with_spread_augment_resumes_bit_identically(world, tmp_path):
    config = TrainConfig(model=HamConfig(glances=2), table=str(world["own"]), steps=16,
                         batch_size=8, eval_every=8, eval_batches=2, spread_augment=0.005)  # fmt: skip
    whole = train(config, tmp_path / "whole", progress=False)
    train(replace(config, steps=8), tmp_path / "parts", progress=False)
    assert resume(tmp_path / "parts", steps=16, progress=False)["history"] == whole["history"]
    plain = train(replace(config, spread_augment=0.0), tmp_path / "plain", progress=False)
    assert plain["history"] != whole["history"]


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"spread_augment": -0.001}, "spread_augment = -0.001; accepted: a number 0..0.05 (m)"),
        ({"spread_augment": float("nan")}, "spread_augment = nan"),
        ({"spread_augment": 0.5}, "spread_augment = 0.5"),
        ({"spread_augment": True}, "spread_augment = True"),
    ],
)
def test_spread_augment_refuses_bad_values(changes, message):
    with pytest.raises(HamError, match=re.escape(message)):
        TrainConfig(**changes)


def test_spread_augment_is_refused_on_ap_gym():
    from ham.learn.ap_adapter import ApGymConfig

    with pytest.raises(HamError, match="with env 'ap_gym:CircleSquare-v0'"):
        TrainConfig(env=ApGymConfig("ap_gym:CircleSquare-v0"), spread_augment=0.005)


def test_batched_runs_with_spread_augment_are_their_single_runs(world, tmp_path):
    """The batched trainer spreads each run's training images by its own batch's draws (one
    lookup for all runs, each run's rows read out by its env): a sweep of spreads, one run
    without, and one of another normalization give their single runs' numbers; its evaluation
    reads the world's own glances."""
    from tests.test_batched import assert_same_runs, metrics, train_both

    table = str(world["own"])
    base = dict(table=table, steps=6, batch_size=8, eval_every=3, eval_batches=2,
                model=HamConfig(glances=2))  # fmt: skip
    configs = [TrainConfig(seed=0, spread_augment=0.005, **base),
               TrainConfig(seed=1, spread_augment=0.01, **base),
               TrainConfig(seed=2, spread_augment=0.005, normalization="l1", **base),
               TrainConfig(seed=3, **base)]  # fmt: skip
    train_both(tmp_path, configs)
    assert_same_runs(tmp_path, configs)
    plain = train(TrainConfig(seed=0, **base), tmp_path / "plain", progress=False)
    assert (
        plain["history"][-1]["train_loss"] != metrics(tmp_path / "b0")["history"][-1]["train_loss"]
    )
    # the first evaluation is before any update: the world's own glances, spread or not
    assert plain["history"][0] == metrics(tmp_path / "single0")["history"][0]


def test_recorded_glances_of_the_same_images_give_the_same_evaluation(world, tmp_path):
    """The run's own images, exported as recorded glances and imported (ham table
    import-recorded): only the simulator differs, and the evaluation is the run's own."""
    from ham.world.table import GlanceTable, import_recorded

    t = GlanceTable.load(world["own"])
    np.savez(tmp_path / "rec.npz", **{n: t.pressure[i].numpy() for i, n in enumerate(t.objects)})
    recorded = import_recorded(tmp_path / "rec.npz", tmp_path / "rec.h5")
    own, run = load_run(world["run"]), load_run(world["run"], transfer_table=str(recorded))
    assert run.transfer == ["simulator: 'fast' -> 'recorded'"]
    assert evaluate(run.agent, run.env, 3, seed=7) == evaluate(own.agent, own.env, 3, seed=7)


def test_recorded_glances_over_the_next_worlds_poses_give_the_same_evaluation(tmp_path):
    """A run of the next world (height fields, poses x, y, phi, phi_y) on its table's images and
    heights, exported as recorded glances and imported over the same axes: the recorded table
    names no object set, so only the simulator differs, and the evaluation is the run's own."""
    from ham.learn.train import model_for_source
    from ham.world.table import GlanceTable, import_recorded

    world = WorldConfig(objects="curvature2d", pose_dims=("x", "y", "phi", "phi_y"))
    own = build_table(world, "3,3,3,3", tmp_path / "c4.h5", progress=False)
    model = model_for_source(HamConfig(glances=2, height_input=True), str(own), WorldConfig())
    config = TrainConfig(model=model, table=str(own), steps=4, batch_size=8, eval_every=2,
                         eval_batches=1)  # fmt: skip
    train(config, tmp_path / "run", progress=False)
    t = GlanceTable.load(own)
    arrays = {n: t.pressure[i].numpy() for i, n in enumerate(t.objects)}
    heights = {f"{n}.height": t.height[i].numpy() for i, n in enumerate(t.objects)}
    np.savez(tmp_path / "rec.npz", **arrays, **heights)
    recorded = import_recorded(tmp_path / "rec.npz", tmp_path / "rec.h5",
                               pose_dims="x,y,phi,phi_y")  # fmt: skip
    mine, run = load_run(tmp_path / "run"), load_run(tmp_path / "run", transfer_table=str(recorded))
    assert run.transfer == ["simulator: 'fast' -> 'recorded'"]
    # the other way: a run trained on the recorded glances, onto a built table; the recorded
    # world's objects, sensor and mapping are defaults, not differences
    train(replace(config, table=str(recorded)), tmp_path / "on_recorded", progress=False)
    back = load_run(tmp_path / "on_recorded", transfer_table=str(own))
    assert back.transfer == ["simulator: 'recorded' -> 'fast'"]
    assert evaluate(run.agent, run.env, 3, seed=7) == evaluate(mine.agent, mine.env, 3, seed=7)
    # recorded without their heights: a model that reads the height cannot run on them
    np.savez(tmp_path / "flat.npz", **arrays)
    bare = import_recorded(tmp_path / "flat.npz", tmp_path / "flat.h5", pose_dims="x,y,phi,phi_y")
    with pytest.raises(HamError, match=f"glance table '{bare}' does not know every glance's"):
        load_run(tmp_path / "run", transfer_table=str(bare))
    from ham.learn.planners import Partitions

    with pytest.raises(HamError, match="height = True on a table that does not know every"):
        Partitions.from_table(GlanceTable.load(bare), height=True)
