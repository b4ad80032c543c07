"""The tactile network: combine *what* (the pressure profile) with *where* (the pose).

Section "The Tactile Network" of the paper: the normalized pressure vector ``p`` (256 values)
passes one dense ReLU layer of 64 units ("what"), the location ``l = (x, phi)`` another dense
ReLU layer of 64 units ("where"); the two are combined by one of four combiners (Table 2,
"What & Where"):

* ``concat2`` (default): concatenate, then two dense ReLU layers;
* ``concat1``: concatenate, then one dense ReLU layer;
* ``add``: element-wise addition of what and where;
* ``mul``: element-wise multiplication of what and where.

Widths: the paper's hyperparameter table says "size of linear layers: 64 neurons"; the authors'
code uses 256 units for each of the two layers after the concatenation, and only with 256 does the
paper's parameter count (741,248; docs/sources.md) come out. We follow the code: ``combine_units``
= 256 by default, a parameter to set 64 for the table's reading.
"""

from __future__ import annotations

import torch
from torch import nn

from ham.errors import HamError

COMBINERS: tuple[str, ...] = ("concat2", "concat1", "add", "mul")


class TactileNetwork(nn.Module):
    """``g = combine(relu(W_p p), relu(W_l l))``: the feature of one glance.

    Args:
        pressure_dim: length of the flattened, normalized pressure vector (256).
        location_dim: length of the location vector (2: ``x`` and ``phi``).
        what_units: width of the pressure layer (64).
        where_units: width of the location layer (64; must equal ``what_units`` for add / mul).
        combiner: one of :data:`COMBINERS`.
        combine_units: width of the dense layers after a concatenation (256, authors' code).
        bias: give the dense layers a bias (the authors' code has none).
    """

    def __init__(
        self,
        pressure_dim: int = 256,
        location_dim: int = 2,
        what_units: int = 64,
        where_units: int = 64,
        combiner: str = "concat2",
        combine_units: int = 256,
        bias: bool = True,
    ) -> None:
        super().__init__()
        if combiner not in COMBINERS:
            raise HamError(f"combiner {combiner!r}; accepted: {', '.join(COMBINERS)}")
        if combiner in ("add", "mul") and what_units != where_units:
            raise HamError(
                f"combiner {combiner!r} needs what_units == where_units, "
                f"got {what_units} and {where_units}"
            )
        self.combiner = combiner
        self.what = nn.Linear(pressure_dim, what_units, bias=bias)
        self.where = nn.Linear(location_dim, where_units, bias=bias)
        layers: list[nn.Module] = []
        if combiner in ("concat2", "concat1"):
            n_layers = 2 if combiner == "concat2" else 1
            width = what_units + where_units
            for _ in range(n_layers):
                layers += [nn.Linear(width, combine_units, bias=bias), nn.ReLU()]
                width = combine_units
            self.out_features = combine_units
        else:
            self.out_features = what_units
        self.combine = nn.Sequential(*layers)

    def forward(self, pressure: torch.Tensor, location: torch.Tensor) -> torch.Tensor:
        """``pressure`` (B, 256) normalized, ``location`` (B, 2) -> glance feature (B, out_features)."""
        what = torch.relu(self.what(pressure))
        where = torch.relu(self.where(location))
        if self.combiner == "add":
            return what + where
        if self.combiner == "mul":
            return what * where
        return self.combine(torch.cat([what, where], dim=-1))
