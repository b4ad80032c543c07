"""The Explorer: a trained HAM driven one glance at a time by glances handed in from outside
gives the very episodes the agent's own loop plays (evaluation's), for every way the first pose
is chosen, with the contact height and with a learned stop."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from ham.errors import HamError
from ham.learn.environment import HapticEnv
from ham.learn.explorer import Explorer
from ham.learn.train import TrainConfig, load_run, train
from ham.model.agent import HamConfig, HapticAttentionModel
from ham.world.config import WorldConfig
from ham.world.source import make_source
from ham.world.table import GlanceTable, build_table, table_info


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    d = tmp_path_factory.mktemp("explorer")
    table = build_table(WorldConfig(), 11, d / "t.h5", progress=False)
    config = TrainConfig(model=HamConfig(glances=3), table=str(table), steps=30, batch_size=16,
                         eval_every=15, eval_batches=2)  # fmt: skip
    train(config, d / "run", progress=False)
    return d / "run"


def _played(agent, env, objects, seed, greedy):
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        return agent.eval()(env, objects, g, greedy=greedy)


def _explored(explorer, env, objects, height=False):
    """One episode per object, each glance's raw image (and height) from ``env``'s source."""
    poses, q = [], explorer.reset()
    while q is not None:
        poses.append(q)
        pressure, h = env.source.glance(objects, q, None)
        q = explorer.observe(pressure, h if height else None)
    return torch.stack(poses)


@pytest.mark.parametrize("policy", ["mean", "sample"])
def test_a_trained_run_explores_as_it_plays(trained, policy):
    run = load_run(trained)
    objects = run.env.balanced_objects(0)
    episode = _played(run.agent, run.env, objects, seed=5, greedy=policy == "mean")
    explorer = Explorer.from_run(trained, episodes=len(objects), policy=policy, seed=5)
    assert explorer.normalization == run.config.normalization and explorer.objects == run.objects
    poses = _explored(explorer, run.env, objects)
    assert torch.equal(poses, episode.locations)
    assert torch.equal(explorer.probabilities, torch.softmax(episode.logits[-1], -1))
    assert torch.equal(explorer.prediction, episode.logits[-1].argmax(-1))
    assert explorer.object_names == [run.objects[i] for i in explorer.prediction.tolist()]
    assert explorer.done and explorer.glances == 3
    # a second episode draws on: poses of its own, the same seed the same again
    again = Explorer.from_run(trained, episodes=len(objects), policy=policy, seed=5)
    _explored(again, run.env, objects)
    assert torch.equal(_explored(again, run.env, objects), _explored(explorer, run.env, objects))
    assert not torch.equal(_explored(again, run.env, objects)[0], poses[0])


@pytest.mark.parametrize(
    "model",
    [
        HamConfig(glances=3, first_glance="learned"),
        HamConfig(glances=3, first_glance="probe"),
        HamConfig(glances=3, height_input=True),
        HamConfig(glances=3, stop=True),
        HamConfig(glances=2, stop=True, stop_input="core", stay_gate=True),
        HamConfig(glances=4, policy="grid"),
    ],
    ids=["learned-first", "probe-first", "height", "stop", "stop-core-gate", "grid"],
)
def test_every_kind_of_episode_explores_as_it_plays(trained, model):
    table = load_run(trained).config.table
    env = HapticEnv(make_source(table, WorldConfig())[0], batch_size=8)
    torch.manual_seed(2)
    agent = HapticAttentionModel(model)
    objects = env.balanced_objects(1)
    episode = _played(agent, env, objects, seed=9, greedy=False)
    explorer = Explorer(agent, episodes=8, policy="sample", seed=9)
    assert torch.equal(_explored(explorer, env, objects, height=model.height_input),
                       episode.locations)  # fmt: skip
    assert torch.equal(explorer.probabilities, torch.softmax(episode.logits[-1], -1))
    if model.stop:
        assert torch.equal(explorer.stop_probability, torch.sigmoid(episode.stop_logits[-1]))
    else:
        assert explorer.stop_probability is None


def test_a_pose_other_than_asked_is_read_as_the_pose(trained):
    """A robot that missed its pose says where it was: the location network reads that pose."""
    explorer = Explorer.from_run(trained, seed=1)
    q = explorer.reset()
    image = torch.zeros(16, 16)
    image[4:6, :] = 1000.0
    asked = explorer.observe(image)
    explorer.reset()
    missed = explorer.observe(image, pose=(q[0] * 0.5).tolist())
    assert not torch.equal(asked, missed)


def test_bad_glances_are_refused_in_one_line(trained):
    explorer = Explorer.from_run(trained, episodes=2)
    with pytest.raises(HamError, match="no glance read yet"):
        explorer.prediction  # noqa: B018
    with pytest.raises(HamError, match=r"observe after 0 of 3 glances; accepted: reset\(\) first"):
        explorer.observe(torch.zeros(2, 16, 16))
    explorer.reset()
    cases = [
        (torch.zeros(16, 16), {}, r"pressure of shape \(16, 16\); accepted: \(2, 16, 16\)"),
        (torch.full((2, 16, 16), float("nan")), {}, "accepted: finite numbers"),
        (-torch.ones(2, 16, 16), {}, r"accepted: pressures >= 0 \(Pa\)"),
        ("text", {}, "accepted: numbers"),
        (torch.zeros(2, 16, 16), {"height": [0.04, 0.04]}, "does not read it"),
        (torch.zeros(2, 16, 16), {"pose": [[2.0, 0.0], [0.0, 0.0]]}, r"poses in \[-1, 1\]"),
    ]
    for pressure, kw, message in cases:
        with pytest.raises(HamError, match=message) as e:
            explorer.observe(pressure, **kw)
        assert "\n" not in str(e.value)
    for _ in range(3):
        explorer.observe(torch.zeros(2, 16, 16))
    with pytest.raises(HamError, match="observe after 3 of 3 glances"):
        explorer.observe(torch.zeros(2, 16, 16))
    height = Explorer(HapticAttentionModel(HamConfig(height_input=True)))
    height.reset()
    with pytest.raises(HamError, match="reads the contact height"):
        height.observe(torch.zeros(16, 16))
    for kw, message in [
        ({"agent": "model"}, "agent = 'model'; accepted: a HapticAttentionModel"),
        ({"normalization": "l3"}, "normalization 'l3'"),
        ({"policy": "greedy"}, "policy 'greedy'; accepted: mean, sample"),
        ({"episodes": 0}, "episodes = 0; accepted: an integer 1"),
        ({"seed": -1}, "seed = -1"),
        ({"objects": ["a"]}, "1 names for 4 classes"),
    ]:
        args = {"agent": HapticAttentionModel(HamConfig()), **kw}
        with pytest.raises(HamError, match=message):
            Explorer(**args)


def test_the_mujoco_example_drives_a_run_with_live_glances(trained):
    """docs/examples/explore_mujoco.py: MuJoCo as the robot, the real engine, one glance at a
    time."""
    script = Path(__file__).resolve().parents[1] / "docs" / "examples" / "explore_mujoco.py"
    r = subprocess.run([sys.executable, str(script), str(trained), "--episodes", "8"],
                       capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    m = re.fullmatch(r"8 episodes, 3 MuJoCo glances each \(taxels read-out\): accuracy (\S+)\n",
                     r.stdout)  # fmt: skip
    assert m and 0.0 <= float(m[1]) <= 1.0


def test_the_sim_to_real_example_records_fine_tunes_and_explores(trained, tmp_path):
    """docs/examples/sim_to_real.py: MuJoCo as the pad; its glances recorded one at a time are
    MuJoCo's built table's, the run fine-tuned on them starts from the trained run, and both
    explore the pad live; a second call reuses what the first made."""
    import json

    script = Path(__file__).resolve().parents[1] / "docs" / "examples" / "sim_to_real.py"
    cmd = [sys.executable, str(script), str(trained), str(tmp_path / "s2r"), "--grid", "3",
           "--steps", "2", "--episodes", "8", "--sensor", "taxels"]  # fmt: skip
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    pattern = (r"8 live episodes on the pad \(MuJoCo, taxels read-out\): (\S+) trained in "
               r"simulation, (\S+) fine-tuned on 3 x 3 recorded glances per object \(2 steps\)\n")  # fmt: skip
    m = re.fullmatch(pattern, r.stdout)
    assert m and all(0.0 <= float(v) <= 1.0 for v in m.groups())
    built = build_table(WorldConfig(simulator="mujoco"), 3, tmp_path / "mj3.h5", progress=False)
    recorded = GlanceTable.load(tmp_path / "s2r" / "recorded.h5")
    assert torch.equal(recorded.pressure, GlanceTable.load(built).pressure)
    config = json.loads((tmp_path / "s2r" / "fine_tuned" / "config.json").read_text())
    assert config["init_from"] == str(trained) and config["steps"] == 2
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0 and again.stdout == r.stdout
    other = [*cmd[:-1], "gazebo"]  # the first call's files are not the gazebo pad's: refused
    refused = subprocess.run(other, capture_output=True, text=True, timeout=300)
    assert refused.returncode == 1 and refused.stdout == ""
    assert refused.stderr.strip().endswith("was made with other arguments (sensor: 'taxels' -> "
                                           "'gazebo'); accepted: the same SIM_RUN and arguments, "
                                           "or another OUT")  # fmt: skip
    assert len(refused.stderr.strip().splitlines()) == 1


def test_the_sim_to_real_example_fine_tunes_on_the_calibrated_table(trained, tmp_path):
    """--calibrate K: the run's own table carried onto the pad by a read-out fitted to the
    recorded glances is what it fine-tunes on; a run trained online gets its world's table
    first (--sim-grid)."""
    import json

    script = Path(__file__).resolve().parents[1] / "docs" / "examples" / "sim_to_real.py"
    online = tmp_path / "online"
    train(TrainConfig(model=HamConfig(glances=2), steps=2, batch_size=4, eval_every=2,
                      eval_batches=1), online, progress=False)  # fmt: skip
    for run, grid, only in ((trained, 11, None), (online, 5, None), (trained, 11, "convex,box")):
        out = tmp_path / f"s2r_{run.name}_{only}"
        cmd = [sys.executable, str(script), str(run), str(out), "--grid", "3", "--steps", "2",
               "--episodes", "8", "--calibrate", "3", "--sim-grid", "5", "--json"]  # fmt: skip
        cmd += [] if only is None else ["--record-objects", only]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        glances = 36 if only is None else 18  # 9 per object recorded
        assert re.match(rf"a 3 x 3 read-out fitted to {glances} recorded glances explains "
                        r"0\.\d{3} ", r.stdout), r.stdout  # fmt: skip
        assert "(2 steps, calibrated)" in r.stdout
        info = table_info(out / "calibrated.h5")
        assert info.simulator["simulator"] == "calibrated" and info.grid == grid
        assert len(info.objects) == 4 and (out / "recorded.h5").exists() == (only is None)
        if only:
            assert info.simulator["recorded_objects"] == ["convex", "box"]
        assert (out / "simulated.h5").exists() == (run == online)
        config = json.loads((out / "fine_tuned" / "config.json").read_text())
        assert config["table"] == str((out / "calibrated.h5").resolve())
        assert json.loads((out / "live.json").read_text())["calibrate"] == 3
    # a read-out fitted before (the trained run's calibration) carries the online run's table
    fitted = tmp_path / "s2r_run_None" / "calibrated.h5"
    carried = [*cmd[:2], str(online), str(tmp_path / "carried"), "--grid", "3", "--steps", "2",
               "--episodes", "8", "--sim-grid", "5", "--readout-from", str(fitted)]  # fmt: skip
    r = subprocess.run(carried, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "of their variance (0." in r.stdout and f"(from {fitted})" in r.stdout
    assert "fine-tuned on its table carried by a read-out fitted before (2 steps)" in r.stdout
    assert not (tmp_path / "carried" / "recorded.npz").exists()
    assert table_info(tmp_path / "carried" / "calibrated.h5").simulator["readout_from"] == (
        "calibrated.h5"
    )
    both = subprocess.run([*carried[:3], str(tmp_path / "both"), *carried[4:], "--calibrate", "3"],
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert both.returncode == 1 and "--readout-from with --calibrate" in both.stderr
    alone = [*cmd[:3], str(tmp_path / "alone"), "--record-objects", "box"]
    refused = subprocess.run(alone, capture_output=True, text=True, timeout=300)
    assert refused.returncode == 1 and not (tmp_path / "alone").exists()
    assert refused.stderr.strip() == ("sim_to_real: error: --record-objects without --calibrate; "
                                      "accepted: it with --calibrate (fine-tuning on the "
                                      "recorded glances alone needs every object)")  # fmt: skip


def test_the_sim_to_real_example_misses_poses_as_a_robot_would(trained, tmp_path):
    """--pad-pose-noise S: the pad glances near the poses asked for, the same errors for the
    same seed (a second OUT gives the same numbers); a negative S is refused in one line."""
    import numpy as np

    script = Path(__file__).resolve().parents[1] / "docs" / "examples" / "sim_to_real.py"
    runs = []
    for out in ("a", "b"):
        cmd = [sys.executable, str(script), str(trained), str(tmp_path / out), "--grid", "3",
               "--steps", "2", "--episodes", "8", "--sensor", "taxels", "--pad-pose-noise",
               "0.2"]  # fmt: skip
        runs.append(subprocess.run(cmd, capture_output=True, text=True, timeout=300))
        assert runs[-1].returncode == 0, runs[-1].stderr
    assert runs[0].stdout == runs[1].stdout
    built = build_table(WorldConfig(simulator="mujoco"), 3, tmp_path / "mj3.h5", progress=False)
    exact = GlanceTable.load(built).pressure
    with (
        np.load(tmp_path / "a" / "recorded.npz") as a,
        np.load(tmp_path / "b" / "recorded.npz") as b,
    ):
        assert np.array_equal(a["box"], b["box"])
        missed = [not np.array_equal(a[n], exact[i].numpy()) for i, n in enumerate(("box",
                  "ramp_up", "convex", "ramp_down"))]  # fmt: skip
    assert all(missed)
    cmd[-1], cmd[3] = "-0.1", str(tmp_path / "c")
    refused = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert refused.returncode == 1 and not (tmp_path / "c").exists()
    assert refused.stderr.strip() == ("sim_to_real: error: --pad-pose-noise -0.1; accepted: a "
                                      "finite number >= 0")  # fmt: skip


def test_a_run_on_ap_gym_is_refused_before_its_world_loads(tmp_path):
    from ham.learn.ap_adapter import ApGymConfig
    from ham.world.files import write_json

    config = TrainConfig(env=ApGymConfig("ap_gym:CircleSquare-s15-nograd-v0"))
    write_json(tmp_path / "config.json", config.to_dict())  # no checkpoint: never read
    with pytest.raises(HamError, match="trained on ap_gym env 'ap_gym:CircleSquare-s15-nograd-v0'"):
        Explorer.from_run(tmp_path)
