"""Plain Gymnasium environments over the haptic world: ``ham/HapticGlance-v0``.

One episode identifies one object (drawn uniformly, or given with ``reset(options=...)``) by a
fixed number of glances ``S`` (``glances``, default 3):

* ``reset()`` makes the first glance at a uniformly random pose (section "Training": "the first
  pressure-location pair is chosen by the first random glance") and returns it;
* steps ``1 .. S-1`` make glance ``s+1`` at the action's ``pose``;
* step ``S`` makes no glance: it is where the agent's last ``prediction`` counts. The episode
  terminates with reward 1 if that prediction is the object, else 0 (the paper's reward); every
  earlier step has reward 0 and its ``prediction`` is ignored. The observation returned with the
  termination repeats the last glance.

Spaces (``k`` = the world's pose dims, 2 for the paper's ``(q_x, q_phi)``; ``WorldConfig.pose_dims``
or the table's grid, in canonical order ``x, y, phi, phi_y``):

* observation ``{"pressure": Box(N, N) float32, "pose": Box(k,) in [-1, 1]}`` (with
  ``height=True`` also ``"height": Box(1,)``, the glance's contact height h in m): the pressure
  image of the last glance (``N`` = the world's or the table's ``taxels``, 16 by default), L2-normalized (the paper; ``normalization='l1'``: the authors' code;
  ``'none'``: raw pressure in Pa) and the normalized pose it was made at;
* action ``{"pose": Box(k,) in [-1, 1], "prediction": Discrete(K)}``: where to glance next
  (``q_x, q_phi``; ``x = q_x * zone``, ``phi = q_phi * pi/2``; values outside ``[-1, 1]`` are
  clipped) and the object the agent believes it touches.

``object_pose`` (online only): a random object pose per episode, yaw and offset
(:class:`ham.world.source.ObjectPoseConfig` or its dict), drawn from the env's ``np_random``.

Glances come from the batched glance sources of :mod:`ham.learn.environment`: a glance table
(``table=FILE``, the nearest grid point, as in the paper) or the fast simulator online (exact
poses). :class:`HapticGlanceVectorEnv` runs ``num_envs`` episodes in lockstep with one batched
glance per step (true vectorization) and resets them all on the step after they end
(Gymnasium's ``NEXT_STEP`` autoreset mode).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from ham.errors import HamError, brief, check_integer, check_known_fields, checked_arguments
from ham.world.config import WorldConfig
from ham.world.devices import check_device
from ham.world.glance import height_bound

ENV_NORMALIZATIONS: tuple[str, ...] = ("l2", "l1", "none")
RENDER_MODES: tuple[str, ...] = ("rgb_array",)
#: Rendered images are about this many pixels wide: each taxel is ``RENDER_SIZE // N`` pixels.
RENDER_SIZE = 128


def check_glances(glances: Any) -> int:
    """``glances`` as an int >= 1, or a :class:`HamError`."""
    return check_integer("glances", glances, 1)


def reset_option(options: Any, key: str) -> Any:
    """``options[key]`` of ``reset(options=...)`` (``None`` if absent); other keys are refused."""
    if options is None:
        return None
    if not isinstance(options, dict) or set(options) - {key}:
        raise HamError(f"reset options {brief(options)}; accepted: None or {{{key!r}: ...}}")
    return options.get(key)


def _check_render_mode(render_mode: str | None) -> str | None:
    if render_mode is not None and render_mode not in RENDER_MODES:
        raise HamError(f"render_mode = {render_mode!r}; accepted: None, {', '.join(RENDER_MODES)}")
    return render_mode


class GlanceBackend:
    """Batched glances for the environments: object ids and poses in, pressure images out.

    Args:
        table: a glance table (HDF5) to look glances up in; ``None``: simulate them online.
        world: the world simulated online (:class:`ham.world.config.WorldConfig` or its dict; paper
            defaults); refused with a table, which carries its own.
        normalization: ``l2`` (paper), ``l1`` (authors' code) or ``none`` (raw pressure, Pa).
        device: where glances are computed (``cpu`` or ``cuda``); observations are NumPy.
        object_pose: a random object pose per episode (online only; ``None``: off).
    """

    def __init__(
        self,
        table: str | Path | None = None,
        world: WorldConfig | dict | None = None,
        normalization: str = "l2",
        device: str = "cpu",
        object_pose=None,
    ) -> None:
        from ham.world.source import ObjectPoseConfig, make_source

        if normalization not in ENV_NORMALIZATIONS:
            raise HamError(
                f"normalization = {normalization!r}; accepted: {', '.join(ENV_NORMALIZATIONS)}"
            )
        if table is not None and not isinstance(table, (str, Path)):
            raise HamError(f"table = {table!r}; accepted: a glance table's path, or None")
        if table is not None and world is not None:
            raise HamError(
                f"table = {str(table)!r} and world = {world!r}: give one (a table holds its own world)"
            )
        if isinstance(world, dict):
            world = WorldConfig.from_dict(world)
        if table is not None and not Path(table).exists():
            raise HamError(f"glance table {str(table)!r} does not exist")
        self.device = check_device(device)
        if isinstance(object_pose, dict):
            check_known_fields(ObjectPoseConfig, object_pose, "object_pose")
            object_pose = ObjectPoseConfig(**object_pose)
        if object_pose is not None and not isinstance(object_pose, ObjectPoseConfig):
            raise HamError(
                f"object_pose = {object_pose!r}; accepted: an ObjectPoseConfig, its dict, or None"
            )
        if object_pose is not None and object_pose.enabled and table is not None:
            raise HamError(
                f"object_pose with table {str(table)!r}: a table records each object at one "
                "pose; accepted: online glances (no table)"
            )
        self.object_pose = object_pose if object_pose is not None and object_pose.enabled else None
        self.source, self.world = make_source(table, world, self.device)
        if self.object_pose is not None:
            self.object_pose.check_world(self.world)
        self.pose_dims: tuple[str, ...] = tuple(self.source.pose_dims)
        self.table = None if table is None else str(table)
        self.normalization = normalization
        self.objects: list[str] = list(self.source.objects)
        self.n_objects = len(self.objects)
        # The image shape follows the sensor: the table's recorded one, or the online world's.
        self.taxels = int(self.source.taxels)
        self.pressure_space = gym.spaces.Box(
            0.0, np.inf if normalization == "none" else 1.0, (self.taxels,) * 2, np.float32
        )

    def glance(self, objects: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """Pressure images ``(B, N, N)`` float32 of ``objects`` ``(B,)`` at ``poses`` ``(B, k)``."""
        return self.glance_height(objects, poses)[0]

    def glance_height(
        self, objects: np.ndarray, poses: np.ndarray, object_pose=None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Pressure images ``(B, N, N)`` and contact heights ``(B,)`` (m), float32, of
        ``objects`` ``(B,)`` at ``poses`` ``(B, k)``; ``object_pose``: per-row ``(yaw, dx, dy)``
        arrays or ``None``."""
        from ham.world.sensor import normalize

        ids = torch.as_tensor(np.asarray(objects, dtype=np.int64), device=self.device)
        q = torch.as_tensor(np.asarray(poses, dtype=np.float32), device=self.device)
        if object_pose is not None:
            object_pose = tuple(
                torch.as_tensor(np.asarray(a, np.float32), device=self.device) for a in object_pose
            )
        with torch.no_grad():
            raw, height = self.source.glance(ids, q, object_pose)
            flat = normalize(raw.to(torch.float32), self.normalization)
        image = flat.reshape(-1, self.taxels, self.taxels).cpu().numpy()
        image = image.astype(np.float32, copy=False)
        if self.normalization != "none":  # unit-norm images lie in [0, 1]; guard rounding
            np.clip(image, 0.0, 1.0, out=image)
        return image, height.to(torch.float32).cpu().numpy()


def as_array(value: Any, what: str, accepted: str, kinds: str) -> np.ndarray:
    """``value`` as a NumPy array of one of the dtype ``kinds`` ("iuf": integers or floats), or a
    :class:`HamError` naming it. A torch tensor is read detached from the CPU or GPU, as an agent
    in PyTorch hands it; a tensor without data (``meta``), a ragged list, text (which NumPy would
    parse), booleans and objects are refused."""
    try:
        if isinstance(value, torch.Tensor):
            if value.is_meta:
                raise TypeError("no data")
            value = value.detach().cpu()
            if value.dtype == torch.bfloat16:  # NumPy has no bfloat16 (autocast agents use it)
                value = value.float()
        a = np.asarray(value)
        if a.dtype.kind not in kinds:
            raise TypeError(a.dtype)
    except (TypeError, ValueError, RuntimeError):
        raise HamError(f"{what} {brief(value)}; accepted: {accepted}") from None
    return a


def check_poses(pose: Any, n: int, k: int = 2) -> np.ndarray:
    """Action poses as ``(n, k)`` float32 clipped to ``[-1, 1]``; NaN or a bad shape: HamError."""
    q = as_array(pose, "pose", f"{n} x {k} numbers in [-1, 1]", "iuf").astype(np.float64)
    if q.size != k * n:
        raise HamError(f"pose of shape {q.shape}; accepted: ({n}, {k}) numbers in [-1, 1]")
    q = q.reshape(n, k)
    if not np.isfinite(q).all():
        raise HamError(
            f"pose {q[~np.isfinite(q).all(1)][0].tolist()} is not finite; accepted: numbers in [-1, 1]"
        )
    return np.clip(q, -1.0, 1.0).astype(np.float32)


def check_object_ids(objects: Any, n: int, n_objects: int) -> np.ndarray:
    """Object ids ``(n,)`` int64 in ``0 .. n_objects-1``, or a :class:`HamError`."""
    accepted = f"{n} integer id(s) in 0..{n_objects - 1}"
    a = as_array(objects, "objects", accepted, "iu")
    if a.size not in (1, n):
        raise HamError(f"objects {brief(objects)}; accepted: {accepted}")
    a = np.broadcast_to(a.reshape(-1).astype(np.int64), (n,)).copy()
    bad = (a < 0) | (a >= n_objects)
    if bad.any():
        raise HamError(f"object id {int(a[bad][0])} out of range; accepted: 0..{n_objects - 1}")
    return a


class GlanceEpisodes:
    """``n`` episodes in lockstep: their objects, the last glance and its pose, and the count."""

    def __init__(self, backend: GlanceBackend, n: int, glances: int, height: bool = False) -> None:
        self.backend = backend
        self.n = n
        self.glances = check_glances(glances)
        self.k = len(backend.pose_dims)
        self.with_height = bool(height)
        self.objects = np.zeros(n, dtype=np.int64)
        self.pose = np.zeros((n, self.k), dtype=np.float32)
        self.height = np.zeros(n, dtype=np.float32)
        self.object_pose = None  # per-episode (yaw, dx, dy) arrays, with backend.object_pose
        self.pressure = np.zeros((n, backend.taxels, backend.taxels), dtype=np.float32)
        self.steps = 0  # steps taken in the current episodes (glances made = min(steps + 1, S))
        self.started = False

    def start(self, rng: np.random.Generator, objects: Any = None) -> None:
        """New episodes: objects uniform (or given), the first glance at a uniform random pose."""
        k = self.backend.n_objects
        if objects is None:
            self.objects = rng.integers(0, k, size=self.n).astype(np.int64)
        else:
            self.objects = check_object_ids(objects, self.n, k)
        self.pose = rng.uniform(-1.0, 1.0, size=(self.n, self.k)).astype(np.float32)
        op = self.backend.object_pose
        if op is not None:
            top = np.array([op.yaw_max, op.offset_max, op.offset_max])
            self.object_pose = tuple(rng.uniform(-1.0, 1.0, size=(3, self.n)) * top[:, None])
        self._glance()
        self.steps = 0
        self.started = True

    def advance(self, pose: Any) -> bool:
        """One step: the next glance at ``pose`` unless the last has been made. True when the
        episodes end with this step (the step that scores the prediction)."""
        if not self.started:
            raise HamError("step() before reset(); call reset() first")
        if self.steps >= self.glances:
            raise HamError("step() after the episode ended; call reset() first")
        q = check_poses(pose, self.n, self.k)
        self.steps += 1
        if self.steps < self.glances:
            self.pose = q
            self._glance()
        return self.steps >= self.glances

    def _glance(self) -> None:
        self.pressure, self.height = self.backend.glance_height(
            self.objects, self.pose, self.object_pose
        )

    def observation(self) -> dict[str, np.ndarray]:
        obs = {"pressure": self.pressure.copy(), "pose": self.pose.copy()}
        if self.with_height:
            obs["height"] = self.height.reshape(self.n, 1).copy()
        return obs

    def info(self) -> dict[str, Any]:
        return {
            "object": self.objects.copy(),
            "glances": np.full(self.n, min(self.steps + 1, self.glances)),
        }

    def render(self) -> np.ndarray:
        """The last pressure images as RGB ``(n, P, P, 3)`` uint8 (each scaled to its max), each
        taxel a ``k x k`` square, ``k = max(1, 128 // N)``: ``P = 128`` for 8, 16, 32 or 64 taxels."""
        p = self.pressure
        scale = max(1, RENDER_SIZE // p.shape[-1])
        top = p.reshape(self.n, -1).max(1).reshape(-1, 1, 1)
        gray = np.where(top > 0, p / np.where(top > 0, top, 1), 0)
        img = (255 * gray).astype(np.uint8).repeat(scale, 1).repeat(scale, 2)
        return np.repeat(img[..., None], 3, axis=-1)


def pose_space(backend: GlanceBackend) -> gym.spaces.Box:
    """The normalized pose ``[-1, 1]^k`` of the backend's pose dims."""
    return gym.spaces.Box(-1.0, 1.0, (len(backend.pose_dims),), np.float32)


def observation_space(backend: GlanceBackend, height: bool = False) -> gym.spaces.Dict:
    spaces = {"pressure": backend.pressure_space, "pose": pose_space(backend)}
    if height:  # the contact height (m): the table at 0, within the pad's reach of the tops
        bound = height_bound(backend.world.sensor)
        spaces["height"] = gym.spaces.Box(-bound, bound, (1,), np.float32)
    return gym.spaces.Dict(spaces)


def _prediction(prediction: Any, n: int, n_objects: int) -> np.ndarray:
    return check_object_ids(prediction, n, n_objects)


def attach_world(
    env,
    n: int,
    glances: int,
    table,
    world,
    normalization: str,
    device: str,
    render_mode,
    height: bool = False,
    object_pose=None,
) -> None:
    """Give ``env`` its glance backend and ``n`` episodes: the setup every env here shares (the
    constructors have checked their arguments' types, :func:`ham.errors.checked_arguments`)."""
    env.render_mode = _check_render_mode(render_mode)
    env.backend = GlanceBackend(table, world, normalization, device, object_pose)
    env.episodes = GlanceEpisodes(env.backend, n, glances, height)
    env.glances = env.episodes.glances
    env.objects = env.backend.objects


class HapticGlanceEnv(gym.Env):
    """``ham/HapticGlance-v0``: identify one haptic object by ``glances`` glances (module doc).

    Args:
        glances: glances per episode ``S`` (3); the first is random, made by ``reset``.
        table: glance table file; ``None``: the fast simulator online.
        world: the online world (``WorldConfig`` or dict; paper defaults).
        normalization: ``l2`` (paper), ``l1`` or ``none`` (raw Pa).
        device: ``cpu`` or ``cuda`` for the glances.
        render_mode: ``None`` or ``rgb_array`` (the last pressure image).
        height: add the glance's contact height (m) to the observation.
        object_pose: a random object pose per episode (online; ``None``: off).

    ``reset(options={"object": ID})`` fixes the object of the episode.
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
        self.observation_space = observation_space(self.backend, height)
        self.action_space = gym.spaces.Dict(
            {
                "pose": pose_space(self.backend),
                "prediction": gym.spaces.Discrete(self.backend.n_objects),
            }
        )

    def _obs(self) -> dict[str, np.ndarray]:
        return {k: v[0] for k, v in self.episodes.observation().items()}

    def _info(self) -> dict[str, Any]:
        obj = int(self.episodes.objects[0])
        return {
            "object": obj,
            "object_name": self.objects[obj],
            "glances": min(self.episodes.steps + 1, self.glances),
        }

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        self.episodes.start(self.np_random, reset_option(options, "object"))
        return self._obs(), self._info()

    def step(
        self, action: dict[str, Any]
    ) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        if not isinstance(action, dict) or set(action) != {"pose", "prediction"}:
            raise HamError(
                f"action {brief(action)}; accepted: a dict with 'pose' ({self.episodes.k} numbers) and "
                "'prediction' (an id)"
            )
        prediction = _prediction(action["prediction"], 1, self.backend.n_objects)[0]
        terminated = self.episodes.advance(action["pose"])
        reward = float(terminated and prediction == self.episodes.objects[0])
        return self._obs(), reward, terminated, False, self._info()

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        return self.episodes.render()[0]


#: Metadata of both vector envs: all episodes end together and reset on the next step.
VECTOR_METADATA = {
    "render_modes": list(RENDER_MODES),
    "render_fps": 2,
    "autoreset_mode": gym.vector.AutoresetMode.NEXT_STEP,
}


def check_num_envs(num_envs) -> int:
    """``num_envs`` as an int >= 1, or a HamError naming it."""
    return check_integer("num_envs", num_envs, 1)


class HapticGlanceVectorEnv(gym.vector.VectorEnv):
    """``num_envs`` episodes of ``ham/HapticGlance-v0`` in lockstep, one batched glance per step.

    Same arguments as :class:`HapticGlanceEnv`. All episodes have ``glances`` steps, so they end
    together; the step after they end resets them all (``NEXT_STEP`` autoreset: it ignores the
    actions and returns the first glances of the new episodes with reward 0).
    ``reset(options={"objects": IDS})`` fixes the objects (e.g. balanced evaluation batches).
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
        self.num_envs = int(num_envs)
        attach_world(
            self, self.num_envs, glances, table, world, normalization, device, render_mode,
            height, object_pose,
        )  # fmt: skip
        self.single_observation_space = observation_space(self.backend, height)
        self.observation_space = gym.vector.utils.batch_space(
            self.single_observation_space, self.num_envs
        )
        self.single_action_space = gym.spaces.Dict(
            {
                "pose": pose_space(self.backend),
                "prediction": gym.spaces.Discrete(self.backend.n_objects),
            }
        )
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, self.num_envs)
        self._autoreset = False

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        self.episodes.start(self.np_random, reset_option(options, "objects"))
        self._autoreset = False
        return self.episodes.observation(), self.episodes.info()

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        n = self.num_envs
        if not isinstance(actions, dict) or set(actions) != {"pose", "prediction"}:
            raise HamError(
                f"actions {brief(actions)}; accepted: a dict with 'pose' ({n}, {self.episodes.k}) and "
                f"'prediction' ({n},)"
            )
        truncated = np.zeros(n, dtype=np.bool_)
        if self._autoreset:
            self.episodes.start(self.np_random)
            self._autoreset = False
            return (
                self.episodes.observation(),
                np.zeros(n),
                np.zeros(n, np.bool_),
                truncated,
                self.episodes.info(),
            )
        prediction = _prediction(actions["prediction"], n, self.backend.n_objects)
        ended = self.episodes.advance(actions["pose"])
        reward = (prediction == self.episodes.objects).astype(np.float64) if ended else np.zeros(n)
        self._autoreset = ended
        return (
            self.episodes.observation(),
            reward,
            np.full(n, ended),
            truncated,
            self.episodes.info(),
        )

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        return self.episodes.render()
