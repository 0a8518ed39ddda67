"""Adaptive Slotine–Li (:mod:`agents.adaptive_slotine_li`): the Slotine–Li regressor
identity, convergence on an exact plant with wrong parameters (and V non-increasing), the
projection under adversarial inputs, the update law by hand, and the error paths."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from agents import adaptive_slotine_li as asl
from agents import slotine_li
from agents.base import ControlContext
from agents.slotine_li import SlotineLiGains
from ptrack_gym.errors import InvalidArgumentError, InvalidConfigError
from ptrack_gym.paths import default_path
from ptrack_gym.robots import BulletModel, PinocchioModel, robot_profile


def context(robot: str = "two_link", dt_s: float = 1e-3) -> ControlContext:
    profile = robot_profile(robot)
    return ControlContext(profile, PinocchioModel(profile), default_path(profile), dt_s)


@pytest.mark.parametrize("robot", ["two_link", "iiwa"])
def test_regressor_gives_m_qddref_plus_c_qdref_plus_g(robot: str) -> None:
    """Y(q, q̇, q̇_ref, q̈_ref) θ_nom = M q̈_ref + C(q, q̇) q̇_ref + g, against the fixed-model
    law's terms and against Pinocchio's Christoffel C matrix; q̇ ≠ q̇_ref, so a regressor of
    RNEA(q, q̇, q̈_ref) (C(q, q̇) q̇) or one counting g twice fails by O(1) N·m. 1e-9 N·m:
    torques of O(10–100) N·m in double precision through three regressor calls."""
    model = PinocchioModel(robot_profile(robot))
    theta = model.dynamic_parameters()
    assert theta.shape == (10 * model.n,)
    zeros = np.zeros(model.n)
    rng = np.random.default_rng(7)
    for _ in range(20):
        q, qd, qd_ref, qdd_ref = rng.uniform(-2.0, 2.0, (4, model.n))
        y = asl.slotine_li_regressor(model, q, qd, qd_ref, qdd_ref)
        assert y.shape == (model.n, theta.size)
        fixed = model.inverse_dynamics(q, zeros, qdd_ref) + slotine_li.christoffel_product(
            model, q, qd, qd_ref
        )
        np.testing.assert_allclose(y @ theta, fixed, rtol=0, atol=1e-9)
        by_matrix = (
            model.mass_matrix(q) @ qdd_ref
            + model.coriolis_matrix(q, qd) @ qd_ref
            + model.gravity(q)
        )
        np.testing.assert_allclose(y @ theta, by_matrix, rtol=0, atol=1e-9)
        # The model's regressor itself: Y₀(q, v, a) θ = RNEA(q, v, a).
        np.testing.assert_allclose(
            model.joint_torque_regressor(q, qd, qdd_ref) @ theta,
            model.inverse_dynamics(q, qd, qdd_ref),
            rtol=0,
            atol=1e-9,
        )


def scaled_plant(robot: str, scale: float) -> tuple[pin.Model, pin.Data]:
    """The exact rigid-body plant with every body's parameters × ``scale`` (masses and
    inertias, centres of mass unchanged): θ_true = scale · θ_nom."""
    plant = pin.buildModelFromUrdf(robot_profile(robot).urdf_path)
    plant.gravity.linear = np.array([0.0, 0.0, -9.81])
    for i in range(1, plant.njoints):
        params = scale * plant.inertias[i].toDynamicParameters()
        plant.inertias[i] = pin.Inertia.FromDynamicParameters(params)
    return plant, plant.createData()


def simulate(ctrl, plant: pin.Model, data: pin.Data, ctx: ControlContext, steps: int):
    """Track ctx.path from on it (e = 0, ė = 0) with τ held over each dt, the plant by RK4
    on Pinocchio's ABA; returns |e| per step, θ̂ per step (or None) and (q, q̇) per step."""
    q, qd, _ = ctx.path.evaluate(0.0)
    ctrl.reset(q, qd, 0.0)
    h = ctx.dt_s
    errors, thetas, states = [], [], []
    for _ in range(steps):
        states.append((q, qd))
        tau = ctrl.step(q, qd, h)
        errors.append(ctrl.diagnostics()["tracking_error"])
        thetas.append(getattr(ctrl, "theta_hat", None))

        def f(x, v, tau=tau):
            return v, pin.aba(plant, data, x, v, tau)

        k1 = f(q, qd)
        k2 = f(q + h / 2 * k1[0], qd + h / 2 * k1[1])
        k3 = f(q + h / 2 * k2[0], qd + h / 2 * k2[1])
        k4 = f(q + h * k3[0], qd + h * k3[1])
        q = q + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        qd = qd + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
    return np.array(errors), thetas, states


