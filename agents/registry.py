"""The registry of controller builders: one entry per controller name.

Adding a controller is one file (a class with the :class:`~agents.base.Controller`
interface and a ``build(ctx, gains=None)`` function that fills in default gains) and one
entry in :data:`CONTROLLERS` (and in :data:`TUNABLE` if its rates are to be tuned).
:func:`make_controller` is the one constructor the residual wrapper, the evaluation and
training scripts and the benchmarks use. Every controller is built from the env's
*nominal* model (``env.unwrapped.model``), never from the simulated body.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from agents import computed_torque, passivity, pd_gravity, slotine_li
from agents.base import ControlContext, Controller
from ptrack_gym.errors import InvalidConfigError

#: name → builder(ctx, gains=None) of every controller.
CONTROLLERS: dict[str, Callable[..., Controller]] = {
    "passivity": passivity.build,
    "passivity_paper": passivity.build_paper,
    "computed_torque": computed_torque.build,
    "pd_gravity": pd_gravity.build,
    "slotine_li": slotine_li.build,
}

#: The controller names :func:`make_controller` accepts.
CONTROLLER_NAMES: tuple[str, ...] = tuple(CONTROLLERS)

#: name → the rates ``python -m train.tune`` searches, rate → (low, high, log scale).
TUNABLE: dict[str, dict[str, tuple[float, float, bool]]] = {
    "passivity": passivity.TUNABLE,
    "passivity_paper": passivity.TUNABLE,
    "computed_torque": computed_torque.TUNABLE,
    "pd_gravity": pd_gravity.TUNABLE,
    "slotine_li": slotine_li.TUNABLE,
}


#: Where tuned gains live: ``<robot>-<controller>.yml`` (written by ``python -m train.tune``).
TUNED_DIR = Path(__file__).resolve().parent / "tuned"

#: The named gain choices of every entry point.
GAIN_CHOICES: tuple[str, ...] = ("default", "tuned")


def tuned_rates(robot: str, controller: str) -> dict[str, Any]:
    """The tuned rates of ``controller`` on ``robot`` (``agents/tuned/<robot>-<controller>.yml``).

    Raises:
        InvalidConfigError: no tuned gains for that pair (the message lists those there are).
    """
    path = TUNED_DIR / f"{robot}-{controller}.yml"
    if not path.exists():
        have = sorted(p.stem for p in TUNED_DIR.glob("*.yml"))
        raise InvalidConfigError(f"no tuned gains for {controller} on {robot}; tuned: {have}")
    return dict(yaml.safe_load(path.read_text())["rates"])


def make_controller(name: str, env: Any, gains: Any = None) -> Controller:
    """The controller ``name`` (one of :data:`CONTROLLER_NAMES`) for ``env`` (any wrapper
    of a ``TrackingEnv``) with ``gains``: None or ``"default"`` — the robot's default gains
    at the env's control rate; ``"tuned"`` — the rates found by ``python -m train.tune``
    (:func:`tuned_rates`); a mapping of rates; or the controller's gains dataclass.

    Raises:
        InvalidConfigError: (a ``ValueError``) an unknown name or gain choice.
    """
    try:
        builder = CONTROLLERS[name]
    except KeyError:
        raise InvalidConfigError(
            f"unknown controller {name!r}; known: {list(CONTROLLER_NAMES)}"
        ) from None
    if isinstance(gains, str):
        if gains not in GAIN_CHOICES:
            raise InvalidConfigError(f"gains must be one of {GAIN_CHOICES}, got {gains!r}")
        robot = env.unwrapped.robot_profile.name
        gains = None if gains == "default" else tuned_rates(robot, name)
    return builder(ControlContext.from_env(env), gains)
