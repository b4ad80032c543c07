"""Stable-Baselines3 agents as baselines, through the supervised-prediction wrapper (real SB3,
real ap_gym environments)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("ap_gym")

from ham.errors import HamError  # noqa: E402
from ham.learn.sb3_agents import (  # noqa: E402
    Sb3Config,
    SupervisedPrediction,
    evaluate_agent,
    make_env,
    resume_sb3,
    train_sb3,
)


def test_wrapper_shows_the_history_and_predicts_from_the_head():
    env = SupervisedPrediction(make_env("ham/HapticGlanceAP-v0", {"glances": 3}))
    obs, _ = env.reset(seed=0)
    assert env.horizon == 3 and obs.shape == env.observation_space.shape
    d = env.step_dim
    assert np.any(obs[:d]) and not np.any(obs[d : 3 * d])  # only the first glance so far
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert np.any(obs[d : 2 * d]) and isinstance(info["correct"], bool)
    assert np.isfinite(reward) and env.head.size == 1


def test_evaluation_leaves_the_head_alone():
    """Evaluation episodes repeat with their seeds: a head that learned from them could memorize
    them (pose -> object) and score above the Bayes bound."""
    import torch

    env = SupervisedPrediction(make_env("ham/HapticGlanceAP-v0", {"glances": 2}))
    env.head.batch = 8

    class RandomGlances:
        def predict(self, obs, deterministic=True):
            return env.action_space.sample(), None

    before = [p.detach().clone() for p in env.head.parameters()]
    m = evaluate_agent(RandomGlances(), env, 40, seed=0)
    assert len(m["accuracy_per_glance"]) == 2 and env.learning
    assert env.head.size == 0 and env.steps == 0
    assert all(torch.equal(a, b) for a, b in zip(before, env.head.parameters(), strict=True))


def test_the_same_wrapper_serves_ap_gym():
    env = SupervisedPrediction(make_env("ap_gym:CircleSquare-v0"))
    assert env.horizon == 16 and env.n_classes == 2
    env.reset(seed=0)
    env.step(env.action_space.sample())


@pytest.mark.parametrize(
    ("algo", "kwargs"),
    [
        ("ppo", {"n_steps": 64, "batch_size": 32, "n_epochs": 1}),
        ("sac", {"learning_starts": 32, "batch_size": 32}),
        ("crossq", {"learning_starts": 32, "batch_size": 32}),
    ],
)
def test_train_writes_metrics_with_env_steps(tmp_path, monkeypatch, algo, kwargs):
    import tempfile

    config = Sb3Config(
        algo=algo, env="ham/HapticGlanceAP-v0", env_kwargs={"glances": 2}, env_steps=128,
        eval_every=64, eval_episodes=8, algo_kwargs=kwargs,
    )  # fmt: skip
    (tmp_path / "temp").mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "temp"))
    m = train_sb3(config, tmp_path / algo)
    # SB3's default logger made an empty SB3-<time> folder in the temp dir at each run
    assert not list((tmp_path / "temp").glob("SB3-*"))
    saved = json.loads((tmp_path / algo / "metrics.json").read_text())
    assert saved["env_steps"] == m["env_steps"] >= 128
    assert 0 <= saved["final_accuracy"] <= 1 and len(saved["accuracy_per_glance"]) == 2
    assert [h["env_steps"] for h in saved["history"]] == [64, 128]
    assert (tmp_path / algo / "model.zip").is_file() and (tmp_path / algo / "head.pt").is_file()
    assert not list((tmp_path / algo).glob("*.tmp"))
    progress = json.loads((tmp_path / algo / "history.json").read_text())
    assert progress["history"] == saved["history"] and progress["env_steps"] == 128


def _interrupted_at(n: int):
    """``evaluate_agent`` that raises KeyboardInterrupt at its ``n``-th call: a run killed there."""
    calls = []

    def evaluate(*args, **kwargs):
        calls.append(1)
        if len(calls) == n:
            raise KeyboardInterrupt
        return evaluate_agent(*args, **kwargs)

    return evaluate


def test_a_run_stopped_early_leaves_its_history_so_far(tmp_path, monkeypatch):
    """A long run killed before its end: the evaluations so far are in history.json, and no
    metrics.json pretends to be the final result."""
    from ham.learn import sb3_agents

    monkeypatch.setattr(sb3_agents, "evaluate_agent", _interrupted_at(2))
    config = Sb3Config(
        algo="sac", env="ham/HapticGlanceAP-v0", env_kwargs={"glances": 2}, env_steps=128,
        eval_every=64, eval_episodes=8, algo_kwargs={"learning_starts": 32, "batch_size": 32},
    )  # fmt: skip
    with pytest.raises(KeyboardInterrupt):
        train_sb3(config, tmp_path / "run")
    progress = json.loads((tmp_path / "run" / "history.json").read_text())
    assert progress["env_steps"] == 64 and [h["env_steps"] for h in progress["history"]] == [64]
    assert 0 <= progress["history"][0]["final_accuracy"] <= 1 and progress["seed"] == 0
    assert not (tmp_path / "run" / "metrics.json").exists()


SMALL = {"policy_kwargs": {"net_arch": [64, 64]}}  # the mechanics, not the defaults' width


@pytest.mark.parametrize(
    ("algo", "kwargs", "env"),
    [
        ("ppo", {"n_steps": 64, "batch_size": 32, "n_epochs": 1}, "ham/HapticGlanceAP-v0"),
        ("sac", {"learning_starts": 32, "batch_size": 32, **SMALL}, "ham/HapticGlanceAP-v0"),
        ("crossq", {"learning_starts": 32, "batch_size": 32, **SMALL}, "ham/HapticGlanceAP-v0"),
        # ap_gym's image environments draw their images on a thread (made to draw in step)
        ("sac", {"learning_starts": 32, "batch_size": 32, **SMALL}, "ap_gym:CircleSquare-v0"),
    ],
)
def test_an_interrupted_run_resumes_bit_identically(tmp_path, monkeypatch, algo, kwargs, env):
    """Killed at its third evaluation, resumed from the checkpoint of the second: the same
    curve, agent and head as the run never stopped (replay buffer, optimizers, environments and
    the global generators all restored)."""
    import torch
    from stable_baselines3.common.save_util import load_from_zip_file

    from ham.learn import sb3_agents

    config = Sb3Config(
        algo=algo, env=env, env_kwargs={"glances": 2} if env.startswith("ham/") else {},
        env_steps=192, eval_every=64, eval_episodes=8, algo_kwargs=kwargs,
    )  # fmt: skip
    straight = train_sb3(config, tmp_path / "straight")

    monkeypatch.setattr(sb3_agents, "evaluate_agent", _interrupted_at(3))
    with pytest.raises(KeyboardInterrupt):
        train_sb3(config, tmp_path / "cut")
    monkeypatch.setattr(sb3_agents, "evaluate_agent", evaluate_agent)
    torch.manual_seed(12345)  # the resumed run must not depend on the process's generators
    np.random.seed(12345)  # noqa: NPY002 - SB3 draws from the legacy global generator
    resumed = resume_sb3(tmp_path / "cut")

    def curve(m):
        return [(h["env_steps"], h["accuracy_per_glance"]) for h in m["history"]]

    assert curve(resumed) == curve(straight) and len(curve(straight)) == 3
    assert resumed["accuracy_per_glance"] == straight["accuracy_per_glance"]
    a = load_from_zip_file(tmp_path / "straight" / "model.zip")[1]
    b = load_from_zip_file(tmp_path / "cut" / "model.zip")[1]
    for name in a:
        for key, value in a[name].items():
            if isinstance(value, torch.Tensor):
                assert torch.equal(value, b[name][key]), (name, key)
    ha = torch.load(tmp_path / "straight" / "head.pt")
    hb = torch.load(tmp_path / "cut" / "head.pt")
    assert all(torch.equal(ha[k], hb[k]) for k in ha)


@pytest.mark.parametrize(
    ("algo", "n_envs", "kwargs", "steps", "chunk"),
    [
        ("ppo", 1, {"n_steps": 48, "batch_size": 16, "n_epochs": 1}, 144, 48),  # 3 rollouts
        ("sac", 2, {"learning_starts": 32, "batch_size": 32, "train_freq": 3}, 102, 6),
    ],
)
def test_a_budget_between_sb3s_chunks_is_said_and_trained_to_the_next(
    tmp_path, capsys, algo, n_envs, kwargs, steps, chunk
):
    config = Sb3Config(
        algo=algo, env="ham/HapticGlanceAP-v0", env_kwargs={"glances": 2}, env_steps=100,
        n_envs=n_envs, eval_every=1000, eval_episodes=2, algo_kwargs=kwargs,
    )  # fmt: skip
    m = train_sb3(config, tmp_path / algo)
    assert m["env_steps"] == steps  # SB3's own count, as predicted and said
    assert capsys.readouterr().err.strip().splitlines() == [
        f"ham sb3: {algo} steps its environments {chunk} steps at a time: it trains to "
        f"{steps} environment steps for --env-steps 100"
    ]
    # a budget on a chunk boundary: nothing said
    m = resume_sb3(tmp_path / algo, env_steps=steps + chunk)
    assert m["env_steps"] == steps + chunk and capsys.readouterr().err == ""


def test_a_run_that_cannot_be_checkpointed_still_finishes(tmp_path, monkeypatch, capsys):
    from ham.learn import sb3_agents

    def unpicklable(obj, f):
        raise TypeError("cannot pickle '_thread.lock' object")

    monkeypatch.setattr(sb3_agents, "_dump", unpicklable)
    config = Sb3Config(
        algo="sac", env="ham/HapticGlanceAP-v0", env_kwargs={"glances": 2}, env_steps=128,
        eval_every=64, eval_episodes=4, algo_kwargs={"learning_starts": 32, "batch_size": 32},
    )  # fmt: skip
    m = train_sb3(config, tmp_path / "run")
    assert m["env_steps"] == 128 and len(m["history"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["ham sb3: no checkpoint, this run cannot be resumed (TypeError: cannot pickle "
                   "'_thread.lock' object); training goes on"]  # fmt: skip
    assert not list((tmp_path / "run").glob("*checkpoint*"))
    with pytest.raises(HamError, match="has no checkpoint.pkl"):
        resume_sb3(tmp_path / "run", env_steps=256)


def test_resume_refuses_in_one_line(tmp_path, capsys):
    from ham.cli.main import main

    for argv, message in [
        (["sb3", "--resume", str(tmp_path), "--out", str(tmp_path / "c")], "not both"),
        (["sb3", "--out", str(tmp_path / "c")], "needs --algo"),
        (
            ["sb3", "--algo", "ppo", "--seed", "4294967296", "--out", str(tmp_path / "c")],
            "seed = 4294967296; accepted: an integer 0..4294967295",
        ),
    ]:
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err
    assert not (tmp_path / "c").exists()
    with pytest.raises(HamError, match="holds no ham sb3 run"):
        resume_sb3(tmp_path)
    config = Sb3Config(
        algo="sac", env="ham/HapticGlanceAP-v0", env_kwargs={"glances": 2}, env_steps=64,
        eval_every=64, eval_episodes=4, algo_kwargs={"learning_starts": 32, "batch_size": 32},
    )  # fmt: skip
    train_sb3(config, tmp_path / "run")
    with pytest.raises(HamError, match="is finished"):
        resume_sb3(tmp_path / "run")
    (tmp_path / "run" / "checkpoint.pkl").write_bytes(b"not a pickle")
    with pytest.raises(HamError, match="cannot read"):
        resume_sb3(tmp_path / "run", env_steps=128)
    # A ham sb3 run is not a ham train run, and the other way round; a damaged config is named.
    from ham.learn.train import load_run

    with pytest.raises(
        HamError, match="'.*run' holds a ham sb3 run \\(sac\\); accepted: a ham train"
    ):
        load_run(tmp_path / "run")
    (tmp_path / "train").mkdir()
    (tmp_path / "train" / "config.json").write_text('{"model": {}, "steps": 3}')
    with pytest.raises(HamError, match="holds a ham train run; accepted: a ham sb3 run"):
        resume_sb3(tmp_path / "train", env_steps=128)
    config_file = tmp_path / "run" / "config.json"
    config_file.write_text(config_file.read_text()[:-2] + ', "bogus": 1}')
    with pytest.raises(HamError, match=r"has unknown fields \['bogus'\]; accepted: algo, env"):
        resume_sb3(tmp_path / "run", env_steps=128)
    for damaged in (b"{bad", b"\xfc\xa9 not text"):
        config_file.write_bytes(damaged)
        with pytest.raises(HamError, match="is not valid JSON"):
            resume_sb3(tmp_path / "run", env_steps=128)
        with pytest.raises(HamError, match="is not valid JSON"):
            load_run(tmp_path / "run")


def test_bad_configs():
    with pytest.raises(HamError, match="algo = 'dqn'; accepted: ppo, sac, crossq"):
        Sb3Config(algo="dqn")
    with pytest.raises(HamError, match="env_steps = 0"):
        Sb3Config(env_steps=0)
    with pytest.raises(HamError, match="not registered"):
        make_env("ap_gym:NoSuchEnv-v0")


def test_cli_trains_ppo_on_a_table_and_refuses_to_overwrite(tmp_path, ham_cli, ham_main):
    table = tmp_path / "paper5.h5"
    r = ham_main("table", "build", "--grid", "5", "--quiet", "--out", str(table))
    assert r.returncode == 0, r.stderr
    out = tmp_path / "ppo"
    args = ["sb3", "--algo", "ppo", "--glances", "2", "--table", str(table), "--env-steps", "128",
            "--eval-every", "64", "--eval-episodes", "8", "--seed", "3", "--json",
            "--algo-kwargs", '{"n_steps": 64, "batch_size": 32, "n_epochs": 1}']  # fmt: skip
    r = ham_cli(*args, "--out", str(out))
    assert r.returncode == 0, r.stderr
    printed = json.loads(r.stdout)
    saved = json.loads((out / "metrics.json").read_text())
    assert printed["env_steps"] == saved["env_steps"] == 128 and printed["algo"] == "ppo"
    assert printed["final_accuracy"] == saved["final_accuracy"]
    assert len(saved["accuracy_per_glance"]) == 2
    config = json.loads((out / "config.json").read_text())
    assert config["env_kwargs"] == {"glances": 2, "table": str(table)} and config["seed"] == 3
    assert (out / "training_curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    r = ham_main(*args, "--out", str(out))
    assert r.returncode == 2 and r.stderr.strip().endswith(
        "accepted: a path that does not exist yet"
    )
    assert len(r.stderr.strip().splitlines()) == 1


def test_cli_resume_trains_a_finished_run_further_as_if_never_stopped(
    tmp_path, ham_cli, ham_main, capsys
):
    # the resume in a new process (the point), the other commands in this one
    base = ["--algo", "sac", "--glances", "2", "--eval-every", "64", "--eval-episodes", "4",
            "--algo-kwargs", json.dumps({"learning_starts": 32, "batch_size": 32, **SMALL}),
            "--json", "--no-progress"]  # fmt: skip
    r = ham_main("sb3", *base, "--env-steps", "128", "--out", str(tmp_path / "a"))
    assert r.returncode == 0, r.stderr
    r = ham_cli("sb3", "--resume", str(tmp_path / "a"), "--env-steps", "192", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["env_steps"] == 192
    r = ham_main("sb3", *base, "--env-steps", "192", "--out", str(tmp_path / "b"))
    assert r.returncode == 0, r.stderr
    a, b = (json.loads((tmp_path / d / "metrics.json").read_text()) for d in "ab")
    assert [h["accuracy_per_glance"] for h in a["history"]] == [
        h["accuracy_per_glance"] for h in b["history"]
    ]
    assert len(a["history"]) == 3 and a["accuracy_per_glance"] == b["accuracy_per_glance"]
    assert json.loads((tmp_path / "a" / "config.json").read_text())["env_steps"] == 192
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(tmp_path / "a" / "tb"))
    events.Reload()
    logged = [(e.step, round(e.value, 6)) for e in events.Scalars("eval/final_accuracy")]
    assert logged == [(h["env_steps"], round(h["final_accuracy"], 6)) for h in a["history"]]
    r = ham_main("sb3", "--resume", str(tmp_path / "a"), "--seed", "1")
    assert r.returncode == 2 and r.stderr.strip().endswith("(only --env-steps may change)")
    assert len(r.stderr.strip().splitlines()) == 1
    from ham.cli.main import main

    for argv, message in [
        (["sb3", "--resume", str(tmp_path / "a")], "is finished (metrics.json); give a larger"),
        (["sb3", "--resume", str(tmp_path / "a"), "--env-steps", "150"],
         "more than the checkpoint's 192"),
    ]:  # fmt: skip
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err
    from ham.world.files import folder_lock

    with folder_lock(tmp_path / "a"):  # another process resuming it now
        assert main(["sb3", "--resume", str(tmp_path / "a"), "--env-steps", "256"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "is in use by another ham process" in err[0], err
    assert json.loads((tmp_path / "a" / "config.json").read_text())["env_steps"] == 192


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--algo", "dqn"], "invalid choice: 'dqn'"),
        (["--algo", "ppo", "--env-steps", "0"], "--env-steps 0; accepted: an integer >= 1"),
        (["--algo", "sac", "--env", "ap_gym:NoSuchEnv-v0"], "'ap_gym:NoSuchEnv-v0' is not registered"),
        (["--algo", "ppo", "--env", "ap_gym:CircleSquare-v0", "--glances", "3"],
         "--glances applies to ham/ environments"),
        (["--algo", "ppo", "--table", "no.h5"], "glance table 'no.h5' does not exist"),
        (["--algo", "ppo", "--glances", "0"], "--glances 0; accepted: an integer >= 1"),
        (["--algo", "ppo", "--algo-kwargs", "[1]"], "accepted: a JSON object"),
        (["--algo", "ppo", "--algo-kwargs", "{x"], "not JSON"),
        (["--algo", "ppo", "--algo-kwargs", '{"nope": 1}'], "unexpected keyword argument 'nope'"),
        # Python's JSON reader takes NaN and Infinity; no hyperparameter means them
        (["--algo", "ppo", "--algo-kwargs", '{"gamma": NaN}'],
         "algo_kwargs: gamma = nan; accepted: JSON values (text keys; text, booleans, null, "
         "integers, finite numbers, lists)"),
        (["--algo", "sac", "--algo-kwargs", '{"policy_kwargs": {"net_arch": [64, -Infinity]}}'],
         "algo_kwargs: policy_kwargs.net_arch[1] = -inf; accepted: JSON values"),
        # hyperparameters that break the algorithm only when it trains (tracebacks before)
        (["--algo", "ppo", "--no-progress", "--algo-kwargs",
          '{"learning_rate": 1e300, "n_steps": 16, "batch_size": 16}'],
         "ppo failed at env step 16: RuntimeError: value cannot be converted to type float without "
         "overflow; accepted: algo_kwargs ppo trains with"),
        (["--algo", "ppo", "--no-progress", "--algo-kwargs",
          '{"ent_coef": "abc", "n_steps": 16, "batch_size": 16}'],
         "ppo failed at env step 16: TypeError: only integer tensors"),
        (["--algo", "ppo", "--no-progress", "--algo-kwargs",
          '{"n_epochs": 0, "n_steps": 16, "batch_size": 16}'],
         "ppo failed at env step 16: UnboundLocalError: cannot access local variable"),
        (["--algo", "sac", "--no-progress", "--algo-kwargs",
          '{"train_freq": 0, "learning_starts": 8, "batch_size": 8}'],
         "sac failed at env step 0: AssertionError: Should at least collect one step or episode."),
        (["--algo", "ppo", "--algo-kwargs", '{"policy_kwargs": {"net_arch": [1000000000000000000000]}}'],
         "for ppo: too large to hold (empty(): argument 'size' failed"),
        (["--algo", "ppo", "--device", "tpu"], "device 'tpu'; accepted: cpu, cuda or cuda:N"),
        # not the active-classification protocol (ap_gym wraps it with an empty prediction)
        (["--algo", "ppo", "--env", "CartPole-v1"],
         "environment 'CartPole-v1' has action space Dict('action': Discrete(2), 'prediction': "
         "Tuple()); accepted: an active classification environment"),
        (["--algo", "ppo", "--env", "ham/HapticGlance-v0"],
         "accepted: an active classification environment with Dict(action=..., prediction=logits)"),
    ],
)  # fmt: skip
def test_cli_refuses_bad_inputs_in_one_line_and_writes_nothing(tmp_path, ham_main, args, message):
    r = ham_main("sb3", *args, "--out", str(tmp_path / "run"), cwd=tmp_path)
    assert r.returncode == 2 and message in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert not (tmp_path / "run").exists()


def test_a_failure_of_our_code_in_training_is_not_put_on_the_algo_kwargs(tmp_path, monkeypatch):
    """Only what the algorithm's own code raises is blamed on the hyperparameters: our
    evaluation callback runs inside SB3's learn() too, and its failure stays a traceback."""
    from ham.learn import sb3_agents

    def broken(*args, **kwargs):
        raise ValueError("a bug of ours")

    monkeypatch.setattr(sb3_agents, "evaluate_agent", broken)
    config = Sb3Config(
        algo="ppo", env="ham/HapticGlanceAP-v0", env_kwargs={"glances": 2}, env_steps=32,
        eval_every=16, eval_episodes=2, algo_kwargs={"n_steps": 16, "batch_size": 16},
    )  # fmt: skip
    with pytest.raises(ValueError, match="a bug of ours"):
        train_sb3(config, tmp_path / "r")


