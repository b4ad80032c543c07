"""k pose dimensions and the contact height: model, sources, tables over any grid, envs."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
import torch

from ham.errors import HamError
from ham.learn.environment import HapticEnv
from ham.learn.hybrid_loss import hybrid_loss
from ham.learn.info_loss import info_loss
from ham.learn.train import TrainConfig, resume, train
from ham.model.agent import HamConfig, HapticAttentionModel
from ham.world.config import WorldConfig, make_simulator
from ham.world.source import ObjectPoseConfig, OnlineSource, TableSource, make_source
from ham.world.table import GlanceTable, build_table, grid_values, table_info, verify_table

#: sha256 of the 11 x 11 paper table's pressures before tables over any pose grid: unchanged.
PAPER_11_CHECKSUM = "b45b54a039e7b459c3609c822f84c73009aea06fd760d1beaa34916c3435266e"


# --------------------------------------------------------------------------- model
def test_pose_dims_are_validated_and_round_trip_through_json():
    c = HamConfig(pose_dims=["x", "y", "phi", "phi_y"], height_input=True)
    assert c.pose_dims == ("x", "y", "phi", "phi_y") and c.location_dim == 5
    back = HamConfig.from_dict(json.loads(json.dumps(c.to_dict())))
    assert back == c
    assert HamConfig(pose_dims="x,phi") == HamConfig()
    for bad in ("phi,x", "x,x", "", "x,z"):
        with pytest.raises(HamError, match="pose_dims.*; accepted: a non-empty subset"):
            HamConfig(pose_dims=bad)
    with pytest.raises(HamError, match="height_input = 1; accepted"):
        HamConfig(height_input=1)


class _FourD:
    """The HapticEnv interface with k = 4 and a height: pressure from the pose (a stand-in
    until the 4-D simulator; the real one is tested below once the world has y)."""

    n_objects, batch_size, device = 3, 6, torch.device("cpu")
    pose_dims = ("x", "y", "phi", "phi_y")

    def glance_height(self, objects, q):
        p = torch.cat([q, objects[:, None].float()], 1).repeat(1, 52)[:, :256].abs()
        return p, q[:, 0] * 0.01 + 0.02

    def glance(self, objects, q):
        return self.glance_height(objects, q)[0]


@pytest.mark.parametrize("policy", ["learned", "random"])
def test_k_dim_model_plays_and_learns(policy):
    torch.manual_seed(0)
    model = HapticAttentionModel(
        HamConfig(
            glances=3, n_objects=3, policy=policy, pose_dims=_FourD.pose_dims, height_input=True
        )  # fmt: skip
    )
    assert model.tactile.where.in_features == 5
    g = torch.Generator().manual_seed(1)
    ep = model(_FourD(), torch.tensor([0, 1, 2, 0, 1, 2]), g)
    assert ep.locations.shape == (3, 6, 4) and ep.locations.abs().max() <= 1
    assert ep.policy.log_prob(ep.locations[1:]).shape == (2, 6)
    (hybrid_loss(ep, 0.4).total + info_loss(ep, 0.5, 1.0).total).backward()
    if policy == "learned":
        assert model.location.mu.weight.grad.shape == (4, 256)
        assert model.location.mu.weight.grad.abs().sum() > 0
    else:
        assert ep.policy.entropy().shape == (2, 6)
        assert torch.allclose(ep.policy.entropy(), torch.full((2, 6), 4 * np.log(2.0)))


def test_height_input_needs_a_height():
    model = HapticAttentionModel(HamConfig(height_input=True))
    with pytest.raises(HamError, match="contact height .* gave none"):
        model.step(
            torch.zeros(2, 256), torch.zeros(2, 2), model.core.initial_state(2, torch.zeros(1))
        )


# --------------------------------------------------------------------------- sources
def test_online_source_glance_is_the_simulators_with_its_height():
    source, _ = make_source(None, WorldConfig())
    assert isinstance(source, OnlineSource) and source.pose_dims == ("x", "phi")
    q = torch.tensor([[0.1, -0.3], [-0.7, 0.5], [0.0, 0.0]])
    ids = torch.tensor([0, 2, 3])
    pressure, height = source.glance(ids, q)
    r = make_simulator(WorldConfig()).glance(ids, q[:, 0], q[:, 1])
    assert torch.equal(pressure, r.pressure) and torch.equal(height, r.z)
    assert torch.equal(source.lookup(ids, q[:, 0], q[:, 1]), r.pressure)
    with pytest.raises(HamError, match=r"poses of shape \(3, 3\); accepted: \(B, 2\)"):
        source.glance(ids, torch.zeros(3, 3))


def test_haptic_env_glance_height_is_normalized_pressure_and_z():
    source, _ = make_source(None, WorldConfig())
    env = HapticEnv(source, batch_size=4)
    ids = env.sample_objects()
    q = torch.rand(4, 2, generator=torch.Generator().manual_seed(0)) * 2 - 1
    p, h = env.glance_height(ids, q)
    assert torch.equal(p, env.glance(ids, q)) and p.shape == (4, 256)
    assert torch.allclose(p.norm(dim=1), torch.ones(4))
    assert torch.equal(h, make_simulator(WorldConfig()).glance(ids, q[:, 0], q[:, 1]).z)


def test_object_pose_config_is_validated():
    assert not ObjectPoseConfig().enabled and ObjectPoseConfig(yaw_max=0.5).enabled
    with pytest.raises(HamError, match="object pose yaw_max = 4; accepted: a number 0..3.14"):
        ObjectPoseConfig(yaw_max=4)
    with pytest.raises(HamError, match="offset_max = -0.1; accepted"):
        ObjectPoseConfig(offset_max=-0.1)
    with pytest.raises(HamError, match="random object pose .* accepted: online glances"):
        TrainConfig(table="t.h5", object_yaw_max=0.1)
    with pytest.raises(HamError, match="object_offset_max = 0.2; accepted: a number 0..0.05"):
        TrainConfig(object_offset_max=0.2)


# --------------------------------------------------------------------------- tables
def test_paper_table_is_bit_identical(tmp_path):
    path = build_table(WorldConfig(), 11, tmp_path / "paper.h5", progress=False)
    info = table_info(path)
    assert info.checksum == PAPER_11_CHECKSUM
    assert info.format_version == 1 and info.pose_dims == ("x", "phi")
    with h5py.File(path) as f:
        assert "pose_dims" not in f.attrs and f["objects/box/pressure"].shape == (11, 11, 16, 16)
        assert f["objects/box/pressure"].chunks is None  # the paper's layout, as before
    table = GlanceTable.load(path)
    q = torch.tensor([[0.4, -0.2], [-1.0, 1.0]])
    ids = torch.tensor([1, 2])
    p, h = table.lookup_pose(ids, q, height=True)
    assert torch.equal(p, table.lookup(ids, q[:, 0], q[:, 1]))
    ix = [round((v + 1) * 5) for v in (0.4, -1.0)]
    ip = [round((v + 1) * 5) for v in (-0.2, 1.0)]
    assert h.tolist() == [float(table.extras["z"][1, ix[0], ip[0]]),
                          float(table.extras["z"][2, ix[1], ip[1]])]  # fmt: skip


@pytest.fixture(scope="module")
def grid_table(tmp_path_factory):
    """A version-2 table: the paper's (x, phi) on a 5 x 3 grid (not square)."""
    return build_table(
        WorldConfig(), "5,3", tmp_path_factory.mktemp("g") / "grid.h5", progress=False, batch=4
    )


