"""Plugins: a user's own core and location policy from a file, with no edit of the package.

``ham train --plugin FILE.py`` registers them; the run keeps the file's text, so the real CLI in
other processes (evaluate, heatmap, --resume) loads the run after the file is gone.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from ham.errors import HamError
from ham.model import core, plugin, policy
from ham.world import objects
from tests.conftest import ok, one_line_error, registries_restored, run_ham, run_ham_inprocess

# the GRU core that ships as the docs' example (registered as "gru"), plus a policy
PLUGIN = (
    (Path(__file__).parents[1] / "docs/plugins/gru_core.py").read_text()
    + """
import torch

from ham.model.policy import LocationPolicy, TruncatedGaussian, register_policy


@register_policy("plugin_state_free")
class StateFree(LocationPolicy):
    @classmethod
    def from_config(cls, config):
        return cls(len(config.pose_dims))

    def __init__(self, k):
        super().__init__()
        self.mu = nn.Parameter(torch.zeros(k))
        self.log_sigma = nn.Parameter(torch.full((k,), -0.5))

    def distribution(self, tau):
        shape = (tau.shape[0], self.mu.shape[0])
        return TruncatedGaussian(torch.tanh(self.mu).expand(shape),
                                 self.log_sigma.exp().expand(shape))
"""
)

TRAIN = ("--glances", "2", "--steps", "4", "--batch-size", "8", "--eval-every", "2",
         "--eval-batches", "2", "--seed", "3", "--no-progress")  # fmt: skip


def test_a_plugin_core_and_policy_train_and_the_run_loads_without_the_file(tmp_path):
    (tmp_path / "mine.py").write_text(PLUGIN)
    ok(run_ham("train", "--plugin", "mine.py", "--core", "gru", "--policy",
               "plugin_state_free", *TRAIN, "--out", "r", cwd=tmp_path))  # fmt: skip
    (tmp_path / "mine.py").unlink()  # the run keeps the text
    saved = json.loads((tmp_path / "r" / "config.json").read_text())["model"]
    assert (saved["core"], saved["policy"], saved["plugin"]["name"]) == (
        "gru", "plugin_state_free", "mine.py")  # fmt: skip
    # other processes: the real CLI
    r = ok(run_ham("evaluate", "r", "--batches", "2", "--json", cwd=tmp_path))
    assert 0 <= json.loads(r.stdout)["accuracy"] <= 1
    ok(run_ham_inprocess("heatmap", "r", "--out", "h.png", "--batches", "2", cwd=tmp_path))
    assert (tmp_path / "h.png").read_bytes()[:4] == b"\x89PNG"
    r = ok(run_ham_inprocess("train", "--resume", "r", "--steps", "6", "--no-progress",
                             cwd=tmp_path))  # fmt: skip
    assert json.loads((tmp_path / "r" / "metrics.json").read_text())["steps"] == 6
    # the registries of this process are as before (the in-process runs restore them)
    assert "gru" not in core.CORES and "plugin_state_free" not in policy.POLICIES


def test_the_same_plugin_and_seed_give_the_same_numbers(tmp_path):
    (tmp_path / "mine.py").write_text(PLUGIN)
    for out in ("a", "b"):
        ok(run_ham_inprocess("train", "--plugin", "mine.py", "--core", "gru", *TRAIN,
                             "--out", out, cwd=tmp_path))  # fmt: skip
    a, b = (json.loads((tmp_path / d / "metrics.json").read_text())["history"] for d in "ab")
    assert a == b


def test_an_altered_plugin_record_is_refused(tmp_path):
    (tmp_path / "mine.py").write_text(PLUGIN)
    ok(run_ham_inprocess("train", "--plugin", "mine.py", "--policy", "plugin_state_free", *TRAIN,
                         "--out", "r", cwd=tmp_path))  # fmt: skip
    path = tmp_path / "r" / "config.json"
    config = json.loads(path.read_text())
    config["model"]["plugin"]["source"] += "\nimport os\n"
    path.write_text(json.dumps(config))
    line = one_line_error(run_ham_inprocess("evaluate", "r", "--batches", "1", cwd=tmp_path))
    assert "plugin 'mine.py': recorded sha256" in line and "altered" in line


def test_a_run_of_an_unregistered_policy_says_how_to_register_it(tmp_path):
    line = one_line_error(run_ham_inprocess("train", "--policy", "mine", *TRAIN, "--out", "r",
                                            cwd=tmp_path))  # fmt: skip
    assert "policy = 'mine'" in line and "--plugin FILE.py" in line
    assert not (tmp_path / "r").exists()


BAD = {
    "missing.py": (None, "plugin 'missing.py' does not exist"),
    "": (None, "--plugin ''; accepted: a value"),
    "latin1.py": (b"# \xe9\n", "cannot read plugin 'latin1.py': 'utf-8' codec can't decode"),
    "mine.txt": ("x = 1\n", "accepted: a .py file that registers cores or location policies"),
    "empty.py": ("x = 1\n", "registers no core, location policy or learner; accepted: a file"),
    "syntax.py": ("def f(:\n", "syntax error at line 1"),
    "raises.py": ("x = 1\nraise ValueError('no\\nway')\n", "raised ValueError at line 2: no way"),
    "clash.py": (
        "from ham.model.core import register_core\nregister_core('lstm')(print)\n",
        "core 'lstm' is registered already",
    ),  # fmt: skip
    "objects.py": (
        "from ham.model.core import register_core\nregister_core('plugin_x')(print)\n"
        "from ham.world.objects import HapticObject, register\n"
        "register(HapticObject.from_polyline('plugin_obj', [(-0.045, 0.0), (0.045, 0.04)]))\n",
        "registers objects ['plugin_obj']; accepted: objects in an objects file",
    ),
    "half.py": (
        "from ham.model.core import register_core\nregister_core('plugin_y')(print)\n1 / 0\n",
        "raised ZeroDivisionError at line 3",
    ),  # fmt: skip
}


@pytest.mark.parametrize("name", list(BAD))
def test_a_bad_plugin_is_one_line_and_registers_nothing(tmp_path, name):
    text, expected = BAD[name]
    if isinstance(text, bytes):
        (tmp_path / name).write_bytes(text)
    elif text is not None:
        (tmp_path / name).write_text(text)
    before = (dict(core.CORES), dict(policy.POLICIES), objects.names(), dict(plugin._LOADED))
    line = one_line_error(run_ham_inprocess("train", "--plugin", name, *TRAIN, "--out", "r",
                                            cwd=tmp_path))  # fmt: skip
    assert expected in line, line
    assert not (tmp_path / "r").exists()
    # the Python API rolls back too (run_ham_inprocess would restore the registries anyway)
    if isinstance(text, str) and name.endswith(".py"):
        with pytest.raises(HamError):
            plugin.load_plugin(plugin.read_plugin(tmp_path / name))
    assert (
        dict(core.CORES),
        dict(policy.POLICIES),
        objects.names(),
        dict(plugin._LOADED),
    ) == before


def test_a_plugin_must_be_used(tmp_path):
    (tmp_path / "mine.py").write_text(PLUGIN)
    line = one_line_error(run_ham_inprocess("train", "--plugin", "mine.py", *TRAIN, "--out", "r",
                                            cwd=tmp_path))  # fmt: skip
    assert "neither of which it registers" in line and "policy plugin_state_free" in line
    line = one_line_error(run_ham_inprocess("train", "--resume", "r", "--plugin", "mine.py",
                                            cwd=tmp_path))  # fmt: skip
    assert "remove --plugin" in line


CORE_HEAD = """from torch import nn
from ham.model.core import register_core

