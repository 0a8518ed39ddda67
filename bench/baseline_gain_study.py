"""Gain study of the classical baselines: computed torque, PD + gravity, Slotine–Li.

For each robot, controller and closed-loop bandwidth ω (each controller's module docstring says
how ω sets its gains), the env (defaults: physics and control at 1 kHz, the
robot's default path, exact nominal model, no disturbance) is run from rest, 0.1 rad off
the path on every joint (signs alternating), from each of a few start phases s₀, and
scored on the time-indexed error |q_r(s₀ + t) − q| (rad):

* ``settle_s``: the first time after which the error stays below ``--threshold-rad``
  (1e-3) to the end of the run (``inf`` if it never does);
* ``final_err_rad``: the largest error over the last ``--final-window-s`` (1 s);
* ``final_path_rad``: the largest path distance min_s |q − q_r(s)| over that window;
* ``peak_tau_ratio``: max over steps and joints of |τ_cmd| / τ_max (> 1: clipped);
* ``sat_frac``: the fraction of steps with at least one joint clipped.

Each row is the worst case over the start phases. The table is written as CSV and as
markdown to ``--out-dir`` and printed. Run from the repository root (the command behind
docs/baselines.md)::

    python -m bench.baseline_gain_study --out-dir /tmp/ptrack_baseline_study
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import NamedTuple

import gymnasium as gym
import numpy as np

import ptrack_gym  # noqa: F401  (registers the envs)
from agents.base import Controller
from agents.computed_torque import ComputedTorqueController, ComputedTorqueGains
from agents.pd_gravity import PDGravityController, PDGravityGains
from agents.policy import ControllerPolicy
from agents.slotine_li import SlotineLiController, SlotineLiGains
from ptrack_gym.robots import ROBOTS, home_inertia_kgm2

ENV_ID = {name: profile.env_id for name, profile in ROBOTS.items()}
CONTROLLERS = ("computed_torque", "pd_gravity", "slotine_li")


@dataclass(frozen=True)
class StudyConfig:
    """What the study runs."""

    robots: tuple[str, ...] = tuple(ROBOTS)
    """Robots to study (keys of ``ENV_ID``)."""
    controllers: tuple[str, ...] = CONTROLLERS
    """Controllers to study."""
    omegas_rad_s: tuple[float, ...] = (5.0, 7.0, 10.0, 14.0, 20.0, 28.0, 40.0)
    """Closed-loop bandwidths ω (rad/s) swept for every controller."""
    duration_s: float = 4.0
    """Simulated time per run (s)."""
    offset_rad: float = 0.1
    """Start offset from q_r(s₀) on every joint (rad), signs alternating, at rest."""
    start_phases: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75)
    """Start phases s₀ as fractions of the path period; the worst run is reported."""
    threshold_rad: float = 1e-3
    """Settling threshold on the time-indexed error (rad)."""
    final_window_s: float = 1.0
    """The final errors are the largest over the last ``final_window_s`` seconds."""
    out_dir: str = "bench/results"
    """Folder for ``baseline_gain_study.csv`` and ``.md``."""


class RunResult(NamedTuple):
    """Scores of one run (see the module docstring)."""

    settle_s: float
    final_err_rad: float
    final_path_rad: float
    peak_tau_ratio: float
    sat_frac: float
    unstable: bool


def make_controller(name: str, env: gym.Env, omega_rad_s: float) -> Controller:
    """The controller ``name`` with bandwidth ω, on the env's nominal model and path.

    Inertia-scaled gains use diag M(q_home) of the env's own model.
    """
    u = env.unwrapped
    inertia = home_inertia_kgm2(u.model, u.robot_profile)
    if name == "computed_torque":
        return ComputedTorqueController(
            u.model, u.path, ComputedTorqueGains.from_bandwidth(omega_rad_s)
        )
    if name == "pd_gravity":
        return PDGravityController(
            u.model, u.path, PDGravityGains.from_inertia(inertia, omega_rad_s)
        )
    if name == "slotine_li":
        return SlotineLiController(
            u.model, u.path, SlotineLiGains.from_inertia(inertia, omega_rad_s)
        )
    raise ValueError(f"unknown controller {name!r}; known: {CONTROLLERS}")


def run_once(
    env: gym.Env, controller: Controller, s0: float, sign: float, cfg: StudyConfig
) -> RunResult:
    """One run from rest at q_r(s₀) ± offset, driven through :class:`ControllerPolicy`."""
    u = env.unwrapped
    q_r, _, _ = u.path.evaluate(s0)
    pattern = sign * np.where(np.arange(u.n) % 2 == 0, 1.0, -1.0)
    obs, _ = env.reset(options={"s0": s0, "q": q_r + cfg.offset_rad * pattern, "qd": np.zeros(u.n)})
    policy = ControllerPolicy(env, controller)
    policy.reset_controller(obs)
    steps = round(cfg.duration_s / u.dt)
    errors = np.full(steps, np.inf)
    path_dist = np.full(steps, np.inf)
    peak, saturated, unstable = 0.0, 0, False
    for k in range(steps):
        action = policy.action(obs)
        ratio = np.abs(policy.last_tau_nm) / policy.torque_limits_nm
        peak = max(peak, float(np.max(ratio)))
        saturated += int(np.any(ratio > 1.0))
        obs, _, terminated, _, info = env.step(action)
        errors[k], path_dist[k] = info["tracking_error"], info["path_distance"]
        if terminated:
            unstable = True
            break
    above = np.flatnonzero(~(errors < cfg.threshold_rad))
    if unstable or (len(above) and above[-1] == steps - 1):
        settle = np.inf
    else:
        settle = 0.0 if not len(above) else float((above[-1] + 1) * u.dt)
    last = slice(steps - round(cfg.final_window_s / u.dt), steps)
    return RunResult(
        settle_s=settle,
        final_err_rad=float(np.max(errors[last])),
        final_path_rad=float(np.max(path_dist[last])),
        peak_tau_ratio=peak,
        sat_frac=saturated / steps,
        unstable=unstable,
    )


def worst(results: list[RunResult]) -> RunResult:
    """The worst case of each score over runs."""
    return RunResult(
        settle_s=max(r.settle_s for r in results),
        final_err_rad=max(r.final_err_rad for r in results),
        final_path_rad=max(r.final_path_rad for r in results),
        peak_tau_ratio=max(r.peak_tau_ratio for r in results),
        sat_frac=max(r.sat_frac for r in results),
        unstable=any(r.unstable for r in results),
    )


def study(cfg: StudyConfig, log: Callable[[str], None] = print) -> list[dict[str, object]]:
    """Run the sweep; one row per (robot, controller, ω), worst case over start phases."""
    rows: list[dict[str, object]] = []
    for robot in cfg.robots:
        env = gym.make(ENV_ID[robot])
        try:
            u = env.unwrapped
            inertia = home_inertia_kgm2(u.model, u.robot_profile)
            log(f"{robot}: diag M(q_home) = {np.array2string(inertia, precision=6)} kg·m²")
            for name in cfg.controllers:
                for omega in cfg.omegas_rad_s:
                    t0 = time.perf_counter()
                    results = [
                        run_once(
                            env,
                            make_controller(name, env, omega),
                            frac * u.path.period_s,
                            1.0 if i % 2 == 0 else -1.0,
                            cfg,
                        )
                        for i, frac in enumerate(cfg.start_phases)
                    ]
                    w = worst(results)
                    rows.append(
                        {"robot": robot, "controller": name, "omega_rad_s": omega} | w._asdict()
                    )
                    log(f"  {name:16s} ω={omega:5.1f}: {w}  ({time.perf_counter() - t0:.1f} s)")
        finally:
            env.close()
    return rows


def markdown(rows: list[dict[str, object]]) -> str:
    """The rows as a markdown table."""
    head = (
        "| robot | controller | ω (rad/s) | settle (s) | final err (rad) | final path dist (rad)"
        " | peak τ/τ_max | saturated steps | unstable |\n"
        "|---|---|---|---|---|---|---|---|---|\n"
    )
    lines = [
        f"| {r['robot']} | {r['controller']} | {r['omega_rad_s']:g} | {r['settle_s']:.3f} "
        f"| {r['final_err_rad']:.2e} | {r['final_path_rad']:.2e} | {r['peak_tau_ratio']:.2f} "
        f"| {100 * float(r['sat_frac']):.1f}% | {'yes' if r['unstable'] else 'no'} |"
        for r in rows
    ]
    return head + "\n".join(lines) + "\n"


def parse_args(argv: list[str] | None = None) -> StudyConfig:
    """A :class:`StudyConfig` from the command line (one option per field)."""
    default = StudyConfig()
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", nargs="+", choices=sorted(ENV_ID), default=default.robots)
    parser.add_argument(
        "--controllers", nargs="+", choices=CONTROLLERS, default=default.controllers
    )
    parser.add_argument("--omegas-rad-s", nargs="+", type=float, default=default.omegas_rad_s)
    parser.add_argument("--duration-s", type=float, default=default.duration_s)
    parser.add_argument("--offset-rad", type=float, default=default.offset_rad)
    parser.add_argument("--start-phases", nargs="+", type=float, default=default.start_phases)
    parser.add_argument("--threshold-rad", type=float, default=default.threshold_rad)
    parser.add_argument("--final-window-s", type=float, default=default.final_window_s)
    parser.add_argument("--out-dir", default=default.out_dir)
    args = vars(parser.parse_args(argv))
    values = {f.name: args[f.name] for f in fields(StudyConfig)}
    for key, value in values.items():
        if isinstance(value, list):
            values[key] = tuple(value)
    cfg = StudyConfig(**values)
    if not 0.0 < cfg.final_window_s <= cfg.duration_s:
        parser.error("--final-window-s must be positive and at most --duration-s")
    return cfg


def main(argv: list[str] | None = None) -> None:
    cfg = parse_args(argv)
    rows = study(cfg)
    out = Path(cfg.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "baseline_gain_study.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    table = markdown(rows)
    (out / "baseline_gain_study.md").write_text(
        f"Command: `python -m bench.baseline_gain_study {' '.join(sys.argv[1:])}`\n\n{table}"
    )
    print(table)


if __name__ == "__main__":
    main()
