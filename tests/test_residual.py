"""The residual wrapper and the controller factory: bit-exact reproduction of the base
controller at a = 0, the checkers, features, bounds and error paths."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env

import ptrack_gym  # noqa: F401  (registers the environment ids)
from agents.base import Controller
from agents.passivity import PassivityGains
from agents.policy import ControllerPolicy, torque_to_action
from agents.registry import CONTROLLER_NAMES, make_controller
from agents.residual import (
    DEFAULT_SCALE_FRACTION,
    ResidualWrapper,
    make_residual_env,
    residual_env,
    residual_env_id,
)
from ptrack_gym.errors import InvalidConfigError

TWO_LINK = "ptrack_gym/TwoLinkTrack-v0"
#: A short episode at the training rate for TwoLink: 250 Hz, 0.4 s.
SHORT = {"control_hz": 250.0, "max_episode_steps": 100, "start": "rest_near_path"}


@pytest.mark.parametrize(
    ("base", "disturbance", "gains"),
    [
        ("passivity", None, "default"),
        ("computed_torque", None, "default"),
        ("passivity", "noise", "default"),
        ("passivity", "impulse", "tuned"),
        ("computed_torque", None, "tuned"),
    ],
)
@pytest.mark.parametrize("include_state", [True, False])
def test_zero_residual_is_bit_identical_to_the_standalone_controller(
    make_env, base: str, disturbance: str | None, gains: str, include_state: bool
) -> None:
    """a = 0 reproduces ControllerPolicy exactly: obs, reward, flags, true (q, q̇) — with
    the base's default gains and with its tuned ones (``base_gains``)."""
    kwargs = {**SHORT, "disturbance": disturbance}
    wrapped = make_env.track(
        make_residual_env(
            TWO_LINK, base, include_controller_state=include_state, base_gains=gains, **kwargs
        )
    )
    plain = make_env(TWO_LINK, **kwargs)
    policy = ControllerPolicy(plain, make_controller(base, plain, gains))
    obs_w, _ = wrapped.reset(seed=7)
    obs_p, _ = plain.reset(seed=7)
    n_inner = obs_p.shape[0]
    assert obs_w.shape[0] == n_inner + len(wrapped.feature_names)
    assert np.array_equal(obs_w[:n_inner], obs_p)
    zero = np.zeros(2, dtype=np.float32)
    steps = 0
    while True:
        action, _ = policy.predict(obs_p)
        obs_w, r_w, term_w, trunc_w, info_w = wrapped.step(zero)
        obs_p, r_p, term_p, trunc_p, info_p = plain.step(action)
        steps += 1
        assert np.array_equal(obs_w[:n_inner], obs_p)
        assert r_w == r_p and term_w == term_p and trunc_w == trunc_p
        for x_w, x_p in zip(
            wrapped.unwrapped.joint_state(), plain.unwrapped.joint_state(), strict=True
        ):
            assert np.array_equal(x_w, x_p)
        assert np.array_equal(info_w["tau_nm"], info_p["tau_nm"])
        assert np.array_equal(info_w["tau_base_nm"], policy.last_tau_nm)
        assert np.array_equal(info_w["tau_residual_nm"], np.zeros(2))
        assert info_w["controller"] == policy.last_diagnostics
        if term_w or trunc_w:
            break
    assert steps == SHORT["max_episode_steps"]


@pytest.mark.parametrize("base", ["passivity", "computed_torque"])
def test_residual_env_passes_gymnasium_and_sb3_checkers(make_env, base: str) -> None:
    env_checker = pytest.importorskip(
        "stable_baselines3.common.env_checker",
        reason="the optional 'train' extra (SB3, torch) is not installed",
    )
    env = make_env.track(make_residual_env(TWO_LINK, base, **SHORT))
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*different from the unwrapped.*")
        gym_check_env(env, skip_render_check=True)
    env_checker.check_env(env)


def test_bad_actions_raise_value_error_and_step_nothing(make_env) -> None:
    env = make_env.track(make_residual_env(TWO_LINK, "passivity", **SHORT))
    env.reset(seed=0)
    for bad in (np.zeros(3), np.zeros((1, 2)), np.array([0.0, np.nan]), np.array([np.inf, 0])):
        with pytest.raises(ValueError):
            env.step(bad)
    assert env.unwrapped.t == 0.0


