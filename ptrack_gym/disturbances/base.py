"""The disturbance interface: a small object with optional hooks, and what it may know.

The env's :class:`~ptrack_gym.disturbances.runner.DisturbanceRunner` calls the hooks at
documented points; a disturbance never touches the simulator itself:

* ``reset(rng, ctx)`` — at every env reset, with the episode's own stream: draws the
  episode's schedule;
* ``acts_during(t0, t1)`` — whether ``joint_torque`` or ``wrench`` may be non-zero in
  [t0, t1); the runner skips the disturbed sub-step loop (and its bookkeeping) for a
  control step in which no disturbance acts;
* ``joint_torque(t, q, q̇)`` — before every physics sub-step (t its start time): τ_d is
  added to the plant torque, after the actuator clip, unseen by the controller;
* ``wrench(t)`` — before every physics sub-step: (link, world-frame force in N) applied
  at the link's centre of mass;
* ``plant(t)`` — before every control step: link mass changes of the plant only;
* ``actuate(τ)`` — every control step, on the commanded (clipped) torque: actuation noise;
* ``sense(q, q̇)`` — every control step, on the true state: what the observation and the
  controllers see.

A subclass with a ``name`` is registered in :data:`DISTURBANCES` (the spec ``type``), so
adding a disturbance family is writing one class.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from ptrack_gym.errors import InvalidConfigError

FloatArray = NDArray[np.float64]

#: Every disturbance family by its spec ``type`` (filled by subclassing :class:`Disturbance`).
DISTURBANCES: dict[str, type[Disturbance]] = {}


@dataclass(frozen=True)
class DisturbanceContext:
    """What a disturbance may know about the episode (SI units).

    Attributes:
        n: number of joints.
        torque_limits_nm: the actuators' limits, shape (n,).
        physics_dt_s / control_dt_s: the time steps.
        horizon_s: the nominal episode length, for onset times and energy budgets.
        ee_link: the end-effector link name (pushes and payloads act there by default).
        home_mass_matrix: nominal M at the home pose, (n, n), for energy budgets.
        ee_jacobian_home: translational Jacobian of the ee link's centre of mass at home, (3, n).
        mean_path_speed_rad_s: mean |q_r'| along the reference (rad/s), for energy budgets.
        link_jacobians_home: every link's centre-of-mass Jacobian at home, (3, n), by name.
        mass_matrix: the nominal model's M(q) (kg·m²), for sizing by the state at onset.
    """

    n: int
    torque_limits_nm: FloatArray
    physics_dt_s: float
    control_dt_s: float
    horizon_s: float
    ee_link: str
    home_mass_matrix: FloatArray
    ee_jacobian_home: FloatArray
    mean_path_speed_rad_s: float
    link_jacobians_home: Mapping[str, FloatArray] = field(default_factory=dict)
    mass_matrix: Callable[[FloatArray], FloatArray] | None = None


@dataclass(frozen=True)
class MassChange:
    """A plant link's mass is ``nominal · scale + added_kg`` (inertia scaled by ``scale``)."""

    scale: float = 1.0
    added_kg: float = 0.0


@dataclass
class Disturbance:
    """Base of every disturbance: all hooks are no-ops. Subclasses are dataclasses whose
    fields are the spec; episode state set by ``reset`` lives in private attributes."""

    name: ClassVar[str] = "none"

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.name != "none":
            if cls.name in DISTURBANCES and DISTURBANCES[cls.name] is not cls:
                raise TypeError(f"two disturbance families are called {cls.name!r}")
            DISTURBANCES[cls.name] = cls

    def validate(self, ctx: DisturbanceContext) -> None:
        """Raise :class:`InvalidConfigError` if this disturbance cannot act on the env of
        ``ctx`` (e.g. a link it names does not exist); called once, at env construction."""

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        """Draw this episode's schedule."""

    def set_context(self, ctx: DisturbanceContext) -> None:
        """Re-attach what ``reset`` keeps of the context and does not pickle (a model's
        method), after an env is unpickled; a no-op for most families."""

    def acts_during(self, t0_s: float, t1_s: float) -> bool:
        """Whether ``joint_torque`` or ``wrench`` may be non-zero in [t0, t1) (s).
        Default: always, for a family that overrides either hook."""
        cls = type(self)
        return (
            cls.joint_torque is not Disturbance.joint_torque or cls.wrench is not Disturbance.wrench
        )

    def joint_torque(self, t_s: float, q: FloatArray, qd: FloatArray) -> FloatArray | None:
        """Joint torque (N·m) to add before the physics sub-step starting at ``t_s``."""
        return None

    def wrench(self, t_s: float) -> tuple[str, FloatArray] | None:
        """(link name, world-frame force in N at the link's centre of mass), or None."""
        return None

    def plant(self, t_s: float) -> dict[str, MassChange] | None:
        """Plant link mass changes in force at ``t_s`` (None: this one changes nothing)."""
        return None

    def plant_change_times(self) -> tuple[float, ...] | None:
        """The times (s) at which :meth:`plant` changes its value this episode, between
        which it is constant (a change at c holds on [c, next change)); None: it may change
        at any time, so the plant is recomputed every control step."""
        return None

    def actuate(self, tau_nm: FloatArray) -> FloatArray:
        """The torque the actuators really produce for the command ``tau_nm``."""
        return tau_nm

    def sense(self, q: FloatArray, qd: FloatArray) -> tuple[FloatArray, FloatArray]:
        """What the sensors report for the true (q, q̇)."""
        return q, qd

    def schedule(self) -> dict[str, Any]:
        """The episode's drawn parameters (for logs and tests)."""
        return {}


def unit_vector(rng: np.random.Generator, n: int) -> FloatArray:
    """A uniformly random unit vector of R^n."""
    v = rng.standard_normal(n)
    return v / np.linalg.norm(v)


def fixed_direction(value: Any, size: int, name: str) -> FloatArray:
    """A given direction as a unit vector of R^size, or :class:`InvalidConfigError`."""
    v = np.asarray(value, dtype=np.float64)
    norm = float(np.linalg.norm(v)) if v.shape == (size,) else 0.0
    if not (np.isfinite(norm) and norm > 0.0):
        raise InvalidConfigError(f"{name} must be {size} finite numbers, not all 0, got {value!r}")
    return v / norm


def check_link(link: str | None, ctx: DisturbanceContext, family: str) -> None:
    """Raise :class:`InvalidConfigError` for a link the robot does not have."""
    if link is not None and ctx.link_jacobians_home and link not in ctx.link_jacobians_home:
        raise InvalidConfigError(
            f"{family}: the robot has no link {link!r}; known: {sorted(ctx.link_jacobians_home)}"
        )


def draw(rng: np.random.Generator, value: float | tuple[float, float]) -> float:
    """A fixed value, or uniform in a (low, high) range."""
    if isinstance(value, tuple):
        return float(rng.uniform(*value))
    return float(value)


def check_non_negative(value: float | tuple[float, float], name: str) -> None:
    """Raise :class:`InvalidConfigError` unless ``value`` (or each end of a range) is a
    finite number ≥ 0."""
    values = value if isinstance(value, tuple) else (value,)
    if not all(
        isinstance(v, (int, float, np.integer, np.floating))
        and not isinstance(v, bool)
        and np.isfinite(v)
        and v >= 0
        for v in values
    ):
        raise InvalidConfigError(f"{name} must be >= 0 (or a (low, high) range), got {value!r}")
