"""The passivity blow-up, traced: the paper's law and the saturation-aware default under the
same push (issue 17).

Takes a worst case the adversarial search found for ``passivity_paper`` (``worst.yml`` of
``ptrack adversary``; an unstable one if there is one), replays it for
``passivity_paper`` and for ``passivity`` (the default: τ_r⁰ scaled into the actuator box)
with the gains the search used, and records per control step: σ̇, the storage E of the law,
the largest commanded |τ_j|/τ_max,j (the law's output, before the env's clip) and applied
(after it), the scale α of τ_r⁰ (1: the paper's law), and the clip power
q̇ᵀ(τ_applied − τ_commanded) (W) — the work the clip does that the law did not ask for.

Prints the trace at fixed times after the push and the energy flows from the push to the
end (or the blow-up), and writes the figure (``--figure``)::

    python bench/passivity_blowup.py --worst docs/results/adversary_iiwa/worst.yml \
        --energy 2 --figure docs/figures/passivity_blowup.png
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import yaml

import ptrack_gym  # noqa: F401
from agents import ControllerPolicy, make_controller


def trace(env_id: str, controller: str, gains: Any, spec: dict, reset_seed: int,
          control_hz: float, episode_s: float) -> dict[str, np.ndarray]:  # fmt: skip
    """One episode, recorded step by step (see the module docstring)."""
    steps = round(episode_s * control_hz)
    env = gym.make(env_id, disturbance=spec, control_hz=control_hz, horizon_s=episode_s,
                   max_episode_steps=steps)  # fmt: skip
    try:
        ctrl = make_controller(controller, env, gains)
        policy = ControllerPolicy(env, ctrl)
        u = env.unwrapped
        limits = u.torque_limits_nm
        obs, _ = env.reset(seed=reset_seed)
        keys = ("t", "sigma_dot", "energy", "cmd", "applied", "alpha", "clip_w", "speed", "dist")
        rows: dict[str, list[float]] = {k: [] for k in keys}
        for _ in range(steps):
            _, qd = u.measured_joint_state()
            tau_cmd = policy.torque(obs)
            action = np.clip(tau_cmd / limits, -1.0, 1.0).astype(np.float32)
            obs, _, terminated, truncated, info = env.step(action)
            d = ctrl.diagnostics()
            applied = info["tau_nm"]
            rows["t"].append(info["t_s"])
            rows["sigma_dot"].append(d["sigma_dot"])
            rows["energy"].append(d["energy"])
            rows["cmd"].append(float(np.max(np.abs(tau_cmd) / limits)))
            rows["applied"].append(float(np.max(np.abs(applied) / limits)))
            rows["alpha"].append(d.get("r0_scale", 1.0))
            rows["clip_w"].append(float(qd @ (applied - tau_cmd)))
            rows["speed"].append(float(np.max(np.abs(u.joint_state()[1]))))
            rows["dist"].append(info["path_distance"])
            if terminated or truncated:
                break
    finally:
        env.close()
    return {k: np.array(v) for k, v in rows.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--worst", type=Path, required=True, help="worst.yml of train.studies.adversary"
    )
    ap.add_argument("--energy", type=float, default=2.0, help="the energy (J) of the case")
    ap.add_argument("--figure", type=Path, help="write the figure here")
    args = ap.parse_args()
    data = yaml.safe_load(args.worst.read_text())
    config = yaml.safe_load((args.worst.parent / "config.yml").read_text())
    entry = data["worst"]["passivity_paper"]["impulse"][f"{args.energy:g}"]
    spec, onset = entry["spec"], entry["spec"]["onset_s"]
    episode_s = onset + spec["duration_s"] + config["post_s"]
    print(f"{data['env_id']}, reset seed {data['reset_seed']}, impulse {args.energy:g} J at "
          f"{onset:.4f} s (the search's worst for passivity_paper: cost "
          f"{entry['cost_rad']:.3g} rad, unstable={entry['unstable']})")  # fmt: skip
    runs = {
        name: trace(data["env_id"], name, entry.get("gains", "default"), spec,
                    data["reset_seed"], data["control_hz"], episode_s)
        for name in ("passivity_paper", "passivity")
    }  # fmt: skip
    for name, r in runs.items():
        after = r["t"] - onset
        print(f"\n{name}: {len(r['t'])} steps, ended at {r['t'][-1]:.3f} s, peak joint speed "
              f"{r['speed'].max():.1f} rad/s, peak sigma_dot {r['sigma_dot'].max():.2f}, min "
              f"alpha {r['alpha'].min():.2f}, clip work after the push "
              f"{np.sum(r['clip_w'][after >= 0]) / data['control_hz']:+.3f} J")  # fmt: skip
        print(
            "| t − onset (ms) | σ̇ | E (J) | max |τ_cmd|/τ_max | max |τ_applied|/τ_max | α "
            "| clip power (W) | max |q̇| (rad/s) |"
        )
        print("|---:|---:|---:|---:|---:|---:|---:|---:|")
        for ms in (0, 20, 30, 40, 50, 60, 80, 100, 200, 500):
            k = int(np.searchsorted(after, ms / 1000.0))
            if k >= len(after):
                break
            print(f"| {ms} | {r['sigma_dot'][k]:.2f} | {r['energy'][k]:.3g} | {r['cmd'][k]:.3g} "
                  f"| {r['applied'][k]:.2f} | {r['alpha'][k]:.2f} | {r['clip_w'][k]:+.3g} "
                  f"| {r['speed'][k]:.2f} |")  # fmt: skip
    if args.figure:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, 4, figsize=(16, 3.6))
        for name, r in runs.items():
            ms = (r["t"] - onset) * 1000.0
            axes[0].plot(ms, r["sigma_dot"], label=name)
            axes[1].plot(ms, r["energy"], label=name)
            (line,) = axes[2].plot(ms, r["cmd"], label=f"{name}: commanded")
            axes[2].plot(ms, r["applied"], ":", color=line.get_color(), label=f"{name}: applied")
            axes[3].plot(ms, r["clip_w"], label=name)
        titles = (
            "σ̇",
            "storage E (J)",
            "max |τ_j| / τ_max,j",
            "clip power q̇ᵀ(τ_applied − τ_cmd) (W)",
        )
        for ax, title in zip(axes, titles, strict=True):
            ax.set_title(title, fontsize=9)
            ax.set_xlabel("time after the push onset (ms)")
            ax.set_xlim(-50, 400)
            ax.grid(True, alpha=0.3)
        for ax in axes[:3]:
            ax.set_yscale("log")
        axes[1].set_ylim(bottom=1e-3)
        axes[3].set_yscale("symlog", linthresh=1.0)
        axes[2].legend(fontsize=7)
        axes[0].legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(args.figure, dpi=110)
        print(f"\nwrote {args.figure}")


if __name__ == "__main__":
    main()
