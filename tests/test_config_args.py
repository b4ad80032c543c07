"""The CLI is derived from the config dataclasses: one declaration per hyperparameter."""

from __future__ import annotations

import argparse
import dataclasses

import pytest

from ham.cli.config_args import add_config_options, choices, given, overrides
from ham.cli.main import build_parser
from ham.errors import HamError
from ham.learn.train import TrainConfig
from ham.model.agent import HamConfig


def train_parser() -> argparse.ArgumentParser:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices["train"]


def option_strings(parser: argparse.ArgumentParser) -> set[str]:
    return {s for a in parser._actions for s in a.option_strings}


@pytest.mark.parametrize(
    ("cls", "skip"),
    [
        (TrainConfig, {"model", "world", "table", "env"}),
        (HamConfig, {"n_objects", "pressure_dim", "moves", "move_length"}),  # set from the env
    ],
)
def test_every_field_is_an_option_of_ham_train(cls, skip):
    flags = option_strings(train_parser())
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        assert "--" + f.name.replace("_", "-") in flags, f.name


def test_choices_come_from_the_config():
    actions = {a.dest: a for a in train_parser()._actions}
    for cls in (TrainConfig, HamConfig):
        for f in dataclasses.fields(cls):
            if "choices" in f.metadata and isinstance(f.metadata["choices"], dict):
                # a registry (cores, policies) grows with --plugin after parsing: the config
                # checks it; the help names what is registered now
                assert actions[f.name].choices is None
                assert actions[f.name].metavar == "{" + ",".join(f.metadata["choices"]) + "}"
            elif "choices" in f.metadata:
                assert tuple(actions[f.name].choices) == tuple(f.metadata["choices"])
    assert choices(HamConfig, "core") == ("lstm", "mlp", "transformer")
    with pytest.raises(HamError, match="no field 'nope'"):
        choices(HamConfig, "nope")


def test_help_comes_from_the_docstring_with_the_real_default():
    actions = {a.dest: a for a in train_parser()._actions}
    assert "decay step size T" in actions["lr_step"].help
    assert "[default: 800]" in actions["lr_step"].help
    assert "[default: lstm]" in actions["core"].help


def test_only_given_values_override_and_booleans_have_both_forms():
    p = argparse.ArgumentParser()
    add_config_options(p, TrainConfig, skip={"model", "world", "table"})
    add_config_options(p, HamConfig, skip={"n_objects", "pressure_dim"})
    args = p.parse_args(["--lr", "0.01", "--no-bias", "--glances", "5", "--no-nesterov"])
    assert overrides(args, TrainConfig) == {"lr": 0.01, "nesterov": False}
    assert overrides(args, HamConfig) == {"glances": 5, "bias": False}
    assert sorted(given(args)) == ["--bias", "--glances", "--lr", "--nesterov"]
    config = TrainConfig(
        model=HamConfig(**overrides(args, HamConfig)), **overrides(args, TrainConfig)
    )
    assert config.lr == 0.01 and config.model.glances == 5 and config.model.bias is False
    assert config.batch_size == TrainConfig().batch_size


@pytest.mark.parametrize(
    "argv",
    # --core gru parses: a plugin may register it; the config refuses it (the test below)
    [["--lr", "inf"], ["--lr", "abc"], ["--steps", "1.5"], ["--combiner", "sum"]],
)
def test_bad_values_are_refused_by_the_parser(argv):
    p = argparse.ArgumentParser()
    add_config_options(p, TrainConfig, skip={"model", "world", "table"})
    add_config_options(p, HamConfig, skip={"n_objects", "pressure_dim"})
    with pytest.raises(SystemExit):
        p.parse_args(argv)


def test_config_validates_choices_with_the_same_list():
    with pytest.raises(HamError, match="core = 'gru'; accepted: lstm, mlp"):
        HamConfig(core="gru")
    with pytest.raises(HamError, match="eval_policy = 'best'; accepted: mean, sample"):
        TrainConfig(eval_policy="best")
