"""A saved pure policy as a controller (``agents.network``) and as a residual's base
(``residual="network"``): it acts as the SB3 model does, a zero residual over it runs
exactly as it does alone, and every bad configuration is refused."""

from __future__ import annotations

import pytest

pytest.importorskip(
    "stable_baselines3", reason="the optional 'train' extra (SB3, torch) is not installed"
)

import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import SAC, TD3
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

import ptrack_gym  # noqa: F401  (registers the envs)
from agents.network import load_network_controller
from agents.policy import ControllerPolicy
from agents.residual import make_residual_env
from ptrack_gym.errors import InvalidConfigError
from train.rl.config import TrainConfig, TrainConfigError, validate

TWO_LINK = "ptrack_gym/TwoLinkTrack-v0"
SHORT = {"control_hz": 250.0, "max_episode_steps": 150, "start": "rest_near_path"}


def _save_pure_model(folder: Path, seed: int = 0, env_id: str = TWO_LINK) -> SAC:
    """A pure SAC policy with random weights and observation statistics from a short
    random rollout (so the normalization is not the identity), saved as a run folder."""
    venv = VecNormalize(DummyVecEnv([lambda: gym.make(env_id, **SHORT)]), norm_reward=False)
    venv.seed(seed)
    venv.reset()
    rng = np.random.default_rng(seed)
    for _ in range(60):
        venv.step(rng.uniform(-0.2, 0.2, size=(1, venv.action_space.shape[0])))
    model = SAC("MlpPolicy", venv, seed=seed, policy_kwargs={"net_arch": [32, 32]}, device="cpu")
    with torch.no_grad():  # small actions: off tanh's saturation, where errors would hide
        model.actor.mu.weight.mul_(0.2)
    folder.mkdir(parents=True, exist_ok=True)
    model.save(folder / "model.zip")
    venv.save(str(folder / "vecnormalize.pkl"))
    venv.close()
    return model


@pytest.mark.parametrize("disturbance", [None, "noise", "impulse"])
def test_network_controller_acts_as_the_sb3_model_predicts(
    make_env, tmp_path: Path, disturbance: str | None
) -> None:
    """Through ControllerPolicy, the controller's action equals ``model.predict`` on the
    env's own observation, normalized by the saved statistics, at every step (float32
    rounding) — a wrong clock, observation layout or normalization breaks it."""
    model = _save_pure_model(tmp_path / "pure")
    stats = VecNormalize.load(str(tmp_path / "pure" / "vecnormalize.pkl"),
                              DummyVecEnv([lambda: gym.make(TWO_LINK, **SHORT)]))  # fmt: skip
    env = make_env(TWO_LINK, disturbance=disturbance, **SHORT)
    policy = ControllerPolicy(env, load_network_controller(tmp_path / "pure", env))
    actions = []
    for seed in (3, 4):
        obs, _ = env.reset(seed=seed)
        done = False
        while not done:
            mine = policy.action(obs)
            theirs, _ = model.predict(stats.normalize_obs(obs[None]), deterministic=True)
            assert np.abs(mine - theirs[0]).max() < 1e-6
            actions.append(mine)
            obs, _, term, trunc, _ = env.step(mine)
            done = term or trunc
    actions = np.array(actions)
    assert len(actions) > 50
    assert np.mean(np.abs(actions) < 0.9) > 0.5  # mostly unsaturated: the check has teeth


def test_shipped_iiwa_imitation_runs_as_a_controller(make_env) -> None:
    """The shipped pure iiwa policy (the network base of the fourth try) acts as SB3 does."""
    folder = Path(__file__).resolve().parents[1] / "models" / "sac_pure_dagger_iiwa"
    model = SAC.load(folder / "model.zip", device="cpu")
    env = make_env("ptrack_gym/IiwaTrack-v0", control_hz=1000.0, max_episode_steps=300)
    plain = DummyVecEnv([lambda: gym.make("ptrack_gym/IiwaTrack-v0")])
    stats = VecNormalize.load(str(folder / "vecnormalize.pkl"), plain)
    policy = ControllerPolicy(env, load_network_controller(folder, env))
    obs, _ = env.reset(seed=0)
    for _ in range(300):
        mine = policy.action(obs)
        theirs, _ = model.predict(stats.normalize_obs(obs[None]), deterministic=True)
        assert np.abs(mine - theirs[0]).max() < 1e-6
        obs, *_ = env.step(mine)


