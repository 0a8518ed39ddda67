"""Computed torque with De Luca's generalized-momentum observer of the external torque.

The plant is M(q) q̈ + C(q, q̇) q̇ + g(q) = τ + τ_ext, τ_ext (N·m) every joint torque the
nominal model does not predict (a load, a push, a payload, model error). With the
generalized momentum p = M(q) q̇ (N·m·s) and Ṁ = C + Cᵀ (C the Christoffel Coriolis
matrix), ṗ = τ + Cᵀ(q, q̇) q̇ − g(q) + τ_ext, a relation without q̈. The residual of De Luca
& Mattone (ICRA 2003; ICRA 2005, "Sensorless robot collision detection and hybrid
force/motion control")

.. math::

    r(t) = K_O \\Big[\\, p(t) - p(0)
        - \\int_0^t \\big(\\tau + C^T(q, \\dot q)\\,\\dot q - g(q) + r\\big)\\,dt \\Big]

(N·m) obeys ṙ = K_O (τ_ext − r): a first-order low-pass estimate of τ_ext with rate K_O
(1/s) per joint, from measured (q, q̇) and the applied τ only. The estimate is subtracted
from computed torque (:mod:`agents.computed_torque`),

.. math::

    \\tau = \\mathrm{ID}(q, \\dot q, \\ddot q_r + K_d \\dot e + K_p e) - r,

so on the nominal model the error obeys ë + K_d ė + K_p e = M(q)⁻¹(τ_ext − r) → 0 for a
constant τ_ext (plain computed torque keeps e = M⁻¹τ_ext / K_p at a set point).

Discretization for a zero-order hold of period dt (s): τ_{k−1} is applied over
[t_{k−1}, t_k], so at step k

.. math::

    S_k = S_{k-1} + dt\\,\\big(\\bar\\tau_{k-1} + C^T(q_{k-1}, \\dot q_{k-1})\\,\\dot q_{k-1}
        - g(q_{k-1}) + r_{k-1}\\big), \\qquad r_k = K_O\\,(p_k - p_0 - S_k),

S₀ = 0, r₀ = 0, τ̄ = clip(τ, −τ_max, τ_max) the torque the env applies. Then
r_k ≈ (1 − K_O dt) r_{k−1} + K_O dt τ_ext: a discrete low-pass that is monotone for
K_O dt < 1; K_O is capped at α / dt (α = 0.2, :func:`agents.gains.cap_bandwidth`).

The observer integrates the torque actually applied: its own, or the sum a wrapper reports
through :meth:`ObserverComputedTorqueController.applied_torque` (the residual wrapper
reports base + residual), so a residual policy's correction is not estimated as external
and cancelled.

Default gains: K_p = ω² (1/s²), K_d = 2ζω (1/s) as computed torque's, K_O = ω_o (1/s)
on every joint, ω and ω_o capped at α / dt; the rates are the robot profile's
``controller_gains["computed_torque_observer"]`` (else :data:`DEFAULT_RATES`). The model
must offer ``coriolis_matrix(q, q̇)`` (:class:`~ptrack_gym.robots.model.PinocchioModel`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from agents.base import ControlContext, FloatArray, state_arrays
from agents.gains import DiagonalGains, Gain, cap_bandwidth, gain_vector, rates
from agents.reference_clock import ReferenceErrors
from agents.time_indexed import TimeIndexedController
from ptrack_gym.errors import InvalidArgumentError
from ptrack_gym.paths import ReferencePath
from ptrack_gym.robots.model import RobotModel

#: The gain rates (:class:`agents.registry.RateSource`): ω (rad/s), ζ and the observer
#: rate ω_o (1/s); ω and ω_o the bandwidths.
NAME = "computed_torque_observer"
DEFAULT_RATES = {"omega": 20.0, "zeta": 1.0, "omega_o": 50.0}
BANDWIDTHS = ("omega", "omega_o")
TUNABLE = {"omega": (3.0, 100.0, True), "zeta": (0.5, 2.0, False), "omega_o": (3.0, 200.0, True)}


@dataclass(frozen=True)
class ObserverComputedTorqueGains(DiagonalGains):
    """Gains of :class:`ObserverComputedTorqueController` (diagonal).

    Attributes:
        kp_1_s2: K_p (1/s²), the stiffness of the error dynamics ë + K_d ė + K_p e = 0.
        kd_1_s: K_d (1/s), its damping.
        ko_1_s: K_O (1/s), the observer's rate: ṙ = K_O (τ_ext − r).
    """

    kp_1_s2: Gain
    kd_1_s: Gain
    ko_1_s: Gain

    @classmethod
    def from_bandwidth(
        cls, omega_rad_s: float, zeta: float, omega_o_1_s: float
    ) -> ObserverComputedTorqueGains:
        """K_p = ω², K_d = 2ζω, K_O = ω_o on every joint (ω in rad/s, ω_o in 1/s)."""
        return cls(kp_1_s2=omega_rad_s**2, kd_1_s=2.0 * zeta * omega_rad_s, ko_1_s=omega_o_1_s)


def gains_from_rates(
    ctx: ControlContext, given: Mapping[str, float] | None
) -> ObserverComputedTorqueGains:
    """Absolute gains from rates — ``DEFAULT_RATES``, updated by the robot's profile rates,
    updated by ``given`` — at the context's control rate (module docstring)."""
    r = rates(DEFAULT_RATES, given, NAME, ctx.profile.controller_gains.get(NAME))
    return ObserverComputedTorqueGains.from_bandwidth(
        cap_bandwidth(r["omega"], ctx.dt_s), r["zeta"], cap_bandwidth(r["omega_o"], ctx.dt_s)
    )


