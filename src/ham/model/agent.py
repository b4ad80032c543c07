"""The Haptic Attention Model (HAM): tactile network -> core -> classifier, location network, baseline.

Section "The Haptic Attention Model" and Fig "Illustration of the Used Model". One episode of
``S`` glances on a batch of objects:

1. the first pose is random, ``q_1 ~ U[-1, 1]^2`` (section "Training": "the first
   pressure-location pair is chosen by the first random glance");
2. glance ``s`` returns the normalized pressure ``p_s``; the tactile network combines it with
   the pose ``l_s = (q_x, q_phi * pi/2)`` into the glance feature ``g_s``;
3. the core integrates ``g_1 .. g_s`` into ``tau_{1:s}``; the classifier reads
   ``pi(o | tau_{1:s})``, the baseline ``b(tau_{1:s})``;
4. the location network maps ``tau_{1:s}`` to ``(mu, sigma)`` for ``x`` and ``phi`` and samples
   the next pose ``q_{s+1}`` from the truncated Gaussian (``learned`` policy), or the pose is
   drawn uniformly (``random`` policy, the paper's ``pi_rloc``: no location network at all).

Every hyperparameter of the network is a field of :class:`HamConfig` with the paper's value as its
default; where the authors' code differs, the field offers the code's choice as an option.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import torch
from torch import nn

from ham.errors import HamError
from ham.model.baseline import Baseline
from ham.model.classifier import Classifier
from ham.model.core import ACTIVATIONS, CORES, State, make_core
from ham.model.location_net import (
    STD_ACTIVATIONS,
    LocationNetwork,
    truncated_normal,
    uniform_locations,
)
from ham.model.tactile_net import COMBINERS, TactileNetwork

POLICIES: tuple[str, ...] = ("learned", "random")


@dataclass(frozen=True)
class HamConfig:
    """The network's hyperparameters (paper defaults; authors' code as options).

    Attributes:
        glances: glances per episode, ``S``.
        n_objects: classes of the classifier (4 objects in the paper).
        pressure_dim: flattened pressure image (16 x 16 = 256); ``taxels^2`` of the glances'
            sensor, set from the table or world by :func:`ham.learn.train.model_for_source`.
        what_units: pressure layer of the tactile network (64).
        where_units: location layer of the tactile network (64, the code's width).
        combiner: what & where combiner: concat2 (paper), concat1, add, mul.
        combine_units: width of the layers after a concatenation (256, the authors' code; the
            paper's table says 64 for "linear layers", see :mod:`ham.model.tactile_net`).
        core: ``lstm`` (paper) or ``mlp`` (the ablation).
        hidden_units: core width (256).
        lstm_activation: ``tanh`` (paper, standard LSTM) or ``relu`` (authors' code).
        truncate_bptt: detach the core state between glances (authors' code) instead of full
            backpropagation through the glance sequence (paper).
        policy: ``learned`` (location network) or ``random`` (uniform poses, ``pi_rloc``).
        std_activation: ``softplus`` (paper) or ``sigmoid`` (authors' code) for ``sigma``.
        sigma_min: floor added to ``sigma`` for numerical safety (not in the paper).
        phi_scale: the pose fed to the tactile network is ``(q_x, q_phi * phi_scale)`` (pi/2).
        bias: biases on the dense layers; ``False`` reproduces the authors' layout (biases only in
            the LSTM), with exactly their 642,432 weights.
    """

    glances: int = 3
    n_objects: int = 4
    pressure_dim: int = 256
    what_units: int = 64
    where_units: int = 64
    combiner: str = "concat2"
    combine_units: int = 256
    core: str = "lstm"
    hidden_units: int = 256
    lstm_activation: str = "tanh"
    forget_bias: float = 1.0
    truncate_bptt: bool = False
    policy: str = "learned"
    std_activation: str = "softplus"
    sigma_min: float = 1e-3
    phi_scale: float = math.pi / 2
    bias: bool = True

    def __post_init__(self) -> None:
        for name in ("glances", "n_objects", "pressure_dim", "what_units", "where_units",
                     "combine_units", "hidden_units"):  # fmt: skip
            v = getattr(self, name)
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
                raise HamError(f"{name} = {v!r}; accepted: an integer >= 1")
        if self.n_objects < 2:
            raise HamError(f"n_objects = {self.n_objects}; accepted: >= 2 objects to classify")
        for name, allowed in (
            ("combiner", COMBINERS),
            ("core", CORES),
            ("lstm_activation", ACTIVATIONS),
            ("policy", POLICIES),
            ("std_activation", STD_ACTIVATIONS),
        ):
            if getattr(self, name) not in allowed:
                raise HamError(f"{name} = {getattr(self, name)!r}; accepted: {', '.join(allowed)}")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> HamConfig:
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise HamError(f"model config has unknown fields {sorted(unknown)}")
        return cls(**d)


@dataclass
class Episode:
    """What one batch of ``S`` glances leaves for the loss and the evaluation.

    Attributes:
        objects: ``(B,)`` the true object ids.
        locations: ``(S, B, 2)`` the poses ``q`` of the glances (detached samples).
        logits: ``(S, B, K)`` classifier outputs after each glance.
        baselines: ``(S, B)`` ``b(tau_{1:s})`` after each glance.
        mu, sigma: ``(S-1, B, 2)`` the policy that drew glances 2..S; ``None`` for the random policy.
    """

    objects: torch.Tensor
    locations: torch.Tensor
    logits: torch.Tensor
    baselines: torch.Tensor
    mu: torch.Tensor | None
    sigma: torch.Tensor | None


def he_normal_init(module: nn.Module) -> None:
    """He-normal weights (fan in, ReLU gain) and zero biases for every dense layer (paper)."""
    for m in module.modules():
        if isinstance(m, nn.Linear):
            nn.init.kaiming_normal_(m.weight, mode="fan_in", nonlinearity="relu")
            if m.bias is not None:
                nn.init.zeros_(m.bias)


def count_parameters(module: nn.Module) -> int:
    """Trainable weights (the number the paper reports as 741,248 for its model)."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)


class HapticAttentionModel(nn.Module):
    """The HAM. ``forward(env, objects, generator)`` plays one episode and returns an :class:`Episode`."""

    def __init__(self, config: HamConfig | None = None) -> None:
        super().__init__()
        self.config = c = config or HamConfig()
        self.tactile = TactileNetwork(
            c.pressure_dim, 2, c.what_units, c.where_units, c.combiner, c.combine_units, c.bias
        )
        self.core = make_core(
            c.core,
            self.tactile.out_features,
            c.hidden_units,
            activation=c.lstm_activation,
            truncate_bptt=c.truncate_bptt,
            forget_bias=c.forget_bias,
            bias=c.bias,
        )
        self.classifier = Classifier(c.hidden_units, c.n_objects, c.bias)
        self.baseline = Baseline(c.hidden_units, c.bias)
        self.location = (
            LocationNetwork(c.hidden_units, c.std_activation, c.sigma_min, c.bias)
            if c.policy == "learned"
            else None
        )
        he_normal_init(self)

    def step(
        self, pressure: torch.Tensor, q: torch.Tensor, state: State
    ) -> tuple[torch.Tensor, State]:
        """One glance through tactile network and core: ``(p_s, q_s) -> tau_{1:s}``."""
        location = torch.stack([q[:, 0], q[:, 1] * self.config.phi_scale], dim=-1)
        return self.core(self.tactile(pressure, location), state)

    def next_location(
        self, tau: torch.Tensor, generator: torch.Generator | None, greedy: bool = False
    ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """The pose of the next glance: ``(q, mu, sigma)``; ``mu = sigma = None`` when random.

        ``greedy``: the policy's mean pose instead of a sample (evaluation only)."""
        if self.location is None:
            return uniform_locations(tau.shape[0], generator, tau.device), None, None
        mu, sigma = self.location(tau)
        if greedy:
            return torch.nan_to_num(mu.detach()).clamp(-1, 1), mu, sigma
        return truncated_normal(mu, sigma, generator), mu, sigma

    def forward(
        self,
        env,
        objects: torch.Tensor,
        generator: torch.Generator | None,
        greedy: bool = False,
    ) -> Episode:
        """Play ``S`` glances of ``env`` on ``objects`` (B,), sampling poses from ``generator``
        (or taking the policy's mean poses when ``greedy``; the first glance is random always)."""
        batch = objects.shape[0]
        q = uniform_locations(batch, generator, objects.device)  # the first glance is random
        state = self.core.initial_state(batch, q)
        locations, logits, baselines, mus, sigmas = [], [], [], [], []
        for s in range(self.config.glances):
            tau, state = self.step(env.glance(objects, q), q, state)
            locations.append(q)
            logits.append(self.classifier(tau))
            baselines.append(self.baseline(tau))
            if s == self.config.glances - 1:
                break
            q, mu, sigma = self.next_location(tau, generator, greedy)
            mus.append(mu)
            sigmas.append(sigma)
        learned = self.location is not None and mus
        return Episode(
            objects=objects,
            locations=torch.stack(locations),
            logits=torch.stack(logits),
            baselines=torch.stack(baselines),
            mu=torch.stack(mus) if learned else None,
            sigma=torch.stack(sigmas) if learned else None,
        )

    def replay(self, pressures: torch.Tensor, locations: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """The bare network on recorded glances ``(S, B, pressure_dim)`` at ``(S, B, 2)``: no environment,
        no sampling. Returns ``(logits, baselines, mu, sigma)`` stacked over the glances (``mu``
        and ``sigma`` empty for the random policy). Used by the benchmark as the reference cost."""
        state = self.core.initial_state(pressures.shape[1], pressures)
        logits, baselines, mus, sigmas = [], [], [], []
        for s in range(pressures.shape[0]):
            tau, state = self.step(pressures[s], locations[s], state)
            logits.append(self.classifier(tau))
            baselines.append(self.baseline(tau))
            if self.location is not None and s < pressures.shape[0] - 1:
                mu, sigma = self.location(tau)
                mus.append(mu)
                sigmas.append(sigma)
        empty = pressures.new_zeros(0)
        return (
            torch.stack(logits),
            torch.stack(baselines),
            torch.stack(mus) if mus else empty,
            torch.stack(sigmas) if sigmas else empty,
        )

    def describe(self) -> str:
        """One line per part with its trainable weights, and the total."""
        lines = [f"{name:<11} {count_parameters(m):>9,}" for name, m in self.named_children()]
        lines.append(f"{'total':<11} {count_parameters(self):>9,}")
        return "\n".join(lines)
