"""PID control with gravity compensation, integral anti-windup by clamping.

.. math::

    \\tau = K_p e + K_d \\dot e + K_i z + g(q), \\qquad e = q_r - q, \\quad
    \\dot e = q_r' - \\dot q, \\quad z \\approx \\int_0^t e \\,dt

PD + gravity (:mod:`agents.pd_gravity`) plus integral action: a constant unmodelled torque
τ_c (a payload's weight, a gravity-model error, a constant push) leaves PD + g with the
steady error e = −K_p⁻¹τ_c at a set point; here the equilibrium needs K_i z = −τ_c and
e = 0. On a moving reference the integral also lowers the lag of PD + g at frequencies
below ω_i.

Integral state z (rad·s), updated once per control step of length dt (s) by forward Euler
and *clamped* (anti-windup):

.. math::

    z_{k+1} = \\mathrm{clip}\\big(z_k + e_k\\,dt,\\; -\\bar u / K_i,\\; \\bar u / K_i\\big),
    \\qquad \\bar u = f_w\\, \\tau_{max} \\;(\\mathrm{N{\\cdot}m}),

so the integral torque K_i z never exceeds ū per joint, whatever the error's history
(while the arm is blocked or the torque saturates): it starts unwinding as soon as e changes
sign. τ at step k uses z_k (the integral up to t_k); ``reset`` sets z = 0.

Default gains: pole placement for a decoupled joint of inertia m (kg·m²), whose error
obeys m s³ + K_d s² + K_p s + K_i = 0 near home; the poles are those of

.. math::

    (s + \\omega_i)(s^2 + 2\\zeta\\omega s + \\omega^2):
    \\quad K_p = (\\omega^2 + 2\\zeta\\omega\\omega_i)\\,m, \\quad
    K_d = (2\\zeta\\omega + \\omega_i)\\,m, \\quad K_i = \\omega^2\\omega_i\\,m,

K_p in N·m/rad, K_d in N·m·s/rad, K_i in N·m/(rad·s), with m = diag M(q_home) of the
nominal model, ω (rad/s), ζ and ω_i (1/s, the integral rate) the robot profile's
``controller_gains["pid_gravity"]`` (else :data:`DEFAULT_RATES`); ω_i → 0 gives PD + g.
ω is capped as PD + g's (:func:`agents.gains.home_inertia_bandwidth`: α / dt, and the
coupled modes of M(q)⁻¹K_p, M(q)⁻¹K_d on the path) with the ratio κ = ω_i / ω kept, so a
capped ω lowers ω_i alike. ū = f_w τ_max, f_w = ``windup_fraction`` of each joint's
torque limit (the profile's ``torque_limits_nm``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from agents.base import ControlContext, FloatArray
from agents.gains import DiagonalGains, Gain, gain_vector, home_inertia_bandwidth, rates, rounded
from agents.reference_clock import ReferenceErrors
from agents.time_indexed import TimeIndexedController
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.paths import ReferencePath
from ptrack_gym.robots.model import RobotModel

#: The gain rates (:class:`agents.registry.RateSource`): ω (rad/s), ζ, the integral rate
#: ω_i (1/s) and the anti-windup bound f_w (fraction of the torque limit, not tuned).
NAME = "pid_gravity"
DEFAULT_RATES = {"omega": 20.0, "zeta": 1.0, "omega_i": 5.0, "windup_fraction": 0.5}
BANDWIDTHS = ("omega", "omega_i")
TUNABLE = {"omega": (3.0, 100.0, True), "zeta": (0.5, 2.0, False), "omega_i": (0.3, 30.0, True)}


@dataclass(frozen=True)
class PIDGravityGains(DiagonalGains):
    """Gains of :class:`PIDGravityController`, diagonal (:class:`~agents.gains.DiagonalGains`).

    Attributes:
        kp_nm_rad: K_p (N·m/rad).
        kd_nms_rad: K_d (N·m·s/rad).
        ki_nm_rad_s: K_i (N·m/(rad·s)), on the integral z = ∫e dt (rad·s).
        windup_nm: ū (N·m), the bound of the integral torque |K_i z| per joint.
    """

    kp_nm_rad: Gain
    kd_nms_rad: Gain
    ki_nm_rad_s: Gain
    windup_nm: Gain

    @classmethod
    def from_inertia(
        cls,
        inertia_kgm2: FloatArray,
        omega_rad_s: float,
        zeta: float,
        omega_i_1_s: float,
        windup_nm: FloatArray,
    ) -> PIDGravityGains:
        """Poles at −ω_i and the roots of s² + 2ζωs + ω² for joint inertias m (kg·m²):
        K_p = (ω² + 2ζωω_i) m, K_d = (2ζω + ω_i) m, K_i = ω²ω_i m; ū = ``windup_nm``."""
        m = np.asarray(inertia_kgm2, dtype=np.float64)
        w, wi = omega_rad_s, omega_i_1_s
        return cls(
            kp_nm_rad=rounded((w**2 + 2.0 * zeta * w * wi) * m),
            kd_nms_rad=rounded((2.0 * zeta * w + wi) * m),
            ki_nm_rad_s=rounded(w**2 * wi * m),
            windup_nm=rounded(np.asarray(windup_nm, dtype=np.float64)),
        )


def gains_from_rates(ctx: ControlContext, given: Mapping[str, float] | None) -> PIDGravityGains:
    """Absolute gains from rates — ``DEFAULT_RATES``, updated by the robot's profile rates,
    updated by ``given`` — at the context's control rate (module docstring).

    Raises:
        InvalidConfigError: an unknown rate, or ``windup_fraction`` outside (0, 1].
    """
    r = rates(DEFAULT_RATES, given, NAME, ctx.profile.controller_gains.get(NAME))
    fraction = float(r["windup_fraction"])
    if not 0.0 < fraction <= 1.0:
        raise InvalidConfigError(f"windup_fraction must lie in (0, 1], got {fraction!r}")
    zeta, kappa = r["zeta"], r["omega_i"] / r["omega"]
    # stiffness (1 + 2ζκ) ω² M⁻¹m, damping (2ζ + κ) ω M⁻¹m (per ω², ω)
    inertia, omega = home_inertia_bandwidth(
        ctx, r["omega"], 1.0 + 2.0 * zeta * kappa, 2.0 * zeta + kappa
    )
    windup = fraction * np.asarray(ctx.profile.torque_limits_nm, dtype=np.float64)  # (n,) N·m
    return PIDGravityGains.from_inertia(inertia, omega, zeta, kappa * omega, windup)


def default_gains(ctx: ControlContext) -> PIDGravityGains:
    """The robot's default gains at the context's control rate: the profile's rates."""
    return gains_from_rates(ctx, None)


