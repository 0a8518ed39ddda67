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

Before any of those, at env construction, ``check_horizon(horizon_s)``: a family with
onsets (an impulse, a push, a step, a payload's pick and drop) refuses an episode too short
for its latest event to happen *and* be recovered from — the latest onset + its duration +
:data:`RECOVERY_S` must fit in the horizon (:func:`check_event_fits`). Without it a short
episode ends before the onset, and a comparison "under impulses" compares undisturbed runs.

A subclass with a ``name`` is registered in :data:`DISTURBANCES` (the spec ``type``), so
adding a disturbance family is writing one class.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from ptrack_gym.errors import InvalidConfigError

FloatArray = NDArray[np.float64]

#: Every disturbance family by its spec ``type`` (filled by subclassing :class:`Disturbance`).
DISTURBANCES: dict[str, type[Disturbance]] = {}

#: A timed event of a disturbance: (field name, onset or (low, high) onset range, duration),
#: in s (:meth:`Disturbance.timed_events`).
TimedEvent = tuple[str, float | tuple[float, float], float]

#: How a joint-torque family's M(q)-based size is taken (its ``sizing`` field): ``"home"``
#: from the nominal M(q_home), whatever the arm's state; ``"onset"`` from the nominal M(q) at
#: the configuration the arm is in when the torque starts to act (per family: its docstring).
SIZINGS: tuple[str, ...] = ("home", "onset")

#: The least time (s) an episode must run after a timed disturbance's latest possible event
#: ends (latest onset + duration): the recovery window. 0.5 s is 10 impulse and 5 push
#: durations of the presets, and more than most recoveries take (results/main, iiwa, 1 kHz:
#: median ``recovery_s`` 0.04-0.08 s after an impulse, three quarters under 0.14 s at levels
#: ≤ 1), so the response is measured, not cut off; every shipped configuration keeps more
#: (5-s episodes: ≥ 0.9 s after onsets of 1-4 s; 8-s episodes: ≥ 3.9 s). A constant, not a
#: fraction of the horizon: the minimum episode of a family is then its latest event + 0.5 s.
RECOVERY_S: float = 0.5


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
        mass_matrix: the nominal model's M(q) (kg·m²), for sizing by the state at onset
            (``energy_mode="delivered"``, ``sizing="onset"``); None where unavailable.
        com_jacobian: (link, q) ↦ the link's centre-of-mass Jacobian at q, (3, n), for a
            push sized at its onset (``energy_mode="delivered"``); None where unavailable.
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
    com_jacobian: Callable[[str, FloatArray], FloatArray] | None = None


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

    def timed_events(self) -> tuple[TimedEvent, ...]:
        """Each event drawn at a time: (its field, its onset or (low, high) onset range,
        its duration), in s; ``()`` for a family without onsets."""
        return ()

    def check_horizon(self, horizon_s: float) -> None:
        """Raise :class:`InvalidConfigError` if an episode of ``horizon_s`` (s) is too short
        for one of :meth:`timed_events` to happen and be recovered from
        (:func:`check_event_fits`); called at env construction."""
        for field_name, onset_s, duration_s in self.timed_events():
            check_event_fits(self.name, field_name, onset_s, duration_s, horizon_s)

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

    def wrench(self, t_s: float, q: FloatArray, qd: FloatArray) -> tuple[str, FloatArray] | None:
        """(link name, world-frame force in N at the link's centre of mass), or None; (q, q̇)
        is the arm's state at the sub-step's start."""
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


def check_sizing(value: Any, name: str = "sizing") -> str:
    """``value`` if it is one of :data:`SIZINGS`, else :class:`InvalidConfigError` listing them."""
    if not (isinstance(value, str) and value in SIZINGS):
        raise InvalidConfigError(f"{name} must be one of {SIZINGS}, got {value!r}")
    return value


def latest(value: float | tuple[float, float]) -> float:
    """The latest time (s) a fixed value or a (low, high) range can draw."""
    return float(max(value)) if isinstance(value, tuple) else float(value)


def check_event_fits(
    family: str,
    field_name: str,
    onset_s: float | tuple[float, float],
    duration_s: float,
    horizon_s: float,
) -> None:
    """Raise :class:`InvalidConfigError` unless every drawable event fits in the episode:

        max(onset) + duration + RECOVERY_S ≤ horizon   (s; 1e-9 s of rounding allowed)

    with :data:`RECOVERY_S` the recovery window. The message names the family, its onset
    range, the duration, the recovery window and the horizon, and what to change: a longer
    episode, or an onset range that ends in time.
    """
    need = latest(onset_s) + duration_s + RECOVERY_S
    if need <= horizon_s + 1e-9:
        return
    room = horizon_s - duration_s - RECOVERY_S  # the latest onset that would fit
    onset = f"{onset_s[0]:g}-{onset_s[1]:g} s" if isinstance(onset_s, tuple) else f"{onset_s:g} s"
    fix = f"an episode of at least {need:.6g} s (episode_s / horizon_s)"
    if room >= 0:
        fix += f", or an explicit {field_name} range that ends by {room:.6g} s"
    raise InvalidConfigError(
        f"{family}: {field_name} {onset} + duration {duration_s:g} s + recovery window "
        f"{RECOVERY_S:g} s does not fit in the episode's horizon_s = {horizon_s:g} s (the "
        f"disturbance could come too late to be measured, or never); use {fix}"
    )


def min_horizon_s(items: Sequence[Disturbance]) -> float:
    """The shortest episode (s) that ``items`` accept: max over their timed events of
    max(onset) + duration + :data:`RECOVERY_S`; 0 without a timed event."""
    return max(
        (
            latest(onset_s) + duration_s + RECOVERY_S
            for d in items
            for _, onset_s, duration_s in d.timed_events()
        ),
        default=0.0,
    )
