"""A plugin (docs/agent.md, "Your own core or policy"): a GRU core in place of the paper's LSTM.

    ham train --plugin docs/plugins/gru_core.py --core gru --glances 2 --steps 3000 --out runs/gru
    ham reproduce grid docs/grids/plugin_gru.toml --workers 2 --out runs/plugin_gru

A core is a module with ``initial_state(batch, like)`` and ``forward(g, state) -> (tau, state)``;
``tau`` has ``hidden_size`` features, which the classifier, the baseline and the location
network read. A run keeps this file's text, so it is needed only to start the run.
"""

from torch import nn

from ham.model.core import register_core


class GRUCore(nn.Module):
    """``tau_s = GRU(g_s, tau_{s-1})``: one state vector, no cell state."""

    def __init__(self, input_size: int, hidden_size: int) -> None:
        super().__init__()
        self.hidden_size = hidden_size
        self.cell = nn.GRUCell(input_size, hidden_size)

    def initial_state(self, batch, like):
        return (like.new_zeros(batch, self.hidden_size),)

    def forward(self, g, state):
        h = self.cell(g, state[0])
        return h, (h,)


@register_core("gru")
def gru(input_size: int, hidden_size: int, **_) -> GRUCore:
    return GRUCore(input_size, hidden_size)
