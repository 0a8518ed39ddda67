"""ptrack_gym: a benchmark of trajectory-tracking controllers for torque-controlled arms.

``import ptrack_gym`` registers the environments listed in :data:`ENV_IDS` with
Gymnasium (string entry points, so nothing heavy is imported until ``gym.make``)::

    import gymnasium as gym
    import ptrack_gym

    env = gym.make("ptrack_gym/IiwaTrack-v0")
"""

from __future__ import annotations

import gymnasium

__version__ = "0.1.0"

#: Default episode length (s) at the default control rate of 1 kHz.
EPISODE_S = 10.0
DEFAULT_CONTROL_HZ = 1000.0

_ROBOTS = {"TwoLink": "two_link", "Iiwa": "iiwa", "Panda": "panda"}

ENV_IDS: list[str] = []
for _name, _robot in _ROBOTS.items():
    _env_id = f"ptrack_gym/{_name}Track-v0"
    if _env_id not in gymnasium.registry:
        gymnasium.register(
            id=_env_id,
            entry_point="ptrack_gym.envs.tracking:TrackingEnv",
            kwargs={"robot": _robot},
            max_episode_steps=int(EPISODE_S * DEFAULT_CONTROL_HZ),
        )
    ENV_IDS.append(_env_id)

__all__ = ["DEFAULT_CONTROL_HZ", "ENV_IDS", "EPISODE_S", "__version__"]
