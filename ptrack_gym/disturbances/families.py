"""The disturbance families: joint torques, pushes, payloads, model mismatch, noise, delay.

Each class is a dataclass whose fields are its spec (``{"type": name, field: value}``)
and registers itself under its ``name`` (:data:`~ptrack_gym.disturbances.base.DISTURBANCES`).
Magnitudes are given as fractions of the torque limits, as accelerations per unit of
joint inertia (``accel_rad_s2``: comparable on light wrists and heavy shoulders) or as
energy budgets (``energy_j``). Families with onsets (impulse, step, push, payload) refuse,
at env construction, an episode too short for their latest onset, its duration and the
recovery window :data:`~ptrack_gym.disturbances.base.RECOVERY_S` (``timed_events``).
"""

from __future__ import annotations

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
from ptrack_gym.errors import InvalidConfigError


def _impulse_energy_scale(p: FloatArray, mass: FloatArray, energy_j: float) -> float:
    """Factor c such that the momentum c·p gives an arm at rest ½(cp)ᵀM⁻¹(cp) = energy_j."""
    e1 = 0.5 * float(p @ np.linalg.solve(mass, p))
    return float(np.sqrt(energy_j / e1)) if e1 > 0 else 0.0


@dataclass
class ImpulseTorque(Disturbance):
    """A joint-torque impulse held for ``duration_s`` from an onset uniform in ``onset_s``.

    Size, by precedence: ``energy_j`` — the impulse changes the velocity of an arm at rest
    at home by c·v (v a random unit vector of joint velocities) with the kinetic energy
    ½c²vᵀMv = energy_j, i.e. τ_d = c·M(q_home)v / duration; ``accel_rad_s2`` —
    τ_d = M(q_home)(α u); otherwise τ_d = a·τ_max ⊙ u (``fraction``), u a random unit vector.
    The torque acts on the physics sub-steps that start inside [onset, onset + duration):
    choose ``duration_s`` as a multiple of the physics step, or the delivered momentum is
    rounded to whole sub-steps.

    ``direction`` fixes v (or u) instead of drawing it (a unit vector is made of it), so a
    found worst case replays exactly. ``energy_mode``: ``"home"`` (above: the budget is the
    energy the impulse would give the arm *at rest at home*; on a moving arm the work it
    really does, ``info["disturbance_work_j"]``, differs — 0.35 to 3.6 J for 2 J was seen)
    or ``"delivered"``: c is chosen at the onset, from the arm's (q, q̇) and the nominal
    M(q), so that the impulse's momentum p = c·M(q_home)v changes the arm's kinetic energy
    by energy_j: pᵀq̇ + ½ pᵀM(q)⁻¹p = energy_j (the work of an instantaneous impulse; the
    50-ms one delivers it up to what gravity and the controller do meanwhile).
    """

    name: ClassVar[str] = "impulse"
    fraction: float = 0.5
    duration_s: float = 0.05
    onset_s: float | tuple[float, float] = (1.0, 4.0)
    accel_rad_s2: float | None = None
    energy_j: float | None = None
    direction: tuple[float, ...] | None = None
    energy_mode: str = "home"

    def __post_init__(self) -> None:
        check_non_negative(self.fraction, "fraction")
        check_non_negative(self.onset_s, "onset_s")
        if not (isinstance(self.duration_s, (int, float)) and self.duration_s > 0):
            raise InvalidConfigError(f"duration_s must be > 0, got {self.duration_s!r}")
        if self.energy_j is not None:
            check_non_negative(self.energy_j, "energy_j")
        if self.energy_mode not in ("home", "delivered"):
            raise InvalidConfigError(
                f"energy_mode must be 'home' or 'delivered', got {self.energy_mode!r}"
            )
        if self.energy_mode == "delivered" and self.energy_j is None:
            raise InvalidConfigError("energy_mode='delivered' needs energy_j")

    def timed_events(self) -> tuple[TimedEvent, ...]:
        return (("onset_s", self.onset_s, self.duration_s),)

    def validate(self, ctx: DisturbanceContext) -> None:
        if self.direction is not None:
            fixed_direction(self.direction, ctx.n, "direction")
        if self.energy_mode == "delivered" and ctx.mass_matrix is None:
            raise InvalidConfigError("energy_mode='delivered' needs the model's mass matrix")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._onset = draw(rng, self.onset_s)
        if self.direction is not None:
            u = fixed_direction(self.direction, ctx.n, "direction")
        else:
            u = unit_vector(rng, ctx.n)
        self._sized = True
        if self.energy_j is not None:
            mass = ctx.home_mass_matrix
            self._momentum_dir = mass @ u  # a: p = c·a
            c = np.sqrt(2.0 * self.energy_j / float(u @ mass @ u))
            self._tau = c * self._momentum_dir / self.duration_s
            if self.energy_mode == "delivered":
                self._mass_matrix = ctx.mass_matrix
                self._sized = False  # c is chosen at the onset, from the arm's state
        else:
            self._tau = _torque_vector(self.fraction, self.accel_rad_s2, u, ctx)

    def acts_during(self, t0_s: float, t1_s: float) -> bool:
        return t0_s < self._onset + self.duration_s and self._onset < t1_s

    def joint_torque(self, t_s: float, q: FloatArray, qd: FloatArray) -> FloatArray | None:
        if self._onset <= t_s < self._onset + self.duration_s:
            if not self._sized:
                self._tau = self._delivered_torque(q, qd)
                self._sized = True
            return self._tau
        return None

    def _delivered_torque(self, q: FloatArray, qd: FloatArray) -> FloatArray:
        """τ = c·a / T with c > 0 the root of c aᵀq̇ + ½c² aᵀM(q)⁻¹a = energy_j."""
        a = self._momentum_dir
        quad = float(a @ np.linalg.solve(self._mass_matrix(q), a))  # aᵀM⁻¹a > 0
        lin = float(a @ qd)
        c = (-lin + np.sqrt(lin * lin + 2.0 * quad * float(self.energy_j))) / quad
        return c * a / self.duration_s

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state.pop("_mass_matrix", None)  # a model method: the env restores it (set_context)
        return state

    def set_context(self, ctx: DisturbanceContext) -> None:
        """Re-attach what ``reset`` took from the context (after unpickling)."""
        if self.energy_mode == "delivered":
            self._mass_matrix = ctx.mass_matrix

    def schedule(self) -> dict[str, Any]:
        return {
            "onset_s": self._onset,
            "tau_nm": self._tau.copy(),
            "duration_s": self.duration_s,
            "sized": self._sized,
        }


