"""Gymnasium / ap_gym environments over the haptic world (ham.envs) and the HAM on ap_gym
environments (ham.learn.ap_adapter): real Gymnasium checker, real ap_gym, real training."""

from __future__ import annotations

import json
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

import ham.envs
from ham.envs import AP_ENV_ID, AP_SPARSE_ENV_ID, ENV_ID, HapticGlanceEnv, HapticGlanceVectorEnv
from ham.errors import HamError
from ham.world.config import WorldConfig
from ham.world.table import build_table

GRID = 11


@pytest.fixture(scope="module")
def ap_gym():
    return pytest.importorskip(
        "ap_gym", reason="ap_gym is not installed (pip install ap-gym aiohttp)"
    )


@pytest.fixture(scope="module")
def ap(ap_gym):
    from ham.envs import ap

    return ap


@pytest.fixture(scope="module")
def table_path(tmp_path_factory):
    return str(
        build_table(WorldConfig(), GRID, tmp_path_factory.mktemp("t") / "t.h5", progress=False)
    )


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


# --------------------------------------------------------------------------- registration
def test_ids_are_registered_on_import():
    for env_id in (ENV_ID, AP_ENV_ID, AP_SPARSE_ENV_ID):
        assert env_id in gym.registry
    ham.envs.register_envs()  # again: no error, no duplicate


# --------------------------------------------------------------------------- env checker
@pytest.mark.parametrize("source", ["online", "table"])
def test_gymnasium_env_checker_passes(source, table_path):
    table = table_path if source == "table" else None
    check_env(HapticGlanceEnv(glances=3, table=table, render_mode="rgb_array"))


@pytest.mark.parametrize("source", ["online", "table"])
def test_gymnasium_env_checker_passes_on_the_ap_gym_envs(source, table_path, ap):
    table = table_path if source == "table" else None
    check_env(ap.HapticGlanceAPEnv(glances=3, table=table))
    check_env(ap.make_sparse_env(glances=3, table=table))


def test_plain_episode_semantics_and_reward():
    env = gym.make(ENV_ID, glances=4, normalization="l2")
    obs, info = env.reset(seed=3, options={"object": 2})
    assert info["object"] == 2 and info["object_name"] == "convex" and info["glances"] == 1
    assert env.observation_space.contains(obs)
    assert obs["pressure"].shape == (16, 16) and obs["pressure"].dtype == np.float32
    norm = np.linalg.norm(obs["pressure"])
    assert norm == pytest.approx(1.0, abs=1e-5) or norm == 0.0  # L2-normalized (or no contact)
    rewards, terminated = [], False
    steps = 0
    while not terminated:
        q = np.array([0.1 * steps, -0.2], np.float32)
        obs, r, terminated, truncated, info = env.step({"pose": q, "prediction": 2})
        steps += 1
        rewards.append(r)
        if not terminated:
            np.testing.assert_allclose(obs["pose"], q)  # the glance was made where asked
    assert steps == 4 and info["glances"] == 4 and rewards == [0.0, 0.0, 0.0, 1.0]
    env.reset(seed=3, options={"object": 2})
    for _ in range(4):
        *_, r, terminated, _, _ = env.step({"pose": np.zeros(2, np.float32), "prediction": 1})
    assert terminated and r == 0.0


