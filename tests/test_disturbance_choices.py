"""A distribution of disturbances (``disturbance_choices``): every reset draws one choice
from the reset seed's own stream; an episode under choice k is, bit for bit, the episode of
the env built with that disturbance alone — a plant edited by an earlier choice included —
every choice is drawn (the draw survives pickling: ``tests/test_path_pool.py``), and bad
choices are refused."""

from __future__ import annotations

from collections import Counter

import gymnasium as gym
import numpy as np
import pytest

import ptrack_gym  # noqa: F401  (registers the envs)
from ptrack_gym.errors import InvalidConfigError

TWO_LINK = "ptrack_gym/TwoLinkTrack-v0"
CHOICES = ["impulse", ("mismatch", 2.0), "noise", ("payload", 1.0)]


def test_an_episode_under_a_choice_is_that_disturbances_own_episode():
    env = gym.make(TWO_LINK, disturbance_choices=CHOICES, control_hz=250.0)
    rng = np.random.default_rng(0)
    seen = []
    for seed in range(10):  # mismatch (plant edits) and the others interleave
        obs, info = env.reset(seed=seed)
        k = info["disturbance_choice"]
        seen.append(k)
        alone = gym.make(TWO_LINK, disturbance=CHOICES[k], control_hz=250.0)
        obs_alone, _ = alone.reset(seed=seed)
        np.testing.assert_array_equal(obs, obs_alone)
        for _ in range(300):
            a = rng.uniform(-0.3, 0.3, size=2).astype(np.float32)
            o1, r1, *_, i1 = env.step(a)
            o2, r2, *_, i2 = alone.step(a)
            np.testing.assert_array_equal(o1, o2)
            assert r1 == r2 and i1["disturbance_work_j"] == i2["disturbance_work_j"]
        alone.close()
    assert 1 in seen and len(set(seen)) >= 3
    env.close()


def test_the_draw_is_the_reset_seeds_and_covers_the_choices():
    a = gym.make(TWO_LINK, disturbance_choices=CHOICES)
    b = gym.make(TWO_LINK, disturbance_choices=CHOICES)
    drawn = [a.reset(seed=s)[1]["disturbance_choice"] for s in range(80)]
    assert drawn == [b.reset(seed=s)[1]["disturbance_choice"] for s in range(80)]
    assert min(Counter(drawn)[k] for k in range(len(CHOICES))) >= 8
    a.close()
    b.close()


def test_choices_and_a_path_pool_draw_independently():
    env = gym.make(TWO_LINK, path="random", path_seeds=[1, 2], disturbance_choices=CHOICES[:2])
    pairs = {tuple(env.reset(seed=s)[1][k] for k in ("path_seed", "disturbance_choice"))
             for s in range(40)}  # fmt: skip
    assert pairs == {(1, 0), (1, 1), (2, 0), (2, 1)}
    env.close()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"disturbance_choices": []}, "one or more disturbance specs"),
        ({"disturbance_choices": ["impulse"], "disturbance": "noise"}, "not both"),
        ({"disturbance_choices": ["impulse", "hurricane"]}, "unknown disturbance preset"),
        ({"disturbance_choices": ["noise", "impulse"], "horizon_s": 2.0}, "impulse: onset_s"),
    ],
)
def test_bad_choices_are_refused_at_construction(kwargs, match):
    with pytest.raises(InvalidConfigError, match=match):
        gym.make(TWO_LINK, **kwargs)
