"""Training the HAM (section "Training"), readable top to bottom.

Each step: draw a fresh batch of 64 objects uniformly, play ``S`` glances (the first random, the
rest from the location policy), compute the hybrid loss (:mod:`ham.learn.hybrid_loss`), take one SGD
step with Nesterov momentum 0.9 at the learning rate
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
run: all randomness comes from three seeded generators (objects, poses, evaluation) whose
states are saved, and the model's initial weights from ``torch.manual_seed(seed)``.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import torch
from tqdm.auto import tqdm

from ham.errors import HamError
from ham.learn.environment import HapticEnv
from ham.learn.evaluation import EVAL_POLICIES, evaluate
from ham.learn.hybrid_loss import REDUCTIONS, HybridLoss, hybrid_loss
from ham.model.agent import HamConfig, HapticAttentionModel, count_parameters
from ham.world.config import WorldConfig
from ham.world.devices import check_device
from ham.world.files import check_output_dir
from ham.world.sensor import NORMALIZATIONS
from ham.world.source import make_source

CONFIG_FILE = "config.json"
METRICS_FILE = "metrics.json"
CHECKPOINT_FILE = "checkpoint.pt"
TIMING_FILE = "timing.json"
DEVICES: tuple[str, ...] = ("cpu", "cuda")


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
        eval_every: steps between evaluations and checkpoints (200, the authors' code).
        eval_batches: balanced batches per evaluation (100).
        eval_policy: the location policy during evaluation: ``mean`` poses (training stopped)
            or ``sample`` (as in training); see :mod:`ham.learn.evaluation`.
        seed: seeds the initial weights and the generators of objects, poses and evaluation.
        normalization: pressure normalization, l2 (paper), l1 (authors' code) or none.
        table: a glance table file (the paper's pre-recorded data set); ``None``: online.
        world: the world simulated online when ``table`` is ``None``.
        device: ``cpu`` or ``cuda``.
        log_every: steps between TensorBoard training scalars.
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
    classification_reduction: str = "sum"
    reinforce_reduction: str = "mean"
    eval_every: int = 200
    eval_batches: int = 100
    eval_policy: str = "mean"
    seed: int = 0
    normalization: str = "l2"
    table: str | None = None
    world: WorldConfig = field(default_factory=WorldConfig)
    device: str = "cpu"
    log_every: int = 10

    def __post_init__(self) -> None:
        for name, kind in (("model", HamConfig), ("world", WorldConfig), ("nesterov", bool)):
            if not isinstance(getattr(self, name), kind):
                raise HamError(f"{name} = {getattr(self, name)!r}; accepted: a {kind.__name__}")
        if self.table is not None and not isinstance(self.table, str):
            raise HamError(f"table = {self.table!r}; accepted: a glance table's path or None")
        for name in ("lr", "lr_min", "lr_decay", "momentum", "beta"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise HamError(f"{name} = {v!r}; accepted: a finite number")
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
        if not (math.isfinite(self.beta) and self.beta >= 0):
            raise HamError(f"beta = {self.beta!r}; accepted: a finite number >= 0")
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or self.seed < 0:
            raise HamError(f"seed = {self.seed!r}; accepted: an integer >= 0")
        for name in ("classification_reduction", "reinforce_reduction"):
            if getattr(self, name) not in REDUCTIONS:
                raise HamError(f"{name} {getattr(self, name)!r}; accepted: {', '.join(REDUCTIONS)}")
        if self.eval_policy not in EVAL_POLICIES:
            raise HamError(
                f"eval_policy {self.eval_policy!r}; accepted: {', '.join(EVAL_POLICIES)}"
            )
        if self.normalization not in NORMALIZATIONS:
            raise HamError(
                f"normalization {self.normalization!r}; accepted: {', '.join(NORMALIZATIONS)}"
            )
        check_device(self.device, available=False)  # spelling only: a saved GPU run loads on CPU

    def learning_rate(self, step: int) -> float:
        """``alpha_t = max(alpha_min, alpha_0 * delta_alpha^(t / T))`` (section "Training")."""
        return max(self.lr_min, self.lr * self.lr_decay ** (step / self.lr_step))

    def to_dict(self) -> dict:
        d = asdict(self)
        d["world"] = self.world.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        if not isinstance(d, dict):
            raise HamError(f"train config {d!r}; accepted: a dict of TrainConfig fields")
        d = dict(d)
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise HamError(f"train config has unknown fields {sorted(unknown)}")
        d["model"] = HamConfig.from_dict(d.get("model", {}))
        d["world"] = WorldConfig.from_dict(d.get("world", {}))
        return cls(**d)


# --------------------------------------------------------------------------- the parts of a run
def stream_seed(seed: int, stream: int) -> int:
    """Independent seeds for the generators of one run: 0 objects, 1 poses, 2 evaluation."""
    return seed * 1000 + stream


@dataclass
class Run:
    """Everything a training run evolves, and what a checkpoint saves."""

    config: TrainConfig
    agent: HapticAttentionModel
    env: HapticEnv
    optimizer: torch.optim.Optimizer
    policy_generator: torch.Generator
    step: int = 0
    best_accuracy: float = -1.0
    best_step: int = 0
    best_accumulated_accuracy: float = -1.0
    history: list = field(default_factory=list)
    objects: list = field(default_factory=list)

    @classmethod
    def create(cls, config: TrainConfig) -> Run:
        device = check_device(config.device)
        source, world = make_source(config.table, config.world, device)
        if source.n_objects != config.model.n_objects:
            raise HamError(
                f"the model classifies {config.model.n_objects} objects but the glance source "
                f"has {source.n_objects} ({', '.join(source.objects)})"
            )
        env = HapticEnv(
            source, config.batch_size, config.normalization, stream_seed(config.seed, 0), device
        )
        torch.manual_seed(config.seed)  # the initial weights
        agent = HapticAttentionModel(config.model).to(device)
        optimizer = torch.optim.SGD(
            agent.parameters(),
            lr=config.lr,
            momentum=config.momentum,
            nesterov=config.nesterov,
            foreach=True,
        )
        policy_generator = torch.Generator(device=device)
        policy_generator.manual_seed(stream_seed(config.seed, 1))
        return cls(config, agent, env, optimizer, policy_generator, objects=list(source.objects))

    def state_dict(self) -> dict:
        return {
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

    def load_state_dict(self, state: dict) -> None:
        self.step = int(state["step"])
        self.agent.load_state_dict(state["model"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.env.load_state_dict(state["env"])
        self.policy_generator.set_state(state["policy_generator"])
        self.best_accuracy = float(state["best_accuracy"])
        self.best_step = int(state["best_step"])
        self.best_accumulated_accuracy = float(state["best_accumulated_accuracy"])
        self.history = list(state["history"])

    def metrics(self) -> dict:
        last = self.history[-1] if self.history else {}
        return {
            "best_accuracy": self.best_accuracy,
            "best_step": self.best_step,
            "best_accumulated_accuracy": self.best_accumulated_accuracy,
            "final_accuracy": last.get("accuracy"),
            "steps": self.step,
            "accuracy_per_glance": last.get("accuracy_per_glance"),
            "accumulated_accuracy_per_glance": last.get("accumulated_accuracy_per_glance"),
            "parameters": count_parameters(self.agent),
            "objects": self.objects,
            "config": self.config.to_dict(),
            "history": self.history,
        }


# --------------------------------------------------------------------------- files
def _write_atomic(path: Path, write) -> None:
    """Write through ``path.tmp`` and ``os.replace``: a killed run never leaves half a file."""
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)


def _write_json(path: Path, obj) -> None:
    _write_atomic(path, lambda p: p.write_text(json.dumps(obj, indent=1) + "\n"))


def read_json(path: Path) -> dict:
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise HamError(f"{str(path)!r} does not exist: not a training run directory?") from None
    except json.JSONDecodeError as exc:
        raise HamError(f"{str(path)!r} is not valid JSON ({exc})") from None


def load_checkpoint(out: Path) -> dict:
    path = Path(out) / CHECKPOINT_FILE
    if not path.exists():
        raise HamError(f"{str(path)!r} does not exist: the run has no checkpoint yet")
    try:
        return torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # noqa: BLE001 - any unreadable file is the user's bad input
        raise HamError(f"cannot read checkpoint {str(path)!r}: {exc}") from None


def load_run(out: str | os.PathLike, device: str | None = None) -> Run:
    """The run in directory ``out`` at its latest checkpoint (for evaluation and heat maps)."""
    out = Path(out)
    config = TrainConfig.from_dict(read_json(out / CONFIG_FILE))
    if device is not None:
        config = replace(config, device=device)
    run = Run.create(config)
    run.load_state_dict(load_checkpoint(out))
    return run


# --------------------------------------------------------------------------- the loop
def train(config: TrainConfig, out: str | os.PathLike, *, progress: bool = True) -> dict:
    """Train a fresh run into directory ``out``; returns the metrics (also in metrics.json)."""
    out = check_output_dir(out)
    if (out / CHECKPOINT_FILE).exists():
        raise HamError(f"{str(out)!r} already holds a run; continue it with --resume {out}")
    run = Run.create(config)  # first: a bad table or device leaves no half-made run directory
    out.mkdir(parents=True, exist_ok=True)
    _write_json(out / CONFIG_FILE, config.to_dict())
    return train_loop(run, out, progress)


def resume(out: str | os.PathLike, *, steps: int | None = None, progress: bool = True) -> dict:
    """Continue the run in ``out`` from its checkpoint (to ``steps`` in all, if given)."""
    out = Path(out)
    config = TrainConfig.from_dict(read_json(out / CONFIG_FILE))
    if steps is not None:
        config = replace(config, steps=steps)
    run = Run.create(config)
    run.load_state_dict(load_checkpoint(out))
    if run.step > config.steps:
        raise HamError(
            f"--steps {config.steps}: the run is already at step {run.step}; accepted: >= {run.step}"
        )
    if steps is not None:  # only once accepted: a refused --steps leaves the run as it was
        _write_json(out / CONFIG_FILE, config.to_dict())
    return train_loop(run, out, progress)


def _check_loss(run: Run, loss: torch.Tensor) -> None:
    """Stop a diverged run with the step named: NaN or inf in the loss."""
    if not bool(torch.isfinite(loss)):
        raise HamError(f"training diverged at step {run.step + 1}: the loss is {loss.item()}")


def _check_weights(run: Run) -> None:
    """Stop a diverged run with the step named: NaN or inf in any weight after the update."""
    # One reduction instead of one check per tensor: NaN and inf propagate into the sum (which
    # overflows only when the weights have diverged anyway).
    total = torch.stack([p.detach().sum() for p in run.agent.parameters()]).sum()
    if not bool(torch.isfinite(total)):
        bad = [n for n, p in run.agent.named_parameters() if not bool(torch.isfinite(p).all())]
        raise HamError(f"training diverged at step {run.step}: NaN/inf in the weights {bad[0]}")


def train_step(run: Run) -> HybridLoss:
    """One training step: a fresh batch, one episode, the hybrid loss, one SGD step."""
    c = run.config
    for group in run.optimizer.param_groups:
        group["lr"] = c.learning_rate(run.step)
    objects = run.env.sample_objects()  # a fresh batch, drawn uniformly
    episode = run.agent(run.env, objects, run.policy_generator)
    loss = hybrid_loss(episode, c.beta, c.classification_reduction, c.reinforce_reduction)
    _check_loss(run, loss.total)
    run.optimizer.zero_grad(set_to_none=True)
    loss.total.backward()
    run.optimizer.step()
    run.step += 1
    _check_weights(run)
    return loss


def _evaluate(run: Run, train_loss: float | None, train_reward: float | None) -> dict:
    c = run.config
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
        "train_loss": train_loss,
        "train_reward": train_reward,
        "lr": c.learning_rate(run.step),
    }
    run.history.append(record)
    return record


def _save(run: Run, out: Path) -> None:
    _write_atomic(out / CHECKPOINT_FILE, lambda p: torch.save(run.state_dict(), p))
    _write_json(out / METRICS_FILE, run.metrics())


def train_loop(run: Run, out: Path, progress: bool) -> dict:
    from torch.utils.tensorboard import SummaryWriter

    c, env, optimizer = run.config, run.env, run.optimizer
    writer = SummaryWriter(str(out / "tb"), purge_step=run.step if run.step else None)
    if run.step == 0 and not run.history:  # the untrained model: the curves start at step 0
        _log_eval(writer, _evaluate(run, None, None), run.config.model.glances)
        _save(run, out)
    loss_sum = torch.zeros((), device=env.device)
    reward_sum = torch.zeros((), device=env.device)
    n_sum = 0
    bar = tqdm(total=c.steps, initial=run.step, disable=not progress, unit="step", desc="train")
    t_train, n_train = 0.0, 0
    try:
        while run.step < c.steps:
            t0 = time.perf_counter()
            loss = train_step(run)
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
                record = _evaluate(run, loss_sum.item() / n_sum, reward_sum.item() / n_sum)
                loss_sum.zero_()
                reward_sum.zero_()
                n_sum = 0
                _log_eval(writer, record, c.model.glances)
                bar.set_postfix(acc=f"{record['accuracy']:.3f}", best=f"{run.best_accuracy:.3f}")
                _save(run, out)
    finally:
        bar.close()
        writer.close()
    if n_train:
        _write_json(
            out / TIMING_FILE,
            {"steps_timed": n_train, "ms_per_step": 1000 * t_train / n_train,
             "torch_threads": torch.get_num_threads(), "device": c.device},
        )  # fmt: skip
    return run.metrics()


def _log_eval(writer, record: dict, glances: int) -> None:
    step = record["step"]
    writer.add_scalar("eval/accuracy", record["accuracy"], step)
    for s in range(glances):
        writer.add_scalar(f"eval/accuracy_glance_{s + 1}", record["accuracy_per_glance"][s], step)
        writer.add_scalar(
            f"eval/accumulated_accuracy_glance_{s + 1}",
            record["accumulated_accuracy_per_glance"][s],
            step,
        )
