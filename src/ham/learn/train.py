"""Training the HAM (section "Training"), readable top to bottom.

Each step: draw a fresh batch of 64 objects uniformly (from the haptic world, a glance table or
online; or from an ap_gym environment, ``TrainConfig.env``), play ``S`` glances (the first
random, the rest from the location policy), compute the hybrid loss (:mod:`ham.learn.hybrid_loss`),
take one SGD step with Nesterov momentum 0.9 at the learning rate
``lr_t = max(lr_min, lr * lr_decay^(t / lr_step))`` (8e-4, 0.97, T = 800; the authors' code uses
T = 200). Every ``eval_every`` steps (200) evaluate 100 fresh balanced batches
(:mod:`ham.learn.evaluation`), track the best accuracy, log to TensorBoard, and write a checkpoint.

A run directory holds::

    config.json      the TrainConfig (model, world/table, every hyperparameter)
    metrics.json     best/final accuracy, per-glance accuracies, the evaluation history
    checkpoint.pt    model, optimizer and random-generator states (written atomically)
    timing.json      wall-clock per step (kept apart: metrics.json is bit-reproducible)
    tb/              TensorBoard scalars

``resume(DIR)`` continues from the checkpoint and gives bit-identical numbers to an uninterrupted
run: all randomness comes from three seeded streams (objects, poses, evaluation) whose states
are saved, and the model's initial weights from ``torch.manual_seed(seed)``. One loop, one
checkpoint and one metrics path serve every world: :meth:`Run.create` makes the environment
the config names (or takes one given).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import time
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import torch
from torch import nn
from tqdm.auto import tqdm

from ham.errors import (
    DivergedError,
    HamError,
    check_choices,
    check_known_fields,
    check_seed,
    check_types,
    checked_arguments,
)
from ham.learn.ap_adapter import ApGymConfig, ApGymGlanceEnv
from ham.learn.environment import HapticEnv, check_pose_noise
from ham.learn.evaluation import EVAL_POLICIES, EvalResult, evaluate
from ham.learn.hybrid_loss import (
    CLASSIFICATION_GLANCES,
    REDUCTIONS,
    REWARD_GLANCES,
    HybridLoss,
    hybrid_loss,
)
from ham.learn.info_loss import (
    INFO_REWARDS,
    MOVE_COSTS,
    InfoLoss,
    clipped_info_loss,
    info_loss,
    info_targets,
    information_gain,
    mean_travel_penalty,
)
from ham.learn.learners import LEARNER_OPTIONS, LEARNERS, READS, learner_loss, unknown_learner
from ham.learn.off_policy import SacLoss, SacState, sac_update
from ham.learn.probe import PROBE_SCORES, probe_due, probe_glances, probe_round, probe_schedule
from ham.learn.stopping import STOP_LEARNERS, stop_loss
from ham.model.agent import HamConfig, HapticAttentionModel, count_parameters
from ham.world.config import WorldConfig, world_differences
from ham.world.devices import check_device, environment_record, source_commit
from ham.world.files import atomic_write, check_output_dir, folder_lock, write_json
from ham.world.sensor import NORMALIZATIONS
from ham.world.source import ObjectPoseConfig, check_model_fits, make_source, world_pose_dims

CONFIG_FILE = "config.json"
METRICS_FILE = "metrics.json"
CHECKPOINT_FILE = "checkpoint.pt"
TIMING_FILE = "timing.json"
DEVICES: tuple[str, ...] = ("cpu", "cuda")
OPTIMIZERS: tuple[str, ...] = ("sgd", "adam")
#: ``TrainConfig.first_pose_lr_scale``'s default (docs/learners.md, "A learned stop")
FIRST_POSE_LR_SCALE = 10.0
#: the first pose's search (``first_glance = "probe"``): its defaults (docs/learners.md)
PROBE_WARMUP, PROBE_EVERY, PROBE_KEEP = 100, 10, 0.5


@dataclass(frozen=True)
class TrainConfig:
    """Every training hyperparameter, with the paper's value as its default (Table Hyperparameters).

    Attributes:
        model: the network (:class:`ham.model.agent.HamConfig`), glances included.
        steps: training steps (50,000).
        batch_size: objects per batch (64).
        lr: initial learning rate alpha_0 (8e-4).
        lr_decay: decay factor delta_alpha (0.97).
        lr_step: decay step size T (800; 200 in the authors' code).
        lr_min: minimal learning rate alpha_min (1e-6).
        momentum: Nesterov momentum (0.9).
        nesterov: SGD with Nesterov momentum (paper) or plain momentum.
        beta: location weight of the hybrid loss (0.4); the random policy has no REINFORCE term.
        classification_reduction: ``sum`` adds the episodes' classification updates over the
            batch (Eq update_weights is written per episode, with no 1/B); ``mean`` averages them
            (64 times smaller steps: at the paper's learning rate it learns far too slowly).
        reinforce_reduction: ``mean`` averages the episodes' REINFORCE updates (the estimate of
            the policy gradient); ``sum`` adds them (64 times larger steps of the location heads:
            the policy collapses, docs/agent.md). The baseline's MSE is a batch mean either way.
        classification_glances: ``last`` trains the prediction after the last glance (the
            paper); ``all`` the prediction after every glance, averaged over the glances (the
            APPLE study's HAM).
        reward_glances: ``last`` rewards the prediction after the last glance (the paper);
            ``all`` rewards the prediction after every glance (the APPLE study's HAM), each
            pose credited with the rewards from its state on (:func:`ham.learn.hybrid_loss.returns`).
        reward_discount: gamma of the hybrid loss's returns within an episode (1: none, the
            paper; 0.99 in the APPLE study's HAM).
        glance_reduction: ``sum`` adds the REINFORCE term over an episode's poses and the
            baseline loss over its sub-sequences (the paper); ``mean`` averages both over the
            glances (the APPLE study's HAM: its policy and value losses are means over the steps;
            at 10 glances with a learned first glance the REINFORCE term is then that of a
            tenth of beta, a ninth with a random one).
        eval_every: steps between evaluations and checkpoints (200, the authors' code).
        eval_batches: balanced batches per evaluation (100).
        eval_policy: the location policy during evaluation: ``mean`` poses (training stopped)
            or ``sample`` (as in training); see :mod:`ham.learn.evaluation`.
        seed: seeds the initial weights and the generators of objects, poses and evaluation.
        normalization: of the glances: pressure (l2 the paper, l1 the authors' code, none) or an
            ap_gym glimpse.
        table: a glance table file (the paper's pre-recorded data set); ``None``: online.
        world: the world simulated online when ``table`` and ``env`` are ``None``.
        env: an ap_gym environment to train on instead of the haptic world
            (:class:`ham.learn.ap_adapter.ApGymConfig`; :func:`fit_to_ap_gym` sizes the model
            for it); ``None``: the haptic world.
        device: ``cpu`` or ``cuda``.
        log_every: steps between TensorBoard training scalars.
        learner: ``hybrid`` (the paper's hybrid REINFORCE loss, :mod:`ham.learn.hybrid_loss`),
            ``info`` (beyond the paper: cross-entropy after every glance and an actor-critic
            on the information each glance gains, :mod:`ham.learn.info_loss`) or ``sac`` (the
            same classification, the location policy by a soft actor-critic over replayed
            episodes, :mod:`ham.learn.off_policy`), or a learner of your own from a plugin
            (:mod:`ham.learn.learners`).
        optimizer: ``sgd`` (the paper: SGD, Nesterov momentum) or ``adam`` (at the same
            learning-rate schedule; beta_1 = momentum).
        gamma: discount of the information reward over the glances (info learner; 0.5: a
            glance is credited mostly with what it and the next few gain, docs/learners.md).
        gae_lambda: GAE lambda of the info learner's advantages (1: Monte-Carlo returns).
        info_reward: what a glance earns the info learner's policy: ``gain`` (the information
            it gains, ``CE_{s-1} - CE_s``) or ``hit`` (the change of the 0/1 score of the
            arg-max answer, ``c_s - c_{s-1}``: the paper's reward spread over the glances;
            :func:`ham.learn.info_loss.glance_reward`).
        entropy_coef: weight of the policy's entropy bonus (info learner; 0).
        move_cost: the info learner's cost per unit of distance between consecutive poses
            (normalized units; 0: moving is free, the paper); evaluations report the path.
        move_cost_on: where the move cost acts (:func:`ham.learn.info_loss.info_loss`):
            ``mean`` (a differentiable penalty on the distance from the pad's pose to the
            policy's mean next pose; halves the path, docs/learners.md) or ``reward`` (in the
            policy's REINFORCE reward, the first version) or ``both``.
        glance_cost: with a learned stop (``HamConfig.stop``), what each glance costs the stop
            head's return (info learner; :mod:`ham.learn.stopping`).
        stop_learner: how the stop head learns (:mod:`ham.learn.stopping`): ``value`` (a
            regression of the reward difference classify-now vs continue), ``hindsight`` (the
            same with the best later payoff as the value of continuing) or ``reinforce``.
        normalize_advantage: scale the info learner's advantages to zero mean and unit
            deviation over the batch (default ``False``: raw advantages in nats; normalized,
            the noise of a solved batch is blown up to unit size, docs/learners.md).
        policy_lr_scale: the location network's learning rate relative to ``lr`` (1: one rate
            for all weights; with separate encoders the policy's encoder's too). Under Adam a
            loss weight cannot slow a part down (its steps are scale-free); this can: a fast
            classifier, a slower policy. 0 keeps the policy as it is (fine-tuning a run's
            reader on a new pad's glances, docs/sim_to_real.md).
        first_pose_lr_scale: the learning rate of the first glance's own pose distribution
            (``HamConfig.first_glance = "own"``) relative to ``lr``, on the same schedule (10:
            in the recipe's decaying schedule its sigma shrinks from 1 to 0.04-0.2; at 3 to
            0.2-0.34, docs/learners.md).
        env_steps: a budget in environment steps (glances) instead of ``steps``: when given,
            ``steps = ceil((env_steps - probes) / (batch_size * glances))`` with ``probes``
            the glances of the first pose's search (``first_glance = "probe"``; 0 otherwise);
            ``None``: ``steps`` rules.
        probe_warmup: with ``HamConfig.first_glance = "probe"`` (:mod:`ham.learn.probe`),
            training steps before the search's first round (100), first glances drawn among
            all the lattice's candidates.
        probe_every: training steps between the search's rounds (10).
        probe_keep: the share of the candidates a round keeps (0.5: successive halving).
        probe_score: how a round ranks the candidates (:func:`ham.learn.probe.rank`):
            ``errors`` (the objects the classifier answers wrong after the one glance, then its
            cross-entropy) or ``ce`` (the cross-entropy alone, the first version).
        epochs: optimizer steps per batch (info learner; 1: one, as the paper). With more, the
            batch is played once and its recorded glances replayed ``epochs`` times, each pass
            one step on the clipped (PPO) policy loss (:func:`ham.learn.info_loss.clipped_info_loss`):
            more updates per environment step.
        clip: PPO's clip of the probability ratio, ``1 +- clip`` (with ``epochs > 1``; 0.2).
        policy_epochs: of the ``epochs`` passes, how many train the location policy (the first
            ones; ``None``: all). The others train the classifier and the critic only: more
            classifier updates without moving the policy further from the batch's.
        object_yaw_max: a random object pose per episode (beyond the paper; online glances
            only): the object turned by a yaw uniform in [-object_yaw_max, object_yaw_max] rad
            (0: off, the paper).
        object_offset_max: and shifted along x and y by offsets uniform in
            [-object_offset_max, object_offset_max] m (0: off, the paper).
        pose_noise: actuation noise (beyond the paper; the haptic world, a table or online):
            each glance is made at the chosen pose plus Gaussian noise of this standard
            deviation in the normalized pose units (the range [-1, 1]: 0.05 is 2.5 % of it),
            clamped to the range, while the model's "where" input stays the chosen pose
            (:class:`ham.learn.environment.HapticEnv`; 0: off, the paper).
        replay_size: the sac learner's replay buffer, in episodes (the oldest overwritten).
        replay_batch: episodes replayed per sac update.
        sac_updates: sac updates per training step (each on a fresh draw from the buffer;
            one training step plays one batch of batch_size episodes into it).
        target_tau: the sac critics' Polyak averaging rate of their target copies.
        init_alpha: the sac entropy temperature at the start (tuned from there).
        target_entropy: the entropy (nats) the sac temperature steers the policy to (None: minus
            the number of pose dims, SAC's choice).
        critic_trains_core: the sac critic's loss also trains the tactile network and the core
            (off: only the classification does; the critic reads the core output detached).
        spread_augment: domain randomization of the read-out (beyond the paper; the haptic
            world): each training episode's images spread by a Gaussian of a sigma drawn
            uniformly in ``[0, spread_augment]`` m (the Gazebo plugin's spread is 0.005), before
            normalization; evaluation reads the world's own glances
            (:class:`ham.learn.environment.HapticEnv`, docs/results/transfer.md). 0: off.
        init_from: a run folder whose latest weights a fresh run starts from instead of its
            seed's initial ones (fine-tuning: a model trained in one world adapted to another;
            :func:`start_from`): the same model, the number of glances aside; the optimizer,
            the generators and the step count start afresh. ``None``: the seed's weights.
    """

    model: HamConfig = field(default_factory=HamConfig)
    steps: int = 50_000
    batch_size: int = 64
    lr: float = 8e-4
    lr_decay: float = 0.97
    lr_step: int = 800
    lr_min: float = 1e-6
    momentum: float = 0.9
    nesterov: bool = True
    beta: float = 0.4
    classification_reduction: str = field(default="sum", metadata={"choices": REDUCTIONS})
    reinforce_reduction: str = field(default="mean", metadata={"choices": REDUCTIONS})
    classification_glances: str = field(
        default="last", metadata={"choices": CLASSIFICATION_GLANCES}
    )
    reward_glances: str = field(default="last", metadata={"choices": REWARD_GLANCES})
    reward_discount: float = 1.0
    glance_reduction: str = field(default="sum", metadata={"choices": REDUCTIONS})
    eval_every: int = 200
    eval_batches: int = 100
    eval_policy: str = field(default="mean", metadata={"choices": EVAL_POLICIES})
    seed: int = 0
    normalization: str = field(default="l2", metadata={"choices": NORMALIZATIONS})
    table: str | None = None
    world: WorldConfig = field(default_factory=WorldConfig)
    device: str = "cpu"
    log_every: int = 10
    env: ApGymConfig | None = None
    learner: str = field(default="hybrid", metadata={"choices": LEARNERS})
    optimizer: str = field(default="sgd", metadata={"choices": OPTIMIZERS})
    gamma: float = 0.5
    gae_lambda: float = 1.0
    info_reward: str = field(default="gain", metadata={"choices": INFO_REWARDS})
    entropy_coef: float = 0.0
    move_cost: float = 0.0
    move_cost_on: str = field(default="mean", metadata={"choices": MOVE_COSTS})
    glance_cost: float = 0.0
    stop_learner: str = field(default="value", metadata={"choices": STOP_LEARNERS})
    normalize_advantage: bool = False
    policy_lr_scale: float = 1.0
    first_pose_lr_scale: float = FIRST_POSE_LR_SCALE
    env_steps: int | None = None
    probe_warmup: int = PROBE_WARMUP
    probe_every: int = PROBE_EVERY
    probe_keep: float = PROBE_KEEP
    probe_score: str = field(default="errors", metadata={"choices": PROBE_SCORES})
    epochs: int = 1
    clip: float = 0.2
    policy_epochs: int | None = None
    object_yaw_max: float = 0.0
    object_offset_max: float = 0.0
    pose_noise: float = 0.0
    replay_size: int = 100_000
    replay_batch: int = 32
    sac_updates: int = 4
    target_tau: float = 0.005
    init_alpha: float = 0.1
    target_entropy: float | None = None
    critic_trains_core: bool = False
    spread_augment: float = field(default=0.0, metadata={"metavar": "M"})
    init_from: str | None = field(default=None, metadata={"metavar": "DIR"})

    def __post_init__(self) -> None:
        check_types(self)
        if self.env_steps is not None:
            v = self.env_steps
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
                raise HamError(f"env_steps = {v!r}; accepted: an integer >= 1 (or None)")
            self._check_probe()
            if isinstance(self.batch_size, int) and self.batch_size >= 1:
                # frozen: the budget in glances defines the steps (recorded both ways); the
                # first pose's probe glances are environment steps too
                per_step = self.batch_size * self.model.glances
                probes = self.probe_glances
                if probes >= v:
                    raise HamError(
                        f"env_steps = {v}: the first pose's search alone spends {probes} "
                        f"glances; accepted: env_steps > {probes} (or a smaller --probe-grid)"
                    )
                object.__setattr__(self, "steps", math.ceil((v - probes) / per_step))
        for name in ("steps", "batch_size", "lr_step", "eval_every", "eval_batches", "log_every"):
            v = getattr(self, name)
            low = 0 if name == "steps" else 1
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= low):
                raise HamError(f"{name} = {v!r}; accepted: an integer >= {low}")
        for name in ("lr", "lr_min"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise HamError(f"{name} = {v!r}; accepted: a finite number > 0")
        if not 0 < self.lr_decay <= 1:
            raise HamError(f"lr_decay = {self.lr_decay!r}; accepted: 0 < lr_decay <= 1")
        if not 0 <= self.momentum < 1:
            raise HamError(f"momentum = {self.momentum!r}; accepted: 0 <= momentum < 1")
        if self.nesterov and self.momentum == 0 and self.optimizer == "sgd":
            raise HamError(
                "nesterov = true with momentum = 0; accepted: momentum > 0, or no nesterov"
            )
        if not (math.isfinite(self.beta) and self.beta >= 0):
            raise HamError(f"beta = {self.beta!r}; accepted: a finite number >= 0")
        check_seed(self.seed)
        if self.learner not in LEARNERS:  # a name of the user's own: say how
            raise unknown_learner(self.learner)
        self._check_plugin_used()
        check_choices(self)
        for name in ("gamma", "gae_lambda", "reward_discount"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0 <= v <= 1):
                raise HamError(f"{name} = {v!r}; accepted: a number in [0, 1]")
        if not (isinstance(self.move_cost, (int, float)) and not isinstance(self.move_cost, bool)
                and math.isfinite(self.move_cost) and self.move_cost >= 0):  # fmt: skip
            raise HamError(f"move_cost = {self.move_cost!r}; accepted: a finite number >= 0")
        if not (isinstance(self.glance_cost, (int, float)) and not isinstance(self.glance_cost, bool)
                and math.isfinite(self.glance_cost) and self.glance_cost >= 0):  # fmt: skip
            raise HamError(f"glance_cost = {self.glance_cost!r}; accepted: a finite number >= 0")
        if self.model.stop and self.learner != "info":
            raise HamError(
                f"a learned stop (--stop) with learner {self.learner!r}; accepted: --learner info "
                "(its classifier answers after every glance)"
            )
        if self.glance_cost > 0 and not self.model.stop:
            raise HamError(
                f"glance_cost = {self.glance_cost!r} without a learned stop; accepted: with --stop"
            )
        if self.move_cost > 0 and self.learner != "info":
            raise HamError(
                f"move_cost = {self.move_cost!r} with learner {self.learner!r}; accepted: a move "
                "cost with --learner info (its reward is per glance)"
            )
        if not (isinstance(self.entropy_coef, (int, float)) and math.isfinite(self.entropy_coef)
                and self.entropy_coef >= 0):  # fmt: skip
            raise HamError(f"entropy_coef = {self.entropy_coef!r}; accepted: a finite number >= 0")
        v = self.policy_lr_scale
        if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise HamError(f"policy_lr_scale = {v!r}; accepted: a finite number >= 0 (0: the "
                           "location network kept as it is)")  # fmt: skip
        v = self.first_pose_lr_scale
        if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise HamError(f"first_pose_lr_scale = {v!r}; accepted: a finite number > 0")
        if v != FIRST_POSE_LR_SCALE and self.model.first_glance != "own":
            raise HamError(
                f"first_pose_lr_scale = {v!r} with first_glance {self.model.first_glance!r}; "
                "accepted: with --first-glance own (its own first pose)"
            )
        self._check_probe()
        self._check_probe_run()
        self._check_epochs()
        self._check_sac()
        self._check_unused()
        check_device(self.device, available=False)  # spelling only: a saved GPU run loads on CPU
        if self.env is not None and self.table is not None:
            raise HamError(
                f"table {self.table!r} and env {self.env.env!r} exclude each other; give one"
            )
        for name, top in (("object_yaw_max", math.pi), ("object_offset_max", 0.05)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v <= top:
                raise HamError(f"{name} = {v!r}; accepted: a number 0..{top:.6g}")
        v = self.spread_augment
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v <= 0.05:
            raise HamError(f"spread_augment = {v!r}; accepted: a number 0..0.05 (m)")
        if v > 0 and self.env is not None:
            raise HamError(
                f"spread_augment = {v!r} with env {self.env.env!r}; accepted: a spread of the "
                "haptic world's images (a table or online glances)"
            )
        check_pose_noise(self.pose_noise)
        if self.pose_noise > 0 and self.env is not None:
            raise HamError(
                f"pose_noise = {self.pose_noise!r} with env {self.env.env!r}; accepted: a pose noise in the "
                "haptic world (a table or online glances)"
            )
        if self.object_pose.enabled and (self.table is not None or self.env is not None):
            raise HamError(
                f"a random object pose ({self.object_pose}) with "
                f"{'table ' + repr(self.table) if self.table else 'env ' + repr(self.env.env)}; "
                "accepted: online glances in the haptic world"
            )
        if self.table is None and self.env is None:
            self.object_pose.check_world(self.world)

    @property
    def object_pose(self) -> ObjectPoseConfig:
        """The random object pose per episode (:class:`ham.world.source.ObjectPoseConfig`)."""
        return ObjectPoseConfig(self.object_yaw_max, self.object_offset_max)

    @property
    def probe_glances(self) -> int:
        """Environment steps the first pose's search spends (0 unless ``first_glance =
        "probe"``)."""
        if self.model.first_glance != "probe":
            return 0
        n = self.model.probe_grid ** len(self.model.pose_dims)
        return probe_glances(n, self.probe_keep, self.model.n_objects)

    def _check_probe(self) -> None:
        for name in ("probe_warmup", "probe_every"):
            v = getattr(self, name)
            low = 0 if name == "probe_warmup" else 1
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= low):
                raise HamError(f"{name} = {v!r}; accepted: an integer >= {low}")
        v = self.probe_keep
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < 1:
            raise HamError(f"probe_keep = {v!r}; accepted: a number in (0, 1)")
        defaults = (PROBE_WARMUP, PROBE_EVERY, PROBE_KEEP, "errors")
        given = (self.probe_warmup, self.probe_every, self.probe_keep, self.probe_score)
        names = ("probe_warmup", "probe_every", "probe_keep", "probe_score")
        for name, value, default in zip(names, given, defaults, strict=True):
            if value != default and self.model.first_glance != "probe":
                raise HamError(
                    f"{name} = {value!r} with first_glance {self.model.first_glance!r}; "
                    "accepted: with --first-glance probe (the first pose's search)"
                )

    def _check_probe_run(self) -> None:
        if self.model.first_glance != "probe":
            return
        where = (
            f"env {self.env.env!r}" if self.env is not None
            else f"a random object pose ({self.object_pose})" if self.object_pose.enabled
            else None
        )  # fmt: skip
        if self.learner != "info" or where is not None:
            raise HamError(
                f"first_glance 'probe' with {where or 'learner ' + repr(self.learner)}; "
                "accepted: --learner info in the haptic world (a table or online glances, "
                "objects at their pose)"
            )
        rounds = len(probe_schedule(self.model.probe_grid ** len(self.model.pose_dims),
                                    self.probe_keep))  # fmt: skip
        last = self.probe_warmup + (rounds - 1) * self.probe_every
        # a budget counts the whole search's glances: it must fit (a run of explicit --steps
        # may stop inside the search and be resumed)
        if self.env_steps is not None and last >= self.steps:
            raise HamError(
                f"the first pose's search ends before step {last + 1} (probe_warmup "
                f"{self.probe_warmup} + {rounds - 1} rounds x probe_every {self.probe_every}) "
                f"but the budget gives {self.steps} steps; accepted: a budget of more steps"
            )

    def _check_plugin_used(self) -> None:
        """A plugin that registers a learner: the run uses its core, policy or learner."""
        plugin = self.model.plugin
        if plugin is None:
            return
        from ham.model.plugin import load_plugin

        registered = load_plugin(plugin)  # loaded once, by HamConfig
        uses = {f"core {self.model.core}", f"policy {self.model.policy}", f"learner {self.learner}"}
        if not uses & set(registered):
            raise HamError(
                f"plugin {plugin['name']!r} with core {self.model.core!r}, policy "
                f"{self.model.policy!r} and learner {self.learner!r}, none of which it registers; "
                f"accepted: --core, --policy or --learner of the plugin's ({', '.join(registered)})"
            )

    def _check_unused(self) -> None:
        """A field set away from its default where nothing reads it is refused, not ignored:
        another learner's options, the move cost's place without a move cost, the stop's
        learner without a stop, PPO's clip and policy epochs with one epoch."""
        defaults = {f.name: f.default for f in fields(self)}
        for name, learners in LEARNER_OPTIONS.items():
            value = getattr(self, name)
            learners = learners + tuple(n for n, reads in READS.items() if name in reads)
            if self.learner not in learners and value != defaults[name]:
                raise HamError(
                    f"{name} = {value!r} with learner {self.learner!r}, which does not read it; "
                    f"accepted: {name} with --learner {' or '.join(learners)}"
                )
        for name, applies, accepted in (
            ("move_cost_on", self.move_cost > 0, "with --move-cost > 0"),
            ("stop_learner", self.model.stop, "with --stop"),
            ("clip", self.epochs > 1, "with --epochs > 1"),
            ("policy_epochs", self.epochs > 1, "with --epochs > 1"),
            ("nesterov", self.optimizer == "sgd", "with --optimizer sgd"),
        ):
            value = getattr(self, name)
            if not applies and value != defaults[name]:
                raise HamError(f"{name} = {value!r} where nothing reads it; accepted: {accepted}")

    def _check_epochs(self) -> None:
        if not (isinstance(self.epochs, int) and not isinstance(self.epochs, bool)
                and self.epochs >= 1):  # fmt: skip
            raise HamError(f"epochs = {self.epochs!r}; accepted: an integer >= 1")
        v = self.clip
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                and v > 0):  # fmt: skip
            raise HamError(f"clip = {v!r}; accepted: a finite number > 0")
        if self.epochs > 1 and self.learner != "info":
            raise HamError(
                f"epochs = {self.epochs} with learner {self.learner!r}; accepted: epochs > 1 with "
                "--learner info"
            )
        v = self.policy_epochs
        if v is not None and not (isinstance(v, int) and not isinstance(v, bool)
                                  and 1 <= v <= self.epochs):  # fmt: skip
            raise HamError(
                f"policy_epochs = {v!r}; accepted: an integer in [1, epochs = {self.epochs}]"
            )
        if self.epochs > 1 and self.model.stop:
            raise HamError(f"epochs = {self.epochs} with a learned stop; accepted: epochs = 1")

    def _check_sac(self) -> None:
        for name in ("replay_size", "replay_batch", "sac_updates"):
            v = getattr(self, name)
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
                raise HamError(f"{name} = {v!r}; accepted: an integer >= 1")
        v = self.target_tau
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v <= 1:
            raise HamError(f"target_tau = {v!r}; accepted: a number in (0, 1]")
        v = self.init_alpha
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v)
                                                                           and v > 0):  # fmt: skip
            raise HamError(f"init_alpha = {v!r}; accepted: a finite number > 0")
        v = self.target_entropy
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                              or not math.isfinite(v)):  # fmt: skip
            raise HamError(f"target_entropy = {v!r}; accepted: a finite number (or None)")
        if not isinstance(self.critic_trains_core, bool):
            raise HamError(
                f"critic_trains_core = {self.critic_trains_core!r}; accepted: true or false"
            )
        if self.learner != "sac":
            return
        refused = (
            (
                "policy",
                self.model.policy not in ("squashed", "learned"),
                "--policy squashed (or learned)",
            ),
            ("stop", self.model.stop, "no --stop"),
            ("epochs", self.epochs > 1, "epochs = 1"),
            ("move_cost", self.move_cost > 0, "move_cost = 0"),
            ("stay_gate", self.model.stay_gate, "no --stay-gate"),
            ("encoders", self.model.encoders != "shared", "encoders 'shared'"),
            ("entropy_coef", self.entropy_coef > 0, "entropy_coef = 0 (the temperature is tuned)"),
        )
        for name, bad, accepted in refused:
            if bad:
                in_model = name in ("policy", "stop", "stay_gate", "encoders")
                value = getattr(self.model, name, None) if in_model else None
                value = getattr(self, name) if value is None else value
                raise HamError(f"{name} = {value!r} with learner 'sac'; accepted: {accepted}")

    def learning_rate(self, step: int) -> float:
        """``alpha_t = max(alpha_min, alpha_0 * delta_alpha^(t / T))`` (section "Training")."""
        return max(self.lr_min, self.lr * self.lr_decay ** (step / self.lr_step))

    def to_dict(self) -> dict:
        d = asdict(self)
        d["world"] = self.world.to_dict()
        d["model"] = self.model.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        check_known_fields(cls, d, "train config")
        d = dict(d)
        d["model"] = HamConfig.from_dict(d.get("model", {}))
        d["world"] = WorldConfig.from_dict(d.get("world", {}))
        if d.get("env") is not None:
            d["env"] = ApGymConfig.from_dict(d["env"])
        return cls(**d)


# --------------------------------------------------------------------------- the parts of a run
def model_for_source(
    model: HamConfig, table: str | os.PathLike | None, world: WorldConfig
) -> HamConfig:
    """``model`` sized for its glances: ``pressure_dim`` (``taxels^2``), ``n_objects`` and the
    ``pose_dims`` (one location stream each) from the glance table when given (its recorded
    sensor, objects and grid), else from the online ``world``."""
    if table is not None:
        from ham.world.table import table_info

        info = table_info(table)
        dim, n, dims = info.pressure_dim, len(info.objects), tuple(info.pose_dims)
    else:
        dim, n = world.sensor.pressure_dim, len(world.resolve_objects())
        dims = world_pose_dims(world)
    return replace(model, pressure_dim=dim, n_objects=n, pose_dims=dims)


def parameter_groups(
    agent: HapticAttentionModel, policy_lr_scale: float, first_pose_lr_scale: float = 1.0
) -> list[dict]:
    """The optimizer's parameter groups: one (every weight at ``lr``), or, when the location
    network or the first glance's own pose (``first_glance = "own"``) learns at its own rate,
    the rest, the location network (with the stay gate and the policy's own encoder,
    ``encoders = "separate"``) and the first pose (``lr_scale`` each)."""
    first = getattr(agent, "first_pose", None)
    if policy_lr_scale == 1.0 and first is None:
        return [{"params": list(agent.parameters()), "lr_scale": 1.0}]
    location = [agent.location]
    if getattr(agent, "stay", None) is not None:  # the stay gate is the location policy's
        location.append(agent.stay)
    if agent.separate_encoders:  # and so is its encoder: only the policy's loss trains it
        location.append(agent.policy_encoder)
    parts = [(nn.ModuleList(location), policy_lr_scale)]
    if first is not None:
        parts.append((first, first_pose_lr_scale))
    own = {id(p) for module, _ in parts for p in module.parameters()}
    rest = [p for p in agent.parameters() if id(p) not in own]
    return [{"params": rest, "lr_scale": 1.0}] + [
        {"params": list(module.parameters()), "lr_scale": scale} for module, scale in parts
    ]


def stream_seed(seed: int, stream: int) -> int:
    """Independent seeds for the generators of one run: 0 objects, 1 poses, 2 evaluation."""
    return seed * 1000 + stream


@dataclass
class Run:
    """Everything a training run evolves, and what a checkpoint saves."""

    config: TrainConfig
    agent: HapticAttentionModel
    env: HapticEnv | ApGymGlanceEnv  # anything with their interface
    optimizer: torch.optim.Optimizer
    policy_generator: torch.Generator
    step: int = 0
    best_accuracy: float = -1.0
    best_step: int = 0
    best_accumulated_accuracy: float = -1.0
    history: list = field(default_factory=list)
    objects: list = field(default_factory=list)
    #: the sac learner's critics, temperature, replay buffer (``None`` for the other learners)
    sac: SacState | None = None
    #: the sha256 of the glance table's pressures (``None`` without a table): a checkpoint
    #: keeps it, so that a run is never continued or evaluated on another table at its path
    table_checksum: str | None = None
    #: a run loaded onto another world's glances (:func:`load_run`'s ``transfer_table``): how
    #: that table's world differs from the one the run trained in (``None``: its own world)
    transfer: list[str] | None = None

    @classmethod
    def create(cls, config: TrainConfig, env: HapticEnv | ApGymGlanceEnv | None = None) -> Run:
        """A fresh run of ``config``: its environment (``env``, or the one the config names:
        the haptic world from a glance table or online, or ``config.env`` on ap_gym), the model
        with its initial weights, the optimizer and the pose generator. The run owns ``env``
        (:meth:`close`)."""
        device = check_device(config.device)
        if env is None:
            env = make_env(config, device)
        _check_env(config.model, env)
        torch.manual_seed(config.seed)  # the initial weights
        agent = HapticAttentionModel(config.model).to(device)
        params = parameter_groups(agent, config.policy_lr_scale, config.first_pose_lr_scale)
        if config.optimizer == "adam":
            optimizer = torch.optim.Adam(
                params, lr=config.lr, betas=(config.momentum, 0.999), foreach=True
            )
        else:
            optimizer = torch.optim.SGD(
                params,
                lr=config.lr,
                momentum=config.momentum,
                nesterov=config.nesterov,
                foreach=True,
            )
        policy_generator = torch.Generator(device=device)
        policy_generator.manual_seed(stream_seed(config.seed, 1))
        sac = SacState(agent, config, device) if config.learner == "sac" else None
        checksum = None
        if config.table is not None:
            from ham.world.table import table_info

            checksum = table_info(config.table).checksum
        return cls(
            config, agent, env, optimizer, policy_generator, objects=list(env.objects), sac=sac,
            table_checksum=checksum,
        )  # fmt: skip

    def close(self) -> None:
        """Release the environment (ap_gym's data loaders)."""
        close = getattr(self.env, "close", None)
        if close is not None:
            close()

    def state_dict(self) -> dict:
        state = {
            "step": self.step,
            "model": self.agent.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "env": self.env.state_dict(),
            "policy_generator": self.policy_generator.get_state(),
            "best_accuracy": self.best_accuracy,
            "best_step": self.best_step,
            "best_accumulated_accuracy": self.best_accumulated_accuracy,
            "history": self.history,
        }
        if self.sac is not None:  # only the sac learner's checkpoints carry it
            state["sac"] = self.sac.state_dict()
        if self.table_checksum is not None:
            state["table_checksum"] = self.table_checksum
        return state

    def load_state_dict(self, state: dict) -> None:
        saved = state.get("table_checksum")  # absent in checkpoints written before it was kept
        if saved is not None and self.table_checksum not in (None, saved):
            raise HamError(
                f"glance table {self.config.table!r} is not the one this run trained on (its "
                f"sha256 {self.table_checksum[:12]}..., the run's {saved[:12]}...); accepted: "
                "the run's own table at that path"
            )
        self.step = int(state["step"])
        self.agent.load_state_dict(state["model"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.env.load_state_dict(state["env"])
        self.policy_generator.set_state(state["policy_generator"])
        self.best_accuracy = float(state["best_accuracy"])
        self.best_step = int(state["best_step"])
        self.best_accumulated_accuracy = float(state["best_accumulated_accuracy"])
        self.history = list(state["history"])
        if self.sac is not None:
            if "sac" not in state:
                raise HamError("the checkpoint has no sac learner state; accepted: a sac run's")
            self.sac.load_state_dict(state["sac"])

    @property
    def env_steps(self) -> int:
        """Environment steps so far, counted as the field counts them: glances (the first
        pose's probe glances included)."""
        played = self.step * self.config.batch_size * self.config.model.glances
        search = getattr(self.agent, "first_probe", None)
        return played if search is None else played + int(search.probes)

    def reached(self, accuracy: float) -> int | None:
        """Environment steps at the first evaluation whose final accuracy was >= ``accuracy``."""
        for row in self.history:
            if row["accuracy"] >= accuracy:
                if "env_steps" in row:  # with the first pose's probe glances
                    return row["env_steps"]
                return row["step"] * self.config.batch_size * self.config.model.glances
        return None

    def metrics(self) -> dict:
        last = self.history[-1] if self.history else {}
        per_glance = last.get("accuracy_per_glance") or []
        return {
            "env_steps": self.env_steps,
            "average_accuracy": sum(per_glance) / len(per_glance) if per_glance else None,
            "path_length": last.get("path_length"),
            "pose_spread": last.get("pose_spread"),
            "pose_spread_within_object": last.get("pose_spread_within_object"),
            "stop_accuracy": last.get("stop_accuracy"),
            "mean_glances": last.get("mean_glances"),
            "env_steps_to_0.95": self.reached(0.95),
            "env_steps_to_0.99": self.reached(0.99),
            "glances_to_0.95": next((i + 1 for i, a in enumerate(per_glance) if a >= 0.95), None),
            "glances_to_0.99": next((i + 1 for i, a in enumerate(per_glance) if a >= 0.99), None),
            "best_accuracy": self.best_accuracy,
            "best_step": self.best_step,
            "best_accumulated_accuracy": self.best_accumulated_accuracy,
            "final_accuracy": last.get("accuracy"),
            "steps": self.step,
            "accuracy_per_glance": last.get("accuracy_per_glance"),
            "accumulated_accuracy_per_glance": last.get("accumulated_accuracy_per_glance"),
            "per_object_accuracy": last.get("per_object_accuracy"),
            "confusion": last.get("confusion"),
            "parameters": count_parameters(self.agent),
            "objects": self.objects,
            "config": self.config.to_dict(),
            "history": self.history,
        }


def make_env(config: TrainConfig, device: torch.device | str = "cpu") -> HapticEnv | ApGymGlanceEnv:
    """The training environment ``config`` names: ap_gym (``config.env``) or the haptic world
    (a glance table, or the online simulator of ``config.world``). Object stream: seed stream 0."""
    if config.env is not None:
        from ham.learn.ap_adapter import make_ap_env

        seed, eval_seed = stream_seed(config.seed, 0), stream_seed(config.seed, 2)
        return make_ap_env(
            config.env, config.batch_size, seed, eval_seed, config.normalization, device
        )
    source, world = make_source(config.table, config.world, device)
    # The model's input and classes come from the source (taxels^2, its objects): refuse a
    # mismatch here, not as a shape error deep in the first step.
    check_model_fits(config.model.pressure_dim, config.model.n_objects, source)
    if config.model.pose_dims != source.pose_dims:
        raise HamError(
            f"the model chooses poses over {','.join(config.model.pose_dims)} but "
            f"{source.description} takes {','.join(source.pose_dims)}; accepted: a model with "
            f"pose_dims = {','.join(source.pose_dims)}"
        )
    return haptic_env(config, source, world, device)


def haptic_env(config: TrainConfig, source, world, device: torch.device | str) -> HapticEnv:
    """The :class:`HapticEnv` of ``config`` over glance ``source`` of ``world`` (its pad sets
    the spread augmentation's unit): the run's batch, normalization, object stream (seed stream
    0), object pose, pose noise and read-out spreads. The batched trainer's runs share one
    source."""
    return HapticEnv(
        source,
        config.batch_size,
        config.normalization,
        stream_seed(config.seed, 0),
        device,
        object_pose=config.object_pose,
        pose_noise=config.pose_noise,
        augment_sigma=config.spread_augment / world.sensor.pitch,
    )


@checked_arguments
def fit_to_ap_gym(config: TrainConfig, env: ApGymConfig, phi_scale: float = 1.0) -> TrainConfig:
    """``config`` training on the ap_gym environment ``env`` instead of the haptic world, the
    model sized for it (:func:`ham.learn.ap_adapter.sized_model`: glimpse size, classes,
    ``phi_scale``)."""
    from ham.learn.ap_adapter import sized_model

    model = sized_model(env, config.model, phi_scale)
    return replace(config, model=model, env=env, table=None)


def _check_env(model: HamConfig, env) -> None:
    """The model fits the environment: its classes, its glance size, its episode length."""
    if env.n_objects != model.n_objects:
        raise HamError(
            f"the model classifies {model.n_objects} objects but the environment "
            f"has {env.n_objects} ({', '.join(map(str, env.objects))})"
        )
    pressure_dim = getattr(env, "pressure_dim", None)
    if pressure_dim is not None and pressure_dim != model.pressure_dim:
        raise HamError(
            f"the model reads glances of {model.pressure_dim} values but the environment "
            f"gives {pressure_dim}"
        )
    check_glances = getattr(env, "check_glances", None)
    if check_glances is not None:
        check_glances(model.glances)
    if model.height_input and not hasattr(env, "glance_height"):
        raise HamError(
            "the model takes the contact height (height_input) but the environment gives none; "
            "accepted: the haptic world (glances carry h)"
        )
    table = getattr(getattr(env, "source", None), "table", None)
    if model.height_input and table is not None and not table.knows_heights:
        raise HamError(
            f"the model takes the contact height (height_input) but glance table "
            f"{table.info.path!r} does not know every glance's (NaN: imported without heights); "
            "accepted: a table with heights (recorded glances: NAME.height beside each object's "
            "images), or a model without height_input"
        )
    dims = tuple(getattr(env, "pose_dims", ("x", "phi")))
    if len(dims) != len(model.pose_dims):
        raise HamError(
            f"the model chooses {len(model.pose_dims)}-D poses ({','.join(model.pose_dims)}) "
            f"but the environment takes {len(dims)}-D ones; accepted: pose_dims = {','.join(dims)}"
        )


# --------------------------------------------------------------------------- files
def read_json(path: Path) -> dict:
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise HamError(f"{str(path)!r} does not exist: not a training run directory?") from None
    except NotADirectoryError:
        raise HamError(
            f"{str(Path(path).parent)!r} is a file; accepted: a training run directory"
        ) from None
    except ValueError as exc:  # JSONDecodeError, or bytes that are not UTF-8 text
        raise HamError(f"{str(path)!r} is not valid JSON ({exc})") from None


def read_run_config(out: Path) -> TrainConfig:
    """The :class:`TrainConfig` of the ``ham train`` run in ``out`` (one-line HamError if not)."""
    d = read_json(out / CONFIG_FILE)
    if isinstance(d, dict) and "algo" in d and "model" not in d:  # what ham sb3 writes
        raise HamError(
            f"{str(out)!r} holds a ham sb3 run ({d['algo']}); accepted: a ham train run "
            "directory (an SB3 run: its metrics.json, or ham sb3 --resume)"
        )
    return TrainConfig.from_dict(d)


def locate_table(
    out: Path, config: TrainConfig, saved: str | None, table: str | None = None
) -> TrainConfig:
    """``config`` with its glance table: ``table`` when given (the run's table moved: accepted
    only with ``saved``, the sha256 the run's checkpoint kept), else where config.json says, or,
    when the run was moved together with its table (a ``ham reproduce`` OUT copied from a
    cluster: its runs record ``OUT/table_N.h5`` by absolute path), the file of that name beside
    the run or up to two folders above it whose sha256 is ``saved``."""
    from ham.world.table import table_info

    if table is not None:
        return _moved_table(config, saved, table)
    if config.table is None or Path(config.table).exists():
        return config
    name = Path(config.table).name
    for folder in (out, out.parent, out.parent.parent) if saved is not None else ():
        candidate = folder / name
        if candidate.is_file() and table_info(candidate).checksum == saved:
            return replace(config, table=str(candidate.resolve()))
    raise HamError(
        f"glance table {config.table!r} does not exist (nor a {name!r} of this run's sha256 "
        f"beside the run or above it); accepted: the run's table at that path, or --table FILE "
        "where it is now"
    )


def _moved_table(config: TrainConfig, saved: str | None, table: str) -> TrainConfig:
    """``config`` with ``table`` (``--table``), the run's own glance table at a new path whose
    sha256 is ``saved``, the checkpoint's."""
    from ham.world.table import table_info

    if config.table is None:
        raise HamError(f"--table {table!r} for a run without a glance table; accepted: --table "
                       "with a run trained on one")  # fmt: skip
    if not Path(table).is_file():
        raise HamError(f"glance table {table!r} does not exist")
    if saved is None:
        raise HamError(f"--table {table!r}: the run's checkpoint keeps no table sha256 to check "
                       "it against (written before they were kept); accepted: the table at its "
                       f"recorded path {config.table!r}")  # fmt: skip
    checksum = table_info(table).checksum
    if checksum != saved:
        raise HamError(f"--table {table!r} is not the run's table (sha256 "
                       f"{checksum[:12]}..., the run's {saved[:12]}...); "
                       "accepted: the table the run trained on")  # fmt: skip
    return replace(config, table=str(Path(table).resolve()))


def load_checkpoint(out: Path) -> dict:
    path = Path(out) / CHECKPOINT_FILE
    if not path.exists():
        raise HamError(f"{str(path)!r} does not exist: the run has no checkpoint yet")
    try:
        return torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # noqa: BLE001 - any unreadable file is the user's bad input
        raise HamError(f"cannot read checkpoint {str(path)!r}: {exc}") from None


@checked_arguments
def load_run(
    out: str | os.PathLike,
    device: str | None = None,
    objects: str | None = None,
    table: str | None = None,
    transfer_table: str | None = None,
) -> Run:
    """The run in directory ``out`` at its latest checkpoint (for evaluation and heat maps).

    ``objects``: evaluate on other objects of the same number, class ``i`` the ``i``-th (e.g.
    ``composite:test``, the held-out instances of a run trained on ``composite:train``); the
    run's world otherwise (online runs only). ``table``: the run's glance table at a new path
    (:func:`locate_table`). ``transfer_table``: the agent on the glances of another table of
    the same objects and pose dims (another simulator, read-out, sensor or grid: how what it
    learned transfers), its own normalization applied; ``Run.transfer`` lists how that world
    differs from the run's own."""
    out = Path(out)
    config = read_run_config(out)
    state = load_checkpoint(out)  # read once: its table sha256 locates a moved table
    config = locate_table(out, config, state.get("table_checksum"), table)
    if device is not None:
        config = replace(config, device=device)
    if objects is not None and transfer_table is not None:
        raise HamError(
            f"--objects {objects!r} with --transfer-table {transfer_table!r}; accepted: one of "
            "them (a transfer table holds its own objects)"
        )
    transfer = None
    if transfer_table is not None:
        config, transfer = _transferred(config, transfer_table)
    if objects is not None:
        if config.table is not None or config.env is not None:
            raise HamError(
                f"--objects {objects!r} with a run on "
                f"{'table ' + repr(config.table) if config.table else 'env ' + repr(config.env.env)}"
                "; accepted: a run with online glances"
            )
        world = replace(config.world, objects=objects)
        n = len(world.resolve_objects())
        if n != config.model.n_objects:
            raise HamError(
                f"--objects {objects!r} has {n} objects but the run classifies "
                f"{config.model.n_objects}; accepted: one object per class, in class order"
            )
        config = replace(config, world=world)
    run = Run.create(config)
    if transfer is not None:  # another table on purpose: its sha256 is not the run's
        run.table_checksum, run.transfer = None, transfer
    run.load_state_dict(state)
    return run


def _transferred(config: TrainConfig, table: str) -> tuple[TrainConfig, list[str]]:
    """``config`` reading the glances of ``table`` (:func:`load_run`'s ``transfer_table``), and
    how that table's world differs from the run's own (its table's, or its online world)."""
    from ham.world.table import table_info

    if config.env is not None:
        raise HamError(
            f"--transfer-table {table!r} with a run on ap_gym env {config.env.env!r}; accepted: "
            "a run in the haptic world (a glance table or online glances)"
        )
    if not Path(table).is_file():
        what = "is a folder" if Path(table).is_dir() else "does not exist"
        raise HamError(f"--transfer-table {table!r} {what}; accepted: a glance table file")
    other = table_info(table)
    if config.table is not None:
        own = table_info(config.table)
        world, objects, grid = _as_built(own), own.objects, list(own.grid_shape)
    else:
        world, grid = config.world.to_dict(), "online"
        objects = [o.name for o in config.world.resolve_objects()]
    if other.objects != objects:
        raise HamError(
            f"--transfer-table {table!r} holds objects {', '.join(other.objects)} but the run "
            f"classifies {', '.join(objects)}; accepted: a table of the same objects in that order"
        )
    if other.pressure_dim != config.model.pressure_dim:
        side = math.isqrt(config.model.pressure_dim)
        raise HamError(
            f"--transfer-table {table!r} holds {other.taxels} x {other.taxels} images but the "
            f"run reads {side} x {side}; accepted: a table of the run's sensor size"
        )
    if tuple(other.pose_dims) != tuple(config.model.pose_dims):
        raise HamError(
            f"--transfer-table {table!r} is a grid over {','.join(other.pose_dims)} but the run "
            f"chooses poses over {','.join(config.model.pose_dims)}; accepted: a table over "
            "the run's pose dims"
        )
    theirs = _as_built(other)
    differences = world_differences(
        {**world, "grid": grid}, {**theirs, "grid": list(other.grid_shape)}
    )
    if "recorded" in (world.get("simulator"), theirs["simulator"]):
        # recorded glances know their grid and pad, not the objects, sensor or mapping that
        # made them: the rest of a recorded table's world is defaults, no difference to name
        differences = [d for d in differences if d.split(":")[0] in ("simulator", "grid")]
    return replace(config, table=str(Path(table).resolve())), differences


def _as_built(info) -> dict:
    """A table's world with the simulator that made its glances: a table imported from the
    authors' data set or from recorded glances names it there, not in its world."""
    made = info.simulator.get("simulator") if isinstance(info.simulator, dict) else None
    return {**info.world, "simulator": made or info.world.get("simulator")}


# --------------------------------------------------------------------------- the loop
@checked_arguments
def train(config: TrainConfig, out: str | os.PathLike, *, progress: bool = True) -> dict:
    """Train a fresh run into directory ``out``; returns the metrics (also in metrics.json)."""
    out = check_output_dir(out)
    _check_no_run(out)
    run = Run.create(config)  # first: a bad table, device or config leaves no run directory
    if config.init_from is not None:
        start_from(run, config.init_from)
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
        with folder_lock(out):  # another process training into out: refused, nothing written
            _check_no_run(out)  # again: another process may have started first and saved since
            try:
                write_json(out / CONFIG_FILE, config.to_dict())
                return train_loop(run, out, progress)
            except Exception as exc:
                if run.step == 0:  # failed before its first step (out of memory, a plugin's
                    remove_run(out, created)  # error): no run left, the same command runs again
                    raise
                if isinstance(exc, DivergedError):
                    exc.saved_step = _saved_step(run)
                raise
    finally:
        run.close()


def init_source_problem(source: str | os.PathLike) -> str | None:
    """Why a fresh run cannot start from folder ``source`` (``"does not exist"``, ``"holds no
    ham train run"``), or ``None`` when it holds a run (:attr:`TrainConfig.init_from`)."""
    folder = Path(source)
    if (folder / CONFIG_FILE).is_file():
        return None
    return "does not exist" if not folder.exists() else "holds no ham train run"


def start_from(run: Run, source: str) -> None:
    """``run``'s model set to the latest weights of the run in folder ``source``
    (:attr:`TrainConfig.init_from`): the two models alike in every field but ``glances``; only
    the model's weights are taken (a sac learner's critics start afresh)."""
    folder = Path(source)
    problem = init_source_problem(folder)
    if problem is not None:
        raise HamError(f"init_from {source!r} {problem}; accepted: a folder of ham train")
    theirs = read_run_config(folder).model.to_dict()
    ours = run.config.model.to_dict()
    keys = sorted((ours.keys() | theirs.keys()) - {"glances"})
    differ = [f"{k} {theirs.get(k)!r} (here {ours.get(k)!r})" for k in keys
              if ours.get(k) != theirs.get(k)]  # fmt: skip
    if differ:
        raise HamError(
            f"init_from {source!r} is another model: its {'; '.join(differ)}; accepted: a run "
            "of the same model (the number of glances may differ)"
        )
    try:
        run.agent.load_state_dict(load_checkpoint(folder)["model"])
    except (KeyError, RuntimeError) as exc:
        first = str(exc).strip().splitlines()[0]
        raise HamError(
            f"init_from {source!r}: its weights do not fit this model ({first})"
        ) from None


def _check_no_run(out: Path) -> None:
    if (out / CHECKPOINT_FILE).exists():
        raise HamError(f"{str(out)!r} already holds a run; continue it with --resume {out}")


def remove_run(
    out: Path,
    created: bool,
    names: tuple[str, ...] = (CONFIG_FILE, METRICS_FILE, CHECKPOINT_FILE, TIMING_FILE),
) -> None:
    """Remove what a run that failed before its first step wrote in ``out``: the files
    ``names`` (:func:`train`'s; ``ham sb3`` names its own) and its TensorBoard events, and
    ``out`` itself if the run made it and it is empty now."""
    for name in names:
        (out / name).unlink(missing_ok=True)
    shutil.rmtree(out / "tb", ignore_errors=True)
    if created and not any(out.iterdir()):
        out.rmdir()


@checked_arguments
def resume(
    out: str | os.PathLike,
    *,
    steps: int | None = None,
    env_steps: int | None = None,
    progress: bool = True,
    table: str | None = None,
) -> dict:
    """Continue the run in ``out`` from its checkpoint (to ``steps`` in all, or to the budget
    ``env_steps`` in glances, if given; ``table``: its glance table at a new path,
    :func:`locate_table`)."""
    out = Path(out)
    recorded = read_run_config(out)
    with folder_lock(out):  # a second resume of the same run at once is refused
        return _resume(out, recorded, steps, env_steps, progress, table)


def _resume(out: Path, recorded, steps, env_steps, progress: bool, table) -> dict:
    state = load_checkpoint(out)  # read once: its table sha256 locates a moved table
    config = locate_table(out, recorded, state.get("table_checksum"), table)
    if steps is not None:  # an explicit step count replaces an env_steps budget
        config = replace(config, steps=steps, env_steps=None)
    elif env_steps is not None:
        config = replace(config, env_steps=env_steps)
    run = Run.create(config)
    try:
        run.load_state_dict(state)
        if run.step > config.steps:
            raise HamError(
                f"--steps {config.steps}: the run is already at step {run.step}; "
                f"accepted: >= {run.step}"
            )
        if config != recorded:  # a budget or a moved table, only once accepted: a refused
            write_json(out / CONFIG_FILE, config.to_dict())  # budget leaves the run as it was
        try:
            return train_loop(run, out, progress)
        except DivergedError as exc:
            exc.saved_step = _saved_step(run)
            raise
    finally:
        run.close()


def _saved_step(run: Run) -> int:
    """The step of the run's last checkpoint: one is written at every evaluation."""
    return run.history[-1]["step"] if run.history else 0


#: torch's words for an update beyond float32 (Adam at lr 3e38: its first step is lr / (1 - beta1))
_UPDATE_OVERFLOW = "cannot be converted to type float without overflow"


def overflowed(run: Run, exc: BaseException) -> DivergedError | None:
    """The run's divergence when ``exc`` is an optimizer's update that overflowed float32 (a
    RuntimeError in place of the NaN/inf weights an SGD step leaves), else None."""
    if isinstance(exc, RuntimeError) and _UPDATE_OVERFLOW in str(exc):
        lr = run.optimizer.param_groups[0]["lr"]
        return DivergedError(
            f"training diverged at step {run.step + 1}: the optimizer's update overflows "
            f"float32 (lr {lr:g})"
        )
    return None


def check_loss(run: Run, loss: torch.Tensor) -> None:
    """Stop a diverged run with the step named: NaN or inf in the loss."""
    if not bool(torch.isfinite(loss)):
        raise DivergedError(f"training diverged at step {run.step + 1}: the loss is {loss.item()}")


def _descend(run: Run, loss: torch.Tensor) -> None:
    """One optimizer step on ``loss``, after checking it is finite."""
    check_loss(run, loss)
    run.optimizer.zero_grad(set_to_none=True)
    loss.backward()
    run.optimizer.step()


def check_weights(run: Run) -> None:
    """Stop a diverged run with the step named: NaN or inf in any weight after the update."""
    # One reduction instead of one check per tensor: NaN and inf propagate into the sum (which
    # overflows only when the weights have diverged anyway).
    total = torch.stack([p.detach().sum() for p in run.agent.parameters()]).sum()
    if not bool(torch.isfinite(total)):
        bad = [n for n, p in run.agent.named_parameters() if not bool(torch.isfinite(p).all())]
        raise DivergedError(
            f"training diverged at step {run.step}: NaN/inf in the weights {bad[0]}"
        )


def _probe(run: Run) -> None:
    """A round of the first pose's search (:mod:`ham.learn.probe`) when one is due."""
    c = run.config
    if probe_due(run.step, c.probe_warmup, c.probe_every, run.agent.first_probe):
        probe_round(run.agent, run.env, c.probe_keep, c.probe_score)


def train_step(run: Run) -> HybridLoss | InfoLoss | SacLoss:
    """One training step: a fresh batch, one episode, the learner's loss, one optimizer step
    (or ``epochs`` of them over the batch's recorded glances, :func:`train_step_epochs`; or the
    sac learner's updates over its replay buffer, :func:`train_step_sac`)."""
    c = run.config
    for group in run.optimizer.param_groups:
        group["lr"] = c.learning_rate(run.step) * group.get("lr_scale", 1.0)
    if c.learner == "sac":
        return train_step_sac(run)
    if c.model.first_glance == "probe":
        _probe(run)
    if c.epochs > 1:
        return train_step_epochs(run)
    objects = run.env.sample_objects()  # a fresh batch, drawn uniformly
    episode = run.agent(run.env, objects, run.policy_generator)
    if c.learner == "info":
        loss = info_loss(
            episode,
            c.gamma,
            c.gae_lambda,
            entropy_coef=c.entropy_coef,
            normalize_advantage=c.normalize_advantage,
            move_cost=c.move_cost,
            move_cost_on=c.move_cost_on,
            reward_kind=c.info_reward,
        )
        if episode.stop_logits is not None:
            loss.total = (
                loss.total
                + stop_loss(episode, c.glance_cost, run.policy_generator, c.stop_learner).total
            )
    elif c.learner == "hybrid":
        loss = hybrid_loss(
            episode,
            c.beta,
            c.classification_reduction,
            c.reinforce_reduction,
            c.classification_glances,
            c.reward_glances,
            c.reward_discount,
            c.glance_reduction,
        )
    else:  # a learner of the user's own (ham.learn.learners)
        loss = learner_loss(c.learner, episode, c)
    _descend(run, loss.total)
    run.step += 1
    check_weights(run)
    return loss


class GlanceRecorder:
    """An environment that passes every glance through and keeps it: the pressures ``(B, D)``,
    the contact heights where the model reads them, and the where-inputs ``(B, k)`` the network
    read (the sensor's observed location where the environment reports one, else the pose asked
    for), so a batch can be replayed."""

    def __init__(self, env) -> None:
        self.env = env
        self.pressures: list[torch.Tensor] = []
        self.heights: list[torch.Tensor] = []
        self.where: list[torch.Tensor] = []

    def _keep(self, pressure: torch.Tensor, q: torch.Tensor) -> None:
        where = getattr(self.env, "observed_location", None)
        self.pressures.append(pressure)
        self.where.append(q if where is None else where)

    def glance(self, objects: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
        pressure = self.env.glance(objects, q)
        self._keep(pressure, q)
        return pressure

    def glance_height(
        self, objects: torch.Tensor, q: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        pressure, height = self.env.glance_height(objects, q)
        self._keep(pressure, q)
        self.heights.append(height)
        return pressure, height

    @property
    def observed_location(self) -> torch.Tensor:
        return self.where[-1]


def train_step_epochs(run: Run) -> InfoLoss:
    """One training step of ``epochs`` optimizer steps (info learner, PPO-style): play a fresh
    batch once without gradients, recording its glances; fix its log-probabilities, advantages
    and critic targets (:func:`ham.learn.info_loss.info_targets`); then ``epochs`` times replay
    the network on the recorded glances and step on :func:`clipped_info_loss`."""
    c = run.config
    objects = run.env.sample_objects()
    recorder = GlanceRecorder(run.env)
    with torch.no_grad():
        played = run.agent(recorder, objects, run.policy_generator)
    on_reward = c.move_cost if c.move_cost_on in ("reward", "both") else 0.0
    targets = info_targets(played, c.gamma, c.gae_lambda, on_reward, c.info_reward)
    pressures, where = torch.stack(recorder.pressures), torch.stack(recorder.where)
    heights = torch.stack(recorder.heights) if recorder.heights else None
    policy_epochs = c.epochs if c.policy_epochs is None else c.policy_epochs
    for epoch in range(c.epochs):
        episode = run.agent.replay(pressures, where, heights, played)
        loss = clipped_info_loss(episode, targets, c.clip, c.entropy_coef, c.info_reward)
        if c.move_cost > 0 and c.move_cost_on in ("mean", "both"):
            loss.total = loss.total + mean_travel_penalty(episode, c.move_cost)
        if epoch >= policy_epochs:  # the classifier and the critic only
            loss.total = loss.classification + loss.critic
        _descend(run, loss.total)
    run.step += 1
    check_weights(run)
    return loss


def train_step_sac(run: Run) -> SacLoss:
    """One training step of the sac learner (:mod:`ham.learn.off_policy`): play a fresh batch
    with sampled poses, without gradients, into the replay buffer; then ``sac_updates`` updates,
    each on ``replay_batch`` episodes drawn from the buffer. Returns the last update's losses
    with the fresh batch's information gain (the training reward)."""
    c, sac = run.config, run.sac
    sac.set_lr(c.learning_rate(run.step))
    objects = run.env.sample_objects()
    recorder = GlanceRecorder(run.env)
    with torch.no_grad():
        played = run.agent(recorder, objects, run.policy_generator)
    sac.buffer.add(
        pressures=torch.stack(recorder.pressures, 1),
        where=torch.stack(recorder.where, 1),
        heights=torch.stack(recorder.heights, 1) if recorder.heights else None,
        locations=played.locations.transpose(0, 1),
        objects=objects,
    )
    for _ in range(c.sac_updates):
        loss = sac_update(
            run.agent, run.optimizer, sac, c.replay_batch, c.gamma, c.target_tau,
            c.critic_trains_core,
        )  # fmt: skip
    run.step += 1
    check_weights(run)
    loss.gain = information_gain(played.logits, objects)
    return loss


def evaluate_run(
    run: Run,
    train_loss: float | None,
    train_reward: float | None,
    result: EvalResult | None = None,
) -> dict:
    """Evaluate ``run`` and record it; ``result``: the evaluation made elsewhere (batched)."""
    c = run.config
    if result is None:
        result = evaluate(
            run.agent, run.env, c.eval_batches, seed=stream_seed(c.seed, 2), policy=c.eval_policy
        )
    if result.accuracy > run.best_accuracy:
        run.best_accuracy, run.best_step = result.accuracy, run.step
    run.best_accumulated_accuracy = max(
        run.best_accumulated_accuracy, result.accumulated_accuracy_per_glance[-1]
    )
    record = {
        "step": run.step,
        "accuracy": result.accuracy,
        "accuracy_per_glance": result.accuracy_per_glance,
        "accumulated_accuracy_per_glance": result.accumulated_accuracy_per_glance,
        "mu_mean": result.mu_mean,
        "per_object_accuracy": result.per_object_accuracy,
        "confusion": result.confusion[-1],  # after the last glance: true x predicted counts
        "env_steps": run.env_steps,
        "average_accuracy": sum(result.accuracy_per_glance) / len(result.accuracy_per_glance),
        "path_length": result.path_length,
        "pose_spread": result.pose_spread,
        "pose_spread_within_object": result.pose_spread_within_object,
        "stop_accuracy": result.stop_accuracy,
        "mean_glances": result.mean_glances,
        "train_loss": train_loss,
        "train_reward": train_reward,
        "lr": c.learning_rate(run.step),
    }
    search = getattr(run.agent, "first_probe", None)
    if search is not None:  # the first pose's search (only its runs' records have the key)
        record["first_probe"] = {
            "committed": bool(search.committed),
            "pose": search.pose.tolist() if bool(search.committed) else None,
            "candidates": int(search.alive.sum()),
            "probe_glances": int(search.probes),
        }
    run.history.append(record)
    return record


def _save(run: Run, out: Path) -> None:
    atomic_write(out / CHECKPOINT_FILE, lambda p: torch.save(run.state_dict(), p))
    write_json(out / METRICS_FILE, run.metrics())


def train_loop(run: Run, out: Path, progress: bool) -> dict:
    from torch.utils.tensorboard import SummaryWriter

    c, env, optimizer = run.config, run.env, run.optimizer
    source_commit()  # the code this run starts with, named in its timing.json at the end
    writer = SummaryWriter(str(out / "tb"), purge_step=run.step if run.step else None)
    loss_sum = torch.zeros((), device=env.device)
    reward_sum = torch.zeros((), device=env.device)
    n_sum = 0
    bar = tqdm(total=c.steps, initial=run.step, disable=not progress, unit="step", desc="train")
    t_train, n_train = 0.0, 0
    try:
        if run.step == 0 and not run.history:  # the untrained model: the curves start at step 0
            log_evaluation(writer, evaluate_run(run, None, None), run.config.model.glances)
            _save(run, out)
        while run.step < c.steps:
            t0 = time.perf_counter()
            try:
                loss = train_step(run)
            except RuntimeError as exc:
                diverged = overflowed(run, exc)
                if diverged is None:
                    raise
                raise diverged from None
            lr = optimizer.param_groups[0]["lr"]

            loss_sum += loss.total.detach()
            reward_sum += loss.reward.mean()
            n_sum += 1
            t_train += time.perf_counter() - t0
            n_train += 1
            bar.update(1)
            if run.step % c.log_every == 0:
                writer.add_scalar("train/loss", loss.total.item(), run.step)
                writer.add_scalar("train/classification", loss.classification.item(), run.step)
                writer.add_scalar("train/reinforce", loss.reinforce.item(), run.step)
                writer.add_scalar("train/baseline_loss", loss.baseline.item(), run.step)
                writer.add_scalar("train/reward", loss.reward.mean().item(), run.step)
                writer.add_scalar("train/lr", lr, run.step)
            if run.step % c.eval_every == 0 or run.step == c.steps:
                record = evaluate_run(run, loss_sum.item() / n_sum, reward_sum.item() / n_sum)
                loss_sum.zero_()
                reward_sum.zero_()
                n_sum = 0
                log_evaluation(writer, record, c.model.glances)
                bar.set_postfix(acc=f"{record['accuracy']:.3f}", best=f"{run.best_accuracy:.3f}")
                _save(run, out)
    finally:
        bar.close()
        writer.close()
    if n_train:
        write_json(
            out / TIMING_FILE,
            {"steps_timed": n_train, "ms_per_step": 1000 * t_train / n_train,
             "torch_threads": torch.get_num_threads(), "device": c.device,
             "environment": environment_record()},
        )  # fmt: skip
    else:  # a finished run resumed (a grid's, whose metrics.json was lost): write it again
        write_json(out / METRICS_FILE, run.metrics())
    return run.metrics()


def log_evaluation(writer, record: dict, glances: int) -> None:
    """An evaluation's record (:func:`evaluate_run`) on TensorBoard, under ``eval/``."""
    step = record["step"]
    writer.add_scalar("eval/accuracy", record["accuracy"], step)
    for s in range(glances):
        writer.add_scalar(f"eval/accuracy_glance_{s + 1}", record["accuracy_per_glance"][s], step)
        writer.add_scalar(
            f"eval/accumulated_accuracy_glance_{s + 1}",
            record["accumulated_accuracy_per_glance"][s],
            step,
        )
        if record.get("pose_spread") is not None:
            writer.add_scalar(f"eval/pose_spread_glance_{s + 1}", record["pose_spread"][s], step)