def test_adaptation_removes_the_error_of_a_wrong_model_and_v_never_grows() -> None:
    """Two-link plant with every body × 1.3 (θ_true = 1.3 θ_nom, inside the ±50 % box),
    1 kHz control, two periods (8 s) of the default path, from on the path.

    Measured (default rates, γ = 1000): adaptive RMS |e| 3.7e-3 rad over the first second,
    ~7e-4 over the last period; fixed-model Slotine–Li ~2.2e-2 there. The bounds leave a
    factor ~2 of margin. V (true M, θ) starts at ½ θ̃ᵀΓ⁻¹θ̃ ≈ 0.10 J, ends at 0.65 V₀, and
    exceeds V₀ by at most 2.2e-4 V₀ (rises ≤ 6e-6 J per step: the zero-order hold's
    discretization error), so 1e-3 V₀ of slack; with the adaptation's sign flipped the
    error grows instead (checked by hand: 5.9e-2 rad over the last period)."""
    ctx = context("two_link", 1e-3)
    plant, data = scaled_plant("two_link", 1.3)
    adaptive = asl.build(ctx)
    steps, period = 8000, 4000
    err_ad, thetas, states = simulate(adaptive, plant, data, ctx, steps)
    fixed = slotine_li.SlotineLiController(
        ctx.model, ctx.path, SlotineLiGains(adaptive.gains.lambda_1_s, adaptive.gains.kd_nms_rad)
    )
    err_fx, _, _ = simulate(fixed, plant, data, ctx, steps)

    def rms(x):
        return float(np.sqrt(np.mean(x**2)))

    first_second, last_period = rms(err_ad[:1000]), rms(err_ad[-period:])
    assert last_period < 0.35 * first_second
    assert last_period < 0.1 * rms(err_fx[-period:])
    assert rms(err_fx[-period:]) > 1e-2  # the wrong model does matter for the fixed law

    theta_true = 1.3 * adaptive.theta_nom
    gamma_inv = 1.0 / adaptive.adaptation_gain
    lyapunov = []
    for k, ((q, qd), theta) in enumerate(zip(states, thetas, strict=True)):
        assert np.all(theta >= adaptive.theta_low) and np.all(theta <= adaptive.theta_high)
        q_r, qd_r, _ = ctx.path.evaluate(k * ctx.dt_s)
        e = q_r - q
        r = qd_r - qd + adaptive.lam * e
        mass = np.triu(pin.crba(plant, data, q))
        mass = mass + np.triu(mass, 1).T
        tilde = thetas[k - 1] - theta_true if k else adaptive.theta_nom - theta_true
        lyapunov.append(
            0.5 * r @ mass @ r
            + e @ (adaptive.lam * adaptive.kd * e)
            + 0.5 * tilde @ (gamma_inv * tilde)
        )
    v = np.array(lyapunov)
    assert v.max() <= v[0] * (1 + 1e-3)
    assert v[-1] < 0.8 * v[0]
    # The estimate moved to the truth: link 2's mass (identifiable; link 1's is not, its
    # regressor column is zero) within 10 % of 1.3 m₂ (measured 1 %; θ_nom is 23 % off).
    assert thetas[-1][10] == pytest.approx(1.3 * adaptive.theta_nom[10], rel=0.1)


def test_projection_keeps_estimates_in_the_box_under_adversarial_inputs() -> None:
    """γ = 1e9 and random far-off states (|r| up to tens of rad/s): every estimate at every
    step stays inside [θ_nom − δ s, θ_nom + δ s], many sit on its faces, masses stay > 0."""
    ctx = context("iiwa", 2e-3)
    ctrl = asl.build(ctx, {"gamma": 1e9, "bound": 0.3})
    scales = asl.parameter_scales(ctrl.theta_nom)
    np.testing.assert_allclose(ctrl.theta_high - ctrl.theta_nom, 0.3 * scales, rtol=1e-12)
    assert np.all(ctrl.theta_low[::10] > 0.0)  # masses: (1 − δ) m > 0
    rng = np.random.default_rng(11)
    ctrl.reset(ctx.profile.home(), np.zeros(ctrl.n), 0.0)
    on_faces = 0
    for _ in range(200):
        q = ctx.profile.home() + rng.uniform(-1.5, 1.5, ctrl.n)
        qd = rng.normal(0.0, 5.0, ctrl.n)
        ctrl.step(q, qd, ctx.dt_s)
        theta = ctrl.theta_hat
        assert np.all(theta >= ctrl.theta_low) and np.all(theta <= ctrl.theta_high)
        assert ctrl.diagnostics()["param_change_scaled"] <= 0.3 + 1e-12
        on_faces += int(np.sum((theta == ctrl.theta_low) | (theta == ctrl.theta_high)))
    assert on_faces > 1000  # the clip did act (70 parameters × 200 steps)
    inside = ctrl.theta_nom + 0.1 * scales
    np.testing.assert_array_equal(ctrl.project(inside), inside)


