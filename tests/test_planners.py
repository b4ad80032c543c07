"""Reference policies on a glance table, exact (ham.learn.planners, ham baselines)."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
import torch

from ham.errors import HamError
from ham.learn.planners import Partitions, Planner, sweep
from ham.world.config import WorldConfig
from ham.world.sensor import normalize
from ham.world.table import GlanceTable, build_table, nearest_index


def hand_made(labels: list[list[int]], weight=None) -> Partitions:
    labels = np.array(labels)
    u = len(labels)
    weight = np.full(u, 1.0 / u) if weight is None else np.asarray(weight, float)
    return Partitions(labels, weight, np.zeros((u, 2)), np.zeros((1, 1), dtype=np.int64))


def test_two_binary_splits_need_two_glances():
    # action 0 tells {0,1} from {2,3}; action 1 tells {0,2} from {1,3}
    pl = Planner(hand_made([[0, 0, 2, 2], [0, 1, 0, 1]]))
    assert pl.oracle(1) == pytest.approx(0.5)
    assert pl.oracle(2) == pytest.approx(1.0)
    assert pl.infogain(2) == pytest.approx(1.0)
    assert pl.expected_glances("oracle") == pytest.approx(2.0)
    # random: each glance either action with p 1/2; two glances: both actions with p 1/2
    assert pl.random(1) == pytest.approx(0.5)
    assert pl.random(2) == pytest.approx(0.5 * 1.0 + 0.5 * 0.5)


@pytest.mark.parametrize("dense", [True, False])
@pytest.mark.parametrize("glances", [1, 2, 3, 4, 5, 7, 16, 40, 1000, 10**12])
def test_random_glances_any_count_in_closed_form(glances, dense, monkeypatch):
    # Two binary splits drawn with p 0.2 / 0.8: wrong half the time unless both were drawn.
    # 4 consistent sets per object: up to 4 glances step by step, beyond by squaring; without
    # squaring (as for a set too large for it) step by step until the distribution is final.
    if not dense:
        monkeypatch.setattr("ham.learn.planners.MAX_DENSE_SETS", 0)
    pl = Planner(hand_made([[0, 0, 2, 2], [0, 1, 0, 1]], weight=[0.2, 0.8]))
    expected = 1 - 0.5 * (0.2**glances + 0.8**glances)
    assert pl.random(glances) == pytest.approx(expected, rel=1e-12)
    assert pl.random(glances) <= 1.0


def test_more_glances_than_objects_cost_no_recursion():
    # Planned policies stop gaining once nothing splits: the same value for any larger count.
    pl = Planner(hand_made([[0, 1, 1, 1], [0, 0, 2, 2], [0, 0, 2, 3], [0, 1, 0, 0]]))
    for first in ("planned", "random"):
        assert pl.oracle(10**6, first) == pl.oracle(4, first) == pytest.approx(1.0)
        assert pl.infogain(10**6, first) == pl.infogain(4, first)
    stuck = Planner(hand_made([[0, 0, 2, 2]]))
    assert stuck.oracle(10**6) == stuck.infogain(10**6) == pytest.approx(0.5)
    with pytest.raises(
        HamError, match=r"glances = 1000001 for the grid sweep; accepted: 1\.\.1000000"
    ):
        pl.grid(10**6 + 1)


def test_greedy_information_gain_never_beats_the_oracle():
    # action 0 isolates object 0 (entropy left 3/4 log 3); action 1 halves {0,1}|{2,3} (log 2),
    # action 2 separates 2 from 3, action 3 separates 1 from 0: the oracle halves first.
    pl = Planner(hand_made([[0, 1, 1, 1], [0, 0, 2, 2], [0, 0, 2, 3], [0, 1, 0, 0]]))
    assert pl.oracle(2) == pytest.approx(1.0)
    assert pl.infogain(2) <= pl.oracle(2) + 1e-12
    assert pl.expected_glances("oracle") <= pl.expected_glances("infogain") + 1e-12


def test_the_share_of_poses_that_identify_every_object():
    pl = hand_made([[0, 1, 2, 3], [0, 0, 2, 2], [0, 1, 2, 0]], weight=[0.2, 0.5, 0.3])
    assert pl.identifying_share() == pytest.approx(0.2)
    assert hand_made([[0, 0, 2, 2]]).identifying_share() == 0.0


def test_indistinguishable_objects_stop_the_count():
    pl = Planner(hand_made([[0, 0, 2, 2]]))  # 0 and 1 are never told apart
    assert pl.oracle(5) == pytest.approx(0.5)
    assert pl.expected_glances("oracle") == pytest.approx(1.0)


@pytest.fixture(scope="module")
def small_table(tmp_path_factory):
    path = tmp_path_factory.mktemp("planners") / "paper11.h5"
    build_table(WorldConfig(), 11, path, progress=False)
    return GlanceTable.load(path)


def brute_force_random(table: GlanceTable, glances: int) -> float:
    """Enumerate every sequence of grid poses with its probability under uniform q."""
    g, k = table.grid, table.n_objects
    p = normalize(table.pressure.double(), "l2").reshape(k, g * g, -1)
    same = (torch.cdist(p.transpose(0, 1), p.transpose(0, 1)) <= 1e-6).numpy()  # (P, K, K)
    cell = np.full(g, 1.0)
    cell[[0, -1]] = 0.5
    w = np.outer(cell, cell).reshape(-1)
    w /= w.sum()
    total = 0.0
    for seq in itertools.product(range(g * g), repeat=glances):
        both = np.logical_and.reduce([same[i] for i in seq])
        total += np.prod(w[list(seq)]) * (1.0 / both.sum(-1)).mean()
    return total


def test_random_is_exact_against_enumeration(small_table):
    pl = Planner(Partitions.from_table(small_table))
    for glances in (1, 2):
        assert pl.random(glances) == pytest.approx(
            brute_force_random(small_table, glances), abs=1e-9
        )


def test_grid_sweep_matches_looking_the_poses_up(small_table):
    pl = Planner(Partitions.from_table(small_table))
    poses = torch.from_numpy(sweep(3))
    ix, ip = nearest_index(poses[:, 0], 11), nearest_index(poses[:, 1], 11)
    p = normalize(small_table.pressure.double(), "l2")[:, ix, ip]  # (K, 3, D)
    flat = p.reshape(small_table.n_objects, -1)
    same = torch.cdist(flat, flat) <= 1e-6 * 3
    assert pl.grid(3) == pytest.approx(float((1.0 / same.sum(-1)).mean()))
    assert sweep(4).tolist() == [[-0.5, -0.5], [0.5, -0.5], [-0.5, 0.5], [0.5, 0.5]]


def test_orderings_on_a_real_table(small_table):
    pl = Planner(Partitions.from_table(small_table))
    for g in (1, 2, 3):
        o = pl.oracle(g)
        assert o >= pl.infogain(g) - 1e-12
        assert o >= pl.random(g) - 1e-12 and o >= pl.grid(g) - 1e-12
        assert pl.oracle(g, "random") <= o + 1e-12
        assert pl.oracle(g + 1) >= o - 1e-12


def test_cli_json_and_errors(tmp_path, ham_cli, ham_main):
    path = tmp_path / "t.h5"
    build_table(WorldConfig(), 11, path, progress=False)
    p = ham_cli(
        "baselines", "--policy", "oracle", "--table", str(path), "--glances", "1", "2", "--json"
    )
    assert p.returncode == 0, p.stderr
    d = json.loads(p.stdout)
    assert set(d["accuracy"]) == {"1", "2"} and 0 < d["accuracy"]["1"] <= 1
    assert d["expected_glances_to_identify"] >= 1
    # the share by brute force: the nearest-grid-point weight of the poses with four distinct images
    t = GlanceTable.load(path)
    img = normalize(t.pressure.double(), "l2").reshape(t.n_objects, 11 * 11, -1).transpose(0, 1)
    alone = ((torch.cdist(img, img) <= 1e-6).sum(-1) == 1).all(-1).numpy()
    cell = np.full(11, 1.0)
    cell[[0, -1]] = 0.5
    w = np.outer(cell, cell).reshape(-1)
    assert d["identifying_share"] == pytest.approx(w[alone].sum() / w.sum(), abs=1e-12)
    text = ham_cli("baselines", "--policy", "random", "--table", str(path), "--glances", "1")
    assert f"tells every object apart at {d['identifying_share']:.1%} of poses" in text.stdout
    bad = ham_main("baselines", "--policy", "random", "--table", str(path), "--glances", "0")
    assert bad.returncode == 2 and "--glances 0" in bad.stderr and "Traceback" not in bad.stderr
    bad = ham_main("baselines", "--policy", "oracle", "--table", str(tmp_path / "no.h5"))
    assert bad.returncode == 2 and "no.h5" in bad.stderr


def test_bad_planner_arguments():
    pl = Planner(hand_made([[0, 1, 1, 1]]))
    with pytest.raises(HamError, match="glances = 0"):
        pl.accuracy("oracle", 0)
    with pytest.raises(HamError, match="policy = 'best'"):
        pl.accuracy("best", 1)
    with pytest.raises(HamError, match="first = 'late'"):
        pl.infogain(1, "late")


@pytest.fixture(scope="module")
def table_3d(tmp_path_factory):
    """A format-2 table over three pose dims (x, y, phi) of the curvature2d objects."""
    path = tmp_path_factory.mktemp("planners3d") / "c2d.h5"
    world = WorldConfig(objects="curvature2d", pose_dims=("x", "y", "phi"))
    build_table(world, "5,4,3", path, progress=False)
    return GlanceTable.load(path)


def test_partitions_of_a_3d_table(table_3d):
    parts = Partitions.from_table(table_3d, height=True)
    assert parts.grid_action.shape == (5, 4, 3) and parts.pose.shape == (len(parts.labels), 3)
    assert parts.weight.sum() == pytest.approx(1.0)
    # each action's pose is a grid pose that realizes it
    for a, q in enumerate(parts.pose):
        idx = tuple(
            int(nearest_index(torch.tensor([v]), n)) for v, n in zip(q, (5, 4, 3), strict=True)
        )
        assert parts.grid_action[idx] == a
    # comparing the poses in chunks gives the same partitions
    small = Partitions.from_table(table_3d, height=True, chunk=7)
    np.testing.assert_array_equal(small.labels, parts.labels)
    np.testing.assert_array_equal(small.grid_action, parts.grid_action)


def test_random_on_a_3d_table_is_exact_against_enumeration(table_3d):
    pl = Planner(Partitions.from_table(table_3d))
    k, shape = table_3d.n_objects, table_3d.grid_shape
    p = normalize(table_3d.pressure.double(), "l2").reshape(k, -1, 256).transpose(0, 1)
    same = (torch.cdist(p, p) <= 1e-6).numpy()  # (P, K, K)
    w = np.ones(())
    for n in shape:
        cell = np.full(n, 1.0)
        cell[[0, -1]] = 0.5
        w = np.multiply.outer(w, cell / cell.sum())
    w = w.reshape(-1)
    one = sum(w[i] * (1.0 / same[i].sum(-1)).mean() for i in range(len(w)))
    assert pl.random(1) == pytest.approx(one, abs=1e-9)
    two = sum(
        w[i] * w[j] * (1.0 / (same[i] & same[j]).sum(-1)).mean()
        for i in range(len(w))
        for j in range(len(w))
    )
    assert pl.random(2) == pytest.approx(two, abs=1e-9)


def test_grid_sweep_on_a_3d_table(table_3d):
    pl = Planner(Partitions.from_table(table_3d))
    poses = torch.from_numpy(sweep(5, 3))
    assert sweep(8, 3).tolist()[:3] == [[-0.5, -0.5, -0.5], [0.5, -0.5, -0.5], [-0.5, 0.5, -0.5]]
    idx = [nearest_index(poses[:, j], n) for j, n in enumerate(table_3d.grid_shape)]
    p = normalize(table_3d.pressure.double(), "l2")[:, idx[0], idx[1], idx[2]]  # (K, 5, D)
    flat = p.reshape(table_3d.n_objects, -1)
    same = torch.cdist(flat, flat) <= 1e-6 * 5
    assert pl.grid(5) == pytest.approx(float((1.0 / same.sum(-1)).mean()))
    for g in (1, 2, 3):
        o = pl.oracle(g)
        assert o >= pl.infogain(g) - 1e-12 and o >= pl.random(g) - 1e-12
        assert o >= pl.grid(g) - 1e-12 and pl.oracle(g, "random") <= o + 1e-12


def test_cli_baselines_on_a_3d_table(tmp_path, ham_cli):
    path = tmp_path / "t3.h5"
    build_table(
        WorldConfig(objects="curvature2d", pose_dims=("x", "y", "phi")), 3, path, progress=False
    )
    p = ham_cli("baselines", "--policy", "infogain", "--table", str(path), "--height",
                "--first", "random", "--glances", "1", "2", "--json")  # fmt: skip
    assert p.returncode == 0, p.stderr
    d = json.loads(p.stdout)
    assert d["pose_dims"] == ["x", "y", "phi"] and d["grid_shape"] == [3, 3, 3]
    assert 0 < d["accuracy"]["1"] <= d["accuracy"]["2"] <= 1