def _torque_vector(
    fraction: float, accel: float | None, direction: FloatArray, ctx: DisturbanceContext
) -> FloatArray:
    """a·τ_max ⊙ u (``fraction``), or M(q_home)·(α u) with α = ``accel`` (rad/s²): the
    inertia-scaled form gives every joint a comparable acceleration, light wrists included."""
    if accel is not None:
        return ctx.home_mass_matrix @ (accel * direction)
    return fraction * ctx.torque_limits_nm * direction


def _unit_like(v: FloatArray) -> FloatArray:
    norm = np.linalg.norm(v)
    return v / norm if norm > 0 else v


def _sustained_amplitude(ctx: DisturbanceContext, energy_j: float) -> float:
    """Torque norm A (N·m) such that A · mean|q_r'| · horizon = energy_j: the most work a
    torque of norm A can do on an arm moving along the reference for the whole horizon."""
    return energy_j / max(ctx.mean_path_speed_rad_s * ctx.horizon_s, 1e-12)


@dataclass
class StepTorque(Disturbance):
    """A constant joint torque from a random onset to the episode's end: a·τ_max ⊙ u, or
    M(q_home)(α u) with ``accel_rad_s2``; with ``energy_j``, |τ_d| = energy_j /
    (mean|q_r'| · horizon), the most work it can do along the reference."""

    name: ClassVar[str] = "step"
    fraction: float = 0.1
    onset_s: float | tuple[float, float] = (1.0, 4.0)
    accel_rad_s2: float | None = None
    energy_j: float | None = None

    def __post_init__(self) -> None:
        check_non_negative(self.fraction, "fraction")
        if self.energy_j is not None:
            check_non_negative(self.energy_j, "energy_j")

    def timed_events(self) -> tuple[TimedEvent, ...]:
        return (("onset_s", self.onset_s, 0.0),)

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._onset = draw(rng, self.onset_s)
        self._tau = _torque_vector(self.fraction, self.accel_rad_s2, unit_vector(rng, ctx.n), ctx)
        if self.energy_j is not None:
            self._tau = _unit_like(self._tau) * _sustained_amplitude(ctx, self.energy_j)

    def acts_during(self, t0_s: float, t1_s: float) -> bool:
        return self._onset < t1_s

    def joint_torque(self, t_s: float, q: FloatArray, qd: FloatArray) -> FloatArray | None:
        return self._tau if t_s >= self._onset else None

    def schedule(self) -> dict[str, Any]:
        return {"onset_s": self._onset, "tau_nm": self._tau.copy()}


