"""Tests of path-following computed torque (:mod:`agents.path_following`).

Closed-loop claims run on the exact nominal model with no disturbance at the env defaults
(physics and control at 1 kHz, default path), against time-indexed computed torque with the
same gains. Path distances are measured by the package's metrics
(:func:`ptrack_gym.metrics.path_distances`) on the true joint positions after each step.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import ptrack_gym  # noqa: F401  (registers the environment ids)
from agents import computed_torque, path_following
from agents.base import ControlContext, Controller, HasResidualFeatures
from agents.path_following import PathFollowingController
from agents.pd_gravity import PDGravityGains
from agents.policy import ControllerPolicy
from agents.residual_features import prior_error_names
from ptrack_gym.errors import InvalidArgumentError, InvalidConfigError, ResetNeededError
from ptrack_gym.metrics import path_distances, rms
from ptrack_gym.robots import ROBOTS

ROBOT_IDS = {name: ROBOTS[name].env_id for name in ("two_link", "iiwa")}

#: Phase delays (s) of the "held back" starts: about 7% of the period, inside the default
#: window (10% of the period: 0.4 s on the two-link arm, 0.8 s on the iiwa).
DELAY_S = {"two_link": 0.3, "iiwa": 0.5}


@pytest.fixture(scope="module")
def envs() -> Iterator[dict[str, gym.Env[Any, Any]]]:
    """One env per robot, shared by the module, then closed."""
    made = {name: gym.make(env_id) for name, env_id in ROBOT_IDS.items()}
    yield made
    for env in made.values():
        env.close()


class Run:
    """A closed-loop run: per step, the true q after it, the torque and the diagnostics."""

    def __init__(self) -> None:
        self.q: list[np.ndarray] = []
        self.tau: list[np.ndarray] = []
        self.diag: list[dict[str, float]] = []

    def path_distance(self, env: gym.Env[Any, Any]) -> np.ndarray:
        """d_k = min_s |q_k − q_r(s)| (rad), by the metrics' projector."""
        return path_distances(env.unwrapped.projector, np.array(self.q))[0]


def simulate(
    env: gym.Env[Any, Any], controller: Controller, duration_s: float, delay_s: float = 0.0
) -> Run:
    """Reset with s₀ = 1 s and the arm on the path ``delay_s`` behind it, at q_r(s₀ − delay),
    q̇ = q_r'(s₀ − delay) (the controller is told s_ref = s₀); run ``duration_s``."""
    u = env.unwrapped
    q0, qd0, _ = u.path.evaluate(1.0 - delay_s)
    obs, _ = env.reset(seed=0, options={"s0": 1.0, "q": q0, "qd": qd0})
    policy = ControllerPolicy(env, controller)
    policy.reset_controller(obs)
    run = Run()
    for _ in range(round(duration_s / u.dt)):
        action = policy.action(obs)
        run.tau.append(policy.last_tau_nm.copy())
        run.diag.append(controller.diagnostics())
        obs, _, terminated, _, _ = u.step(action)
        assert not terminated, f"unstable at t = {u.t:.3f} s"
        run.q.append(u.joint_state()[0])
    return run


def build_pair(env: gym.Env[Any, Any]) -> tuple[Controller, PathFollowingController]:
    """(computed torque, path-following computed torque), default gains."""
    ctx = ControlContext.from_env(env)
    return computed_torque.build(ctx), path_following.build(ctx)


# -- (a) on the path, undisturbed: as computed torque -----------------------------------


@pytest.mark.parametrize("robot", list(ROBOT_IDS))
def test_on_the_path_it_tracks_like_computed_torque(
    robot: str, envs: dict[str, gym.Env[Any, Any]]
) -> None:
    """Started on the path, both stay within the 1-kHz discretisation floor (measured: RMS
    7.0e-5 rad both on the two-link arm, 2.4e-5 rad both on the iiwa); the re-synced phase
    differs from s₀ + t by < 1e-3 s, so the laws nearly coincide — 10% of slack."""
    env = envs[robot]
    ct, pf = build_pair(env)
    d_ct, d_pf = (
        simulate(env, ct, 2.0).path_distance(env),
        simulate(env, pf, 2.0).path_distance(env),
    )
    assert rms(d_pf) < 2e-4
    assert rms(d_pf) < 1.1 * rms(d_ct)


