"""The disturbance families: pushes, payloads, model mismatch, noise, delay — and, from
:mod:`~ptrack_gym.disturbances.torques` (re-exported here), the joint torques (impulse,
step, periodic and noise torques).

Each class is a dataclass whose fields are its spec (``{"type": name, field: value}``)
and registers itself under its ``name`` (:data:`~ptrack_gym.disturbances.base.DISTURBANCES`).
Magnitudes are given as fractions of the torque limits, as accelerations per unit of
joint inertia (``accel_rad_s2``: comparable on light wrists and heavy shoulders) or as
energy budgets (``energy_j``). Families with onsets (impulse, step, push, payload) refuse,
at env construction, an episode too short for their latest onset, its duration and the
recovery window :data:`~ptrack_gym.disturbances.base.RECOVERY_S` (``timed_events``).
The families here are sized at the home pose only (the joint torques' ``sizing`` option
does not apply to them; see :class:`Mismatch` and :class:`ActionNoise`).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ptrack_gym.disturbances.base import (
    Disturbance,
    DisturbanceContext,
    FloatArray,
    MassChange,
    TimedEvent,
    check_link,
    check_non_negative,
    draw,
    fixed_direction,
    unit_vector,
)
from ptrack_gym.disturbances.torques import (
    ImpulseTorque,
    NoiseTorque,
    PeriodicTorque,
    StepTorque,
)
from ptrack_gym.errors import InvalidConfigError

__all__ = [
    "ActionNoise",
    "ImpulseTorque",
    "Mismatch",
    "NoiseTorque",
    "ObservationDelay",
    "ObservationNoise",
    "Payload",
    "PeriodicTorque",
    "Push",
    "StepTorque",
]


def _impulse_energy_scale(p: FloatArray, mass: FloatArray, energy_j: float) -> float:
    """Factor c such that the momentum c·p gives an arm at rest ½(cp)ᵀM⁻¹(cp) = energy_j."""
    e1 = 0.5 * float(p @ np.linalg.solve(mass, p))
    return float(np.sqrt(energy_j / e1)) if e1 > 0 else 0.0


@dataclass
class Push(Disturbance):
    """A force on a link (default: the end effector) for ``duration_s`` from a random onset,
    in a random world direction, applied at the link's centre of mass each physics
    sub-step (PyBullet clears external forces after every step). With ``energy_j``, the
    force is scaled so its momentum Jᵀ(F·T) (J the link's centre-of-mass Jacobian at home)
    gives an arm at rest at home that energy. ``direction`` fixes the world direction.

    ``energy_mode="delivered"`` (with ``energy_j``): the force's size f is chosen at the
    onset from the arm's (q, q̇), J(q) and the nominal M(q), the way an impulse's is: its
    joint momentum p = f·a, a = J(q)ᵀF̂·T, changes the arm's kinetic energy by energy_j,
    pᵀq̇ + ½pᵀM(q)⁻¹p = energy_j (the work of an instantaneous push; the ``duration_s``-long
    one delivers it up to what gravity and the controller do meanwhile)."""

    name: ClassVar[str] = "push"
    force_n: float = 20.0
    duration_s: float = 0.1
    onset_s: float | tuple[float, float] = (1.0, 4.0)
    link: str | None = None
    energy_j: float | None = None
    direction: tuple[float, float, float] | None = None
    energy_mode: str = "home"

    def __post_init__(self) -> None:
        check_non_negative(self.force_n, "force_n")
        check_non_negative(self.onset_s, "onset_s")
        if not (isinstance(self.duration_s, (int, float)) and self.duration_s > 0):
            raise InvalidConfigError(f"duration_s must be > 0, got {self.duration_s!r}")
        if self.energy_j is not None:
            check_non_negative(self.energy_j, "energy_j")
        if self.direction is not None:
            fixed_direction(self.direction, 3, "direction")
        if self.energy_mode not in ("home", "delivered"):
            raise InvalidConfigError(
                f"energy_mode must be 'home' or 'delivered', got {self.energy_mode!r}"
            )
        if self.energy_mode == "delivered" and self.energy_j is None:
            raise InvalidConfigError("energy_mode='delivered' needs energy_j")

    def timed_events(self) -> tuple[TimedEvent, ...]:
        return (("onset_s", self.onset_s, self.duration_s),)

    def validate(self, ctx: DisturbanceContext) -> None:
        check_link(self.link, ctx, "push")
        if self.energy_mode == "delivered" and (
            ctx.mass_matrix is None or ctx.com_jacobian is None
        ):
            raise InvalidConfigError(
                "energy_mode='delivered' needs the model's mass matrix and the links' Jacobians"
            )

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._onset = draw(rng, self.onset_s)
        self._link = self.link or ctx.ee_link
        direction = unit_vector(rng, 3)
        if self.direction is not None:
            direction = fixed_direction(self.direction, 3, "direction")
        self._direction = direction
        self._force = self.force_n * direction
        self._sized = True
        if self.energy_mode == "delivered":
            self.set_context(ctx)
            self._force = np.full(3, np.nan)
            self._sized = False  # f is chosen at the onset, from the arm's state
        elif self.energy_j is not None:
            jac = ctx.link_jacobians_home.get(self._link, ctx.ee_jacobian_home)
            p = jac.T @ direction * self.duration_s
            self._force = direction * _impulse_energy_scale(p, ctx.home_mass_matrix, self.energy_j)

    def set_context(self, ctx: DisturbanceContext) -> None:
        """Re-attach the model's M(q) and the links' Jacobians (after unpickling)."""
        if self.energy_mode == "delivered":
            self._mass_matrix, self._com_jacobian = ctx.mass_matrix, ctx.com_jacobian

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        for name in ("_mass_matrix", "_com_jacobian"):  # model methods: set_context restores
            state.pop(name, None)
        return state

    def acts_during(self, t0_s: float, t1_s: float) -> bool:
        return t0_s < self._onset + self.duration_s and self._onset < t1_s

    def wrench(self, t_s: float, q: FloatArray, qd: FloatArray) -> tuple[str, FloatArray] | None:
        if self._onset <= t_s < self._onset + self.duration_s:
            if not self._sized:
                a = self._com_jacobian(self._link, q).T @ self._direction * self.duration_s
                quad = float(a @ np.linalg.solve(self._mass_matrix(q), a))
                if quad > 0:
                    lin = float(a @ qd)
                    f = (-lin + np.sqrt(lin * lin + 2.0 * quad * float(self.energy_j))) / quad
                else:  # a direction the link cannot move in: no push reaches the joints
                    f = 0.0
                self._force = f * self._direction
                self._sized = True
            return self._link, self._force
        return None

    def schedule(self) -> dict[str, Any]:
        return {
            "onset_s": self._onset,
            "duration_s": self.duration_s,
            "force_n": self._force.copy(),
            "link": self._link,
            "sized": self._sized,
        }


@dataclass
class Payload(Disturbance):
    """A point mass at the end effector (its link's centre of mass) of the plant only.

    Held from ``pick_s`` (0: from the start; a (low, high) range: drawn) until ``drop_s``
    (None: never dropped). The nominal model never sees it."""

    name: ClassVar[str] = "payload"
    mass_kg: float = 1.0
    pick_s: float | tuple[float, float] = 0.0
    drop_s: float | tuple[float, float] | None = None
    link: str | None = None

    def __post_init__(self) -> None:
        check_non_negative(self.mass_kg, "mass_kg")

    def timed_events(self) -> tuple[TimedEvent, ...]:
        pick: TimedEvent = ("pick_s", self.pick_s, 0.0)
        return (pick,) if self.drop_s is None else (pick, ("drop_s", self.drop_s, 0.0))

    def validate(self, ctx: DisturbanceContext) -> None:
        check_link(self.link, ctx, "payload")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._link = self.link or ctx.ee_link
        self._pick = draw(rng, self.pick_s)
        self._drop = np.inf if self.drop_s is None else draw(rng, self.drop_s)

    def plant(self, t_s: float) -> dict[str, MassChange] | None:
        held = self._pick <= t_s < self._drop
        return {self._link: MassChange(added_kg=self.mass_kg if held else 0.0)}

    def plant_change_times(self) -> tuple[float, ...]:
        return tuple(t for t in (self._pick, self._drop) if np.isfinite(t))

    def schedule(self) -> dict[str, Any]:
        return {
            "link": self._link,
            "pick_s": self._pick,
            "drop_s": self._drop,
            "mass_kg": self.mass_kg,
        }


@dataclass
class Mismatch(Disturbance):
    """Plant ≠ model: every listed link's mass and inertia scaled by a factor drawn per
    episode in ``mass_scale``; joint viscous damping and Coulomb friction as explicit plant
    torques τ_d,j = −β M_jj q̇_j − a_f M_jj tanh(q̇_j / 0.1 rad/s), M_jj = M_jj(q_home): per
    unit of joint inertia (β in 1/s, a_f in rad/s²), so light wrists are not over-damped
    and the explicit scheme stays stable (a_f < 0.1 rad/s / dt).

    No ``sizing`` option: βM_jj and a_f M_jj are the joints' damping (N·m·s/rad) and
    friction (N·m) coefficients, properties of the joint that do not change with the arm's
    configuration, and the terms act from the episode's start, with no onset; M_jj(q_home)
    only makes the coefficients comparable across joints and robots."""

    name: ClassVar[str] = "mismatch"
    mass_scale: float | tuple[float, float] = (0.8, 1.2)
    damping_per_s: float = 0.0
    friction_rad_s2: float = 0.0
    links: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        check_non_negative(self.mass_scale, "mass_scale")
        check_non_negative(self.damping_per_s, "damping_per_s")
        check_non_negative(self.friction_rad_s2, "friction_rad_s2")

    def validate(self, ctx: DisturbanceContext) -> None:
        for link in self.links:
            check_link(link, ctx, "mismatch")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._scales = {link: draw(rng, self.mass_scale) for link in self.links}
        inertia = np.diag(ctx.home_mass_matrix)
        self._damping = self.damping_per_s * inertia
        self._friction = self.friction_rad_s2 * inertia

    def plant(self, t_s: float) -> dict[str, MassChange] | None:
        return {link: MassChange(scale=s) for link, s in self._scales.items()}

    def plant_change_times(self) -> tuple[float, ...]:
        return ()  # drawn once per episode, constant from its start

    def acts_during(self, t0_s: float, t1_s: float) -> bool:
        return self.damping_per_s > 0.0 or self.friction_rad_s2 > 0.0

    def joint_torque(self, t_s: float, q: FloatArray, qd: FloatArray) -> FloatArray | None:
        if self.damping_per_s == 0.0 and self.friction_rad_s2 == 0.0:
            return None
        return -self._damping * qd - self._friction * np.tanh(qd / 0.1)

    def schedule(self) -> dict[str, Any]:
        return {"mass_scales": dict(self._scales)}


@dataclass
class ActionNoise(Disturbance):
    """Actuation noise: the actuators produce τ + σ ⊙ w, σ = a·τ_max (or α·M_jj(q_home)
    with ``accel_rad_s2``), w standard normal per control step (held over the sub-steps).
    Always sized at home: ``actuate`` sees the command, not the state, so there is no
    ``sizing`` option (the noise preset's joint-torque noise has one)."""

    name: ClassVar[str] = "action_noise"
    fraction: float = 0.02
    accel_rad_s2: float | None = None

    def __post_init__(self) -> None:
        check_non_negative(self.fraction, "fraction")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._rng = rng
        self._sigma = (
            self.fraction * ctx.torque_limits_nm
            if self.accel_rad_s2 is None
            else self.accel_rad_s2 * np.diag(ctx.home_mass_matrix)
        )

    def actuate(self, tau_nm: FloatArray) -> FloatArray:
        return tau_nm + self._sigma * self._rng.standard_normal(tau_nm.shape[0])


@dataclass
class ObservationNoise(Disturbance):
    """Sensor noise: q + σ_q w₁ (rad), q̇ + σ_q̇ w₂ (rad/s), w standard normal per control step."""

    name: ClassVar[str] = "observation_noise"
    q_std_rad: float = 1e-3
    qd_std_rad_s: float = 1e-2

    def __post_init__(self) -> None:
        check_non_negative(self.q_std_rad, "q_std_rad")
        check_non_negative(self.qd_std_rad_s, "qd_std_rad_s")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._rng = rng

    def sense(self, q: FloatArray, qd: FloatArray) -> tuple[FloatArray, FloatArray]:
        n = q.shape[0]
        return (
            q + self.q_std_rad * self._rng.standard_normal(n),
            qd + self.qd_std_rad_s * self._rng.standard_normal(n),
        )


@dataclass
class ObservationDelay(Disturbance):
    """Sensor delay: the reported state is the one ``steps`` control steps ago (the
    episode's first state until enough steps have passed); 2 steps if neither ``steps``
    nor ``delay_s`` is given.

    With ``delay_s`` (s) the delay is given in time instead: steps = ⌈delay_s / Δt⌉ at the
    env's control step Δt — the newest sample at least ``delay_s`` old (at 1 kHz, 2 ms is
    2 steps; at 250 Hz, 1 step of 4 ms), so a preset means the same on every control rate.
    """

    name: ClassVar[str] = "observation_delay"
    steps: int | None = None
    delay_s: float | None = None

    def __post_init__(self) -> None:
        if self.steps is not None and self.delay_s is not None:
            raise InvalidConfigError("give the delay as steps or as delay_s, not both")
        if self.steps is not None and not (
            isinstance(self.steps, (int, np.integer))
            and not isinstance(self.steps, bool)
            and self.steps >= 0
        ):
            raise InvalidConfigError(f"steps must be an integer >= 0, got {self.steps!r}")
        if self.delay_s is not None:
            check_non_negative(self.delay_s, "delay_s")

    def delay_steps(self, control_dt_s: float) -> int:
        """The delay in control steps at the control step ``control_dt_s`` (s)."""
        if self.delay_s is None:
            return 2 if self.steps is None else int(self.steps)
        return math.ceil(self.delay_s / control_dt_s - 1e-9)

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._steps = self.delay_steps(ctx.control_dt_s)
        self._buffer: deque[tuple[FloatArray, FloatArray]] = deque(maxlen=self._steps + 1)

    def sense(self, q: FloatArray, qd: FloatArray) -> tuple[FloatArray, FloatArray]:
        self._buffer.append((q, qd))
        return self._buffer[0]