@dataclass
class PeriodicTorque(Disturbance):
    """τ_d,j(t) = A_j sin(2π f t + φ_j), A = a·τ_max ⊙ |u| (or |M(q_home) α|u|| with
    ``accel_rad_s2``), f drawn once per episode in ``frequency_hz``, phases φ_j uniform in
    [0, 2π) once per episode (never redrawn). With ``energy_j``: |A| = energy_j /
    (mean|q_r'| · horizon). ``direction`` fixes u (its absolute values weigh the joints)."""

    name: ClassVar[str] = "periodic"
    fraction: float = 0.1
    frequency_hz: float | tuple[float, float] = (0.5, 2.0)
    accel_rad_s2: float | None = None
    energy_j: float | None = None
    direction: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        check_non_negative(self.fraction, "fraction")
        check_non_negative(self.frequency_hz, "frequency_hz")
        if self.energy_j is not None:
            check_non_negative(self.energy_j, "energy_j")

    def validate(self, ctx: DisturbanceContext) -> None:
        if self.direction is not None:
            fixed_direction(self.direction, ctx.n, "direction")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._freq = draw(rng, self.frequency_hz)
        u = unit_vector(rng, ctx.n)  # drawn always: the phases' draws stay where they were
        if self.direction is not None:
            u = fixed_direction(self.direction, ctx.n, "direction")
        self._amp = np.abs(_torque_vector(self.fraction, self.accel_rad_s2, np.abs(u), ctx))
        self._phase = rng.uniform(0.0, 2.0 * np.pi, ctx.n)
        if self.energy_j is not None:
            self._amp = _unit_like(self._amp) * _sustained_amplitude(ctx, self.energy_j)

    def joint_torque(self, t_s: float, q: FloatArray, qd: FloatArray) -> FloatArray | None:
        return self._amp * np.sin(2.0 * np.pi * self._freq * t_s + self._phase)

    def schedule(self) -> dict[str, Any]:
        return {
            "frequency_hz": self._freq,
            "amplitude_nm": self._amp.copy(),
            "phase_rad": self._phase.copy(),
        }


@dataclass
class NoiseTorque(Disturbance):
    """Random joint torque, std a·τ_max per joint (or α·M_jj(q_home) with
    ``accel_rad_s2``), drawn every physics sub-step.

    ``bandwidth_hz=None``: white (independent draws). Otherwise band-limited: a first-order
    low-pass (Ornstein–Uhlenbeck) process x ← ρx + √(1−ρ²)·σw, ρ = exp(−2π f_c dt), whose
    stationary std is σ and whose spectrum falls off above f_c."""

    name: ClassVar[str] = "noise_torque"
    fraction: float = 0.05
    bandwidth_hz: float | None = 5.0
    accel_rad_s2: float | None = None

    def __post_init__(self) -> None:
        check_non_negative(self.fraction, "fraction")
        if self.bandwidth_hz is not None and not self.bandwidth_hz > 0:
            raise InvalidConfigError(f"bandwidth_hz must be > 0 or None, got {self.bandwidth_hz!r}")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._rng = rng
        self._sigma = (
            self.fraction * ctx.torque_limits_nm
            if self.accel_rad_s2 is None
            else self.accel_rad_s2 * np.diag(ctx.home_mass_matrix)
        )
        self._rho = (
            0.0
            if self.bandwidth_hz is None
            else float(np.exp(-2.0 * np.pi * self.bandwidth_hz * ctx.physics_dt_s))
        )
        self._x = self._sigma * rng.standard_normal(ctx.n)

    def joint_torque(self, t_s: float, q: FloatArray, qd: FloatArray) -> FloatArray | None:
        w = self._rng.standard_normal(self._x.shape[0])
        self._x = self._rho * self._x + np.sqrt(1.0 - self._rho**2) * self._sigma * w
        return self._x


