"""Extension points: a user's own core plugs in by registration, without editing the package."""

from __future__ import annotations

import json

import torch
from torch import nn

from ham.learn.train import TrainConfig, train
from ham.model.agent import HamConfig, HapticAttentionModel
from ham.model.core import CORES, register_core


class GRUCore(nn.Module):
    def __init__(self, input_size: int, hidden_size: int) -> None:
        super().__init__()
        self.hidden_size = hidden_size
        self.cell = nn.GRUCell(input_size, hidden_size)

    def initial_state(self, batch: int, like: torch.Tensor):
        return (like.new_zeros(batch, self.hidden_size),)

    def forward(self, g, state):
        h = self.cell(g, state[0])
        return h, (h,)


def test_a_registered_core_trains(tmp_path):
    if "gru_test" not in CORES:
        register_core("gru_test")(lambda i, h, **_: GRUCore(i, h))
    model = HapticAttentionModel(HamConfig(core="gru_test", hidden_units=32))
    assert isinstance(model.core, GRUCore)
    # a registered core may read any core option: none is refused as unread (the built-in
    # cores' unread options are, tests/test_bad_inputs.py)
    HamConfig(core="gru_test", forget_bias=2.0, transformer_layers=3, lstm_activation="relu")
    config = TrainConfig(
        model=HamConfig(core="gru_test", hidden_units=32, glances=2),
        steps=4, eval_every=2, eval_batches=1, batch_size=8,
    )  # fmt: skip
    metrics = train(config, tmp_path / "run", progress=False)
    assert metrics["steps"] == 4
    saved = json.loads((tmp_path / "run" / "config.json").read_text())
    assert saved["model"]["core"] == "gru_test"


def test_unknown_core_names_the_registry():
    import pytest

    from ham.errors import HamError

    with pytest.raises(HamError, match="core = 'nope'; accepted: lstm, mlp"):
        HamConfig(core="nope")
