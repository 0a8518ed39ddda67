"""Simulated steps per second of ptrack_gym's Panda against panda-gym's ``PandaReach-v3``.

Both run in one process with their timings alternating (round robin, median of
``--repeats``): panda-gym's reach task with a fixed action (its control at 25 Hz: 20
physics steps of 2 ms per env step), and ``ptrack_gym/PandaTrack-v0`` with a zero action at
1 kHz control (1 physics step of 1 ms) and at 100 Hz (10 physics steps). Printed per env:
env steps/s, physics steps/s and simulated seconds per wall-clock second, and each
ptrack_gym figure's ratio to panda-gym's. Needs the ``bench`` extra (``panda-gym``).

Run: ``python bench/panda_gym_compare.py [--steps 1000] [--repeats 5]``.
"""

from __future__ import annotations

import argparse

import gymnasium as gym
from env_step import env_runner, median_rates

import ptrack_gym  # noqa: F401  (registers the envs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--warmup", type=int, default=100)
    args = parser.parse_args()
    try:
        import panda_gym  # noqa: F401  (registers PandaReach-v3)
    except ImportError:
        parser.error("needs panda-gym: pip install 'ptrack_gym[bench]'")
    reach = gym.make("PandaReach-v3")
    sim = reach.unwrapped.sim
    ours = {hz: gym.make("ptrack_gym/PandaTrack-v0", control_hz=hz) for hz in (1000.0, 100.0)}
    try:
        runs = [env_runner(reach, fill=0.1)] + [env_runner(env) for env in ours.values()]
        rates = median_rates(runs, args.steps, args.repeats, args.warmup)
    finally:
        reach.close()
        for env in ours.values():
            env.close()
    rows = [("panda-gym PandaReach-v3", sim.n_substeps, sim.timestep, rates[0])]
    for (hz, env), rate in zip(ours.items(), rates[1:], strict=True):
        u = env.unwrapped
        rows.append((f"ptrack_gym PandaTrack-v0, {hz:g} Hz", u.substeps, u.physics_dt, rate))
    ref_physics, ref_sim = rows[0][1] * rows[0][3], rows[0][1] * rows[0][2] * rows[0][3]
    print(
        "| env | physics steps per env step | physics dt (s) | env steps/s | physics steps/s "
        "| simulated s per s | physics steps/s vs panda-gym | simulated s/s vs panda-gym |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for name, substeps, dt, rate in rows:
        physics, simulated = substeps * rate, substeps * dt * rate
        print(
            f"| {name} | {substeps} | {dt:g} | {rate:,.0f} | {physics:,.0f} | {simulated:.1f} "
            f"| {physics / ref_physics:.2f} | {simulated / ref_sim:.2f} |"
        )


if __name__ == "__main__":
    main()
