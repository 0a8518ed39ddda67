"""Computed-torque (inverse-dynamics) tracking of the time-indexed reference q_r(t).

.. math::

    \\tau = M(q)\\,(\\ddot q_r + K_d \\dot e + K_p e) + C(q, \\dot q)\\dot q + g(q),
    \\qquad e = q_r - q, \\quad \\dot e = q_r' - \\dot q

With the exact model the closed loop is linear and decoupled, ë + K_d ė + K_p e = 0.
Default gains: K_p = ω² I (1/s²), K_d = 2ζω I (1/s) — a double pole at −ω for ζ = 1 —
with ω the robot profile's ``controller_gains["computed_torque"]["omega"]`` (rad/s),
capped at α / dt (:func:`agents.gains.cap_bandwidth`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from agents.base import ControlContext, FloatArray
from agents.gains import DiagonalGains, Gain, cap_bandwidth, gain_vector, rates
from agents.reference_clock import ReferenceErrors
from agents.time_indexed import TimeIndexedController
from ptrack_gym.paths import ReferencePath
from ptrack_gym.robots.model import RobotModel

#: The gain rates (:class:`agents.registry.RateSource`): ω (rad/s) and ζ, ω the bandwidth.
NAME = "computed_torque"
DEFAULT_RATES = {"omega": 20.0, "zeta": 1.0}
BANDWIDTHS = ("omega",)
TUNABLE = {"omega": (3.0, 100.0, True), "zeta": (0.5, 2.0, False)}


@dataclass(frozen=True)
class ComputedTorqueGains(DiagonalGains):
    """Gains of :class:`ComputedTorqueController`, diagonal (:class:`~agents.gains.DiagonalGains`).

    Attributes:
        kp_1_s2: K_p (1/s²), the stiffness of the error dynamics ë + K_d ė + K_p e = 0.
        kd_1_s: K_d (1/s), its damping.
    """

    kp_1_s2: Gain
    kd_1_s: Gain

    @classmethod
    def from_bandwidth(cls, omega_rad_s: float, zeta: float = 1.0) -> ComputedTorqueGains:
        """K_p = ω², K_d = 2ζω on every joint (ω in rad/s)."""
        return cls(kp_1_s2=omega_rad_s**2, kd_1_s=2.0 * zeta * omega_rad_s)


def gains_from_rates(ctx: ControlContext, given: Mapping[str, float] | None) -> ComputedTorqueGains:
    """Absolute gains from rates — ``DEFAULT_RATES``, updated by the robot's profile rates,
    updated by ``given`` — at the context's control rate (module docstring)."""
    r = rates(DEFAULT_RATES, given, NAME, ctx.profile.controller_gains.get(NAME))
    return ComputedTorqueGains.from_bandwidth(cap_bandwidth(r["omega"], ctx.dt_s), r["zeta"])


def default_gains(ctx: ControlContext) -> ComputedTorqueGains:
    """The robot's default gains at the context's control rate: the profile's rates."""
    return gains_from_rates(ctx, None)


class ComputedTorqueController(TimeIndexedController):
    """Computed torque (module docstring) on the nominal model, tracking q_r(s), s = s₀ + t;
    constructed, reset and stepped as :class:`~agents.time_indexed.TimeIndexedController`
    with :class:`ComputedTorqueGains`."""

    gains_type = ComputedTorqueGains
    rates_to_gains = staticmethod(gains_from_rates)
    gains: ComputedTorqueGains

    def __init__(self, model: RobotModel, path: ReferencePath, gains: ComputedTorqueGains) -> None:
        super().__init__(model, path, gains)
        self.kp = gain_vector(gains.kp_1_s2, self.n, "kp_1_s2")  # (n,) 1/s²
        self.kd = gain_vector(gains.kd_1_s, self.n, "kd_1_s")  # (n,) 1/s

    def torque(self, q: FloatArray, qd: FloatArray, err: ReferenceErrors) -> FloatArray:
        """τ = ID(q, q̇, q̈_r + K_d ė + K_p e) (N·m), shape (n,): one inverse-dynamics call
        gives M(q) v + C(q, q̇) q̇ + g(q) exactly."""
        v = err.qdd_r + self.kd * err.ed + self.kp * err.e  # (n,) rad/s²
        return self.model.inverse_dynamics(q, qd, v)


#: The controller for a context: default gains, the given gains, or gains from given rates
#: (:meth:`~agents.time_indexed.TimeIndexedController.build`).
build = ComputedTorqueController.build