def test_cli_names_a_missing_gpu_before_writing(tmp_path, ham_cli):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    r = ham_cli("sb3", "--algo", "sac", "--device", "cuda", "--out", str(tmp_path / "run"))
    assert r.returncode == 2 and "CUDA is not available on this machine" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"algo_kwargs": {"n_steps": np.int64(32)}}, "algo_kwargs: n_steps = np.int64(32); accepted"),
        ({"algo_kwargs": {"x": b"x"}}, "algo_kwargs: x = b'x'; accepted: JSON values"),
        ({"algo_kwargs": {"x": object()}}, "algo_kwargs: x = <object object at"),
        ({"env_kwargs": {1: 2}}, "env_kwargs: key 1; accepted: JSON values (text keys;"),
        ({"env_kwargs": {"glances": float("inf")}}, "env_kwargs: glances = inf; accepted"),
    ],
)  # fmt: skip
def test_kwargs_are_json_a_run_can_save_and_resume_from(tmp_path, kwargs, message):
    # before: a TypeError writing config.json, after the model was made; NaN and inf taken
    with pytest.raises(HamError, match="^" + re.escape(message)):
        train_sb3(Sb3Config(algo="ppo", env_steps=16, **kwargs), tmp_path / "run")
    assert not (tmp_path / "run").exists()


def test_the_curve_of_a_baseline_is_its_evaluations_and_the_final_one(tmp_path):
    import matplotlib.image

    from ham.experiments.figures import plot_training_curve

    row = {"accuracy_per_glance": [0.5, 0.75], "final_accuracy": 0.75, "average_accuracy": 0.625}
    final = {"algo": "ppo", "env": "ham/HapticGlanceAP-v0", "env_steps": 100, **row}
    # no evaluation before the end (env_steps < eval_every): the final one alone
    png = plot_training_curve({**final, "history": []}, tmp_path / "one.png")
    assert matplotlib.image.imread(png).shape[2] == 4
    two = plot_training_curve(
        {**final, "history": [{**row, "env_steps": 50}]}, tmp_path / "two.png"
    )
    assert two.read_bytes() != png.read_bytes()
    with pytest.raises(HamError, match="no evaluation history"):  # a HAM run's metrics need one
        plot_training_curve({"history": []}, tmp_path / "ham.png")
