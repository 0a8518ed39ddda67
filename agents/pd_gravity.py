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

from agents.base import ControlContext, FeatureBlock, FloatArray, state_arrays
from agents.gains import (
    Gain,
    cap_bandwidth,
    cap_coupled_bandwidth,
    check_gain,
    coupling_ratio,
    gain_vector,
    rates,
    rounded,
)
from agents.reference_clock import (
    ReferenceClock,
    ReferenceErrors,
    error_diagnostics,
    time_indexed_features,
)
from ptrack_gym.paths import ReferencePath
from ptrack_gym.robots.model import RobotModel, home_inertia_kgm2

NAME = "pd_gravity"
#: Generic default rates: ω (rad/s), ζ.
DEFAULT_RATES = {"omega": 20.0, "zeta": 1.0}
#: What ``python -m train.tune`` searches: rate → (low, high, log scale).
#: The rates one gain scale multiplies (``python -m train.fronts``): the bandwidth.
BANDWIDTHS = ("omega",)
TUNABLE = {"omega": (3.0, 100.0, True), "zeta": (0.5, 2.0, False)}


@dataclass(frozen=True)
class PDGravityGains:
    """Gains of :class:`PDGravityController`.

    Attributes:
        kp_nm_rad: K_p (N·m/rad).
        kd_nms_rad: K_d (N·m·s/rad).
    """

    kp_nm_rad: Gain
    kd_nms_rad: Gain

    def __post_init__(self) -> None:
        object.__setattr__(self, "kp_nm_rad", check_gain(self.kp_nm_rad, "kp_nm_rad"))
        object.__setattr__(self, "kd_nms_rad", check_gain(self.kd_nms_rad, "kd_nms_rad"))

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
    inertia = home_inertia_kgm2(ctx.model, ctx.profile)
    ratio = coupling_ratio(ctx.model, ctx.path, inertia)
    omega = cap_coupled_bandwidth(
        cap_bandwidth(r["omega"], ctx.dt_s), ctx.dt_s, ratio, 2.0 * r["zeta"] * ratio
    )
    return PDGravityGains.from_inertia(inertia, omega, r["zeta"])


def default_gains(ctx: ControlContext) -> PDGravityGains:
    """The robot's default gains at the context's control rate: the profile's rates."""
    return gains_from_rates(ctx, None)


class PDGravityController:
    """PD + gravity compensation on the time-indexed reference q_r(s), s = s₀ + t.

    The clock is set to the env's reference phase by :meth:`reset` and advanced by ``dt``
    in :meth:`step`.

    Args:
        model: the controller's nominal dynamics model (only g(q) is used).
        path: the reference path q_r(s), s in seconds.
        gains: K_p (N·m/rad) and K_d (N·m·s/rad), diagonal.

    Raises:
        InvalidConfigError: (a ``ValueError``) bad gains, or a model/path mismatch.
    """

    def __init__(self, model: RobotModel, path: ReferencePath, gains: PDGravityGains) -> None:
        if not isinstance(gains, PDGravityGains):
            raise TypeError(f"gains must be PDGravityGains, got {type(gains).__name__}")
        self.clock = ReferenceClock(model, path)
        self.model = model
        self.path = path
        self.gains = gains
        self.n = model.n
        self.kp = gain_vector(gains.kp_nm_rad, self.n, "kp_nm_rad")  # (n,) N·m/rad
        self.kd = gain_vector(gains.kd_nms_rad, self.n, "kd_nms_rad")  # (n,) N·m·s/rad
        self._last: tuple[float, ReferenceErrors] | None = None  # (s after, errors)
        self._s0 = 0.0

    def reset(self, q: FloatArray, qd: FloatArray, s_ref: float) -> None:
        """Start the clock at s = ``s_ref`` (s)."""
        self.clock.reset(s_ref)
        self._last, self._s0 = None, float(s_ref)

    def step(self, q: FloatArray, qd: FloatArray, dt: float) -> FloatArray:
        """τ = K_p e + K_d ė + g(q) (N·m), shape (n,); then s ← s + dt."""
        q, qd = state_arrays(q, qd)
        err = self.clock.errors(q, qd, dt)
        tau = self.kp * err.e + self.kd * err.ed + self.model.gravity(q)
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
    ctx: ControlContext, gains: PDGravityGains | Mapping[str, float] | None = None
) -> PDGravityController:
    """The controller for a context: its default gains, the given gains, or gains from the
    given rates (a mapping, e.g. tuned ones)."""
    if gains is None:
        gains = default_gains(ctx)
    elif isinstance(gains, Mapping):
        gains = gains_from_rates(ctx, gains)
    return PDGravityController(ctx.model, ctx.path, gains)
