"""The Slotine–Li adaptive-control law with a fixed (nominal) model.

With e = q_r − q, ė = q_r' − q̇ and diagonal gains Λ (1/s), K_D (N·m·s/rad):

.. math::

    \\dot q_{ref} = q_r' + \\Lambda e, \\quad \\ddot q_{ref} = q_r'' + \\Lambda \\dot e,
    \\quad r = \\dot q_{ref} - \\dot q = \\dot e + \\Lambda e,

    \\tau = M(q)\\,\\ddot q_{ref} + C(q, \\dot q)\\,\\dot q_{ref} + g(q) + K_D r.

(Slotine & Li, 1987, write s = q̇ − q̇_ref = −r and −K_D s.) C is the Christoffel-symbol
Coriolis matrix, for which Ṁ − 2C is skew-symmetric; with the exact model the closed loop
is M ṙ + C r + K_D r = 0 and

.. math::

    V = \\tfrac12 r^T M(q)\\, r + e^T \\Lambda K_D e, \\qquad
    \\dot V = -\\dot e^T K_D \\dot e - e^T \\Lambda K_D \\Lambda e \\le 0

(Λ K_D is symmetric because both are diagonal).

C(q, q̇) q̇_ref is not the model's ``coriolis(q, q̇)`` = C(q, q̇) q̇. It follows exactly from
the quadratic form h(x) = C(q, x) x: with Christoffel symbols
c_ijk = ½(∂M_ij/∂q_k + ∂M_ik/∂q_j − ∂M_jk/∂q_i), symmetric in j and k,
(C(q, a) b)_i = Σ_jk c_ijk a_k b_j is a symmetric bilinear form in (a, b), so by
polarization

.. math::

    C(q, a)\\, b = \\tfrac12\\,[h(a + b) - h(a) - h(b)] = \\tfrac14\\,[h(a + b) - h(a - b)].

:func:`christoffel_product` uses the second form through inverse dynamics with q̈ = 0,
where g(q) cancels: two model calls, no finite differences.

Default gains: Λ = ω I (1/s), K_D = c ω diag(m) (N·m·s/rad), m = diag M(q_home) — with
c = 1 the linearised error obeys (s + Λ)(s + M⁻¹K_D) e = 0, a double pole near −ω — with ω
and c (``kd_ratio``, default 1) the robot profile's ``controller_gains["slotine_li"]``, ω
capped at α / dt (:func:`agents.gains.cap_bandwidth`) and where the coupled modes of the
velocity feedback Λ + M(q)⁻¹K_D and the stiffness M(q)⁻¹K_DΛ on the path would outrun the
control rate (:func:`agents.gains.cap_coupled_bandwidth`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from agents.base import ControlContext, FeatureBlock, FloatArray
from agents.gains import DiagonalGains, Gain, gain_vector, home_inertia_bandwidth, rates, rounded
from agents.reference_clock import ReferenceErrors, time_indexed_features
from agents.time_indexed import TimeIndexedController
from ptrack_gym.paths import ReferencePath
from ptrack_gym.robots.model import RobotModel

#: The gain rates (:class:`agents.registry.RateSource`): ω (rad/s) and c = ``kd_ratio``, ω
#: the bandwidth.
NAME = "slotine_li"
DEFAULT_RATES = {"omega": 20.0, "kd_ratio": 1.0}
BANDWIDTHS = ("omega",)
TUNABLE = {"omega": (3.0, 100.0, True), "kd_ratio": (0.25, 4.0, True)}


@dataclass(frozen=True)
class SlotineLiGains(DiagonalGains):
    """Gains of :class:`SlotineLiController`, diagonal (:class:`~agents.gains.DiagonalGains`).

    Attributes:
        lambda_1_s: Λ (1/s), the sliding-surface slope: r = ė + Λ e.
        kd_nms_rad: K_D (N·m·s/rad), the damping injected on r.
    """

    lambda_1_s: Gain
    kd_nms_rad: Gain

    @classmethod
    def from_inertia(
        cls, inertia_kgm2: FloatArray, omega_rad_s: float, kd_ratio: float = 1.0
    ) -> SlotineLiGains:
        """Λ = ω, K_D = c ω m, with m the joint inertias (kg·m²) and c = ``kd_ratio``: c = 1
        puts a double pole near −ω."""
        m = np.asarray(inertia_kgm2, dtype=np.float64)
        return cls(lambda_1_s=float(omega_rad_s), kd_nms_rad=rounded(kd_ratio * omega_rad_s * m))


def gains_from_rates(ctx: ControlContext, given: Mapping[str, float] | None) -> SlotineLiGains:
    """Absolute gains from rates — ``DEFAULT_RATES``, updated by the robot's profile rates,
    updated by ``given`` — at the context's control rate (module docstring)."""
    r = rates(DEFAULT_RATES, given, NAME, ctx.profile.controller_gains.get(NAME))
    c = r["kd_ratio"]  # damping Λ + c ω M⁻¹m, stiffness c ω² M⁻¹m (per ω, ω²)
    inertia, omega = home_inertia_bandwidth(ctx, r["omega"], c, c, damping_offset=1.0)
    return SlotineLiGains.from_inertia(inertia, omega, c)


