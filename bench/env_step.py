"""Steps per second of the tracking env against the raw PyBullet floor, per robot.

For each robot and each control rate (1 kHz = 1 physics sub-step, 100 Hz = 10
sub-steps, physics at 1 kHz) it times, with a zero action:

* **env** — the bare :class:`~ptrack_gym.envs.tracking.TrackingEnv` (no wrappers);
* **gym.make** — the registered env, with ``TimeLimit``, ``OrderEnforcing`` and
  ``PassiveEnvChecker``;
* **floor** — the least any env step must do, written directly against PyBullet on a
  body loaded by :meth:`ptrack_gym.sim.BulletSim.load_arm` (same conventions): per
  sub-step one ``setJointMotorControlArray(TORQUE_CONTROL)`` and one
  ``stepSimulation``, then one ``getJointStates`` and one ``calculateMassMatrix``.

Each figure is the median over ``--repeats`` timings of ``--steps`` steps, after a
warm-up, with ``time.perf_counter``; the three variants' timings alternate, so load
from other processes biases no column. Output is a markdown table::

    python bench/env_step.py --steps 2000 --robots two_link iiwa panda
"""

from __future__ import annotations

import argparse
import importlib.metadata
import os
import platform
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import pybullet as p

import ptrack_gym
from ptrack_gym.envs.tracking import TrackingEnv
from ptrack_gym.robots import ROBOTS, robot_profile
from ptrack_gym.sim import BulletSim

#: Registered id of each robot's env.
ENV_ID = {name: profile.env_id for name, profile in ROBOTS.items()}

PHYSICS_HZ = 1000.0


@dataclass(frozen=True)
class Row:
    """One line of the table: steps/s of each variant for one robot and control rate."""

    robot: str
    control_hz: float
    substeps: int
    env_sps: float
    wrapped_sps: float
    floor_sps: float


def median_rates(
    runs: Sequence[Callable[[int], None]], steps: int, repeats: int, warmup: int
) -> list[float]:
    """Median steps per second of each ``run(steps)`` over ``repeats`` timings.

    Every run is warmed up first; the timings then alternate between the runs (round
    robin), so a load change on a shared machine hits every column alike.
    """
    for run in runs:
        run(warmup)
    rates: list[list[float]] = [[] for _ in runs]
    for _ in range(repeats):
        for run, column in zip(runs, rates, strict=True):
            start = time.perf_counter()
            run(steps)
            column.append(steps / (time.perf_counter() - start))
    return [statistics.median(column) for column in rates]


def env_runner(env: gym.Env[np.ndarray, np.ndarray], fill: float = 0.0) -> Callable[[int], None]:
    """A function stepping ``env`` ``k`` times with one action, every entry ``fill`` (zero by
    default), resetting if an episode ends."""
    action = np.full(env.action_space.shape, fill, dtype=np.float32)
    env.reset(seed=0)

    def run(k: int) -> None:
        for _ in range(k):
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()

    return run


def floor_runner(sim: BulletSim, robot: str, substeps: int) -> Callable[[int], None]:
    """A function doing the raw PyBullet work of ``k`` env steps (see the module docstring)."""
    spec = robot_profile(robot)
    arm = sim.load_arm(spec.urdf_path, spec.joint_names, spec.torque_limits_nm)
    arm.reset_state(np.array(spec.home_q_rad), np.zeros(spec.n))
    cid, body, joints = sim.client_id, arm.body_id, arm.joint_indices
    forces = [0.0] * spec.n
    torque_control = p.TORQUE_CONTROL

    def run(k: int) -> None:
        for _ in range(k):
            for _ in range(substeps):
                p.setJointMotorControlArray(
                    body, joints, torque_control, forces=forces, physicsClientId=cid
                )
                p.stepSimulation(physicsClientId=cid)
            states = p.getJointStates(body, joints, physicsClientId=cid)
            p.calculateMassMatrix(body, [s[0] for s in states], physicsClientId=cid)

    return run


def measure(robot: str, control_hz: float, steps: int, repeats: int, warmup: int) -> Row:
    """Time the three variants for one robot and control rate."""
    substeps = round(PHYSICS_HZ / control_hz)
    env = TrackingEnv(robot=robot, physics_hz=PHYSICS_HZ, control_hz=control_hz)
    wrapped = gym.make(ENV_ID[robot], physics_hz=PHYSICS_HZ, control_hz=control_hz)
    sim = BulletSim(timestep_s=1.0 / PHYSICS_HZ)
    try:
        runs = [env_runner(env), env_runner(wrapped), floor_runner(sim, robot, substeps)]
        env_sps, wrapped_sps, floor_sps = median_rates(runs, steps, repeats, warmup)
    finally:
        env.close()
        wrapped.close()
        sim.close()
    return Row(robot, control_hz, substeps, env_sps, wrapped_sps, floor_sps)


def markdown_table(rows: Sequence[Row]) -> str:
    """The rows as a markdown table (steps per second; ratios to the floor)."""
    lines = [
        "| robot | control Hz | sub-steps | env steps/s | gym.make steps/s "
        "| PyBullet floor steps/s | env/floor | gym.make/floor |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r.robot} | {r.control_hz:g} | {r.substeps} | {r.env_sps:,.0f} "
            f"| {r.wrapped_sps:,.0f} | {r.floor_sps:,.0f} | {r.env_sps / r.floor_sps:.2f} "
            f"| {r.wrapped_sps / r.floor_sps:.2f} |"
        )
    return "\n".join(lines)


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """Command-line arguments."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000, help="env steps per timing")
    parser.add_argument("--robots", nargs="+", choices=sorted(ROBOTS), default=list(ROBOTS))
    parser.add_argument("--repeats", type=int, default=5, help="timings per figure (median)")
    parser.add_argument("--warmup", type=int, default=200, help="untimed steps first")
    args = parser.parse_args(argv)
    if args.steps < 1 or args.repeats < 1 or args.warmup < 0:
        parser.error("--steps and --repeats must be >= 1, --warmup >= 0")
    return args


def main(argv: Sequence[str] | None = None) -> None:
    """Run the benchmark and print the table."""
    args = parse_args(argv)
    rows = [
        measure(robot, control_hz, args.steps, args.repeats, args.warmup)
        for robot in args.robots
        for control_hz in (1000.0, 100.0)
    ]
    print(
        f"ptrack_gym {ptrack_gym.__version__}, pybullet {importlib.metadata.version('pybullet')}, "
        f"Python {platform.python_version()}, {len(os.sched_getaffinity(0))} usable cores; "
        f"physics {PHYSICS_HZ:g} Hz, zero action, median of {args.repeats} x "
        f"{args.steps} steps after {args.warmup} warm-up steps\n"
    )
    print(markdown_table(rows))


if __name__ == "__main__":
    main()
