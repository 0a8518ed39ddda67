"""The bounded kernel reward (``reward="kernel"``) and the off-path termination.

The reward is recomputed here from the info's distances and an independent gravity
torque (Pinocchio's RNEA at zero speed and acceleration, not the ``gravity`` call the env
uses); its bounds and the "ending never pays" property are checked on random and
diverging episodes.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import ptrack_gym  # noqa: F401
from ptrack_gym.envs.rewards import KernelReward, multiscale_kernel
from ptrack_gym.errors import InvalidConfigError

ID = "ptrack_gym/TwoLinkTrack-v0"


def make(**kwargs):
    return gym.make(ID, control_hz=250.0, reward="kernel", **kwargs).unwrapped


def expected_reward(env, info, q, weights=(0.5, 0.4, 0.1), scales=(0.1, 0.01, 0.001), su=0.5):
    w = np.asarray(weights) / sum(weights)
    g = env.model.inverse_dynamics(q, np.zeros(env.n), np.zeros(env.n))
    u = (info["tau_nm"] - g) / env.torque_limits_nm
    k = [np.mean([math.exp(-((x / s) ** 2)) for s in scales])
         for x in (info["path_distance"], info["tracking_error"])]  # fmt: skip
    return w[0] * k[0] + w[1] * k[1] + w[2] * math.exp(-float(u @ u) / (env.n * su**2))


def test_multiscale_kernel_values() -> None:
    assert multiscale_kernel(0.0, (0.1, 0.01)) == 1.0
    assert multiscale_kernel(0.01, (0.01,)) == pytest.approx(math.exp(-1.0))
    assert multiscale_kernel(0.01, (0.1, 0.01)) == pytest.approx(
        (math.exp(-0.01) + math.exp(-1)) / 2
    )
    # several scales keep a slope far from the finest one (one kernel alone is flat there)
    fine, multi = (0.001,), (0.1, 0.01, 0.001)
    assert multiscale_kernel(0.05, fine) - multiscale_kernel(0.06, fine) < 1e-300
    assert multiscale_kernel(0.05, multi) - multiscale_kernel(0.06, multi) > 0.01


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kernel_reward_matches_its_formula_and_stays_in_unit_interval(seed: int) -> None:
    env = make(disturbance=("impulse", 1.0))
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    for _ in range(120):
        a = rng.uniform(-1.0, 1.0, env.n)
        _, r, term, _, info = env.step(a)
        q, _ = env.joint_state()
        assert 0.0 <= r <= 1.0
        assert r == pytest.approx(expected_reward(env, info, q), rel=1e-12, abs=1e-15)
        terms = info["reward_path"] + info["reward_time"] + info["reward_effort"]
        assert r == pytest.approx(terms, rel=1e-15)
        if term:
            break
    env.close()


def test_holding_the_arm_against_gravity_costs_no_effort() -> None:
    env = make(kernel_weights=(0.0, 0.0, 1.0))
    env.reset(seed=0, options={"q": np.array([0.3, -0.4]), "qd": np.zeros(2)})
    q, _ = env.joint_state()
    g = env.model.gravity(q)
    _, r, *_ = env.step(g / env.torque_limits_nm)  # exactly the gravity torque
    assert r == pytest.approx(1.0, abs=1e-12)
    env.reset(seed=0, options={"q": np.array([0.3, -0.4]), "qd": np.zeros(2)})
    _, r0, *_ = env.step(np.zeros(2))  # no torque: the arm's whole weight is "effort"
    assert r0 < 0.99
    env.close()


def test_weights_normalise_and_the_terms_obey_them() -> None:
    env_a = make(kernel_weights=(2.0, 2.0, 0.0))
    env_b = make(kernel_weights=(1.0, 1.0, 0.0))
    for env in (env_a, env_b):
        env.reset(seed=3)
    a = np.array([0.2, -0.1])
    ra = env_a.step(a)[1]
    _, rb, _, _, info = env_b.step(a)
    assert ra == rb and info["reward_effort"] == 0.0
    env_a.close()
    env_b.close()


def test_off_path_ends_the_episode_and_ending_never_pays() -> None:
    env = make(max_path_distance_rad=0.2, start="rest_near_path", start_offset_rad=0.0)
    env.reset(seed=0)
    rewards, ended = [], None
    for k in range(1000):
        _, r, term, _, info = env.step(np.zeros(env.n))  # the arm falls off the path
        rewards.append(r)
        assert info["off_path"] == (info["path_distance"] > 0.2)
        if term:
            ended = k
            break
    assert ended is not None and info["off_path"] and not info["unstable"]
    assert min(rewards) >= 0.0  # so the return of any continuation is >= the ended one's
    env.close()


def test_no_off_path_end_without_the_option_and_quadratic_reward_unchanged() -> None:
    plain = gym.make(ID, control_hz=250.0).unwrapped
    plain.reset(seed=0)
    _, r, term, _, info = plain.step(np.zeros(2))
    assert not term and not info["off_path"] and r < 0  # the quadratic reward
    assert r == pytest.approx(info["reward_path"] + info["reward_time"] + info["reward_effort"])
    plain.close()


def test_unstable_step_earns_zero_with_the_kernel_reward() -> None:
    env = make()
    env.reset(seed=0, options={"qd": np.array([49.9, 0.0])})
    stepped = [env.step(np.ones(2)) for _ in range(30)]
    unstable = [s for s in stepped if s[4]["unstable"]]
    assert unstable and unstable[0][1] == 0.0 and unstable[0][2]
    env.close()


@pytest.mark.parametrize(
    "kwargs",
    [
        {"reward": "cubic"},
        {"reward": "kernel", "kernel_weights": (1.0, -1.0, 0.0)},
        {"reward": "kernel", "kernel_weights": (0.0, 0.0, 0.0)},
        {"reward": "kernel", "kernel_weights": (1.0, 1.0)},
        {"reward": "kernel", "kernel_scales_rad": ()},
        {"reward": "kernel", "kernel_scales_rad": (0.1, 0.0)},
        {"reward": "kernel", "kernel_scales_rad": "0.1"},
        {"reward": "kernel", "kernel_effort_scale": 0.0},
        {"max_path_distance_rad": 0.0},
        {"max_path_distance_rad": float("nan")},
    ],
)
def test_bad_reward_arguments_raise(kwargs) -> None:
    with pytest.raises(InvalidConfigError):
        gym.make(ID, **kwargs)


def test_kernel_reward_class_direct() -> None:
    kr = KernelReward((1, 0, 1), (0.01,), 0.5, np.array([40.0, 20.0]))
    path, time, effort = kr.terms(0.01, 5.0, np.array([4.0, 0.0]), np.zeros(2))
    assert path == pytest.approx(0.5 * math.exp(-1.0))
    assert time == 0.0
    assert effort == pytest.approx(0.5 * math.exp(-(0.1**2) / (2 * 0.25)))