def test_residual_torque_adds_scale_times_clipped_action(make_env) -> None:
    """τ = τ_base + scale ⊙ clip(a, −1, 1); the env applies torque_to_action(τ) · τ_max."""
    env = make_env.track(make_residual_env(TWO_LINK, "computed_torque", **SHORT))
    env.reset(seed=1)
    limits = env.unwrapped.torque_limits_nm
    np.testing.assert_array_equal(env.scale_nm, DEFAULT_SCALE_FRACTION * limits)
    _, _, _, _, info = env.step(np.array([3.0, -0.5], dtype=np.float32))
    expected_res = env.scale_nm * np.array([1.0, -0.5])
    np.testing.assert_array_equal(info["tau_residual_nm"], expected_res)
    applied = torque_to_action(info["tau_base_nm"] + expected_res, limits).astype(np.float64)
    np.testing.assert_array_equal(info["tau_nm"], applied * limits)


@pytest.mark.parametrize("base", ["computed_torque", "passivity"])
def test_acceleration_residual_adds_alpha_a_to_the_plants_acceleration(make_env, base: str) -> None:
    """scale_accel_rad_s2 α: τ_res = M(q) α a with M the nominal model at the measured q,
    and PyBullet's plant (an independent computation of the dynamics) then accelerates
    α a more than with a = 0 from the same state — to 0.5% of α over one 2-ms step."""
    kwargs = {"control_hz": 500.0, "max_episode_steps": 10, "start": "on_path"}
    envs = [
        make_env.track(
            make_residual_env("ptrack_gym/IiwaTrack-v0", base, scale_accel_rad_s2=10.0, **kwargs)
        )
        for _ in range(2)
    ]
    a = np.array([1.0, -1.0, 0.5, -0.5, 1.0, -1.0, 0.25])
    for env in envs:
        env.reset(seed=0)
        assert env.scale_nm is None and env.scale_accel_rad_s2 == 10.0
    q, _ = envs[1].unwrapped.measured_joint_state()
    m = envs[1].unwrapped.model.mass_matrix(q).copy()
    _, _, _, _, info0 = envs[0].step(np.zeros(7, dtype=np.float32))
    _, _, _, _, info1 = envs[1].step(a.astype(np.float32))
    np.testing.assert_allclose(info1["tau_residual_nm"], m @ (10.0 * a), rtol=1e-12)
    np.testing.assert_array_equal(info0["tau_base_nm"], info1["tau_base_nm"])
    dqd = envs[1].unwrapped.joint_state()[1] - envs[0].unwrapped.joint_state()[1]
    dt = envs[0].unwrapped.dt
    np.testing.assert_allclose(dqd / dt, 10.0 * a, rtol=0.0, atol=0.05)  # 0.5% of α (0.011 seen)
    # The registered entry point takes the argument too; scale_nm and α together are refused.
    reg = make_env.track(residual_env("two_link", "computed_torque", scale_accel_rad_s2=5.0))
    assert reg.scale_accel_rad_s2 == 5.0
    inner = make_env(TWO_LINK, **SHORT)
    with pytest.raises(InvalidConfigError, match="not both"):
        ResidualWrapper(inner, "passivity", scale_nm=1.0, scale_accel_rad_s2=5.0)


@pytest.mark.parametrize("alpha", [-1.0, float("nan"), float("inf"), True, "10"])
def test_bad_acceleration_authority_is_refused(alpha: object) -> None:
    with pytest.raises(InvalidConfigError, match="scale_accel_rad_s2"):
        make_residual_env(TWO_LINK, "passivity", scale_accel_rad_s2=alpha, **SHORT)


