"""ptrack_gym: a benchmark of trajectory-tracking controllers for torque-controlled arms.

``import ptrack_gym`` registers one environment per robot of
:data:`ptrack_gym.robots.ROBOTS` with Gymnasium (string entry points, so the simulator is
not touched until ``gym.make``); :data:`ENV_IDS` lists them::

    import gymnasium as gym
    import ptrack_gym

    env = gym.make("ptrack_gym/IiwaTrack-v0")
"""

from __future__ import annotations

import gymnasium

from ptrack_gym.robots import ROBOTS

__version__ = "0.2.0"

#: Default episode length (s) at the default control rate of 1 kHz.
EPISODE_S = 10.0
DEFAULT_CONTROL_HZ = 1000.0

ENV_IDS: list[str] = []
for _profile in ROBOTS.values():
    if _profile.env_id not in gymnasium.registry:
        gymnasium.register(
            id=_profile.env_id,
            entry_point="ptrack_gym.envs.tracking:TrackingEnv",
            kwargs={"robot": _profile.name},
            max_episode_steps=int(EPISODE_S * DEFAULT_CONTROL_HZ),
        )
    ENV_IDS.append(_profile.env_id)

__all__ = ["DEFAULT_CONTROL_HZ", "ENV_IDS", "EPISODE_S", "__version__"]