def test_one_step_is_the_law_then_the_euler_update() -> None:
    """τ = Y θ_nom + K_D r at the first step, then θ̂ = clip(θ_nom + dt Γ Yᵀ r), by hand."""
    ctx = context("iiwa", 2e-3)
    ctrl = asl.build(ctx, {"gamma": 50.0})
    q = ctx.profile.home() + 0.05
    qd = np.full(ctrl.n, 0.2)
    ctrl.reset(q, qd, 0.4)
    tau = ctrl.step(q, qd, ctx.dt_s)
    q_r, qd_r, qdd_r = ctx.path.evaluate(0.4)
    e, ed = q_r - q, qd_r - qd
    lam, kd = ctrl.lam, ctrl.kd
    y = asl.slotine_li_regressor(ctx.model, q, qd, qd_r + lam * e, qdd_r + lam * ed)
    r = ed + lam * e
    np.testing.assert_allclose(tau, y @ ctrl.theta_nom + kd * r, rtol=1e-10, atol=1e-10)
    gamma = 50.0 * asl.parameter_scales(ctrl.theta_nom) ** 2 / np.sum(lam * kd)
    np.testing.assert_allclose(ctrl.adaptation_gain, gamma, rtol=1e-12)
    expected = np.clip(
        ctrl.theta_nom + ctx.dt_s * gamma * (y.T @ r), ctrl.theta_low, ctrl.theta_high
    )
    np.testing.assert_allclose(ctrl.theta_hat, expected, rtol=1e-10, atol=1e-14)
    assert not np.array_equal(ctrl.theta_hat, ctrl.theta_nom)


def test_gains_reuse_slotine_li_and_rates_are_a_rate_source() -> None:
    ctx = context("two_link", 4e-3)
    gains = asl.default_gains(ctx)
    base = slotine_li.gains_from_rates(ctx, {"omega": 20.0, "kd_ratio": 1.0})
    assert (gains.lambda_1_s, gains.kd_nms_rad) == (base.lambda_1_s, base.kd_nms_rad)
    assert (gains.gamma, gains.bound) == (asl.DEFAULT_RATES["gamma"], asl.DEFAULT_RATES["bound"])
    assert set(asl.TUNABLE) <= set(asl.DEFAULT_RATES) and set(asl.BANDWIDTHS) <= set(asl.TUNABLE)
    assert all(log for _, _, log in asl.TUNABLE.values())
    assert asl.NAME == "adaptive_slotine_li"


def test_a_model_without_a_regressor_is_refused_clearly() -> None:
    profile = robot_profile("two_link")
    bullet = BulletModel(profile)
    try:
        ctx = ControlContext(profile, bullet, default_path(profile), 4e-3)
        message = (
            "adaptive Slotine–Li needs a model that gives its joint-torque regressor "
            "(PinocchioModel); got BulletModel"
        )
        with pytest.raises(InvalidArgumentError) as info:
            asl.build(ctx, asl.AdaptiveSlotineLiGains(20.0, 1.0, gamma=10.0, bound=0.5))
        assert str(info.value) == message
    finally:
        bullet.close()


@pytest.mark.parametrize(
    "rates",
    [
        {"gamma": 0.0},
        {"gamma": -1.0},
        {"gamma": float("nan")},
        {"bound": 1.0},
        {"bound": 0.0},
        {"bound": 2.0},
        {"gamma": (1.0, 2.0)},
        {"omega": -3.0},
        {"gain": 1.0},
    ],
)
def test_bad_rates_raise(rates: dict) -> None:
    with pytest.raises(InvalidConfigError):
        asl.build(context("two_link", 4e-3), rates)


def test_gains_of_another_controller_raise() -> None:
    with pytest.raises(InvalidArgumentError, match="AdaptiveSlotineLiGains"):
        asl.build(context("two_link", 4e-3), SlotineLiGains(20.0, 1.0))


def test_reset_restores_the_nominal_parameters_and_runs_repeat_exactly() -> None:
    ctx = context("iiwa", 2e-3)
    a, b = asl.build(ctx), asl.build(ctx)
    np.testing.assert_array_equal(a.theta_hat, ctx.model.dynamic_parameters())
    rng = np.random.default_rng(5)
    states = [
        (ctx.profile.home() + rng.normal(0, 0.1, 7), rng.normal(0, 0.5, 7)) for _ in range(30)
    ]

    def run(ctrl):
        ctrl.reset(ctx.profile.home(), np.zeros(7), 0.1)
        return np.array([ctrl.step(q, qd, ctx.dt_s) for q, qd in states]), ctrl.theta_hat.copy()

    tau_a, theta_a = run(a)
    assert not np.array_equal(theta_a, a.theta_nom)
    a.reset(ctx.profile.home(), np.zeros(7), 0.1)
    np.testing.assert_array_equal(a.theta_hat, a.theta_nom)
    assert a.diagnostics()["s"] == 0.1
    tau_a2, theta_a2 = run(a)
    tau_b, theta_b = run(b)
    for tau, theta in ((tau_a2, theta_a2), (tau_b, theta_b)):
        np.testing.assert_array_equal(tau, tau_a)
        np.testing.assert_array_equal(theta, theta_a)
    diag = a.diagnostics()
    change = np.linalg.norm(theta_a - a.theta_nom) / np.linalg.norm(a.theta_nom)
    assert diag["param_change_rel"] == pytest.approx(change, rel=1e-12)
    assert diag["tracking_error"] > 0.0
