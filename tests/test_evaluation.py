"""Evaluation: the confusion matrix and per-object accuracy, in ham evaluate and metrics.json."""

from __future__ import annotations

import json

import pytest
import torch

from ham.errors import HamError
from ham.experiments.figures import plot_confusion
from ham.learn.evaluation import SWAPS, evaluate, last_pose_swap, swap_partners
from ham.learn.train import TrainConfig, load_run, train
from ham.model.agent import HamConfig, HapticAttentionModel


def _evaluated_again(agent, env, batches: int, seed: int) -> list:
    """The episodes of ``evaluate(agent, env, batches, seed=seed)`` (mean poses) played again by
    hand, ``(objects, episode)`` per batch: evaluation draws only from its seeded generator."""
    g = torch.Generator().manual_seed(seed)
    agent.eval()
    with torch.no_grad():
        return [
            (o, agent(env, o, g, greedy=True)) for o in map(env.balanced_objects, range(batches))
        ]


@pytest.mark.parametrize("policy", ["learned", "random"])
def test_confusion_matrix_counts_every_episode_by_true_and_predicted_object(env, policy):
    torch.manual_seed(3)
    agent = HapticAttentionModel(HamConfig(glances=3, policy=policy))
    result = evaluate(agent, env, batches=3, seed=5)
    # the same episodes again, counted by hand
    expected = torch.zeros(3, 4, 4, dtype=torch.long)
    for objects, episode in _evaluated_again(agent, env, 3, 5):
        predicted = episode.logits.argmax(-1)
        for s in range(3):
            for o, p in zip(objects.tolist(), predicted[s].tolist(), strict=True):
                expected[s, o, p] += 1
    assert result.confusion == expected.tolist()
    assert result.objects == ["box", "ramp_up", "convex", "ramp_down"]
    for s in range(3):
        assert expected[s].sum(1).tolist() == [6, 6, 6, 6]  # balanced: 24 episodes
        assert expected[s].trace().item() / 24 == pytest.approx(result.accuracy_per_glance[s])
    last = expected[-1]
    assert result.per_object_accuracy == [last[o, o].item() / 6 for o in range(4)]


@pytest.mark.parametrize("policy", ["learned", "random"])
def test_pose_spread_is_the_poses_standard_deviation_over_the_episodes(env, policy):
    torch.manual_seed(3)
    agent = HapticAttentionModel(HamConfig(glances=3, policy=policy))
    result = evaluate(agent, env, batches=4, seed=5)
    # the same episodes again, their poses' spread computed directly
    runs = _evaluated_again(agent, env, 4, 5)
    objects = torch.cat([o for o, _ in runs])
    q = torch.cat([episode.locations for _, episode in runs], 1).double()  # (S, 32, 2)
    overall = q.var(1, unbiased=False).mean(-1).sqrt()
    within = torch.stack(
        [q[:, objects == o].var(1, unbiased=False) for o in range(4)]  # 8 episodes each
    ).mean(0).mean(-1).sqrt()  # fmt: skip
    assert result.pose_spread == pytest.approx(overall.tolist(), abs=1e-9)
    assert result.pose_spread_within_object == pytest.approx(within.tolist(), abs=1e-9)
    # the first glance is uniform in [-1, 1]^2 (std 1/sqrt(3)), and so is every random one
    assert 0.4 < result.pose_spread[0] < 0.75
    if policy == "random":
        assert all(0.4 < s < 0.75 for s in result.pose_spread)


def test_a_fixed_sequence_of_glances_has_no_pose_spread(env):
    """The grid policy's glances ignore what was felt: from the second on, every episode is at
    the same pose."""
    agent = HapticAttentionModel(HamConfig(glances=3, policy="grid"))
    result = evaluate(agent, env, batches=2, seed=1)
    assert result.pose_spread[1:] == [0.0, 0.0]
    assert result.pose_spread_within_object[1:] == [0.0, 0.0]


def test_metrics_carry_the_confusion_matrix(tmp_path):
    config = TrainConfig(model=HamConfig(glances=2), steps=4, batch_size=8, eval_every=2,
                         eval_batches=2, seed=3)  # fmt: skip
    m = train(config, tmp_path / "r", progress=False)
    for record in m["history"]:
        confusion = record["confusion"]
        assert len(confusion) == 4 and sum(map(sum, confusion)) == 16
        assert record["per_object_accuracy"] == [confusion[o][o] / 4 for o in range(4)]
    assert m["confusion"] == m["history"][-1]["confusion"]
    assert m["per_object_accuracy"] == m["history"][-1]["per_object_accuracy"]
    on_disk = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert on_disk["history"][-1]["confusion"] == m["confusion"]


def test_per_object_accuracy_of_an_object_never_shown_is_none(env):
    """ap_gym's labels follow its data: an object may not appear in an evaluation."""

    class OneObject:
        def __init__(self, inner):
            self.inner, self.n_objects, self.batch_size = inner, 4, inner.batch_size
            self.objects, self.device = inner.objects, inner.device

        def balanced_objects(self, batch_index=0):
            return torch.zeros(self.batch_size, dtype=torch.long)

        def glance(self, objects, q):
            return self.inner.glance(objects, q)

    agent = HapticAttentionModel(HamConfig(glances=2))
    result = evaluate(agent, OneObject(env), batches=1)
    assert result.per_object_accuracy[1:] == [None, None, None]
    assert result.per_object_accuracy[0] == result.accuracy


