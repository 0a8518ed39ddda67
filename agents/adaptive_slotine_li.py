"""The adaptive Slotine–Li law (Slotine & Li, 1987): :mod:`agents.slotine_li` with the
model's dynamic parameters θ̂ estimated on line.

With e = q_r − q, ė = q_r' − q̇, diagonal Λ (1/s) and K_D (N·m·s/rad) as in
:mod:`agents.slotine_li`, and the rigid-body dynamics linear in the parameters θ (per moved
body m, m c, I at the joint frame; kg, kg·m, kg·m²):

.. math::

    \\dot q_{ref} = q_r' + \\Lambda e, \\quad \\ddot q_{ref} = q_r'' + \\Lambda \\dot e,
    \\quad r = \\dot q_{ref} - \\dot q = \\dot e + \\Lambda e,

    M(q)\\,\\ddot q_{ref} + C(q, \\dot q)\\,\\dot q_{ref} + g(q)
        = Y(q, \\dot q, \\dot q_{ref}, \\ddot q_{ref})\\,\\theta,

    \\tau = Y \\hat\\theta + K_D r, \\qquad \\dot{\\hat\\theta} = \\Gamma Y^T r.

On the plant M q̈ + C q̇ + g = Y θ the closed loop is M ṙ + C r + K_D r = −Y θ̃,
θ̃ = θ̂ − θ, and with Ṁ − 2C skew-symmetric

.. math::

    V = \\tfrac12 r^T M r + e^T \\Lambda K_D e + \\tfrac12 \\tilde\\theta^T \\Gamma^{-1}
        \\tilde\\theta, \\qquad
    \\dot V = -\\dot e^T K_D \\dot e - e^T \\Lambda K_D \\Lambda e \\le 0

(the Y θ̃ terms cancel exactly for the sign + Γ Yᵀ r; with r = −s of the paper this is its
−Γ Yᵀ s). Y is not the regressor of RNEA(q, q̇, q̈_ref), which holds C(q, q̇) q̇: by the
Christoffel polarization of :func:`agents.slotine_li.christoffel_product` applied to the
regressor Y₀(q, v, a) of τ = M a + C(q, v) v + g (:func:`slotine_li_regressor`),

.. math::

    Y = Y_0(q, 0, \\ddot q_{ref})
        + \\tfrac14\\,[Y_0(q, \\dot q + \\dot q_{ref}, 0) - Y_0(q, \\dot q - \\dot q_{ref}, 0)],

g once (in the first term; it cancels in the difference).

Adaptation gain and projection (:func:`parameter_scales`): each parameter has a scale
s_j = max(|θ_nom,j|, ε u_j), u_j its body's mass m, m ℓ or m ℓ² by unit (ℓ the body's
radius of gyration about its joint frame, ε = :data:`SCALE_FLOOR`), and

.. math::

    \\Gamma = \\frac{\\gamma}{E}\\,\\mathrm{diag}(s_j^2), \\quad
    E = \\textstyle\\sum_j \\Lambda_j K_{D,j} \\cdot (1\\,\\mathrm{rad})^2 \\ \\mathrm{(J)},
    \\qquad
    \\hat\\theta_j \\in [\\theta_{nom,j} - \\delta s_j,\\ \\theta_{nom,j} + \\delta s_j],

γ dimensionless (``gamma``), δ < 1 (``bound``): a parameter off by its scale weighs E / 2γ
in V, as much as a 1 rad error on every joint over 2γ; masses stay in [(1 − δ) m, (1 + δ) m],
positive. The box is convex and, Γ being diagonal, clipping to it is the projection in the
Γ⁻¹ metric: it never increases ½ θ̃ᵀΓ⁻¹θ̃ when θ lies in the box, so V still decreases.
(It is not the physically consistent set — positive-definite inertias — only a box.)
Discretization: θ̂ ← clip(θ̂ + dt Γ Yᵀ r) once per control step (explicit Euler), after τ.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol, cast

import numpy as np

from agents import slotine_li
from agents.base import ControlContext, FloatArray
from agents.gains import rates
from agents.reference_clock import ReferenceErrors
from agents.slotine_li import SlotineLiController, SlotineLiGains
from ptrack_gym.errors import InvalidArgumentError, InvalidConfigError
from ptrack_gym.paths import ReferencePath
from ptrack_gym.robots.model import RobotModel

#: The gain rates (:class:`agents.registry.RateSource`): ω (rad/s) and c = ``kd_ratio`` as
#: Slotine–Li's; γ = ``gamma`` (dimensionless) the adaptation rate; δ = ``bound`` the
#: projection box's half-width relative to the parameter scales.
NAME = "adaptive_slotine_li"
DEFAULT_RATES = {"omega": 20.0, "kd_ratio": 1.0, "gamma": 1000.0, "bound": 0.5}
BANDWIDTHS = ("omega",)
TUNABLE = {"omega": (3.0, 100.0, True), "kd_ratio": (0.25, 4.0, True), "gamma": (10.0, 3e4, True)}

#: ε: a parameter's scale is at least this fraction of its body's scale in its unit, so a
#: parameter that is zero nominally (a product of inertia, an off-axis moment) may adapt.
SCALE_FLOOR = 0.1


class RegressorModel(Protocol):
    """A dynamics model linear in its parameters
    (:class:`~ptrack_gym.robots.model.PinocchioModel`)."""

    def joint_torque_regressor(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        """Y₀(q, q̇, q̈), shape (n, p): M q̈ + C(q, q̇) q̇ + g = Y₀ θ (N·m)."""
        ...

    def dynamic_parameters(self) -> FloatArray:
        """θ, shape (p,): ten standard parameters per moved body (kg, kg·m, kg·m²)."""
        ...


@dataclass(frozen=True)
class AdaptiveSlotineLiGains(SlotineLiGains):
    """Gains of :class:`AdaptiveSlotineLiController`: Slotine–Li's Λ, K_D
    (:class:`~agents.slotine_li.SlotineLiGains`) and

    Attributes:
        gamma: γ > 0 (dimensionless), the adaptation rate: Γ = γ diag(s²) / E.
        bound: δ in (0, 1), the projection box's half-width in parameter scales s.
    """

    gamma: float
    bound: float

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("gamma", "bound"):
            if not isinstance(getattr(self, name), float):
                raise InvalidConfigError(f"{name} must be one number, got {getattr(self, name)!r}")
        if not self.bound < 1.0:
            raise InvalidConfigError(f"bound must be in (0, 1) (masses > 0), got {self.bound!r}")


def gains_from_rates(
    ctx: ControlContext, given: Mapping[str, float] | None
) -> AdaptiveSlotineLiGains:
    """Absolute gains from rates — ``DEFAULT_RATES``, updated by the robot's profile rates,
    updated by ``given``: Λ, K_D by :func:`agents.slotine_li.gains_from_rates` (capped for
    the context's control rate), γ and δ as given."""
    r = rates(DEFAULT_RATES, given, NAME, ctx.profile.controller_gains.get(NAME))
    base = slotine_li.gains_from_rates(ctx, {"omega": r["omega"], "kd_ratio": r["kd_ratio"]})
    return AdaptiveSlotineLiGains(
        base.lambda_1_s, base.kd_nms_rad, gamma=r["gamma"], bound=r["bound"]
    )


def default_gains(ctx: ControlContext) -> AdaptiveSlotineLiGains:
    """The robot's default gains at the context's control rate: the profile's rates."""
    return gains_from_rates(ctx, None)


def slotine_li_regressor(
    model: RegressorModel, q: FloatArray, qd: FloatArray, qd_ref: FloatArray, qdd_ref: FloatArray
) -> FloatArray:
    """Y (N·m per parameter unit), shape (n, p), with Y θ = M(q) q̈_ref + C(q, q̇) q̇_ref +
    g(q) for the Christoffel C (module docstring), from the model's
    ``joint_torque_regressor`` Y₀(q, v, a): three calls. q̇, q̇_ref in rad/s, q̈_ref in rad/s².
    """
    zeros = np.zeros_like(qd)
    return model.joint_torque_regressor(q, zeros, qdd_ref) + 0.25 * (
        model.joint_torque_regressor(q, qd + qd_ref, zeros)
        - model.joint_torque_regressor(q, qd - qd_ref, zeros)
    )


def parameter_scales(theta: FloatArray) -> FloatArray:
    """s_j = max(|θ_j|, ε u_j), shape (p,) (kg, kg·m, kg·m²), for θ the ten standard
    parameters per body (m, m c, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz at the joint frame):
    u = m, m ℓ, m ℓ² by unit, ℓ = √(tr I / 2m) the body's radius of gyration about its joint
    frame (m), ε = :data:`SCALE_FLOOR`. A massless body's parameters get scale 0: fixed."""
    body = np.asarray(theta, dtype=np.float64).reshape(-1, 10)  # (nb, 10)
    mass = body[:, 0]
    trace = body[:, 4] + body[:, 6] + body[:, 9]  # kg·m²
    safe = np.where(mass > 0.0, mass, 1.0)
    length = np.where(mass > 0.0, np.sqrt(np.maximum(trace, 0.0) / (2.0 * safe)), 0.0)
    unit = np.repeat(np.stack([mass, mass * length, mass * length**2], axis=1), [1, 3, 6], axis=1)
    return np.maximum(np.abs(body), SCALE_FLOOR * unit).ravel()


class AdaptiveSlotineLiController(SlotineLiController):
    """Adaptive Slotine–Li tracking of q_r(s), s = s₀ + t (module docstring), with
    :class:`AdaptiveSlotineLiGains`. The estimate θ̂ starts at the nominal model's
    parameters θ_nom and :meth:`reset` restores it there (each episode adapts afresh).

    Args:
        model: the nominal model; it must give ``joint_torque_regressor`` and
            ``dynamic_parameters`` (:class:`~ptrack_gym.robots.model.PinocchioModel`).
        path, gains: as :class:`~agents.slotine_li.SlotineLiController`.

    Raises:
        InvalidArgumentError: a model without a joint-torque regressor, or gains of
            another type.
    """

    gains_type = AdaptiveSlotineLiGains
    rates_to_gains = staticmethod(gains_from_rates)
    gains: AdaptiveSlotineLiGains

    def __init__(
        self, model: RobotModel, path: ReferencePath, gains: AdaptiveSlotineLiGains
    ) -> None:
        if not callable(getattr(model, "joint_torque_regressor", None)):
            raise InvalidArgumentError(
                "adaptive Slotine–Li needs a model that gives its joint-torque regressor "
                f"(PinocchioModel); got {type(model).__name__}"
            )
        super().__init__(model, path, gains)
        self.regressor_model = cast(RegressorModel, model)
        self.theta_nom = np.array(self.regressor_model.dynamic_parameters(), dtype=np.float64)
        self.theta_nom.setflags(write=False)
        self.scales = parameter_scales(self.theta_nom)  # (p,) s_j
        energy_j = float(np.sum(self.lam * self.kd))  # E = Σ Λ_j K_D,j · 1 rad²
        self.adaptation_gain = gains.gamma * self.scales**2 / energy_j  # (p,) diag Γ
        self.theta_low = self.theta_nom - gains.bound * self.scales  # (p,)
        self.theta_high = self.theta_nom + gains.bound * self.scales  # (p,)
        self.theta_hat: FloatArray = self.theta_nom.copy()  # (p,) θ̂
        self._update: tuple[FloatArray, FloatArray] | None = None  # (Y, r) of the last τ

    def reset(self, q: FloatArray, qd: FloatArray, s_ref: float) -> None:
        """Start the clock at s = ``s_ref`` (s) and restore θ̂ = θ_nom."""
        super().reset(q, qd, s_ref)
        self.theta_hat = self.theta_nom.copy()
        self._update = None

    def torque(self, q: FloatArray, qd: FloatArray, err: ReferenceErrors) -> FloatArray:
        """τ = Y(q, q̇, q̇_ref, q̈_ref) θ̂ + K_D r (N·m), shape (n,), θ̂ before this step's
        update."""
        qd_ref = err.qd_r + self.lam * err.e  # (n,) rad/s
        qdd_ref = err.qdd_r + self.lam * err.ed  # (n,) rad/s²
        r = err.ed + self.lam * err.e  # (n,) rad/s, = qd_ref − qd
        y = slotine_li_regressor(self.regressor_model, q, qd, qd_ref, qdd_ref)  # (n, p)
        self._update = (y, r)
        return y @ self.theta_hat + self.kd * r

    def step(self, q: FloatArray, qd: FloatArray, dt: float) -> FloatArray:
        """τ (N·m) of :meth:`torque`; then s ← s + dt and θ̂ ← clip(θ̂ + dt Γ Yᵀ r) to the
        box (explicit Euler, then projection)."""
        tau = super().step(q, qd, dt)
        assert self._update is not None
        y, r = self._update
        self.theta_hat = self.project(self.theta_hat + dt * self.adaptation_gain * (y.T @ r))
        return tau

    def project(self, theta: FloatArray) -> FloatArray:
        """θ clipped to [θ_nom − δ s, θ_nom + δ s]: the box's projection in the Γ⁻¹ metric."""
        return np.clip(theta, self.theta_low, self.theta_high)

    def diagnostics(self) -> dict[str, float]:
        """Slotine–Li's (``s``, ``tracking_error`` |e| rad, ``velocity_error``,
        ``sliding_error``, and ``lyapunov_j``: V's tracking part ½ rᵀMr + eᵀΛK_De, J — the
        θ̃ term needs the unknown θ), and ``param_change_rel`` ‖θ̂ − θ_nom‖ / ‖θ_nom‖ and
        ``param_change_scaled`` max_j |θ̂_j − θ_nom,j| / s_j (≤ δ)."""
        delta = self.theta_hat - self.theta_nom
        moved = np.abs(delta[self.scales > 0.0]) / self.scales[self.scales > 0.0]
        return {
            **super().diagnostics(),
            "param_change_rel": float(np.linalg.norm(delta) / np.linalg.norm(self.theta_nom)),
            "param_change_scaled": float(moved.max(initial=0.0)),
        }


#: The controller for a context: default gains, the given gains, or gains from given rates
#: (:meth:`~agents.time_indexed.TimeIndexedController.build`).
build = AdaptiveSlotineLiController.build
