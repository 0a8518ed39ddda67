"""The residual wrapper's safeguards: the penalty on the learned part reaches the reward
(and nothing else), the path-error gate silences the residual on the path, and with both
off the wrapper is what it was (``test_residual.py`` checks bit-identity to the base)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import ptrack_gym  # noqa: F401
from agents.residual import make_residual_env
from ptrack_gym.errors import InvalidConfigError

ID = "ptrack_gym/TwoLinkTrack-v0"
KW = {"control_hz": 250.0, "max_episode_steps": 250}


def episode(env, actions, seed=0):
    env.reset(seed=seed)
    return [env.step(a) for a in actions]


@pytest.mark.parametrize("reward", ["quadratic", "kernel"])
def test_action_penalty_reaches_the_reward_and_only_the_reward(reward: str) -> None:
    rng = np.random.default_rng(1)
    actions = rng.uniform(-1.5, 1.5, (60, 2))  # some beyond ±1: the penalty sees clip(a)
    w = 0.07
    plain = make_residual_env(ID, "passivity", reward=reward, disturbance="impulse", **KW)
    penal = make_residual_env(
        ID, "passivity", action_penalty=w, reward=reward, disturbance="impulse", **KW
    )
    for (o0, r0, t0, _, _), (o1, r1, t1, _, i1), a in zip(
        episode(plain, actions), episode(penal, actions), actions, strict=True
    ):
        np.testing.assert_array_equal(o0, o1)
        assert t0 == t1
        ac = np.clip(a, -1.0, 1.0)
        bonus = w * (1.0 - float(ac @ ac) / 2)
        assert i1["reward_residual"] == pytest.approx(bonus, rel=1e-15)
        assert r1 == pytest.approx(float(r0) + bonus, rel=1e-12, abs=1e-15)
        if reward == "kernel":
            assert r1 >= 0.0
    plain.close()
    penal.close()


def test_gate_silences_the_residual_on_the_path_and_opens_off_it() -> None:
    gate = 0.01
    env = make_residual_env(ID, "computed_torque", gate_rad=gate, **KW)
    env.reset(seed=0)
    u = env.unwrapped
    for _ in range(20):  # on the path, undisturbed: computed torque keeps d ~ 1e-5 rad
        q, _ = u.measured_joint_state()
        d = u.projector.nearest(q).distance
        _, _, _, _, info = env.step(np.ones(2))
        g = -math.expm1(-((d / gate) ** 2))  # 1 − exp(−(d/d_g)²), without cancellation
        assert info["residual_gate"] == pytest.approx(g, rel=1e-12, abs=1e-300)
        np.testing.assert_allclose(info["tau_residual_nm"], g * env.scale_nm, rtol=1e-12)
        assert info["residual_gate"] < 1e-4
    # 0.1 rad off the path the gate is open: γ = 1 − e^{−100}
    env.reset(seed=0, options={"q": u.path.evaluate(u.s0)[0] + 0.1})
    _, _, _, _, info = env.step(np.ones(2))
    assert info["residual_gate"] > 0.999
    env.close()


@pytest.mark.parametrize("base", ["passivity", "computed_torque"])
def test_deadband_gate_runs_bit_identical_to_the_base_while_on_the_path(base: str) -> None:
    """With d₀ above the base's undisturbed path distance, whatever the policy outputs
    (here random full-authority actions) the episode is the base's, bit for bit: whole
    5-s episodes from several start phases, with the 2-mrad deadband of
    train/configs/campaign/rl_deadband_two_link.yml."""
    rng = np.random.default_rng(3)
    kw = {**KW, "max_episode_steps": 1250}
    actions = rng.uniform(-1.0, 1.0, (1250, 2))
    alone = make_residual_env(ID, base, **kw)
    gated = make_residual_env(ID, base, gate_rad=0.002, gate_deadband_rad=0.002, **kw)
    for seed in (0, 7, 123):
        for (o0, r0, t0, u0, i0), (o1, r1, t1, u1, i1) in zip(
            episode(alone, np.zeros_like(actions), seed),
            episode(gated, actions, seed),
            strict=True,
        ):
            assert i1["residual_gate"] == 0.0
            assert i0["path_distance"] <= 0.002
            np.testing.assert_array_equal(o0, o1)
            assert (r0, t0, u0) == (r1, t1, u1)
            np.testing.assert_array_equal(i0["tau_base_nm"], i1["tau_base_nm"])
    alone.close()
    gated.close()


def test_deadband_gate_opens_past_the_deadband() -> None:
    gate, band = 0.01, 0.05
    env = make_residual_env(ID, "computed_torque", gate_rad=gate, gate_deadband_rad=band, **KW)
    u = env.unwrapped
    for offset, opens in ((0.02, False), (0.08, True), (0.2, True)):
        env.reset(seed=0, options={"q": u.path.evaluate(u.s0)[0] + offset})
        q, _ = u.measured_joint_state()
        d = u.projector.nearest(q).distance
        _, _, _, _, info = env.step(np.ones(2))
        g = -math.expm1(-((max(d - band, 0.0) / gate) ** 2))
        assert info["residual_gate"] == pytest.approx(g, rel=1e-12, abs=1e-300)
        np.testing.assert_allclose(info["tau_residual_nm"], g * env.scale_nm, rtol=1e-12)
        assert (info["residual_gate"] > 0.0) == opens
    env.close()


def test_gate_and_penalty_are_recorded_in_the_spec() -> None:
    env = make_residual_env(
        ID, "passivity", action_penalty=0.1, gate_rad=0.02, gate_deadband_rad=0.003, **KW
    )
    again = env.spec.make()
    assert again.action_penalty == 0.1 and again.gate_rad == 0.02
    assert again.gate_deadband_rad == 0.003
    env.close()
    again.close()


@pytest.mark.parametrize(
    "kwargs",
    [
        {"action_penalty": -0.1},
        {"action_penalty": float("nan")},
        {"action_penalty": True},
        {"gate_rad": 0.0},
        {"gate_rad": float("inf")},
        {"gate_rad": "0.1"},
        {"gate_rad": 0.01, "gate_deadband_rad": -0.001},
        {"gate_rad": 0.01, "gate_deadband_rad": float("nan")},
        {"gate_deadband_rad": 0.001},  # a deadband needs the gate it widens
    ],
)
def test_bad_safeguards_raise(kwargs) -> None:
    with pytest.raises(InvalidConfigError):
        make_residual_env(ID, "passivity", **kwargs, **KW)


# -- the control prior -------------------------------------------------------------------
def _path_error(env, obs) -> np.ndarray:
    """q_r(s) − q from the observation's passivity block (float32)."""
    names = list(env.feature_names)
    inner = env.observation_space.shape[0] - len(names)
    return np.array([obs[inner + names.index(f"path_error_{j}_rad")] for j in range(env.n)])


