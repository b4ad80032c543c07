"""The Haptic Attention Model (HAM): tactile network -> core -> classifier, location network, baseline.

Section "The Haptic Attention Model" and Fig "Illustration of the Used Model". One episode of
``S`` glances on a batch of objects:

1. the first pose is random, ``q_1 ~ U[-1, 1]^2`` (section "Training": "the first
   pressure-location pair is chosen by the first random glance");
2. glance ``s`` returns the normalized pressure ``p_s``; the tactile network combines it with
   the pose ``l_s = (q_x, q_phi * pi/2)`` into the glance feature ``g_s``. Beyond the paper (its
   Discussion): ``k`` pose dimensions ``HamConfig.pose_dims`` (e.g. ``x, y, phi, phi_y``; angles
   scaled by ``phi_scale``), one location stream each, and optionally the contact height ``h``
   of the glance, ``g: q -> (p, h)``, as one more where-input (``h / MAX_HEIGHT``);
3. the core integrates ``g_1 .. g_s`` into ``tau_{1:s}``; the classifier reads
   ``pi(o | tau_{1:s})``, the baseline ``b(tau_{1:s})``;
4. the location policy (:mod:`ham.model.policy`) maps ``tau_{1:s}`` to a distribution over
   poses and the next pose ``q_{s+1}`` is drawn from it: the location network's truncated
   Gaussian (``learned``), or uniform poses (``random``, the paper's ``pi_rloc``: no weights),
   or a fixed sweep (``grid``: the pose depends on the glance index alone, which the model
   passes to every policy, :meth:`ham.model.policy.LocationPolicy.distribution_at`).

The location policy and the baseline read the classifier's core output, detached (the paper);
beyond it, ``encoders = "separate"`` gives each a tactile network and a core of its own
(:class:`Encoder`, the APPLE study's HAM), which its own loss trains.

Every hyperparameter of the network is a field of :class:`HamConfig` with the paper's value as its
default; where the authors' code differs, the field offers the code's choice as an option.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields

import torch
from torch import nn

from ham.errors import HamError, check_choices, check_known_fields, check_types
from ham.model.baseline import Baseline
from ham.model.classifier import Classifier
from ham.model.core import ACTIVATIONS, CORES, State, make_core
from ham.model.location_net import STD_ACTIVATIONS, uniform_locations
from ham.model.plugin import (
    BUILTIN_CORES,
    BUILTIN_POLICIES,
    build_part,
    check_core,
    check_policy,
    check_poses,
    check_tau,
    load_plugin,
)
from ham.model.policy import (
    POLICIES,
    FirstPose,
    LocationDistribution,
    ProbedFirstPose,
    TruncatedGaussian,
    make_policy,
)
from ham.model.tactile_net import COMBINERS, TactileNetwork
from ham.world.glance import PAPER_POSE_DIMS, check_pose_dims
from ham.world.objects import MAX_HEIGHT

FIRST_GLANCES: tuple[str, ...] = ("random", "learned", "own", "probe")
#: The stay gate's initial logit (``HamConfig.stay_gate``): ``g = sigmoid(-3) = 0.047``.
STAY_GATE_BIAS = -3.0
#: What the learned stop's head reads (``HamConfig.stop_input``).
STOP_INPUTS: tuple[str, ...] = ("confidence", "core")
#: What the location policy and the baseline read (``HamConfig.encoders``): the classifier's core
#: output, detached (the paper), or an encoder each of their own (the APPLE study's HAM).
ENCODERS: tuple[str, ...] = ("shared", "separate")
#: ``phi`` and ``phi_y`` of the pose dims (:data:`ham.world.glance.POSE_DIMS`) are angles, fed to
#: the tactile network as ``q * phi_scale``.
ANGLE_DIMS: tuple[str, ...] = ("phi", "phi_y")


#: The HamConfig fields each built-in core reads (:mod:`ham.model.core`); a core registered by
#: :func:`ham.model.core.register_core` may read any of them, so only these are checked.
CORE_OPTIONS: dict[str, tuple[str, ...]] = {
    "lstm": ("lstm_activation", "forget_bias", "truncate_bptt"),
    "mlp": (),
    "transformer": ("transformer_layers", "transformer_heads"),
}


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
        core: ``lstm`` (paper), ``mlp`` (the ablation) or ``transformer`` (beyond the paper:
            causal self-attention over the glances so far, :class:`ham.model.core.TransformerCore`).
        transformer_layers: layers of the transformer core (2).
        transformer_heads: attention heads of the transformer core (4; they divide
            ``hidden_units``).
        hidden_units: core width (256).
        lstm_activation: ``tanh`` (paper, standard LSTM) or ``relu`` (authors' code).
        truncate_bptt: detach the core state between glances (authors' code) instead of full
            backpropagation through the glance sequence (paper).
        policy: a registered location policy (:mod:`ham.model.policy`): ``learned`` (the
            location network), ``random`` (uniform poses, ``pi_rloc``), ``squashed`` (the
            location network as SAC's squashed Gaussian) or ``grid`` (a fixed sweep, no weights;
            with ``first_glance`` ``random``, ``learned`` (the sweep's first pose) or ``probe``); ``grid-corner``: APPLE's
            grid walk from the glimpse's position, ap_gym ``relative`` actions only).
        moves: the policy's poses are moves of the sensor, not targets (ap_gym's ``relative``
            actions; set by :func:`ham.learn.ap_adapter.sized_model` for the ``grid`` policy,
            the only one that reads it: its sweep is then a walk of moves; and for
            ``grid-corner``).
        move_length: the sensor's full step per move (set with ``moves`` for ``grid-corner``,
            which plans its walk in it; 0: unused).
        plugin: the record ``{"name", "sha256", "source"}`` of the user's plugin file that
            registers ``core`` or ``policy`` (or the run's learner, which TrainConfig checks;
            ``--plugin FILE.py``, :mod:`ham.model.plugin`): run before the config is checked, so
            a saved config loads anywhere.
        std_activation: ``softplus`` (paper) or ``sigmoid`` (authors' code) for ``sigma``.
        sigma_min: floor added to ``sigma`` for numerical safety (not in the paper).
        phi_scale: the pose fed to the tactile network is ``(q_x, q_phi * phi_scale)`` (pi/2).
        bias: biases on the dense layers; ``False`` reproduces the authors' layout (biases only in
            the LSTM), with exactly their 642,432 weights.
        stop: a learned stop (beyond the paper): a stop head reads the core output after each
            glance and says classify-now or glance-again (:mod:`ham.learn.stopping`); the
            episode still has at most ``glances`` glances.
        stop_input: what the stop head reads: ``confidence`` (a small MLP on the classifier's
            confidence after the glance, ``-log(1 - max pi)`` and the entropy;
            :class:`StopHead`) or ``core`` (a linear layer on the core output ``tau_{1:s}``,
            the first version).
        first_glance: ``random`` (paper: uniform, the location network acts from glance 2 on)
            or ``learned`` (beyond the paper: the policy also chooses the first pose, from the
            core output before any glance, zeros; its learned biases make it a learned pose)
            or ``own`` (beyond the paper: a learned pose distribution of its own, a mean and a
            sigma, the same for every episode, :class:`ham.model.policy.FirstPose`; its
            learning rate is ``TrainConfig.first_pose_lr_scale``) or ``probe`` (beyond the
            paper: one pose for every episode, found by probe glances on a lattice of candidates
            and successive halving, :mod:`ham.learn.probe`; uniform until the search starts).
        first_pose_grid: with ``first_glance = "own"``, the components of its mixture per pose
            dimension (``grid^k`` Gaussians, started on a regular grid over the poses; 1: one
            Gaussian at pose 0).
        stay_gate: a learned "stay" gate on the location policy (beyond the paper): the mean
            next pose is ``g q_{s-1} + (1 - g) mu(tau)``, ``g`` a small MLP (as the stop
            head's) on the classifier's confidence after glance ``s - 1``, so staying where the
            pad is needs one unit, not the linear map ``mu(tau)`` to recall the pose
            (``--move-cost``, docs/learners.md).
        probe_grid: with ``first_glance = "probe"``, the lattice's candidate first poses per
            pose dimension, from -1 to 1 (21: spacing 0.1; ``grid^k`` candidates).
        pose_dims: the pose dimensions the policy chooses, in the world's order (the paper's
            ``x, phi``; any non-empty subset of ``x, y, phi, phi_y``): one location stream and
            one where-input each. Set from the world by :func:`ham.learn.train.model_for_source`.
        height_input: feed the glance's contact height ``h`` (m, over ``MAX_HEIGHT``) to the
            tactile network's where-layer (the paper's Discussion, ``g: q -> (p, h)``).
        encoders: what the location policy and the baseline read: ``shared`` (the paper: the
            classifier's core output, detached, so only the classification loss trains the
            tactile network and the core) or ``separate`` (beyond the paper, the APPLE study's
            HAM: each reads a tactile network and a core of its own, as the classifier's, which
            its own loss trains: the policy's by the REINFORCE term, the baseline's by Eq
            baseline; :class:`Encoder`). ``separate`` needs the ``learned`` policy.
    """

    glances: int = 3
    n_objects: int = 4
    pressure_dim: int = 256
    what_units: int = 64
    where_units: int = 64
    combiner: str = field(default="concat2", metadata={"choices": COMBINERS})
    combine_units: int = 256
    core: str = field(default="lstm", metadata={"choices": CORES})
    hidden_units: int = 256
    transformer_layers: int = 2
    transformer_heads: int = 4
    lstm_activation: str = field(default="tanh", metadata={"choices": ACTIVATIONS})
    forget_bias: float = 1.0
    truncate_bptt: bool = False
    policy: str = field(default="learned", metadata={"choices": POLICIES})
    std_activation: str = field(default="softplus", metadata={"choices": STD_ACTIVATIONS})
    sigma_min: float = 1e-3
    phi_scale: float = math.pi / 2
    bias: bool = True
    first_glance: str = field(default="random", metadata={"choices": FIRST_GLANCES})
    stop: bool = False
    stop_input: str = field(default="confidence", metadata={"choices": STOP_INPUTS})
    first_pose_grid: int = 1
    probe_grid: int = 21
    stay_gate: bool = False
    pose_dims: tuple[str, ...] = PAPER_POSE_DIMS
    height_input: bool = False
    encoders: str = field(default="shared", metadata={"choices": ENCODERS})
    moves: bool = False
    move_length: float = 0.0
    plugin: dict | None = None

    def __post_init__(self) -> None:
        check_types(self)
        if self.plugin is not None:
            registered = load_plugin(self.plugin)
            learners = any(r.startswith("learner ") for r in registered)  # TrainConfig checks
            if not learners and not {f"core {self.core}", f"policy {self.policy}"} & set(
                registered
            ):
                raise HamError(
                    f"plugin {self.plugin['name']!r} with core {self.core!r} and policy "
                    f"{self.policy!r}, neither of which it registers; accepted: --core or "
                    f"--policy of the plugin's ({', '.join(registered)})"
                )
        # frozen: a JSON list (a saved config) becomes the tuple
        object.__setattr__(self, "pose_dims", check_pose_dims(self.pose_dims))
        for name in ("glances", "n_objects", "pressure_dim", "what_units", "where_units",
                     "combine_units", "hidden_units", "transformer_layers",
                     "transformer_heads", "first_pose_grid"):  # fmt: skip
            v = getattr(self, name)
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
                raise HamError(f"{name} = {v!r}; accepted: an integer >= 1")
        if self.first_pose_grid != 1 and self.first_glance != "own":
            raise HamError(
                f"first_pose_grid = {self.first_pose_grid} with first_glance "
                f"{self.first_glance!r}; accepted: with first_glance 'own' (--first-glance own)"
            )
        if not (isinstance(self.probe_grid, int) and not isinstance(self.probe_grid, bool)
                and self.probe_grid >= 2):  # fmt: skip
            raise HamError(f"probe_grid = {self.probe_grid!r}; accepted: an integer >= 2")
        if self.probe_grid != 21 and self.first_glance != "probe":
            raise HamError(
                f"probe_grid = {self.probe_grid} with first_glance {self.first_glance!r}; "
                "accepted: with first_glance 'probe' (--first-glance probe)"
            )
        if self.move_length < 0:
            raise HamError(f"move_length = {self.move_length!r}; accepted: a finite number >= 0")
        if self.sigma_min < 0:  # checked again by the location network, built without a config
            raise HamError(f"sigma_min = {self.sigma_min!r}; accepted: a finite number >= 0")
        if self.policy == "grid" and self.first_glance == "own":
            raise HamError(
                "first_glance = 'own' with policy 'grid'; accepted: random, learned (the "
                "sweep's first pose) or probe"
            )
        if self.stay_gate and self.policy != "learned":
            raise HamError(
                f"stay_gate with policy {self.policy!r}; accepted: --policy learned (a mean pose "
                "to gate)"
            )
        if self.encoders == "separate" and self.policy != "learned":
            raise HamError(
                f"encoders 'separate' with policy {self.policy!r}; accepted: --policy learned "
                "(a location network whose encoder the REINFORCE term trains)"
            )
        if self.n_objects < 2:
            raise HamError(f"n_objects = {self.n_objects}; accepted: >= 2 objects to classify")
        for name, registry in (("core", CORES), ("policy", POLICIES)):
            if getattr(self, name) not in registry:  # a name of the user's own: say how
                raise HamError(
                    f"{name} = {getattr(self, name)!r}; accepted: {', '.join(registry)}, or a "
                    f"{name} of your own registered by a plugin (--plugin FILE.py, "
                    "HamConfig(plugin=ham.model.plugin.read_plugin(FILE)))"
                )
        check_choices(self)
        self._check_unused()

    def _check_unused(self) -> None:
        """A field set away from its default where nothing reads it is refused, not ignored:
        another built-in core's options, the stop head's input without a stop."""
        defaults = {f.name: f.default for f in fields(self)}
        if self.core in CORE_OPTIONS:
            for core, names in CORE_OPTIONS.items():
                for name in names if core != self.core else ():
                    value = getattr(self, name)
                    if value != defaults[name]:
                        raise HamError(
                            f"{name} = {value!r} with core {self.core!r}, which does not read "
                            f"it; accepted: {name} with --core {core}"
                        )
        if self.combine_units != defaults["combine_units"] and self.combiner in ("add", "mul"):
            raise HamError(
                f"combine_units = {self.combine_units} with combiner {self.combiner!r}, which "
                "has no layers after it; accepted: combine_units with --combiner concat2 or concat1"
            )
        unsampled = (
            self.policy in ("random", "grid", "grid-corner") and self.first_glance == "random"
        )
        if self.std_activation != defaults["std_activation"] and unsampled:
            raise HamError(
                f"std_activation = {self.std_activation!r} with policy {self.policy!r}, which "
                "has no sigma; accepted: std_activation with --policy learned or squashed"
            )
        if self.stop_input != defaults["stop_input"] and not self.stop:
            raise HamError(
                f"stop_input = {self.stop_input!r} without a learned stop; accepted: with --stop"
            )

    @property
    def location_dim(self) -> int:
        """Inputs of the tactile network's where-layer: the pose dims and the height if fed."""
        return len(self.pose_dims) + int(self.height_input)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["pose_dims"] = list(self.pose_dims)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> HamConfig:
        check_known_fields(cls, d, "model config")
        if d.get("stop") and "stop_input" not in d:  # written before the field: a linear head
            d = {**d, "stop_input": "core"}
        return cls(**d)


