"""PD control with gravity compensation and reference velocity feed-forward.

.. math::

    \\tau = K_p e + K_d \\dot e + g(q), \\qquad e = q_r - q, \\quad \\dot e = q_r' - \\dot q

Takegaki & Arimoto (1981) proved this law (without q_r') globally asymptotically stable
for a *fixed* set point. On a moving reference it is not a tracking controller: the
inertial and Coriolis torques M q̈_r + C q̇_r of the reference are never supplied, so the
arm lags the reference by roughly e ≈ K_p⁻¹ (M q̈_r + C q̇_r). ``docs/baselines.md`` reports
the size of that steady error on each robot.

Default gains: K_p = ω² diag(m) (N·m/rad), K_d = 2ζω diag(m) (N·m·s/rad), m = diag M(q_home)
of the nominal model — the poles of computed torque for a decoupled arm near home — with ω
the robot profile's ``controller_gains["pd_gravity"]["omega"]`` (rad/s), capped at α / dt
(:func:`agents.gains.cap_bandwidth`) and where the coupled modes of M(q)⁻¹K_p and M(q)⁻¹K_d
on the path would outrun the control rate (:func:`agents.gains.cap_coupled_bandwidth`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from agents.base import ControlContext, FloatArray
from agents.gains import DiagonalGains, Gain, gain_vector, home_inertia_bandwidth, rates, rounded
from agents.reference_clock import ReferenceErrors
from agents.time_indexed import TimeIndexedController
from ptrack_gym.paths import ReferencePath
from ptrack_gym.robots.model import RobotModel

#: The gain rates (:class:`agents.registry.RateSource`): ω (rad/s) and ζ, ω the bandwidth.
NAME = "pd_gravity"
DEFAULT_RATES = {"omega": 20.0, "zeta": 1.0}
BANDWIDTHS = ("omega",)
TUNABLE = {"omega": (3.0, 100.0, True), "zeta": (0.5, 2.0, False)}


@dataclass(frozen=True)
class PDGravityGains(DiagonalGains):
    """Gains of :class:`PDGravityController`, diagonal (:class:`~agents.gains.DiagonalGains`).

    Attributes:
        kp_nm_rad: K_p (N·m/rad).
        kd_nms_rad: K_d (N·m·s/rad).
    """

    kp_nm_rad: Gain
    kd_nms_rad: Gain

    @classmethod
    def from_inertia(
        cls, inertia_kgm2: FloatArray, omega_rad_s: float, zeta: float = 1.0
    ) -> PDGravityGains:
        """K_p = ω² m, K_d = 2ζω m, with m the joint inertias (kg·m²), e.g. diag M(q_home)."""
        m = np.asarray(inertia_kgm2, dtype=np.float64)
        return cls(
            kp_nm_rad=rounded(omega_rad_s**2 * m),
            kd_nms_rad=rounded(2.0 * zeta * omega_rad_s * m),
        )


def gains_from_rates(ctx: ControlContext, given: Mapping[str, float] | None) -> PDGravityGains:
    """Absolute gains from rates — ``DEFAULT_RATES``, updated by the robot's profile rates,
    updated by ``given`` — at the context's control rate (module docstring)."""
    r = rates(DEFAULT_RATES, given, NAME, ctx.profile.controller_gains.get(NAME))
    # stiffness ω² M⁻¹m, damping 2ζω M⁻¹m (per ω², ω)
    inertia, omega = home_inertia_bandwidth(ctx, r["omega"], 1.0, 2.0 * r["zeta"])
    return PDGravityGains.from_inertia(inertia, omega, r["zeta"])


def default_gains(ctx: ControlContext) -> PDGravityGains:
    """The robot's default gains at the context's control rate: the profile's rates."""
    return gains_from_rates(ctx, None)


class PDGravityController(TimeIndexedController):
    """PD + gravity compensation (module docstring) on the time-indexed reference q_r(s),
    s = s₀ + t, with :class:`PDGravityGains`; of the model only g(q) is used. Arguments,
    clock and errors: :class:`~agents.time_indexed.TimeIndexedController`."""

    gains_type = PDGravityGains
    rates_to_gains = staticmethod(gains_from_rates)
    gains: PDGravityGains

    def __init__(self, model: RobotModel, path: ReferencePath, gains: PDGravityGains) -> None:
        super().__init__(model, path, gains)
        self.kp = gain_vector(gains.kp_nm_rad, self.n, "kp_nm_rad")  # (n,) N·m/rad
        self.kd = gain_vector(gains.kd_nms_rad, self.n, "kd_nms_rad")  # (n,) N·m·s/rad

    def torque(self, q: FloatArray, qd: FloatArray, err: ReferenceErrors) -> FloatArray:
        """τ = K_p e + K_d ė + g(q) (N·m), shape (n,)."""
        return self.kp * err.e + self.kd * err.ed + self.model.gravity(q)


#: The controller for a context: default gains, the given gains, or gains from given rates
#: (:meth:`~agents.time_indexed.TimeIndexedController.build`).
build = PDGravityController.build
