"""Off-the-shelf agents as baselines: Stable-Baselines3 PPO and SAC, sb3-contrib CrossQ.

An active classification environment (``ap_gym``'s protocol, which ours follow too:
``ham/HapticGlanceAP-v0``, ``ap_gym:CircleSquare-v0``, ...) asks each step for a glance *and* a
prediction, and rewards the prediction (base reward minus its cross-entropy). SB3's agents act
in one box, so :class:`SupervisedPrediction` splits the job as the APPLE study does:

* the SB3 agent chooses only the glance (``action``), from an observation that holds the whole
  episode so far (every glance flattened, zero-padded to the episode length, and the step's
  fraction): a memoryless agent that still sees its history;
* a :class:`PredictionHead` (an MLP on the same observation) makes the prediction and is trained
  by supervision (cross-entropy to the true class, which the environment reports after each
  step) from a buffer of recent steps; it is shared by all sub-environments.

The reward the agent sees is the environment's own, computed with the head's prediction: the
drop of cross-entropy per glance, a dense information reward. Environment steps count glances,
as the APPLE study counts them. :func:`train_sb3` trains, evaluates and writes
``metrics.json``/``config.json`` (atomically) and the SB3 model and head beside them, and
``history.json`` (the evaluations so far) after each evaluation.
"""

from __future__ import annotations

import contextlib
import math
import os
import pickle
import random
import sys
import time
import traceback
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from ham.errors import (
    HamError,
    check_choices,
    check_json,
    check_known_fields,
    check_seed,
    check_types,
    checked_arguments,
    too_large,
)
from ham.world.files import atomic_write, check_output_dir, folder_lock, write_json

ALGOS: tuple[str, ...] = ("ppo", "sac", "crossq")


