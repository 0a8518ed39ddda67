"""How often an impulse throws the tuned passivity law off its path at a slower control rate,
with the pump lowered with the springs (the current rate cap) and with the pump as it was
before (loop 6 of docs/control_rates.md): k at its 1-kHz strength, only its own limit
k dt ≤ 0.8. Side by side in one run, the same episodes: random admissible paths, impulses at
level 1 (``--disturbance``: another preset, or none), reset seeds 1 … ``--seeds``, started
on the path.

    python bench/impulse_throws.py --hz 250 --paths 1 2 3 4 5 6 7 8 9 10 --seeds 10

Prints per variant the episodes past 0.1 and 0.5 rad of path distance, the worst, the median
of the per-episode RMS, and each thrown (path, reset seed).
"""

from __future__ import annotations

import argparse
import dataclasses

import gymnasium as gym
import numpy as np

import ptrack_gym  # noqa: F401  (registers the envs)
from agents.passivity import PUMP_LIMIT, RATE_MARGIN, PassivityGains
from agents.policy import ControllerPolicy
from agents.registry import make_controller
from ptrack_gym.robots import robot_profile
from train.evaluation.episode import rollout


def _env(robot: str, hz: float, path_seed: int, episode_s: float, disturbance: str) -> gym.Env:
    return gym.make(
        robot_profile(robot).env_id, control_hz=hz, path="random", path_seed=path_seed,
        disturbance=None if disturbance == "none" else (disturbance, 1.0),
        max_episode_steps=round(episode_s * hz),
    )  # fmt: skip


def earlier_gains(robot: str, hz: float, path_seed: int, gains: str) -> PassivityGains:
    """The gains as the rate cap built them before loop 6: the pump at the 1-kHz gains'
    strength (where the springs are not capped), then only its own limit."""
    env = gym.make(robot_profile(robot).env_id, control_hz=hz, path="random", path_seed=path_seed)
    fast = gym.make(
        robot_profile(robot).env_id, control_hz=1000.0, path="random", path_seed=path_seed
    )
    try:
        now = make_controller("passivity", env, gains).gains
        k_fast = make_controller("passivity", fast, gains).gains.k_pump
        return dataclasses.replace(now, k_pump=min(k_fast, RATE_MARGIN * PUMP_LIMIT * hz))
    finally:
        env.close()
        fast.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="two_link")
    ap.add_argument("--hz", type=float, default=250.0)
    ap.add_argument("--gains", default="tuned")
    ap.add_argument("--paths", type=int, nargs="+", default=list(range(1, 11)))
    ap.add_argument("--seeds", type=int, default=10, help="reset seeds 1 … N per path")
    ap.add_argument("--episode-s", type=float, default=5.0)
    ap.add_argument("--disturbance", default="impulse", help="a preset at level 1, or none")
    args = ap.parse_args()
    rows: dict[str, list[tuple[int, int, float, float]]] = {"current": [], "earlier pump": []}
    for path_seed in args.paths:
        variants = {"current": args.gains, "earlier pump": earlier_gains(
            args.robot, args.hz, path_seed, args.gains)}  # fmt: skip
        for name, gains in variants.items():
            env = _env(args.robot, args.hz, path_seed, args.episode_s, args.disturbance)
            try:
                policy = ControllerPolicy(env, make_controller("passivity", env, gains))
                for seed in range(1, args.seeds + 1):
                    record, _ = rollout(env, policy, seed)
                    d = np.asarray(record.path_distance)
                    rows[name].append(
                        (path_seed, seed, float(d.max()), float(np.sqrt(np.mean(d**2))))
                    )
            finally:
                env.close()
    print(f"{args.robot}, {args.gains} gains, {args.hz:g} Hz, {args.disturbance} (level 1), "
          f"{len(args.paths)} paths x reset seeds 1-{args.seeds}")  # fmt: skip
    for name, r in rows.items():
        a = np.array([x[2:] for x in r])
        thrown = [(p, s, round(m, 3)) for p, s, m, _ in r if m > 0.1]
        print(
            f"{name:>13}: {len(r)} episodes, past 0.1 rad {int((a[:, 0] > 0.1).sum())}, "
            f"past 0.5 rad {int((a[:, 0] > 0.5).sum())}, worst {a[:, 0].max():.3g} rad, "
            f"median RMS {np.median(a[:, 1]):.3g} rad; thrown {thrown}"
        )


if __name__ == "__main__":
    main()
