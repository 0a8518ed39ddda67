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

from agents.base import ControlContext, FeatureBlock, FloatArray, state_arrays
from agents.gains import Gain, cap_bandwidth, check_gain, gain_vector, rates
from agents.reference_clock import (
    ReferenceClock,
    ReferenceErrors,
    error_diagnostics,
    time_indexed_features,
)
from ptrack_gym.paths import ReferencePath
from ptrack_gym.robots.model import RobotModel

NAME = "computed_torque"
#: Generic default rates: ω (rad/s), ζ.
DEFAULT_RATES = {"omega": 20.0, "zeta": 1.0}
#: What ``python -m train.tune`` searches: rate → (low, high, log scale).
#: The rates one gain scale multiplies (``python -m train.fronts``): the bandwidth.
BANDWIDTHS = ("omega",)
TUNABLE = {"omega": (3.0, 100.0, True), "zeta": (0.5, 2.0, False)}


@dataclass(frozen=True)
class ComputedTorqueGains:
    """Gains of :class:`ComputedTorqueController`.

    Attributes:
        kp_1_s2: K_p (1/s²), the stiffness of the error dynamics ë + K_d ė + K_p e = 0.
        kd_1_s: K_d (1/s), its damping.
    """

    kp_1_s2: Gain
    kd_1_s: Gain

    def __post_init__(self) -> None:
        object.__setattr__(self, "kp_1_s2", check_gain(self.kp_1_s2, "kp_1_s2"))
        object.__setattr__(self, "kd_1_s", check_gain(self.kd_1_s, "kd_1_s"))

    @classmethod
    def from_bandwidth(cls, omega_rad_s: float, zeta: float = 1.0) -> ComputedTorqueGains:
        """K_p = ω², K_d = 2ζω on every joint."""
        return cls(kp_1_s2=omega_rad_s**2, kd_1_s=2.0 * zeta * omega_rad_s)


def gains_from_rates(ctx: ControlContext, given: Mapping[str, float] | None) -> ComputedTorqueGains:
    """Absolute gains from rates — ``DEFAULT_RATES``, updated by the robot's profile rates,
    updated by ``given`` — at the context's control rate (module docstring)."""
    r = rates(DEFAULT_RATES, given, NAME, ctx.profile.controller_gains.get(NAME))
    return ComputedTorqueGains.from_bandwidth(cap_bandwidth(r["omega"], ctx.dt_s), r["zeta"])


def default_gains(ctx: ControlContext) -> ComputedTorqueGains:
    """The robot's default gains at the context's control rate: the profile's rates."""
    return gains_from_rates(ctx, None)


class ComputedTorqueController:
    """Computed torque on the nominal model, tracking q_r(s) with an internal clock s.

    The clock is set to the env's reference phase by :meth:`reset` and advanced by ``dt``
    in :meth:`step`, so s = s₀ + t: the reference is time-indexed.

    Args:
        model: the controller's nominal dynamics model (never the simulator).
        path: the reference path q_r(s), s in seconds.
        gains: K_p (1/s²) and K_d (1/s), diagonal.

    Raises:
        InvalidConfigError: (a ``ValueError``) bad gains, or a model/path mismatch.
    """

    def __init__(self, model: RobotModel, path: ReferencePath, gains: ComputedTorqueGains) -> None:
        if not isinstance(gains, ComputedTorqueGains):
            raise TypeError(f"gains must be ComputedTorqueGains, got {type(gains).__name__}")
        self.clock = ReferenceClock(model, path)
        self.model = model
        self.path = path
        self.gains = gains
        self.n = model.n
        self.kp = gain_vector(gains.kp_1_s2, self.n, "kp_1_s2")  # (n,) 1/s²
        self.kd = gain_vector(gains.kd_1_s, self.n, "kd_1_s")  # (n,) 1/s
        self._last: tuple[float, ReferenceErrors] | None = None  # (s after, errors)
        self._s0 = 0.0

    def reset(self, q: FloatArray, qd: FloatArray, s_ref: float) -> None:
        """Start the clock at s = ``s_ref`` (s)."""
        self.clock.reset(s_ref)
        self._last, self._s0 = None, float(s_ref)

    def step(self, q: FloatArray, qd: FloatArray, dt: float) -> FloatArray:
        """τ = ID(q, q̇, q̈_r + K_d ė + K_p e) (N·m), shape (n,); then s ← s + dt.

        One inverse-dynamics call gives M(q) v + C(q, q̇) q̇ + g(q) exactly.
        """
        q, qd = state_arrays(q, qd)
        err = self.clock.errors(q, qd, dt)
        v = err.qdd_r + self.kd * err.ed + self.kp * err.e  # (n,) rad/s²
        tau = self.model.inverse_dynamics(q, qd, v)
        self._last = (self.clock.advance(dt), err)
        return tau

    def diagnostics(self) -> dict[str, float]:
        """``s``: the clock after the last step (s), equal to the env's ``s_ref`` then;
        ``tracking_error`` |e| (rad) and ``velocity_error`` |ė| (rad/s) of the state
        passed to the last step (against q_r(s − dt))."""
        return {"s": self._s0} if self._last is None else error_diagnostics(*self._last)

    def residual_features(self, max_speed_rad_s: float) -> FeatureBlock:
        """e, ė against the clock (see :func:`agents.reference_clock.time_indexed_features`)."""
        return time_indexed_features(self.clock, self.n, max_speed_rad_s)


def build(
    ctx: ControlContext, gains: ComputedTorqueGains | Mapping[str, float] | None = None
) -> ComputedTorqueController:
    """The controller for a context: its default gains, the given gains, or gains from the
    given rates (a mapping, e.g. tuned ones)."""
    if gains is None:
        gains = default_gains(ctx)
    elif isinstance(gains, Mapping):
        gains = gains_from_rates(ctx, gains)
    return ComputedTorqueController(ctx.model, ctx.path, gains)