def test_on_the_reference_the_torque_is_the_reference_torque(
    envs: dict[str, gym.Env[Any, Any]],
) -> None:
    """At (q_r(s), q_r'(s)) the window's nearest point is s itself: τ = ID(q_r, q_r', q_r'')."""
    u = envs["iiwa"].unwrapped
    pf = path_following.build(ControlContext.from_env(envs["iiwa"]))
    for s in (0.0, 1.3, 5.7, 7.99):
        q_r, qd_r, qdd_r = u.path.evaluate(s)
        pf.reset(q_r, qd_r, s)
        tau = pf.step(q_r, qd_r, u.dt)
        np.testing.assert_allclose(tau, u.model.inverse_dynamics(q_r, qd_r, qdd_r), atol=1e-6)
        diag = pf.diagnostics()
        assert abs(diag["phase_correction_s"]) < 1e-9
        assert diag["s"] == pytest.approx(s + u.dt + diag["phase_correction_s"], abs=1e-12)


# -- (b) held back: it rejoins the path where the arm is --------------------------------


@pytest.mark.parametrize("robot", list(ROBOT_IDS))
def test_after_a_delay_its_path_distance_is_far_below_computed_torques(
    robot: str, envs: dict[str, gym.Env[Any, Any]]
) -> None:
    """The arm starts on the path but DELAY_S behind the reference. Computed torque cuts
    across the curve to catch up q_r(s₀ + t) (measured path-distance RMS over 3 s: 2.0e-3
    rad two-link, 4.4e-3 rad iiwa; peaks 1.1e-2 and 2.3e-2 rad); the path-following
    variant re-syncs its phase on the first step and stays at the discretisation floor
    (8.3e-5 and 1.5e-5 rad RMS, peaks 1.4e-4 and 2.8e-5 rad): ratios 0.04 and 0.003,
    asserted < 0.1, and its peak < 1e-3 rad."""
    env = envs[robot]
    ct, pf = build_pair(env)
    d_ct = simulate(env, ct, 3.0, DELAY_S[robot]).path_distance(env)
    run = simulate(env, pf, 3.0, DELAY_S[robot])
    d_pf = run.path_distance(env)
    assert rms(d_pf) < 0.1 * rms(d_ct)
    assert np.max(d_pf) < 1e-3 < np.max(d_ct)
    assert run.diag[0]["phase_correction_s"] == pytest.approx(-DELAY_S[robot], abs=1e-6)


# -- (c) the phase: bounded by the window, nominal rate --------------------------------


def test_the_phase_moves_at_most_the_window_per_step_and_catches_a_longer_delay(
    envs: dict[str, gym.Env[Any, Any]],
) -> None:
    """A delay of 0.25 S (1 s) exceeds the window W = 0.1 S (0.4 s): the first two steps move
    the phase by exactly −W (the window's edge), the third finds the arm; no step moves it
    by more than W. The path distance stays far below computed torque's (measured: 5.4e-4
    vs 3.0e-2 rad RMS over 3 s)."""
    env = envs["two_link"]
    ct, pf = build_pair(env)
    window_s = 0.1 * env.unwrapped.path.period_s
    run = simulate(env, pf, 3.0, delay_s=2.5 * window_s)
    corrections = np.array([d["phase_correction_s"] for d in run.diag])
    assert np.all(np.abs(corrections) <= window_s + 1e-12)
    np.testing.assert_allclose(corrections[:2], -window_s, rtol=0, atol=1e-12)
    # The rest of the delay, 0.5 W, less what the two steps pulled the arm forward (3.7e-4 s).
    assert corrections[2] == pytest.approx(-0.5 * window_s, abs=1e-3)
    d_ct = simulate(env, ct, 3.0, delay_s=2.5 * window_s).path_distance(env)
    assert rms(run.path_distance(env)) < 0.1 * rms(d_ct)