def test_raw_pressure_and_bad_input_is_named():
    env = HapticGlanceEnv(glances=2, normalization="none")
    obs, _ = env.reset(seed=0, options={"object": 0})
    obs, *_ = env.step({"pose": np.array([0.0, 0.0]), "prediction": 0})
    assert obs["pressure"].sum() > 1.0  # raw Pa, not normalized
    with pytest.raises(HamError, match="nan"):
        env.step({"pose": np.array([np.nan, 0.0]), "prediction": 0})
    for pose in (["0.5", "0.1"], [True, False]):  # a string or a flag is no number (was cast)
        with pytest.raises(HamError, match=r"accepted: 1 x 2 numbers in \[-1, 1\]"):
            env.step({"pose": pose, "prediction": 0})
    with pytest.raises(HamError, match=r"object id 7 out of range; accepted: 0\.\.3"):
        env.step({"pose": np.zeros(2), "prediction": 7})
    with pytest.raises(HamError, match="normalization = 'l3'"):
        HapticGlanceEnv(normalization="l3")
    with pytest.raises(HamError, match="glances = 0"):
        HapticGlanceEnv(glances=0)
    with pytest.raises(
        HamError, match=r"object_pose has unknown fields \['yaw'\]; accepted: yaw_max"
    ):
        HapticGlanceEnv(object_pose={"yaw": 0.1})
    env.step({"pose": np.zeros(2), "prediction": 0})
    with pytest.raises(HamError, match="after the episode ended"):
        env.step({"pose": np.zeros(2), "prediction": 0})


def test_vector_env_is_batched_and_autoresets(table_path):
    n, s = 16, 3
    envs = gym.make_vec(ENV_ID, num_envs=n, glances=s, table=table_path)
    assert isinstance(envs.unwrapped, HapticGlanceVectorEnv)
    obs, info = envs.reset(seed=0, options={"objects": np.arange(n) % 4})
    np.testing.assert_array_equal(info["object"], np.arange(n) % 4)
    single = HapticGlanceEnv(glances=s, table=table_path)
    for step in range(s):
        act = {"pose": np.full((n, 2), 0.5, np.float32), "prediction": np.arange(n) % 4}
        obs, r, terminated, truncated, info = envs.step(act)
        assert envs.observation_space.contains(obs)
        assert terminated.all() == (step == s - 1)
    np.testing.assert_array_equal(r, np.ones(n))  # every prediction was the object
    # a sub-environment sees what the single environment sees at the same pose
    single.reset(seed=0, options={"object": 1})
    sobs, *_ = single.step({"pose": np.full(2, 0.5, np.float32), "prediction": 0})
    np.testing.assert_allclose(obs["pressure"][1], sobs["pressure"], atol=1e-6)
    obs, r, terminated, truncated, info = envs.step(envs.action_space.sample())  # NEXT_STEP reset
    assert not terminated.any() and (r == 0).all() and (info["glances"] == 1).all()


# --------------------------------------------------------------------------- ap_gym
def test_random_policy_episode_through_ap_gym_make(ap_gym):
    for env_id, dense in ((AP_ENV_ID, True), (AP_SPARSE_ENV_ID, False)):
        env = ap_gym.make(env_id, glances=3)
        obs, info = env.reset(seed=1)
        target = info["prediction"]["target"]  # the -sparse wrapper needs it at reset
        if not dense:
            target = target["target"]
        assert isinstance(target, np.ndarray) and target.dtype == np.int64
        env.action_space.seed(1)
        rewards, done = [], False
        while not done:
            obs, r, terminated, truncated, info = env.step(env.action_space.sample())
            rewards.append(float(r))
            done = terminated or truncated
        assert len(rewards) == 3 and all(r <= 1e-9 for r in rewards)
        if dense:
            assert all(r < 0 for r in rewards)  # base 0 minus a cross-entropy
        else:
            assert rewards[:2] == [0.0, 0.0] and rewards[2] < 0  # only the last is scored
        assert "stats" in info  # ap_gym's classification log wrapper reports the episode


def test_perfect_prediction_scores_zero_and_blind_guess_minus_one(ap_gym):
    env = ap_gym.make(AP_ENV_ID, glances=2)
    obs, info = env.reset(seed=0)
    target = int(info["prediction"]["target"])
    logits = np.full(4, -1e3, np.float32)
    logits[target] = 1e3
    _, r, *_ = env.step({"action": np.zeros(2, np.float32), "prediction": logits})
    assert r == pytest.approx(0.0, abs=1e-6)
    _, r, terminated, *_ = env.step(
        {"action": np.zeros(2, np.float32), "prediction": np.zeros(4, np.float32)}
    )
    assert terminated and r == pytest.approx(-1.0, abs=1e-6)


