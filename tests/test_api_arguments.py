"""The public Python functions refuse an argument of the wrong type in one line naming the
function and the argument (``ham.errors.checked_arguments``), as the configs do their fields
(tests/test_config_types.py): a NaN for a world, a dict for a config or a string for a list of
glances must not end as an AttributeError deep inside, nor be taken silently, and nothing is
written."""

import re
from pathlib import Path

import numpy as np
import pytest

from ham.envs import HapticGlanceEnv, HapticGlanceVectorEnv, ap
from ham.errors import HamError, brief
from ham.experiments.grid_run import run_grid
from ham.experiments.reproduce import reproduce
from ham.learn.ap_adapter import ApGymGlanceEnv
from ham.learn.evaluation import evaluate, heatmap_data
from ham.learn.learners import register_learner
from ham.learn.sb3_agents import Sb3Config, resume_sb3, train_sb3
from ham.learn.train import TrainConfig, fit_to_ap_gym, load_run, resume, train
from ham.model.core import register_core
from ham.model.policy import register_policy
from ham.world.cache import cache_dir
from ham.world.config import WorldConfig
from ham.world.files import check_output_dir
from ham.world.objects import HapticObject, register
from ham.world.simulators import register_simulator
from ham.world.table import (
    GlanceTable,
    build_table,
    import_authors,
    table_info,
    verify_table,
)

#: the functions a user calls from Python (docs): each checks its arguments first
PUBLIC = [build_table, GlanceTable.load, table_info, verify_table, import_authors, train, resume,
          load_run, evaluate, heatmap_data, reproduce, run_grid, train_sb3, resume_sb3,
          HapticGlanceEnv.__init__, HapticGlanceVectorEnv.__init__, ap.HapticGlanceAPEnv.__init__,
          ap.HapticGlanceAPVectorEnv.__init__, ApGymGlanceEnv.__init__, fit_to_ap_gym,
          HapticObject.from_function, HapticObject.from_polyline, HapticObject.from_surface,
          HapticObject.from_height_field, HapticObject.from_image, HapticObject.from_mesh,
          HapticObject.from_heightmap, register, register_policy, register_core,
          register_learner, register_simulator]  # fmt: skip

GRID = '[base]\nsteps = 2\n[axes]\n"model.glances" = [1, 2]\n'


def test_every_public_function_checks_its_arguments():
    for fn in PUBLIC:
        assert hasattr(fn, "__wrapped__"), fn.__qualname__


CASES = {
    "world": (lambda o: build_table(float("nan"), 3, o / "t.h5"),
              "build_table: world = nan; accepted: a WorldConfig"),
    "out-type": (lambda o: build_table(WorldConfig(), 3, 5),
                 "build_table: out = 5; accepted: a path (a str or an os.PathLike)"),
    "batch": (lambda o: build_table(WorldConfig(), 3, o / "t.h5", batch=0),
              "batch = 0; accepted: an integer >= 1"),
    "load-path": (lambda o: GlanceTable.load(None),
                  "GlanceTable.load: path = None; accepted: a path (a str or an os.PathLike)"),
    "load-memory": (lambda o: GlanceTable.load(o / "t.h5", max_memory=-1),
                    "max_memory = -1; accepted: a byte count >= 0"),
    "load-verify": (lambda o: GlanceTable.load(o / "t.h5", verify="no"),
                    "GlanceTable.load: verify = 'no'; accepted: true or false"),
    "info": (lambda o: table_info(b"t.h5"), "table_info: path = b't.h5'; accepted: a path"),
    "import": (lambda o: import_authors(o / "a.h5", o / "t.h5", axes=["x"]),
               "import_authors: axes = ['x']; accepted: a str"),
    "config": (lambda o: train({}, o / "r"), "train: config = {}; accepted: a TrainConfig"),
    "unknown": (lambda o: train(TrainConfig(), o / "r", progres=False),
                "train: got an unexpected keyword argument 'progres'"),
    "root": (lambda o: train(TrainConfig(), "/"),
             "--out '/' is the filesystem's root; accepted: a folder below it"),
    "resume": (lambda o: resume(o / "r", steps=2.5),
               "resume: steps = 2.5; accepted: an integer or None"),
    "load_run": (lambda o: load_run(o / "r", device=0),
                 "load_run: device = 0; accepted: a str or None"),
    "glances": (lambda o: reproduce("table1", "smoke", o / "p", glances=[1, "2"]),
                "reproduce: glances = [1, '2']; accepted: a list of integers or None"),
    "variants": (lambda o: reproduce("table1", "smoke", o / "p", variants="full"),
                 "reproduce: variants = 'full'; accepted: a list of strings or None"),
    "reproduce-world": (lambda o: reproduce("table1", "smoke", o / "p", world={}),
                        "reproduce: world = {}; accepted: a WorldConfig or None"),
    "eval-policy": (lambda o: reproduce("table1", "smoke", o / "p", eval_policy="greedy"),
                    "eval_policy = 'greedy'; accepted: mean, sample"),
    "cache": (lambda o: reproduce("table1", "smoke", o / "p", cache_dir=o / "c"),
              "without table_cache; accepted: cache_dir with table_cache=True"),
    "grid-batched": (lambda o: run_grid(o / "g.toml", o / "p", batched={}),
                     "run_grid: batched = {}; accepted: a BatchedOptions or None"),
    "grid-workers": (lambda o: run_grid(o / "g.toml", o / "p", workers=0),
                     "workers = 0; accepted: an integer >= 1"),
    "grid-out": (lambda o: run_grid(o / "g.toml", ""), "--out ''; accepted: a folder path"),
    "sb3": (lambda o: train_sb3(Sb3Config(), None),
            "train_sb3: out = None; accepted: a path (a str or an os.PathLike)"),
    "sb3-file": (lambda o: train_sb3(Sb3Config(), o / "g.toml"), "is a file; accepted: a folder"),
    "sb3-resume": (lambda o: resume_sb3(o / "r", env_steps="9"),
                   "resume_sb3: env_steps = '9'; accepted: an integer or None"),
}  # fmt: skip


