"""The joint-torque families: impulse, step, periodic and noise torques.

Each class is a dataclass whose fields are its spec (``{"type": name, field: value}``)
and registers itself under its ``name`` (:data:`~ptrack_gym.disturbances.base.DISTURBANCES`).
Magnitudes are fractions of the torque limits (``fraction``), accelerations per unit of
joint inertia (``accel_rad_s2``: comparable on light wrists and heavy shoulders) or energy
budgets (``energy_j``).

``sizing`` (:data:`~ptrack_gym.disturbances.base.SIZINGS`) says which inertia an M-based
size uses: ``"home"`` (the default) the nominal M(q_home), whatever the arm's state;
``"onset"`` the nominal M(q) at the configuration q the arm is in when the torque starts
to act — an impulse's or a step's onset, a periodic torque's first sub-step (the episode's
start state: its amplitude is then fixed), and, for a noise torque, which acts all the
time, every draw (its std follows diag M(q) at the current q). The size is computed
lazily, at the first ``joint_torque`` call of the active window, from the true q handed
to it; every random draw (onset, direction, phases, noise) still comes from ``reset``'s
stream in the same order, so the two sizings of one seed meet the same directions, phases
and noise sequence (paired). A ``fraction`` size is τ_max-based, not M-based: ``sizing``
does not change it. Until its onset, an onset-sized family's schedule reports NaN for the
torque it has not yet sized, and ``"sized": False``. ``sizing="onset"`` needs the model's
M(q) (``DisturbanceContext.mass_matrix``): without it, ``validate`` refuses it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ptrack_gym.disturbances.base import (
    Disturbance,
    DisturbanceContext,
    FloatArray,
    TimedEvent,
    check_non_negative,
    check_sizing,
    draw,
    fixed_direction,
    unit_vector,
)
from ptrack_gym.errors import InvalidConfigError


def _torque_vector(
    fraction: float,
    accel: float | None,
    direction: FloatArray,
    torque_limits_nm: FloatArray,
    mass: FloatArray,
) -> FloatArray:
    """a·τ_max ⊙ u (``fraction``), or M·(α u) with α = ``accel`` (rad/s²) and M the
    nominal mass matrix (kg·m²) the torque is sized by: the inertia-scaled form gives every
    joint a comparable acceleration, light wrists included."""
    if accel is not None:
        return mass @ (accel * direction)
    return fraction * torque_limits_nm * direction


def _unit_like(v: FloatArray) -> FloatArray:
    norm = np.linalg.norm(v)
    return v / norm if norm > 0 else v


def _sustained_amplitude(ctx: DisturbanceContext, energy_j: float) -> float:
    """Torque norm A (N·m) such that A · mean|q_r'| · horizon = energy_j: the most work a
    torque of norm A can do on an arm moving along the reference for the whole horizon."""
    return energy_j / max(ctx.mean_path_speed_rad_s * ctx.horizon_s, 1e-12)


def _impulse_at_rest(
    mass: FloatArray, v: FloatArray, energy_j: float, duration_s: float
) -> tuple[FloatArray, FloatArray]:
    """(a, τ): the momentum direction a = M v and the torque τ = c·a / T that changes the
    velocity of an arm at rest (mass matrix M) by c·v with ½c²vᵀMv = energy_j (J)."""
    a = mass @ v  # p = c·a
    c = np.sqrt(2.0 * energy_j / float(v @ mass @ v))
    return a, c * a / duration_s


class _SizedByMass(Disturbance):
    """What the families with a ``sizing`` field share: the model check, and the model's
    method kept out of pickles (the env re-attaches it, ``set_context``)."""

    sizing: str  # a field of each subclass ("home" or "onset")
    accel_rad_s2: float | None

    def _onset_sized(self) -> bool:
        """Whether the size is taken from M(q) when the torque starts to act."""
        return self.sizing == "onset" and self.accel_rad_s2 is not None

    def validate(self, ctx: DisturbanceContext) -> None:
        if self._onset_sized() and ctx.mass_matrix is None:
            raise InvalidConfigError(
                f"{self.name}: sizing='onset' needs the nominal model's mass matrix M(q), and "
                "this env's DisturbanceContext has none (mass_matrix=None); use sizing='home'"
            )

    def set_context(self, ctx: DisturbanceContext) -> None:
        """Re-attach the model's M(q) (after unpickling)."""
        if self._onset_sized():
            self._mass_matrix = ctx.mass_matrix

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state.pop("_mass_matrix", None)  # a model method: the env restores it (set_context)
        return state

    def _sizing_schedule(self) -> dict[str, Any]:
        """The sizing, and where an onset-sized torque was sized (None until it is)."""
        out: dict[str, Any] = {"sizing": self.sizing}
        if self._onset_sized():
            q = self._q_sized
            out["q_sized_rad"] = None if q is None else q.copy()
        return out