def test_random_policy_episodes_through_ap_gym_make_vec(ap_gym, ap):
    n = 8
    for env_id in (AP_ENV_ID, AP_SPARSE_ENV_ID):
        envs = ap_gym.make_vec(env_id, num_envs=n, glances=3)
        assert isinstance(envs.unwrapped, ap.HapticGlanceAPVectorEnv)
        obs, info = envs.reset(seed=0)
        envs.action_space.seed(0)
        for _ in range(3):
            obs, r, terminated, truncated, info = envs.step(envs.action_space.sample())
            assert r.shape == (n,) and envs.observation_space.contains(obs)
        assert terminated.all()
        obs, r, terminated, truncated, info = envs.step(envs.action_space.sample())
        assert not terminated.any()  # auto-reset
        envs.close()


# --------------------------------------------------------------------------- HAM on ap_gym
def test_adapter_presents_an_ap_gym_env_like_haptic_env(ap_gym):
    from ham.learn.ap_adapter import TELEPORT_STEP, ApGymGlanceEnv

    env = ApGymGlanceEnv(
        "ap_gym:CircleSquare-s15-nograd-v0", 8, max_step_length=TELEPORT_STEP, seed=1
    )
    assert (env.n_objects, env.pressure_dim, env.step_limit) == (2, 25, 16)
    labels = env.sample_objects()
    assert labels.dtype == torch.long and labels.shape == (8,)
    x = env.glance(labels, torch.zeros(8, 2))  # the reset glimpse, at a random position
    assert x.shape == (8, 25)
    q = torch.tensor([[0.5, -0.25]]).repeat(8, 1)
    env.glance(labels, q)
    torch.testing.assert_close(env.observed_location, q)  # absolute + teleport: exactly there
    rel = ApGymGlanceEnv("CircleSquare-s15-nograd-v0", 8, actions="relative", seed=1)
    labels = rel.sample_objects()
    rel.glance(labels, torch.zeros(8, 2))
    start = rel.observed_location.clone()
    rel.glance(labels, torch.tensor([[1.0, 0.0]]).repeat(8, 1))  # the registered step: 0.2
    moved = rel.observed_location - start
    assert torch.all(moved[:, 0] <= 0.2 + 1e-6) and torch.all(moved[:, 1].abs() < 1e-6)
    assert torch.any(moved[:, 0] > 0.19)  # not clipped at the border for most
    rel.close()
    with pytest.raises(HamError, match="glances = 20; accepted"):
        env.check_glances(20)
    with pytest.raises(HamError, match="actions = 'sideways'"):
        ApGymGlanceEnv("CircleSquare-s15-nograd-v0", 2, actions="sideways")
    with pytest.raises(HamError, match="not registered"):
        ApGymGlanceEnv("ap_gym:NoSuchEnv-v0", 2)
    env.close()


def test_a_step_length_too_short_for_float32_moves_the_glimpse_by_it(ap_gym):
    """With ``max_step_length=1e-300`` an absolute move of 0.5 is 5e299 steps, inf in float32:
    ap_gym's cap made it inf / inf = NaN and its glimpse lookup failed (a traceback). The move
    is capped here as ap_gym caps it (one step), so the glimpse moves by the step length."""
    from ham.learn.ap_adapter import ApGymGlanceEnv

    env = ApGymGlanceEnv("CircleSquare-s15-nograd-v0", 4, max_step_length=1e-300, seed=1)
    labels = env.sample_objects()
    env.glance(labels, torch.zeros(4, 2))
    start = env.observed_location.clone()
    x = env.glance(labels, torch.tensor([[0.5, -0.5]]).repeat(4, 1))
    assert torch.isfinite(x).all()
    torch.testing.assert_close(env.observed_location, start)  # moved by 1e-300 at most
    env.close()


