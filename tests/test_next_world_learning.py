"""The HAM in the paper's next world: 4-D poses on height fields, tables over 4-D grids, random
object poses, held-out composite instances, the envs on the extended world, heat-map projections."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from ham.errors import HamError
from ham.learn.environment import HapticEnv
from ham.learn.train import TrainConfig, load_run, model_for_source, resume, train
from ham.model.agent import HamConfig
from ham.world.config import WorldConfig, make_simulator
from ham.world.glance import glance_at
from ham.world.source import ObjectPoseConfig, make_source
from ham.world.table import GlanceTable, build_table, grid_poses, verify_table

DIMS4 = ("x", "y", "phi", "phi_y")
W4 = WorldConfig(objects="curvature2d", pose_dims=DIMS4)


def test_online_4d_source_is_glance_at():
    source, _ = make_source(None, W4)
    assert source.pose_dims == DIMS4
    g = torch.Generator().manual_seed(0)
    q = torch.rand(12, 4, generator=g) * 2 - 1
    ids = torch.arange(12) % source.n_objects
    pressure, height = source.glance(ids, q)
    r = glance_at(make_simulator(W4), ids, q, DIMS4)
    assert torch.equal(pressure, r.pressure) and torch.equal(height, r.height)
    # flat_low and flat_high differ only in height: equal images, heights 2 cm apart
    names = source.objects
    lo, hi = names.index("flat_low"), names.index("flat_high")
    p, h = source.glance(torch.tensor([lo, hi]), torch.zeros(2, 4))
    assert torch.allclose(p[0], p[1]) and float(h[1] - h[0]) == pytest.approx(0.02, abs=1e-4)


def test_4d_table_round_trip_and_stream(tmp_path):
    world = WorldConfig(objects="flat_low,dome,saddle", pose_dims=DIMS4)
    path = build_table(world, "3,3,3,2", tmp_path / "t4.h5", progress=False, batch=7)
    info = verify_table(path)
    assert info.pose_dims == DIMS4 and info.grid_shape == (3, 3, 3, 2) and info.poses == 54
    table = GlanceTable.load(path)
    q = torch.from_numpy(grid_poses((3, 3, 3, 2), 0, 54))
    sim = make_simulator(world)
    for oid in range(3):
        ids = torch.full((54,), oid)
        p, h = table.lookup_pose(ids, q, height=True)
        r = glance_at(sim, ids, q, DIMS4)
        assert torch.equal(p, r.pressure) and torch.equal(h, r.height)
    streamed = GlanceTable.load(path, lookup="stream")
    ids = torch.tensor([0, 2, 1, 2])
    qq = torch.tensor(
        [[0.1, -0.9, 0.4, 0.6], [1, 1, 1, 1], [-1, 0, 0.2, -1], [0.1, -0.9, 0.4, 0.6]]
    )
    assert torch.equal(streamed.lookup_pose(ids, qq), table.lookup_pose(ids, qq))
    with pytest.raises(HamError, match=r"lookup\(q_x, q_phi\) on a table over pose dims"):
        table.lookup([0], [0.0], [0.0])


def test_random_object_pose_per_episode_changes_glances_and_is_reproducible():
    source, _ = make_source(None, W4)
    plain = HapticEnv(source, batch_size=8, seed=1)
    moved = HapticEnv(source, batch_size=8, seed=1,
                      object_pose=ObjectPoseConfig(yaw_max=1.0, offset_max=0.01))  # fmt: skip
    q = torch.zeros(8, 4)
    ids = plain.sample_objects()
    assert torch.equal(moved.sample_objects(), ids)  # the ids come first from the same stream
    a, b = plain.glance(ids, q), moved.glance(ids, q)
    assert not torch.equal(a, b)
    assert torch.equal(moved.glance(ids, q), b)  # one pose per episode: every glance sees it
    e1, e2 = moved.balanced_objects(3), moved.balanced_objects(3)
    assert torch.equal(moved.glance(e1, q), moved.glance(e2, q))  # evaluation batches repeat
    with pytest.raises(HamError, match="4 objects but the batch drew 8 object poses"):
        moved.glance(ids[:4], q[:4])


def _tiny(world: WorldConfig, **kw) -> TrainConfig:
    model = model_for_source(HamConfig(glances=3, height_input=True), None, world)
    base = dict(model=model, world=world, steps=4, batch_size=8, eval_every=2, eval_batches=2,
                seed=2, learner="info", optimizer="adam", lr=0.003)  # fmt: skip
    base.update(kw)
    return TrainConfig(**base)


def test_4d_training_resumes_bit_identically(tmp_path):
    config = _tiny(W4, object_yaw_max=0.5, object_offset_max=0.005)
    assert config.model.pose_dims == DIMS4 and config.model.n_objects == 9
    full = train(config, tmp_path / "full", progress=False)
    train(TrainConfig(**{**config.__dict__, "steps": 2}), tmp_path / "half", progress=False)
    resumed = resume(tmp_path / "half", steps=4, progress=False)
    assert full["history"] == resumed["history"]
    saved = json.loads((tmp_path / "full" / "config.json").read_text())
    assert saved["model"]["pose_dims"] == list(DIMS4) and saved["object_yaw_max"] == 0.5
    assert saved["world"]["pose_dims"] == list(DIMS4)


def test_held_out_instances_evaluate_a_composite_run(tmp_path):
    from ham.learn.evaluation import evaluate

    world = WorldConfig(objects="composite:train", pose_dims=("x", "y"))
    train(_tiny(world, steps=2), tmp_path / "run", progress=False)
    run = load_run(tmp_path / "run", objects="composite:test")
    assert run.env.objects[0].endswith("_2") and run.objects == run.env.objects
    result = evaluate(run.agent, run.env, 1, seed=0)
    assert len(result.per_object_accuracy) == 12
    with pytest.raises(HamError, match="--objects 'curvature2d' has 9 objects but the run"):
        load_run(tmp_path / "run", objects="curvature2d")


def test_ham_train_evaluate_heatmap_on_4d_poses(tmp_path, ham_cli, ham_main):
    run = tmp_path / "run"
    r = ham_cli("train", "--objects", "curvature2d", "--pose-dims", "x,y,phi,phi_y",
                "--height-input", "--glances", "2", "--batch-size", "4", "--steps", "2",
                "--eval-every", "2", "--eval-batches", "1", "--learner", "info",
                "--no-progress", "--out", str(run))  # fmt: skip
    assert r.returncode == 0, r.stderr
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["model"]["pose_dims"] == list(DIMS4) and cfg["model"]["height_input"]
    png, data = tmp_path / "heat.png", tmp_path / "heat.json"
    r = ham_main("heatmap", str(run), "--out", str(png), "--batches", "2", "--bins", "5",
                "--json", str(data))  # fmt: skip
    assert r.returncode == 0, r.stderr
    d = json.loads(data.read_text())
    assert [p["dims"] for p in d["projections"]][:2] == [["x", "y"], ["x", "phi"]]
    assert len(d["projections"]) == 6 and png.read_bytes()[:4] == b"\x89PNG"
    counts = np.asarray(d["projections"][0]["counts"])
    assert counts.shape == (9, 5, 5) and counts.sum() == 2 * 4
    r = ham_main("evaluate", str(run), "--objects", "composite:test", "--batches", "1")
    assert r.returncode == 2 and "has 12 objects but the run classifies 9" in r.stderr


def test_gym_envs_take_the_extended_world():
    from ham.envs.haptic import HapticGlanceVectorEnv

    env = HapticGlanceVectorEnv(2, glances=2, world=W4, height=True)
    assert env.single_action_space["pose"].shape == (4,)
    obs, _ = env.reset(seed=0)
    assert obs["pose"].shape == (2, 4) and obs["height"].shape == (2, 1)
    obs, *_ = env.step({"pose": np.zeros((2, 4)), "prediction": np.zeros(2, int)})
    assert env.single_observation_space.contains({k: v[0] for k, v in obs.items()})
    pytest.importorskip("ap_gym")
    from ham.envs.ap import HapticGlanceAPEnv

    ap = HapticGlanceAPEnv(glances=2, world=W4.to_dict(), height=True,
                           object_pose={"yaw_max": 0.3})  # fmt: skip
    obs, _ = ap.reset(seed=0)
    assert obs["pose"].shape == (4,) and ap.action_space["action"].shape == (4,)


def test_epochs_replay_the_recorded_contact_heights(tmp_path):
    """PPO-style epochs on 4-D poses with the height input: the replayed first pass is the
    played episode (heights included), and training runs."""
    from ham.learn.train import GlanceRecorder

    config = _tiny(W4, epochs=2)
    torch.manual_seed(0)
    from ham.model.agent import HapticAttentionModel

    model = HapticAttentionModel(config.model)
    source, _ = make_source(None, W4)
    env = HapticEnv(source, batch_size=4, seed=0)
    recorder = GlanceRecorder(env)
    played = model(recorder, env.sample_objects(), torch.Generator().manual_seed(1))
    assert len(recorder.heights) == config.model.glances
    again = model.replay(
        torch.stack(recorder.pressures),
        torch.stack(recorder.where),
        torch.stack(recorder.heights),
        played=played,
    )
    assert torch.allclose(again.logits, played.logits, atol=1e-5)
    metrics = train(config, tmp_path / "run", progress=False)
    assert metrics["env_steps"] > 0