@dataclass
class ImpulseTorque(_SizedByMass):
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

    ``sizing="onset"``: every M(q_home) above becomes M(q_on), q_on the configuration at the
    onset — τ_d = M(q_on)(α u); τ_d = c·M(q_on)v / T with ½c²vᵀM(q_on)v = energy_j (the
    energy the impulse gives the arm at rest *at the onset's configuration*); delivered:
    p = c·M(q_on)v. The ``fraction`` size is not M-based and does not change.
    """

    name: ClassVar[str] = "impulse"
    fraction: float = 0.5
    duration_s: float = 0.05
    onset_s: float | tuple[float, float] = (1.0, 4.0)
    accel_rad_s2: float | None = None
    energy_j: float | None = None
    direction: tuple[float, ...] | None = None
    energy_mode: str = "home"
    sizing: str = "home"

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
        check_sizing(self.sizing)

    def _onset_sized(self) -> bool:
        return self.sizing == "onset" and (
            self.energy_j is not None or self.accel_rad_s2 is not None
        )

    def timed_events(self) -> tuple[TimedEvent, ...]:
        return (("onset_s", self.onset_s, self.duration_s),)

    def validate(self, ctx: DisturbanceContext) -> None:
        if self.direction is not None:
            fixed_direction(self.direction, ctx.n, "direction")
        if self.energy_mode == "delivered" and ctx.mass_matrix is None:
            raise InvalidConfigError("energy_mode='delivered' needs the model's mass matrix")
        super().validate(ctx)

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._onset = draw(rng, self.onset_s)
        if self.direction is not None:
            u = fixed_direction(self.direction, ctx.n, "direction")
        else:
            u = unit_vector(rng, ctx.n)
        self._sized, self._q_sized = True, None
        if self._onset_sized():  # sized at the onset, from M(q_on)
            self._u = u
            self._mass_matrix = ctx.mass_matrix
            self._tau = np.full(ctx.n, np.nan)
            self._sized = False
        elif self.energy_j is not None:
            mass = ctx.home_mass_matrix
            self._momentum_dir, self._tau = _impulse_at_rest(
                mass, u, self.energy_j, self.duration_s
            )
            if self.energy_mode == "delivered":
                self._mass_matrix = ctx.mass_matrix
                self._sized = False  # c is chosen at the onset, from the arm's state
        else:
            self._tau = _torque_vector(
                self.fraction, self.accel_rad_s2, u, ctx.torque_limits_nm, ctx.home_mass_matrix
            )

    def acts_during(self, t0_s: float, t1_s: float) -> bool:
        return t0_s < self._onset + self.duration_s and self._onset < t1_s

    def joint_torque(self, t_s: float, q: FloatArray, qd: FloatArray) -> FloatArray | None:
        if self._onset <= t_s < self._onset + self.duration_s:
            if not self._sized:
                self._tau = self._torque_at_onset(q, qd)
                self._sized = True
            return self._tau
        return None

    def _torque_at_onset(self, q: FloatArray, qd: FloatArray) -> FloatArray:
        """τ_d from the state (q, q̇) at the onset (see the class docstring)."""
        if self._onset_sized():
            self._q_sized = np.array(q, dtype=np.float64)
            mass = np.array(self._mass_matrix(q))  # M(q_on), (n, n)
            if self.energy_j is None:
                return mass @ (self.accel_rad_s2 * self._u)
            self._momentum_dir, tau = _impulse_at_rest(
                mass, self._u, self.energy_j, self.duration_s
            )
            if self.energy_mode == "home":
                return tau
        return self._delivered_torque(q, qd)

    def _delivered_torque(self, q: FloatArray, qd: FloatArray) -> FloatArray:
        """τ = c·a / T with c > 0 the root of c aᵀq̇ + ½c² aᵀM(q)⁻¹a = energy_j."""
        a = self._momentum_dir
        quad = float(a @ np.linalg.solve(self._mass_matrix(q), a))  # aᵀM⁻¹a > 0
        lin = float(a @ qd)
        c = (-lin + np.sqrt(lin * lin + 2.0 * quad * float(self.energy_j))) / quad
        return c * a / self.duration_s

    def set_context(self, ctx: DisturbanceContext) -> None:
        """Re-attach what ``reset`` took from the context (after unpickling)."""
        if self.energy_mode == "delivered" or self._onset_sized():
            self._mass_matrix = ctx.mass_matrix

    def schedule(self) -> dict[str, Any]:
        return {
            "onset_s": self._onset,
            "tau_nm": self._tau.copy(),
            "duration_s": self.duration_s,
            "sized": self._sized,
            **self._sizing_schedule(),
        }


@dataclass
class StepTorque(_SizedByMass):
    """A constant joint torque from a random onset to the episode's end: a·τ_max ⊙ u, or
    M(q_home)(α u) with ``accel_rad_s2``; with ``energy_j``, |τ_d| = energy_j /
    (mean|q_r'| · horizon), the most work it can do along the reference, in the direction
    of the former. ``sizing="onset"``: M(q_on)(α u), q_on the configuration at the onset
    (held from then on; with ``energy_j`` it sets the direction only)."""

    name: ClassVar[str] = "step"
    fraction: float = 0.1
    onset_s: float | tuple[float, float] = (1.0, 4.0)
    accel_rad_s2: float | None = None
    energy_j: float | None = None
    sizing: str = "home"

    def __post_init__(self) -> None:
        check_non_negative(self.fraction, "fraction")
        if self.energy_j is not None:
            check_non_negative(self.energy_j, "energy_j")
        check_sizing(self.sizing)

    def timed_events(self) -> tuple[TimedEvent, ...]:
        return (("onset_s", self.onset_s, 0.0),)

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._onset = draw(rng, self.onset_s)
        u = unit_vector(rng, ctx.n)
        self._sized, self._q_sized = True, None
        self._norm_nm = None if self.energy_j is None else _sustained_amplitude(ctx, self.energy_j)
        if self._onset_sized():
            self._u, self._mass_matrix = u, ctx.mass_matrix
            self._tau = np.full(ctx.n, np.nan)
            self._sized = False
        else:
            tau = _torque_vector(
                self.fraction, self.accel_rad_s2, u, ctx.torque_limits_nm, ctx.home_mass_matrix
            )
            self._tau = self._with_norm(tau)

    def _with_norm(self, tau: FloatArray) -> FloatArray:
        """τ, or with ``energy_j`` its direction at the sustained norm (N·m)."""
        return tau if self._norm_nm is None else _unit_like(tau) * self._norm_nm

    def acts_during(self, t0_s: float, t1_s: float) -> bool:
        return self._onset < t1_s

    def joint_torque(self, t_s: float, q: FloatArray, qd: FloatArray) -> FloatArray | None:
        if t_s < self._onset:
            return None
        if not self._sized:  # onset sizing: M(q_on), once
            self._q_sized = np.array(q, dtype=np.float64)
            self._tau = self._with_norm(self._mass_matrix(q) @ (self.accel_rad_s2 * self._u))
            self._sized = True
        return self._tau

    def schedule(self) -> dict[str, Any]:
        return {
            "onset_s": self._onset,
            "tau_nm": self._tau.copy(),
            "sized": self._sized,
            **self._sizing_schedule(),
        }


@dataclass
class PeriodicTorque(_SizedByMass):
    """τ_d,j(t) = A_j sin(2π f t + φ_j), A = a·τ_max ⊙ |u| (or |M(q_home) α|u|| with
    ``accel_rad_s2``), f drawn once per episode in ``frequency_hz``, phases φ_j uniform in
    [0, 2π) once per episode (never redrawn). With ``energy_j``: |A| = energy_j /
    (mean|q_r'| · horizon). ``direction`` fixes u (its absolute values weigh the joints).
    ``sizing="onset"``: A = |M(q₀) α|u||, q₀ the configuration at the first sub-step (the
    episode's start state), fixed for the episode (with ``energy_j``: its direction)."""

    name: ClassVar[str] = "periodic"
    fraction: float = 0.1
    frequency_hz: float | tuple[float, float] = (0.5, 2.0)
    accel_rad_s2: float | None = None
    energy_j: float | None = None
    direction: tuple[float, ...] | None = None
    sizing: str = "home"

    def __post_init__(self) -> None:
        check_non_negative(self.fraction, "fraction")
        check_non_negative(self.frequency_hz, "frequency_hz")
        if self.energy_j is not None:
            check_non_negative(self.energy_j, "energy_j")
        check_sizing(self.sizing)

    def validate(self, ctx: DisturbanceContext) -> None:
        if self.direction is not None:
            fixed_direction(self.direction, ctx.n, "direction")
        super().validate(ctx)

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._freq = draw(rng, self.frequency_hz)
        u = unit_vector(rng, ctx.n)  # drawn always: the phases' draws stay where they were
        if self.direction is not None:
            u = fixed_direction(self.direction, ctx.n, "direction")
        self._sized, self._q_sized = True, None
        self._norm_nm = None if self.energy_j is None else _sustained_amplitude(ctx, self.energy_j)
        if self._onset_sized():
            self._u_abs, self._mass_matrix = np.abs(u), ctx.mass_matrix
            self._amp = np.full(ctx.n, np.nan)
            self._sized = False
        else:
            amp = _torque_vector(
                self.fraction, self.accel_rad_s2, np.abs(u), ctx.torque_limits_nm,
                ctx.home_mass_matrix,
            )  # fmt: skip
            self._amp = self._with_norm(np.abs(amp))
        self._phase = rng.uniform(0.0, 2.0 * np.pi, ctx.n)

    def _with_norm(self, amp: FloatArray) -> FloatArray:
        """A, or with ``energy_j`` its direction at the sustained norm (N·m)."""
        return amp if self._norm_nm is None else _unit_like(amp) * self._norm_nm

    def joint_torque(self, t_s: float, q: FloatArray, qd: FloatArray) -> FloatArray | None:
        if not self._sized:  # onset sizing: M(q₀) at the first sub-step, once
            self._q_sized = np.array(q, dtype=np.float64)
            amp = self._mass_matrix(q) @ (self.accel_rad_s2 * self._u_abs)
            self._amp = self._with_norm(np.abs(amp))
            self._sized = True
        return self._amp * np.sin(2.0 * np.pi * self._freq * t_s + self._phase)

    def schedule(self) -> dict[str, Any]:
        return {
            "frequency_hz": self._freq,
            "amplitude_nm": self._amp.copy(),
            "phase_rad": self._phase.copy(),
            "sized": self._sized,
            **self._sizing_schedule(),
        }


@dataclass
class NoiseTorque(_SizedByMass):
    """Random joint torque, std σ = a·τ_max per joint (or α·M_jj(q_home) with
    ``accel_rad_s2``), drawn every physics sub-step.

    ``bandwidth_hz=None``: white (independent draws). Otherwise band-limited: a first-order
    low-pass (Ornstein–Uhlenbeck) process x ← ρx + √(1−ρ²)·σw, ρ = exp(−2π f_c dt), whose
    stationary std is σ and whose spectrum falls off above f_c.

    ``sizing="onset"`` (a noise acts all the time, so its "onset" is every draw): the
    torque is σ(q) ⊙ z, σ(q) = α·diag M(q) at the current q of each sub-step and z the
    unit-std process z ← ρz + √(1−ρ²)·w — the same w as home sizing draws, so the two are
    paired (home: σ(q_home) ⊙ z). Its std follows the arm's inertia at once, where scaling
    the increments would lag it by 1/(2π f_c)."""

    name: ClassVar[str] = "noise_torque"
    fraction: float = 0.05
    bandwidth_hz: float | None = 5.0
    accel_rad_s2: float | None = None
    sizing: str = "home"

    def __post_init__(self) -> None:
        check_non_negative(self.fraction, "fraction")
        if self.bandwidth_hz is not None and not self.bandwidth_hz > 0:
            raise InvalidConfigError(f"bandwidth_hz must be > 0 or None, got {self.bandwidth_hz!r}")
        check_sizing(self.sizing)

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._rng = rng
        self._rho = (
            0.0
            if self.bandwidth_hz is None
            else float(np.exp(-2.0 * np.pi * self.bandwidth_hz * ctx.physics_dt_s))
        )
        if self._onset_sized():
            self._mass_matrix = ctx.mass_matrix
            self._sigma = np.full(ctx.n, np.nan)  # σ(q) of the latest draw
            self._x = rng.standard_normal(ctx.n)  # z, unit std
            return
        self._sigma = (
            self.fraction * ctx.torque_limits_nm
            if self.accel_rad_s2 is None
            else self.accel_rad_s2 * np.diag(ctx.home_mass_matrix)
        )
        self._x = self._sigma * rng.standard_normal(ctx.n)

    def joint_torque(self, t_s: float, q: FloatArray, qd: FloatArray) -> FloatArray | None:
        w = self._rng.standard_normal(self._x.shape[0])
        if self._onset_sized():
            self._x = self._rho * self._x + np.sqrt(1.0 - self._rho**2) * w
            self._sigma = self.accel_rad_s2 * np.diag(self._mass_matrix(q))
            return self._sigma * self._x
        self._x = self._rho * self._x + np.sqrt(1.0 - self._rho**2) * self._sigma * w
        return self._x

    def schedule(self) -> dict[str, Any]:
        return {"std_nm": self._sigma.copy(), "sizing": self.sizing}