class PredictionHead(nn.Module):
    """An MLP from the episode-so-far observation to class logits, trained by cross-entropy."""

    def __init__(self, obs_dim: int, n_classes: int, hidden: int = 256, lr: float = 1e-3,
                 buffer: int = 50_000, batch: int = 256, seed: int = 0) -> None:  # fmt: skip
        super().__init__()
        gen = torch.Generator().manual_seed(seed)
        self.net = nn.Sequential(
            nn.Linear(obs_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
            nn.Linear(hidden, n_classes),
        )  # fmt: skip
        with torch.no_grad():  # seeded initial weights, independent of torch's global state
            for p in self.net.parameters():
                p.copy_(torch.empty_like(p).uniform_(-1, 1, generator=gen) / math.sqrt(p.shape[-1]))
        self.optimizer = torch.optim.Adam(self.net.parameters(), lr=lr)
        self.obs = np.zeros((buffer, obs_dim), np.float32)
        self.target = np.zeros(buffer, np.int64)
        self.size = self.next = 0
        self.batch = batch
        self.rng = np.random.default_rng(seed)

    @torch.no_grad()
    def logits(self, obs: np.ndarray) -> np.ndarray:
        return self.net(torch.as_tensor(obs, dtype=torch.float32)).numpy()

    def remember(self, obs: np.ndarray, target: int) -> None:
        self.obs[self.next], self.target[self.next] = obs, target
        self.next = (self.next + 1) % len(self.obs)
        self.size = min(self.size + 1, len(self.obs))

    def learn(self) -> float:
        """One Adam step of cross-entropy on a batch drawn from the buffer."""
        if self.size < self.batch:
            return float("nan")
        i = self.rng.integers(0, self.size, self.batch)
        loss = nn.functional.cross_entropy(
            self.net(torch.from_numpy(self.obs[i])), torch.from_numpy(self.target[i])
        )
        self.optimizer.zero_grad()
        loss.backward()
        self.optimizer.step()
        return loss.item()


class SupervisedPrediction(gym.Wrapper):
    """The glance for the SB3 agent, the prediction from a shared supervised head."""

    def __init__(self, env: gym.Env, head: PredictionHead | None = None, *,
                 learn_every: int = 4) -> None:  # fmt: skip
        super().__init__(env)
        space = env.action_space
        if not (
            isinstance(space, gym.spaces.Dict)
            and {"action", "prediction"} <= set(space)
            and isinstance(space["prediction"], gym.spaces.Box)  # logits over the classes
            and len(space["prediction"].shape) == 1
        ):
            # ap_gym.make wraps an environment without the protocol as "pseudo active
            # perception", with an empty prediction: nothing for the head to classify
            name = getattr(env.spec, "id", None) or type(env).__name__
            raise HamError(
                f"environment {name!r} has action space {space}; accepted: an active "
                "classification environment with Dict(action=..., prediction=logits) (ap_gym's "
                "protocol), e.g. ham/HapticGlanceAP-v0 or ap_gym:CircleSquare-v0"
            )
        self.horizon = episode_length(env)
        self.step_dim = gym.spaces.flatdim(env.observation_space)
        self.n_classes = int(np.prod(space["prediction"].shape))
        self.observation_space = gym.spaces.Box(
            -np.inf, np.inf, (self.horizon * self.step_dim + 1,), np.float32
        )
        self.action_space = space["action"]
        self.head = head or PredictionHead(self.observation_space.shape[0], self.n_classes)
        self.learn_every = learn_every
        # False while evaluating: the head neither stores nor learns from evaluation episodes
        # (they repeat with their seeds, so it could memorize them: pose -> object).
        self.learning = True
        self.t = 0
        self.steps = 0
        self.history = np.zeros(self.observation_space.shape, np.float32)
        self.last_correct: list[bool] = []

    def _record(self, obs) -> np.ndarray:
        flat = gym.spaces.flatten(self.env.observation_space, obs).astype(np.float32)
        if self.t < self.horizon:
            self.history[self.t * self.step_dim : (self.t + 1) * self.step_dim] = flat
        self.history[-1] = self.t / self.horizon
        return self.history.copy()

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.t = 0
        self.history[:] = 0
        self.last_correct = []
        return self._record(obs), info

    def step(self, action):
        seen = self.history.copy()
        logits = self.head.logits(seen[None])[0]
        obs, reward, terminated, truncated, info = self.env.step(
            {"action": np.asarray(action, np.float32), "prediction": logits}
        )
        target = int(info["prediction"]["target"])
        self.last_correct.append(bool(logits.argmax() == target))
        info = dict(info, correct=self.last_correct[-1])
        if self.learning:
            self.head.remember(seen, target)
            self.steps += 1
            if self.steps % self.learn_every == 0:
                self.head.learn()
        self.t += 1
        return self._record(obs), float(reward), terminated, truncated, info


def episode_length(env: gym.Env) -> int:
    """Glances per episode: the environment's time limit or its ``glances`` setting."""
    for candidate in (
        getattr(env.spec, "max_episode_steps", None) if env.spec else None,
        getattr(env.unwrapped, "glances", None),
        getattr(env.unwrapped, "episode_length", None),
        (getattr(env.unwrapped, "spec", None) and env.unwrapped.spec.max_episode_steps),
    ):
        if isinstance(candidate, int) and candidate > 0:
            return candidate
    raise HamError("the environment names no episode length (max_episode_steps or glances)")


@dataclass(frozen=True)
class Sb3Config:
    """An SB3 baseline run.

    Attributes:
        algo: ppo (Stable-Baselines3), sac (Stable-Baselines3) or crossq (sb3-contrib).
        env: ``ap_gym:ENV_ID`` or one of ours (``ham/HapticGlanceAP-v0``).
        env_kwargs: keyword arguments of the environment (e.g. ``{"glances": 10}``).
        env_steps: environment steps (glances) to train for.
        n_envs: parallel environments (sub-environments of one process).
        seed: seeds the agent, the head and the environments.
        eval_episodes: episodes per evaluation.
        eval_every: environment steps between evaluations.
        device: cpu or cuda.
        algo_kwargs: keyword arguments of the SB3 algorithm (its defaults otherwise), e.g.
            ``{"n_steps": 256}`` for PPO or ``{"learning_starts": 1000}`` for SAC.
    """

    algo: str = field(default="sac", metadata={"choices": ALGOS})
    env: str = "ap_gym:CircleSquare-v0"
    env_kwargs: dict = field(default_factory=dict)
    env_steps: int = 250_000
    n_envs: int = 1
    seed: int = 0
    eval_episodes: int = 200
    eval_every: int = 10_000
    device: str = "cpu"
    algo_kwargs: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        check_types(self)
        check_choices(self)
        for name in ("env_steps", "n_envs", "eval_episodes", "eval_every"):
            v = getattr(self, name)
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
                raise HamError(f"{name} = {v!r}; accepted: an integer >= 1")
        check_seed(self.seed)
        check_json("env_kwargs", self.env_kwargs)
        check_json("algo_kwargs", self.algo_kwargs)
        from ham.world.devices import check_device

        check_device(self.device, available=False)  # the spelling; train_sb3 checks presence


def make_env(name: str, kwargs: dict | None = None, prefetch: bool = True) -> gym.Env:
    """``ap_gym:ID`` through ``ap_gym.make``; our ids through ``ap_gym.make`` after registering.
    ``prefetch=False``: an ap_gym image environment draws its images when asked, not ahead on
    a thread (the same images; what lets a run be checkpointed)."""
    kwargs = dict(kwargs or {})
    try:
        import ap_gym
    except ImportError as exc:
        raise HamError(f"ap_gym is not available ({exc}); pip install 'ham[ap]'") from None
    import ham.envs  # noqa: F401  (registers ham/...)

    env_id = name.split(":", 1)[1] if name.startswith("ap_gym:") else name
    if env_id not in gym.registry:
        raise HamError(f"environment {name!r} is not registered; e.g. ap_gym:CircleSquare-v0")
    config = gym.registry[env_id].kwargs.get("image_perception_config")
    if not prefetch and "image_perception_config" not in kwargs and hasattr(config, "prefetch"):
        # ap_gym's image environments draw their images on a background thread (a queue
        # ahead of the episodes: neither picklable nor in step with them); without it the
        # very same images come in the same order, and a checkpoint can hold the stream
        kwargs["image_perception_config"] = replace(config, prefetch=False)
    try:
        return ap_gym.make(env_id, **kwargs)
    except TypeError as exc:
        raise HamError(f"environment {name!r} with {kwargs!r}: {exc}") from None


def evaluate_agent(model, env: SupervisedPrediction, episodes: int, seed: int) -> dict:
    """Deterministic glances; the head's accuracy after each glance, averaged over episodes.
    The head does not learn from them (``env.learning`` is off meanwhile)."""
    per_step = np.zeros(env.horizon)
    learning, env.learning = env.learning, False
    for e in range(episodes):
        obs, _ = env.reset(seed=seed + e)
        done = False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
        per_step[: len(env.last_correct)] += env.last_correct
    env.learning = learning
    acc = per_step / episodes
    return {
        "accuracy_per_glance": acc.tolist(),
        "final_accuracy": float(acc[-1]),
        "average_accuracy": float(acc.mean()),
    }


CHECKPOINT = "checkpoint.pkl"
# the replay buffer's arrays with a row per step (SB3's ReplayBuffer)
_BUFFER_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


@contextlib.contextmanager
def _compact_buffer(model):
    """The replay buffer's arrays cut to their filled rows while the model is pickled (SB3
    allocates all ``buffer_size`` rows up front: 1M rows of a CircleSquare observation are
    3.5 GB, of which 250k steps fill a quarter), and the logger left out (no part of a
    run's state: :func:`_learn` gives the model a new one before it learns)."""
    buf = getattr(model, "replay_buffer", None)
    big: dict[str, np.ndarray] = {}
    if buf is not None:
        n = buf.buffer_size if buf.full else buf.pos
        big = {k: getattr(buf, k) for k in _BUFFER_ARRAYS
               if isinstance(getattr(buf, k, None), np.ndarray)}  # fmt: skip
        for k, v in big.items():
            setattr(buf, k, v[:n])
    logger = model.__dict__.pop("_logger", None)
    try:
        yield
    finally:
        for k, v in big.items():
            setattr(buf, k, v)
        if logger is not None:
            model._logger = logger


def _expand_buffer(model) -> None:
    """Undo :func:`_compact_buffer` on a loaded model: the arrays back to ``buffer_size`` rows."""
    buf = getattr(model, "replay_buffer", None)
    if buf is None:
        return
    for k in _BUFFER_ARRAYS:
        v = getattr(buf, k, None)
        if isinstance(v, np.ndarray):
            full = np.zeros((buf.buffer_size, *v.shape[1:]), v.dtype)
            full[: len(v)] = v
            setattr(buf, k, full)


def _rng_states(device: str) -> dict:
    # SB3 draws replay batches from NumPy's global generator, not from one of its own
    states = {"torch": torch.get_rng_state(), "numpy": np.random.get_state(),  # noqa: NPY002
              "random": random.getstate()}  # fmt: skip
    if device.startswith("cuda") and torch.cuda.is_available():
        states["cuda"] = torch.cuda.get_rng_state_all()
    return states


def _set_rng_states(states: dict) -> None:
    torch.set_rng_state(states["torch"])
    np.random.set_state(states["numpy"])  # noqa: NPY002
    random.setstate(states["random"])
    if "cuda" in states and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(states["cuda"])


def _save_checkpoint(
    out: Path, model, eval_env, history: list, seconds: float, device: str
) -> None:
    """Everything a resumed run needs to continue bit-identically, in one pickle (so the agent's
    environments and the evaluation environment keep sharing one prediction head): the agent
    with its optimizers, replay buffer (filled rows), environments and last observation; the
    evaluations so far; the global generators SB3 draws from (actions: torch; replay
    batches: NumPy). Written at the start of a rollout (after the previous step's training),
    the one point of SB3's loop where nothing is half done."""
    state = {"model": model, "eval_env": eval_env, "history": history, "seconds": seconds,
             "rng": _rng_states(device)}  # fmt: skip

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            _dump(state, f)

    with _compact_buffer(model):
        atomic_write(out / CHECKPOINT, write, what="checkpoint")


def _new(cls: type) -> Any:
    return cls.__new__(cls)


def _set_dict(obj: Any, state: dict) -> None:
    obj.__dict__.update(state)


def _dump(obj: Any, f) -> None:
    """cloudpickle, with objects that forward unknown attributes (``__getattr__`` without
    ``__setstate__``, as ap_gym's wrappers) rebuilt without asking them for ``__setstate__``:
    a bare instance forwards that question to its missing inner environment, forever."""
    import cloudpickle

    class Pickler(cloudpickle.Pickler):
        def reducer_override(self, obj):
            cls = type(obj)
            if (
                hasattr(cls, "__getattr__")
                and not hasattr(cls, "__setstate__")
                and cls.__reduce_ex__ is object.__reduce_ex__
                and isinstance(getattr(obj, "__dict__", None), dict)
            ):
                return _new, (cls,), obj.__dict__, None, None, _set_dict
            return super().reducer_override(obj)

    Pickler(f, protocol=5).dump(obj)


@checked_arguments
def train_sb3(config: Sb3Config, out: str | os.PathLike, progress: bool = False) -> dict:
    """Train ``config.algo`` on ``config.env`` with a supervised prediction head; evaluate every
    ``eval_every`` environment steps; write ``out/metrics.json``, ``config.json``, the model, and
    after each evaluation ``out/history.json`` (the curve so far, for runs stopped early),
    ``out/checkpoint.pkl`` (:func:`resume_sb3` continues from it) and TensorBoard events in
    ``out/tb``. ``progress``: a bar over the environment steps on stderr."""
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.vec_env import DummyVecEnv

    from ham.world.devices import check_device

    check_device(config.device)  # a missing GPU is named before anything is written
    out = check_output_dir(out)
    _check_empty(out)

    # The environment first: a bad id or keyword fails before anything is written.
    def wrapped(head: PredictionHead | None = None) -> SupervisedPrediction:
        return SupervisedPrediction(make_env(config.env, config.env_kwargs, prefetch=False), head)

    probe = wrapped()
    head = PredictionHead(probe.observation_space.shape[0], probe.n_classes, seed=config.seed)
    probe.close()
    venv = DummyVecEnv([lambda: wrapped(head)] * config.n_envs)
    venv.seed(config.seed)
    eval_env = wrapped(head)
    if config.algo == "crossq":
        from sb3_contrib import CrossQ as algo
    else:
        algo = {"ppo": PPO, "sac": SAC}[config.algo]
    try:
        model = algo(
            "MlpPolicy", venv, seed=config.seed, device=config.device, verbose=0,
            **config.algo_kwargs,
        )  # fmt: skip
    except (TypeError, ValueError, AssertionError) as exc:
        msg = too_large(exc) or (str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
        raise HamError(f"algo_kwargs {config.algo_kwargs!r} for {config.algo}: {msg}") from None
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    with folder_lock(out):  # another process starting the same --out: refused
        _check_empty(out)  # again: another process may have started first and written since
        write_json(out / "config.json", asdict(config))
        try:
            return _learn(config, out, model, eval_env, [], 0.0, progress)
        except HamError:
            if not (out / CHECKPOINT).exists():  # refused before its first checkpoint: nothing
                from ham.learn.train import remove_run  # left, the same command runs again

                remove_run(out, created, ("config.json", "history.json"))
            raise


def _check_empty(out: Path) -> None:
    if out.exists() and any(out.iterdir()):
        raise HamError(f"output directory {str(out)!r} exists and is not empty")


def _read_config(out: Path) -> Sb3Config:
    """The :class:`Sb3Config` of the ``ham sb3`` run in ``out`` (one-line HamError if not)."""
    from ham.learn.train import read_json  # its one-line errors for a damaged file

    path = out / "config.json"
    if not path.is_file():
        raise HamError(f"{str(out)!r} holds no ham sb3 run (no config.json)")
    d = read_json(path)
    if isinstance(d, dict) and "model" in d and "algo" not in d:  # what ham train writes
        raise HamError(
            f"{str(out)!r} holds a ham train run; accepted: a ham sb3 run directory (continue "
            "a ham train run with ham train --resume)"
        )
    check_known_fields(Sb3Config, d, f"sb3 config {str(path)!r}")
    return Sb3Config(**d)


@checked_arguments
def resume_sb3(
    out: str | os.PathLike, env_steps: int | None = None, progress: bool = False
) -> dict:
    """Continue the run in ``out`` from its checkpoint (the last evaluation before it stopped)
    to its ``env_steps`` (or a new total ``env_steps``): the same numbers as a run never
    stopped."""
    out = Path(out)
    config = _read_config(out)
    with folder_lock(out):  # a second resume of the same run at once is refused
        return _resume_sb3(out, config, env_steps, progress)


def _resume_sb3(out: Path, config: Sb3Config, env_steps: int | None, progress: bool) -> dict:
    if (out / "metrics.json").is_file() and env_steps is None:
        raise HamError(f"the run in {str(out)!r} is finished (metrics.json); give a larger "
                       "--env-steps to train it further")  # fmt: skip
    if not (out / CHECKPOINT).is_file():
        raise HamError(f"the run in {str(out)!r} has no {CHECKPOINT} (it stopped before its "
                       "first evaluation, or its environment could not be pickled); start it "
                       "again")  # fmt: skip
    try:
        state = pickle.loads((out / CHECKPOINT).read_bytes())
    except Exception as exc:  # a truncated or foreign file: say so in one line
        raise HamError(f"cannot read {str(out / CHECKPOINT)!r}: {exc}") from None
    model = state["model"]
    if env_steps is not None:
        if env_steps <= model.num_timesteps:
            raise HamError(f"--env-steps {env_steps}; accepted: more than the checkpoint's "
                           f"{model.num_timesteps} steps")  # fmt: skip
        config = replace(config, env_steps=env_steps)
        write_json(out / "config.json", asdict(config))
    _expand_buffer(model)
    _set_rng_states(state["rng"])
    return _learn(config, out, model, state["eval_env"], state["history"], state["seconds"],
                  progress, resumed=True)  # fmt: skip


def _log_eval(writer, row: dict) -> None:
    """An evaluation in TensorBoard, by environment steps (glances)."""
    step = row["env_steps"]
    writer.add_scalar("eval/final_accuracy", row["final_accuracy"], step)
    writer.add_scalar("eval/average_accuracy", row["average_accuracy"], step)
    for g, acc in enumerate(row["accuracy_per_glance"], 1):
        writer.add_scalar(f"eval_per_glance/{g}", acc, step)
    writer.add_scalar("time/seconds", row["seconds"], step)


def _raised_by_the_algorithm(exc: BaseException) -> bool:
    """Whether ``exc`` came from the algorithm's own code (SB3, torch, NumPy): no frame of this
    package between :func:`_learn`'s call of ``learn`` and where it was raised (our callback's
    evaluation and our environments run inside ``learn`` too)."""
    package = str(Path(__file__).resolve().parents[1])  # .../ham
    frames = traceback.extract_tb(exc.__traceback__)[1:]  # [0]: _learn itself
    return not any(f.filename.startswith(package) for f in frames)


def steps_trained(model, env_steps: int) -> tuple[int, int] | None:
    """``(steps, chunk)``: SB3 steps the environments ``chunk`` steps at a time between its
    checks of the budget (PPO a rollout: ``n_steps`` per environment; SAC and CrossQ
    ``train_freq`` steps per environment), so a run from ``model.num_timesteps`` asked for
    ``env_steps`` trains ``steps``, the first multiple at or past it. ``None`` where that cannot
    be told ahead (``train_freq`` in episodes, or 0)."""
    from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
    from stable_baselines3.common.type_aliases import TrainFrequencyUnit

    if isinstance(model, OnPolicyAlgorithm):
        chunk = model.n_steps * model.n_envs
    elif model.train_freq.unit == TrainFrequencyUnit.STEP:
        chunk = model.train_freq.frequency * model.n_envs
    else:
        return None
    if chunk < 1:  # train_freq 0: SB3's own check refuses it when training starts
        return None
    start = model.num_timesteps
    return start + -(-(env_steps - start) // chunk) * chunk, chunk


def _learn(config: Sb3Config, out: Path, model, eval_env, history: list, seconds: float,
           progress: bool, resumed: bool = False) -> dict:  # fmt: skip
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.logger import Logger
    from torch.utils.tensorboard import SummaryWriter
    from tqdm.auto import tqdm

    started = time.time() - seconds
    # a resumed run redoes the steps after its checkpoint (its evaluations up to and including
    # num_timesteps are kept): the events of those steps are purged
    writer = SummaryWriter(str(out / "tb"), purge_step=model.num_timesteps + 1 if resumed else None)
    trained = steps_trained(model, config.env_steps)
    if trained is not None and trained[0] != config.env_steps:  # said, not silently rounded
        print(f"ham sb3: {config.algo} steps its environments {trained[1]:,} steps at a time: "
              f"it trains to {trained[0]:,} environment steps for --env-steps "
              f"{config.env_steps:,}", file=sys.stderr, flush=True)  # fmt: skip
    total = config.env_steps if trained is None else trained[0]
    bar = tqdm(total=total, initial=model.num_timesteps, disable=not progress,
               unit="step", desc=f"{config.algo} {config.env}", file=sys.stderr)  # fmt: skip
    saved: list[int | None] = [len(history)]  # evaluations in the last checkpoint; None: off

    def _checkpoint(evaluations: int) -> int | None:
        """A checkpoint; an environment that cannot be pickled costs the run its resume, not
        its result: one line on stderr, and no more tries."""
        try:
            _save_checkpoint(out, model, eval_env, history, time.time() - started, config.device)
        except (TypeError, AttributeError, pickle.PicklingError) as exc:
            print(f"ham sb3: no checkpoint, this run cannot be resumed ({type(exc).__name__}: "
                  f"{exc}); training goes on", file=sys.stderr, flush=True)  # fmt: skip
            return None
        return evaluations

    class Evaluate(BaseCallback):
        def _on_step(self) -> bool:
            bar.update(config.n_envs)
            if self.num_timesteps % config.eval_every < config.n_envs:
                row = evaluate_agent(model, eval_env, config.eval_episodes, 10**6)
                row["env_steps"] = int(self.num_timesteps)
                row["seconds"] = time.time() - started
                history.append(row)
                _log_eval(writer, row)
                bar.set_postfix(final=f"{row['final_accuracy']:.3f}",
                                avg=f"{row['average_accuracy']:.3f}")  # fmt: skip
                # A long run that is stopped early still leaves its curve so far (metrics.json
                # is written only at the end, so it is never a partial result).
                write_json(out / "history.json", {
                    "algo": config.algo, "env": config.env, "seed": config.seed,
                    "env_steps": row["env_steps"], "history": history,
                })  # fmt: skip
            return True

        def _on_rollout_start(self) -> None:
            if saved[0] is not None and len(history) > saved[0]:  # an evaluation since
                saved[0] = _checkpoint(len(history))  # the last checkpoint

    # a logger of no outputs: SB3's default makes an empty folder in the temp dir at each learn()
    model.set_logger(Logger(folder=None, output_formats=[]))
    try:
        model.learn(
            total_timesteps=config.env_steps - model.num_timesteps,
            callback=Evaluate(),
            reset_num_timesteps=not resumed,
        )
    except Exception as exc:
        if not (config.algo_kwargs and _raised_by_the_algorithm(exc)):
            raise  # the algorithm's defaults, or code of ours: a bug, of ours or of SB3's
        # the user's hyperparameters broke it mid-training: a learning rate beyond float32
        # (RuntimeError), NaN in the policy (torch.distributions' ValueError), a string or
        # 10**30 ent_coef (TypeError, OverflowError), n_epochs 0 (SB3's UnboundLocalError)
        first = (str(exc).splitlines() or [""])[0]
        raise HamError(
            f"algo_kwargs {config.algo_kwargs!r}: {config.algo} failed at env step "
            f"{model.num_timesteps}: {too_large(exc) or f'{type(exc).__name__}: {first}'}; "
            f"accepted: algo_kwargs {config.algo} trains with"
        ) from None
    finally:
        bar.close()
        writer.close()
    if saved[0] is not None:  # the end is a checkpoint too: --resume --env-steps N goes on
        _checkpoint(len(history))
    final = evaluate_agent(model, eval_env, config.eval_episodes, 10**6)
    metrics = {
        "algo": config.algo,
        "env": config.env,
        "env_steps": int(model.num_timesteps),
        **final,
        "best_accuracy": max([final["final_accuracy"]] + [h["final_accuracy"] for h in history]),
        "history": history,
        "seconds": time.time() - started,
    }
    head = eval_env.head
    model.save(out / "model.zip")
    atomic_write(out / "head.pt", lambda tmp: torch.save(head.state_dict(), tmp), what="checkpoint")
    write_json(out / "metrics.json", metrics)
    return metrics