@pytest.mark.parametrize("robot", list(ROBOT_IDS))
def test_undisturbed_the_phase_advances_at_one_second_per_second(
    robot: str, envs: dict[str, gym.Env[Any, Any]]
) -> None:
    """On the path with no disturbance: every correction < 1e-5 s (measured ≤ 6e-7 s) and
    the mean phase rate over 3 s is 1 within 1e-3 (measured 0.9999)."""
    env = envs[robot]
    run = simulate(env, build_pair(env)[1], 3.0)
    corrections = np.array([d["phase_correction_s"] for d in run.diag])
    assert np.max(np.abs(corrections)) < 1e-5
    s = np.array([d["s"] for d in run.diag])
    rate = (s[-1] - s[0]) / ((len(s) - 1) * env.unwrapped.dt)
    assert rate == pytest.approx(1.0, abs=1e-3)


def test_the_window_search_finds_the_windows_nearest_point(
    envs: dict[str, gym.Env[Any, Any]],
) -> None:
    """Against a dense scan of the window (h = W/20000 = 2e-5 s), whether the projector's
    global nearest point lies in the window or not: never farther than the scan's best
    point, and nearer by at most the scan's resolution (|q_r'|² (h/2)² ≈ 1e-10 rad² in d²,
    1e-9 asserted)."""
    u = envs["two_link"].unwrapped
    pf = path_following.build(ControlContext.from_env(envs["two_link"]))
    rng = np.random.default_rng(5)
    for _ in range(50):
        s_true, s_hat = rng.uniform(0.0, 4.0), rng.uniform(0.0, 4.0)
        q = u.path.evaluate(s_true)[0] + rng.normal(0.0, 0.02, size=u.n)
        s_star, dist = pf.nearest_in_window(q, s_hat)
        grid = np.linspace(s_hat - pf.window_s, s_hat + pf.window_s, 40001)
        dense = np.linalg.norm(u.path.evaluate(grid)[0] - q, axis=1)
        assert abs(s_star - s_hat) <= pf.window_s + 1e-12
        # The scan's d² exceeds the exact minimum by at most f''(h/2)²/2, f = |q − q_r|².
        assert float(np.min(dense)) ** 2 - 1e-9 <= dist**2 <= float(np.min(dense)) ** 2 + 1e-15
        assert dist == pytest.approx(float(np.linalg.norm(u.path.evaluate(s_star)[0] - q)))


def test_a_finite_sync_rate_blends_the_correction(envs: dict[str, gym.Env[Any, Any]]) -> None:
    """γ = 100 1/s: the first correction is (1 − e^{−γ dt}) of the full one."""
    env = envs["two_link"]
    ctx = ControlContext.from_env(env)
    pf = PathFollowingController(
        computed_torque.ComputedTorqueController(
            ctx.model, ctx.path, path_following.default_gains(ctx)
        ),
        sync_rate_1_s=100.0,
    )
    run = simulate(env, pf, 0.002, delay_s=0.3)
    beta = -math.expm1(-100.0 * env.unwrapped.dt)
    assert run.diag[0]["phase_correction_s"] == pytest.approx(-0.3 * beta, rel=1e-6)


# -- (d) determinism, reset, errors, gains, features ----------------------------------


def test_runs_are_deterministic_and_reset_restores_the_state(
    envs: dict[str, gym.Env[Any, Any]],
) -> None:
    env = envs["two_link"]
    pf = build_pair(env)[1]
    first = simulate(env, pf, 0.5, delay_s=0.3)
    again = simulate(env, pf, 0.5, delay_s=0.3)  # the same controller, reset by the policy
    fresh = simulate(env, build_pair(env)[1], 0.5, delay_s=0.3)
    for other in (again, fresh):
        np.testing.assert_array_equal(np.array(other.tau), np.array(first.tau))
        assert other.diag == first.diag
    q, qd = env.unwrapped.joint_state()
    pf.reset(q, qd, 2.0)
    assert pf.diagnostics() == {"s": 2.0}


