"""``actor_bc_weight``: a behaviour-cloning term pulls the actor's deterministic action
toward 0 (the residual's base), added to SB3's actor update without changing the critic's."""

from __future__ import annotations

import pytest

pytest.importorskip(
    "stable_baselines3", reason="the optional 'train' extra (SB3, torch) is not installed"
)

import copy
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import PPO, SAC, TD3

import ptrack_gym  # noqa: F401  (registers the envs)
from train.rl.actor import ActorWarmupCallback, actor_bc_loss, add_actor_bc
from train.rl.config import TrainConfig, TrainConfigError, parse_args, validate


def _filled(cls: type, **kwargs: object) -> SAC | TD3:
    env = gym.make("ptrack_gym/TwoLinkTrack-v0", max_episode_steps=20)
    model = cls("MlpPolicy", env, learning_starts=64, batch_size=16, seed=0,
                policy_kwargs={"net_arch": [16]}, **kwargs)  # fmt: skip
    model.learn(64)  # fills the buffer; no gradient step yet
    return model


def _params(module: torch.nn.Module) -> torch.Tensor:
    return torch.cat([p.detach().flatten().clone() for p in module.parameters()])


@pytest.mark.parametrize("cls", [SAC, TD3])
def test_the_loss_is_the_mean_square_of_the_deterministic_action(cls: type) -> None:
    model = _filled(cls)
    obs = model.replay_buffer.sample(16).observations
    # predict's deterministic action, rescaled from the env's box to the policy's [-1, 1]
    actions, _ = model.predict(obs.numpy(), deterministic=True)
    unit = model.policy.scale_action(actions)
    loss = actor_bc_loss(model, obs, 2.5).detach()
    assert float(loss) == pytest.approx(2.5 * float(np.mean(unit**2)), rel=1e-6)
    assert float(loss) > 0  # a fresh actor is not at 0: the check is not vacuous


def _one_update(model: SAC, batch: object) -> tuple[torch.Tensor, torch.Tensor]:
    actor0, critic0 = _params(model.actor), _params(model.critic)
    model.replay_buffer.sample = lambda *args, **kwargs: batch  # the same batch everywhere
    with torch.random.fork_rng():
        torch.manual_seed(1)
        model.train(gradient_steps=1, batch_size=16)
    return _params(model.actor) - actor0, _params(model.critic) - critic0


def test_the_term_reaches_the_actor_update_and_not_the_critic() -> None:
    base = _filled(SAC)
    pulled = copy.deepcopy(base)
    add_actor_bc(pulled, 1e4)  # large enough to dominate the actor's gradient
    batch = base.replay_buffer.sample(16)
    d_actor, d_critic = _one_update(base, batch)
    d_actor_b, d_critic_b = _one_update(pulled, batch)
    assert torch.equal(d_critic_b, d_critic)
    assert not torch.equal(d_actor_b, d_actor)
    # the step went down the BC term's gradient: the squared action on the batch shrank
    # more than under the plain update
    obs = batch.observations
    assert float(actor_bc_loss(pulled, obs, 1.0).detach()) < float(
        actor_bc_loss(base, obs, 1.0).detach()
    )


def test_training_with_the_term_keeps_the_action_nearer_zero() -> None:
    runs = {}
    for weight in (0.0, 100.0):
        model = _filled(SAC)
        if weight:
            add_actor_bc(model, weight)
        model.learn(300, reset_num_timesteps=False)
        obs = model.replay_buffer.sample(64).observations
        runs[weight] = float(actor_bc_loss(model, obs, 1.0).detach())
    assert runs[100.0] < 0.5 * runs[0.0]  # measured: 0.15x after 300 steps


def test_a_frozen_actor_stays_frozen() -> None:
    model = _filled(SAC)  # past learning_starts: every step below is a gradient step
    add_actor_bc(model, 10.0)
    actor0 = _params(model.actor)
    model.learn(40, callback=ActorWarmupCallback(10_000), reset_num_timesteps=False)
    assert torch.equal(_params(model.actor), actor0)


def test_ppo_is_refused() -> None:
    env = gym.make("ptrack_gym/TwoLinkTrack-v0", max_episode_steps=20)
    with pytest.raises(TrainConfigError, match="SAC and TD3"):
        add_actor_bc(PPO("MlpPolicy", env, n_steps=16, batch_size=16), 1.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"actor_bc_weight": -1.0}, ">= 0"),
        ({"actor_bc_weight": float("nan")}, ">= 0"),
        ({"actor_bc_weight": float("inf")}, ">= 0"),
        ({"actor_bc_weight": 1.0, "algo": "ppo"}, "sac, td3"),
        ({"actor_bc_weight": 1.0, "backend": "sbx"}, "actor_bc_weight"),
    ],
)
def test_bad_weights_are_refused(tmp_path: Path, kwargs: dict, match: str) -> None:
    with pytest.raises(TrainConfigError, match=match):
        validate(TrainConfig(out=str(tmp_path / "r"), **kwargs))
    assert not (tmp_path / "r").exists()


def test_the_flag_reaches_the_config() -> None:
    assert parse_args(["--out", "x", "--actor-bc-weight", "0.5"]).actor_bc_weight == 0.5
