"""Tests of PID + gravity compensation with a clamped integral (agents/pid_gravity.py).

The integral's claim is checked twice: exactly, on a set point of the closed-form two-link
arm integrated here (semi-implicit Euler at 1 kHz, the torque held over each step, as
PyBullet does) under a constant joint torque; and on the PyBullet iiwa carrying a payload
the nominal model does not know.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import ptrack_gym  # noqa: F401  (registers the environment ids)
from agents import pd_gravity, pid_gravity
from agents.base import ControlContext, Controller
from agents.gains import MAX_FREQUENCY_PER_SAMPLE
from agents.pd_gravity import PDGravityController
from agents.pid_gravity import PIDGravityController, PIDGravityGains
from agents.policy import ControllerPolicy
from ptrack_gym.errors import InvalidArgumentError, InvalidConfigError
from ptrack_gym.paths import MultiSinePath, default_path
from ptrack_gym.robots import PinocchioModel, robot_profile
from ptrack_gym.robots.two_link import TwoLinkAnalyticModel

PROFILE = robot_profile("two_link")
DT_S = 1e-3


def two_link_context(dt_s: float = DT_S) -> ControlContext:
    """The two-link arm's context (Pinocchio model, default path) at control period dt."""
    return ControlContext(PROFILE, PinocchioModel(PROFILE), default_path(PROFILE), dt_s)


def set_point(q: np.ndarray) -> MultiSinePath:
    """A constant reference q_r(s) = q (zero amplitude): a regulation task."""
    n = q.shape[0]
    return MultiSinePath(q, np.zeros((1, n)), np.zeros((1, n)), period_s=4.0)


def regulate(
    controller: Controller, q_star: np.ndarray, tau_ext_nm: np.ndarray, duration_s: float
) -> np.ndarray:
    """The closed-form two-link arm from rest at q* with a constant external torque,
    M q̈ + C q̇ + g = clip(τ, ±τ_max) + τ_ext, integrated by semi-implicit Euler at dt;
    returns e = q* − q at every step, (steps, 2) (rad)."""
    plant = TwoLinkAnalyticModel()
    limit = np.array(PROFILE.torque_limits_nm)
    q, qd = q_star.copy(), np.zeros(2)
    controller.reset(q, qd, 0.0)
    errors = []
    for _ in range(round(duration_s / DT_S)):
        errors.append(q_star - q)
        tau = np.clip(controller.step(q, qd, DT_S), -limit, limit)
        qdd = np.linalg.solve(
            plant.mass_matrix(q), tau + tau_ext_nm - plant.coriolis(q, qd) - plant.gravity(q)
        )
        qd = qd + DT_S * qdd
        q = q + DT_S * qd
    return np.array(errors)


# -- gains ---------------------------------------------------------------------------------


def test_default_gains_place_the_poles_of_a_decoupled_joint() -> None:
    """m s³ + K_d s² + K_p s + K_i = m (s + ω_i)(s² + 2ζωs + ω²): K_p = (ω² + 2ζωω_i) m,
    K_d = (2ζω + ω_i) m, K_i = ω²ω_i m with m = diag M(q_home) (rtol 5e-4: the gains are
    rounded to four digits); ū = ½ τ_max."""
    ctx = two_link_context()
    g = pid_gravity.default_gains(ctx)
    m = np.diag(ctx.model.mass_matrix(PROFILE.home()))
    w, wi = 20.0, 5.0
    np.testing.assert_allclose(g.kp_nm_rad, (w**2 + 2 * w * wi) * m, rtol=5e-4)
    np.testing.assert_allclose(g.kd_nms_rad, (2 * w + wi) * m, rtol=5e-4)
    np.testing.assert_allclose(g.ki_nm_rad_s, w**2 * wi * m, rtol=5e-4)
    np.testing.assert_allclose(g.windup_nm, 0.5 * np.array(PROFILE.torque_limits_nm))
    for j in range(2):  # the cubic's roots: −ω (double, ζ = 1) and −ω_i
        roots = np.sort(np.roots([m[j], g.kd_nms_rad[j], g.kp_nm_rad[j], g.ki_nm_rad_s[j]]).real)
        np.testing.assert_allclose(roots, [-w, -w, -wi], rtol=2e-2)  # a double root splits by √ε


def test_without_integral_rate_the_gains_are_pd_gravitys() -> None:
    """ω_i → 0 gives PD + gravity's K_p = ω² m, K_d = 2ζω m (same cap, same rounding)."""
    ctx = two_link_context()
    pid = pid_gravity.gains_from_rates(ctx, {"omega_i": 1e-9})
    pd = pd_gravity.default_gains(ctx)
    np.testing.assert_allclose(pid.kp_nm_rad, pd.kp_nm_rad, rtol=1e-9)
    np.testing.assert_allclose(pid.kd_nms_rad, pd.kd_nms_rad, rtol=1e-9)