def test_grid_table_layout_and_round_trip(grid_table):
    info = verify_table(grid_table)
    assert info.format_version == 2 and info.grid_shape == (5, 3) and info.poses == 15
    with h5py.File(grid_table) as f:
        ds = f["objects/convex/pressure"]
        assert ds.shape == (15, 16, 16) and ds.compression == "gzip" and ds.chunks is not None
        assert f["objects/convex/height"].shape == (15,)
        assert "progress" not in f and "build" not in f.attrs
    table = GlanceTable.load(grid_table)
    assert table.pressure.shape == (4, 5, 3, 16, 16)
    qx, qp = np.meshgrid(grid_values(5), grid_values(3), indexing="ij")
    q = torch.tensor(np.stack([qx.ravel(), qp.ravel()], 1))
    sim = make_simulator(WorldConfig())
    for oid in range(4):
        ids = torch.full((15,), oid)
        p, h = table.lookup_pose(ids, q, height=True)
        r = sim.glance(ids, q[:, 0], q[:, 1])
        assert torch.equal(p, r.pressure) and torch.equal(h, r.z)
    with pytest.raises(HamError, match=r"q_phi = 1.5 is outside"):
        table.lookup_pose([0], [[0.0, 1.5]])
    with pytest.raises(HamError, match=r"poses of shape \(1, 3\); accepted: \(1, 2\)"):
        table.lookup_pose([0], [[0.0, 0.0, 0.0]])