@pytest.mark.parametrize("name", list(CASES))
def test_a_bad_argument_is_one_line_naming_it_and_nothing_is_written(tmp_path, name):
    call, expected = CASES[name]
    (tmp_path / "g.toml").write_text(GRID)
    with pytest.raises(HamError) as err:
        call(tmp_path)
    assert expected in str(err.value) and "\n" not in str(err.value), str(err.value)
    assert [p.name for p in tmp_path.iterdir()] == ["g.toml"]


def test_the_root_and_an_empty_path_are_refused_as_folders():
    with pytest.raises(HamError, match="'/' is the filesystem's root"):
        check_output_dir("/")
    with pytest.raises(HamError, match="'//..' is the filesystem's root"):
        check_output_dir("//..")
    with pytest.raises(HamError, match=r"cache dir ''; accepted: a folder path"):
        cache_dir("")
    assert check_output_dir(Path("/tmp")) == Path("/tmp")


def test_an_env_names_itself_not_its_constructor():
    with pytest.raises(
        HamError, match=r"^HapticGlanceEnv: got an unexpected keyword argument 'glance'$"
    ):
        HapticGlanceEnv(glance=2)


def test_a_message_is_one_line_whatever_the_value_and_arrays_are_brief():
    e = HamError(f"pose {np.zeros((3, 3))!r}; accepted: numbers")
    assert str(e) == "pose array([[0., 0., 0.], [0., 0., 0.], [0., 0., 0.]]); accepted: numbers"
    assert brief(np.zeros((64, 2))) == "an array of shape (64, 2) and dtype float64"
    assert brief(np.zeros(2)) == "array([0., 0.])"
    assert brief({"p": 1}) == "{'p': 1}" and brief("x" * 100) == repr("x" * 100)
    with pytest.raises(
        HamError, match=r"^evaluate: batches = an array of shape \(500,\) and dtype"
    ):
        evaluate(None, None, batches=np.zeros(500))  # 500 numbers were quoted before
    assert brief({"pose": np.zeros((64, 2)), "p": 1}) == "a dict with keys ['p', 'pose']"


@pytest.mark.parametrize(
    ("call", "message"),
    [
        # a bad name is refused when the decorator is made, not registered as it was before
        (lambda: register_policy("my policy"), "location policy name 'my policy'; accepted: letters"),
        (lambda: register_core(float("nan")), "register_core: name = nan; accepted: a str"),
        (lambda: register(HapticObject.from_polyline("fz_api", [[-0.04, 0.02], [0.04, 0.02]]),
                          replace=float("nan")),
         "register: replace = nan; accepted: true or false"),  # NaN was taken as True
        (lambda: HapticObject("fz_api", lambda x: x, vertices=float("nan")),
         "object 'fz_api': vertices nan; accepted: None or N >= 2 finite points (x, z)"),
        (lambda: HapticObject("fz_api", lambda x: x, surface_fn="dome"),
         "object 'fz_api': surface_fn 'dome' is not a function"),
        (lambda: fit_to_ap_gym(float("nan"), None), "fit_to_ap_gym: config = nan; accepted: a TrainConfig"),
    ],
)  # fmt: skip
def test_registries_and_objects_refuse_at_once(call, message):
    with pytest.raises(HamError, match="^" + re.escape(message)):
        call()