def test_ham_trains_on_an_offline_ap_gym_env_and_beats_random_locations(ap_gym, tmp_path):
    """A short real run through the HAM's own training loop on ap_gym's CircleSquare (15 x 15
    px, no gradient; built locally, no download). Both agents: 2 glances, the same seed,
    steps, batches and learning rate; the baseline draws its second glance uniformly (the
    paper's random-location model). Measured (docs/gym.md): learned 0.688 vs random 0.617 with
    this seed; seeds 0 and 2 lead too (0.730 vs 0.677, 0.680 vs 0.677)."""
    from ham.learn.ap_adapter import TELEPORT_STEP, ApGymConfig
    from ham.learn.train import TrainConfig, fit_to_ap_gym, train
    from ham.model.agent import HamConfig

    env = ApGymConfig("ap_gym:CircleSquare-s15-nograd-v0", max_step_length=TELEPORT_STEP)
    runs = {}
    for policy in ("learned", "random"):
        config = TrainConfig(model=HamConfig(glances=2, policy=policy), steps=400, batch_size=32,
                             lr=0.003, eval_every=400, eval_batches=20, seed=1)  # fmt: skip
        runs[policy] = train(fit_to_ap_gym(config, env), tmp_path / policy, progress=False)
    learned, baseline = runs["learned"], runs["random"]
    env_id = env.env
    assert learned["steps"] == baseline["steps"] == 400
    assert (tmp_path / "learned" / "checkpoint.pt").exists()
    assert learned["config"]["normalization"] == "l2"  # the glimpse L2-normalized, as a pressure
    assert learned["config"]["env"]["env"] == env_id
    assert learned["config"]["model"]["pressure_dim"] == 25
    chance = learned["history"][0]["accuracy"]
    assert learned["final_accuracy"] > chance + 0.1  # it learned to classify
    assert learned["final_accuracy"] > baseline["final_accuracy"]  # and where to look


def test_a_sparse_variant_trains_the_ham_as_its_dense_one(ap_gym, tmp_path):
    """The HAM trains on its own reward (docs/gym.md); a ``-sparse`` variant changes only the
    env's reward and prediction weights, so the same seed must give the same run, number for
    number (measured at 250k steps on CircleSquare-sparse-v0: docs/learners.md)."""
    from ham.learn.ap_adapter import TELEPORT_STEP, ApGymConfig
    from ham.learn.train import TrainConfig, fit_to_ap_gym, train
    from ham.model.agent import HamConfig

    runs = {}
    for env_id in ("CircleSquare-s15-nograd-v0", "CircleSquare-s15-nograd-sparse-v0"):
        env = ApGymConfig(f"ap_gym:{env_id}", max_step_length=TELEPORT_STEP)
        config = TrainConfig(model=HamConfig(glances=2), steps=20, batch_size=8, lr=0.003,
                             eval_every=10, eval_batches=4, seed=3)  # fmt: skip
        runs[env_id] = train(fit_to_ap_gym(config, env), tmp_path / env_id, progress=False)
    dense, sparse = runs.values()
    assert sparse["config"]["env"]["env"] == "ap_gym:CircleSquare-s15-nograd-sparse-v0"
    assert [h["accuracy"] for h in sparse["history"]] == [h["accuracy"] for h in dense["history"]]
    assert sparse["history"][-1]["train_loss"] == dense["history"][-1]["train_loss"]
    assert len(dense["history"]) == 3