@pytest.mark.parametrize("accel", [None, 10.0])
def test_prior_adds_clipped_stiffness_to_the_learned_action(accel) -> None:
    """τ_res = authority ⊙ clip(a + clip(g e, −1, 1), −1, 1), e = q_r(s) − q as the policy
    observed it (float32 there, float64 in the wrapper), for random actions under impulses."""
    g = 300.0
    env = make_residual_env(ID, "passivity", prior_gain_per_rad=g, scale_accel_rad_s2=accel,
                            disturbance="impulse", **KW)  # fmt: skip
    rng = np.random.default_rng(5)
    obs, _ = env.reset(seed=2)
    u = env.unwrapped
    seen_unsaturated = False
    for _ in range(200):
        a = rng.uniform(-1.0, 1.0, 2)
        prior = np.clip(g * _path_error(env, obs), -1.0, 1.0)
        seen_unsaturated |= bool(np.any(np.abs(prior) < 0.99) and np.any(np.abs(prior) > 1e-3))
        q, _ = u.measured_joint_state()
        authority = env.scale_nm if accel is None else None
        obs, _, term, trunc, info = env.step(a)
        np.testing.assert_allclose(info["residual_prior"], prior, rtol=1e-5, atol=1e-5)
        a_eff = np.clip(a + info["residual_prior"], -1.0, 1.0)
        expected = authority * a_eff if accel is None else u.model.mass_matrix(q) @ (accel * a_eff)
        np.testing.assert_allclose(info["tau_residual_nm"], expected, rtol=1e-12, atol=1e-12)
        if term or trunc:
            break
    assert seen_unsaturated  # the linear part of the clip was exercised, not only ±1
    env.close()