@dataclass
class Episode:
    """What one batch of ``S`` glances leaves for the loss and the evaluation.

    Attributes:
        objects: ``(B,)`` the true object ids (``None`` in a replay of bare glances:
            :meth:`HapticAttentionModel.replay`).
        locations: ``(S, B, k)`` the poses ``q`` of the glances (detached samples), columns in
            ``HamConfig.pose_dims`` order.
        logits: ``(S, B, K)`` classifier outputs after each glance.
        baselines: ``(S, B)`` ``b(tau_{1:s})`` after each glance.
        policy: the location distributions that drew glances ``first_chosen + 1..S``
            (:class:`ham.model.policy.LocationDistribution`), batch shape ``(S - 1, B)`` when
            the first glance is random, ``(S, B)`` when it is learned; ``None`` when no glance
            was chosen by the policy.
        first_baseline: ``b(tau_0)`` ``(B,)``, the baseline of the state that chose a learned
            first glance (``None`` when the first glance is random).
    """

    objects: torch.Tensor | None
    locations: torch.Tensor
    logits: torch.Tensor
    baselines: torch.Tensor
    policy: LocationDistribution | None
    first_baseline: torch.Tensor | None = None
    #: ``(S, B)`` the stop head's logits after each glance (``None`` without a learned stop)
    stop_logits: torch.Tensor | None = None
    #: ``(B,)`` the mixture component that drew each first pose (``first_glance = "own"``)
    first_choice: torch.Tensor | None = None

    @property
    def chosen(self) -> slice:
        """The glances the policy chose: all (learned first glance) or 2..S."""
        return slice(0 if self.first_baseline is not None else 1, None)

    def values(self) -> torch.Tensor:
        """The baselines of the states that chose the policy's glances, ``(S', B)``."""
        if self.first_baseline is None:
            return self.baselines[:-1]
        return torch.cat([self.first_baseline[None], self.baselines[:-1]])


