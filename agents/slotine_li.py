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

NAME = "slotine_li"
#: Generic default rates: ω (rad/s).
DEFAULT_RATES = {"omega": 20.0, "kd_ratio": 1.0}
#: What ``python -m train.tune`` searches: rate → (low, high, log scale).
#: The rates one gain scale multiplies (``python -m train.fronts``): the bandwidth.
BANDWIDTHS = ("omega",)
TUNABLE = {"omega": (3.0, 100.0, True), "kd_ratio": (0.25, 4.0, True)}


@dataclass(frozen=True)
class SlotineLiGains:
    """Gains of :class:`SlotineLiController`.

    Attributes:
        lambda_1_s: Λ (1/s), the sliding-surface slope: r = ė + Λ e.
        kd_nms_rad: K_D (N·m·s/rad), the damping injected on r.
    """

    lambda_1_s: Gain
    kd_nms_rad: Gain

    def __post_init__(self) -> None:
        object.__setattr__(self, "lambda_1_s", check_gain(self.lambda_1_s, "lambda_1_s"))
        object.__setattr__(self, "kd_nms_rad", check_gain(self.kd_nms_rad, "kd_nms_rad"))

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
    inertia = home_inertia_kgm2(ctx.model, ctx.profile)
    ratio = coupling_ratio(ctx.model, ctx.path, inertia)
    c = r["kd_ratio"]  # damping Λ + c ω M⁻¹m, stiffness c ω² M⁻¹m (per ω, ω²)
    omega = cap_coupled_bandwidth(
        cap_bandwidth(r["omega"], ctx.dt_s), ctx.dt_s, c * ratio, 1.0 + c * ratio
    )
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


class SlotineLiController:
    """Slotine–Li tracking of the time-indexed reference q_r(s), s = s₀ + t, on the
    nominal model (no parameter adaptation).

    The clock is set to the env's reference phase by :meth:`reset` and advanced by ``dt``
    in :meth:`step`. Each step costs three inverse-dynamics calls and one mass matrix
    (the latter only for the Lyapunov value in :meth:`diagnostics`).

    Args:
        model: the controller's nominal dynamics model (never the simulator).
        path: the reference path q_r(s), s in seconds.
        gains: Λ (1/s) and K_D (N·m·s/rad), diagonal.

    Raises:
        InvalidConfigError: (a ``ValueError``) bad gains, or a model/path mismatch.
    """

    def __init__(self, model: RobotModel, path: ReferencePath, gains: SlotineLiGains) -> None:
        if not isinstance(gains, SlotineLiGains):
            raise TypeError(f"gains must be SlotineLiGains, got {type(gains).__name__}")
        self.clock = ReferenceClock(model, path)
        self.model = model
        self.path = path
        self.gains = gains
        self.n = model.n
        self.lam = gain_vector(gains.lambda_1_s, self.n, "lambda_1_s")  # (n,) 1/s
        self.kd = gain_vector(gains.kd_nms_rad, self.n, "kd_nms_rad")  # (n,) N·m·s/rad
        self._zeros = np.zeros(self.n)
        self._last: tuple[float, ReferenceErrors, FloatArray] | None = None  # (s, errors, q)
        self._s0 = 0.0

    def lyapunov(self, q: FloatArray, qd: FloatArray, s: float) -> float:
        """V = ½ rᵀ M(q) r + eᵀ Λ K_D e (J) at state (q, q̇) against q_r(s)."""
        q_r, qd_r, _ = self.path.evaluate(s)
        e = q_r - q
        r = qd_r - qd + self.lam * e
        return float(0.5 * r @ self.model.mass_matrix(q) @ r + e @ (self.lam * self.kd * e))

    def reset(self, q: FloatArray, qd: FloatArray, s_ref: float) -> None:
        """Start the clock at s = ``s_ref`` (s)."""
        self.clock.reset(s_ref)
        self._last, self._s0 = None, float(s_ref)

    def step(self, q: FloatArray, qd: FloatArray, dt: float) -> FloatArray:
        """τ = M q̈_ref + C(q, q̇) q̇_ref + g + K_D r (N·m), shape (n,); then s ← s + dt."""
        q, qd = state_arrays(q, qd)
        err = self.clock.errors(q, qd, dt)
        e, ed = err.e, err.ed
        qd_ref = err.qd_r + self.lam * e  # (n,) rad/s
        qdd_ref = err.qdd_r + self.lam * ed  # (n,) rad/s²
        r = ed + self.lam * e  # (n,) rad/s, = qd_ref − qd
        tau = (
            self.model.inverse_dynamics(q, self._zeros, qdd_ref)  # M q̈_ref + g
            + christoffel_product(self.model, q, qd, qd_ref)  # C(q, q̇) q̇_ref
            + self.kd * r
        )
        self._last = (self.clock.advance(dt), err, np.array(q, dtype=np.float64))
        return tau

    def diagnostics(self) -> dict[str, float]:
        """``s``: the clock after the last step (s), equal to the env's ``s_ref`` then;
        for the state passed to the last step (against q_r(s − dt)): ``tracking_error``
        |e| (rad), ``velocity_error`` |ė| (rad/s), ``sliding_error`` |r| (rad/s) and
        ``lyapunov_j`` V (J), computed when asked for."""
        if self._last is None:
            return {"s": self._s0}
        s, err, q = self._last
        r = err.ed + self.lam * err.e  # (n,) rad/s
        mass = self.model.mass_matrix(q)  # (n, n)
        return {
            **error_diagnostics(s, err),
            "sliding_error": float(np.linalg.norm(r)),
            "lyapunov_j": float(0.5 * r @ mass @ r + err.e @ (self.lam * self.kd * err.e)),
        }

    def residual_features(self, max_speed_rad_s: float) -> FeatureBlock:
        """e, ė and r = ė + Λ e against the clock
        (see :func:`agents.reference_clock.time_indexed_features`)."""
        return time_indexed_features(self.clock, self.n, max_speed_rad_s, lam=self.lam)


def build(
    ctx: ControlContext, gains: SlotineLiGains | Mapping[str, float] | None = None
) -> SlotineLiController:
    """The controller for a context: its default gains, the given gains, or gains from the
    given rates (a mapping, e.g. tuned ones)."""
    if gains is None:
        gains = default_gains(ctx)
    elif isinstance(gains, Mapping):
        gains = gains_from_rates(ctx, gains)
    return SlotineLiController(ctx.model, ctx.path, gains)
