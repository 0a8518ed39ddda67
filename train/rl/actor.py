"""Surgery on an SB3 actor: zero-initialised output, a constant log-std, a scaled actor
learning rate, a behaviour-cloning pull toward the base, a frozen-actor warm-up.

Each function acts on SB3's torch actor (SAC, TD3; PPO where noted) and is what a
:class:`~train.rl.config.TrainConfig` field turns on (``zero_init_residual``,
``init_log_std``, ``actor_lr_scale``, ``actor_bc_weight``, ``critic_warmup_steps``,
``freeze_actor``).
"""

from __future__ import annotations

from typing import Any

import torch
from stable_baselines3 import SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from torch import nn

from train.rl.hyperparameters import (
    TrainConfigError,
)


# -- model -------------------------------------------------------------------------------
def _last_linear(module: nn.Module) -> nn.Linear:
    linears = [m for m in module.modules() if isinstance(m, nn.Linear)]
    if not linears:
        raise TrainConfigError(f"no linear layer in {module}")
    return linears[-1]


def zero_init_actor(model: BaseAlgorithm) -> None:
    """Zero the weights and bias of the actor's output layer, so the deterministic action
    is exactly 0 (SAC: ``actor.mu``; TD3: the last linear layer of ``actor.mu``, copied to
    the target actor; PPO and RecurrentPPO: ``policy.action_net``)."""
    policy: Any = model.policy
    if isinstance(model, SAC):
        layers = [_last_linear(policy.actor.mu)]
    elif isinstance(model, TD3):
        layers = [_last_linear(policy.actor.mu)]
    elif isinstance(model, OnPolicyAlgorithm):  # PPO, RecurrentPPO
        layers = [_last_linear(policy.action_net)]
    else:
        raise TrainConfigError(f"zero init is not implemented for {type(model).__name__}")
    with torch.no_grad():
        for layer in layers:
            layer.weight.zero_()
            layer.bias.zero_()
    if isinstance(model, TD3):
        policy.actor_target.load_state_dict(policy.actor.state_dict())


def init_actor_log_std(model: BaseAlgorithm, log_std: float) -> None:
    """SAC: make the actor's log-std head constant at ``log_std`` (zero weights, bias =
    ``log_std``): exploration starts with std exp(log_std) before the tanh squashing."""
    if not isinstance(model, SAC):
        raise TrainConfigError(f"init_log_std is implemented for SAC, not {type(model).__name__}")
    head = model.policy.actor.log_std  # type: ignore[union-attr]
    with torch.no_grad():
        head.weight.zero_()
        head.bias.fill_(log_std)


def scale_actor_lr(model: BaseAlgorithm, scale: float) -> None:
    """SAC/TD3: every step of the actor's optimizer uses ``scale`` times the learning rate
    SB3 set for it (its schedule's value; SB3 resets it before each ``train`` call), which
    is restored right after the step, so the scale never compounds and the critic's and
    the entropy coefficient's optimizers are untouched. Hooks are not saved with a model:
    apply again after loading one (``run`` does, on ``--resume``)."""
    if not isinstance(model, (SAC, TD3)):
        raise TrainConfigError(f"actor_lr_scale is for SAC and TD3, not {type(model).__name__}")
    optimizer = model.actor.optimizer  # type: ignore[union-attr]
    saved: list[float] = []

    def before(opt: torch.optim.Optimizer, args: Any, kwargs: Any) -> None:
        saved[:] = [group["lr"] for group in opt.param_groups]
        for group in opt.param_groups:
            group["lr"] = group["lr"] * scale

    def after(opt: torch.optim.Optimizer, args: Any, kwargs: Any) -> None:
        for group, lr in zip(opt.param_groups, saved, strict=True):
            group["lr"] = lr

    optimizer.register_step_pre_hook(before)
    optimizer.register_step_post_hook(after)


def actor_bc_loss(model: BaseAlgorithm, obs: torch.Tensor, weight: float) -> torch.Tensor:
    """λ·mean over the batch and the n action dimensions of μ(s)², μ the actor's
    deterministic action (SAC: tanh of the Gaussian's mean; TD3: the actor's output), in the
    policy's [−1, 1]ⁿ: TD3+BC's (π(s) − a)² with the residual's base action a = 0."""
    actor: Any = model.actor  # type: ignore[attr-defined]
    if isinstance(model, SAC):
        mean_actions, _, _ = actor.get_action_dist_params(obs)
        mu = torch.tanh(mean_actions)
    elif isinstance(model, TD3):
        mu = actor(obs)
    else:
        raise TrainConfigError(f"actor_bc_weight is for SAC and TD3, not {type(model).__name__}")
    return weight * (mu**2).mean()


def add_actor_bc(model: BaseAlgorithm, weight: float) -> None:
    """SAC/TD3: before every step of the actor's optimizer, add the gradient of
    :func:`actor_bc_loss` on a fresh replay-buffer batch (SB3's batch size, observations
    normalised as SB3's ``train`` does) to the actor's loss gradient SB3 has just computed:
    an unbiased gradient of actor loss + BC term from two independent batches, without
    copying SB3's update. Skipped while the actor is frozen (critic warm-up). Hooks are not
    saved with a model: apply again after loading one (``run`` does, on ``--resume``)."""
    if not isinstance(model, (SAC, TD3)):
        raise TrainConfigError(f"actor_bc_weight is for SAC and TD3, not {type(model).__name__}")
    algo: Any = model
    params = list(algo.actor.parameters())

    def before(opt: torch.optim.Optimizer, args: Any, kwargs: Any) -> None:
        if not any(p.requires_grad for p in params):
            return
        batch = algo.replay_buffer.sample(algo.batch_size, env=algo._vec_normalize_env)
        actor_bc_loss(algo, batch.observations, weight).backward()

    algo.actor.optimizer.register_step_pre_hook(before)


class ActorWarmupCallback(BaseCallback):
    """Freeze the actor (its parameters get no gradient, so no update) until the model
    has taken ``until_steps`` env steps — None: for the whole of ``learn``
    (``freeze_actor``) —, while the critic trains on what the frozen actor does. In SB3's
    SAC and TD3 the critic is updated before the actor and the actor loss reaches the
    actor only through its parameters, so a frozen actor leaves the critic's and the
    entropy coefficient's updates as they are."""

    def __init__(self, until_steps: int | None) -> None:
        super().__init__()
        self.until_steps = None if until_steps is None else int(until_steps)
        self.frozen = False

    def _set(self, frozen: bool) -> None:
        for p in self.model.actor.parameters():  # type: ignore[attr-defined]
            p.requires_grad_(not frozen)
        self.frozen = frozen

    def _on_training_start(self) -> None:
        if self.until_steps is None or self.num_timesteps < self.until_steps:
            self._set(True)

    def _on_step(self) -> bool:
        if self.frozen and self.until_steps is not None and self.num_timesteps >= self.until_steps:
            self._set(False)
        return True

    def _on_training_end(self) -> None:
        if self.frozen:
            self._set(False)
