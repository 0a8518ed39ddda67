"""How much of its authority a trained policy uses: its deterministic actions over one
undisturbed episode of the env it was trained in (the run's own residual base, authority,
gate, control rate and decision period; its steps are its decisions).

A residual meant to correct its base should act small; one that sits at its bounds is
feedback of its own. For each joint j, over the episode's steps t (actions in [-1, 1],
the residual's scale applied by the wrapper afterwards)::

    mean |a|             = mean_{t,j} |a_tj|
    saturated fraction   = mean_{t,j} [|a_tj| > threshold]
    mean a_j, std a_j    = mean_t a_tj, std_t a_tj

Usage::

    ptrack probe-actions runs/rl_study_iiwa_accel1/residual-computed_torque-a1_s0 \\
        runs/rl_study_iiwa_accel1/residual-passivity-a1_s0 --seed 123
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ptrack_gym.errors import InvalidActionError
from train.evaluation.envs import build_decision_env, trained_wrapper_kwargs
from train.evaluation.policies import deploy_safeguards, load_sb3_policy, run_config


@dataclass(frozen=True)
class ActionUsage:
    """The actions of one deterministic episode (see the module docstring)."""

    steps: int
    mean_abs: float
    saturated_fraction: float
    mean_per_joint: np.ndarray
    std_per_joint: np.ndarray

    @classmethod
    def of(cls, actions: np.ndarray, threshold: float = 0.9) -> ActionUsage:
        """Statistics of ``actions`` (steps × joints, in [-1, 1])."""
        a = np.asarray(actions, dtype=float)
        if a.ndim != 2 or a.shape[0] == 0:
            raise InvalidActionError(
                f"actions must be a non-empty (steps, joints) array, got {a.shape}"
            )
        return cls(
            steps=a.shape[0],
            mean_abs=float(np.abs(a).mean()),
            saturated_fraction=float((np.abs(a) > threshold).mean()),
            mean_per_joint=a.mean(axis=0),
            std_per_joint=a.std(axis=0),
        )


def action_usage(run_dir: Path, seed: int, threshold: float = 0.9) -> ActionUsage:
    """Run the trained policy of ``run_dir`` deterministically for one undisturbed episode
    (reset with ``seed``) in the env it was trained in, and summarise its actions."""
    cfg = run_config(run_dir)
    config, derived = cfg["config"], cfg["derived"]
    policy, _ = load_sb3_policy(f"sb3:{run_dir}", config["env_id"])
    residual = config["residual"]
    env = build_decision_env(  # as it trained and is evaluated: its base, gate, decisions
        int(config.get("decision_every", 1)),
        config["env_id"],
        residual,
        config["scale_fraction"],
        derived["control_hz"],
        derived["max_episode_steps"],
        config["start"],
        None,
        residual_kwargs={**trained_wrapper_kwargs(cfg), **deploy_safeguards(run_dir)}
        if residual != "none"
        else None,
    )
    try:
        obs, _ = env.reset(seed=seed)
        actions = []
        done = False
        while not done:
            action, _ = policy.predict(obs)
            actions.append(action)
            obs, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
    finally:
        env.close()
    return ActionUsage.of(np.array(actions), threshold)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="ptrack probe-actions", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("runs", nargs="+", type=Path, help="run folders (train.rl.run --out)")
    parser.add_argument("--seed", type=int, default=123, help="the episode's reset seed")
    parser.add_argument("--threshold", type=float, default=0.9, help="|a| counted as saturated")
    args = parser.parse_args(argv)
    for run in args.runs:
        u = action_usage(run, args.seed, args.threshold)
        print(
            f"{run}: {u.steps} steps, mean |a| {u.mean_abs:.3f}, "
            f"|a| > {args.threshold}: {u.saturated_fraction:.3f}; "
            f"mean a per joint {np.round(u.mean_per_joint, 2)}, "
            f"std {np.round(u.std_per_joint, 2)}"
        )


if __name__ == "__main__":
    main()
