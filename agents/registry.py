"""The registry of controller builders: one entry per controller name.

Adding a controller is one file (a class with the :class:`~agents.base.Controller`
interface and a ``build(ctx, gains=None)`` function that fills in default gains) and one
entry in :data:`CONTROLLERS` and one in :data:`RATE_MODULES` (the module stating its
default, tunable and bandwidth rates).
:func:`make_controller` is the one constructor the residual wrapper, the evaluation and
training scripts and the benchmarks use. Every controller is built from the env's
*nominal* model (``env.unwrapped.model``), never from the simulated body.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from types import ModuleType
from typing import Any

import yaml

from agents import computed_torque, passivity, pd_gravity, slotine_li
from agents.base import ControlContext, Controller
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots.profile import RobotProfile

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

#: name → the module that states the controller's rates (``NAME``, the profile key of its
#: rates; ``DEFAULT_RATES``; ``TUNABLE``; ``BANDWIDTHS``).
RATE_MODULES: dict[str, ModuleType] = {
    "passivity": passivity,
    "passivity_paper": passivity,
    "computed_torque": computed_torque,
    "pd_gravity": pd_gravity,
    "slotine_li": slotine_li,
}

#: name → the rates ``python -m train.tune`` searches, rate → (low, high, log scale).
TUNABLE: dict[str, dict[str, tuple[float, float, bool]]] = {
    name: module.TUNABLE for name, module in RATE_MODULES.items()
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


def effective_rates(profile: RobotProfile, name: str, gains: Any = "default") -> dict[str, Any]:
    """Every rate ``name`` uses on the robot of ``profile`` with ``gains`` ("default",
    "tuned" or a mapping of rates): its generic defaults, updated by the profile's, updated
    by the tuned or given ones — what :func:`make_controller` makes absolute."""
    module = RATE_MODULES[name]
    rates = {**module.DEFAULT_RATES, **profile.controller_gains.get(module.NAME, {})}
    if isinstance(gains, str):
        if gains not in GAIN_CHOICES:
            raise InvalidConfigError(f"gains must be one of {GAIN_CHOICES}, got {gains!r}")
        if gains == "tuned":
            rates.update(tuned_rates(profile.name, name))
    elif isinstance(gains, Mapping):
        rates.update(gains)
    return rates


def scaled_rates(profile: RobotProfile, name: str, gains: Any, scale: float) -> dict[str, Any]:
    """:func:`effective_rates` with the controller's bandwidths (``BANDWIDTHS``) × ``scale``:
    one knob from soft to stiff, the other rates (damping ratios, …) kept."""
    if not (isinstance(scale, (int, float)) and scale > 0 and scale < float("inf")):
        raise InvalidConfigError(f"a gain scale must be a positive number, got {scale!r}")
    rates = effective_rates(profile, name, gains)
    return {**rates, **{k: rates[k] * scale for k in RATE_MODULES[name].BANDWIDTHS}}


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