def he_normal_init(module: nn.Module) -> None:
    """He-normal weights (fan in, ReLU gain) and zero biases for every dense layer (paper)."""
    for m in module.modules():
        if isinstance(m, nn.Linear):
            nn.init.kaiming_normal_(m.weight, mode="fan_in", nonlinearity="relu")
            if m.bias is not None:
                nn.init.zeros_(m.bias)


class StopHead(nn.Module):
    """The learned stop's head on the classifier's confidence after a glance: ``(-log(1 -
    max_k pi_k), H(pi)) -> 16 ReLU units -> logit``. Its inputs are detached: its loss trains
    only it.

    Why the confidence, and only it: whether to stop is a question of how sure the classifier
    is, a nonlinear function of ``tau`` that a linear head on 256 units learns slowly; and the
    confidence means the same under the sampled poses of training and the mean poses of
    evaluation, where the glance index does not (a head that also read ``s / S`` learned to stop
    at a fixed glance). Why logarithms: "sure" (``1 - max pi = 0.01``) and "unsure" (0.25) lie
    0.24 apart in probabilities but 3.2 nats apart here (docs/learners.md)."""

    features = 2
    #: the first input's ceiling (nats): a float32 classifier can be "sure" to 1e-30
    cap = 30.0

    def __init__(self, hidden: int = 16) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Linear(self.features, hidden), nn.ReLU(), nn.Linear(hidden, 1))

    @classmethod
    def confidence(cls, logits: torch.Tensor) -> torch.Tensor:
        """``(B, 2)`` the head's input: ``-log(1 - max_k pi_k)`` and the entropy ``H(pi)``
        (nats) of the classifier's output."""
        logp = torch.log_softmax(logits.detach(), -1)
        top = logp.argmax(-1, keepdim=True)
        rest = logp.scatter(-1, top, float("-inf")).logsumexp(-1)  # log(1 - max pi), stable
        entropy = -(logp.exp() * logp).sum(-1)
        return torch.stack([(-rest).clamp(max=cls.cap), entropy], -1)

    def forward(self, logits: torch.Tensor) -> torch.Tensor:
        return self.net(self.confidence(logits)).squeeze(-1)


