"""The shared body of the time-indexed baselines (:mod:`agents.time_indexed`): each step is
the subclass's law at the clock's reference errors, then the clock advances by dt; the
build paths (defaults, rates, gains) and the diagnostics are the base's."""

from __future__ import annotations

import numpy as np
import pytest

from agents import computed_torque, pd_gravity, slotine_li
from agents.base import ControlContext
from agents.time_indexed import TimeIndexedController
from ptrack_gym.paths import default_path
from ptrack_gym.robots import PinocchioModel, robot_profile

MODULES = {"computed_torque": computed_torque, "pd_gravity": pd_gravity, "slotine_li": slotine_li}


def context(robot: str = "iiwa", dt_s: float = 2e-3) -> ControlContext:
    profile = robot_profile(robot)
    return ControlContext(profile, PinocchioModel(profile), default_path(profile), dt_s)


def law_by_hand(name: str, ctrl, q, qd, s: float) -> np.ndarray:
    """The module docstring's law at (q, q̇) against q_r(s), from ``path.evaluate``."""
    q_r, qd_r, qdd_r = ctrl.path.evaluate(s)
    e, ed = q_r - q, qd_r - qd
    model = ctrl.model
    if name == "computed_torque":
        return model.inverse_dynamics(q, qd, qdd_r + ctrl.kd * ed + ctrl.kp * e)
    if name == "pd_gravity":
        return ctrl.kp * e + ctrl.kd * ed + model.gravity(q)
    qd_ref, qdd_ref = qd_r + ctrl.lam * e, qdd_r + ctrl.lam * ed
    zeros = np.zeros(ctrl.n)
    return (
        model.inverse_dynamics(q, zeros, qdd_ref)
        + slotine_li.christoffel_product(model, q, qd, qd_ref)
        + ctrl.kd * (ed + ctrl.lam * e)
    )


@pytest.mark.parametrize("name", sorted(MODULES))
def test_a_step_is_the_law_at_the_clock_then_the_clock_advances(name: str) -> None:
    ctx = context()
    ctrl = MODULES[name].build(ctx)
    assert isinstance(ctrl, TimeIndexedController)
    rng = np.random.default_rng(3)
    q0 = ctx.profile.home()
    ctrl.reset(q0, np.zeros(ctrl.n), 0.25)
    assert ctrl.diagnostics() == {"s": 0.25}
    s = 0.25
    for _ in range(5):
        q = q0 + 0.05 * rng.standard_normal(ctrl.n)
        qd = 0.3 * rng.standard_normal(ctrl.n)
        tau = ctrl.step(q, qd, ctx.dt_s)
        np.testing.assert_allclose(tau, law_by_hand(name, ctrl, q, qd, s), rtol=1e-10, atol=1e-9)
        s += ctx.dt_s
        diag = ctrl.diagnostics()
        assert diag["s"] == pytest.approx(s, abs=1e-15)
        q_r, qd_r, _ = ctrl.path.evaluate(s - ctx.dt_s)
        assert diag["tracking_error"] == pytest.approx(np.linalg.norm(q_r - q), rel=1e-10)
        assert diag["velocity_error"] == pytest.approx(np.linalg.norm(qd_r - qd), rel=1e-10)


@pytest.mark.parametrize("name", sorted(MODULES))
def test_build_takes_defaults_rates_or_gains(name: str) -> None:
    ctx = context("two_link", 1e-3)
    module = MODULES[name]
    default = module.build(ctx)
    assert default.gains == module.default_gains(ctx)
    assert module.build(ctx, {}).gains == default.gains
    fast = module.build(ctx, {"omega": 30.0})
    assert fast.gains == module.gains_from_rates(ctx, {"omega": 30.0}) != default.gains
    assert module.build(ctx, default.gains).gains is default.gains
    with pytest.raises(TypeError, match=module.build(ctx).gains_type.__name__):
        type(default)(ctx.model, ctx.path, object())