def test_plot_confusion(tmp_path):
    out = plot_confusion([[5, 1], [0, 6]], ["a", "b"], tmp_path / "sub" / "c.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in out.parent.iterdir()] == ["c.png"]  # no temporary file left
    big = torch.randint(0, 9, (20, 20)).tolist()  # many classes: no numbers in the cells
    assert plot_confusion(big, [str(k) for k in range(20)], tmp_path / "big.png").exists()
    with pytest.raises(HamError, match=r"shape \(2, 3\); accepted: \(2, 2\)"):
        plot_confusion([[1, 2, 3], [4, 5, 6]], ["a", "b"], tmp_path / "x.png")
    with pytest.raises(HamError, match="negative"):
        plot_confusion([[1, -2], [0, 1]], ["a", "b"], tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()


def test_swap_partners_take_the_same_object_elsewhere_and_every_other_object():
    objects = torch.arange(24) % 4  # a balanced batch
    same, other = swap_partners(objects, 4)
    assert (objects[same] == objects).all() and (same != torch.arange(24)).all()
    assert (objects[other] != objects).all()
    for o in range(4):  # every other object in turn
        assert set(objects[other][objects == o].tolist()) == set(range(4)) - {o}
    odd = torch.tensor([2, 0, 1, 0, 2, 1, 1])  # unbalanced, unordered
    same, other = swap_partners(odd, 3)
    assert (odd[same] == odd).all() and (same != torch.arange(7)).all()
    assert (odd[other] != odd).all()
    with pytest.raises(HamError, match=r"\[2, 1, 2\] episodes per object; accepted: >= 2"):
        swap_partners(torch.tensor([0, 0, 1, 2, 2]), 3)


@pytest.mark.parametrize("core", ["lstm", "mlp"])
def test_last_pose_swap_own_is_the_evaluation_and_a_fixed_sweep_loses_nothing(env, core, tmp_path):
    # briefly trained: untrained, a classifier may answer one class whatever it feels
    config = TrainConfig(model=HamConfig(glances=3, core=core), steps=40, batch_size=8,
                         eval_every=40, eval_batches=1, seed=1)  # fmt: skip
    train(config, tmp_path / "r", progress=False)
    run = load_run(tmp_path / "r")
    agent = run.agent
    run.close()
    swap = last_pose_swap(agent, env, batches=3, seed=7, policy="sample")
    result = evaluate(agent, env, batches=3, seed=7, policy="sample")
    answered = [c for c in range(4) if any(row[c] for row in result.confusion[-1])]
    assert len(answered) >= 2  # answers that depend on the glances
    assert swap["own"] == pytest.approx(result.accuracy, abs=1e-6)  # the same count of 24
    if core == "mlp":  # no memory: the same object's poses, permuted, are the same glances
        assert swap["same_object"] == swap["own"]
    assert swap["episodes"] == 24 and set(swap) == {*SWAPS, "batches", "episodes"}
    # A fixed sweep sends every episode's last glance to one pose: any swap is the same glance.
    sweep = HapticAttentionModel(HamConfig(glances=3, core=core, policy="grid"))
    sweep.load_state_dict(agent.state_dict(), strict=False)  # the trained classifier; no policy
    swap = last_pose_swap(sweep, env, batches=3, seed=7)
    result = evaluate(sweep, env, batches=3, seed=7)
    assert sum(any(row[c] for row in result.confusion[-1]) for c in range(4)) >= 2
    assert swap["own"] == swap["same_object"] == swap["other_object"]
    assert swap["own"] == pytest.approx(result.accuracy, abs=1e-6)
    with pytest.raises(HamError, match="on object; accepted: a haptic world"):
        last_pose_swap(agent, object())


def test_a_progress_bar_changes_no_number(env, capsys):
    # The CLI's evaluations show a bar on stderr; the episodes and counts stay those without it.
    from ham.learn.evaluation import heatmap_data

    torch.manual_seed(4)
    agent = HapticAttentionModel(HamConfig(glances=2))
    quiet = evaluate(agent, env, batches=3, seed=2, policy="sample")
    assert capsys.readouterr().err == ""
    shown = evaluate(agent, env, batches=3, seed=2, policy="sample", progress=True)
    assert "evaluate" in capsys.readouterr().err
    assert shown == quiet
    assert heatmap_data(agent, env, 3, seed=2, progress=True) == heatmap_data(agent, env, 3, seed=2)
    swaps = last_pose_swap(agent, env, 3, seed=2, progress=True)
    assert "last pose swaps" in capsys.readouterr().err
    assert swaps == last_pose_swap(agent, env, 3, seed=2)


def test_the_pose_spread_is_in_the_history_and_on_tensorboard(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    config = TrainConfig(model=HamConfig(glances=2), steps=4, batch_size=8, eval_every=2,
                         eval_batches=2, seed=3)  # fmt: skip
    m = train(config, tmp_path / "r", progress=False)
    assert m["pose_spread"] == m["history"][-1]["pose_spread"]
    events = EventAccumulator(str(tmp_path / "r" / "tb"))
    events.Reload()
    for s in range(2):
        logged = [(e.step, e.value) for e in events.Scalars(f"eval/pose_spread_glance_{s + 1}")]
        want = [(h["step"], h["pose_spread"][s]) for h in m["history"]]
        assert [t for t, _ in logged] == [t for t, _ in want]
        assert [v for _, v in logged] == pytest.approx([v for _, v in want], rel=1e-6)
