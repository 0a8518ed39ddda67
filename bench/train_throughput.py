"""SAC training throughput on the residual env next to the same env without the base
controller, measured in one run.

Three variants of the env of ``ptrack train`` (the robot's default control rate, 5-s
episodes, start on the path, no disturbance): *pure* (no base controller), *residual,
no features* (the base controller, the inner observation only: the same network input
as pure, so the difference is the controller's cost) and *residual* (the default: the
controller's features appended, which also widens the network's input); over a passivity
base a fourth, *energy tank* (the residual gated by the tank: its prediction and
bookkeeping per step). ``--env-only`` measures the envs' rates without SAC. SAC uses the
packaged ``train/hyperparams/sac.yml`` except ``learning_starts`` (= ``--warmup``) and
the buffer size. For each variant: build the env and SAC, run ``--warmup`` + 50 steps
untimed, then time ``--steps`` more steps of ``learn`` (one gradient step each). The
variants alternate over ``--repeats`` rounds, in reverse order every other round; the
median steps/s is reported. Also measured, without learning: env steps/s under uniform
random actions, whose difference gives the controller's cost per step in µs, reported
as a fraction of a pure SAC step (a load-independent estimate of the same ratio).

Issue target: the base controller costs at most 10 % of SAC's training throughput,
i.e. residual / pure ≥ 0.9.

Run: ``python bench/train_throughput.py [--env ptrack_gym/TwoLinkTrack-v0]
[--base passivity] [--steps 1000] [--warmup 300] [--repeats 3]``. One process at a
time; it sets ``torch.set_num_threads(1)``.

``--learners`` measures instead the learners the RL study chose between, on the pure env
with the kernel reward (same rounds and medians): SB3 SAC with [256, 256] and [64, 64]
networks, sb3-contrib's TQC [64, 64] (when installed: the ``zoo`` extra brings it), SB3
PPO with 8 envs in a DummyVecEnv, and sbx's JAX SAC [64, 64] (``ptrack train --backend sbx``;
the optional ``sbx`` extra: a row says so when it is missing).
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.logger import Logger

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from agents.registry import CONTROLLER_NAMES
from agents.residual import make_residual_env
from train.rl.config import TrainConfig, validate


def make(
    env_id: str, residual: str, features: bool = True, tank: bool = False
) -> tuple[gym.Env, dict]:
    """The training env of ``ptrack train`` (residual "none" or a base controller, with or
    without its features, gated by the energy tank or not) and the resolved SAC
    hyperparameters."""
    res = validate(TrainConfig(out="/nonexistent", algo="sac", env_id=env_id, residual=residual))
    env_kwargs = {
        "control_hz": res.control_hz,
        "max_episode_steps": res.max_episode_steps,
        "start": "on_path",
    }
    if residual == "none":
        return gym.make(env_id, **env_kwargs), res.algo_kwargs
    env = make_residual_env(
        env_id, residual, include_controller_state=features, tank=tank, **env_kwargs
    )
    return env, res.algo_kwargs


def timed_learn(model: Any, untimed: int, steps: int) -> float:
    """Seconds of ``model.learn(steps)`` after an untimed ``model.learn(untimed)`` (the
    buffer fill and first updates, which are not the steady rate). Logs nowhere (SB3's
    default logger would leave a ``/tmp/SB3-<date>`` folder per model)."""
    model.set_logger(Logger(folder=None, output_formats=[]))
    model.learn(total_timesteps=untimed)
    t0 = time.perf_counter()
    model.learn(total_timesteps=steps, reset_num_timesteps=False)
    return time.perf_counter() - t0


def sac_steps_per_s(
    env_id: str,
    residual: str,
    features: bool,
    steps: int,
    warmup: int,
    seed: int,
    tank: bool = False,
) -> float:
    """Env steps per second of ``SAC.learn`` after ``warmup`` steps (one gradient step
    per env step)."""
    env, kwargs = make(env_id, residual, features, tank)
    kwargs = {**kwargs, "learning_starts": warmup, "buffer_size": warmup + steps + 10}
    model = SAC(env=env, seed=seed, device="cpu", **kwargs)
    elapsed = timed_learn(model, warmup + 50, steps)
    env.close()
    return steps / elapsed


def env_steps_per_s(
    env_id: str, residual: str, features: bool, steps: int, seed: int, tank: bool = False
) -> float:
    """Env steps per second under uniform random actions (resets included)."""
    env, _ = make(env_id, residual, features, tank)
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    n = env.action_space.shape[0]
    actions = rng.uniform(-1.0, 1.0, size=(steps, n)).astype(np.float32)
    t0 = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            env.reset()
    elapsed = time.perf_counter() - t0
    env.close()
    return steps / elapsed


def learner_steps_per_s(label: str, env_id: str, steps: int, warmup: int, seed: int) -> float:
    """Env steps per second of one learner configuration (see the module docstring)."""
    res = validate(TrainConfig(out="/nonexistent", env_id=env_id, reward="kernel"))
    kw = {"control_hz": res.control_hz, "max_episode_steps": res.max_episode_steps,
          "reward": "kernel"}  # fmt: skip
    off_policy = {"learning_starts": warmup, "buffer_size": warmup + steps + 10}
    if label.startswith("SB3 PPO"):
        from stable_baselines3 import PPO
        from stable_baselines3.common.env_util import make_vec_env

        venv = make_vec_env(env_id, n_envs=8, seed=seed, env_kwargs=kw)
        model = PPO("MlpPolicy", venv, n_steps=256, batch_size=256, seed=seed, device="cpu")
        elapsed = timed_learn(model, 8 * 256, steps)  # one rollout + update untimed
        venv.close()
        return (model.num_timesteps - 8 * 256) / elapsed
    env = gym.make(env_id, **kw)
    net = [256, 256] if "256" in label else [64, 64]
    if label.startswith("sbx"):
        from train.evaluation.policies import (
            algo_class,  # ptrack train --backend sbx (one XLA thread)
        )

        model = algo_class("sac", "sbx")(
            "MlpPolicy", env, policy_kwargs={"net_arch": net}, seed=seed, **off_policy
        )
    elif label.startswith("sb3-contrib TQC"):
        from sb3_contrib import TQC

        model = TQC("MlpPolicy", env, policy_kwargs={"net_arch": net}, seed=seed,
                    device="cpu", **off_policy)  # fmt: skip
    else:
        model = SAC("MlpPolicy", env, policy_kwargs={"net_arch": net}, seed=seed,
                    device="cpu", **off_policy)  # fmt: skip
    elapsed = timed_learn(model, warmup + 50, steps)
    env.close()
    return steps / elapsed


#: The learners of ``--learners``, each with the package it needs.
LEARNERS: dict[str, str] = {
    "SB3 SAC [256, 256]": "stable_baselines3",
    "SB3 SAC [64, 64]": "stable_baselines3",
    "sb3-contrib TQC [64, 64]": "sb3_contrib",
    "SB3 PPO, 8 envs, DummyVecEnv": "stable_baselines3",
    "sbx SAC [64, 64]": "sbx",
}


def learners_table(env_id: str, steps: int, warmup: int, repeats: int) -> None:
    """Print the learners' steps/s (medians of ``repeats`` alternating rounds)."""
    import importlib.util

    rates: dict[str, list[float]] = {  # the learners whose package is installed
        label: [] for label, pkg in LEARNERS.items() if importlib.util.find_spec(pkg)
    }
    for r in range(repeats):
        order = list(rates) if r % 2 == 0 else list(reversed(rates))
        for label in order:
            ppo = label.startswith("SB3 PPO")
            rates[label].append(learner_steps_per_s(label, env_id, steps * (8 if ppo else 1),
                                                    warmup, r))  # fmt: skip
            print(f"# round {r}: {label}: {rates[label][-1]:.0f} steps/s", flush=True)
    print(f"\n{env_id}, kernel reward, 1 torch thread, medians of {repeats} rounds:\n")
    print("| learner | steps/s |\n| --- | ---: |")
    for label in LEARNERS:
        value = f"{statistics.median(rates[label]):.0f}" if label in rates else "not installed"
        print(f"| {label} | {value} |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="ptrack_gym/TwoLinkTrack-v0")
    parser.add_argument("--base", choices=CONTROLLER_NAMES, default="passivity")
    parser.add_argument("--steps", type=int, default=1000, help="timed SAC steps")
    parser.add_argument("--warmup", type=int, default=300, help="untimed steps first")
    parser.add_argument("--env-steps", type=int, default=5000, help="random-action steps")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--learners", action="store_true", help="the learners' table instead")
    parser.add_argument("--env-only", action="store_true", help="no SAC: the envs' rates only")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    if args.learners:
        learners_table(args.env, args.steps, args.warmup, args.repeats)
        return 0

    variants = {
        "pure": ("none", False, False),
        f"residual ({args.base}), no features": (args.base, False, False),
        f"residual ({args.base})": (args.base, True, False),
    }
    if args.base in ("passivity", "passivity_paper"):  # the tank's bases
        variants[f"residual ({args.base}), energy tank"] = (args.base, True, True)
    sac: dict[str, list[float]] = {k: [] for k in variants}
    raw: dict[str, list[float]] = {k: [] for k in variants}
    for r in range(args.repeats):
        order = list(variants) if r % 2 == 0 else list(reversed(variants))
        for label in order:
            residual, features, tank = variants[label]
            raw[label].append(
                env_steps_per_s(args.env, residual, features, args.env_steps, r, tank)
            )
            sac[label].append(
                math.nan
                if args.env_only
                else sac_steps_per_s(args.env, residual, features, args.steps, args.warmup, r, tank)
            )
            print(
                f"# round {r}: {label}: env {raw[label][-1]:.0f} steps/s, "
                f"SAC {sac[label][-1]:.1f} steps/s",
                flush=True,
            )
    med_sac = {k: statistics.median(v) for k, v in sac.items()}
    med_env = {k: statistics.median(v) for k, v in raw.items()}
    pure_sac, pure_env = med_sac["pure"], med_env["pure"]
    print(f"\n{args.env}, medians of {args.repeats} rounds:\n")
    if args.env_only:
        print("| variant | env only, random actions (steps/s) | extra env cost (µs/step) |")
        print("|---|---:|---:|")
        for label in variants:
            extra_us = (1.0 / med_env[label] - 1.0 / pure_env) * 1e6
            print(f"| {label} | {med_env[label]:.0f} | {extra_us:.0f} |")
        return 0
    print(
        "| variant | env only, random actions (steps/s) | SAC training (steps/s) "
        "| SAC vs pure | extra env cost (µs/step) | extra env cost / pure SAC step |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    for label in variants:
        extra_us = (1.0 / med_env[label] - 1.0 / pure_env) * 1e6
        print(
            f"| {label} | {med_env[label]:.0f} | {med_sac[label]:.1f} "
            f"| {med_sac[label] / pure_sac:.3f} | {extra_us:.0f} "
            f"| {extra_us * 1e-6 * pure_sac:.1%} |"
        )
    print("\ntarget: the base controller costs <= 10 % (SAC vs pure >= 0.9)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
