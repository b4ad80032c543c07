"""Learners of your own: a loss from a plugin file (``ham train --plugin F --learner NAME``).

The example is the one the docs ship, docs/plugins/no_baseline.py: the paper's hybrid loss with
the reward in place of the advantage ``r - b`` (plain REINFORCE).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from ham.errors import HamError
from ham.learn import learners
from ham.learn.hybrid_loss import hybrid_loss, reinforce_term
from ham.model import plugin
from ham.model.agent import HamConfig, HapticAttentionModel
from tests.conftest import ok, one_line_error, registries_restored, run_ham, run_ham_inprocess

NO_BASELINE = Path(__file__).parents[1] / "docs/plugins/no_baseline.py"
TRAIN = ("--glances", "2", "--steps", "4", "--batch-size", "8", "--eval-every", "2",
         "--eval-batches", "2", "--seed", "3", "--no-progress")  # fmt: skip


def test_the_no_baseline_learner_is_the_hybrid_loss_with_the_reward_as_advantage(env):
    with registries_restored():
        plugin.load_plugin(plugin.read_plugin(NO_BASELINE))
        from ham.learn.train import TrainConfig

        config = TrainConfig(learner="no_baseline", beta=0.3)
        model = HapticAttentionModel(HamConfig(glances=3, n_objects=env.n_objects))
        episode = model(env, env.sample_objects(), torch.Generator().manual_seed(0))
        mine = learners.learner_loss("no_baseline", episode, config)
        paper = hybrid_loss(episode, 0.3)
        r = paper.reward
        assert torch.equal(mine.reward, r) and torch.equal(
            mine.classification, paper.classification
        )
        assert mine.baseline.item() == 0.0  # no baseline is trained
        advantage = r[None].expand(episode.values().shape)
        expected = reinforce_term(episode.locations[episode.chosen], episode.policy, advantage)
        assert torch.allclose(mine.reinforce, expected)
        assert not torch.allclose(mine.reinforce, paper.reinforce)  # the baseline is not 0
        assert torch.allclose(mine.total, mine.classification + 0.3 * mine.reinforce)
    assert "no_baseline" not in learners.LEARNERS


def test_a_plugin_learner_trains_and_the_run_loads_without_the_file(tmp_path, small_table):
    (tmp_path / "nb.py").write_text(NO_BASELINE.read_text())
    ok(run_ham_inprocess("train", "--table", small_table, "--plugin", "nb.py", "--learner",
                         "no_baseline", "--beta", "0.2", *TRAIN, "--out", "r", cwd=tmp_path))  # fmt: skip
    (tmp_path / "nb.py").unlink()
    config = json.loads((tmp_path / "r" / "config.json").read_text())
    assert (config["learner"], config["beta"], config["model"]["plugin"]["name"]) == (
        "no_baseline", 0.2, "nb.py")  # fmt: skip
    r = ok(run_ham("evaluate", "r", "--batches", "2", "--json", cwd=tmp_path))  # another process
    assert 0 <= json.loads(r.stdout)["accuracy"] <= 1
    ok(run_ham_inprocess("train", "--resume", "r", "--steps", "6", "--no-progress", cwd=tmp_path))
    assert json.loads((tmp_path / "r" / "metrics.json").read_text())["steps"] == 6
    assert "no_baseline" not in learners.LEARNERS  # the in-process runs restore the registries


def test_the_same_plugin_learner_and_seed_give_the_same_numbers(tmp_path, small_table):
    for out in ("a", "b"):
        ok(run_ham_inprocess("train", "--table", small_table, "--plugin", str(NO_BASELINE),
                             "--learner", "no_baseline", *TRAIN, "--out", out, cwd=tmp_path))  # fmt: skip
    a, b = (json.loads((tmp_path / d / "metrics.json").read_text())["history"] for d in "ab")
    assert a == b


def test_a_0_1_reward_of_ints_or_bools_is_taken_as_floats(tmp_path, small_table):
    """Rewards as a user may count them (correct or not) train and log as the float rewards do:
    the same seed gives the same history (before, a traceback in the reward's mean)."""
    (tmp_path / "f.py").write_text(_learner("loss"))
    (tmp_path / "b.py").write_text(_learner("dataclasses.replace(loss, reward=loss.reward.bool())")
                                   .replace("import torch\n", "import dataclasses, torch\n"))  # fmt: skip
    for name in ("f", "b"):
        ok(run_ham_inprocess("train", "--table", small_table, "--plugin", f"{name}.py",
                             "--learner", "bad", *TRAIN, "--out", name, cwd=tmp_path))  # fmt: skip
    f, b = (json.loads((tmp_path / d / "metrics.json").read_text())["history"] for d in "fb")
    assert f == b and any("reward" in json.dumps(h) for h in f)


def _learner(body: str, reads: str = "()") -> str:
    return (
        "import torch\nfrom ham.learn.hybrid_loss import HybridLoss, hybrid_loss\n"
        "from ham.learn.learners import register_learner\n"
        f"@register_learner('bad', reads={reads})\n"
        "def bad(episode, config):\n"
        "    loss = hybrid_loss(episode)\n"
        f"    return {body}\n"
    )


BAD = {
    "type.py": (_learner("loss.total"), "learner 'bad' returned a Tensor; accepted: a ham.learn"),
    "grad.py": (
        _learner(
            "HybridLoss(loss.total.detach(), loss.classification, loss.reinforce, "
            "loss.baseline, loss.reward)"
        ),  # fmt: skip
        "returned a total with no gradient",
    ),
    "leaf.py": (  # a tensor of its own that requires grad: it trained nothing, silently
        _learner(
            "HybridLoss(loss.total.detach().requires_grad_(), loss.classification, "
            "loss.reinforce, loss.baseline, loss.reward)"
        ),  # fmt: skip
        "returned a total with no gradient; accepted: a loss of the episode's outputs",
    ),
    "shape.py": (
        _learner(
            "HybridLoss(loss.total, loss.classification, loss.reinforce, loss.baseline, "
            "loss.reward[:3])"
        ),  # fmt: skip
        "returned reward (3,); accepted: a tensor (8,), one per episode",
    ),
    "scalar.py": (
        _learner(
            "HybridLoss(loss.total, loss.classification[None], loss.reinforce, "
            "loss.baseline, loss.reward)"
        ),  # fmt: skip
        "returned classification (1,); accepted: a scalar tensor",
    ),
    "complex.py": (  # a traceback in backward() before
        _learner(
            "HybridLoss(loss.total.to(torch.complex64), loss.classification, loss.reinforce, "
            "loss.baseline, loss.reward)"
        ),  # fmt: skip
        "returned total of torch.complex64 on cpu; accepted: real numbers on cpu (the episode's)",
    ),
    "meta.py": (
        _learner(
            "HybridLoss(loss.total, loss.classification, loss.reinforce, loss.baseline, "
            "loss.reward.to('meta'))"
        ),  # fmt: skip
        "returned reward of torch.float32 on meta; accepted: real numbers on cpu",
    ),
    "raises.py": (_learner("1 / 0"), "plugin 'raises.py' raised ZeroDivisionError at line 7"),
    "reads.py": (_learner("loss", "('lr',)"), "learner 'bad' reads 'lr'; accepted: a tuple"),
    "taken.py": (
        "from ham.learn.learners import register_learner\nregister_learner('hybrid')(print)\n",
        "learner 'hybrid' is registered already",
    ),
    "half.py": (
        "from ham.learn.learners import register_learner\nregister_learner('half')(print)\n1 / 0\n",
        "raised ZeroDivisionError at line 3",
    ),
}


@pytest.mark.parametrize("name", list(BAD))
def test_a_bad_plugin_learner_is_one_line(tmp_path, small_table, name):
    text, expected = BAD[name]
    (tmp_path / name).write_text(text)
    learner = "half" if name == "half.py" else "bad"
    before = dict(learners.LEARNERS)
    line = one_line_error(run_ham_inprocess("train", "--table", small_table, "--plugin", name,
                                            "--learner", learner, *TRAIN, "--out", "r",
                                            cwd=tmp_path))  # fmt: skip
    assert expected in line, line
    # refused at load, or failed in the first step: no run left, the same command runs again
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]
    if name in ("reads.py", "taken.py", "half.py"):  # refused at load: rolled back
        with pytest.raises(HamError):
            plugin.load_plugin(plugin.read_plugin(tmp_path / name))
    assert dict(learners.LEARNERS) == before


