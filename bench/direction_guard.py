"""What the passivity law's direction guard changes (``agents.passivity.DIRECTION_GUARD``,
the class docstring of :class:`~agents.passivity.PassivityController`): the same episodes
with the guard off (c = 0) and on (the package's c), side by side.

    python bench/direction_guard.py                      # all three parts (~25 min, 1 core)
    python bench/direction_guard.py --part stall --robots two_link --hz 250

Parts:

* ``identity`` — every robot, default and tuned gains, the default path and random paths
  1-10, 1 kHz, 500 Hz and 250 Hz, 5 s undisturbed: whether the guarded episode is the
  unguarded one bit for bit (the joint trajectory), else both path-distance RMS.
* ``stall`` — a constant torque 0.1 τ_max ⊙ (1, −1, 1, …) held on the arm (a residual
  wrapper's constant action, no tank), tuned gains, random paths 1-5: the energy the
  sampled law created at its port (the most it owed at any step, as
  :class:`agents.energy_tank.EnergyTank` keeps it: created energy less what it dissipated
  since, from :class:`agents.energy_tank.PortDissipation`) and the path-distance RMS,
  off and on.
* ``disturbed`` — tuned gains, random paths 1-5, 2 seeds, the disturbance families at
  level 1: the path-distance RMS off and on (their ratio) and the energy created.

One line per episode pair, then per part and robot: pairs, pairs not bit-identical, the
median and largest on/off ratio of the path-distance RMS, the energy created off and on.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

import gymnasium as gym
import numpy as np

import ptrack_gym  # noqa: F401  (registers the envs)
from agents import passivity
from agents.energy_tank import PortDissipation
from agents.residual_wrapper import ResidualWrapper
from ptrack_gym.robots import ROBOTS, robot_profile

#: The guard's c as the package sets it.
GUARD = passivity.DIRECTION_GUARD
FAMILIES = ("impulse", "periodic", "noise", "payload", "push", "mismatch", "delay", "friction")


def episode(
    robot: str, hz: float, path_seed: int | None, gains: str, guard: float,
    constant: float = 0.0, disturbance: str | None = None, seed: int = 0, episode_s: float = 5.0,
) -> dict:  # fmt: skip
    """One episode of the passivity law (``gains``: "default" or "tuned") with the guard's c
    = ``guard`` under a constant torque ``constant`` τ_max ⊙ (1, −1, …) and ``disturbance``
    at level 1: the joint trajectory, the path-distance RMS (rad) and the energy the
    sampled law created (J)."""
    passivity.DIRECTION_GUARD = guard
    try:
        profile = robot_profile(robot)
        steps = round(episode_s * hz)
        kw = (
            {"path": "default"} if path_seed is None else {"path": "random", "path_seed": path_seed}
        )
        env = gym.make(
            profile.env_id, control_hz=hz, max_episode_steps=steps,
            disturbance=None if disturbance is None else (disturbance, 1.0), **kw,
        )  # fmt: skip
        w = ResidualWrapper(
            env, "passivity", scale_fraction=max(constant, 1e-9),
            base_gains=gains,
        )  # fmt: skip
    finally:
        passivity.DIRECTION_GUARD = GUARD
    action = np.where(np.arange(w.n) % 2 == 0, 1.0, -1.0).astype(np.float32)
    if not constant:
        action = np.zeros(w.n, dtype=np.float32)
    u, port = w.tracking_env, PortDissipation()
    w.reset(seed=seed)
    qs, dist, created, debt = [], [], 0.0, 0.0
    try:
        for _ in range(steps):
            q, qd = u.measured_joint_state()
            _, _, terminated, truncated, info = w.step(action)
            if info.get("controller_diverged"):
                created = np.inf
                break
            arm = 0.5 * float(qd @ u.model.mass_matrix(q) @ qd) + float(u.model.potential(q))
            d = port.record(info["controller"], arm, q, info["tau_base_nm"], u.dt)
            debt = max(debt - d, 0.0) if np.isfinite(d) else np.inf  # owed, as the tank's
            created = max(created, debt)
            true_q = u.joint_state()[0]
            qs.append(true_q)
            dist.append(u.projector.nearest(true_q).distance)
            if terminated or truncated:
                break
    finally:
        w.close()
    return {"q": np.array(qs), "rms": float(np.sqrt(np.mean(np.square(dist)))), "created": created}


def pair(**kw) -> dict:
    """The episode with the guard off and on, and how they differ (printed)."""
    off, on = episode(guard=0.0, **kw), episode(guard=GUARD, **kw)
    same = off["q"].shape == on["q"].shape and np.array_equal(off["q"], on["q"])
    row = {
        **kw, "same": same, "rms_off": off["rms"], "rms_on": on["rms"],
        "created_off": off["created"], "created_on": on["created"],
    }  # fmt: skip
    print(
        *[f"{k}={v}" for k, v in kw.items()], f"same={same}",
        f"rms {off['rms']:.3g} -> {on['rms']:.3g}",
        f"created {off['created']:.3g} -> {on['created']:.3g} J", flush=True,
    )  # fmt: skip
    return row


def summary(part: str, rows: list[dict]) -> None:
    print(
        f"\n{part}: robot  pairs  changed  rms on/off median  largest",
        " created off  created on (J, sums)",
    )
    for robot in sorted({r["robot"] for r in rows}):
        mine = [r for r in rows if r["robot"] == robot]
        ratio = np.array([r["rms_on"] / r["rms_off"] for r in mine])
        print(
            f"{part}: {robot} {len(mine)} {sum(not r['same'] for r in mine)}",
            f"{np.median(ratio):.3f} {ratio.max():.3f}",
            f"{sum(r['created_off'] for r in mine):.3g} {sum(r['created_on'] for r in mine):.3g}",
        )  # fmt: skip


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--part", nargs="+", default=["identity", "stall", "disturbed"],
                        choices=["identity", "stall", "disturbed"])  # fmt: skip
    parser.add_argument("--robots", nargs="+", default=list(ROBOTS), choices=list(ROBOTS))
    parser.add_argument(
        "--hz", nargs="+", type=float, default=None,
        help="rates (default: 1000 500 250 for identity, 250 1000 for stall, 250 disturbed)",
    )  # fmt: skip
    parser.add_argument("--paths", nargs="+", type=int, default=None)
    args = parser.parse_args(argv)
    if "identity" in args.part:
        rows = []
        for robot in args.robots:
            for hz in args.hz or (1000.0, 500.0, 250.0):
                for seed in (None, *(args.paths or range(1, 11))):
                    for gains in ("default", "tuned"):
                        rows.append(pair(robot=robot, hz=hz, path_seed=seed, gains=gains))
        summary("identity", rows)
    if "stall" in args.part:
        rows = []
        for robot in args.robots:
            for hz in args.hz or (250.0, 1000.0):
                for seed in args.paths or range(1, 6):
                    rows.append(pair(robot=robot, hz=hz, path_seed=seed, gains="tuned",
                                     constant=0.1))  # fmt: skip
        summary("stall", rows)
    if "disturbed" in args.part:
        rows = []
        for robot in args.robots:
            for hz in args.hz or (250.0,):
                for family in FAMILIES:
                    for seed in args.paths or range(1, 6):
                        for reset in (0, 1):
                            rows.append(pair(robot=robot, hz=hz, path_seed=seed, gains="tuned",
                                             disturbance=family, seed=reset))  # fmt: skip
        summary("disturbed", rows)


if __name__ == "__main__":
    main()
