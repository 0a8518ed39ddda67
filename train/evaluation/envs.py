"""Environment building shared by training and evaluation: one disturbance parser, one
``build_env``, and the check of env arguments before anything runs.

Env arguments are validated by the env's own validator,
:class:`ptrack_gym.envs.config.EnvConfig`; nothing here re-checks them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym

import ptrack_gym  # noqa: F401  (registers the envs)
from agents.residual_spec import WRAPPER_DEFAULTS
from ptrack_gym.envs.config import EnvConfig
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots import RobotProfile, profile_for_env_id


def parse_disturbance(text: str | None) -> Any:
    """The env's ``disturbance`` argument from the scripts' syntax: ``"none"`` → None;
    ``"impulse"`` → ``"impulse"``; ``"impulse:0.5"`` → ``("impulse", 0.5)``."""
    if text is None or text == "none":
        return None
    name, sep, level = text.partition(":")
    if not sep:
        return name
    try:
        return (name, float(level))
    except ValueError:
        raise InvalidConfigError(f"disturbance level must be a number: {text!r}") from None


def residual_wrapper_kwargs(config: Mapping[str, Any]) -> dict[str, Any]:
    """The residual wrapper's arguments (``agents.residual_spec.WRAPPER_DEFAULTS``' keys) of a run
    config — a ``TrainConfig`` as a mapping or a run's saved ``config.yml`` section (keys
    a run predates take the wrapper's default). Training and evaluation both build their
    wrapper from this, so a run is evaluated with the authority and gate it trained with
    (unless its ``deploy.yml`` says otherwise)."""
    return {key: config.get(key, default) for key, default in WRAPPER_DEFAULTS.items()}


def trained_wrapper_kwargs(run: Mapping[str, Any]) -> dict[str, Any]:
    """The residual wrapper's arguments of a trained run (its whole ``config.yml``:
    ``config`` and ``derived``): :func:`residual_wrapper_kwargs`, with the base's rates
    the run pinned (``derived.base_rates``: the tuned or default rates it trained over) in
    place of its ``base_gains`` choice — so a shipped residual keeps the base it learned to
    correct when ``agents/tuned`` is retuned or a default changes."""
    kwargs = residual_wrapper_kwargs(run["config"])
    derived = run.get("derived") or {}
    pinned, base = derived.get("base_rates"), run["config"].get("residual", "none")
    if pinned:
        kwargs["base_gains"] = dict(pinned)
    if base not in ("none", "network") and derived.get("robot"):
        _warn_unpinned(derived["robot"], base, kwargs["base_gains"], pinned)
    return kwargs


def _warn_unpinned(robot: str, base: str, gains: Any, pinned: Any) -> None:
    """Warn where a trained residual's base runs rates of today rather than of its training:
    a run without a pin (written before pins), or a pin that leaves rates to the default."""
    import warnings

    from agents.registry import pinned_rates
    from ptrack_gym.robots import robot_profile

    if not pinned:
        warnings.warn(
            f"a residual over {base} on {robot} recorded no rates for its base (a run written "
            f"before pins): its base runs today's {gains} gains, which may not be those it "
            "trained over",
            UserWarning,
            stacklevel=3,
        )
        return
    left = sorted(set(pinned_rates(robot_profile(robot), base, "default")) - set(pinned))
    if left:
        warnings.warn(
            f"a residual over {base} on {robot} pinned only some of its base's rates: {left} "
            "take today's defaults, which may not be those it trained over",
            UserWarning,
            stacklevel=3,
        )


def env_kwargs(
    control_hz: float,
    max_episode_steps: int,
    start: str,
    disturbance: str | None,
    reward_weights: Sequence[float] | None = None,
    extra: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """``gym.make`` keyword arguments of a script's env: the disturbances' horizon (energy
    budgets of sustained torques, onsets) is the episode length; ``extra`` adds further env
    arguments (``reward``, ``max_path_distance_rad``, ...), checked by the env."""
    kwargs: dict[str, Any] = {
        "control_hz": control_hz,
        "start": start,
        "disturbance": parse_disturbance(disturbance),
        "horizon_s": max_episode_steps / control_hz,
        "max_episode_steps": max_episode_steps,
    }
    if reward_weights is not None:
        kwargs["reward_weights"] = tuple(reward_weights)
    kwargs.update(extra or {})
    return kwargs


def check_env_kwargs(env_id: str, kwargs: dict[str, Any]) -> RobotProfile:
    """Validate the arguments ``gym.make(env_id, **kwargs)`` would get, without building
    the env (no simulator is started); returns the robot's profile.

    Raises:
        InvalidConfigError: an unknown env id or a bad argument, naming it.
    """
    profile = profile_for_env_id(env_id)
    steps = kwargs.get("max_episode_steps")
    if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int) or steps < 1):
        raise InvalidConfigError(f"max_episode_steps must be an integer >= 1, got {steps!r}")
    EnvConfig(robot=profile.name, **{k: v for k, v in kwargs.items() if k != "max_episode_steps"})
    return profile


def build_env(
    env_id: str,
    residual: str,
    scale_fraction: float,
    control_hz: float,
    max_episode_steps: int,
    start: str,
    disturbance: str | None,
    reward_weights: Sequence[float] | None = None,
    extra: Mapping[str, Any] | None = None,
    residual_kwargs: Mapping[str, Any] | None = None,
) -> gym.Env[Any, Any]:
    """One training or evaluation env: ``gym.make`` (``residual="none"``) or the residual
    wrapper around the controller ``residual`` (``residual_kwargs``: the wrapper's
    safeguards and base gains, :func:`residual_wrapper_kwargs`); ``extra`` as in
    :func:`env_kwargs`."""
    kwargs = env_kwargs(control_hz, max_episode_steps, start, disturbance, reward_weights, extra)
    if residual == "none":
        return gym.make(env_id, **kwargs)
    from agents.residual import make_residual_env

    return make_residual_env(env_id, residual, scale_fraction, **(residual_kwargs or {}), **kwargs)


def build_decision_env(decision_every: int, *args: Any, **kwargs: Any) -> gym.Env[Any, Any]:
    """``build_env(*args, **kwargs)`` whose actions are held for ``decision_every`` control
    steps when it is > 1 (``agents.hold.ActionRepeat``): the env a run with that decision
    period trains in."""
    env = build_env(*args, **kwargs)
    if decision_every == 1:
        return env
    from agents.hold import ActionRepeat

    return ActionRepeat(env, decision_every)