@pytest.mark.parametrize("disturbance", [None, "impulse"])
def test_zero_residual_over_a_network_is_bit_identical_to_the_network_alone(
    make_env, tmp_path: Path, disturbance: str | None
) -> None:
    """a = 0 over a network base reproduces the network run standalone exactly."""
    _save_pure_model(tmp_path / "pure", seed=1)
    kwargs = {**SHORT, "disturbance": disturbance}
    wrapped = make_env.track(
        make_residual_env(TWO_LINK, "network", base_model=str(tmp_path / "pure"), **kwargs)
    )
    plain = make_env(TWO_LINK, **kwargs)
    policy = ControllerPolicy(plain, load_network_controller(tmp_path / "pure", plain))
    obs_w, _ = wrapped.reset(seed=5)
    obs_p, _ = plain.reset(seed=5)
    n = wrapped.unwrapped.n
    for _ in range(150):
        obs_w, r_w, term_w, trunc_w, _ = wrapped.step(np.zeros(n, dtype=np.float32))
        obs_p, r_p, term_p, trunc_p, _ = plain.step(policy.action(obs_p))
        assert np.array_equal(obs_w[: obs_p.shape[0]], obs_p) and r_w == r_p
        assert (term_w, trunc_w) == (term_p, trunc_p)
        if term_p or trunc_p:
            break
    q_w, qd_w = wrapped.unwrapped.joint_state()
    q_p, qd_p = plain.unwrapped.joint_state()
    assert np.array_equal(q_w, q_p) and np.array_equal(qd_w, qd_p)


def test_network_base_spec_recreates_the_wrapper(make_env, tmp_path: Path) -> None:
    """Given by name and folder, the wrapper is re-creatable from its spec."""
    _save_pure_model(tmp_path / "pure")
    env = make_env.track(make_residual_env(TWO_LINK, "network", base_model=str(tmp_path / "pure")))
    again = make_env.track(env.spec.make())
    assert again.base_model == str(tmp_path / "pure")
    assert type(again.controller).__name__ == "NetworkController"


def test_bad_network_bases_are_refused(make_env, tmp_path: Path) -> None:
    """No folder, a folder without a model, a model for another robot, a base_model on a
    controller base, gains on a network, another algorithm's model: each a clear error."""
    _save_pure_model(tmp_path / "pure")
    with pytest.raises(InvalidConfigError, match="needs base_model"):
        make_residual_env(TWO_LINK, "network")
    with pytest.raises(InvalidConfigError, match=r"no model\.zip"):
        make_residual_env(TWO_LINK, "network", base_model=str(tmp_path / "empty"))
    with pytest.raises(InvalidConfigError, match="base_model is for a 'network' base"):
        make_residual_env(TWO_LINK, "passivity", base_model=str(tmp_path / "pure"))
    with pytest.raises(InvalidConfigError, match="no gains"):
        make_residual_env(
            TWO_LINK, "network", base_model=str(tmp_path / "pure"), base_gains="tuned"
        )
    with pytest.raises(InvalidConfigError, match="pure policy of this robot"):
        make_residual_env("ptrack_gym/IiwaTrack-v0", "network", base_model=str(tmp_path / "pure"))
    iiwa_imitation = str(Path(__file__).resolve().parents[1] / "models" / "sac_pure_dagger_iiwa")
    with pytest.raises(InvalidConfigError, match="trained on iiwa, not panda"):  # same obs size
        make_residual_env("ptrack_gym/PandaTrack-v0", "network", base_model=iiwa_imitation)
    env = make_env(TWO_LINK, **SHORT)
    TD3("MlpPolicy", env, device="cpu").save(tmp_path / "td3" / "model.zip")
    with pytest.raises(InvalidConfigError, match=r"not a SAC model|pure SAC policy"):
        load_network_controller(tmp_path / "td3", env)