def default_gains(ctx: ControlContext) -> ObserverComputedTorqueGains:
    """The robot's default gains at the context's control rate: the profile's rates."""
    return gains_from_rates(ctx, None)


class MomentumObserver:
    """De Luca's generalized-momentum residual r (module docstring), discretized for a
    zero-order hold: :meth:`update` at each measured state, :meth:`applied` with the torque
    then commanded.

    Args:
        model: the nominal model; it must have ``coriolis_matrix(q, q̇)`` (N·m·s/rad).
        ko_1_s: K_O (1/s), shape (n,).
        torque_limits_nm: τ_max (N·m), shape (n,): the commanded torque is clipped to it
            as the env does; None takes it as applied unclipped.

    Raises:
        InvalidArgumentError: (a ``TypeError``) a model without ``coriolis_matrix``.
    """

    def __init__(
        self, model: RobotModel, ko_1_s: FloatArray, torque_limits_nm: FloatArray | None = None
    ) -> None:
        if not callable(getattr(model, "coriolis_matrix", None)):
            raise InvalidArgumentError(
                f"the momentum observer needs the Coriolis matrix C(q, q̇): "
                f"{type(model).__name__} has no coriolis_matrix(q, qd) (use PinocchioModel)"
            )
        self.model = model
        self._coriolis_matrix: Callable[[FloatArray, FloatArray], FloatArray] = (
            model.coriolis_matrix  # type: ignore[attr-defined]  # checked above
        )
        self.ko = np.asarray(ko_1_s, dtype=np.float64)  # (n,) 1/s
        self.limit = None if torque_limits_nm is None else np.asarray(torque_limits_nm, np.float64)
        n = self.ko.shape[0]
        self.r = np.zeros(n)  # (n,) N·m, the estimate of τ_ext
        self._p0 = np.zeros(n)  # (n,) N·m·s, p(0)
        self._sum = np.zeros(n)  # (n,) N·m·s, S_k
        self._beta = np.zeros(n)  # (n,) N·m, Cᵀq̇ − g at the last state
        self._pending: tuple[FloatArray, float] | None = None  # (τ̄_{k−1}, dt)

    def reset(self, q: FloatArray, qd: FloatArray) -> None:
        """Start at (q, q̇) (rad, rad/s): p₀ = M(q) q̇, S = 0, r = 0."""
        self._p0 = self.model.mass_matrix(q) @ qd
        self._sum = np.zeros_like(self._p0)
        self.r = np.zeros_like(self._p0)
        self._beta = np.zeros_like(self._p0)
        self._pending = None

    def _momentum_rate(self, q: FloatArray, qd: FloatArray) -> FloatArray:
        """β = Cᵀ(q, q̇) q̇ − g(q) (N·m), shape (n,): ṗ − τ − τ_ext."""
        return self._coriolis_matrix(q, qd).T @ qd - self.model.gravity(q)

    def update(self, q: FloatArray, qd: FloatArray) -> FloatArray:
        """r_k (N·m), shape (n,), at the measured (q_k, q̇_k): S_k adds the last step's
        dt (τ̄_{k−1} + β_{k−1} + r_{k−1}); r_k = K_O (M(q_k) q̇_k − p₀ − S_k)."""
        if self._pending is not None:
            tau_prev, dt = self._pending
            self._sum = self._sum + dt * (tau_prev + self._beta + self.r)
            self.r = self.ko * (self.model.mass_matrix(q) @ qd - self._p0 - self._sum)
        self._beta = self._momentum_rate(q, qd)
        self._pending = None
        return self.r

    def applied(self, tau_nm: FloatArray, dt: float) -> None:
        """Record τ (N·m), commanded for the next ``dt`` seconds (clipped to τ_max)."""
        tau = tau_nm if self.limit is None else np.clip(tau_nm, -self.limit, self.limit)
        self._pending = (tau, float(dt))


