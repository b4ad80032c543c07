"""The haptic world as an ``ap_gym`` active classification environment: ``ham/HapticGlanceAP-v0``.

The Active Perception Gym's convention (``ap_gym``, PyPI ``ap-gym``): the action is
``{"action": glance parameters, "prediction": class logits}``; the reward of every step is the
environment's base reward minus the normalized cross-entropy of that step's prediction (0 for
a perfect prediction, -1 for a blind guess); the ``-sparse`` variant scores only the prediction
of the episode's last step. Here:

* observation ``{"pressure": (N, N), "pose": (k,)}`` as in ``ham/HapticGlance-v0`` (N = taxels, 16;
  k = the world's pose dims, 2 for the paper's; ``height=True``: also ``"height": (1,)``, m);
* ``action["action"]``: the normalized pose ``(q_x, q_phi)`` (``k`` values in the world's pose
  dims) of the next glance (absolute, in ``[-1, 1]``; outside values are clipped);
  ``action["prediction"]``: ``K`` logits;
* base reward 0; ``reset`` makes the first, random glance; step ``s`` scores the prediction made
  after glances ``1..s`` and makes glance ``s+1``; step ``S`` only scores, and terminates. So an
  episode has ``S`` steps and ``S`` scored predictions (``-sparse``: the last one only);
* the prediction target (the object id) is a NumPy ``int64`` value, and ``reset``'s info carries
  it as ``info["prediction"]["target"]``, which ap-gym 0.7.0's ``SparsifyWrapper.reset``
  requires (its own image environments lack it, so their single ``-sparse`` variants fail at
  ``reset`` with ``KeyError: 'prediction'``).

The vector environment makes one batched glance per step and resets all episodes on the step
after they end (``NEXT_STEP``), like ap_gym's image environments; ap_gym scores that step's
prediction against the new targets (``-sparse``: with weight 0).

Importing this module imports ``ap_gym`` (which needs ``aiohttp``); :mod:`ham.envs` registers
the ids without importing it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from ham.envs.haptic import (
    RENDER_MODES,
    VECTOR_METADATA,
    as_array,
    attach_world,
    check_num_envs,
    observation_space,
    pose_space,
    reset_option,
)
from ham.errors import HamError, brief, checked_arguments
from ham.world.config import WorldConfig

try:
    import ap_gym
except ImportError as exc:  # pragma: no cover - depends on the installation
    raise HamError(
        f"ap_gym is not available ({exc}); install it with: pip install ap-gym aiohttp"
    ) from None


def _ap_action(action: Any, shape: tuple[int, ...]) -> dict[str, Any]:
    """ap_gym's action: a dict with exactly ``action`` (the pose) and ``prediction`` (finite
    logits of ``shape``), checked before ap_gym scores the prediction (its loss took booleans to
    a TypeError and infinite logits to a NaN or infinite reward)."""
    if not isinstance(action, dict) or set(action) != {"action", "prediction"}:
        raise HamError(
            f"action {brief(action)}; accepted: a dict with 'action' (the pose q_x, q_phi) and "
            "'prediction' (logits)"
        )
    p = as_array(action["prediction"], "prediction", f"finite logits of shape {shape}", "iuf")
    if p.shape != shape:
        raise HamError(f"prediction of shape {p.shape}; accepted: finite logits of shape {shape}")
    if not np.isfinite(p).all():
        raise HamError(f"prediction {brief(action['prediction'])}; accepted: finite logits")
    return {"action": action["action"], "prediction": p.astype(np.float64)}


class HapticGlanceAPEnv(ap_gym.ActiveClassificationEnv):
    """``ham/HapticGlanceAP-v0``: the haptic world as an ap_gym active classification env.

    Arguments as :class:`ham.envs.haptic.HapticGlanceEnv`; ``reset(options={"object": ID})``.
    """

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": 2}

    @checked_arguments
    def __init__(
        self,
        glances: int = 3,
        table: str | Path | None = None,
        world: WorldConfig | dict | None = None,
        normalization: str = "l2",
        device: str = "cpu",
        render_mode: str | None = None,
        height: bool = False,
        object_pose=None,
    ) -> None:
        attach_world(
            self, 1, glances, table, world, normalization, device, render_mode, height, object_pose
        )
        super().__init__(self.backend.n_objects, pose_space(self.backend))
        self.observation_space = observation_space(self.backend, height)

    def _target(self) -> np.ndarray:
        return np.asarray(self.episodes.objects[0], dtype=np.int64)

    def _obs(self) -> dict[str, np.ndarray]:
        return {k: v[0] for k, v in self.episodes.observation().items()}

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        self.episodes.start(self.np_random, reset_option(options, "object"))
        obj = int(self.episodes.objects[0])
        info = {
            "object": obj,
            "object_name": self.objects[obj],
            "prediction": {"target": self._target()},
        }
        return self._obs(), info

    def step(self, action: dict[str, Any]):
        return super().step(_ap_action(action, (self.backend.n_objects,)))

    def _step(
        self, action: np.ndarray, prediction: np.ndarray
    ) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any], np.ndarray]:
        terminated = self.episodes.advance(action)
        return self._obs(), 0.0, terminated, False, {}, self._target()

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        return self.episodes.render()[0]


class HapticGlanceAPVectorEnv(ap_gym.ActiveClassificationVectorEnv):
    """``num_envs`` episodes of ``ham/HapticGlanceAP-v0`` in lockstep (one batched glance a step).

    ``reset(options={"objects": IDS})`` fixes the objects.
    """

    metadata = VECTOR_METADATA

    @checked_arguments
    def __init__(
        self,
        num_envs: int = 1,
        glances: int = 3,
        table: str | Path | None = None,
        world: WorldConfig | dict | None = None,
        normalization: str = "l2",
        device: str = "cpu",
        render_mode: str | None = None,
        height: bool = False,
        object_pose=None,
    ) -> None:
        num_envs = check_num_envs(num_envs)
        attach_world(
            self, int(num_envs), glances, table, world, normalization, device, render_mode,
            height, object_pose,
        )  # fmt: skip
        super().__init__(int(num_envs), self.backend.n_objects, pose_space(self.backend))
        self.single_observation_space = observation_space(self.backend, height)
        self.observation_space = gym.vector.utils.batch_space(
            self.single_observation_space, self.num_envs
        )
        self._autoreset = False

    def _targets(self) -> np.ndarray:
        return self.episodes.objects.astype(np.int64)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        self.episodes.start(self.np_random, reset_option(options, "objects"))
        self._autoreset = False
        return self.episodes.observation(), {
            **self.episodes.info(),
            "prediction": {"target": self._targets()},
        }

    def step(self, actions: dict[str, Any]):
        return super().step(_ap_action(actions, (self.num_envs, self.backend.n_objects)))

    def _step(
        self, action: np.ndarray, prediction: np.ndarray
    ) -> tuple[
        dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray, dict[str, Any], np.ndarray
    ]:
        n = self.num_envs
        truncated = np.zeros(n, dtype=np.bool_)
        if self._autoreset:
            self.episodes.start(self.np_random)
            self._autoreset = False
            ended = False
        else:
            ended = self.episodes.advance(action)
            self._autoreset = ended
        obs = self.episodes.observation()
        return obs, np.zeros(n), np.full(n, ended), truncated, self.episodes.info(), self._targets()

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        return self.episodes.render()


# ---------------------------------------------------------------------- entry points
def make_env(**kwargs: Any) -> gym.Env:
    """``ham/HapticGlanceAP-v0``: the env with ap_gym's classification log wrapper."""
    return ap_gym.ActiveClassificationLogWrapper(HapticGlanceAPEnv(**kwargs))


def make_vector_env(num_envs: int = 1, **kwargs: Any) -> gym.vector.VectorEnv:
    """The vector ``ham/HapticGlanceAP-v0`` with ap_gym's classification log wrapper."""
    return ap_gym.ActiveClassificationVectorLogWrapper(HapticGlanceAPVectorEnv(num_envs, **kwargs))


def make_sparse_env(**kwargs: Any) -> gym.Env:
    """``ham/HapticGlanceAP-sparse-v0``: only the last prediction is scored."""
    return ap_gym.SparsifyWrapper(make_env(**kwargs))


def make_sparse_vector_env(num_envs: int = 1, **kwargs: Any) -> gym.vector.VectorEnv:
    """The vector ``ham/HapticGlanceAP-sparse-v0``."""
    return ap_gym.SparsifyVectorWrapper(make_vector_env(num_envs, **kwargs))
