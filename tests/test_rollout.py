"""The evaluation's lean episode loop (``rollout(..., lean=True)``: a controller policy run
on ``env.unwrapped`` with the time limit counted by the loop) produces bit-identical
episodes to the loop through ``gym.make``'s wrappers and SB3's ``predict`` — for every
controller, undisturbed and pushed, time-indexed and path-tracking, to the time limit and
to a divergence — and is only taken where it may be."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import pytest

import ptrack_gym  # noqa: F401
from agents import CONTROLLER_NAMES, ControllerPolicy, make_controller
from agents.residual import make_residual_env
from ptrack_gym.metrics import episode_metrics
from tests.test_divergence import Diverging
from train.evaluation.episode import _lean_limit, rollout

ENV = "ptrack_gym/TwoLinkTrack-v0"


def _episodes(env: gym.Env, make_policy, seed: int) -> list:
    """(record, trace) of the wrapped loop, then of the lean loop, from fresh policies."""
    return [rollout(env, make_policy(), seed, keep_trace=True, lean=lean) for lean in (False, True)]


def _assert_identical(wrapped, lean) -> None:
    (r0, trace0), (r1, trace1) = wrapped, lean
    for field in dataclasses.fields(r0):
        a, b = getattr(r0, field.name), getattr(r1, field.name)
        if isinstance(a, np.ndarray):
            assert a.shape == b.shape and np.array_equal(a, b, equal_nan=True), field.name
        else:
            assert a == b, field.name
    assert np.array_equal(trace0, trace1, equal_nan=True)


@pytest.mark.parametrize("controller", CONTROLLER_NAMES)
@pytest.mark.parametrize("disturbance", [None, ("impulse", 2.0), ("noise", 1.0)])
def test_the_lean_loop_is_bit_identical_to_the_wrapped_one(controller, disturbance) -> None:
    env = gym.make(ENV, control_hz=250.0, max_episode_steps=400, disturbance=disturbance)
    try:
        assert _lean_limit(env, ControllerPolicy(env, make_controller(controller, env))) == 400
        wrapped, lean = _episodes(
            env, lambda: ControllerPolicy(env, make_controller(controller, env)), seed=3
        )
        assert len(lean[0].t_s) == 400 and not lean[0].unstable
        _assert_identical(wrapped, lean)
    finally:
        env.close()


def test_the_lean_loop_ends_a_diverged_episode_where_the_wrapped_one_does() -> None:
    env = gym.make(ENV, control_hz=250.0, max_episode_steps=100)
    try:
        wrapped, lean = _episodes(
            env,
            lambda: ControllerPolicy(env, Diverging(make_controller("passivity", env), 37)),
            seed=0,
        )
        assert lean[0].unstable and len(lean[0].t_s) == 37
        _assert_identical(wrapped, lean)
    finally:
        env.close()


def test_the_lean_loop_is_taken_only_for_a_controller_on_a_plain_env() -> None:
    env = gym.make(ENV, control_hz=250.0, max_episode_steps=50)
    residual = make_residual_env(ENV, "passivity", 0.1, control_hz=250.0, max_episode_steps=50)
    other = gym.make(ENV, control_hz=250.0, max_episode_steps=50)
    try:
        policy = ControllerPolicy(env, make_controller("pd_gravity", env))
        assert _lean_limit(env, policy) == 50
        # another env's policy, a wrapper that changes the episode, no time limit: wrapped loop
        assert _lean_limit(other, policy) is None
        assert _lean_limit(gym.wrappers.ClipAction(env), policy) is None
        assert _lean_limit(env.unwrapped, policy) is None
        rpolicy = ControllerPolicy(residual, make_controller("pd_gravity", residual))
        assert _lean_limit(residual, rpolicy) is None
    finally:
        for e in (env, residual, other):
            e.close()


@pytest.mark.parametrize("disturbance", [None, ("impulse", 2.0)])
def test_metrics_from_the_recorded_info_equal_recomputed_ones(disturbance) -> None:
    """The record's per-step path distance, nearest s and time-indexed error (the env's
    info) give the metrics that recomputing them from q (the projector, the path) gives."""
    env = gym.make(ENV, control_hz=250.0, max_episode_steps=400, disturbance=disturbance)
    try:
        u = env.unwrapped
        record, _ = rollout(env, ControllerPolicy(env, make_controller("passivity", env)), 3)
        recomputed = dataclasses.replace(
            record, path_distance=None, path_s=None, tracking_error=None
        )
        from_info = episode_metrics(record, u.model, u.projector)
        again = episode_metrics(recomputed, u.model, u.projector)
    finally:
        env.close()
    assert record.tracking_error is not None and len(record.tracking_error) == 400
    assert from_info.keys() == again.keys()
    for name, value in from_info.items():
        np.testing.assert_allclose(value, again[name], rtol=1e-9, atol=1e-12, err_msg=name)
