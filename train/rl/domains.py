"""The numbers of a training config in their domains, and settings that are each valid but
contradict each other — checked by :func:`train.rl.config.validate` before any file is
written, so a bad value is one line (``ptrack train`` exits with 2), never a traceback after
the run folder holds a run that cannot be resumed.

The functions take the config's fields as a mapping (``dataclasses.asdict``) or as values,
so this module does not import :class:`~train.rl.config.TrainConfig` (which imports it).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import torch

from train.common.algorithms import ON_POLICY
from train.rl.hyperparameters import TrainConfigError, hyperparameter_default

#: The lowest value of each integer field (an optional one may also be None).
INT_AT_LEAST: dict[str, int] = {
    "steps": 1, "seed": 0, "n_envs": 1, "eval_freq": 0, "eval_episodes": 1,
    "checkpoint_freq": 0, "critic_warmup_steps": 0, "imitate_rounds": 0, "imitate_steps": 1,
    "imitate_round_steps": 1, "torch_threads": 1, "verbose": 0,
}  # fmt: skip
#: The real fields that must be finite and >= 0.
REAL_AT_LEAST_ZERO = ("scale_fraction", "imitate_noise", "demo_bc_weight", "actor_bc_weight")
#: The real fields that must be finite and > 0 (None allowed where optional).
REAL_ABOVE_ZERO = ("episode_s", "control_hz")
#: Seeds are numpy's legacy ones (``np.random.seed``, which SB3 calls): below 2³².
SEED_LIMIT = 2**32


def check_numbers(fields: Mapping[str, Any]) -> None:
    """Every numeric field of a training config (``dataclasses.asdict``) in its domain, and
    its ``device`` a torch device. The residual's safeguards, the prior, the decision period
    and the env's arguments are checked by their own validators.

    Raises:
        TrainConfigError: naming every bad value at once.
    """
    bad = []
    for name, low in INT_AT_LEAST.items():
        value = fields[name]
        if value is not None and value < low:
            bad.append(f"{name} must be >= {low}, got {value}")
    for name in (*REAL_AT_LEAST_ZERO, *REAL_ABOVE_ZERO):
        value, zero_ok = fields[name], name in REAL_AT_LEAST_ZERO
        if value is None:
            continue
        if not (math.isfinite(value) and (value >= 0 if zero_ok else value > 0)):
            bad.append(f"{name} must be {'>=' if zero_ok else '>'} 0, got {value}")
    if fields["seed"] >= SEED_LIMIT:
        bad.append(f"seed must be < 2**32, got {fields['seed']}")
    if fields["verbose"] > 2:
        bad.append(f"verbose must be 0, 1 or 2, got {fields['verbose']}")
    scale = fields["actor_lr_scale"]
    if not (math.isfinite(scale) and 0 < scale <= 1):
        bad.append(f"actor_lr_scale must be in (0, 1], got {scale}")
    if fields["init_log_std"] is not None and not math.isfinite(fields["init_log_std"]):
        bad.append(f"init_log_std must be finite, got {fields['init_log_std']}")
    try:
        torch.device(fields["device"])
    except RuntimeError:
        bad.append(f"device {fields['device']!r} is not a torch device (cpu, cuda, cuda:1, mps)")
    if bad:
        raise TrainConfigError("; ".join(bad))


def check_agreement(
    fields: Mapping[str, Any],
    algo_kwargs: Mapping[str, Any],
    n_envs: int,
    done: int,
    steps: int,
) -> None:
    """Settings that are each valid but contradict each other, for a run that has taken
    ``done`` steps and takes ``steps`` more:

    * an off-policy actor must get an update before the run's last step, ``done + steps``:
      SB3 updates once ``num_timesteps > learning_starts`` and the critic warm-up holds the
      actor until ``learning_starts + critic_warmup_steps`` — unless ``freeze_actor`` asks
      for that on purpose;
    * PPO's advantage normalisation needs two samples per rollout and per batch;
    * an episodic ``train_freq`` needs one env.

    A ``checkpoint_freq`` or ``eval_freq`` beyond the run is fine: the final state is always
    saved, and the run then has no evaluation during training.

    Raises:
        TrainConfigError: naming the values that disagree.
    """
    algo, backend = fields["algo"], fields["backend"]
    if algo in ON_POLICY:
        n_steps, batch = (
            int(algo_kwargs.get(key, hyperparameter_default(algo, backend, key)))
            for key in ("n_steps", "batch_size")
        )
        if algo_kwargs.get("normalize_advantage", True) and (n_steps * n_envs < 2 or batch < 2):
            raise TrainConfigError(
                f"{algo} normalises advantages: n_steps · n_envs ({n_steps} · {n_envs}) and "
                f"batch_size ({batch}) must be >= 2"
            )
        return
    freq = algo_kwargs.get("train_freq", 1)
    if isinstance(freq, tuple) and freq[1] == "episode" and n_envs > 1:
        raise TrainConfigError(f"train_freq {list(freq)} counts episodes: it needs n_envs 1")
    if fields["freeze_actor"]:
        return
    starts = algo_kwargs.get("learning_starts")
    if starts is None:
        starts = hyperparameter_default(algo, backend, "learning_starts") or 0
    warmup = fields["critic_warmup_steps"]
    frozen, end = int(starts) + warmup, done + steps
    if frozen >= end:
        what = f"learning_starts ({starts})"
        if warmup:
            what += f" + critic_warmup_steps ({warmup}) = {frozen}"
        run = f"{done} done + steps ({steps}) = {end}" if done else f"steps ({steps})"
        raise TrainConfigError(
            f"{what} >= the run's last step, {run}: the actor would never be updated. "
            "Train longer or start sooner (--hp learning_starts=..., --critic-warmup-steps); "
            "to keep the actor as initialised on purpose, --freeze-actor"
        )