def test_cli_lists_environments(ap_gym, ham_cli):
    import json

    r = ham_cli("envs", "list", "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert [e["id"] for e in d["ham"]] == [ENV_ID, AP_ENV_ID, AP_SPARSE_ENV_ID]
    offline = {e["id"] for e in d["ap_gym"] if e["offline"]}
    assert "CircleSquare-s15-nograd-v0" in offline and "MNIST-v0" not in offline


CS15 = "ap_gym:CircleSquare-s15-nograd-v0"


def test_adapter_batches_follow_the_seed_and_the_batch_index(ap_gym):
    from ham.learn.ap_adapter import ApGymGlanceEnv

    def first_glimpses(env, n):
        out = []
        for _ in range(n):
            labels = env.sample_objects()
            out.append((labels, env.glance(labels, torch.zeros(4, 2))))
        return out

    a, b = ApGymGlanceEnv(CS15, 4, seed=7), ApGymGlanceEnv(CS15, 4, seed=7)
    first = first_glimpses(a, 3)
    state = b.state_dict()
    assert state["batches"] == 0
    first_glimpses(b, 2)
    b.load_state_dict(a.state_dict())  # b continues where a is: at batch 3
    later_a, later_b = first_glimpses(a, 2), first_glimpses(b, 2)
    for (la, ga), (lb, gb) in zip(later_a, later_b, strict=True):
        assert torch.equal(la, lb) and torch.equal(ga, gb)
    assert not torch.equal(first[0][1], first[1][1])  # a fresh batch every step
    with pytest.raises(HamError, match="no batch count"):
        b.load_state_dict({"settings": b.settings()})
    a.close()
    b.close()


def _ap_config(**kw):
    from ham.learn.ap_adapter import TELEPORT_STEP, ApGymConfig
    from ham.learn.train import TrainConfig, fit_to_ap_gym
    from ham.model.agent import HamConfig

    base = dict(model=HamConfig(glances=2), steps=6, batch_size=8, eval_every=2, eval_batches=2,
                seed=2, lr=0.003)  # fmt: skip
    base.update(kw)
    return fit_to_ap_gym(TrainConfig(**base), ApGymConfig(CS15, max_step_length=TELEPORT_STEP))


def test_ap_gym_config_round_trip_and_bad_values(ap_gym):
    from ham.learn.ap_adapter import ApGymConfig
    from ham.learn.train import TrainConfig

    c = _ap_config()
    assert (c.model.n_objects, c.model.pressure_dim, c.model.phi_scale) == (2, 25, 1.0)
    assert TrainConfig.from_dict(json.loads(json.dumps(c.to_dict()))) == c
    with pytest.raises(HamError, match="actions = 'sideways'"):
        ApGymConfig(CS15, actions="sideways")
    with pytest.raises(HamError, match="max_step_length = -1"):
        ApGymConfig(CS15, max_step_length=-1)
    with pytest.raises(HamError, match="exclude each other"):
        TrainConfig(table="t.h5", env=ApGymConfig(CS15))
    with pytest.raises(HamError, match="unknown fields"):
        ApGymConfig.from_dict({"env": CS15, "glimpse_size": 5})


def test_ap_gym_resume_gives_the_same_numbers(ap_gym, tmp_path):
    """The pattern of tests/test_train.py on ap_gym: a run stopped at step 2 and resumed to 6
    has every number of the uninterrupted run, weights included."""
    from ham.learn.train import load_run, resume, train

    full = train(_ap_config(steps=6), tmp_path / "full", progress=False)
    train(_ap_config(steps=2), tmp_path / "half", progress=False)
    resumed = resume(tmp_path / "half", steps=6, progress=False)
    assert resumed == full  # bit-identical: every float in the history
    assert full["history"][-1]["train_loss"] != full["history"][1]["train_loss"]
    a, b = load_run(tmp_path / "full"), load_run(tmp_path / "half")
    for (n, p), (_, q) in zip(
        a.agent.state_dict().items(), b.agent.state_dict().items(), strict=True
    ):
        assert torch.equal(p, q), n
    a.close()
    b.close()


def ham_inprocess(capsys, *args: str) -> tuple[int, str, str]:
    """The same ``ham`` command line, run in this process (no second import of ap_gym)."""
    from ham.cli.main import main

    try:
        code = main(list(args))
    except SystemExit as exc:  # argparse refuses the command line
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def test_ham_train_env_flag_resumes_and_evaluates(ap_gym, ham_cli, tmp_path, capsys):
    """``ham train --env``: a real run in a subprocess, resumed to the numbers of a run that was
    not interrupted; ``ham evaluate`` on it; bad command lines as one-line errors."""
    from ham.learn.train import TrainConfig, train

    out = tmp_path / "run"
    r = ham_cli(
        "train", "--env", CS15, "--glances", "2", "--eval-every", "3", "--eval-batches", "1",
        "--batch-size", "8", "--max-step-length", "teleport", "--no-progress", "--threads", "1",
        "--steps", "3", "--out", str(out),
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    config = TrainConfig.from_dict(json.loads((out / "config.json").read_text()))
    assert config.env.max_step_length == pytest.approx(2 * 2**0.5)
    assert (config.model.pressure_dim, config.model.n_objects, config.normalization) == (
        25,
        2,
        "l2",
    )
    code, _, err = ham_inprocess(capsys, "train", "--resume", str(out), "--steps", "6",
                                 "--no-progress")  # fmt: skip
    assert code == 0, err
    full = train(TrainConfig.from_dict({**config.to_dict(), "steps": 6}), tmp_path / "full",
                 progress=False)  # fmt: skip
    assert json.loads((out / "metrics.json").read_text()) == full  # bit-identical

    code, stdout, err = ham_inprocess(capsys, "evaluate", str(out), "--batches", "2", "--json")
    assert code == 0, err
    d = json.loads(stdout)
    assert d["objects"] == ["0", "1"] and d["episodes"] == 16
    assert sum(map(sum, d["confusion"][-1])) == 16
    code, _, err = ham_inprocess(capsys, "evaluate", str(out), "--swap-last-pose")
    assert code == 2 and "accepted: a haptic world" in err and len(err.strip().splitlines()) == 1

    code, _, err = ham_inprocess(capsys, "train", "--resume", str(out), "--env", CS15)
    assert code == 2 and "remove --env" in err
    code, _, err = ham_inprocess(capsys, "train", "--env", "ap_gym:NoSuchEnv-v0", "--out",
                                 str(tmp_path / "x"))  # fmt: skip
    assert code == 2 and "'NoSuchEnv-v0' is not registered" in err
    assert not (tmp_path / "x").exists()  # a refused run leaves no directory behind
    code, _, err = ham_inprocess(capsys, "train", "--env", CS15, "--table", "t.h5", "--out", "x")
    assert code == 2 and "not allowed with argument --env" in err
    code, _, err = ham_inprocess(capsys, "train", "--actions", "relative", "--out", "z")
    assert code == 2 and "--actions apply only with --env" in err
    code, _, err = ham_inprocess(capsys, "envs", "train", CS15, "--out", "y")
    assert code == 2 and "invalid choice: 'train'" in err  # ham train --env does it


def test_a_pytorch_agent_may_hand_tensors(tmp_path):
    # an agent in PyTorch hands its actions as tensors, often still in its graph: read detached
    # (before: "Can't call numpy() on Tensor that requires grad", a traceback); a tensor
    # without data is refused in one line
    env = HapticGlanceEnv(glances=3)
    pose = np.array([0.25, -0.5], dtype=np.float32)
    env.reset(seed=1)
    want, *_ = env.step({"pose": pose, "prediction": 0})
    env.reset(seed=1)
    got, *_ = env.step(
        {"pose": torch.tensor(pose, requires_grad=True) * 1, "prediction": torch.tensor(0)}
    )
    assert np.array_equal(got["pressure"], want["pressure"]) and np.array_equal(got["pose"], pose)
    env.reset(seed=1)
    got, *_ = env.step({"pose": torch.tensor(pose, dtype=torch.bfloat16), "prediction": 0})
    assert np.array_equal(got["pose"], torch.tensor(pose, dtype=torch.bfloat16).float().numpy())
    with pytest.raises(HamError, match=r"^pose tensor\(\.\.\., device='meta'"):
        env.step({"pose": torch.zeros(2, device="meta"), "prediction": 0})
