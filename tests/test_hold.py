"""``agents.hold``: a policy deciding every k steps — the training wrapper and its run-time
twin take the same decisions, the reward is the mean over the held steps, episodes end
mid-hold, and bad values are refused."""

from __future__ import annotations

import functools
import itertools

import gymnasium as gym
import numpy as np
import pytest

import ptrack_gym  # noqa: F401  (registers the envs)
from agents.hold import ActionRepeat, HeldActionPolicy
from agents.policy import ControllerPolicy
from agents.registry import make_controller
from ptrack_gym.errors import InvalidConfigError

TWO_LINK = "ptrack_gym/TwoLinkTrack-v0"
SHORT = {"control_hz": 250.0, "max_episode_steps": 103, "start": "rest_near_path"}


class _StatePolicy:
    """A deterministic policy of the observation (SB3's predict), counting its calls: PD +
    gravity's action plus a bias that depends on the observation, so a decision taken at
    another step or from another observation gives another action."""

    def __init__(self, env: gym.Env) -> None:
        self.inner = ControllerPolicy(env, make_controller("pd_gravity", env))
        self.calls = 0

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        self.calls += 1
        action, _ = self.inner.predict(obs, state, episode_start, deterministic)
        return np.clip(action + 0.05 * np.tanh(obs[:2]), -1, 1).astype(np.float32), None


@pytest.mark.parametrize("k", [1, 4, 10])
@pytest.mark.parametrize("disturbance", [None, "noise"])
def test_held_policy_on_the_plain_env_takes_the_repeat_wrappers_decisions(
    make_env, k: int, disturbance: str | None
) -> None:
    """Training (ActionRepeat) and evaluation (HeldActionPolicy on the plain env) see the
    same observations at the same decisions and leave the arm in the same state; the
    repeat's reward is the mean of the held steps' rewards and its last decision stops at
    the episode's end (103 steps is not a multiple of 4 or 10)."""
    repeated = ActionRepeat(make_env(TWO_LINK, disturbance=disturbance, **SHORT), k)
    plain = make_env(TWO_LINK, disturbance=disturbance, **SHORT)
    train_policy, eval_policy = _StatePolicy(repeated), _StatePolicy(plain)
    held = HeldActionPolicy(eval_policy, k)

    obs_r, _ = repeated.reset(seed=11)
    decisions_r, rewards_r, taken = [], [], []
    start = np.ones(1, dtype=bool)
    done = False
    while not done:
        decisions_r.append(obs_r)
        action, _ = train_policy.predict(obs_r, episode_start=start)
        start = np.zeros(1, dtype=bool)
        obs_r, reward, term, trunc, info = repeated.step(action)
        rewards_r.append(reward)
        taken.append(info["decision_steps"])
        done = term or trunc

    obs_p, _ = plain.reset(seed=11)
    step_rewards, decisions_p = [], []
    start = np.ones(1, dtype=bool)
    done, steps = False, 0
    while not done:
        before = eval_policy.calls
        action, _ = held.predict(obs_p, episode_start=start)
        if eval_policy.calls > before:
            decisions_p.append(obs_p)
        start = np.zeros(1, dtype=bool)
        obs_p, reward, term, trunc, _ = plain.step(action)
        step_rewards.append(reward)
        done, steps = term or trunc, steps + 1

    assert sum(taken) == steps == 103
    assert taken[-1] == (103 % k or k)
    assert len(decisions_r) == len(decisions_p) == train_policy.calls == eval_policy.calls
    for a, b in zip(decisions_r, decisions_p, strict=True):
        assert np.array_equal(a, b)
    assert np.array_equal(obs_r, obs_p)
    q_r, qd_r = repeated.unwrapped.joint_state()
    q_p, qd_p = plain.unwrapped.joint_state()
    assert np.array_equal(q_r, q_p) and np.array_equal(qd_r, qd_p)
    bounds = np.cumsum([0, *taken])
    means = [np.mean(step_rewards[a:b]) for a, b in itertools.pairwise(bounds)]
    assert np.allclose(rewards_r, means, rtol=1e-12, atol=1e-15)


def test_a_new_episode_starts_a_new_decision(make_env) -> None:
    """episode_start forces a fresh decision even mid-hold."""
    env = make_env(TWO_LINK, **SHORT)
    inner = _StatePolicy(env)
    held = HeldActionPolicy(inner, 10)
    obs, _ = env.reset(seed=0)
    held.predict(obs, episode_start=np.ones(1, dtype=bool))
    held.predict(obs, episode_start=np.zeros(1, dtype=bool))
    assert inner.calls == 1
    held.predict(obs, episode_start=np.ones(1, dtype=bool))
    assert inner.calls == 2


@pytest.mark.parametrize("k", [0, -1, 2.0, True, "3", None])
def test_bad_decision_periods_are_refused(make_env, k: object) -> None:
    env = make_env(TWO_LINK, **SHORT)
    with pytest.raises(InvalidConfigError, match="decision_every"):
        ActionRepeat(env, k)  # type: ignore[arg-type]
    with pytest.raises(InvalidConfigError, match="decision_every"):
        HeldActionPolicy(object(), k)  # type: ignore[arg-type]


def test_train_config_checks_the_decision_period(tmp_path) -> None:
    pytest.importorskip("stable_baselines3", reason="the optional 'train' extra")
    from train.rl.config import TrainConfig, TrainConfigError, validate

    with pytest.raises(TrainConfigError, match="decision_every"):
        validate(TrainConfig(out=str(tmp_path / "a"), decision_every=0))
    with pytest.raises(TrainConfigError, match="keep decision_every 1"):
        validate(TrainConfig(out=str(tmp_path / "b"), decision_every=5, imitate="pd_gravity",
                             init_log_std=-3.0, overrides={"learning_starts": 0}))  # fmt: skip
    validate(TrainConfig(out=str(tmp_path / "c"), decision_every=5))


def test_a_run_trains_on_decisions_and_is_evaluated_holding_them(tmp_path) -> None:
    """``--decision-every 5``: the run's steps are decisions (10 per 50-step episode in its
    Monitor log), and the evaluation runs it behind HeldActionPolicy on the unrepeated env,
    recording every env step."""
    pytest.importorskip("stable_baselines3", reason="the optional 'train' extra")
    import pandas as pd

    from train.cli import run_command as _run_command
    from train.evaluation.episode import EpisodeSettings, Task, _sb3_env_and_policy, run_episode

    main = functools.partial(_run_command, "train")

    out = tmp_path / "run"
    main(["--algo", "sac", "--residual", "passivity", "--steps", "60", "--out", str(out),
          "--episode-s", "0.2", "--eval-freq", "0", "--decision-every", "5", "--zero-init-residual",
          "--hp", "learning_starts=20", "--hp", "buffer_size=1000",
          "--hp", "policy_kwargs=dict(net_arch=[16])"])  # fmt: skip
    monitor = pd.read_csv(next(out.glob("monitor/*/*.monitor.csv")), skiprows=1)
    assert (monitor["l"] == 10).all() and len(monitor) == 6
    settings = EpisodeSettings(
        env_id=TWO_LINK, episode_s=0.2, control_hz=250.0, start="on_path", gains="default",
        failure_distance_rad=0.5, recovery_threshold_rad=0.01,
    )  # fmt: skip
    row, _ = run_episode(Task(f"sb3:{out}", "periodic", 1.0, 0, 0), settings)  # acts at once
    assert row["steps"] == 50
    _, policy = _sb3_env_and_policy(f"sb3:{out}", settings, "periodic", 1.0)
    assert isinstance(policy, HeldActionPolicy) and policy.k == 5
