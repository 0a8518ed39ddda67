"""The passivity law at real control rates, traced: why the earlier discretization diverged
or lost accuracy at 500 and 250 Hz, and what each part of the current one does.

1. A trace of a diverging episode under the earlier discretization (symplectic Euler for
   (s, ṡ, σ), the torque held from the sample, no damper beside φ): the two-link's one-seed
   tuned gains (:data:`ONE_SEED_TWO_LINK_RATES`) on random path 7000 at 250 Hz, undisturbed,
   started on the path; per control step s̃̇,
   ṡ, σ̇, M_r(s) and the phase loop's a dt² and c dt (``agents.passivity_sampling``).
2. The per-step growth factor ρ of the law's four fast loops against the control rate,
   worst over one random path per robot (default gains; the two-link also at its one-seed
   and its fight-tuned gains), earlier scheme against current: the phase loop, the velocity
   turning, the spring modes, the virtual pump (earlier: k uncapped).
3. (``--figure``) the same as a figure.

    python bench/passivity_rates.py --figure docs/figures/control_rates_growth.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import numpy as np

import ptrack_gym  # noqa: F401  (registers the envs)
from agents import passivity
from agents import passivity_sampling as sampling
from agents.base import ControlContext
from agents.gains import max_mode_frequency
from agents.gains import rates as layered_rates
from agents.passivity import PassivityController
from agents.passivity_tables import passivity_tables
from agents.policy import ControllerPolicy
from agents.registry import tuned_rates
from ptrack_gym.errors import ControllerDivergedError

RATES_HZ = (1000.0, 500.0, 250.0, 100.0)
ROBOTS = ("two_link", "iiwa", "xarm6", "panda")
PATH_SEED = 7000
#: The two-link's passivity rates of the one-seed tuning study, at which the earlier scheme
#: diverged at 250 Hz (part 1); its tuning fight has since replaced them.
ONE_SEED_TWO_LINK_RATES = {"omega": 28.90665553129495, "omega_s": 7.019631076479537,
                           "rho": 29.54292291649651, "lam": 1.8963637937954358}  # fmt: skip


def context(robot: str, control_hz: float, path_seed: int = PATH_SEED) -> tuple:
    """(env, context, tables) for a random path of ``robot`` at ``control_hz``."""
    from ptrack_gym.robots import robot_profile

    env = gym.make(
        robot_profile(robot).env_id, control_hz=control_hz, path="random",
        path_seed=path_seed, horizon_s=4.0, max_episode_steps=round(4 * control_hz),
    )  # fmt: skip
    ctx = ControlContext.from_env(env)
    return env, ctx, passivity_tables(ctx.path, ctx.model)


def earlier_gains(ctx: ControlContext, tables, rates: dict) -> passivity.PassivityGains:
    """The gains of the earlier discretization: no damper beside φ, no coupled-mode cap."""
    r = layered_rates(passivity.DEFAULT_RATES, {**rates, "zoh_damping": 0.0}, passivity.NAME,
                        ctx.profile.controller_gains.get(passivity.NAME))  # fmt: skip
    aware = bool(r.pop("saturation_aware"))
    inertia = np.diag(ctx.model.mass_matrix(ctx.profile.home()))
    return passivity.PassivityGains.from_rates(
        inertia, tables.mean_m_r, dt_s=ctx.dt_s,
        torque_limits_nm=ctx.profile.torque_limits_nm if aware else None, **r,
    )  # fmt: skip


def trace(robot: str = "two_link", control_hz: float = 250.0) -> None:
    """Part 1 of the module docstring."""
    env, ctx, tables = context(robot, control_hz)
    gains = earlier_gains(ctx, tables, ONE_SEED_TWO_LINK_RATES)
    ctrl = PassivityController(ctx.model, tables, gains, integrator="symplectic", hold="sample")
    policy = ControllerPolicy(env, ctrl)
    obs, _ = env.reset(seed=0)
    policy.reset_controller(obs)
    n, dt = tables.n, ctx.dt_s
    k_diag, d_diag = gains.stiffness(n), gains.damping(n)
    print(f"1. {robot}, one-seed tuned gains, random path {PATH_SEED}, {control_hz:g} Hz, "
          "earlier scheme")  # fmt: skip
    print(f"{'t (s)':>7} {'s̃̇':>10} {'ṡ':>9} {'σ̇':>9} {'M_r(s) (J)':>11} {'a dt²':>7} {'c dt':>6}")
    rows = []
    for _ in range(round(4.0 * control_hz)):
        try:
            action = policy.action(obs)
        except ControllerDivergedError:
            rows.append("   (a non-finite torque: diverged)")
            break
        obs, _, terminated, truncated, info = env.step(action)
        d = ctrl.diagnostics()
        ref = tables(d["s"])
        a = (gains.kappa + ref.qd @ (k_diag * ref.qd)) / ref.m_r
        c = (gains.R + ref.qd @ (d_diag * ref.qd)) / ref.m_r
        rows.append(
            f"{info['t_s']:7.3f} {d['s_tilde_dot']:+10.3e} {d['sd']:9.4f} "
            f"{d['sigma_dot']:9.4f} {ref.m_r:11.4f} {a * dt * dt:7.3f} {c * dt:6.3f}"
        )
        if terminated or truncated:
            break
    env.close()
    for line in rows[-12:]:
        print(line)


def growth_rows(robot: str, rates: dict) -> list[tuple]:
    """Per control rate: ρ of each loop, worst over the path, earlier and current scheme."""
    out = []
    for hz in RATES_HZ:
        env, ctx, tables = context(robot, hz)
        env.close()
        dt = ctx.dt_s
        old = earlier_gains(ctx, tables, rates)
        new = passivity.gains_from_rates(ctx, rates, tables)
        omega_old = max_mode_frequency(ctx.model, tables.q_samples(), old.stiffness(tables.n))
        omega_new = max_mode_frequency(ctx.model, tables.q_samples(), new.stiffness(tables.n))
        c_new = float(np.min(new.damping(tables.n) / new.stiffness(tables.n))) / dt
        out.append((
            hz,
            sampling.phase_growth(tables, old, dt, "symplectic", "sample").max(),
            sampling.phase_growth(tables, new, dt, "implicit", "midpoint").max(),
            sampling.turning_growth(tables, ctx.model, old, dt, "sample").max(),
            sampling.turning_growth(tables, ctx.model, new, dt, "midpoint").max(),
            float(sampling.spring_growth(omega_old * dt, 0.0)[0]),
            float(sampling.spring_growth(omega_new * dt, c_new)[0]),
            sampling.pump_growth(old.k_pump, dt),
            sampling.pump_growth(new.k_pump, dt),
            omega_new * dt,
        ))  # fmt: skip
    return out


def figure(results: dict[str, list[tuple]], path: Path) -> None:
    """Part 3: ρ against the control rate, one panel per loop."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(15, 3.6), sharey=True)
    titles = ("phase loop", "velocity turning (τ_r⁰)", "spring modes (φ)", "virtual pump")
    for label, rows in results.items():
        hz = [r[0] for r in rows]
        for k, ax in enumerate(axes):
            (line,) = ax.plot(hz, [r[1 + 2 * k] for r in rows], "--", marker="o", ms=3)
            ax.plot(hz, [r[2 + 2 * k] for r in rows], "-", marker="o", ms=3,
                    color=line.get_color(), label=label)  # fmt: skip
    for ax, title in zip(axes, titles, strict=True):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_xlabel("control rate (Hz)")
        ax.set_title(title)
        ax.invert_xaxis()
    axes[0].set_ylabel("growth per control step ρ (worst on the path)")
    axes[3].legend(fontsize=8)
    fig.suptitle("dashed: earlier discretization; solid: current (ρ > 1 grows)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--figure", type=Path, help="write part 3's figure here")
    return ap.parse_args(argv)