def test_prior_is_the_starting_policy_and_a_cancels_it() -> None:
    """With a = 0 the residual is the prior's; a = −a_prior (the prior the wrapper reports for
    the state the policy sees) cancels it: the episode is the base's, bit for bit."""
    alone = make_residual_env(ID, "passivity", disturbance="impulse", **KW)
    prior = make_residual_env(ID, "passivity", prior_gain_per_rad=1000.0, disturbance="impulse",
                              **KW)  # fmt: skip
    alone.reset(seed=4)
    prior.reset(seed=4)
    acted = False
    for _ in range(150):
        cancel = -prior.prior_action  # a_prior at the state about to be stepped
        acted |= bool(np.any(cancel != 0.0))
        o0, r0, t0, _, _ = alone.step(np.zeros(2))
        o1, r1, t1, _, i1 = prior.step(cancel)
        np.testing.assert_array_equal(o0, o1)
        np.testing.assert_array_equal(i1["tau_residual_nm"], np.zeros(2))
        assert (r0, t0) == (r1, t1)
    assert acted
    alone.close()
    prior.close()


def test_prior_changes_the_episode_and_the_gate_silences_it_on_the_path() -> None:
    kw = {**KW, "max_episode_steps": 500}
    base = make_residual_env(ID, "passivity", **kw)
    open_ = make_residual_env(ID, "passivity", prior_gain_per_rad=1000.0, **kw)
    gated = make_residual_env(ID, "passivity", prior_gain_per_rad=1000.0, gate_rad=0.002,
                              gate_deadband_rad=0.002, **kw)  # fmt: skip
    zero = np.zeros((500, 2))
    b, o, g = episode(base, zero), episode(open_, zero), episode(gated, zero)
    assert any(np.any(step[4]["tau_residual_nm"] != 0.0) for step in o)
    assert not np.array_equal(b[-1][0], o[-1][0])
    for s0, s1 in zip(b, g, strict=True):  # undisturbed, within the deadband: the base's
        np.testing.assert_array_equal(s0[0], s1[0])
    for env in (base, open_, gated):
        env.close()


def test_penalty_stays_on_the_learned_action_with_a_prior() -> None:
    env = make_residual_env(ID, "passivity", prior_gain_per_rad=1000.0, action_penalty=0.1,
                            disturbance="impulse", **KW)  # fmt: skip
    env.reset(seed=0)
    for _ in range(30):
        _, _, _, _, info = env.step(np.zeros(2))
        assert info["reward_residual"] == 0.1  # a = 0: the full bonus, whatever the prior
    env.close()


def test_prior_bases_are_the_controllers_with_a_reference_error_block() -> None:
    from agents.registry import CONTROLLER_NAMES
    from agents.residual import PRIOR_BASES, prior_error_names

    has = []
    for name in CONTROLLER_NAMES:
        env = make_residual_env(ID, name, **KW)
        if prior_error_names(env.feature_names, env.n) is not None:
            has.append(name)
        env.close()
    assert tuple(has) == PRIOR_BASES


