"""A pool of random paths (``path_seeds``): every reset draws one from the reset seed's own
stream, an episode on a drawn path is the episode of the env built on that path alone,
every path is drawn, the draw survives pickling, and bad pools are refused at construction."""

from __future__ import annotations

import pickle
from collections import Counter

import gymnasium as gym
import numpy as np
import pytest

import ptrack_gym  # noqa: F401  (registers the envs)
from ptrack_gym.errors import InvalidConfigError

TWO_LINK = "ptrack_gym/TwoLinkTrack-v0"


def test_an_episode_on_a_drawn_path_is_the_single_path_env_episode():
    pool = gym.make(TWO_LINK, path="random", path_seeds=[4, 5, 6], disturbance="mixed")
    rng = np.random.default_rng(0)
    for seed in range(4):
        obs, info = pool.reset(seed=seed)
        alone = gym.make(TWO_LINK, path="random", path_seed=info["path_seed"], disturbance="mixed")
        obs_alone, _ = alone.reset(seed=seed)
        np.testing.assert_array_equal(obs, obs_alone)
        for _ in range(200):
            a = rng.uniform(-0.3, 0.3, size=2).astype(np.float32)
            o1, r1, *_ = pool.step(a)
            o2, r2, *_ = alone.step(a)
            np.testing.assert_array_equal(o1, o2)
            assert r1 == r2
        alone.close()
    pool.close()


def test_the_draw_is_the_reset_seeds_and_covers_the_pool():
    a = gym.make(TWO_LINK, path="random", path_seeds=[1, 2, 3])
    b = gym.make(TWO_LINK, path="random", path_seeds=[1, 2, 3])
    drawn = [a.reset(seed=s)[1]["path_seed"] for s in range(60)]
    assert drawn == [b.reset(seed=s)[1]["path_seed"] for s in range(60)]
    counts = Counter(drawn)
    assert set(counts) == {1, 2, 3} and min(counts.values()) >= 10
    periods = set()
    for s in range(6):
        a.reset(seed=s)
        periods.add(a.unwrapped.path.period_s)
    assert len(periods) > 1  # other paths, not one path renamed
    a.close()
    b.close()


@pytest.mark.parametrize(
    ("kwargs", "seed", "before", "after"),
    [
        ({"path": "random", "path_seeds": [1, 2, 3]}, 5, 50, 50),
        # a drawn disturbance too (tests/test_disturbance_choices.py), its plant edits included
        ({"disturbance_choices": ["impulse", ("mismatch", 2.0), "noise", ("payload", 1.0)],
          "control_hz": 250.0}, 3, 100, 200),
    ],
)  # fmt: skip
def test_a_pooled_env_pickles_mid_episode_and_continues_identically(kwargs, seed, before, after):
    env = gym.make(TWO_LINK, **kwargs).unwrapped
    env.reset(seed=seed)
    for _ in range(before):
        env.step(np.full(2, 0.1, dtype=np.float32))
    copy = pickle.loads(pickle.dumps(env))
    assert copy.path_seed == env.path_seed and copy.runner is not env.runner
    for _ in range(after):
        o1, r1, *_ = env.step(np.full(2, 0.1, dtype=np.float32))
        o2, r2, *_ = copy.step(np.full(2, 0.1, dtype=np.float32))
        np.testing.assert_array_equal(o1, o2)
        assert r1 == r2
    env.close()
    copy.close()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"path": "random", "path_seeds": []}, "path_seeds must be distinct integers"),
        ({"path": "random", "path_seeds": [1, 1]}, "path_seeds must be distinct integers"),
        ({"path": "random", "path_seeds": [1, 2.5]}, "path_seeds must be distinct integers"),
        ({"path_seeds": [1, 2]}, "give path='random'"),
        ({"path": "random", "path_seed": 3, "path_seeds": [1, 2]}, "no path_seed"),
    ],
)
def test_bad_pools_are_refused(kwargs, match):
    with pytest.raises(InvalidConfigError, match=match):
        gym.make(TWO_LINK, **kwargs)


def test_a_pool_seed_without_an_admissible_path_is_refused_at_construction(no_admissible_path):
    from ptrack_gym.errors import InvalidPathError

    no_admissible_path(2)
    with pytest.raises(InvalidPathError, match="path_seeds: seed 2: no admissible random path"):
        gym.make(TWO_LINK, path="random", path_seeds=[1, 2, 3])
    with pytest.raises(InvalidPathError, match="path_seeds: seed 2: no admissible random path"):
        gym.make(TWO_LINK, path="random", path_seeds=[2, 3])  # the first one too


@pytest.mark.parametrize("base", ["passivity", "computed_torque"])
def test_a_residual_over_a_pool_runs_each_paths_own_base(base):
    """Each episode's residual env is, bit for bit, the residual env built on the drawn path
    alone: the wrapper switches to that path's base (and its features) at the reset."""
    from agents.residual_wrapper import ResidualWrapper

    pool = ResidualWrapper(gym.make(TWO_LINK, path="random", path_seeds=[4, 5, 6]), base,
                           prior_gain_per_rad=5.0)  # fmt: skip
    rng = np.random.default_rng(1)
    drawn = set()
    for seed in range(5):
        obs, _ = pool.reset(seed=seed)
        drawn.add(pool.tracking_env.path_seed)
        alone = ResidualWrapper(
            gym.make(TWO_LINK, path="random", path_seed=pool.tracking_env.path_seed), base,
            prior_gain_per_rad=5.0,
        )  # fmt: skip
        obs_alone, _ = alone.reset(seed=seed)
        np.testing.assert_array_equal(obs, obs_alone)
        assert pool.observation_space.contains(obs)
        for _ in range(150):
            a = rng.uniform(-1, 1, size=2)
            o1, r1, *_ = pool.step(a)
            o2, r2, *_ = alone.step(a)
            np.testing.assert_array_equal(o1, o2)
            assert r1 == r2
            assert pool.observation_space.contains(o1)
        alone.close()
    assert len(drawn) > 1
    pool.close()


def test_a_residual_over_a_pool_needs_its_base_by_name():
    from agents import make_controller
    from agents.residual_wrapper import ResidualWrapper

    env = gym.make(TWO_LINK, path="random", path_seeds=[1, 2])
    with pytest.raises(InvalidConfigError, match="pool of paths"):
        ResidualWrapper(env, make_controller("pd_gravity", env))
    env.close()