@pytest.mark.parametrize("base", CONTROLLER_NAMES)
def test_features_are_bounded_float32_and_named(make_env, base: str) -> None:
    env = make_env.track(make_residual_env(TWO_LINK, base, disturbance="impulse", **SHORT))
    space = env.observation_space
    assert space.dtype == np.float32
    assert np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))
    n_inner = env.unwrapped.observation_space.shape[0]
    assert space.shape == (n_inner + len(env.feature_names),)
    expected = {
        "passivity": 6 + 4, "passivity_paper": 6 + 4, "computed_torque": 6, "pd_gravity": 6,
        "slotine_li": 8, "pid_gravity": 6, "computed_torque_observer": 6,
        "adaptive_slotine_li": 8, "computed_torque_path": 6,
    }  # fmt: skip
    assert len(env.feature_names) == expected[base]
    obs, _ = env.reset(seed=2)
    rng = np.random.default_rng(0)
    for _ in range(50):
        assert space.contains(obs)
        obs, *_ = env.step(rng.uniform(-1, 1, 2).astype(np.float32))


def test_passivity_features_at_reset(make_env) -> None:
    """At reset s̃ = 0 and ṡ₀ = σ̇(q₀, q̇₀, s₀) (the controller's default), the path error
    is the norm of its vector, and the last base torque is 0."""
    env = make_env.track(make_residual_env(TWO_LINK, "passivity", **SHORT))
    obs, info = env.reset(seed=3)
    f = dict(zip(env.feature_names, obs[-len(env.feature_names) :].astype(np.float64), strict=True))
    assert f["s_tilde_s"] == 0.0
    assert f["sd"] == pytest.approx(f["sigma_dot"], rel=1e-6)
    assert f["sd"] == pytest.approx(info["controller"]["sd"], rel=1e-6)
    err = np.array([f["path_error_0_rad"], f["path_error_1_rad"]])
    assert f["path_error_rad"] == pytest.approx(np.linalg.norm(err), rel=1e-5)
    assert f["tau_base_ratio_0"] == f["tau_base_ratio_1"] == 0.0
    phase = 2 * np.pi * info["controller"]["s"] / env.unwrapped.path.period_s
    assert f["sin_phase_s"] == pytest.approx(np.sin(phase), abs=1e-6)


def test_time_indexed_features_repeat_the_observation_errors(make_env) -> None:
    """Computed torque's clock equals s₀ + t, so its e, ė match obs[4n:6n]."""
    env = make_env.track(make_residual_env(TWO_LINK, "computed_torque", **SHORT))
    obs, _ = env.reset(seed=4)
    n, n_inner = 2, 14
    for _ in range(20):
        obs, _, _, _, info = env.step(np.zeros(2, dtype=np.float32))
    feats = obs[n_inner:]
    np.testing.assert_allclose(feats[: 2 * n], obs[4 * n : 6 * n], atol=1e-6)
    ratio = info["tau_base_nm"] / env.unwrapped.torque_limits_nm
    np.testing.assert_allclose(feats[2 * n :], ratio, rtol=1e-6)


def test_spec_recreates_a_named_controller_but_not_an_object(make_env) -> None:
    env = make_env.track(make_residual_env(TWO_LINK, "pd_gravity", **SHORT))
    remade = make_env.track(gym.make(env.spec))
    assert isinstance(remade, ResidualWrapper)
    assert remade.feature_names == env.feature_names
    assert remade.spec.max_episode_steps == SHORT["max_episode_steps"]
    inner = make_env(TWO_LINK, **SHORT)
    by_object = ResidualWrapper(inner, make_controller("pd_gravity", inner))
    assert by_object.spec is None


@pytest.mark.parametrize("base", ["passivity", "computed_torque"])
def test_tuned_base_gains_build_the_tuned_controller_and_survive_the_spec(
    make_env, base: str
) -> None:
    """``base_gains="tuned"`` gives the base ``agents/tuned``'s gains (not the defaults), on
    the registered id as on ``make_residual_env``, and ``gym.make(env.spec)`` keeps them."""
    env = make_env.track(make_residual_env(TWO_LINK, base, base_gains="tuned", **SHORT))
    plain = make_env(TWO_LINK, **SHORT)
    tuned = make_controller(base, plain, "tuned").gains
    assert env.controller.gains == tuned
    assert make_controller(base, plain).gains != tuned
    assert make_env.track(gym.make(env.spec)).controller.gains == tuned
    registered = make_env.track(
        gym.make(residual_env_id(TWO_LINK, base), base_gains="tuned", **SHORT)
    )
    assert registered.get_wrapper_attr("controller").gains == tuned