def test_bad_input_raises(envs: dict[str, gym.Env[Any, Any]]) -> None:
    env = envs["two_link"]
    ctx = ControlContext.from_env(env)
    pf = path_following.build(ctx)
    q, qd, _ = ctx.path.evaluate(0.0)
    with pytest.raises(ResetNeededError):
        pf.step(q, qd, 1e-3)
    pf.reset(q, qd, 0.0)
    for dt in (0.0, -1e-3, math.nan, math.inf):
        with pytest.raises(InvalidConfigError, match="dt"):
            pf.step(q, qd, dt)
    with pytest.raises(InvalidConfigError, match="shape"):
        pf.step(np.zeros(3), qd, 1e-3)
    with pytest.raises(InvalidConfigError, match="finite"):
        pf.step(np.array([math.nan, 0.0]), qd, 1e-3)
    inner = pf.inner
    for fraction in (0.0, 0.5, -0.1, math.nan):
        with pytest.raises(InvalidConfigError, match="window_fraction"):
            PathFollowingController(inner, window_fraction=fraction)
    for rate in (0.0, -1.0, math.nan):
        with pytest.raises(InvalidConfigError, match="sync_rate"):
            PathFollowingController(inner, sync_rate_1_s=rate)
    with pytest.raises(InvalidArgumentError):
        path_following.build(ctx, PDGravityGains(kp_nm_rad=1.0, kd_nms_rad=1.0))
    with pytest.raises(InvalidConfigError, match="unknown computed_torque_path"):
        path_following.build(ctx, {"omega_s": 3.0})


def test_gains_are_computed_torques_under_their_own_name(
    envs: dict[str, gym.Env[Any, Any]],
) -> None:
    """Its own profile section applies (equal to computed torque's on every robot), not
    computed torque's; given rates override it."""
    ctx = ControlContext.from_env(envs["two_link"])
    assert path_following.NAME == "computed_torque_path"
    assert path_following.DEFAULT_RATES == computed_torque.DEFAULT_RATES
    assert path_following.TUNABLE == computed_torque.TUNABLE
    assert path_following.default_gains(ctx) == computed_torque.default_gains(ctx)

    def with_rates(section: dict[str, dict[str, float]]) -> ControlContext:
        return dataclasses.replace(
            ctx, profile=dataclasses.replace(ctx.profile, controller_gains=section)
        )

    lent = with_rates({"computed_torque": {"omega": 14.0}})  # not its section: defaults
    assert path_following.default_gains(lent).kp_1_s2 == pytest.approx(400.0)
    from ptrack_gym.robots import ROBOTS

    for profile in ROBOTS.values():
        gains = profile.controller_gains
        assert gains["computed_torque_path"] == gains["computed_torque"]
        assert gains["computed_torque_observer"] == gains["computed_torque"]
        assert gains["pid_gravity"] == gains["pd_gravity"]
        assert gains["adaptive_slotine_li"] == gains["slotine_li"]
    own = with_rates({"computed_torque": {"omega": 14.0}, "computed_torque_path": {"omega": 10.0}})
    assert path_following.default_gains(own).kp_1_s2 == pytest.approx(100.0)
    given = path_following.gains_from_rates(own, {"omega": 5.0, "zeta": 2.0})
    assert (given.kp_1_s2, given.kd_1_s) == pytest.approx((25.0, 20.0))


def test_residual_features_are_the_errors_to_the_resynced_clock(
    envs: dict[str, gym.Env[Any, Any]],
) -> None:
    """The block is the time-indexed one (e, ė: a control prior can read e), evaluated
    against the re-synced clock: after a 0.3-s delay it reads the small transverse error,
    where computed torque's reads the whole lag."""
    env = envs["two_link"]
    u = env.unwrapped
    ct, pf = build_pair(env)
    assert isinstance(pf, Controller) and isinstance(pf, HasResidualFeatures)
    block = pf.residual_features(50.0)
    assert prior_error_names(block.names, u.n) == [f"e_{j}_rad" for j in range(u.n)]
    errors = {}
    for name, controller in (("ct", ct), ("pf", pf)):
        simulate(env, controller, 0.001, delay_s=0.3)
        q, qd = u.joint_state()
        values = controller.residual_features(50.0).values(q, qd)  # type: ignore[attr-defined]
        errors[name] = float(np.linalg.norm(values[: u.n]))
    assert errors["pf"] < 1e-2 * errors["ct"]