def test_train_config_validates_the_network_base(tmp_path: Path) -> None:
    """``train.rl.run`` refuses a network base without a model, a model without a network
    base, and accepts the pair."""
    _save_pure_model(tmp_path / "pure")
    with pytest.raises(TrainConfigError, match="needs base_model"):
        validate(TrainConfig(out=str(tmp_path / "a"), residual="network"))
    with pytest.raises(TrainConfigError, match="need a residual base"):
        validate(TrainConfig(out=str(tmp_path / "b"), base_model=str(tmp_path / "pure")))
    validate(TrainConfig(out=str(tmp_path / "c"), residual="network",
                         base_model=str(tmp_path / "pure")))  # fmt: skip


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"config": {"residual": "passivity"}}, "residual='passivity'"),
        ({"config": {"decision_every": 10}}, "decision_every=10"),
        ({"config": {"algo": "td3"}}, "algo='td3'"),
        ({"derived": {"robot": "panda"}}, "trained on panda, not two_link"),
        ({"derived": {"vec_normalize": {"norm_obs": True}}, "drop": "vecnormalize.pkl"},
         "has no vecnormalize.pkl"),
    ],
)  # fmt: skip
def test_a_base_whose_run_is_not_a_pure_every_step_policy_is_refused(
    tmp_path: Path, change: dict, message: str
) -> None:
    """With its run's config.yml beside it, a base must have been a pure SB3 SAC run of this
    robot deciding every step, with its statistics if it normalized (checked before any env
    or model is built)."""
    import yaml

    from agents.network import check_network_folder

    _save_pure_model(tmp_path / "pure")
    run = {"config": {"residual": "none", "algo": "sac", "backend": "sb3"},
           "derived": {"robot": "two_link"}}  # fmt: skip
    check_network_folder(tmp_path / "pure", "two_link")  # no config.yml: shape checked at load
    (tmp_path / "pure" / "config.yml").write_text(yaml.safe_dump(run))
    check_network_folder(tmp_path / "pure", "two_link")
    for section in ("config", "derived"):
        run[section].update(change.get(section, {}))
    (tmp_path / "pure" / "config.yml").write_text(yaml.safe_dump(run))
    if "drop" in change:
        (tmp_path / "pure" / change["drop"]).unlink()
    with pytest.raises(InvalidConfigError, match=re.escape(message)):
        check_network_folder(tmp_path / "pure", "two_link")


def test_train_refuses_a_base_of_another_robot_before_writing_anything(tmp_path: Path) -> None:
    imitation = str(Path(__file__).resolve().parents[1] / "models" / "sac_pure_dagger_iiwa")
    iiwa = "ptrack_gym/IiwaTrack-v0"
    with pytest.raises(TrainConfigError, match="trained on iiwa, not two_link"):
        validate(TrainConfig(out=str(tmp_path / "a"), residual="network", base_model=imitation))
    with pytest.raises(TrainConfigError, match="a network base has no gains"):
        tuned = TrainConfig(
            out=str(tmp_path / "b"), env_id=iiwa, residual="network", base_model=imitation,
            base_gains="tuned",
        )  # fmt: skip
        validate(tuned)
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


@pytest.mark.parametrize("algo", ["sac", "td3", "ppo"])
def test_the_evaluation_policy_acts_as_sb3_predict_bit_for_bit(tmp_path: Path, algo: str) -> None:
    """``SB3Policy`` skips SB3's per-call ``set_training_mode(False)`` (half of an
    evaluation episode's time) and repeats the rest of ``BasePolicy.predict``: its actions
    equal ``model.predict(deterministic=True)`` bit for bit, for one observation and a
    batch, saturated or not — and it still does after something switched the policy to
    training mode."""
    from stable_baselines3 import PPO

    from train.evaluation.policies import SB3Policy

    env = gym.make(TWO_LINK, **SHORT)
    kwargs = {"policy_kwargs": {"net_arch": [16]}, "seed": 0, "device": "cpu"}
    model = {"sac": SAC, "td3": TD3, "ppo": PPO}[algo]("MlpPolicy", env, **kwargs)
    policy = SB3Policy(model, None)
    assert policy._fast
    rng = np.random.default_rng(0)
    for scale in (0.1, 1.0, 30.0):
        obs = (scale * rng.normal(size=(5, *env.observation_space.shape))).astype(np.float32)
        for x in (obs[0], obs):
            mine, _ = policy.predict(x)
            theirs, _ = model.predict(x, deterministic=True)
            assert mine.shape == theirs.shape and np.array_equal(mine, theirs)
    model.policy.set_training_mode(True)
    mine, _ = policy.predict(obs[1])
    assert not model.policy.training
    assert np.array_equal(mine, model.predict(obs[1], deterministic=True)[0])
    env.close()
