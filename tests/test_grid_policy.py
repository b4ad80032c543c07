"""The ``grid`` location policy (ham.model.policy.GridPolicy): a fixed sweep of poses on the
haptic world, a boustrophedon of moves on ap_gym; trained by ``ham train`` with the info and
hybrid learners, refused by sac."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from ham.errors import HamError
from ham.learn.environment import HapticEnv
from ham.learn.planners import sweep as planner_sweep
from ham.model.agent import HamConfig, HapticAttentionModel
from ham.model.policy import FixedPose, GridPolicy, make_policy, raster_counts, snake, sweep
from ham.world.config import WorldConfig
from ham.world.source import make_source
from tests.conftest import ok, one_line_error, run_ham, run_ham_inprocess

CS = "ap_gym:CircleSquare-v0"


def test_absolute_sweep_is_the_table_baselines_raster():
    # the table baseline and the policy share one definition
    assert planner_sweep is sweep
    # glance 1 random: glances 2..5 sweep a 2 x 2 raster of cell centres, x fastest
    policy = GridPolicy(5, 2)
    assert policy.poses[1:].tolist() == [[-0.5, -0.5], [0.5, -0.5], [-0.5, 0.5], [0.5, 0.5]]
    # the policy chooses the first glance too: exactly the table baseline's G poses
    first = make_policy(HamConfig(glances=4, policy="grid", first_glance="learned"))
    assert torch.equal(first.poses, torch.from_numpy(sweep(4)).float())
    assert list(first.state_dict()) == []  # no weights, nothing in a checkpoint


def test_moves_sweep_circle_square_in_four_rows():
    moves = GridPolicy(16, 2, moves=True).poses.tolist()
    right, left, up = [1.0, 0.0], [-1.0, 0.0], [0.0, 1.0]
    assert (
        moves
        == [[0.0, 0.0]] + [right] * 3 + [up] + [left] * 3 + [up] + [right] * 3 + [up] + [left] * 3
    )
    assert raster_counts(16) == [4, 4] and raster_counts(10) == [4, 3]


@pytest.mark.parametrize("dims", [1, 2, 3])
def test_snake_steps_one_unit_along_one_axis(dims):
    for glances in range(1, 40):
        points = snake(glances, dims)
        assert points.shape == (glances, dims)
        assert len({tuple(p) for p in points}) == glances  # each lattice point once
        assert (points >= 0).all() and (points < np.array(raster_counts(glances, dims))).all()
        steps = np.abs(np.diff(points, axis=0))
        assert (steps.sum(1) == 1).all()


def test_fixed_pose_distribution():
    pose = torch.tensor([[0.5, -0.5]]).expand(3, 2)
    dist = FixedPose(pose)
    assert not dist.trainable and dist.batch_shape == (3,)
    assert torch.equal(dist.sample(None), pose) and torch.equal(dist.mode(), pose)
    assert torch.equal(dist.act(None, greedy=False), pose)
    assert torch.equal(dist.log_prob(pose), torch.zeros(3))
    assert torch.equal(dist.entropy(), torch.zeros(3))
    assert FixedPose.stack([dist, dist]).batch_shape == (2, 3)
    with pytest.raises(HamError, match="needs the glance index"):
        GridPolicy(3).distribution(torch.zeros(3, 8))
    with pytest.raises(HamError, match="asked for glance 3; accepted: 0 .. 2"):
        GridPolicy(3).distribution_at(torch.zeros(3, 8), 3)


def test_grid_refuses_an_own_first_pose():
    with pytest.raises(HamError, match="first_glance = 'own' with policy 'grid'"):
        HamConfig(policy="grid", first_glance="own")


def test_rollout_on_the_paper_world_follows_the_sweep():
    source, _ = make_source(None, WorldConfig())  # the paper's world, online
    env = HapticEnv(source, batch_size=6, seed=0)
    model = HapticAttentionModel(HamConfig(glances=5, policy="grid"))
    objects = env.sample_objects()
    g = torch.Generator().manual_seed(3)
    sampled = model(env, objects, g)
    greedy = model(env, objects, torch.Generator().manual_seed(3), greedy=True)
    expected = torch.from_numpy(sweep(4)).float()[:, None].expand(4, 6, 2)
    for episode in (sampled, greedy):
        assert torch.equal(episode.locations[1:], expected)
        assert torch.equal(episode.policy.mode(), expected)  # the evaluation's mean poses
        assert not episode.policy.trainable  # no REINFORCE term
    # the first glance is random (the paper's), the same draw either way
    assert torch.equal(sampled.locations[0], greedy.locations[0])


def _train(tmp_path, name, *extra):
    out = tmp_path / name
    ok(run_ham_inprocess("train", "--steps", "2", "--batch-size", "4", "--eval-every", "2",
               "--eval-batches", "1", "--threads", "1", "--seed", "0", "--out", str(out),
               "--policy", "grid", *extra))  # fmt: skip
    return json.loads((out / "metrics.json").read_text()), json.loads(
        (out / "config.json").read_text()
    )


@pytest.mark.parametrize("learner", ["info", "hybrid"])
def test_train_grid_on_the_paper_world(tmp_path, learner):
    metrics, config = _train(tmp_path, learner, "--glances", "3", "--learner", learner)
    assert metrics["steps"] == 2 and config["model"]["policy"] == "grid"
    assert config["model"]["moves"] is False
    # evaluated at the sweep's last pose (glances 2..3: a raster of 2 cells)
    assert metrics["history"][-1]["mu_mean"] == [[0.5, 0.0]] * 4


def test_train_grid_refused_by_sac(tmp_path):
    r = run_ham("train", "--glances", "3", "--policy", "grid", "--learner", "sac", "--steps",
                "2", "--out", str(tmp_path / "r"))  # fmt: skip
    assert "policy = 'grid' with learner 'sac'" in one_line_error(r)


def test_train_grid_on_circle_square(tmp_path):
    metrics, config = _train(
        tmp_path, "cs", "--env", CS, "--glances", "16", "--actions", "relative", "--glimpse",
        "centered", "--normalization", "none", "--learner", "info", "--optimizer", "adam",
    )  # fmt: skip
    assert metrics["steps"] == 2 and config["model"]["moves"] is True
    r = run_ham_inprocess("train", "--env", CS, "--glances", "16", "--actions", "relative",
                "--max-step-length", "1", "--policy", "grid", "--steps", "2",
                "--out", str(tmp_path / "wide"))  # fmt: skip
    assert "wider than its image" in one_line_error(r)


def test_grid_walks_the_snake_on_circle_square():
    """On the real environment: each glimpse sits one full step (0.2) from the last along the
    snake's axis, clipped at the image border; the model's rollout sends the moves."""
    from ham.learn.ap_adapter import ApGymConfig, ApGymGlanceEnv
    from ham.learn.train import TrainConfig, fit_to_ap_gym

    config = fit_to_ap_gym(
        TrainConfig(model=HamConfig(glances=16, policy="grid")),
        ApGymConfig(CS, actions="relative"),
    )
    assert config.model.moves
    # another policy's config is left as it was
    other = fit_to_ap_gym(
        TrainConfig(model=HamConfig(glances=16)), ApGymConfig(CS, actions="relative")
    )
    assert not other.model.moves

    class Recording(ApGymGlanceEnv):
        def glance(self, objects, q):
            x = super().glance(objects, q)
            self.seen.append(self.observed_location.clone())
            return x

    env = Recording(CS, 8, actions="relative", seed=2)
    env.seen = []
    try:
        model = HapticAttentionModel(config.model)
        model(env, env.sample_objects(), None, greedy=True)
    finally:
        env.close()
    moves = GridPolicy(16, 2, moves=True).poses.double()
    seen = torch.stack(env.seen).double()  # (16, B, 2)
    expected = (seen[:-1] + 0.2 * moves[1:, None]).clamp(-1, 1)
    assert torch.allclose(seen[1:], expected, atol=1e-5)


def test_grid_corner_walks_to_the_nearest_corner_then_the_columns():
    """On the real environment: from a known start the glimpse goes to the nearest corner at
    full steps (0.2), then down its border column; the moves are read from the position."""
    from ham.learn.ap_adapter import ApGymConfig, ApGymGlanceEnv
    from ham.learn.train import TrainConfig, fit_to_ap_gym
    from ham.model.policy import CornerGridPolicy

    config = fit_to_ap_gym(
        TrainConfig(model=HamConfig(glances=16, policy="grid-corner")),
        ApGymConfig(CS, actions="relative"),
    )
    assert config.model.moves and config.model.move_length == pytest.approx(0.2)

    class Recording(ApGymGlanceEnv):
        def glance(self, objects, q):
            x = super().glance(objects, q)
            self.seen.append(self.observed_location.clone())
            return x

    env = Recording(CS, 4, actions="relative", seed=2)
    env.seen = []
    try:
        model = HapticAttentionModel(config.model)
        episode = model(env, env.sample_objects(), None, greedy=True)
    finally:
        env.close()
    seen = torch.stack(env.seen).double()  # (16, B, 2)
    start = seen[0]
    corner = torch.where(start >= 0, 1.0, -1.0).double()
    # the first glimpse is the environment's, anywhere: the start of the walk
    assert (start.abs() < 1).all()
    for b in range(4):
        # straight to the corner: full steps, then onto it
        to_corner = int(torch.ceil((corner[b] - start[b]).norm() / 0.2 - 1e-6))
        path = seen[: to_corner + 1, b]
        assert torch.allclose(path[-1], corner[b], atol=1e-5)
        steps = path.diff(dim=0).norm(dim=-1)
        assert torch.allclose(steps[:-1], torch.full_like(steps[:-1], 0.2), atol=1e-5)
        assert steps[-1] <= 0.2 + 1e-5
        # then along the border column x = corner's x, toward the other y border, 0.2 a step
        column = seen[to_corner:, b]
        rows = min(len(column), 11)  # 2 units of column: 10 steps
        expected_y = corner[b, 1] * (1 - 0.2 * torch.arange(rows, dtype=torch.float64))
        assert torch.allclose(column[:rows, 0], corner[b, 0].expand(rows), atol=1e-5)
        assert torch.allclose(column[:rows, 1], expected_y, atol=1e-5)
        if len(column) > 11:  # then one step toward the next column, 0.5 inward
            assert torch.allclose(
                column[11], torch.stack([corner[b, 0] * 0.8, -corner[b, 1]]), atol=1e-5
            )
    # the moves it asked for: the planned walk, each at most a full step (action norm <= 1)
    assert (episode.locations[1:].norm(dim=-1) <= 1 + 1e-5).all()
    assert not episode.policy.trainable
    # one start by hand: (0.3, -0.1) -> corner (1, -1), the waypoints' columns 0.5 apart
    ends = CornerGridPolicy.waypoints(torch.tensor([[0.3, -0.1]], dtype=torch.float64))
    assert ends[:4, 0].tolist() == [[1.0, -1.0], [1.0, 1.0], [0.5, 1.0], [0.5, -1.0]]
    assert ends[-1, 0].tolist() == [-1.0, 1.0] and ends.shape[0] == 10


def test_train_grid_corner_on_circle_square(tmp_path):
    metrics, config = _train(
        tmp_path, "cs", "--env", CS, "--glances", "16", "--actions", "relative", "--glimpse",
        "centered", "--normalization", "none", "--learner", "info", "--optimizer", "adam",
    )  # fmt: skip
    out = tmp_path / "corner"
    ok(run_ham_inprocess("train", "--env", CS, "--glances", "16", "--actions", "relative", "--glimpse",
               "centered", "--normalization", "none", "--learner", "info", "--optimizer", "adam",
               "--steps", "2", "--batch-size", "4", "--eval-every", "2", "--eval-batches", "1",
               "--threads", "1", "--seed", "0", "--out", str(out), "--policy", "grid-corner"))  # fmt: skip
    corner = json.loads((out / "metrics.json").read_text())
    model = json.loads((out / "config.json").read_text())["model"]
    assert corner["steps"] == 2 and model["policy"] == "grid-corner"
    assert model["moves"] is True and model["move_length"] == pytest.approx(0.2)
    # the plain grid's numbers stay as they were: its config has no move length
    assert config["model"]["move_length"] == 0.0
    # the evaluation's moves depend on the start: not one sweep for every episode
    assert corner["history"][-1]["mu_mean"] != metrics["history"][-1]["mu_mean"]


def test_grid_corner_run_resumes_bit_identically(tmp_path):
    """The walk's plan is made anew at each episode's start, not kept in the checkpoint: a run
    stopped at step 2 and resumed to 4 has every number of the uninterrupted run."""
    common = ["--env", CS, "--glances", "16", "--actions", "relative", "--glimpse", "centered",
              "--normalization", "none", "--learner", "info", "--optimizer", "adam",
              "--batch-size", "4", "--eval-every", "2", "--eval-batches", "1", "--threads", "1",
              "--seed", "0", "--policy", "grid-corner"]  # fmt: skip
    # the resume in a new process, the other runs in this one
    ok(run_ham_inprocess("train", *common, "--steps", "4", "--out", str(tmp_path / "full")))
    ok(run_ham_inprocess("train", *common, "--steps", "2", "--out", str(tmp_path / "half")))
    ok(run_ham("train", "--resume", str(tmp_path / "half"), "--steps", "4"))
    full = json.loads((tmp_path / "full" / "metrics.json").read_text())
    half = json.loads((tmp_path / "half" / "metrics.json").read_text())
    assert full["steps"] == half["steps"] == 4
    assert full["history"] == half["history"]
    assert full["history"][-1]["train_loss"] != full["history"][0]["train_loss"]


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--glances", "3"], "policy 'grid-corner' on a world of moves = False"),
        (["--env", CS, "--glances", "16", "--actions", "absolute"],
         "policy 'grid-corner' on a world of moves = False"),
        (["--env", CS, "--glances", "16", "--actions", "relative", "--first-glance", "learned"],
         "first_glance = 'learned' with policy 'grid-corner'"),
    ],
)  # fmt: skip
def test_train_grid_corner_refuses_other_worlds(tmp_path, extra, message):
    r = run_ham_inprocess("train", "--policy", "grid-corner", "--steps", "2", "--out",
                str(tmp_path / "r"), *extra)  # fmt: skip
    assert message in one_line_error(r)
    assert not (tmp_path / "r").exists()


def test_grid_corner_needs_the_position():
    from ham.model.policy import CornerGridPolicy

    policy = CornerGridPolicy(4, 0.2)
    with pytest.raises(HamError, match="asked for glance 1 at position none"):
        policy.distribution_at(torch.zeros(2, 8), 1)
    with pytest.raises(HamError, match="before glance 1 of the episode"):
        policy.distribution_at(torch.zeros(2, 8), 2, torch.zeros(2, 2))
    with pytest.raises(HamError, match="move_length = -1; accepted: a finite number >= 0"):
        HamConfig(move_length=-1)