def test_a_capped_bandwidth_keeps_the_ratio_of_the_integral_rate() -> None:
    """At 50 Hz (α / dt = 10 rad/s) the 20 rad/s default is capped to ω' ≤ 10 and ω_i to
    κω' with κ = ω_i / ω = 0.25: the gains are those of (ω', 0.25 ω')."""
    ctx = two_link_context(dt_s=0.02)
    g = pid_gravity.default_gains(ctx)
    m = np.diag(ctx.model.mass_matrix(PROFILE.home()))
    w = float(np.mean(np.asarray(g.kd_nms_rad) / (2.25 * m)))  # K_d = (2 + κ) ω' m
    assert w <= MAX_FREQUENCY_PER_SAMPLE / 0.02 * (1 + 1e-3)
    expected = PIDGravityGains.from_inertia(m, w, 1.0, 0.25 * w, g.windup_nm)
    np.testing.assert_allclose(g.kp_nm_rad, expected.kp_nm_rad, rtol=1e-3)
    np.testing.assert_allclose(g.ki_nm_rad_s, expected.ki_nm_rad_s, rtol=1e-3)


@pytest.mark.parametrize("field", ["kp_nm_rad", "kd_nms_rad", "ki_nm_rad_s", "windup_nm"])
@pytest.mark.parametrize("bad", [0.0, -1.0, np.nan, np.inf, (1.0, 0.0)])
def test_bad_gains_raise_value_error(field: str, bad: Any) -> None:
    good = {"kp_nm_rad": 1.0, "kd_nms_rad": 1.0, "ki_nm_rad_s": 1.0, "windup_nm": 1.0}
    with pytest.raises(ValueError, match=field):
        PIDGravityGains(**{**good, field: bad})


def test_bad_rates_and_gains_of_another_controller_raise() -> None:
    ctx = two_link_context()
    for fraction in (0.0, -0.1, 1.5):
        with pytest.raises(InvalidConfigError, match="windup_fraction"):
            pid_gravity.gains_from_rates(ctx, {"windup_fraction": fraction})
    with pytest.raises(InvalidConfigError, match="unknown pid_gravity gain rate"):
        pid_gravity.gains_from_rates(ctx, {"omega_I": 5.0})
    with pytest.raises(InvalidArgumentError, match="PIDGravityGains"):
        PIDGravityController(ctx.model, ctx.path, pd_gravity.default_gains(ctx))
    with pytest.raises(ValueError, match="one entry per joint"):
        PIDGravityController(ctx.model, ctx.path, PIDGravityGains(1.0, 1.0, (1.0, 1.0, 1.0), 1.0))


# -- the integral ----------------------------------------------------------------------------


def test_integral_removes_the_steady_error_of_a_constant_torque() -> None:
    """Set point q* = home, τ_ext = (3, −1.5) N·m on the exact plant. PD + g settles at
    K_p e = −τ_ext (to 1%: after 3 s its double pole at −20 rad/s has decayed by e⁻⁶⁰);
    PID + g has e → 0 at the rate of its slowest pole, −ω_i = −5 1/s, and K_i z → −τ_ext.
    After 3 s that mode is down by e⁻¹⁵ ≈ 3e-7 of its start: |e| < 1e-3 |e_PD| and
    |K_i z + τ_ext| < 1e-3 |τ_ext| are loose by two decades; the error must fall second
    by second, and the integral stay inside its clamp ū = ½ τ_max = (20, 10) N·m."""
    ctx = two_link_context()
    q_star, tau_ext = PROFILE.home(), np.array([3.0, -1.5])
    path, model = set_point(q_star), TwoLinkAnalyticModel()
    pd = PDGravityController(model, path, pd_gravity.default_gains(ctx))
    pid = PIDGravityController(model, path, pid_gravity.default_gains(ctx))
    e_pd = regulate(pd, q_star, tau_ext, 3.0)[-1]
    np.testing.assert_allclose(pd.kp * e_pd, -tau_ext, rtol=1e-2)
    e_pid = np.linalg.norm(regulate(pid, q_star, tau_ext, 3.0), axis=1)
    per_second = e_pid[[999, 1999, 2999]]
    assert np.all(np.diff(per_second) < 0), per_second
    assert per_second[-1] < 1e-3 * np.linalg.norm(e_pd)
    np.testing.assert_allclose(pid.integral_torque(), -tau_ext, rtol=0, atol=1e-3 * 3.36)
    assert pid.diagnostics()["integral_torque_nm"] == pytest.approx(np.linalg.norm(tau_ext), 1e-3)