class PIDGravityController(TimeIndexedController):
    """PID + gravity compensation with a clamped integral (module docstring) on the
    time-indexed reference q_r(s), s = s₀ + t, with :class:`PIDGravityGains`; of the model
    only g(q) is used. Arguments, clock and errors:
    :class:`~agents.time_indexed.TimeIndexedController`."""

    gains_type = PIDGravityGains
    rates_to_gains = staticmethod(gains_from_rates)
    gains: PIDGravityGains

    def __init__(self, model: RobotModel, path: ReferencePath, gains: PIDGravityGains) -> None:
        super().__init__(model, path, gains)
        self.kp = gain_vector(gains.kp_nm_rad, self.n, "kp_nm_rad")  # (n,) N·m/rad
        self.kd = gain_vector(gains.kd_nms_rad, self.n, "kd_nms_rad")  # (n,) N·m·s/rad
        self.ki = gain_vector(gains.ki_nm_rad_s, self.n, "ki_nm_rad_s")  # (n,) N·m/(rad·s)
        self.windup = gain_vector(gains.windup_nm, self.n, "windup_nm")  # (n,) N·m
        self.z_max = self.windup / self.ki  # (n,) rad·s, the clamp of z
        self.z = np.zeros(self.n)  # (n,) rad·s, the integral state

    def reset(self, q: FloatArray, qd: FloatArray, s_ref: float) -> None:
        """Start the clock at s = ``s_ref`` (s) and clear the integral, z = 0."""
        super().reset(q, qd, s_ref)
        self.z = np.zeros(self.n)

    def step(self, q: FloatArray, qd: FloatArray, dt: float) -> FloatArray:
        """τ (N·m) of :meth:`torque` with z_k; then z ← clip(z + e dt, ±ū/K_i) and
        s ← s + dt (s)."""
        tau = super().step(q, qd, dt)
        assert self._last is not None
        self.z = np.clip(self.z + dt * self._last[1].e, -self.z_max, self.z_max)
        return tau

    def integral_torque(self) -> FloatArray:
        """K_i z (N·m), shape (n,): the integral term of the next step, |K_i z| ≤ ū."""
        return self.ki * self.z

    def torque(self, q: FloatArray, qd: FloatArray, err: ReferenceErrors) -> FloatArray:
        """τ = K_p e + K_d ė + K_i z + g(q) (N·m), shape (n,)."""
        return self.kp * err.e + self.kd * err.ed + self.ki * self.z + self.model.gravity(q)

    def diagnostics(self) -> dict[str, float]:
        """Those of :class:`~agents.time_indexed.TimeIndexedController` and
        ``integral_torque_nm`` |K_i z| (N·m) after the last step's update."""
        return {
            **super().diagnostics(),
            "integral_torque_nm": float(np.linalg.norm(self.ki * self.z)),
        }


#: The controller for a context: default gains, the given gains, or gains from given rates
#: (:meth:`~agents.time_indexed.TimeIndexedController.build`).
build = PIDGravityController.build
