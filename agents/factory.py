"""One place that builds a default-gain controller for a ptrack_gym environment.

:func:`make_controller` is the only constructor the residual wrapper, the training
script and the benchmarks use, so changing a default (e.g. the passivity gains) happens
here once. Every controller is built from the env's *nominal* model
(``env.unwrapped.model``), never from the simulated body.

Names, controllers (in ``agents``) and their gains:

* ``passivity``: ``passivity.PassivityController``, :func:`passivity_gains`;
* ``computed_torque``: ``computed_torque.ComputedTorqueController``,
  ``gains.default_computed_torque_gains``;
* ``pd_gravity``: ``pd_gravity.PDGravityController``, ``gains.default_pd_gravity_gains``;
* ``slotine_li``: ``slotine_li.SlotineLiController``, ``gains.default_slotine_li_gains``.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable
from typing import Any

import numpy as np

from agents.base import Controller
from agents.computed_torque import ComputedTorqueController
from agents.gains import (
    default_computed_torque_gains,
    default_pd_gravity_gains,
    default_slotine_li_gains,
)
from agents.passivity import PassivityController, PassivityGains
from agents.pd_gravity import PDGravityController
from agents.slotine_li import SlotineLiController
from ptrack_gym.errors import InvalidConfigError

#: The controller names :func:`make_controller` accepts.
CONTROLLER_NAMES: tuple[str, ...] = ("passivity", "computed_torque", "pd_gravity", "slotine_li")

#: Interim passivity gains in physical terms (used only while
#: ``agents.passivity_defaults`` does not exist): K_j = ω² M_jj(q_home) with ω = 20 rad/s,
#: κ = ω_s² M̄_r with ω_s = 10 rad/s, R = ρ M̄_r with ρ = 10 1/s, k_pump = λ / M̄_r with
#: λ = 5 1/s (M̄_r: the mean of M_r(s) over the path, J), the parametrisation of
#: ``bench/passivity_gain_study.py``.
_INTERIM_PASSIVITY = {"omega": 20.0, "omega_s": 10.0, "rho": 10.0, "lam": 5.0}


def _interim_passivity_gains(env: Any) -> PassivityGains:
    """The interim gains of :data:`_INTERIM_PASSIVITY` for ``env``'s robot and path."""
    u = env.unwrapped
    home = np.array(u.robot_spec.home_q_rad)
    inertia = np.diag(u.model.mass_matrix(home))  # (n,) kg·m²
    mean_m_r = float(np.mean([u.tables(s).m_r for s in u.tables.grid_s]))  # J
    g = _INTERIM_PASSIVITY
    return PassivityGains(
        K=tuple(float(g["omega"] ** 2 * m) for m in inertia),
        kappa=g["omega_s"] ** 2 * mean_m_r,
        R=g["rho"] * mean_m_r,
        k_pump=g["lam"] / mean_m_r,
    )


#: How :func:`passivity_gains` fills the parameters of ``default_passivity_gains``, by name.
_DEFAULTS_ARGUMENTS: dict[str, Callable[[Any], Any]] = {
    "robot": lambda env: env.unwrapped.robot_spec.name,
    "robot_name": lambda env: env.unwrapped.robot_spec.name,
    "name": lambda env: env.unwrapped.robot_spec.name,
    "spec": lambda env: env.unwrapped.robot_spec,
    "robot_spec": lambda env: env.unwrapped.robot_spec,
    "model": lambda env: env.unwrapped.model,
    "tables": lambda env: env.unwrapped.tables,
    "path": lambda env: env.unwrapped.path,
    "env": lambda env: env,
}


def passivity_gains(env: Any) -> PassivityGains:
    """Default passivity gains for ``env``'s robot and path.

    ``agents.passivity_defaults.default_passivity_gains`` when that module exists — its
    required parameters are filled by name from ``env`` (robot / robot_name / name: the
    robot's name; spec / robot_spec; model; tables; path; env) — otherwise the interim
    gains of :data:`_INTERIM_PASSIVITY`.

    Raises:
        InvalidConfigError: ``default_passivity_gains`` has a required parameter of
            another name.
    """
    try:
        module = importlib.import_module("agents.passivity_defaults")
    except ModuleNotFoundError as exc:
        if exc.name != "agents.passivity_defaults":
            raise
        return _interim_passivity_gains(env)
    fn = module.default_passivity_gains
    kwargs: dict[str, Any] = {}
    for param in inspect.signature(fn).parameters.values():
        if param.default is not inspect.Parameter.empty or param.kind in (
            inspect.Parameter.VAR_POSITIONAL,
            inspect.Parameter.VAR_KEYWORD,
        ):
            continue
        if param.name not in _DEFAULTS_ARGUMENTS:
            raise InvalidConfigError(
                f"default_passivity_gains needs {param.name!r}; agents.factory knows "
                f"{sorted(_DEFAULTS_ARGUMENTS)}"
            )
        kwargs[param.name] = _DEFAULTS_ARGUMENTS[param.name](env)
    return fn(**kwargs)


def make_controller(name: str, env: Any) -> Controller:
    """A controller ``name`` (one of :data:`CONTROLLER_NAMES`) with its default gains for
    ``env`` (any wrapper of a ``TrackingEnv``).

    Raises:
        InvalidConfigError: (a ``ValueError``) an unknown name.
    """
    if name not in CONTROLLER_NAMES:
        raise InvalidConfigError(f"unknown controller {name!r}; known: {list(CONTROLLER_NAMES)}")
    u = env.unwrapped
    robot = u.robot_spec.name
    if name == "passivity":
        return PassivityController(u.model, u.tables, passivity_gains(env))
    if name == "computed_torque":
        return ComputedTorqueController(u.model, u.path, default_computed_torque_gains(robot))
    if name == "pd_gravity":
        return PDGravityController(u.model, u.path, default_pd_gravity_gains(robot))
    return SlotineLiController(u.model, u.path, default_slotine_li_gains(robot))