def default_gains(ctx: ControlContext) -> SlotineLiGains:
    """The robot's default gains at the context's control rate: the profile's rates."""
    return gains_from_rates(ctx, None)


def christoffel_product(
    model: RobotModel, q: FloatArray, a: FloatArray, b: FloatArray
) -> FloatArray:
    """C(q, a) b (N·m) for the Christoffel Coriolis matrix, shape (n,).

    .. math::

        C(q, a)\\, b = \\tfrac14\\,[\\mathrm{ID}(q, a + b, 0) - \\mathrm{ID}(q, a - b, 0)],

    ID(q, x, 0) = C(q, x) x + g(q) the model's inverse dynamics. Exact for any model whose
    Coriolis term is an exact quadratic form in q̇ (rigid bodies); symmetric in (a, b).
    ``a`` in rad/s, ``b`` in rad/s.
    """
    zeros = np.zeros(model.n)
    return 0.25 * (
        model.inverse_dynamics(q, a + b, zeros) - model.inverse_dynamics(q, a - b, zeros)
    )


class SlotineLiController(TimeIndexedController):
    """Slotine–Li tracking of the time-indexed reference q_r(s), s = s₀ + t, on the
    nominal model, without parameter adaptation, with :class:`SlotineLiGains` (arguments,
    clock and errors: :class:`~agents.time_indexed.TimeIndexedController`).

    Each step costs three inverse-dynamics calls; :meth:`diagnostics` one mass matrix more
    (for the Lyapunov value).
    """

    gains_type = SlotineLiGains
    rates_to_gains = staticmethod(gains_from_rates)
    gains: SlotineLiGains

    def __init__(self, model: RobotModel, path: ReferencePath, gains: SlotineLiGains) -> None:
        super().__init__(model, path, gains)
        self.lam = gain_vector(gains.lambda_1_s, self.n, "lambda_1_s")  # (n,) 1/s
        self.kd = gain_vector(gains.kd_nms_rad, self.n, "kd_nms_rad")  # (n,) N·m·s/rad
        self._zeros = np.zeros(self.n)
        self._q_last = np.zeros(self.n)  # the q passed to the last step (rad)

    def lyapunov(self, q: FloatArray, qd: FloatArray, s: float) -> float:
        """V = ½ rᵀ M(q) r + eᵀ Λ K_D e (J) at state (q, q̇) against q_r(s)."""
        q_r, qd_r, _ = self.path.evaluate(s)
        e = q_r - q
        r = qd_r - qd + self.lam * e
        return float(0.5 * r @ self.model.mass_matrix(q) @ r + e @ (self.lam * self.kd * e))

    def step(self, q: FloatArray, qd: FloatArray, dt: float) -> FloatArray:
        """τ (N·m) of :meth:`torque`; then s ← s + dt (s), keeping q for :meth:`diagnostics`."""
        tau = super().step(q, qd, dt)
        self._q_last = np.array(q, dtype=np.float64)
        return tau

    def torque(self, q: FloatArray, qd: FloatArray, err: ReferenceErrors) -> FloatArray:
        """τ = M q̈_ref + C(q, q̇) q̇_ref + g + K_D r (N·m), shape (n,)."""
        e, ed = err.e, err.ed
        qd_ref = err.qd_r + self.lam * e  # (n,) rad/s
        qdd_ref = err.qdd_r + self.lam * ed  # (n,) rad/s²
        r = ed + self.lam * e  # (n,) rad/s, = qd_ref − qd
        return (
            self.model.inverse_dynamics(q, self._zeros, qdd_ref)  # M q̈_ref + g
            + christoffel_product(self.model, q, qd, qd_ref)  # C(q, q̇) q̇_ref
            + self.kd * r
        )

    def diagnostics(self) -> dict[str, float]:
        """``s``: the clock after the last step (s), equal to the env's ``s_ref`` then;
        for the state passed to the last step (against q_r(s − dt)): ``tracking_error``
        |e| (rad), ``velocity_error`` |ė| (rad/s), ``sliding_error`` |r| (rad/s) and
        ``lyapunov_j`` V (J), computed when asked for."""
        if self._last is None:
            return {"s": self._s0}
        err = self._last[1]
        r = err.ed + self.lam * err.e  # (n,) rad/s
        mass = self.model.mass_matrix(self._q_last)  # (n, n)
        return {
            **super().diagnostics(),
            "sliding_error": float(np.linalg.norm(r)),
            "lyapunov_j": float(0.5 * r @ mass @ r + err.e @ (self.lam * self.kd * err.e)),
        }

    def residual_features(self, max_speed_rad_s: float) -> FeatureBlock:
        """e, ė and r = ė + Λ e against the clock
        (:func:`agents.reference_clock.time_indexed_features`)."""
        return time_indexed_features(self.clock, self.n, max_speed_rad_s, lam=self.lam)


#: The controller for a context: default gains, the given gains, or gains from given rates
#: (:meth:`~agents.time_indexed.TimeIndexedController.build`).
build = SlotineLiController.build