class Core(nn.Module):
    def __init__(self, i, h):
        super().__init__()
        self.hidden_size, self.lin = h, nn.Linear(i, h)

    def initial_state(self, batch, like):
        return (like.new_zeros(batch, self.hidden_size),)

"""
POLICY_HEAD = """import torch
from ham.model.policy import LocationPolicy, TruncatedGaussian, register_policy

class Dist(TruncatedGaussian):
    pass

@register_policy("wrong")
class Wrong(LocationPolicy):
    @classmethod
    def from_config(cls, config):
        return cls()

"""
#: a plugin file whose core ``wrong`` (or policy) breaks the contract the model relies on
BAD_PARTS = {
    "width": (
        CORE_HEAD + "    def forward(self, g, state):\n        t = self.lin(g)[:, :-3]\n"
        "        return t, (t,)\n\n@register_core('wrong')\ndef f(i, h, **_):\n"
        "    return Core(i, h)\n",
        "core 'wrong' of 'bad.py' gave tau (2, 253) of torch.float32 on cpu for 2 episodes; "
        "accepted: (2, 256) of torch.float32 on cpu (its input's)",
    ),
    "dtype": (  # float64 tau met float32 weights: a traceback deep in the classifier
        CORE_HEAD + "    def forward(self, g, state):\n        t = self.lin(g).double()\n"
        "        return t, (t,)\n\n@register_core('wrong')\ndef f(i, h, **_):\n"
        "    return Core(i, h)\n",
        "core 'wrong' of 'bad.py' gave tau (2, 256) of torch.float64 on cpu for 2 episodes; "
        "accepted: (2, 256) of torch.float32 on cpu (its input's)",
    ),
    "meta": (
        CORE_HEAD + "    def forward(self, g, state):\n        t = self.lin(g).to('meta')\n"
        "        return t, (t,)\n\n@register_core('wrong')\ndef f(i, h, **_):\n"
        "    return Core(i, h)\n",
        "core 'wrong' of 'bad.py' gave tau (2, 256) of torch.float32 on meta for 2 episodes",
    ),
    "pair": (
        CORE_HEAD + "    def forward(self, g, state):\n        return self.lin(g)\n\n"
        "@register_core('wrong')\ndef f(i, h, **_):\n    return Core(i, h)\n",
        "core 'wrong' of 'bad.py' returned (2, 256); accepted: a pair (tau, state)",
    ),
    "module": (
        CORE_HEAD + "@register_core('wrong')\ndef f(i, h, **_):\n    return 42\n",
        "core 'wrong' of 'bad.py' built an int; accepted: a torch.nn.Module with initial_state",
    ),
    "factory": (
        CORE_HEAD + "@register_core('wrong')\ndef f(i, h, **_):\n    return Core(i, h, 3)\n",
        "core 'wrong' of 'bad.py' raised TypeError at line 14: ",
    ),
    "forward": (
        CORE_HEAD + "    def forward(self, g, state):\n        return 1 / 0\n\n"
        "@register_core('wrong')\ndef f(i, h, **_):\n    return Core(i, h)\n",
        "core 'wrong' of 'bad.py' raised ZeroDivisionError at line 13: division by zero",
    ),
    "distribution": (
        POLICY_HEAD + "    def distribution(self, tau):\n        return tau[:, :2]\n",
        "policy 'wrong' of 'bad.py' gave (2, 2); accepted: a ham.model.policy.LocationDistribution",
    ),
    "range": (
        POLICY_HEAD.replace(
            "    pass", "    def sample(self, generator):\n        return (self.mu + 3).detach()"
        )
        + "    def distribution(self, tau):\n        z = tau[:, :2]\n"
        "        return Dist(z, z + 1)\n",
        "policy 'wrong' of 'bad.py' sampled [[3.0, 3.0], [3.0, 3.0]] outside [-1, 1]; accepted: "
        "poses (2, 2) in [-1, 1]",
    ),
    "pose dtype": (  # float64 poses met float32 weights: a traceback in the where-network
        POLICY_HEAD.replace(
            "    pass", "    def sample(self, generator):\n        return self.mu.double()"
        )
        + "    def distribution(self, tau):\n        z = torch.tanh(tau[:, :2])\n"
        "        return Dist(z, z.abs() + 1)\n",
        "policy 'wrong' of 'bad.py' sampled poses of torch.float64 on cpu; accepted: poses (2, 2) "
        "in [-1, 1] of torch.float32 on cpu (the model's)",
    ),
    "pose grad": (
        POLICY_HEAD.replace(
            "    pass",
            "    def sample(self, generator):\n        return self.mu.detach().requires_grad_()",
        )
        + "    def distribution(self, tau):\n        z = torch.tanh(tau[:, :2])\n"
        "        return Dist(z, z.abs() + 1)\n",
        "policy 'wrong' of 'bad.py' sampled poses that require grad; accepted: poses (2, 2) in "
        "[-1, 1] without a gradient (detach them: the policy learns through log_prob)",
    ),
    "log_prob grad": (  # a trainable policy that REINFORCE could not train: silent before
        POLICY_HEAD.replace(
            "    pass",
            "    def log_prob(self, q):\n        return TruncatedGaussian.log_prob(self, q).detach()",
        )
        + "    def distribution(self, tau):\n        z = torch.tanh(tau[:, :2])\n"
        "        return Dist(z, z.abs() + 1)\n",
        "policy 'wrong' of 'bad.py' gave a log_prob without a gradient; accepted: a log_prob of "
        "the distribution's parameters",
    ),
    "log_prob": (
        POLICY_HEAD.replace("    pass", "    def log_prob(self, q):\n        return q")
        + "    def distribution(self, tau):\n        z = tau[:, :2]\n"
        "        return Dist(z, z + 1)\n",
        "policy 'wrong' of 'bad.py' gave log_prob (2, 2); accepted: (2,), one value per episode",
    ),
}


@pytest.mark.parametrize("name", list(BAD_PARTS))
def test_a_plugin_core_or_policy_that_breaks_the_contract_is_one_line(tmp_path, name):
    text, expected = BAD_PARTS[name]
    (tmp_path / "bad.py").write_text(text)
    part = "--policy" if "policy" in expected[:7] else "--core"
    line = one_line_error(run_ham_inprocess("train", "--plugin", "bad.py", part, "wrong", *TRAIN,
                                            "--online", "--out", "r", cwd=tmp_path))  # fmt: skip
    assert expected in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.py"]  # no run left


#: a core that passes the contract check (2 episodes) and fails in training (8 a batch)
LATE = (
    CORE_HEAD + "    def forward(self, g, state):\n        if g.shape[0] != 2:\n"
    "            raise ValueError(f'{g.shape[0]} episodes')\n        t = self.lin(g)\n"
    "        return t, (t,)\n\n@register_core('late')\ndef f(i, h, **_):\n    return Core(i, h)\n"
)


def test_a_plugin_core_that_fails_in_training_is_one_line_naming_its_file_and_line(tmp_path):
    (tmp_path / "late.py").write_text(LATE)
    line = one_line_error(run_ham_inprocess("train", "--plugin", "late.py", "--core", "late",
                                            *TRAIN, "--online", "--out", "r", cwd=tmp_path))  # fmt: skip
    assert line == "ham: error: plugin 'late.py' raised ValueError at line 14: 8 episodes", line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["late.py"]  # failed at step 0: no run
    # a grid's report names it too (the single-run and the batched executors' runs alike)
    (tmp_path / "g.toml").write_text(
        GRID.replace("mine.py", "late.py").replace('["lstm", "gru"]', '["late"]')
    )
    (tmp_path / "plugins").mkdir()
    (tmp_path / "late.py").rename(tmp_path / "plugins" / "late.py")
    for executor in ("local", "batched"):
        r = run_ham_inprocess("reproduce", "grid", "g.toml", "--out", executor, "--executor",
                              executor, "--workers", "1", "--quiet", cwd=tmp_path)  # fmt: skip
        assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
        report = (tmp_path / executor / "report.md").read_text()
        assert "- `core=late-s0`: plugin 'late.py' raised ValueError at line 14: 8 episodes" in (
            report
        ), report


#: a core and a policy that keep the contract on the check's 2 episodes and break it on a
#: training batch (8): a shape, not an exception, so no user line to name; the model checks
LATE_SHAPES = {
    "core": (
        CORE_HEAD + "    def forward(self, g, state):\n        t = self.lin(g[:2])\n"
        "        return t, (t,)\n\n@register_core('wrong')\ndef f(i, h, **_):\n"
        "    return Core(i, h)\n",
        "ham: error: core 'wrong' of 'bad.py' gave tau (2, 256) of torch.float32 on cpu for 8 "
        "episodes; accepted: (8, 256) of torch.float32 on cpu (its input's), hidden_size floats "
        "per episode",
    ),
    "policy": (
        POLICY_HEAD.replace(
            "    pass",
            "    def sample(self, generator):\n        return self.mu.clamp(-1, 1)[:2].detach()",
        )
        + "    def distribution(self, tau):\n        z = torch.tanh(tau[:, :2])\n"
        "        return Dist(z, z.abs() + 1)\n",
        "ham: error: policy 'wrong' of 'bad.py' sampled (2, 2) for 8 episodes; accepted: poses "
        "(8, 2) in [-1, 1]",
    ),
}


@pytest.mark.parametrize("part", list(LATE_SHAPES))
def test_a_plugin_part_that_breaks_the_contract_only_in_training_is_one_line(tmp_path, part):
    text, expected = LATE_SHAPES[part]
    (tmp_path / "bad.py").write_text(text)
    line = one_line_error(run_ham_inprocess("train", "--plugin", "bad.py", f"--{part}", "wrong",
                                            *TRAIN, "--online", "--out", "r", cwd=tmp_path))  # fmt: skip
    assert line == expected, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.py"]


def test_a_failure_of_ours_is_not_put_on_a_user_file(tmp_path):
    from ham.world import recorded_file

    with registries_restored():
        recorded_file.run_python("plugin", "mine.py", "def f():\n    return 1 / 0\n", "m")
        with pytest.raises(ValueError) as ours:  # raised by code of ours, not the file's
            int("x")
        assert recorded_file.raised_in(ours.value) is None
        namespace: dict = {}
        exec(compile("def f():\n    return 1 / 0\n", "mine.py", "exec"), namespace)
        try:
            namespace["f"]()
        except ZeroDivisionError as exc:
            assert recorded_file.raised_in(exc) == (
                "plugin 'mine.py' raised ZeroDivisionError at line 2: division by zero"
            )
    assert "mine.py" not in recorded_file._RAN


def test_the_contract_check_leaves_the_core_and_the_random_numbers_as_they_were(tmp_path):
    import torch

    from ham.model.agent import HamConfig, HapticAttentionModel

    # a core that draws random numbers (dropout) and keeps running statistics (batch norm)
    (tmp_path / "mine.py").write_text(
        CORE_HEAD.replace("nn.Linear(i, h)", "nn.Sequential(nn.Linear(i, h), "
                          "nn.BatchNorm1d(h), nn.Dropout(0.5))")
        + "    def forward(self, g, state):\n        t = self.lin(g)\n        return t, (t,)\n"
        "\n@register_core('noisy')\ndef f(i, h, **_):\n    return Core(i, h)\n"
    )  # fmt: skip
    with registries_restored():
        config = HamConfig(glances=2, core="noisy", plugin=plugin.read_plugin(tmp_path / "mine.py"))
        torch.manual_seed(0)
        a = HapticAttentionModel(config)
        after = torch.rand(3)
        torch.manual_seed(0)
        with pytest.MonkeyPatch.context() as m:  # the same model without the checks
            m.setattr("ham.model.agent.check_core", lambda *a: None)
            m.setattr("ham.model.agent.check_policy", lambda *a: None)
            b = HapticAttentionModel(config)
        assert torch.equal(after, torch.rand(3))
    for (k, v), (k2, v2) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        assert k == k2 and torch.equal(v, v2), k


GRID = """
name = "plugged"
plugin = "plugins/mine.py"
[base]
steps = 2
batch_size = 8
eval_every = 2
eval_batches = 1
[axes]
"model.core" = ["lstm", "gru"]
"""


def test_a_grid_names_its_plugin_and_only_the_runs_that_use_it_keep_it(tmp_path):
    (tmp_path / "plugins").mkdir()
    (tmp_path / "plugins" / "mine.py").write_text(PLUGIN)  # beside the grid file, not the cwd
    (tmp_path / "g.toml").write_text(GRID)
    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    # the local executor's worker processes load the plugin from the grid's record
    r = run_ham_inprocess("reproduce", "grid", "../g.toml", "--out", "out", "--workers", "1",
                          "--quiet", cwd=cwd)  # fmt: skip
    ok(r)
    runs = cwd / "out" / "runs"
    model = {d.name: json.loads((d / "config.json").read_text())["model"] for d in runs.iterdir()}
    assert model["core=lstm-s0"]["plugin"] is None
    assert model["core=gru-s0"]["plugin"]["name"] == "mine.py"
    assert json.loads((runs / "core=gru-s0" / "metrics.json").read_text())["steps"] == 2
    # the batched executor cannot stack a core of the user's: that run trains alone, as the
    # local executor trains it (the same numbers), and the terminal and the report say so
    r = ok(run_ham_inprocess("reproduce", "grid", "../g.toml", "--out", "b", "--executor",
                             "batched", "--workers", "1", cwd=cwd))  # fmt: skip
    note = "1 of 2 run(s) cannot be batched (run core=gru-s0: core 'gru' cannot be batched)"
    assert note in r.stderr and note in (cwd / "b" / "report.md").read_text()
    history = [json.loads((cwd / d / "runs" / "core=gru-s0" / "metrics.json").read_text())["history"]
               for d in ("out", "b")]  # fmt: skip
    assert history[0] == history[1]
    assert json.loads((cwd / "b" / "runs" / "core=lstm-s0" / "metrics.json").read_text())[
        "steps"] == 2  # fmt: skip


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        ('plugin = "plugins/gone.py"', "plugin 'plugins/gone.py' does not exist"),
        ("plugin = 3", "plugin = 3; accepted: the path of a .py plugin file"),
        ('"model.plugin" = "x.py"', "key 'model.plugin' is set by the grid's plugin = FILE.py"),
        (
            '"model.core" = ["lstm", "mlp"]',
            "registers core gru, policy plugin_state_free, which no cell uses",
        ),  # fmt: skip
    ],
)
def test_a_grid_with_a_bad_plugin_is_refused(tmp_path, edit, expected):
    (tmp_path / "plugins").mkdir()
    (tmp_path / "plugins" / "mine.py").write_text(PLUGIN)
    if edit.startswith('"model.core"'):  # the plugin's core named by no cell
        text = GRID.replace('"model.core" = ["lstm", "gru"]', edit)
    elif edit.startswith('"model.plugin"'):
        text = GRID.replace('plugin = "plugins/mine.py"', "").replace("[base]", "[base]\n" + edit)
    else:
        text = GRID.replace('plugin = "plugins/mine.py"', edit)
    (tmp_path / "g.toml").write_text(text)
    line = one_line_error(run_ham_inprocess("reproduce", "grid", "g.toml", "--out", "o",
                                            cwd=tmp_path))  # fmt: skip
    assert expected in line, line
    assert not (tmp_path / "o").exists()