def test_a_learner_the_run_does_not_read_or_name_is_refused(tmp_path, small_table):
    args = ["train", "--table", small_table, *TRAIN, "--out", "r"]
    line = one_line_error(run_ham_inprocess(*args, "--learner", "mine", cwd=tmp_path))
    assert "learner = 'mine'; accepted: hybrid, info, sac, or a learner of your own" in line
    line = one_line_error(run_ham_inprocess(*args, "--plugin", str(NO_BASELINE), "--learner",
                                            "no_baseline", "--gamma", "0.9", cwd=tmp_path))  # fmt: skip
    assert "gamma = 0.9 with learner 'no_baseline', which does not read it" in line
    line = one_line_error(run_ham_inprocess(*args, "--plugin", str(NO_BASELINE), cwd=tmp_path))
    assert "learner 'hybrid', none of which it registers" in line
    assert "(learner no_baseline)" in line
    assert not (tmp_path / "r").exists()


def test_a_grid_runs_a_plugin_learner_alone_under_the_batched_executor(tmp_path, small_table):
    (tmp_path / "nb.py").write_text(NO_BASELINE.read_text())
    (tmp_path / "g.toml").write_text(
        'name = "learners"\nplugin = "nb.py"\n[table]\ngrid = 9\n'
        "[base]\nsteps = 2\nbatch_size = 8\neval_every = 2\neval_batches = 1\n"
        '[axes]\nlearner = ["hybrid", "no_baseline"]\n'
    )
    r = ok(run_ham_inprocess("reproduce", "grid", "g.toml", "--executor", "batched", "--workers",
                             "1", "--out", "o", cwd=tmp_path))  # fmt: skip
    assert "1 of 2 run(s) cannot be batched (run learner=no_baseline-s0: learner" in r.stderr
    runs = tmp_path / "o" / "runs"
    config = {d.name: json.loads((d / "config.json").read_text()) for d in runs.iterdir()}
    assert config["learner=hybrid-s0"]["model"]["plugin"] is None  # only its users keep it
    assert config["learner=no_baseline-s0"]["model"]["plugin"]["name"] == "nb.py"
    assert all(json.loads((d / "metrics.json").read_text())["steps"] == 2 for d in runs.iterdir())


