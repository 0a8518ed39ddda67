"""Cost of one passivity-controller step next to the bare env step, measured in one run.

For each robot: µs per ``env.step`` with a zero action (unwrapped env, default 1 kHz),
µs per ``PassivityController.step`` on the states of that rollout, and their ratio.
Issue target: the controller adds at most 1× the bare env step's cost on the iiwa.

Run: ``python bench/controller_cost.py [--steps 3000] [--repeats 5]``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import gymnasium as gym
import numpy as np

import ptrack_gym  # noqa: F401  (registers the envs)
from agents.passivity import PassivityController, PassivityGains

ROBOTS = {"two_link": "TwoLink", "iiwa": "Iiwa", "panda": "Panda"}


def measure(robot: str, steps: int, repeats: int) -> tuple[float, float]:
    """Median µs per bare env step and per controller step for ``robot``."""
    env = gym.make(f"ptrack_gym/{ROBOTS[robot]}Track-v0").unwrapped
    ctrl = PassivityController(env.model, env.tables, PassivityGains())
    zero = np.zeros(env.n)
    env.reset(seed=0)
    states = []
    for _ in range(steps):
        env.step(zero)
        states.append(env.joint_state())
    env_us, ctrl_us = [], []
    for _ in range(repeats):
        env.reset(seed=0)
        t0 = time.perf_counter()
        for _ in range(steps):
            env.step(zero)
        env_us.append((time.perf_counter() - t0) / steps * 1e6)
        q, qd = states[0]
        ctrl.reset(q, qd, env.s0)
        t0 = time.perf_counter()
        for q, qd in states:
            ctrl.step(q, qd, env.dt)
        ctrl_us.append((time.perf_counter() - t0) / steps * 1e6)
    env.close()
    return statistics.median(env_us), statistics.median(ctrl_us)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--robots", nargs="+", default=list(ROBOTS), choices=list(ROBOTS))
    args = parser.parse_args()
    print("| robot | bare env step (µs) | passivity step (µs) | controller / env |")
    print("|---|---:|---:|---:|")
    for robot in args.robots:
        env_us, ctrl_us = measure(robot, args.steps, args.repeats)
        print(f"| {robot} | {env_us:.1f} | {ctrl_us:.1f} | {ctrl_us / env_us:.2f} |")


if __name__ == "__main__":
    main()