def main() -> None:
    args = parse_args()
    trace()
    print("\n2. growth per control step ρ, worst on random path "
          f"{PATH_SEED} (earlier → current scheme); θ = ω_max dt of φ's springs")  # fmt: skip
    cases = {f"{r}, default": (r, {}) for r in ROBOTS}
    cases["two_link, one-seed tuned"] = ("two_link", ONE_SEED_TWO_LINK_RATES)
    cases["two_link, fight-tuned"] = ("two_link", tuned_rates("two_link", "passivity"))
    results = {}
    for label, (robot, rates) in cases.items():
        results[label] = rows = growth_rows(robot, rates)
        print(f"\n{label}")
        print(f"{'rate (Hz)':>9} {'phase':>15} {'turning':>15} {'springs':>15} {'pump':>15} "
              f"{'θ':>6}")  # fmt: skip
        for hz, p0, p1, t0, t1, s0, s1, k0, k1, theta in rows:
            print(f"{hz:9g} {p0:7.3f} → {p1:5.3f} {t0:7.3f} → {t1:5.3f} {s0:7.3f} → {s1:5.3f} "
                  f"{k0:7.3f} → {k1:5.3f} {theta:6.3f}")  # fmt: skip
    if args.figure:
        figure(results, args.figure)
        print(f"\nfigure: {args.figure}")


if __name__ == "__main__":
    main()
