"""A controller that diverges (returns a non-finite torque) has a defined outcome: the
policy adapter raises ``ControllerDivergedError``, an evaluation episode ends there as
unstable and counts as failed, and the residual env terminates the episode with the
unstable penalty and a finite observation — nothing crashes a sweep or a training run."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import ptrack_gym  # noqa: F401
from agents import ControllerPolicy, make_controller
from agents.residual import ResidualWrapper
from ptrack_gym.errors import ControllerDivergedError, PtrackError
from ptrack_gym.metrics import episode_metrics
from train.evaluation.episode import rollout

ENV = "ptrack_gym/TwoLinkTrack-v0"


class Diverging:
    """A real controller that returns NaN from its ``after``-th step on."""

    def __init__(self, inner: Any, after: int) -> None:
        self.inner, self.after, self.steps = inner, after, 0
        self.n = inner.n

    def reset(self, q: np.ndarray, qd: np.ndarray, s_ref: float) -> None:
        self.steps = 0
        self.inner.reset(q, qd, s_ref)

    def step(self, q: np.ndarray, qd: np.ndarray, dt: float) -> np.ndarray:
        self.steps += 1
        tau = self.inner.step(q, qd, dt)
        return np.full_like(tau, np.nan) if self.steps > self.after else tau

    def diagnostics(self) -> dict[str, float]:
        return self.inner.diagnostics()


def make(after: int, steps: int = 100) -> tuple[gym.Env, Diverging]:
    env = gym.make(ENV, control_hz=250.0, max_episode_steps=steps)
    return env, Diverging(make_controller("computed_torque", env), after)


def test_the_policy_adapter_names_a_diverged_controller():
    env, ctrl = make(after=3)
    try:
        policy = ControllerPolicy(env, ctrl)
        obs, _ = env.reset(seed=0)
        for _ in range(3):
            obs, *_ = env.step(policy.action(obs))
        with pytest.raises(ControllerDivergedError, match=r"non-finite torque at t = 0\.0120 s"):
            policy.action(obs)
        assert issubclass(ControllerDivergedError, PtrackError)
        assert issubclass(ControllerDivergedError, FloatingPointError)
    finally:
        env.close()


@pytest.mark.parametrize("after", [0, 40])
def test_an_evaluation_episode_ends_as_unstable_and_failed(after):
    env, ctrl = make(after=after)
    try:
        record, _ = rollout(env, ControllerPolicy(env, ctrl), reset_seed=0)
        u = env.unwrapped
        assert record.unstable and len(record.t_s) == after
        metrics = episode_metrics(
            record, u.model, u.projector, failure_distance_rad=0.5, recovery_threshold_rad=0.01
        )
        assert metrics["failed"] == 1
        assert np.isfinite(metrics["path_dist_rms"])  # padded, as for an unstable plant
    finally:
        env.close()


def test_the_residual_env_terminates_with_the_penalty_and_a_finite_observation():
    env, ctrl = make(after=5)
    wrapped = ResidualWrapper(env, ctrl, scale_nm=1.0)
    try:
        obs, _ = wrapped.reset(seed=0)
        zero = np.zeros(wrapped.action_space.shape, dtype=np.float32)
        for _ in range(5):
            obs, reward, terminated, _, info = wrapped.step(zero)
            assert not terminated
        last = obs
        obs, reward, terminated, truncated, info = wrapped.step(zero)
        assert terminated and not truncated
        assert info["unstable"] and info["controller_diverged"]
        assert reward == -env.unwrapped.config.unstable_penalty
        assert np.all(np.isfinite(obs)) and np.array_equal(obs, last)
        assert wrapped.observation_space.contains(obs)
    finally:
        wrapped.close()


def test_a_residual_env_whose_base_state_diverges_ends_as_unstable():
    """The base's torque can still be finite in the step its own state runs to inf (the
    passivity law's phase s, ṡ): the observation's features of that state are then NaN,
    and the step ends the episode as unstable, its last finite observation returned —
    never a math error inside ``step`` (a residual policy's training died of one)."""
    env = gym.make("ptrack_gym/TwoLinkTrack-v0", max_episode_steps=50)
    wrapped = ResidualWrapper(env, "passivity", scale_fraction=0.1, include_controller_state=True)
    try:
        obs, _ = wrapped.reset(seed=0)
        zero = np.zeros(wrapped.action_space.shape, dtype=np.float32)
        obs, _, terminated, _, _ = wrapped.step(zero)
        assert not terminated
        last = obs
        ctrl, law_step = wrapped.controller, wrapped.controller.step

        def diverging_step(q: np.ndarray, qd: np.ndarray, dt: float) -> np.ndarray:
            tau = law_step(q, qd, dt)  # finite, from the finite state at the sample
            ctrl._state[1] = np.inf  # ṡ after the step
            return tau

        ctrl.step = diverging_step  # type: ignore[method-assign]
        obs, reward, terminated, truncated, info = wrapped.step(zero)
        assert terminated and not truncated
        assert info["unstable"] and info["controller_diverged"]
        assert reward == -env.unwrapped.config.unstable_penalty
        assert np.array_equal(obs, last) and wrapped.observation_space.contains(obs)
        assert wrapped.balance.excess_max_j == np.inf  # storage + tank unbounded
    finally:
        wrapped.close()