class Encoder(nn.Module):
    """A tactile network and a core of their own (``HamConfig.encoders = "separate"``): the
    location policy's or the baseline's features, ``(p_s, l_s) -> tau'_{1:s}``, trained by that
    head's loss alone (the APPLE study's HAM has one such recurrent encoder each for its policy,
    classifier and value)."""

    def __init__(self, tactile: nn.Module, core: nn.Module) -> None:
        super().__init__()
        self.tactile = tactile
        self.core = core

    def forward(
        self, pressure: torch.Tensor, where: torch.Tensor, state: State
    ) -> tuple[torch.Tensor, State]:
        return self.core(self.tactile(pressure, where), state)


def count_parameters(module: nn.Module) -> int:
    """Trainable weights (the number the paper reports as 741,248 for its model)."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)


class HapticAttentionModel(nn.Module):
    """The HAM. ``forward(env, objects, generator)`` plays one episode and returns an :class:`Episode`."""

    def __init__(self, config: HamConfig | None = None) -> None:
        super().__init__()
        self.config = c = config or HamConfig()
        if c.plugin is not None:  # a config unpickled in a worker has not run its __post_init__
            load_plugin(c.plugin)
        self.tactile = self._tactile_network()
        self.core = self._core()
        self.classifier = Classifier(c.hidden_units, c.n_objects, c.bias)
        self.baseline = Baseline(c.hidden_units, c.bias, trains_input=self.separate_encoders)
        # the location policy (ham.model.policy); created last, as its weights always were
        self.location = build_part("policy", c.policy, POLICIES, make_policy, c)
        he_normal_init(self)
        if c.stop:  # after every other part: their initial weights stay those of a run without
            if c.stop_input == "core":
                self.stop_head = nn.Linear(c.hidden_units, 1, bias=c.bias)
            else:
                self.stop_head = StopHead()
            he_normal_init(self.stop_head)
        if self.chooses_first_glance and c.first_glance == "own":  # draws no random numbers
            self.first_pose = FirstPose(len(c.pose_dims), c.first_pose_grid, c.sigma_min)
        if c.first_glance == "probe":  # buffers only: draws no random numbers
            self.first_probe = ProbedFirstPose(len(c.pose_dims), c.probe_grid)
        if c.stay_gate:  # last: every other part's initial weights stay those of a run without
            # On the classifier's confidence (as the stop head): stay once sure, move while
            # unsure; a gate on the core output learned to stay everywhere (docs/learners.md).
            # Starts open (g = sigmoid(-3) = 0.05 in every state): the policy is first the
            # location network's.
            self.stay = StopHead()
            he_normal_init(self.stay)
            nn.init.zeros_(self.stay.net[-1].weight)
            nn.init.constant_(self.stay.net[-1].bias, STAY_GATE_BIAS)
        if self.separate_encoders:  # last: the other parts start as with shared encoders
            self.policy_encoder = Encoder(self._tactile_network(), self._core())
            self.value_encoder = Encoder(self._tactile_network(), self._core())
            he_normal_init(self.policy_encoder)
            he_normal_init(self.value_encoder)
        # where-input column i: q_i, times phi_scale for an angle
        self._angle = [d in ANGLE_DIMS for d in c.pose_dims]
        # a core or policy of the user's own keeps the contract the model relies on
        check_core(c.core, self.core, self.tactile.out_features, c.hidden_units)
        check_policy(c.policy, self.location, c.hidden_units, len(c.pose_dims))
        # and keeps it at every glance: a batch of 8 can break what 2 episodes kept
        self._own_core = c.core not in BUILTIN_CORES
        self._own_policy = c.policy not in BUILTIN_POLICIES

    def _tactile_network(self) -> TactileNetwork:
        c = self.config
        return TactileNetwork(
            c.pressure_dim,
            c.location_dim,
            c.what_units,
            c.where_units,
            c.combiner,
            c.combine_units,
            c.bias,
        )

    def _core(self) -> nn.Module:
        c = self.config
        return build_part(
            "core",
            c.core,
            CORES,
            make_core,
            c.core,
            self.tactile.out_features,
            c.hidden_units,
            activation=c.lstm_activation,
            truncate_bptt=c.truncate_bptt,
            forget_bias=c.forget_bias,
            bias=c.bias,
            layers=c.transformer_layers,
            heads=c.transformer_heads,
        )

    @property
    def separate_encoders(self) -> bool:
        """The policy and the baseline read encoders of their own (``encoders = "separate"``)."""
        return self.config.encoders == "separate"

    def initial_heads_state(self, batch: int, like: torch.Tensor) -> tuple[State, State] | None:
        """The separate encoders' states before the first glance (``None`` when shared)."""
        if not self.separate_encoders:
            return None
        return (
            self.policy_encoder.core.initial_state(batch, like),
            self.value_encoder.core.initial_state(batch, like),
        )

    def heads_step(
        self,
        tau: torch.Tensor,
        pressure: torch.Tensor,
        where: torch.Tensor,
        state: tuple[State, State] | None,
        height: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, tuple[State, State] | None]:
        """What the location policy and the baseline read after a glance: the classifier's
        core output ``tau`` twice (shared; they detach it), or each separate encoder's output on
        the same glance ``(p_s, where_s[, h_s])``, and the encoders' next states."""
        if state is None:
            return tau, tau, None
        w = self.where(where, height)
        tau_policy, policy_state = self.policy_encoder(pressure, w, state[0])
        tau_value, value_state = self.value_encoder(pressure, w, state[1])
        return tau_policy, tau_value, (policy_state, value_state)

    @property
    def chooses_first_glance(self) -> bool:
        """The policy chooses the first pose too (``first_glance`` ``learned`` or ``own``, and a
        policy with weights; ``probe``'s first pose is the search's, not the policy's)."""
        return self.config.first_glance in ("learned", "own") and self.config.policy != "random"

    def first_glance(
        self,
        batch: int,
        device: torch.device | str = "cpu",
        generator: torch.Generator | None = None,
        greedy: bool = False,
        choice: torch.Tensor | None = None,
    ) -> tuple[LocationDistribution, torch.Tensor]:
        """The distribution of a chosen first pose ``(batch,)`` and the baseline ``b(tau_0)`` of
        the state that chooses it, ``tau_0 = 0`` (the core before any glance): the location
        network's at ``tau_0`` (``learned``) or the first pose's own (``own``; its mixture
        components drawn from ``generator``, the heaviest when ``greedy``, or ``choice``)."""
        tau0 = torch.zeros((batch, self.config.hidden_units), device=device)
        if self.config.first_glance == "own":
            dist = self.first_pose.distribution(batch, generator, greedy, choice)
            return dist, self.baseline(tau0)
        return self.location.distribution_at(tau0, 0), self.baseline(tau0)

    def next_distribution(
        self,
        tau: torch.Tensor,
        q: torch.Tensor,
        logits: torch.Tensor | None = None,
        glance: int | None = None,
        position: torch.Tensor | None = None,
    ) -> LocationDistribution:
        """The distribution of the next pose after the glance at ``q`` ``(B, k)`` that left the
        core at ``tau`` and the classifier at ``logits``: the location policy's, its mean gated
        towards ``q`` with ``stay_gate`` (the gate reads the classifier's confidence, detached:
        :meth:`StopHead.confidence`). ``glance``: the index (0-based) of the glance it chooses,
        for a policy that reads it (``grid``); ``position`` ``(B, k)``: where the sensor is now
        (the last glance's where-input), for ``grid-corner``."""
        dist = self.location.distribution_at(tau, glance, position)
        if not self.config.stay_gate:
            return dist
        if logits is None:
            logits = self.classifier(tau)
        g = torch.sigmoid(self.stay(logits))[:, None]  # (B, 1); reads detached inputs
        return TruncatedGaussian(g * q.detach() + (1 - g) * dist.mu, dist.sigma)

    def where(self, q: torch.Tensor, height: torch.Tensor | None = None) -> torch.Tensor:
        """The tactile network's where-input: ``(q_x, q_phi * phi_scale)`` in the paper; angles
        scaled, and ``h / MAX_HEIGHT`` appended with ``height_input``."""
        scale = self.config.phi_scale
        cols = [q[..., i] * scale if a else q[..., i] for i, a in enumerate(self._angle)]
        if self.config.height_input:
            if height is None:
                raise HamError(
                    "the model takes the contact height (height_input) but the environment "
                    "gave none; accepted: a haptic world's glances (they carry h)"
                )
            cols.append(height.to(q.dtype) / MAX_HEIGHT)
        return torch.stack(cols, dim=-1)

    def step(
        self,
        pressure: torch.Tensor,
        q: torch.Tensor,
        state: State,
        height: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, State]:
        """One glance through tactile network and core: ``(p_s, q_s[, h_s]) -> tau_{1:s}``."""
        g = self.tactile(pressure, self.where(q, height))
        tau, state = self.core(g, state)
        if self._own_core:
            check_tau(self.config.core, tau, pressure.shape[0], self.config.hidden_units, g)
        return tau, state

    def act(self, dist: LocationDistribution, generator, greedy: bool, batch: int) -> torch.Tensor:
        """The pose ``dist`` acts on (:meth:`LocationDistribution.act`), checked for a policy of
        the user's own."""
        q = dist.act(generator, greedy)
        if self._own_policy:
            like = next(self.parameters())  # the model's dtype and device
            check_poses(self.config.policy, q, batch, len(self.config.pose_dims), like)
        return q

    def glance(
        self, env, objects: torch.Tensor, q: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """Glance ``objects`` at ``q`` in ``env``: the pressures, the where-input's pose
        (``env.observed_location`` when the environment reports one, else ``q``) and the contact
        height (``None`` without ``height_input``)."""
        height = None
        if self.config.height_input:
            pressure, height = env.glance_height(objects, q)
        else:
            pressure = env.glance(objects, q)
        where = getattr(env, "observed_location", None)
        return pressure, q if where is None else where, height

    def glance_step(
        self, env, objects: torch.Tensor, q: torch.Tensor, state: State
    ) -> tuple[torch.Tensor, State]:
        """Glance ``objects`` at ``q`` in ``env`` (:meth:`glance`) and take the :meth:`step` on
        it."""
        pressure, where, height = self.glance(env, objects, q)
        return self.step(pressure, where, state, height)

    def initial_pose(
        self,
        batch: int,
        device: torch.device | str,
        generator: torch.Generator | None,
        greedy: bool = False,
    ) -> tuple[torch.Tensor, LocationDistribution | None, torch.Tensor | None]:
        """The first pose ``q_1`` ``(batch, k)`` of an episode, with the distribution and the
        baseline it was chosen with (``None`` but for a chosen first glance): the policy's
        (:meth:`first_glance`), the first-pose search's (``probe``: not the policy's; glances
        2..S are) or uniform (the paper)."""
        if self.chooses_first_glance:
            dist, baseline = self.first_glance(batch, device, generator, greedy)
            return self.act(dist, generator, greedy, batch), dist, baseline
        if self.config.first_glance == "probe":
            return self.first_probe.first_poses(batch, generator, device), None, None
        return uniform_locations(batch, generator, device, len(self.config.pose_dims)), None, None

    def stop_logit(self, tau: torch.Tensor, logits: torch.Tensor) -> torch.Tensor:
        """The learned stop's logit ``(B,)`` after a glance that left the core at ``tau`` and
        the classifier at ``logits``; it reads detached inputs (``stop_input``: the core's
        output or the classifier's confidence), so the stop's loss trains only its head."""
        if self.config.stop_input == "core":
            return self.stop_head(tau.detach()).squeeze(-1)
        return self.stop_head(logits)

    def forward(
        self,
        env,
        objects: torch.Tensor,
        generator: torch.Generator | None,
        greedy: bool = False,
    ) -> Episode:
        """Play ``S`` glances of ``env`` on ``objects`` (B,), sampling poses from ``generator``
        (or taking the policy's mode when ``greedy``; the first glance is random always).

        The where-input of a glance is ``env.observed_location`` when the environment reports
        one (a sensor that moved itself, e.g. a capped step of an ap_gym environment), else the
        pose ``q`` asked for; ``Episode.locations`` holds the poses asked for (the policy's
        actions)."""
        batch = objects.shape[0]
        locations, logits, baselines, dists, stops = [], [], [], [], []
        q, dist, first_baseline = self.initial_pose(batch, objects.device, generator, greedy)
        if dist is not None:
            dists.append(dist)
        state = self.core.initial_state(batch, q)
        heads_state = self.initial_heads_state(batch, q)
        for s in range(self.config.glances):
            pressure, where, height = self.glance(env, objects, q)
            tau, tau_policy, logit, baseline, state, heads_state = self.read(
                pressure, where, height, state, heads_state
            )
            locations.append(q)
            logits.append(logit)
            baselines.append(baseline)
            if self.config.stop:
                stops.append(self.stop_logit(tau, logits[-1]))
            if s == self.config.glances - 1:
                break
            dist = self.next_distribution(tau_policy, q, logits[-1], glance=s + 1, position=where)
            q = self.act(dist, generator, greedy, batch)
            dists.append(dist)
        return Episode(
            objects=objects,
            locations=torch.stack(locations),
            logits=torch.stack(logits),
            baselines=torch.stack(baselines),
            policy=type(dists[0]).stack(dists) if dists else None,
            first_baseline=first_baseline,
            stop_logits=torch.stack(stops) if stops else None,
            first_choice=getattr(dists[0], "choice", None) if first_baseline is not None else None,
        )

    def read(
        self,
        pressure: torch.Tensor,
        where: torch.Tensor,
        height: torch.Tensor | None,
        state: State,
        heads_state: tuple[State, State] | None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, State, tuple | None]:
        """One glance ``(p_s, where_s[, h_s])`` read by every part, the body of an episode played
        (:meth:`forward`) or replayed (:meth:`replay`): ``(tau, tau_policy, logits, baseline,
        state, heads_state)``, the core output ``tau_{1:s}``, what the location policy reads
        (:meth:`heads_step`), the classifier's logits and the baseline ``b(tau_{1:s})``, and the
        next states of the core and of the separate encoders."""
        tau, state = self.step(pressure, where, state, height)
        tau_policy, tau_value, heads_state = self.heads_step(
            tau, pressure, where, heads_state, height
        )
        return tau, tau_policy, self.classifier(tau), self.baseline(tau_value), state, heads_state

    def replay(
        self,
        pressures: torch.Tensor,
        where: torch.Tensor,
        heights: torch.Tensor | None = None,
        played: Episode | None = None,
    ) -> Episode:
        """The network as it is now on recorded glances: pressures ``(S, B, pressure_dim)`` at the
        where-inputs ``(S, B, k)`` (contact heights ``(S, B)`` with ``height_input``); no
        environment, no sampling.

        ``played``: the episode that recorded them (:class:`ham.learn.train.GlanceRecorder`);
        its poses asked for are the replay's (the stay gate pulls towards them) and its chosen
        first glance is replayed too (the same mixture component). Without it the where-inputs
        stand for the poses, the first glance counts as random and ``objects`` is ``None``: the
        bare network, the benchmark's reference cost. The info learner's PPO-style epochs replay
        each batch with the episode that played it."""
        batch, glances = pressures.shape[1], pressures.shape[0]
        locations = where if played is None else played.locations
        logits, baselines, dists = [], [], []
        first_baseline = None
        if played is not None and played.first_baseline is not None:  # a chosen first glance
            dist, first_baseline = self.first_glance(
                batch, pressures.device, choice=played.first_choice
            )
            dists.append(dist)
        state = self.core.initial_state(batch, pressures)
        heads_state = self.initial_heads_state(batch, pressures)
        for s in range(glances):
            h = None if heights is None else heights[s]
            tau, tau_policy, logit, baseline, state, heads_state = self.read(
                pressures[s], where[s], h, state, heads_state
            )
            logits.append(logit)
            baselines.append(baseline)
            if s < glances - 1:
                dists.append(
                    self.next_distribution(
                        tau_policy, locations[s], logit, glance=s + 1, position=where[s]
                    )
                )
        return Episode(
            objects=None if played is None else played.objects,
            locations=locations,
            logits=torch.stack(logits),
            baselines=torch.stack(baselines),
            policy=type(dists[0]).stack(dists) if dists else None,
            first_baseline=first_baseline,
            first_choice=None if played is None else played.first_choice,
        )

    def describe(self) -> str:
        """One line per part with its trainable weights, and the total."""
        lines = [f"{name:<11} {count_parameters(m):>9,}" for name, m in self.named_children()]
        lines.append(f"{'total':<11} {count_parameters(self):>9,}")
        return "\n".join(lines)
