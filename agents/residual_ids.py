"""The registered residual ids: ``ptrack_gym/<Robot>Track-Residual-<Base>-v0``.

:func:`register_residual_envs` registers one id per robot and base controller with
Gymnasium, entry point :func:`residual_env` (a string, so nothing is imported until
``gym.make``) and the plain id's time limit; ``import agents`` calls it. ``import
ptrack_gym`` registers the same ids with the same string entry point (its
``RESIDUAL_BASES``) without importing ``agents``. ``gym.make(id, **options)`` takes the
residual's options (:class:`~agents.residual_spec.ResidualSpec` fields) and the env's
arguments alike.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from agents.registry import CONTROLLER_NAMES
from agents.residual_spec import ResidualSpec, resolve_spec
from agents.residual_wrapper import ResidualWrapper, wrap


def _camel(name: str) -> str:
    return "".join(part.capitalize() for part in name.split("_"))


def residual_env_id(env_id: str, base: str) -> str:
    """``ptrack_gym/<Robot>Track-v0`` + ``computed_torque`` →
    ``ptrack_gym/<Robot>Track-Residual-ComputedTorque-v0``."""
    stem = env_id.removesuffix("-v0")
    return f"{stem}-Residual-{_camel(base)}-v0"


def residual_env(robot: str, base: ResidualSpec | str, **options: Any) -> ResidualWrapper:
    """The entry point of the registered residual ids: a ``TrackingEnv(robot=robot,
    **env_options)`` in a :class:`~agents.residual_wrapper.ResidualWrapper` built by the
    spec of ``base`` (a spec, or the base's name) and the ``options`` that are its fields
    (:func:`~agents.residual_spec.resolve_spec`); ``gym.make`` adds the time limit and its
    checkers.

    Raises:
        InvalidConfigError: an unknown base or a bad option value (unknown env arguments
            raise ``TypeError``, bad values ``ValueError``, as ``TrackingEnv``).
    """
    from ptrack_gym.envs.tracking import TrackingEnv

    spec, env_options = resolve_spec(base, options)
    wrapper = wrap(TrackingEnv(robot=robot, **env_options), spec)
    wrapper.use_registered_spec()
    return wrapper


def register_residual_envs() -> list[str]:
    """Register ``ptrack_gym/<Robot>Track-Residual-<Base>-v0`` for every robot and base
    controller (module docstring) and return the ids."""
    from ptrack_gym.robots import ROBOTS

    ids = []
    for profile in ROBOTS.values():
        plain = gym.spec(profile.env_id)
        for base in CONTROLLER_NAMES:
            env_id = residual_env_id(profile.env_id, base)
            if env_id not in gym.registry:
                gym.register(
                    id=env_id,
                    entry_point="agents.residual_ids:residual_env",
                    kwargs={"robot": profile.name, "base": base},
                    max_episode_steps=plain.max_episode_steps,
                )
            ids.append(env_id)
    return ids
