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
    train/configs/rl_deadband_two_link.yml."""
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
