"""The tracking env's arguments and their validation — the one place they are checked.

:class:`EnvConfig` is what ``TrackingEnv(**kwargs)`` validates its arguments with; the
training and evaluation scripts build one (``EnvConfig(**kwargs)``) to reject a bad
argument before any simulator or worker is started, instead of re-checking it themselves.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from ptrack_gym.disturbances import Disturbance, DisturbanceSpec, build_disturbances
from ptrack_gym.disturbances.base import check_sizing
from ptrack_gym.envs.rewards import (
    DEFAULT_EFFORT_SCALE,
    DEFAULT_KERNEL_SCALES_RAD,
    DEFAULT_KERNEL_WEIGHTS,
    REWARD_MODES,
)
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.paths import PATH_FAMILIES, ReferencePath
from ptrack_gym.robots import RobotProfile, robot_profile

#: ``start`` values: at the path point q_r(s₀) moving at q_r'(s₀), or at rest near it.
START_MODES: tuple[str, ...] = ("on_path", "rest_near_path")
RENDER_MODES: tuple[str, ...] = ("rgb_array",)


def _real(value: Any, name: str, *, positive: bool = False) -> float:
    """``value`` as a float if it is a real, finite number (not a bool) of the required
    sign; otherwise :class:`InvalidConfigError` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InvalidConfigError(f"{name} must be a real number, got {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise InvalidConfigError(f"{name} must be finite, got {value!r}")
    if x < 0 or (positive and x == 0):
        sign = "> 0" if positive else ">= 0"
        raise InvalidConfigError(f"{name} must be {sign}, got {value!r}")
    return x


def _reals(
    values: Any, name: str, *, size: int | None = None, positive: bool = False
) -> tuple[float, ...]:
    """``values`` as a tuple of floats (each checked by :func:`_real`), of ``size`` entries
    when given, at least one otherwise; :class:`InvalidConfigError` naming ``name``."""
    if isinstance(values, (str, bytes)) or not isinstance(values, Sequence):
        raise InvalidConfigError(f"{name} must be a sequence of numbers, got {values!r}")
    if (size is not None and len(values) != size) or len(values) == 0:
        want = f"{size} numbers" if size is not None else "at least one number"
        raise InvalidConfigError(f"{name} must be {want}, got {values!r}")
    return tuple(_real(v, f"{name}[{i}]", positive=positive) for i, v in enumerate(values))


@dataclass(frozen=True)
class EnvConfig:
    """The arguments of :class:`~ptrack_gym.envs.tracking.TrackingEnv` (see its docstring),
    validated on construction. ``disturbances`` and ``profile`` are derived."""

    robot: str = "two_link"
    path: str | ReferencePath = "default"
    path_seed: int | None = None
    physics_hz: float = 1000.0
    control_hz: float = 1000.0
    start: str = "on_path"
    start_noise_rad: float = 0.0
    start_offset_rad: float = 0.1
    reward_weights: tuple[float, float, float] = (10.0, 1.0, 0.01)
    unstable_penalty: float = 100.0
    reward: str = "quadratic"
    kernel_weights: tuple[float, float, float] = DEFAULT_KERNEL_WEIGHTS
    kernel_scales_rad: tuple[float, ...] = DEFAULT_KERNEL_SCALES_RAD
    kernel_effort_scale: float = DEFAULT_EFFORT_SCALE
    max_path_distance_rad: float | None = None
    disturbance: DisturbanceSpec | Sequence[DisturbanceSpec] | None = None
    disturbance_sizing: str = "home"
    horizon_s: float = 10.0
    info_energy: bool = False
    render_mode: str | None = None
    gui: bool = False
    path_seeds: tuple[int, ...] | None = None
    disturbance_choices: tuple[Any, ...] | None = None
    profile: RobotProfile = field(init=False, repr=False)
    disturbances: list[Disturbance] = field(init=False, repr=False)
    choices: list[list[Disturbance]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "profile", robot_profile(self.robot))
        physics = _real(self.physics_hz, "physics_hz", positive=True)
        control = _real(self.control_hz, "control_hz", positive=True)
        ratio = physics / control
        if not (math.isfinite(ratio) and ratio >= 1.0 and abs(ratio - round(ratio)) < 1e-9):
            raise InvalidConfigError(
                f"physics_hz ({self.physics_hz}) must be a positive integer multiple of "
                f"control_hz ({self.control_hz})"
            )
        set_(self, "physics_hz", physics)
        set_(self, "control_hz", control)
        if isinstance(self.path, str):
            if self.path not in PATH_FAMILIES:
                raise InvalidConfigError(
                    f"path must be one of {PATH_FAMILIES} or a ReferencePath, got {self.path!r}"
                )
        elif not isinstance(self.path, ReferencePath):
            raise InvalidConfigError(f"path must be a name or a ReferencePath, got {self.path!r}")
        elif self.path.n != self.profile.n:
            raise InvalidConfigError(
                f"path has {self.path.n} joints, robot {self.robot} has {self.profile.n}"
            )
        if self.path_seed is not None and (
            isinstance(self.path_seed, bool) or not isinstance(self.path_seed, numbers.Integral)
        ):
            raise InvalidConfigError(
                f"path_seed must be an integer or None, got {self.path_seed!r}"
            )
        if self.path_seeds is not None:
            seeds = tuple(self.path_seeds) if isinstance(self.path_seeds, (list, tuple)) else ()
            if (
                not seeds
                or len(set(seeds)) != len(seeds)
                or any(isinstance(k, bool) or not isinstance(k, numbers.Integral) for k in seeds)
            ):
                raise InvalidConfigError(
                    f"path_seeds must be distinct integers, at least one, got {self.path_seeds!r}"
                )
            if self.path != "random" or self.path_seed is not None:
                raise InvalidConfigError(
                    "path_seeds is a pool of random paths: give path='random' and no path_seed"
                )
            set_(self, "path_seeds", tuple(int(k) for k in seeds))
        if self.start not in START_MODES:
            raise InvalidConfigError(f"start must be one of {START_MODES}, got {self.start!r}")
        set_(self, "start_noise_rad", _real(self.start_noise_rad, "start_noise_rad"))
        set_(self, "start_offset_rad", _real(self.start_offset_rad, "start_offset_rad"))
        set_(self, "reward_weights", _reals(self.reward_weights, "reward_weights", size=3))
        set_(self, "unstable_penalty", _real(self.unstable_penalty, "unstable_penalty"))
        if self.reward not in REWARD_MODES:
            raise InvalidConfigError(f"reward must be one of {REWARD_MODES}, got {self.reward!r}")
        set_(self, "kernel_weights", _reals(self.kernel_weights, "kernel_weights", size=3))
        if sum(self.kernel_weights) <= 0:
            raise InvalidConfigError(f"kernel_weights must not all be 0, got {self.kernel_weights}")
        set_(
            self,
            "kernel_scales_rad",
            _reals(self.kernel_scales_rad, "kernel_scales_rad", positive=True),
        )
        set_(
            self,
            "kernel_effort_scale",
            _real(self.kernel_effort_scale, "kernel_effort_scale", positive=True),
        )
        if self.max_path_distance_rad is not None:
            set_(
                self,
                "max_path_distance_rad",
                _real(self.max_path_distance_rad, "max_path_distance_rad", positive=True),
            )
        set_(self, "horizon_s", _real(self.horizon_s, "horizon_s", positive=True))
        for name in ("info_energy", "gui"):
            if not isinstance(getattr(self, name), bool):
                raise InvalidConfigError(
                    f"{name} must be True or False, got {getattr(self, name)!r}"
                )
        if self.render_mode is not None and self.render_mode not in RENDER_MODES:
            raise InvalidConfigError(
                f"render_mode must be None or one of {RENDER_MODES}, got {self.render_mode!r}"
            )
        check_sizing(self.disturbance_sizing, "disturbance_sizing")
        set_(
            self,
            "disturbances",
            build_disturbances(self.disturbance, self.profile, self.disturbance_sizing),
        )
        choices: list[list[Disturbance]] = []
        if self.disturbance_choices is not None:
            options = self.disturbance_choices
            if not isinstance(options, (list, tuple)) or not options:
                raise InvalidConfigError(
                    f"disturbance_choices must be a list of one or more disturbance specs, "
                    f"got {options!r}"
                )
            if self.disturbance is not None:
                raise InvalidConfigError(
                    "give disturbance (always on) or disturbance_choices (one per episode), "
                    "not both"
                )
            set_(self, "disturbance_choices", tuple(options))
            choices = [
                build_disturbances(c, self.profile, self.disturbance_sizing) for c in options
            ]
        set_(self, "choices", choices)
        for d in [*self.disturbances, *(d for c in choices for d in c)]:
            d.check_horizon(self.horizon_s)  # onsets that fit the episode, before any simulator

    @property
    def substeps(self) -> int:
        """Physics sub-steps per control step."""
        return round(self.physics_hz / self.control_hz)

    def kwargs(self) -> dict[str, Any]:
        """The constructor arguments (what rebuilds this config and its env)."""
        return {
            name: getattr(self, name)
            for name in self.__dataclass_fields__
            if name not in ("profile", "disturbances", "choices")
        }