def test_a_plugin_that_imports_the_learn_layer_itself_is_counted_and_rolled_back(tmp_path):
    """In a process that has not imported ham.learn, the learners' registry joins the plugin
    registries while the plugin runs: its learner counts, and a failure removes it."""
    import subprocess
    import sys

    (tmp_path / "half.py").write_text(NO_BASELINE.read_text() + "1 / 0\n")
    code = (
        "import sys\nfrom ham.model.plugin import load_plugin, read_plugin\n"
        "assert 'ham.learn.learners' not in sys.modules\n"
        f"print(load_plugin(read_plugin({str(NO_BASELINE)!r})))\n"
        "from ham.learn.learners import LEARNERS\nprint(list(LEARNERS))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.split("\n")[:2] == [
        "['learner no_baseline']", "['hybrid', 'info', 'sac', 'no_baseline']"]  # fmt: skip
    code = (
        "from ham.errors import HamError\nfrom ham.model.plugin import load_plugin, read_plugin\n"
        f"try:\n    load_plugin(read_plugin({str(tmp_path / 'half.py')!r}))\n"
        "except HamError as exc:\n    print(exc)\n"
        "from ham.learn.learners import LEARNERS\nprint(list(LEARNERS))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert "plugin 'half.py' raised ZeroDivisionError at line" in r.stdout
    assert r.stdout.strip().split("\n")[-1] == "['hybrid', 'info', 'sac']"
