"""``actor_lr_scale``: the actor learns at a fraction of the critic's rate, and nothing
else about an update changes."""

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
from stable_baselines3 import PPO, SAC

import ptrack_gym  # noqa: F401  (registers the envs)
from train.rl.actor import scale_actor_lr
from train.rl.config import TrainConfig, TrainConfigError, parse_args, validate


def _filled_sac() -> SAC:
    env = gym.make("ptrack_gym/TwoLinkTrack-v0", max_episode_steps=20)
    model = SAC("MlpPolicy", env, learning_starts=64, batch_size=16, seed=0,
                policy_kwargs={"net_arch": [16]})  # fmt: skip
    model.learn(64)  # fills the buffer; no gradient step yet (num_timesteps == learning_starts)
    return model


def _params(module: torch.nn.Module) -> torch.Tensor:
    return torch.cat([p.detach().flatten().clone() for p in module.parameters()])


def _one_update(model: SAC, batch: object) -> tuple[torch.Tensor, torch.Tensor]:
    actor0, critic0 = _params(model.actor), _params(model.critic)
    model.replay_buffer.sample = lambda *args, **kwargs: batch  # both models: the same batch
    with torch.random.fork_rng():  # and the same reparametrisation noise, leaked nowhere
        torch.manual_seed(1)
        model.train(gradient_steps=1, batch_size=16)
    return _params(model.actor) - actor0, _params(model.critic) - critic0


def test_the_actor_moves_scale_times_as_far_and_the_critic_as_before() -> None:
    base = _filled_sac()
    scaled = copy.deepcopy(base)
    scale_actor_lr(scaled, 0.1)
    batch = base.replay_buffer.sample(16)
    d_actor, d_critic = _one_update(base, batch)
    d_actor_s, d_critic_s = _one_update(scaled, batch)
    # one Adam step from fresh moments is lr * g / (|g| + eps) per parameter: exactly the
    # learning rate's ratio wherever the gradient is not ~eps
    assert torch.equal(d_critic_s, d_critic)
    moved = d_actor.abs() > 1e-6
    assert moved.sum() > 100
    np.testing.assert_allclose((d_actor_s[moved] / d_actor[moved]).numpy(), 0.1, rtol=1e-3)


def test_the_scale_never_compounds() -> None:
    model = _filled_sac()
    scale_actor_lr(model, 0.5)
    lr = model.actor.optimizer.param_groups[0]["lr"]
    for _ in range(3):
        model.train(gradient_steps=4, batch_size=16)
        assert model.actor.optimizer.param_groups[0]["lr"] == lr  # restored after each step
    assert model.critic.optimizer.param_groups[0]["lr"] == lr


def test_ppo_is_refused(tmp_path: Path) -> None:
    env = gym.make("ptrack_gym/TwoLinkTrack-v0", max_episode_steps=20)
    with pytest.raises(TrainConfigError, match="SAC and TD3"):
        scale_actor_lr(PPO("MlpPolicy", env, n_steps=16, batch_size=16), 0.5)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"actor_lr_scale": 0.0}, r"\(0, 1\]"),
        ({"actor_lr_scale": float("nan")}, r"\(0, 1\]"),
        ({"actor_lr_scale": 2.0}, r"\(0, 1\]"),
        ({"actor_lr_scale": 0.5, "algo": "ppo"}, "sac, td3"),
        ({"actor_lr_scale": 0.5, "backend": "sbx"}, "actor_lr_scale"),
    ],
)
def test_bad_scales_are_refused(tmp_path: Path, kwargs: dict, match: str) -> None:
    with pytest.raises(TrainConfigError, match=match):
        validate(TrainConfig(out=str(tmp_path / "r"), **kwargs))
    assert not (tmp_path / "r").exists()


def test_the_flag_reaches_the_config() -> None:
    assert parse_args(["--out", "x", "--actor-lr-scale", "0.1"]).actor_lr_scale == 0.1
