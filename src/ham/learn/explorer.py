"""A trained HAM driven one glance at a time by glances from outside: a robot's pad, another
simulator, recorded data.

The agent's own loop (:meth:`ham.model.agent.HapticAttentionModel.forward`) asks an environment
for each glance. A robot does not fit that loop: it moves, presses, reads its pad and then asks
where to go next. :class:`Explorer` turns the loop inside out::

    explorer = Explorer.from_run("runs/demo/ham")  # make demo's run
    q = explorer.reset()                       # the first pose, normalized: q in [-1, 1]^k
    while q is not None:
        image = my_pad_glance(q)               # (16, 16) pressures (Pa) at pose q
        q = explorer.observe(image)            # the next pose, or None after the last glance
    explorer.prediction, explorer.probabilities

Each glance goes through the same steps as in training and evaluation (the run's normalization,
the tactile network, the core, the classifier; the location policy's mean pose or a sample), so
glances from the run's own table give :func:`ham.learn.evaluation.evaluate`'s episodes exactly
(tests/test_explorer.py). ``q`` is the agent's action, as in the Gymnasium envs: the metric pose
is ``x = q_x`` times half the object's width (4.5 cm for the paper's blocks), ``phi = q_phi *
phi_max`` (the world's :class:`ham.world.glance.PoseConfig`; docs/world.md).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from ham.errors import HamError, brief, check_integer, checked_arguments
from ham.learn.evaluation import EVAL_POLICIES
from ham.model.agent import HapticAttentionModel
from ham.world.sensor import check_normalization, normalize


class Explorer:
    """``episodes`` episodes of a trained :class:`HapticAttentionModel`, one glance at a time.

    Args:
        agent: the trained model (``Run.agent``; :meth:`from_run` loads a run folder).
        normalization: the images' normalization, the run's (``l2``, the paper; ``l1``; ``none``).
        episodes: episodes explored side by side (a batch: one image each per glance).
        policy: ``mean`` (the location policy's mean pose, as evaluation) or ``sample``.
        seed: seeds the first poses (uniform, the paper's) and any sampled pose: the same seed
            gives the same poses for the same glances.
        objects: the classes' names (``Run.objects``), for :attr:`object_names`.
    """

    @checked_arguments
    def __init__(
        self,
        agent: HapticAttentionModel,
        normalization: str = "l2",
        *,
        episodes: int = 1,
        policy: str = "mean",
        seed: int = 0,
        objects: list | None = None,
    ) -> None:
        if not isinstance(agent, HapticAttentionModel):
            raise HamError(f"agent = {brief(agent)}; accepted: a HapticAttentionModel")
        check_normalization(normalization)
        if policy not in EVAL_POLICIES:
            raise HamError(f"policy {policy!r}; accepted: {', '.join(EVAL_POLICIES)}")
        self.episodes = check_integer("episodes", episodes, 1)
        self.seed = check_integer("seed", seed, 0)
        n = agent.config.n_objects
        if objects is not None and len(objects) != n:
            raise HamError(f"objects {brief(objects)}: {len(objects)} names for {n} classes; "
                           f"accepted: {n} names, in class order")  # fmt: skip
        self.agent = agent.eval()
        self.normalization = normalization
        self.greedy = policy == "mean"
        self.objects = (
            [str(o) for o in objects] if objects is not None else list(map(str, range(n)))
        )
        self.device = next(agent.parameters()).device
        self.taxels = int(round(agent.config.pressure_dim**0.5))
        self.generator = torch.Generator(device=self.device).manual_seed(self.seed)
        self.glances = 0
        self._pose: torch.Tensor | None = None
        self._logits: torch.Tensor | None = None
        self._stop_logit: torch.Tensor | None = None

    @classmethod
    @checked_arguments
    def from_run(
        cls,
        run: str | os.PathLike,
        *,
        episodes: int = 1,
        policy: str | None = None,
        seed: int = 0,
        device: str | None = None,
    ) -> Explorer:
        """The agent of run folder ``run`` (its latest checkpoint), with the run's normalization,
        objects and evaluation policy (``policy`` overrides it)."""
        from ham.learn.train import load_run, read_run_config

        env = read_run_config(Path(run)).env  # refused before its world is loaded
        if env is not None:
            raise HamError(
                f"run {str(run)!r} trained on ap_gym env {env.env!r}; accepted: a run in the "
                "haptic world (an ap_gym glimpse is prepared by its adapter)"
            )
        loaded = load_run(Path(run), device=device)
        loaded.close()
        return cls(loaded.agent, loaded.config.normalization, episodes=episodes,
                   policy=policy or loaded.config.eval_policy, seed=seed,
                   objects=list(loaded.objects))  # fmt: skip

    # ------------------------------------------------------------------ the episode
    @torch.no_grad()
    def reset(self) -> torch.Tensor:
        """Start ``episodes`` new episodes: their first poses ``(episodes, k)``."""
        a = self.agent
        q, _, _ = a.initial_pose(self.episodes, self.device, self.generator, self.greedy)
        self._state = a.core.initial_state(self.episodes, q)
        self._heads_state = a.initial_heads_state(self.episodes, q)
        self._pose, self._logits, self._stop_logit, self.glances = q, None, None, 0
        return q.clone()

    @torch.no_grad()
    @checked_arguments
    def observe(
        self,
        pressure: torch.Tensor | np.ndarray,
        height: torch.Tensor | np.ndarray | float | None = None,
        pose: torch.Tensor | np.ndarray | None = None,
    ) -> torch.Tensor | None:
        """Read the glance at the pose asked for: ``pressure`` the raw images ``(episodes, N,
        N)`` in Pa (``(N, N)`` for one episode), ``height`` the contact heights (m; for a model
        that reads them), ``pose`` where the glances were made if not where asked (a robot that
        missed its pose; the location network reads it as the pose). Returns the next poses
        ``(episodes, k)``, or ``None`` after the episode's last glance."""
        a = self.agent
        if self._pose is None or self.glances >= a.config.glances:
            raise HamError(
                f"observe after {self.glances} of {a.config.glances} glances; accepted: "
                "reset() first, then one observe per pose it returns"
            )
        p = normalize(self._images(pressure), self.normalization)
        h = self._heights(height)
        where = self._pose if pose is None else self._poses(pose)
        tau, tau_policy, logits, _, self._state, self._heads_state = a.read(
            p, where, h, self._state, self._heads_state
        )
        self._logits = logits
        if a.config.stop:
            self._stop_logit = a.stop_logit(tau, logits)
        self.glances += 1
        if self.glances == a.config.glances:
            self._pose = None
            return None
        dist = a.next_distribution(tau_policy, self._pose, logits, self.glances, where)
        self._pose = a.act(dist, self.generator, self.greedy, self.episodes)
        return self._pose.clone()

    # ------------------------------------------------------------------ what it knows
    @property
    def probabilities(self) -> torch.Tensor:
        """The classifier's probabilities of the objects ``(episodes, K)`` after the last glance
        read."""
        return torch.softmax(self._read_logits(), -1)

    @property
    def prediction(self) -> torch.Tensor:
        """The most probable object of each episode ``(episodes,)``."""
        return self._read_logits().argmax(-1)

    @property
    def object_names(self) -> list[str]:
        """The names of :attr:`prediction`."""
        return [self.objects[i] for i in self.prediction.tolist()]

    @property
    def stop_probability(self) -> torch.Tensor | None:
        """With a learned stop (``--stop``): its probability of stopping now ``(episodes,)``
        (evaluation stops at > 1/2); ``None`` without one."""
        if not self.agent.config.stop:
            return None
        self._read_logits()
        return torch.sigmoid(self._stop_logit)

    @property
    def done(self) -> bool:
        """Whether the episodes have had all their glances."""
        return self.glances == self.agent.config.glances

    # ------------------------------------------------------------------ checks
    def _read_logits(self) -> torch.Tensor:
        if self._logits is None:
            raise HamError("no glance read yet; accepted: reset(), then observe(image) first")
        return self._logits

    def _tensor(self, what: str, value) -> torch.Tensor:
        try:
            t = torch.as_tensor(value, dtype=torch.float32, device=self.device)
        except (TypeError, ValueError, RuntimeError):
            raise HamError(
                f"{what} {brief(value)}; accepted: numbers (a tensor or an array)"
            ) from None
        if not torch.isfinite(t).all():
            raise HamError(f"{what} {brief(value)}; accepted: finite numbers")
        return t

    def _images(self, pressure) -> torch.Tensor:
        t = self._tensor("pressure", pressure)
        n, e = self.taxels, self.episodes
        if t.shape == (n, n) and e == 1:
            t = t.unsqueeze(0)
        if t.shape != (e, n, n):
            raise HamError(f"pressure of shape {tuple(t.shape)}; accepted: ({e}, {n}, {n}) "
                           "images (Pa), one per episode")  # fmt: skip
        if (t < 0).any():
            raise HamError(f"pressure {brief(pressure)}; accepted: pressures >= 0 (Pa)")
        return t

    def _heights(self, height) -> torch.Tensor | None:
        if not self.agent.config.height_input:
            if height is not None:
                raise HamError("height given to a model that does not read it; accepted: None")
            return None
        if height is None:
            raise HamError(
                "the model reads the contact height; accepted: observe(image, height=H) (m)"
            )
        t = self._tensor("height", height).reshape(-1)
        if t.shape != (self.episodes,):
            raise HamError(f"height {brief(height)}; accepted: {self.episodes} heights (m)")
        return t

    def _poses(self, pose) -> torch.Tensor:
        t = self._tensor("pose", pose)
        k = len(self.agent.config.pose_dims)
        if t.shape == (k,) and self.episodes == 1:
            t = t.unsqueeze(0)
        if t.shape != (self.episodes, k) or (t.abs() > 1).any():
            raise HamError(f"pose {brief(pose)}; accepted: ({self.episodes}, {k}) normalized "
                           "poses in [-1, 1]")  # fmt: skip
        return t