@dataclass
class Push(Disturbance):
    """A force on a link (default: the end effector) for ``duration_s`` from a random onset,
    in a random world direction, applied at the link's centre of mass each physics
    sub-step (PyBullet clears external forces after every step). With ``energy_j``, the
    force is scaled so its momentum Jᵀ(F·T) (J the link's centre-of-mass Jacobian at home)
    gives an arm at rest at home that energy. ``direction`` fixes the world direction."""

    name: ClassVar[str] = "push"
    force_n: float = 20.0
    duration_s: float = 0.1
    onset_s: float | tuple[float, float] = (1.0, 4.0)
    link: str | None = None
    energy_j: float | None = None
    direction: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        check_non_negative(self.force_n, "force_n")
        check_non_negative(self.onset_s, "onset_s")
        if not (isinstance(self.duration_s, (int, float)) and self.duration_s > 0):
            raise InvalidConfigError(f"duration_s must be > 0, got {self.duration_s!r}")
        if self.energy_j is not None:
            check_non_negative(self.energy_j, "energy_j")
        if self.direction is not None:
            fixed_direction(self.direction, 3, "direction")

    def timed_events(self) -> tuple[TimedEvent, ...]:
        return (("onset_s", self.onset_s, self.duration_s),)

    def validate(self, ctx: DisturbanceContext) -> None:
        check_link(self.link, ctx, "push")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._onset = draw(rng, self.onset_s)
        self._link = self.link or ctx.ee_link
        direction = unit_vector(rng, 3)
        if self.direction is not None:
            direction = fixed_direction(self.direction, 3, "direction")
        self._force = self.force_n * direction
        if self.energy_j is not None:
            jac = ctx.link_jacobians_home.get(self._link, ctx.ee_jacobian_home)
            p = jac.T @ direction * self.duration_s
            self._force = direction * _impulse_energy_scale(p, ctx.home_mass_matrix, self.energy_j)

    def acts_during(self, t0_s: float, t1_s: float) -> bool:
        return t0_s < self._onset + self.duration_s and self._onset < t1_s

    def wrench(self, t_s: float) -> tuple[str, FloatArray] | None:
        if self._onset <= t_s < self._onset + self.duration_s:
            return self._link, self._force
        return None

    def schedule(self) -> dict[str, Any]:
        return {
            "onset_s": self._onset,
            "duration_s": self.duration_s,
            "force_n": self._force.copy(),
            "link": self._link,
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
    and the explicit scheme stays stable (a_f < 0.1 rad/s / dt)."""

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
    with ``accel_rad_s2``), w standard normal per control step (held over the sub-steps)."""

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
    episode's first state until enough steps have passed)."""

    name: ClassVar[str] = "observation_delay"
    steps: int = 2

    def __post_init__(self) -> None:
        if not (isinstance(self.steps, (int, np.integer)) and self.steps >= 0):
            raise InvalidConfigError(f"steps must be an integer >= 0, got {self.steps!r}")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._buffer: list[tuple[FloatArray, FloatArray]] = []

    def sense(self, q: FloatArray, qd: FloatArray) -> tuple[FloatArray, FloatArray]:
        self._buffer.append((q, qd))
        if len(self._buffer) > self.steps + 1:
            self._buffer.pop(0)
        return self._buffer[0]
