"""The registry of controller builders: one entry per controller name.

Adding a controller is one file (a class with the :class:`~agents.base.Controller`
interface and a ``build(ctx, gains=None)`` function that fills in default gains) and one
entry in :data:`CONTROLLERS`. :func:`make_controller` is the one constructor the residual
wrapper, the evaluation and training scripts and the benchmarks use. Every controller is
built from the env's *nominal* model (``env.unwrapped.model``), never from the simulated
body.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from agents import computed_torque, passivity, pd_gravity, slotine_li
from agents.base import ControlContext, Controller
from ptrack_gym.errors import InvalidConfigError

#: name → builder(ctx, gains=None) of every controller.
CONTROLLERS: dict[str, Callable[..., Controller]] = {
    "passivity": passivity.build,
    "computed_torque": computed_torque.build,
    "pd_gravity": pd_gravity.build,
    "slotine_li": slotine_li.build,
}

#: The controller names :func:`make_controller` accepts.
CONTROLLER_NAMES: tuple[str, ...] = tuple(CONTROLLERS)


def make_controller(name: str, env: Any, gains: Any = None) -> Controller:
    """The controller ``name`` (one of :data:`CONTROLLER_NAMES`) for ``env`` (any wrapper
    of a ``TrackingEnv``), with ``gains`` (its gains dataclass) or, by default, the robot's
    default gains at the env's control rate.

    Raises:
        InvalidConfigError: (a ``ValueError``) an unknown name.
    """
    try:
        builder = CONTROLLERS[name]
    except KeyError:
        raise InvalidConfigError(
            f"unknown controller {name!r}; known: {list(CONTROLLER_NAMES)}"
        ) from None
    return builder(ControlContext.from_env(env), gains)
