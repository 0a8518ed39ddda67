"""A recurrent policy (sb3-contrib's RecurrentPPO, ``--algo ppo_lstm``): it trains, saves and
reloads like the other algorithms, and the evaluation carries its hidden state through an
episode and starts it over at the next one — without which an LSTM policy would be judged
as a different (memoryless) policy."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("sb3_contrib", reason="the optional 'recurrent' extra is not installed")

from sb3_contrib import RecurrentPPO

from train.evaluation.episode import EpisodeSettings, Task, run_episode
from train.evaluation.policies import algo_class, load_sb3_policy
from train.rl.actor import zero_init_actor
from train.rl.config import TrainConfigError, parse_args, validate
from train.rl.run import run

ENV = "ptrack_gym/TwoLinkTrackPreview-v0"
NET = "dict(net_arch=dict(pi=[16], vf=[16]), lstm_hidden_size=8, log_std_init=-1.0)"


def argv(out: Path, residual: str, *extra: str) -> list[str]:
    """128 steps of 0.2-s TwoLink episodes at 250 Hz, one env, a tiny LSTM."""
    hp = ["n_envs=1", "n_steps=64", "batch_size=32", "n_epochs=1", f"policy_kwargs={NET}"]
    return [
        "--algo", "ppo_lstm", "--env-id", ENV, "--residual", residual, "--steps", "128",
        "--out", str(out), "--episode-s", "0.2", "--eval-freq", "1000", "--checkpoint-freq",
        "1000", "--disturbance", "periodic:0.5", *[x for h in hp for x in ("--hp", h)], *extra,
    ]  # fmt: skip


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("lstm") / "run"
    result = run(parse_args(argv(out, "passivity")))
    assert isinstance(result.model, RecurrentPPO)
    assert result.num_timesteps >= 128
    return out


def test_a_recurrent_run_reloads_and_acts_as_it_trained(trained: Path) -> None:
    model = RecurrentPPO.load(trained / "model.zip", device="cpu")
    policy, _ = load_sb3_policy(f"sb3:{trained}", ENV)
    assert policy.recurrent
    obs = np.random.default_rng(0).normal(size=(6, model.observation_space.shape[0]))
    obs = obs.astype(np.float32)
    # the policy threads the hidden state itself: the same actions as threading it by hand
    state, by_hand = None, []
    for i, o in enumerate(obs):
        x = policy.obs_stats.normalize_obs(o) if policy.obs_stats is not None else o
        a, state = model.predict(x, state, np.array([i == 0]), deterministic=True)
        by_hand.append(a)
    mine = [policy.predict(o, episode_start=np.array([i == 0]))[0] for i, o in enumerate(obs)]
    np.testing.assert_array_equal(np.array(mine), np.array(by_hand))
    # the state matters (an LSTM with memory), and an episode start forgets it
    again, _ = policy.predict(obs[0], episode_start=np.array([False]))
    fresh, _ = policy.predict(obs[0], episode_start=np.array([True]))
    np.testing.assert_array_equal(fresh, mine[0])
    assert not np.array_equal(again, fresh)


def test_the_evaluation_gives_a_recurrent_run_the_same_episode_twice(trained: Path) -> None:
    # a sweep of the -v0 id (the controllers' env) runs the preview run in its own observation
    settings = EpisodeSettings("ptrack_gym/TwoLinkTrack-v0", 0.2, 250.0, "on_path", 0.5, 0.01)
    task = Task(f"sb3:{trained}", "periodic", 0.5, 0, 0)
    first, second = (run_episode(task, settings)[0] for _ in range(2))
    assert first["path_dist_rms"] == second["path_dist_rms"]
    assert np.isfinite(first["path_dist_rms"]) and not first["failed"]


def test_a_zero_initialised_recurrent_residual_starts_at_zero_action() -> None:
    import gymnasium as gym

    env = gym.make("ptrack_gym/TwoLinkTrack-Residual-Passivity-v0")
    try:
        model = RecurrentPPO("MlpLstmPolicy", env, seed=0, device="cpu",
                             policy_kwargs={"lstm_hidden_size": 8, "net_arch": [8]})  # fmt: skip
        zero_init_actor(model)
        obs = np.random.default_rng(1).normal(size=(3, env.observation_space.shape[0]))
        action, _ = model.predict(obs.astype(np.float32), deterministic=True)
        np.testing.assert_array_equal(action, np.zeros_like(action))
    finally:
        env.close()


def test_a_recurrent_algorithm_is_refused_where_it_does_not_exist(tmp_path: Path) -> None:
    with pytest.raises(TrainConfigError, match="sb3 backend only"):
        validate(parse_args(argv(tmp_path / "x", "none", "--backend", "sbx")))
    assert algo_class("ppo_lstm") is RecurrentPPO
    with pytest.raises(TrainConfigError, match="noise_type"):
        validate(parse_args(argv(tmp_path / "y", "none", "--hp", "noise_type=normal")))
    with pytest.raises(TrainConfigError, match="critic_warmup_steps"):
        validate(parse_args(argv(tmp_path / "z", "passivity", "--critic-warmup-steps", "10")))


def test_a_preview_id_takes_its_plain_ids_hyperparameters() -> None:
    from train.rl.hyperparameters import load_hyperparams

    for algo in ("sac", "ppo", "ppo_lstm"):
        plain = load_hyperparams(algo, "ptrack_gym/IiwaTrack-v0", None, {})
        assert load_hyperparams(algo, "ptrack_gym/IiwaTrackPreview-v0", None, {}) == plain
    # the iiwa's own section differs from the default, so the fallback is seen
    assert plain["n_timesteps"] != load_hyperparams("ppo_lstm", ENV, None, {})["n_timesteps"]


def test_a_preview_run_is_refused_as_a_network_base(trained: Path, tmp_path: Path) -> None:
    import shutil

    import yaml

    from agents.network import check_network_folder
    from ptrack_gym.errors import InvalidConfigError

    pure = tmp_path / "pure"  # the run's files as a pure SAC run on the preview id
    shutil.copytree(trained, pure)
    saved = yaml.safe_load((pure / "config.yml").read_text())
    saved["config"].update(residual="none", algo="sac")
    (pure / "config.yml").write_text(yaml.safe_dump(saved))
    with pytest.raises(InvalidConfigError, match="preview observation"):
        check_network_folder(pure, "two_link")
