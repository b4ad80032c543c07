"""Every config dataclass refuses a value of the wrong type in its fields, in one line naming the
field (``ham.errors.check_types``): a saved config, a grid file or a Python caller may hand in
anything, and a NaN or a string must not slip past the range checks into a run."""

import dataclasses
import math
import re
import typing

import numpy as np
import pytest

from ham.errors import HamError, check_types
from ham.experiments.executors import BatchedOptions
from ham.learn.ap_adapter import ApGymConfig
from ham.learn.sb3_agents import Sb3Config
from ham.learn.train import TrainConfig
from ham.model.agent import HamConfig
from ham.world.config import WorldConfig
from ham.world.glance import GlanceConfig, PoseConfig
from ham.world.mujoco_sim import MujocoConfig
from ham.world.sensor import SensorConfig
from ham.world.source import ObjectPoseConfig

CONFIGS = {
    HamConfig: {},
    WorldConfig: {},
    PoseConfig: {},
    GlanceConfig: {},
    ObjectPoseConfig: {},
    MujocoConfig: {},
    SensorConfig: {},
    BatchedOptions: {},
    ApGymConfig: {"env": "ap_gym:CircleSquare-v0"},
    Sb3Config: {},
    TrainConfig: {},
}

#: Values of the wrong type for each simple annotation (for ``X | None`` those of ``X`` but None).
WRONG = {
    bool: [0, 1, 1.0, "true", None, [], math.nan],
    int: [1.5, 2.0, True, "3", None, [], math.nan, 2**63, -(2**63) - 1],  # beyond torch's
    float: [math.nan, math.inf, -math.inf, True, "0.5", None, [], {}, 1e300, -1e39, 10**400],
    str: [0, 1.5, True, None, [], {}, math.nan],
    dict: [0, "a", [], None, math.nan],
}


def _cases():
    for cls, required in CONFIGS.items():
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            kind = hints[f.name]
            args = [a for a in typing.get_args(kind) if a is not type(None)]
            optional = type(None) in typing.get_args(kind)
            base = args[0] if optional and len(args) == 1 else kind
            values = [v for v in WRONG.get(base, []) if not (optional and v is None)]
            if values:
                yield pytest.param(cls, required, f.name, values, id=f"{cls.__name__}.{f.name}")


CASES = list(_cases())


def test_every_config_has_fields_checked_by_type():
    assert {c.values[0] for c in CASES} == set(CONFIGS)
    assert len(CASES) > 100


@pytest.mark.parametrize("cls, required, name, values", CASES)
def test_a_value_of_the_wrong_type_is_refused_in_one_line(cls, required, name, values):
    for value in values:
        with pytest.raises(HamError) as e:
            cls(**{**required, name: value})
        message = str(e.value)
        assert "\n" not in message and f"{name} = {value!r}" in message, message
        assert "accepted:" in message, message


@pytest.mark.parametrize("cls", CONFIGS)
def test_the_defaults_pass(cls):
    check_types(cls(**CONFIGS[cls]))


def test_numbers_of_numpy_and_ints_for_floats_are_accepted():
    assert HamConfig(forget_bias=1, sigma_min=np.float32(0.01)).forget_bias == 1
    assert SensorConfig(taxels=np.int64(8), pitch=0.01).taxels == 8


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"readout": "pixels"}, "readout = 'pixels'; accepted: taxels, gazebo"),
        ({"solref": 0.02}, "solref = 0.02; accepted: a list of 2 finite numbers or None"),
        ({"solref": [0.02, math.nan]}, "solref = [0.02, nan]; accepted: a list of 2 finite"),
        ({"solimp": [0.9, 0.95, 0.001]}, "solimp = [0.9, 0.95, 0.001]; accepted: a list of 5"),
        ({"threads": 1.5}, "threads = 1.5; accepted: an integer or None"),
    ],
)
def test_literals_tuples_and_optionals_say_what_they_take(kwargs, message):
    with pytest.raises(HamError, match="^" + re.escape(message)):
        MujocoConfig(**kwargs)


def test_an_integer_beyond_64_bits_is_refused_for_its_size():
    # an overflow inside torch before (``zeros(): ... Overflow when unpacking long long``)
    with pytest.raises(HamError, match=r"^glances = 10{30}; accepted: an integer of at most 64"):
        HamConfig(glances=10**30)
    assert HamConfig(n_objects=2**63 - 1).n_objects == 2**63 - 1  # the largest torch takes


def test_a_number_beyond_float32_is_refused_for_its_size():
    # finite, and an overflow in the optimizer's float32 step before
    with pytest.raises(HamError, match=r"^lr = 1e\+300; accepted: a finite number within float32"):
        TrainConfig(lr=1e300)
    assert TrainConfig(lr=3e38).lr == 3e38  # within float32: it diverges, as a large lr does


def test_a_nested_config_must_be_its_dataclass():
    with pytest.raises(
        HamError, match=r"^env = 'ap_gym:CircleSquare-v0'; accepted: an ApGymConfig or None$"
    ):
        TrainConfig(env="ap_gym:CircleSquare-v0")


def test_a_negative_sigma_floor_is_refused_by_the_config_not_first_by_the_model():
    with pytest.raises(HamError, match=r"^sigma_min = -1; accepted: a finite number >= 0$"):
        HamConfig(sigma_min=-1)
