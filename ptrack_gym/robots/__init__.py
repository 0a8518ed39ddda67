"""Robots: one file per robot (``<name>.py`` defines ``PROFILE``), and the dynamics models.

Adding a robot is one file in this package and one name in :data:`ROBOT_MODULES`: the
env id ``ptrack_gym/<env_name>Track-v0`` is registered from it, and every test battery
that loops over :data:`ROBOTS` runs on it.
"""

from __future__ import annotations

import importlib

from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots.model import BulletModel, PinocchioModel, RobotModel, home_inertia_kgm2
from ptrack_gym.robots.profile import DisturbanceScales, EECircle, RobotProfile

#: The robot files of this package, in registration order.
ROBOT_MODULES: tuple[str, ...] = ("two_link", "iiwa", "panda", "xarm6")

#: name → profile of every registered robot.
ROBOTS: dict[str, RobotProfile] = {
    (profile := importlib.import_module(f"ptrack_gym.robots.{module}").PROFILE).name: profile
    for module in ROBOT_MODULES
}


def robot_profile(name: str) -> RobotProfile:
    """The profile of the robot called ``name`` (a key of :data:`ROBOTS`)."""
    try:
        return ROBOTS[name]
    except KeyError:
        raise InvalidConfigError(f"unknown robot {name!r}; known: {sorted(ROBOTS)}") from None


#: How a preview id ends: ``ptrack_gym/<Robot>TrackPreview-v0``. A name of its own, not a
#: ``-v1`` of the plain id: Gymnasium reads a higher version as the newer revision of the
#: same env and told everyone making a ``-v0`` to "upgrade" to it.
PREVIEW_SUFFIX = "Preview-v0"


def preview_env_id(env_id: str) -> str:
    """The preview id (the observation with a preview of the reference ahead,
    :mod:`ptrack_gym.envs.preview`) of a robot's plain ``-v0`` id."""
    return env_id.removesuffix("-v0") + PREVIEW_SUFFIX


def is_preview_env_id(env_id: str) -> bool:
    """Whether ``env_id`` is a preview id (``ptrack_gym/<Robot>TrackPreview-v0``)."""
    return env_id.endswith(PREVIEW_SUFFIX)


def plain_env_id(env_id: str) -> str:
    """The plain ``-v0`` id of a preview id (the same robot, task and dynamics); any other
    id unchanged."""
    if is_preview_env_id(env_id):
        return env_id.removesuffix(PREVIEW_SUFFIX) + "-v0"
    return env_id


def profile_for_env_id(env_id: str) -> RobotProfile:
    """The profile of the robot whose env id is ``env_id`` (its ``-v0`` id or its preview
    id: the same robot, task and dynamics)."""
    for profile in ROBOTS.values():
        if env_id in (profile.env_id, preview_env_id(profile.env_id)):
            return profile
    known = sorted(i for p in ROBOTS.values() for i in (p.env_id, preview_env_id(p.env_id)))
    raise InvalidConfigError(f"unknown env id {env_id!r}; known: {known}")


__all__ = [
    "ROBOTS",
    "ROBOT_MODULES",
    "BulletModel",
    "DisturbanceScales",
    "EECircle",
    "PinocchioModel",
    "RobotModel",
    "RobotProfile",
    "home_inertia_kgm2",
    "is_preview_env_id",
    "plain_env_id",
    "preview_env_id",
    "profile_for_env_id",
    "robot_profile",
]
