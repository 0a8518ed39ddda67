"""The preview envs (``…TrackPreview-v0``): the ``-v0`` observation followed by the
reference ahead (q_r − q and q_r' at the preview times), exact against the path; the
``-v0`` envs unchanged and not told to upgrade; Gymnasium's and SB3's checkers pass; bad
preview times are refused."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest

import ptrack_gym
from ptrack_gym.envs.preview import DEFAULT_PREVIEW_S, ReferencePreview
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots import plain_env_id


@pytest.mark.parametrize("env_id", ptrack_gym.PREVIEW_ENV_IDS)
def test_a_preview_env_appends_the_reference_ahead_to_the_plain_observation(env_id):
    v0_id = plain_env_id(env_id)
    v1, v0 = gym.make(env_id, path="random", path_seed=3), gym.make(v0_id, path="random",
                                                                      path_seed=3)  # fmt: skip
    try:
        n, m = v0.unwrapped.n, len(DEFAULT_PREVIEW_S)
        assert v1.observation_space.shape == (6 * n + 2 + 2 * n * m,)
        o1, _ = v1.reset(seed=7)
        o0, _ = v0.reset(seed=7)
        rng = np.random.default_rng(0)
        for _ in range(40):
            np.testing.assert_array_equal(o1[: 6 * n + 2], o0)  # the v0 block, bit for bit
            u = v1.unwrapped
            q, _ = u.measured_joint_state()
            for i, delta in enumerate(DEFAULT_PREVIEW_S):
                q_r, qd_r, _ = u.path.evaluate(u.s0 + u.t + delta)
                block = o1[6 * n + 2 + 2 * n * i : 6 * n + 2 + 2 * n * (i + 1)]
                np.testing.assert_allclose(block[:n], q_r - q, atol=1e-6)
                np.testing.assert_allclose(block[n:], qd_r, atol=1e-5)
            assert v1.observation_space.contains(o1)
            a = rng.uniform(-0.2, 0.2, size=n).astype(np.float32)
            o1, r1, *_ = v1.step(a)
            o0, r0, *_ = v0.step(a)
            assert r1 == r0  # the same task: only the observation grows
    finally:
        v1.close()
        v0.close()


def test_the_preview_is_of_the_future_the_env_will_reward():
    """The preview δ ahead at step k is the v0 reference block at step k + δ/Δt."""
    env = gym.make("ptrack_gym/TwoLinkTrackPreview-v0", control_hz=100.0, preview_s=(0.05, 0.1))
    n = 2
    obs, _ = env.reset(seed=1)
    history = [obs]
    for _ in range(12):
        obs, *_ = env.step(np.zeros(n, dtype=np.float32))
        history.append(obs)
    for k in range(len(history) - 10):
        for i, steps in enumerate((5, 10)):  # 0.05 s and 0.1 s at 100 Hz
            later = history[k + steps]
            ahead = history[k][14 + 2 * n * i + n : 14 + 2 * n * (i + 1)]
            np.testing.assert_allclose(ahead, later[3 * n : 4 * n], atol=1e-5)  # q_r'
    env.close()


def test_the_plain_env_is_unchanged():
    env = gym.make("ptrack_gym/IiwaTrack-v0")
    assert env.observation_space.shape == (6 * 7 + 2,)
    assert not isinstance(env, ReferencePreview)
    env.close()


def test_a_preview_env_passes_the_checkers():
    from gymnasium.utils.env_checker import check_env

    sb3_checker = pytest.importorskip(
        "stable_baselines3.common.env_checker", reason="the optional 'train' extra (SB3)"
    )
    env = gym.make("ptrack_gym/TwoLinkTrackPreview-v0")
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*different from the unwrapped.*")
        check_env(env, skip_render_check=True)
    sb3_checker.check_env(env, warn=False)
    env.close()


@pytest.mark.parametrize("preview_s", [(), (0.0,), (-0.1,), (float("nan"),), (True,), ("a",)])
def test_bad_preview_times_are_refused(preview_s):
    with pytest.raises(InvalidConfigError, match="preview_s"):
        gym.make("ptrack_gym/TwoLinkTrackPreview-v0", preview_s=preview_s)


@pytest.mark.parametrize("env_id", ptrack_gym.ENV_IDS)
def test_making_a_plain_env_says_nothing_of_an_upgrade(env_id):
    """No id is a newer version of another: Gymnasium warned on every ``gym.make`` of a
    ``-v0`` that it was out of date while the preview env was registered as its ``-v1``."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # Gymnasium's "out of date" is a DeprecationWarning
        gym.make(env_id).close()
    assert plain_env_id(ptrack_gym.robots.preview_env_id(env_id)) == env_id
    assert gym.spec(ptrack_gym.robots.preview_env_id(env_id)).version == 0