@pytest.mark.parametrize("base", ["computed_torque", "pd_gravity", "slotine_li"])
def test_prior_on_a_time_indexed_base_is_stiffness_toward_its_clock(base: str) -> None:
    """On a time-indexed base the prior's error is q_r(s) − q at the controller's clock s,
    computed here from the path itself (not from the feature block), for the state the
    policy observed; its residual torque is authority ⊙ clip(a + a_prior, −1, 1)."""
    g = 300.0
    env = make_residual_env(ID, base, prior_gain_per_rad=g, disturbance="impulse", **KW)
    rng = np.random.default_rng(8)
    env.reset(seed=3)
    u, clock = env.unwrapped, env.controller.clock
    seen_unsaturated = False
    for _ in range(200):
        q, qd = u.measured_joint_state()
        expected = np.clip(g * (u.path.evaluate(clock.s)[0] - q), -1.0, 1.0)
        np.testing.assert_allclose(env.prior_action, expected, rtol=0, atol=1e-12)
        # ... and the error the base is about to act on (its compiled reference errors)
        tracked = np.clip(g * clock.errors(q, qd, u.dt).e, -1.0, 1.0)
        np.testing.assert_allclose(env.prior_action, tracked, rtol=0, atol=1e-9)
        seen_unsaturated |= bool(np.any(np.abs(expected) < 0.99) and np.any(expected != 0))
        a = rng.uniform(-1.0, 1.0, 2)
        _, _, term, trunc, info = env.step(a)
        np.testing.assert_array_equal(info["residual_prior"], expected)
        np.testing.assert_allclose(
            info["tau_residual_nm"], env.scale_nm * np.clip(a + expected, -1.0, 1.0), rtol=1e-12
        )
        if term or trunc:
            break
    assert seen_unsaturated
    env.close()


def test_prior_is_recorded_in_the_spec_and_works_without_controller_state() -> None:
    env = make_residual_env(ID, "passivity", prior_gain_per_rad=50.0, **KW)
    again = env.spec.make()
    assert again.prior_gain_per_rad == 50.0
    bare = make_residual_env(ID, "passivity", prior_gain_per_rad=50.0,
                             include_controller_state=False, **KW)  # fmt: skip
    env.reset(seed=1, options={"q": env.unwrapped.path.evaluate(env.unwrapped.s0)[0] + 0.003})
    bare.reset(seed=1, options={"q": bare.unwrapped.path.evaluate(bare.unwrapped.s0)[0] + 0.003})
    i0, i1 = env.step(np.zeros(2))[4], bare.step(np.zeros(2))[4]
    np.testing.assert_array_equal(i0["residual_prior"], i1["residual_prior"])
    assert np.any(i0["residual_prior"] != 0.0)
    for e in (env, again, bare):
        e.close()


def test_prior_on_a_controller_without_a_reference_error_block_is_refused() -> None:
    """A controller object whose feature block has no reference error (here: none at all)
    cannot carry a prior: refused when the wrapper is built, with the features it needs."""
    import gymnasium as gym

    from agents.registry import make_controller
    from agents.residual import ResidualWrapper

    env = gym.make(ID, **KW)
    inner = make_controller("pd_gravity", env)

    class Bare:  # the controller protocol without residual_features
        n = inner.n

        def reset(self, q, qd, s):
            inner.reset(q, qd, s)

        def step(self, q, qd, dt):
            return inner.step(q, qd, dt)

        def diagnostics(self):
            return inner.diagnostics()

    with pytest.raises(InvalidConfigError, match="reference-error features"):
        ResidualWrapper(env, Bare(), prior_gain_per_rad=100.0)
    ResidualWrapper(env, Bare())  # without a prior it is a valid base
    env.close()


@pytest.mark.parametrize(
    ("base", "gain"),
    [("passivity", -1.0), ("passivity", float("nan")), ("passivity", True),
     ("passivity", "10"), ("computed_torque", -10.0), ("pd_gravity", float("inf"))],
)  # fmt: skip
def test_bad_prior_is_refused_before_an_env_is_built(base, gain, monkeypatch) -> None:
    import gymnasium as gym

    def no_make(*args, **kwargs):
        raise AssertionError("an env was built")

    monkeypatch.setattr(gym, "make", no_make)
    with pytest.raises(InvalidConfigError, match="prior"):
        make_residual_env(ID, base, prior_gain_per_rad=gain, **KW)


def test_prior_through_the_registered_id_passes_the_checkers() -> None:
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    sb3_checker = pytest.importorskip(
        "stable_baselines3.common.env_checker", reason="the optional 'train' extra (SB3)"
    )

    from agents.residual import residual_env_id

    env = gym.make(residual_env_id(ID, "passivity"), prior_gain_per_rad=1000.0, **KW)
    assert env.get_wrapper_attr("prior_gain_per_rad") == 1000.0
    import warnings

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*different from the unwrapped.*")
        check_env(env, skip_render_check=True)
    sb3_checker.check_env(env, warn=False)
    env.close()
