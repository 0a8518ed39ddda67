"""Robots: specs (data), the simulated arm is built by :mod:`ptrack_gym.sim`, and models.

``ROBOTS`` maps a robot name to the function that builds its :class:`RobotSpec`.
"""

from __future__ import annotations

from collections.abc import Callable

from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots.iiwa import iiwa
from ptrack_gym.robots.model import BulletModel, RobotModel
from ptrack_gym.robots.panda import panda
from ptrack_gym.robots.spec import RobotSpec
from ptrack_gym.robots.two_link import TwoLinkAnalyticModel, TwoLinkParams, two_link

ROBOTS: dict[str, Callable[[], RobotSpec]] = {"two_link": two_link, "iiwa": iiwa, "panda": panda}


def make_robot(name: str) -> RobotSpec:
    """The spec of the robot called ``name`` (one of ``ROBOTS``)."""
    try:
        return ROBOTS[name]()
    except KeyError:
        raise InvalidConfigError(f"unknown robot {name!r}; known: {sorted(ROBOTS)}") from None


__all__ = [
    "ROBOTS",
    "BulletModel",
    "RobotModel",
    "RobotSpec",
    "TwoLinkAnalyticModel",
    "TwoLinkParams",
    "iiwa",
    "make_robot",
    "panda",
    "two_link",
]