@pytest.mark.parametrize("compression", ["gzip", "none"])
def test_streamed_lookup_equals_memory(tmp_path, grid_table, compression):
    path = grid_table
    if compression == "none":  # contiguous: memory-mapped
        path = build_table(WorldConfig(), "5,3", tmp_path / "raw.h5", progress=False,
                           compression="none")  # fmt: skip
    mem = GlanceTable.load(path)
    streamed = GlanceTable.load(path, lookup="stream")
    assert streamed.streamed and streamed.pressure is None
    assert (streamed._stream._maps is not None) == (compression == "none")
    g = torch.Generator().manual_seed(0)
    ids = torch.randint(4, (40,), generator=g)
    q = torch.rand(40, 2, generator=g) * 2 - 1
    a, ha = mem.lookup_pose(ids, q, height=True)
    b, hb = streamed.lookup_pose(ids, q, height=True)
    assert torch.equal(a, b) and torch.equal(ha, hb)
    source = TableSource(streamed)
    assert torch.equal(source.glance(ids, q)[0], a)
    streamed._stream.close()


def test_grid_table_checks(tmp_path, grid_table):
    with pytest.raises(HamError, match="grid = 5,3,2: 3 axes for the 2 pose dims x,phi"):
        build_table(WorldConfig(), "5,3,2", tmp_path / "x.h5", progress=False)
    with pytest.raises(HamError, match="compression = 'zip'; accepted: gzip, lzf, none"):
        build_table(WorldConfig(), "5,3", tmp_path / "x.h5", progress=False, compression="zip")
    with pytest.raises(HamError, match=r"compression = 'lzf' for the paper's \(x, phi\) table"):
        build_table(WorldConfig(), 3, tmp_path / "x.h5", progress=False, compression="lzf")
    assert not (tmp_path / "x.h5").exists()
    with pytest.raises(HamError, match="lookup = 'stream' on .*version-1"):
        GlanceTable.load(build_table(WorldConfig(), 3, tmp_path / "p.h5", progress=False),
                         lookup="stream")  # fmt: skip
    bad = tmp_path / "bad.h5"
    bad.write_bytes(grid_table.read_bytes())
    with h5py.File(bad, "a") as f:
        f["objects/box/pressure"][2, 3, 4] += 1.0
    with pytest.raises(HamError, match="checksum does not match"):
        verify_table(bad)
    with pytest.raises(HamError, match="random object pose .* accepted: online glances"):
        TableSource(GlanceTable.load(grid_table)).glance(
            torch.tensor([0]), torch.zeros(1, 2), (torch.zeros(1),) * 3
        )


# --------------------------------------------------------------------------- training
def test_training_with_the_height_input_resumes_bit_identically(tmp_path):
    config = TrainConfig(
        model=HamConfig(glances=2, height_input=True), steps=4, batch_size=8, eval_every=2,
        eval_batches=2, seed=5,
    )  # fmt: skip
    full = train(config, tmp_path / "full", progress=False)
    train(TrainConfig(**{**config.__dict__, "steps": 2}), tmp_path / "half", progress=False)
    resumed = resume(tmp_path / "half", steps=4, progress=False)
    assert full["history"] == resumed["history"]
    saved = json.loads((tmp_path / "full" / "config.json").read_text())
    assert saved["model"]["height_input"] is True and saved["model"]["pose_dims"] == ["x", "phi"]


