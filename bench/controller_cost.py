"""Cost of a controlled env step against the raw PyBullet floor, per robot and controller.

For each robot (1 kHz physics and control, the default path, started on it) it times, in
one run with the timings alternating (round robin, median of ``--repeats``):

* **floor** — the raw PyBullet work of a step (``bench/env_step.py``'s definition: torque
  command, ``stepSimulation``, ``getJointStates``, ``calculateMassMatrix``);
* **env** — ``gym.make`` env, zero action;
* **<controller>** — a closed-loop step as a user writes it: ``ControllerPolicy.predict``
  (the controller's step on the measured state, torque → action) and ``env.step`` on the
  ``gym.make`` env.

Printed: µs per step and the ratio to the floor (issue target: a passivity-controlled step
on the iiwa ≤ 2.5 floors).

Run: ``python bench/controller_cost.py [--steps 3000] [--repeats 5] [--robots iiwa]``.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import gymnasium as gym
from env_step import PHYSICS_HZ, env_runner, floor_runner, median_rates

import ptrack_gym  # noqa: F401  (registers the envs)
from agents.policy import ControllerPolicy
from agents.registry import CONTROLLER_NAMES, make_controller
from ptrack_gym.robots import ROBOTS
from ptrack_gym.sim import BulletSim


def controlled_runner(env: gym.Env, name: str) -> Callable[[int], None]:
    """``k`` closed-loop steps of controller ``name`` on ``env`` (reset when it ends)."""
    policy = ControllerPolicy(env, make_controller(name, env))
    obs, _ = env.reset(seed=0)
    state = {"obs": obs}

    def run(k: int) -> None:
        obs = state["obs"]
        for _ in range(k):
            action, _ = policy.predict(obs)
            obs, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                obs, _ = env.reset()
        state["obs"] = obs

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--warmup", type=int, default=300)
    parser.add_argument("--robots", nargs="+", default=list(ROBOTS), choices=list(ROBOTS))
    parser.add_argument(
        "--controllers", nargs="+", default=list(CONTROLLER_NAMES), choices=CONTROLLER_NAMES
    )
    args = parser.parse_args()
    names = list(args.controllers)
    head = " | ".join(f"{c} (µs, ×floor)" for c in names)
    print(f"| robot | floor (µs) | env, zero action (µs, ×floor) | {head} |")
    print("|---|---:|---:|" + "---:|" * len(names))
    for robot in args.robots:
        profile = ROBOTS[robot]
        sim = BulletSim(timestep_s=1.0 / PHYSICS_HZ)
        envs = [gym.make(profile.env_id, max_episode_steps=10**9) for _ in range(len(names) + 1)]
        try:
            runs = [floor_runner(sim, robot, 1), env_runner(envs[0])]
            runs += [controlled_runner(env, c) for env, c in zip(envs[1:], names, strict=True)]
            rates = median_rates(runs, args.steps, args.repeats, args.warmup)
        finally:
            sim.close()
            for env in envs:
                env.close()
        us = [1e6 / r for r in rates]
        cells = " | ".join(f"{u:.1f} ({u / us[0]:.2f})" for u in us[1:])
        print(f"| {robot} | {us[0]:.1f} | {cells} |")


if __name__ == "__main__":
    main()