class ObserverComputedTorqueController(TimeIndexedController):
    """Computed torque minus the momentum observer's estimate of τ_ext (module docstring) on
    the nominal model, tracking q_r(s), s = s₀ + t, with
    :class:`ObserverComputedTorqueGains`; arguments, clock and errors as
    :class:`~agents.time_indexed.TimeIndexedController`, plus ``torque_limits_nm`` (N·m,
    (n,); :meth:`build` passes the profile's) for the applied torque.

    Raises:
        InvalidArgumentError: a model without ``coriolis_matrix``.
    """

    gains_type = ObserverComputedTorqueGains
    rates_to_gains = staticmethod(gains_from_rates)
    gains: ObserverComputedTorqueGains

    def __init__(
        self,
        model: RobotModel,
        path: ReferencePath,
        gains: ObserverComputedTorqueGains,
        torque_limits_nm: FloatArray | None = None,
    ) -> None:
        super().__init__(model, path, gains)
        self.kp = gain_vector(gains.kp_1_s2, self.n, "kp_1_s2")  # (n,) 1/s²
        self.kd = gain_vector(gains.kd_1_s, self.n, "kd_1_s")  # (n,) 1/s
        ko = gain_vector(gains.ko_1_s, self.n, "ko_1_s")  # (n,) 1/s
        self.observer = MomentumObserver(model, ko, torque_limits_nm)

    @classmethod
    def build(cls, ctx: ControlContext, gains: Any = None) -> ObserverComputedTorqueController:
        """As :meth:`TimeIndexedController.build`, with the profile's torque limits."""
        if gains is None or isinstance(gains, Mapping):
            gains = cls.rates_to_gains(ctx, gains)
        limits = np.asarray(ctx.profile.torque_limits_nm, dtype=np.float64)  # (n,) N·m
        return cls(ctx.model, ctx.path, gains, limits)

    def reset(self, q: FloatArray, qd: FloatArray, s_ref: float) -> None:
        """Start the clock at s = ``s_ref`` (s) and the observer at (q, q̇): r = 0."""
        super().reset(q, qd, s_ref)
        self.observer.reset(*state_arrays(q, qd))

    def step(self, q: FloatArray, qd: FloatArray, dt: float) -> FloatArray:
        """τ (N·m) of :meth:`torque`; the observer records it as applied over ``dt``; then
        s ← s + dt (s)."""
        tau = super().step(q, qd, dt)
        self.observer.applied(tau, dt)
        return tau

    def applied_torque(self, tau_nm: FloatArray, dt: float) -> None:
        """The torque actually applied after the last step (N·m), e.g. base + a residual
        policy's correction (:class:`~agents.base.ObservesAppliedTorque`): the observer
        integrates it instead, so the residual is not estimated as an external torque."""
        self.observer.applied(np.asarray(tau_nm, dtype=np.float64), dt)

    def torque(self, q: FloatArray, qd: FloatArray, err: ReferenceErrors) -> FloatArray:
        """τ = ID(q, q̇, q̈_r + K_d ė + K_p e) − r_k (N·m), shape (n,), r_k the observer's
        estimate at this (q, q̇)."""
        r = self.observer.update(q, qd)  # (n,) N·m
        v = err.qdd_r + self.kd * err.ed + self.kp * err.e  # (n,) rad/s²
        return self.model.inverse_dynamics(q, qd, v) - r

    def diagnostics(self) -> dict[str, float]:
        """Those of :class:`~agents.time_indexed.TimeIndexedController` and
        ``external_torque_nm`` |r| (N·m), the estimate used by the last step."""
        return {
            **super().diagnostics(),
            "external_torque_nm": float(np.linalg.norm(self.observer.r)),
        }


#: The controller for a context: default gains, the given gains, or gains from given rates
#: (:meth:`ObserverComputedTorqueController.build`).
build = ObserverComputedTorqueController.build
