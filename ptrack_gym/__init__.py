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

from ptrack_gym.robots import ROBOTS, preview_env_id

__version__ = "0.4.0"

#: Default episode length (s) at the default control rate of 1 kHz.
EPISODE_S = 10.0
DEFAULT_CONTROL_HZ = 1000.0

ENV_IDS: list[str] = []
#: The preview ids ``ptrack_gym/<Robot>TrackPreview-v0``: the ``-v0`` env with a preview of
#: the reference ahead in its observation (:mod:`ptrack_gym.envs.preview`).
PREVIEW_ENV_IDS: list[str] = []
for _profile in ROBOTS.values():
    if _profile.env_id not in gymnasium.registry:
        gymnasium.register(
            id=_profile.env_id,
            entry_point="ptrack_gym.envs.tracking:TrackingEnv",
            kwargs={"robot": _profile.name},
            max_episode_steps=int(EPISODE_S * DEFAULT_CONTROL_HZ),
        )
    ENV_IDS.append(_profile.env_id)
    _preview = preview_env_id(_profile.env_id)
    if _preview not in gymnasium.registry:
        gymnasium.register(
            id=_preview,
            entry_point="ptrack_gym.envs.preview:make_preview_env",
            kwargs={"robot": _profile.name},
            max_episode_steps=int(EPISODE_S * DEFAULT_CONTROL_HZ),
        )
    PREVIEW_ENV_IDS.append(_preview)

#: The base controllers of the residual-RL ids ``ptrack_gym/<Robot>Track-Residual-<Base>-v0``
#: (``agents.registry.CONTROLLER_NAMES``: tests/test_zoo.py keeps the two equal). Registered
#: here with a string entry point, so ``gym.make`` of a residual id works after ``import
#: ptrack_gym`` alone: ``agents`` is imported only when such an env is built.
RESIDUAL_BASES = (
    "passivity",
    "passivity_paper",
    "computed_torque",
    "pd_gravity",
    "slotine_li",
    "pid_gravity",
    "computed_torque_observer",
    "adaptive_slotine_li",
    "computed_torque_path",
)
for _profile in ROBOTS.values():
    for _base in RESIDUAL_BASES:
        _camel = "".join(part.capitalize() for part in _base.split("_"))
        _id = f"{_profile.env_id.removesuffix('-v0')}-Residual-{_camel}-v0"
        if _id not in gymnasium.registry:
            gymnasium.register(
                id=_id,
                entry_point="agents.residual_ids:residual_env",
                kwargs={"robot": _profile.name, "base": _base},
                max_episode_steps=int(EPISODE_S * DEFAULT_CONTROL_HZ),
            )

__all__ = ["DEFAULT_CONTROL_HZ", "ENV_IDS", "EPISODE_S", "PREVIEW_ENV_IDS", "__version__"]
