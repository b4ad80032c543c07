"""The HAM on other worlds: any ``ap_gym`` active classification environment with a glimpse.

The Active Perception Gym (``ap_gym``, PyPI ``ap-gym``) offers image classification tasks in
which an agent moves a small glimpse over an image: observation ``{"glimpse": (G, G, C),
"glimpse_pos": (2,) in [-1, 1], ...}``, action ``{"action": movement (2,), "prediction":
logits (K,)}``. :class:`ApGymGlanceEnv` presents such a vector environment to the HAM exactly
like :class:`ham.learn.environment.HapticEnv` presents the haptic world:

* ``sample_objects()`` resets a batch of ``batch_size`` episodes and returns their class labels
  (the "objects" the HAM classifies); training batch ``k`` is drawn with a seed derived from
  ``(seed, k)``, so the images and first glimpses depend on the batch's index alone and a
  resumed run draws the same ones (ap_gym's own generators, with a prefetching data loader,
  cannot be saved);
* ``glance(objects, q)`` returns the next glimpse, flattened to ``pressure_dim`` values and
  normalized (``none`` by default: an image glimpse's brightness is information, unlike the
  pressure image's scale); the first glance of an episode is the environment's reset glimpse
  (ap_gym's image environments start at a uniformly random position: the paper's random first
  glance);
* ``observed_location``: where the glimpse actually was, ``(B, 2)`` in ``[-1, 1]``: the
  HAM's where-input (the tactile network's location branch), not the pose it asked for.

Actions (``actions``):

* ``relative``: the HAM's sampled ``q in [-1, 1]^2`` is passed unchanged as the environment's
  action: ap_gym's image environments move the glimpse by ``max_step_length * q`` (``q``
  projected into the unit disc; 0.2 by default, a tenth of the image);
* ``absolute``: ``q`` is a target position; the adapter sends the movement toward it,
  ``(q - position) / max_step_length``, which the environment caps at its step length. With
  ``max_step_length=2 * sqrt(2)`` (an override of the environment's configuration, a different
  and easier task than the registered one) every target is reached in one step: the paper's
  glances, which go anywhere.

The reward the HAM trains on is its own, as in the paper: 1 at the end of the episode if the
arg-max class after the last glance is right, else 0 (:mod:`ham.learn.hybrid_loss`); the environment's
reward (base reward minus normalized cross-entropy) is not used, and the adapter sends uniform
logits as the environment's ``prediction``.

Evaluation (``balanced_objects``) runs on a separate environment (``eval_env_id``, default the
same id) reseeded at every evaluation, so every evaluation sees the same images and first
glimpses. Labels come from the environment's data and are not balanced by class.

A training run on ap_gym is a regular run (:mod:`ham.learn.train`): ``TrainConfig(env=
ApGymConfig(...))`` names the environment, :func:`ham.learn.train.fit_to_ap_gym` sizes the model
for it (:func:`sized_model`), and ``train``, ``resume``, ``load_run`` and ``ham train --env
ap_gym:ENV_ID`` / ``--resume`` / ``ham evaluate`` work as on the haptic world.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch

from ham.errors import HamError, check_integer, check_known_fields, check_types, checked_arguments
from ham.model.agent import HamConfig
from ham.model.policy import raster_counts
from ham.world.devices import check_device

ACTIONS: tuple[str, ...] = ("relative", "absolute")
NORMALIZATIONS: tuple[str, ...] = ("none", "l2", "l1")
#: How a glimpse becomes the tactile network's input: ``flat`` (the glimpse's values, normalized
#: as the run says) or ``centered`` (the glimpse minus its mean, times :data:`CENTER_GAIN`, and
#: the mean itself as one more value; docs/learners.md: why).
GLIMPSES: tuple[str, ...] = ("flat", "centered")
#: The gain of a centered glimpse: CircleSquare's object edge (a step of 0.1 on its brightness
#: gradient) becomes a step of about 1, the scale of the network's initial weights.
CENTER_GAIN = 10.0
#: ``max_step_length`` with which one step reaches any position of ``[-1, 1]^2``.
TELEPORT_STEP = 2.0 * math.sqrt(2.0)
GLIMPSE_KEYS: tuple[str, ...] = ("glimpse",)
POSITION_KEYS: tuple[str, ...] = ("glimpse_pos",)
ENV_PREFIX = "ap_gym:"


def import_ap_gym():
    """``ap_gym``, or a :class:`HamError` that says how to install it."""
    try:
        import ap_gym
    except ImportError as exc:
        raise HamError(
            f"ap_gym is not available ({exc}); install it with: pip install ap-gym aiohttp"
        ) from None
    return ap_gym


def parse_env(env: str) -> str:
    """``ap_gym:ENV_ID`` (or a bare ``ENV_ID``) -> ``ENV_ID``; a :class:`HamError` when unknown."""
    if not isinstance(env, str) or not env:
        raise HamError(f"environment {env!r}; accepted: ap_gym:ENV_ID, e.g. ap_gym:CircleSquare-v0")
    env_id = env[len(ENV_PREFIX) :] if env.startswith(ENV_PREFIX) else env
    import gymnasium as gym

    import_ap_gym()  # registers ap_gym's environments
    if env_id not in gym.registry:
        close = [k for k in gym.registry if env_id.split("-")[0].lower() in k.lower()][:8]
        hint = f"; similar: {', '.join(close)}" if close else ""
        raise HamError(f"environment {env_id!r} is not registered with gymnasium/ap_gym{hint}")
    return env_id


def _image_config_with(env_id: str, **changes: Any) -> dict:
    """The ``image_perception_config`` kwarg of ``env_id`` with ``changes`` (``{}`` for an
    environment without one and no changes)."""
    import gymnasium as gym

    cfg = (gym.spec(env_id).kwargs or {}).get("image_perception_config")
    if cfg is None or not dataclasses.is_dataclass(cfg):
        if "max_step_length" in changes:
            raise HamError(
                f"max_step_length = {changes['max_step_length']!r} applies only to ap_gym image "
                f"environments (with an image_perception_config); {env_id!r} has none"
            )
        return {}
    known = {f.name for f in dataclasses.fields(cfg)}
    return {
        "image_perception_config": dataclasses.replace(
            cfg, **{k: v for k, v in changes.items() if k in known}
        )
    }


def _pick_key(space, candidates: tuple[str, ...], what: str, env_id: str) -> str:
    keys = list(getattr(space, "spaces", {}) or {})
    for k in candidates:
        if k in keys:
            return k
    raise HamError(
        f"environment {env_id!r} has no {what} in its observation (keys: {', '.join(keys) or 'none'}); "
        f"accepted: an observation dict with one of {', '.join(candidates)}"
    )


def _as_target_array(target: Any) -> np.ndarray:
    """A step's or reset's prediction target (plain or ``-sparse``'s ``{target, weight}``)."""
    if isinstance(target, dict):
        target = target["target"]
    return np.asarray(target, dtype=np.int64).reshape(-1)


@dataclass(frozen=True)
class ApGymConfig:
    """Which ap_gym environment a run trains on, and how the HAM acts in it (``TrainConfig.env``).

    Attributes:
        env: the environment, ``ap_gym:ENV_ID`` (e.g. ``ap_gym:CircleSquare-s15-nograd-v0``).
        eval_env: the evaluation environment (``None``: ``env``; e.g. a ``-test`` split).
        actions: ``absolute`` (the HAM's pose is a target) or ``relative`` (a movement).
        max_step_length: override of the image environment's step length (``None``: as
            registered; :data:`TELEPORT_STEP` reaches any target in one step).
        glimpse: ``flat`` (the glimpse's values, normalized as the run says) or ``centered``
            (the glimpse minus its mean, times :data:`CENTER_GAIN`, then its mean: ``G*G*C + 1``
            values; needs the run's normalization ``none``).

    The glimpse's normalization is the run's (``TrainConfig.normalization``), its batch size and
    seeds too. Registration is checked when the environment is made, not here.
    """

    env: str
    eval_env: str | None = None
    actions: str = "absolute"
    max_step_length: float | None = None
    glimpse: str = "flat"

    def __post_init__(self) -> None:
        check_types(self)
        for name in ("env", "eval_env"):
            v = getattr(self, name)
            if not (isinstance(v, str) and v) and not (name == "eval_env" and v is None):
                raise HamError(f"{name} = {v!r}; accepted: ap_gym:ENV_ID")
        if self.actions not in ACTIONS:
            raise HamError(f"actions = {self.actions!r}; accepted: {', '.join(ACTIONS)}")
        if self.glimpse not in GLIMPSES:
            raise HamError(f"glimpse = {self.glimpse!r}; accepted: {', '.join(GLIMPSES)}")
        v = self.max_step_length
        if v is not None and not (
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0
        ):
            raise HamError(f"max_step_length = {v!r}; accepted: a finite number > 0")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> ApGymConfig:
        check_known_fields(cls, d, "ap_gym env config")
        return cls(**d)


def batch_seed(seed: int, batch: int) -> int:
    """The reset seed of training batch ``batch``: independent streams per ``(seed, batch)``."""
    return int(np.random.SeedSequence([int(seed), int(batch)]).generate_state(1)[0])


class ApGymGlanceEnv:
    """An ap_gym active classification vector environment with the interface of
    :class:`ham.learn.environment.HapticEnv` (``sample_objects``, ``balanced_objects``, ``glance``,
    ``n_objects``, ``batch_size``, ``device``, ``state_dict``), plus ``observed_location``.

    Args:
        env_id: an ap_gym environment id (``CircleSquare-v0``) or ``ap_gym:ENV_ID``.
        batch_size: episodes per batch (parallel environments).
        actions: ``relative`` (the HAM's pose is the environment's movement) or ``absolute``
            (a target position; the adapter moves toward it).
        max_step_length: override of the image environments' step length (``None``: as
            registered, 0.2); :data:`TELEPORT_STEP` reaches any target in one step.
        normalization: of the flattened glimpse: ``none`` (default), ``l2`` or ``l1``.
        glimpse: ``flat`` or ``centered`` (:data:`GLIMPSES`; ``centered`` needs normalization
            ``none``).
        seed: seeds the training environment's images and first glimpses (batch ``k`` is reset
            with :func:`batch_seed` ``(seed, k)``).
        eval_env_id: environment of the evaluation (default ``env_id``; e.g. a ``-test`` split).
        eval_seed: seeds the evaluation environment at every evaluation.
        device: where the glimpses go (the HAM's device).
        env_kwargs: more keyword arguments for ``ap_gym.make_vec``.
    """

    @checked_arguments
    def __init__(
        self,
        env_id: str,
        batch_size: int = 64,
        *,
        actions: str = "absolute",
        max_step_length: float | None = None,
        normalization: str = "none",
        seed: int = 0,
        eval_env_id: str | None = None,
        eval_seed: int = 12345,
        device: str | torch.device = "cpu",
        env_kwargs: dict | None = None,
        glimpse: str = "flat",
    ) -> None:
        if not (
            isinstance(batch_size, int) and not isinstance(batch_size, bool) and batch_size >= 1
        ):
            raise HamError(f"batch_size = {batch_size!r}; accepted: an integer >= 1")
        if actions not in ACTIONS:
            raise HamError(f"actions = {actions!r}; accepted: {', '.join(ACTIONS)}")
        if normalization not in NORMALIZATIONS:
            raise HamError(
                f"normalization = {normalization!r}; accepted: {', '.join(NORMALIZATIONS)}"
            )
        if glimpse not in GLIMPSES:
            raise HamError(f"glimpse = {glimpse!r}; accepted: {', '.join(GLIMPSES)}")
        if glimpse == "centered" and normalization != "none":
            raise HamError(
                f"normalization = {normalization!r} with a centered glimpse; accepted: none "
                "(the centered glimpse keeps its mean brightness as an input)"
            )
        if max_step_length is not None and not (
            isinstance(max_step_length, (int, float))
            and math.isfinite(max_step_length)
            and max_step_length > 0
        ):
            raise HamError(f"max_step_length = {max_step_length!r}; accepted: a finite number > 0")
        self.env_id = parse_env(env_id)
        self.eval_env_id = parse_env(eval_env_id) if eval_env_id else self.env_id
        self.batch_size = batch_size
        self.actions = actions
        self.normalization = normalization
        self.glimpse = glimpse
        self.seed = check_integer("seed", seed)
        self.eval_seed = check_integer("eval_seed", eval_seed)
        self.device = check_device(device)
        self.max_step_length = max_step_length
        self.env_kwargs = dict(env_kwargs or {})

        self.train_env = self._make(self.env_id)
        self.eval_env = self._make(self.eval_env_id)
        env = self.train_env
        self.glimpse_key = _pick_key(
            env.single_observation_space, GLIMPSE_KEYS, "glimpse", self.env_id
        )
        self.position_key = _pick_key(
            env.single_observation_space, POSITION_KEYS, "glimpse position", self.env_id
        )
        glimpse_space = env.single_observation_space[self.glimpse_key]
        self.glimpse_shape = tuple(int(s) for s in glimpse_space.shape)
        self.pressure_dim = int(np.prod(self.glimpse_shape)) + (1 if glimpse == "centered" else 0)
        target_space = env.single_prediction_target_space
        n = getattr(target_space, "n", None)
        if n is None and hasattr(target_space, "spaces"):  # a -sparse variant: {target, weight}
            n = getattr(target_space.spaces.get("target"), "n", None)
        if n is None:
            raise HamError(
                f"environment {self.env_id!r} is not an active classification environment "
                f"(its prediction target is {target_space}); accepted: a Discrete class target"
            )
        self.n_objects = int(n)
        self.objects = [str(k) for k in range(self.n_objects)]
        self.step_limit = self._step_limit(env)
        self.env_max_step = self._env_max_step(env)
        if actions == "absolute" and self.env_max_step is None:
            raise HamError(
                f"actions = 'absolute' needs the step length of {self.env_id!r}, which it does not "
                "report; accepted: actions = 'relative'"
            )
        self._active = None
        self._position: np.ndarray | None = None
        self._labels: np.ndarray | None = None
        self._glances = 0
        self._batches = 0  # training batches drawn: the only state a checkpoint needs

    # ------------------------------------------------------------------ construction
    def _make(self, env_id: str):
        ap_gym = import_ap_gym()
        kwargs = dict(self.env_kwargs)
        # No prefetching data loader: every training batch reseeds the environment (the
        # batch's images follow from its index), which would restart the loader's thread and
        # discard its 128 prefetched batches each time. The images drawn are the same.
        changes: dict[str, Any] = {"prefetch": False}
        if self.max_step_length is not None:
            changes["max_step_length"] = float(self.max_step_length)
        kwargs.update(_image_config_with(env_id, **changes))
        try:
            return ap_gym.make_vec(env_id, num_envs=self.batch_size, **kwargs)
        except HamError:
            raise
        except Exception as exc:  # noqa: BLE001 - e.g. a hub data set that cannot be fetched
            raise HamError(
                f"cannot make ap_gym environment {env_id!r}: {type(exc).__name__}: {exc}"
            ) from None

    @staticmethod
    def _step_limit(env) -> int | None:
        config = getattr(env.unwrapped, "config", None)
        limit = getattr(config, "step_limit", None)
        if limit is None and env.spec is not None:
            limit = env.spec.max_episode_steps
        return None if limit is None else int(limit)

    @staticmethod
    def _env_max_step(env) -> np.ndarray | None:
        config = getattr(env.unwrapped, "config", None)
        step = getattr(config, "max_step_length", None)
        if step is None:
            return None
        return np.ones(2) * np.asarray(step, dtype=np.float64)

    def check_glances(self, glances: int) -> None:
        """A :class:`HamError` when an episode of ``glances`` glances would outlast the
        environment's episode (the first glance is the reset, each further one a step)."""
        if self.step_limit is not None and glances - 1 > self.step_limit:
            raise HamError(
                f"glances = {glances}; accepted for {self.env_id!r}: at most {self.step_limit + 1} "
                f"(its episodes end after {self.step_limit} steps)"
            )

    # ------------------------------------------------------------------ HapticEnv interface
    def _reset(self, env, seed: int | None) -> torch.Tensor:
        obs, info = env.reset(seed=seed)
        target = (info.get("prediction") or {}).get("target") if isinstance(info, dict) else None
        if target is None:
            labels = getattr(
                getattr(env.unwrapped, "image_perception_module", None), "current_labels", None
            )
            if labels is None:
                raise HamError(
                    f"environment {self.env_id!r} reports no prediction target at reset "
                    "(info['prediction']['target']); the adapter needs the labels to train"
                )
            target = labels
        self._labels = _as_target_array(target)
        self._active = env
        self._glances = 0
        self._obs = obs
        return torch.as_tensor(self._labels, dtype=torch.long, device=self.device)

    def sample_objects(self) -> torch.Tensor:
        """A fresh training batch: reset ``batch_size`` episodes; their labels ``(B,)`` long."""
        seed = batch_seed(self.seed, self._batches)
        self._batches += 1
        return self._reset(self.train_env, seed)

    def balanced_objects(self, batch_index: int = 0) -> torch.Tensor:
        """Evaluation batch ``batch_index`` (the evaluation environment is reseeded at 0)."""
        return self._reset(self.eval_env, self.eval_seed if batch_index == 0 else None)

    def glance(self, object_ids: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
        """The next glimpse of the current episodes, flattened and normalized ``(B, pressure_dim)``.

        The first call after a reset returns the reset glimpse (``q`` is not used); every later
        call moves the glimpse by ``q`` (``relative``) or toward ``q`` (``absolute``).
        """
        if self._active is None:
            raise HamError("glance() before sample_objects() or balanced_objects()")
        env = self._active
        if self._glances > 0:
            qn = q.detach().to("cpu", torch.float64).numpy()
            if qn.shape != (self.batch_size, 2) or not np.isfinite(qn).all():
                raise HamError(
                    f"poses of shape {qn.shape}; accepted: ({self.batch_size}, 2) finite values"
                )
            if self.actions == "relative":
                action = qn.astype(np.float32)
            else:
                move = qn - self._obs[self.position_key]
                with np.errstate(over="ignore"):
                    action = (move / self.env_max_step).astype(np.float32)
                far = ~np.isfinite(action).all(-1)
                if far.any():  # a step length so short (1e-300) that the move overflows float32
                    # (ap_gym's cap then made inf / inf = NaN): its cap, a unit step toward q
                    unit = move[far] / np.linalg.norm(move[far], axis=-1, keepdims=True)
                    action[far] = unit.astype(np.float32)
            prediction = np.zeros((self.batch_size, self.n_objects), dtype=np.float32)
            obs, _, terminated, truncated, info = env.step(
                {"action": action, "prediction": prediction}
            )
            if (
                np.any(terminated | truncated)
                and self.step_limit is not None
                and self._glances < self.step_limit
            ):
                raise HamError(
                    f"environment {self.env_id!r} ended an episode after {self._glances} steps; "
                    "use fewer glances"
                )
            target = info.get("prediction", {}).get("target")
            if target is not None and not np.array_equal(_as_target_array(target), self._labels):
                raise HamError(f"environment {self.env_id!r} changed its targets within an episode")
            self._obs = obs
        self._glances += 1
        glimpse = np.asarray(self._obs[self.glimpse_key], dtype=np.float32).reshape(
            self.batch_size, -1
        )
        self._position = np.asarray(self._obs[self.position_key], dtype=np.float32)
        x = torch.from_numpy(glimpse).to(self.device)
        if self.normalization != "none":
            norm = x.norm(p=2 if self.normalization == "l2" else 1, dim=-1, keepdim=True)
            x = torch.where(norm > 0, x / norm.clamp_min(torch.finfo(x.dtype).tiny), 0.0)
        if self.glimpse == "centered":
            mean = x.mean(-1, keepdim=True)
            x = torch.cat([(x - mean) * CENTER_GAIN, mean], dim=-1)
        return x

    @property
    def observed_location(self) -> torch.Tensor | None:
        """Where the last glimpse was, ``(B, 2)`` in ``[-1, 1]`` (the HAM's where-input)."""
        if self._position is None:
            return None
        return torch.from_numpy(self._position).to(self.device)

    def settings(self) -> dict:
        """The adapter's settings, with what it found out about the environment (in checkpoints)."""
        return {
            "env": ENV_PREFIX + self.env_id,
            "eval_env": ENV_PREFIX + self.eval_env_id,
            "actions": self.actions,
            "max_step_length": self.max_step_length,
            "normalization": self.normalization,
            "glimpse": self.glimpse,
            "eval_seed": self.eval_seed,
            "glimpse_shape": list(self.glimpse_shape),
            "pressure_dim": self.pressure_dim,
            "n_objects": self.n_objects,
            "step_limit": self.step_limit,
        }

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict:
        """The training batches drawn so far: batch ``k``'s images follow from ``(seed, k)``."""
        return {"batches": self._batches, "settings": self.settings()}

    def load_state_dict(self, state: dict) -> None:
        if "batches" not in state:
            raise HamError(
                "the checkpoint's ap_gym state has no batch count (written before resume was "
                "supported); start a new run"
            )
        self._batches = int(state["batches"])

    def close(self) -> None:
        self.train_env.close()
        self.eval_env.close()


def make_ap_env(
    config: ApGymConfig,
    batch_size: int,
    seed: int = 0,
    eval_seed: int = 12345,
    normalization: str = "none",
    device: str | torch.device = "cpu",
) -> ApGymGlanceEnv:
    """The adapter ``config`` describes (training images from ``seed``, evaluation images from
    ``eval_seed``)."""
    return ApGymGlanceEnv(
        config.env,
        batch_size,
        actions=config.actions,
        max_step_length=config.max_step_length,
        normalization=normalization,
        seed=seed,
        eval_env_id=config.eval_env,
        eval_seed=eval_seed,
        device=device,
        glimpse=config.glimpse,
    )


def sized_model(config: ApGymConfig, model: HamConfig, phi_scale: float = 1.0) -> HamConfig:
    """``model`` sized for the environment: its glimpse (``pressure_dim``) and classes
    (``n_objects``), with ``phi_scale`` (1: both coordinates are positions, unscaled); a
    :class:`HamError` when its episodes are too short for the glances."""
    probe = make_ap_env(config, 1, normalization="none")  # the size does not depend on it
    try:
        probe.check_glances(model.glances)
        changes = {}
        if model.policy == "grid" and config.actions == "relative":
            # only the grid policy reads it: every other policy's config stays as it was
            changes["moves"] = True
            _check_grid_fits(model.glances, probe.env_max_step, config.env)
        if model.policy == "grid-corner" and config.actions == "relative":
            # plans its walk in the environment's full step
            step = probe.env_max_step
            if step is None or step[0] != step[1]:
                raise HamError(
                    f"policy 'grid-corner' on {config.env!r}, which reports no one step length "
                    "(max_step_length); accepted: an ap_gym image environment"
                )
            changes.update(moves=True, move_length=float(step[0]))
        return dataclasses.replace(
            model,
            n_objects=probe.n_objects,
            pressure_dim=probe.pressure_dim,
            phi_scale=phi_scale,
            **changes,
        )
    finally:
        probe.close()


def _check_grid_fits(glances: int, step: np.ndarray | None, env_id: str) -> None:
    """A :class:`HamError` when the ``grid`` policy's walk of moves (:func:`ham.model.policy.
    snake`, one full step per move) is wider than the image ``[-1, 1]``: its rows would be
    clipped at the border into one another. ``step``: the environment's step length per axis
    (``None``: not reported, not checked)."""
    if step is None:
        return
    counts = raster_counts(glances, 2)
    for axis, (n, length) in enumerate(zip(counts, step, strict=True)):
        if (n - 1) * length > 2 + 1e-9:
            raise HamError(
                f"policy 'grid' with {glances} glances moves {n - 1} steps of {length:g} along "
                f"axis {axis} of {env_id!r}, wider than its image (2); accepted: fewer glances "
                "or a shorter --max-step-length"
            )