def test_grid_table_trains_and_refuses_mismatched_models(tmp_path, grid_table):
    from ham.learn.train import model_for_source

    model = model_for_source(HamConfig(glances=2), str(grid_table), WorldConfig())
    assert model.pose_dims == ("x", "phi")
    m = train(
        TrainConfig(
            model=model, table=str(grid_table), steps=2, batch_size=8, eval_every=2, eval_batches=1
        ),  # fmt: skip
        tmp_path / "run",
        progress=False,
    )
    assert m["steps"] == 2
    from dataclasses import replace

    from ham.learn.train import Run

    one_d = replace(model, pose_dims=("x",))
    with pytest.raises(HamError, match="the model chooses poses over x but glance table .* x,phi"):
        Run.create(TrainConfig(model=one_d, table=str(grid_table), steps=1))


# --------------------------------------------------------------------------- envs
def test_gym_env_height_observation():
    from ham.envs.haptic import HapticGlanceEnv, HapticGlanceVectorEnv

    env = HapticGlanceEnv(glances=2, height=True)
    assert env.observation_space["height"].shape == (1,)
    assert env.action_space["pose"].shape == (2,)
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    r = make_simulator(WorldConfig()).glance([info["object"]], obs["pose"][:1], obs["pose"][1:])
    assert obs["height"][0] == pytest.approx(float(r.z[0]))
    venv = HapticGlanceVectorEnv(3, glances=2)
    obs, _ = venv.reset(seed=0)
    assert set(obs) == {"pressure", "pose"}  # the paper's observation without height=True
    with pytest.raises(HamError, match=r"pose of shape \(3, 3\); accepted: \(3, 2\)"):
        venv.step({"pose": np.zeros((3, 3)), "prediction": np.zeros(3, int)})
    with pytest.raises(HamError, match="^HapticGlanceEnv: height = 1; accepted: true or false$"):
        HapticGlanceEnv(height=1)


def test_the_height_observation_space_holds_a_big_tilted_pad():
    # a 3.2 m pad (16 x 20 cm) tilted to the limit ends 1.6 m up: outside the Box(-1, 1) the
    # space was before; its bound is now the tallest top plus the pad's size
    from ham.envs.haptic import HapticGlanceEnv
    from ham.world.sensor import SensorConfig

    world = WorldConfig(objects="curvature2d", pose_dims=("x", "y", "phi", "phi_y"),
                        sensor=SensorConfig(pitch=0.2))  # fmt: skip
    env = HapticGlanceEnv(glances=2, height=True, world=world)
    env.reset(seed=0)
    obs, *_ = env.step({"pose": np.ones(4), "prediction": 0})
    assert obs["height"][0] > 1.5 and env.observation_space.contains(obs)


def test_baselines_can_tell_objects_apart_by_height(tmp_path):
    from ham.learn.planners import Partitions, Planner

    table = GlanceTable.load(build_table(WorldConfig(), 5, tmp_path / "p5.h5", progress=False))
    plain = Planner(Partitions.from_table(table))
    tall = Planner(Partitions.from_table(table, height=True))
    # at every grid pose the height splits at least what the images split: a refinement
    pairs = zip(tall.parts.grid_action.ravel(), plain.parts.grid_action.ravel(), strict=True)
    for a_t, a_p in pairs:
        t, q = tall.parts.labels[a_t], plain.parts.labels[a_p]
        assert all(q[i] == q[j] for i in range(4) for j in range(4) if t[i] == t[j])
    assert tall.accuracy("random", 1) > plain.accuracy("random", 1)
    assert tall.accuracy("oracle", 1) >= plain.accuracy("oracle", 1)
    assert table.height.shape == (4, 5, 5)
