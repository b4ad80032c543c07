"""The first pose found by a global search (``--first-glance probe``, ham.learn.probe): the
lattice and its phases, successive halving, probe glances counted as environment steps, the
budget, determinism and resume across the search, the CLI and bad input."""

from __future__ import annotations

import json

import pytest
import torch

from ham.errors import HamError
from ham.learn.probe import (
    probe_glances,
    probe_round,
    probe_schedule,
    probe_scores,
    rank,
    survivors,
)
from ham.learn.train import Run, TrainConfig, resume, train, train_step
from ham.model.agent import HamConfig, HapticAttentionModel
from ham.model.policy import ProbedFirstPose
from tests.conftest import ok, one_line_error

#: a 3 x 3 lattice: rounds on 9, 5, 3, 2 candidates, 4 objects: 76 probe glances
GRID3 = HamConfig(glances=3, first_glance="probe", probe_grid=3)


def tiny(**kw) -> TrainConfig:
    base = dict(model=kw.pop("model", GRID3), steps=12, batch_size=8, eval_every=3,
                eval_batches=2, seed=5, learner="info", optimizer="adam", lr=3e-3,
                probe_warmup=2, probe_every=2)  # fmt: skip
    base.update(kw)
    return TrainConfig(**base)


def test_successive_halving_schedule_and_its_glances():
    assert [survivors(n, 0.5) for n in (2, 3, 9, 441)] == [1, 2, 5, 221]
    assert survivors(10, 0.95) == 9  # always fewer
    assert probe_schedule(9, 0.5) == [9, 5, 3, 2]
    assert probe_schedule(441, 0.5) == [441, 221, 111, 56, 28, 14, 7, 4, 2]
    assert probe_glances(441, 0.5, 4) == 4 * 884 == 3536
    assert probe_schedule(1, 0.5) == []


def test_the_lattice_gives_candidates_until_one_is_committed():
    search = ProbedFirstPose(dims=2, grid=3)
    assert search.candidates.shape == (9, 2)
    assert sorted(set(search.candidates[:, 0].tolist())) == [-1.0, 0.0, 1.0]
    g = torch.Generator().manual_seed(0)
    q = search.first_poses(200, g)
    assert {tuple(p) for p in q.tolist()} == {tuple(p) for p in search.candidates.tolist()}
    search.alive.zero_()
    search.alive[[2, 7]] = True
    q = search.first_poses(100, g)
    assert {tuple(p) for p in q.tolist()} == {tuple(search.candidates[i].tolist()) for i in (2, 7)}
    search.pose.copy_(torch.tensor([0.5, -0.25]))
    search.committed.fill_(True)
    assert search.first_poses(4, g).tolist() == [[0.5, -0.25]] * 4
    assert set(search.state_dict()) == {"alive", "committed", "pose", "probes"}
    with pytest.raises(HamError):
        ProbedFirstPose(grid=1)


def test_a_round_scores_every_survivor_by_one_glance_of_each_object_and_halves(env):
    torch.manual_seed(0)
    agent = HapticAttentionModel(GRID3)
    search = agent.first_probe
    ce, wrong = probe_scores(agent, env, search.candidates)
    assert ce.shape == wrong.shape == (9,) and bool((ce > 0).all())
    assert set(wrong.tolist()) <= {0.0, 1.0, 2.0, 3.0, 4.0}
    log = probe_round(agent, env, 0.5)
    assert log["probed"] == 9 and log["kept"] == 5 and int(search.probes) == 36
    best = rank(ce, wrong, "errors")[:5]
    assert search.alive.nonzero()[:, 0].tolist() == sorted(best.tolist())
    while not bool(search.committed):
        probe_round(agent, env, 0.5)
    assert int(search.probes) == 76 and int(search.alive.sum()) == 1
    assert torch.equal(search.pose, search.candidates[search.alive][0])
    # every episode's first glance is the committed pose, sampled or greedy
    for greedy in (False, True):
        episode = agent(env, env.sample_objects(), torch.Generator().manual_seed(1), greedy)
        assert torch.equal(episode.locations[0], search.pose.expand(8, 2))
        assert episode.first_baseline is None and tuple(episode.policy.batch_shape) == (2, 8)


def test_candidates_rank_by_wrong_answers_first_then_cross_entropy():
    ce = torch.tensor([0.35, 0.9, 0.2, 0.9, 0.5])
    wrong = torch.tensor([1.0, 0.0, 2.0, 0.0, 0.0])
    assert rank(ce, wrong, "errors").tolist() == [4, 1, 3, 0, 2]  # ties: the lower index
    assert rank(ce, wrong, "ce").tolist() == [2, 0, 4, 1, 3]