def test_pid_removes_the_error_of_a_payload_pd_gravity_keeps() -> None:
    """The iiwa carrying a 2 kg payload (its level-1 payload) from t = 0 that the nominal
    model does not know, on its default path at 1 kHz. Measured over [3, 4] s: PD + g
    0.19 rad mean |e| (the payload's weight and inertia against K_p), PID + g 0.010 rad;
    claimed: PID's error is below a tenth of PD's (the integral removes the part of the
    payload torque slower than ω_i = 5 1/s; the path's 8 s period is slower)."""
    errors = {}
    env = gym.make(
        "ptrack_gym/IiwaTrack-v0",
        disturbance={"type": "payload", "mass_kg": 2.0, "pick_s": 0.0},
        horizon_s=5.0,
    )
    try:
        for module in (pd_gravity, pid_gravity):
            u = env.unwrapped
            obs, _ = env.reset(seed=0)
            policy = ControllerPolicy(env, module.build(ControlContext.from_env(env)))
            e = []
            for _ in range(4000):
                e.append(np.linalg.norm(u.path.evaluate(u.s0 + u.t)[0] - u.joint_state()[0]))
                obs, _, terminated, _, _ = u.step(policy.action(obs))
                assert not terminated
            errors[module.NAME] = float(np.mean(e[3000:]))
    finally:
        env.close()
    assert errors["pd_gravity"] > 0.1  # the payload is felt: not a vacuous comparison
    assert errors["pid_gravity"] < 0.1 * errors["pd_gravity"], errors


def hold(controller: PIDGravityController, e0: np.ndarray, s0: float, steps: int) -> list[float]:
    """Step with the state held at a constant error e = e0 from the moving reference
    (q = q_r(s) − e0, q̇ = q_r'(s)); returns K_i z of joint 0 after every step (N·m)."""
    out = []
    for k in range(steps):
        q_r, qd_r, _ = controller.path.evaluate(s0 + k * DT_S)
        controller.step(q_r - e0, qd_r, DT_S)
        assert np.all(np.abs(controller.integral_torque()) <= controller.windup * (1 + 1e-12))
        out.append(float(controller.integral_torque()[0]))
    return out


def test_the_clamped_integral_stays_bounded_and_unwinds_at_once() -> None:
    """A blocked arm: e = +0.1 rad held for 2 s, then −0.1 rad. The integral torque K_i z
    ramps at K_i e and stops at ū (every step: |K_i z| ≤ ū); once e flips it crosses zero
    after t = ū / (K_i |e|), the time it took to reach the clamp. An unclamped integrator
    (ū = 1e9 N·m) crosses after the whole 2 s it has wound up."""
    ctx = two_link_context()
    gains = pid_gravity.default_gains(ctx)
    e0 = np.full(2, 0.1)
    crossings = {}
    for label, windup in (("clamped", gains.windup_nm), ("unclamped", 1e9)):
        c = PIDGravityController(ctx.model, ctx.path, replace(gains, windup_nm=windup))
        c.reset(np.zeros(2), np.zeros(2), 0.0)
        wound = hold(c, e0, 0.0, 2000)
        unwound = np.array(hold(c, -e0, 2.0, 3000))
        crossings[label] = (np.argmax(unwound < 0.0) + 1) * DT_S
        if label == "clamped":
            assert wound[-1] == pytest.approx(c.windup[0], rel=1e-12)  # at the clamp
    t_clamp = gains.windup_nm[0] / (gains.ki_nm_rad_s[0] * 0.1)  # s
    assert 0.05 < t_clamp < 1.0  # the clamp is reached inside the 2 s hold
    assert crossings["clamped"] == pytest.approx(t_clamp, abs=2 * DT_S)
    assert crossings["unclamped"] == pytest.approx(2.0, abs=2 * DT_S)


# -- state: reset, determinism --------------------------------------------------------------


def test_reset_clears_the_integral_and_runs_are_deterministic() -> None:
    ctx = two_link_context()
    path = ctx.path
    q, qd = np.array([-0.4, 0.9]), np.array([0.2, -0.1])

    def episode(c: PIDGravityController) -> np.ndarray:
        c.reset(q, qd, 0.3)
        return np.array([c.step(q + 0.01 * k, qd, DT_S) for k in range(300)])

    first, second = pid_gravity.build(ctx), pid_gravity.build(ctx)
    run = episode(first)
    assert np.linalg.norm(first.integral_torque()) > 1.0  # wound up: the reset has work to do
    np.testing.assert_array_equal(run, episode(second))  # two controllers, the same torques
    np.testing.assert_array_equal(run, episode(first))  # reset: the same episode again
    first.reset(q, qd, 0.3)
    assert np.all(first.z == 0.0) and first.diagnostics()["integral_torque_nm"] == 0.0
    q_r, qd_r, _ = path.evaluate(0.3)  # on the reference with z = 0: τ = g(q_r)
    np.testing.assert_allclose(first.step(q_r, qd_r, DT_S), ctx.model.gravity(q_r), atol=1e-12)