def test_base_gains_may_be_the_rates_themselves(make_env) -> None:
    """What a trained residual pins: the base built from the very rates given."""
    rates = {"omega": 25.0, "zeta": 0.9}
    env = make_env.track(make_residual_env(TWO_LINK, "computed_torque", base_gains=rates, **SHORT))
    plain = make_env(TWO_LINK, **SHORT)
    assert env.controller.gains == make_controller("computed_torque", plain, rates).gains
    assert env.controller.gains != make_controller("computed_torque", plain).gains
    for bad in ({}, {"omega": float("nan")}, {"omega": "fast"}, {"omega": True}):
        with pytest.raises(InvalidConfigError, match="base_gains as rates"):
            make_residual_env(TWO_LINK, "computed_torque", base_gains=bad)


def test_bad_configuration_raises(make_env) -> None:
    with pytest.raises(InvalidConfigError, match="base_gains must be one of"):
        make_residual_env(TWO_LINK, "passivity", base_gains="stiff")
    with pytest.raises(InvalidConfigError, match="base_gains must be one of"):
        residual_env("two_link", "passivity", base_gains=None)
    with pytest.raises(ValueError, match="unknown base controller"):
        make_residual_env(TWO_LINK, "lqr")
    with pytest.raises(ValueError, match="scale_fraction"):
        make_residual_env(TWO_LINK, "passivity", scale_fraction=-0.1)
    inner = make_env(TWO_LINK, **SHORT)
    ctrl = make_controller("passivity", inner)
    for scale in (np.array([1.0, 2.0, 3.0]), -1.0, np.nan):
        with pytest.raises(InvalidConfigError):
            ResidualWrapper(inner, ctrl, scale_nm=scale)
    iiwa_ctrl = make_controller("computed_torque", make_env("ptrack_gym/IiwaTrack-v0"))
    with pytest.raises(InvalidConfigError, match="joints"):
        ResidualWrapper(inner, iiwa_ctrl)
    with pytest.raises(InvalidConfigError, match="base_gains is for a base given by name"):
        ResidualWrapper(inner, ctrl, base_gains="tuned")


def test_factory_builds_every_controller(make_env) -> None:
    env = make_env(TWO_LINK, **SHORT)
    for name in CONTROLLER_NAMES:
        assert isinstance(make_controller(name, env), Controller)
    with pytest.raises(ValueError, match="unknown controller"):
        make_controller("lqr", env)


def test_registry_passes_explicit_gains(make_env) -> None:
    env = make_env(TWO_LINK, **SHORT)
    gains = PassivityGains(K=7.0, kappa=2.0, R=0.5, k_pump=1.0)
    assert make_controller("passivity", env, gains).gains == gains
    assert make_controller("passivity", env).gains != gains


class _NoFeatures:
    """A controller without ``residual_features``: the wrapper falls back to τ_base / τ_max."""

    def __init__(self, n: int) -> None:
        self.n = n

    def reset(self, q, qd, s_ref) -> None:
        pass

    def step(self, q, qd, dt):
        return np.zeros(self.n)

    def diagnostics(self) -> dict[str, float]:
        return {}


def test_a_controller_without_features_gets_the_base_torque_block(make_env) -> None:
    inner = make_env(TWO_LINK, **SHORT)
    env = ResidualWrapper(inner, _NoFeatures(2))
    assert env.feature_names == ("tau_base_ratio_0", "tau_base_ratio_1")
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)


def test_controller_policy_restarts_its_controller_after_an_env_reset(make_env) -> None:
    """``action()`` right after ``env.reset`` starts the controller from the new episode's
    start (its path point), not where the last episode left it."""
    env = make_env("ptrack_gym/IiwaTrack-v0", max_episode_steps=100)
    policy = ControllerPolicy(env, make_controller("passivity", env))
    for seed in (0, 1):
        obs, info = env.reset(seed=seed)
        policy.action(obs)
        assert policy.controller.diagnostics()["s"] == pytest.approx(info["s_ref"], abs=1e-2)
        for _ in range(50):
            obs, _, terminated, _, info = env.step(policy.action(obs))
            assert not terminated
        assert info["path_distance"] < 1e-3