def test_a_probe_run_counts_its_probe_glances_and_commits_on_schedule():
    run = Run.create(tiny())
    try:
        counts = []
        for _ in range(8):
            train_step(run)
            counts.append((run.step, int(run.agent.first_probe.alive.sum()), run.env_steps))
        # rounds before steps 3, 5, 7, 9 (warm-up 2, every 2): 9 -> 5 -> 3 -> 2 -> 1
        assert counts == [(1, 9, 24), (2, 9, 48), (3, 5, 108), (4, 5, 132), (5, 3, 176),
                          (6, 3, 200), (7, 2, 236), (8, 2, 260)]  # fmt: skip
        train_step(run)
        assert bool(run.agent.first_probe.committed) and run.env_steps == 9 * 24 + 76
    finally:
        run.close()


def test_the_budget_in_environment_steps_includes_the_probes():
    c = tiny(env_steps=1000)  # 76 probe glances, 24 a step: ceil(924 / 24) = 39 steps
    assert c.probe_glances == 76 and c.steps == 39
    assert tiny(model=HamConfig(glances=3), probe_warmup=100, probe_every=10,
                env_steps=1000).steps == 42  # fmt: skip


def test_the_other_first_glances_keep_their_weights():
    torch.manual_seed(3)
    before = HapticAttentionModel(HamConfig(glances=3)).state_dict()
    torch.manual_seed(3)
    probe = HapticAttentionModel(GRID3).state_dict()
    assert set(probe) - set(before) == {f"first_probe.{n}" for n in
                                        ("alive", "committed", "pose", "probes")}  # fmt: skip
    for name, w in before.items():
        assert torch.equal(w, probe[name]), name


def test_a_probe_run_is_deterministic_and_resumes_bit_identically_across_the_search(tmp_path):
    full = train(tiny(), tmp_path / "full", progress=False)
    again = train(tiny(), tmp_path / "again", progress=False)
    assert full["history"] == again["history"]
    train(tiny(steps=6), tmp_path / "half", progress=False)  # stopped inside the search
    resumed = resume(tmp_path / "half", steps=12, progress=False)
    assert full["history"] == resumed["history"]
    assert full["env_steps"] == 12 * 24 + 76 == resumed["env_steps"]
    last = full["history"][-1]["first_probe"]
    assert last["committed"] and last["candidates"] == 1 and last["probe_glances"] == 76
    assert full["history"][0]["first_probe"]["candidates"] == 9
    a = torch.load(tmp_path / "full" / "checkpoint.pt", weights_only=False)["model"]
    b = torch.load(tmp_path / "half" / "checkpoint.pt", weights_only=False)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize(
    "kw",
    [{"probe_keep": 0.0}, {"probe_keep": 1.0}, {"probe_keep": float("nan")},
     {"probe_keep": True}, {"probe_score": "best"}, {"probe_warmup": -1}, {"probe_warmup": 1.5}, {"probe_every": 0},
     {"learner": "hybrid"}, {"env_steps": 200},  # 6 steps: the search ends before step 9
     {"env_steps": 76},  # the probes alone spend the budget
     {"probe_every": 3, "model": HamConfig(glances=3, first_glance="own")},
     {"probe_warmup": 5, "model": HamConfig(glances=3)},
     {"probe_score": "ce", "model": HamConfig(glances=3)},
     {"object_yaw_max": 0.1}],
)  # fmt: skip
def test_bad_probe_configs(kw):
    with pytest.raises(HamError):
        tiny(**kw)


@pytest.mark.parametrize("kw", [{"probe_grid": 1}, {"probe_grid": 2.5}, {"probe_grid": True},
                                {"probe_grid": 5, "first_glance": "own"}])  # fmt: skip
def test_bad_probe_grid(kw):
    with pytest.raises(HamError):
        HamConfig(**{"first_glance": "probe", **kw})


def test_probe_first_glance_through_the_cli(tmp_path, ham_cli, ham_main):
    out = tmp_path / "run"
    ok(ham_cli("train", "--learner", "info", "--optimizer", "adam", "--glances", "3",
               "--batch-size", "8", "--steps", "6", "--first-glance", "probe",
               "--probe-grid", "2", "--probe-warmup", "1", "--probe-every", "2",
               "--probe-keep", "0.5", "--stop", "--glance-cost", "0.1", "--eval-every", "3",
               "--eval-batches", "2", "--no-progress", "--out", str(out)))  # fmt: skip
    m = json.loads((out / "metrics.json").read_text())
    assert m["config"]["model"]["probe_grid"] == 2 and m["config"]["probe_warmup"] == 1
    assert m["history"][-1]["first_probe"]["committed"]
    assert m["env_steps"] == 6 * 24 + 4 * (4 + 2)  # rounds on 4 and 2 candidates
    err = one_line_error(ham_main("train", "--learner", "info", "--probe-grid", "5",
                                 "--steps", "1", "--out", str(tmp_path / "bad")))  # fmt: skip
    assert "probe_grid" in err and not (tmp_path / "bad").exists()
    err = one_line_error(ham_main("train", "--first-glance", "probe", "--steps", "200",
                                 "--out", str(tmp_path / "bad")))  # fmt: skip
    assert "first_glance 'probe' with learner 'hybrid'" in err and not (tmp_path / "bad").exists()
