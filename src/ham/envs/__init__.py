"""Gymnasium and Active Perception Gym environments over the haptic world.

Importing :mod:`ham.envs` registers (with ``gymnasium.register``, lazy entry points):

* ``ham/HapticGlance-v0``: plain Gymnasium; action ``{"pose", "prediction"}``, reward 1 at the
  end if the prediction is right (:mod:`ham.envs.haptic`);
* ``ham/HapticGlanceAP-v0`` and ``ham/HapticGlanceAP-sparse-v0``: ap_gym active classification
  (:mod:`ham.envs.ap`; making them needs ``ap_gym``);

each with a vector entry point (one batched glance for all sub-environments per step)::

    import gymnasium as gym, ham.envs
    env = gym.make("ham/HapticGlance-v0", glances=10, table="tables/paper.h5")
    envs = gym.make_vec("ham/HapticGlance-v0", num_envs=64)

    import ap_gym
    env = ap_gym.make("ham/HapticGlanceAP-sparse-v0")
    envs = ap_gym.make_vec("ham/HapticGlanceAP-v0", num_envs=64)

Keyword arguments: ``glances`` (3), ``table`` (``None``: the fast simulator online), ``world``,
``normalization`` (``l2``, ``l1``, ``none``), ``device``, ``render_mode``. See docs/gym.md.
"""

from __future__ import annotations

import gymnasium as gym

from ham.envs.haptic import GlanceBackend, GlanceEpisodes, HapticGlanceEnv, HapticGlanceVectorEnv

ENV_ID = "ham/HapticGlance-v0"
AP_ENV_ID = "ham/HapticGlanceAP-v0"
AP_SPARSE_ENV_ID = "ham/HapticGlanceAP-sparse-v0"
ENV_IDS: tuple[str, ...] = (ENV_ID, AP_ENV_ID, AP_SPARSE_ENV_ID)

__all__ = [
    "AP_ENV_ID",
    "AP_SPARSE_ENV_ID",
    "ENV_ID",
    "ENV_IDS",
    "GlanceBackend",
    "GlanceEpisodes",
    "HapticGlanceEnv",
    "HapticGlanceVectorEnv",
    "register_envs",
]


def register_envs() -> None:
    """Register the environments with Gymnasium (again: a no-op)."""
    entries = {
        ENV_ID: ("ham.envs.haptic:HapticGlanceEnv", "ham.envs.haptic:HapticGlanceVectorEnv"),
        AP_ENV_ID: ("ham.envs.ap:make_env", "ham.envs.ap:make_vector_env"),
        AP_SPARSE_ENV_ID: ("ham.envs.ap:make_sparse_env", "ham.envs.ap:make_sparse_vector_env"),
    }
    for env_id, (entry_point, vector_entry_point) in entries.items():
        if env_id in gym.registry:
            continue
        gym.register(
            id=env_id,
            entry_point=entry_point,
            vector_entry_point=vector_entry_point,
            nondeterministic=False,
        )


register_envs()
