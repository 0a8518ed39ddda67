"""Gain study of the passivity controller: which gains converge, per robot, at 1 kHz.

For each gain set of a grid and each seed i in first-seed .. first-seed + seeds − 1, one
episode of ``--duration-s`` seconds of the env defaults (1 kHz physics and control, the
robot's default path, its real torque limits):

* start at rest off the path (``--start study``, default): rng = np.random.default_rng(i);
  s₀ ~ U[0, S); q₀ = q_r(s₀) + U(±off) per joint with off = ``--offset-rad`` (default
  0.15 rad); q̇₀ = 0; the env's reference phase is s₀ too. ``--start env`` instead uses
  the env's own ``start="rest_near_path"`` sampler (same distribution, other draws)
  after ``env.reset(seed=i)``;
* the controller is reset at (q₀, 0, s₀) (it picks s at the path point nearest q₀, and
  ṡ₀ = σ̇(q₀, 0) = 0), then the env loop runs:
  τ = ctrl.step(q, q̇, env.dt); env.step(clip(τ / τ_max, −1, 1)); q, q̇ = env.joint_state();
* recorded: convergence time t_c — the first time after which path distance
  (``info["path_distance"]``) < 1e-3 rad AND |ṡ − 1| < 1e-2 hold at every step until
  the end (ṡ is ``ctrl.diagnostics()["sd"]``; NaN if the last step fails either test);
  the final path distance and |ṡ − 1|; peak |τ|/τ_max over joints and steps (of the
  controller's unclipped torque); the fraction of steps where any joint saturates
  (|τ_j| > τ_max,j); and whether the env terminated (unstable).

Gain parametrisation (every set is stated in physical terms, then made absolute):

* K_j = ω² · max(M_jj(q_home), m_floor)   (spring of φ, per joint; M of the nominal model)
* κ = ω_s² · M̄_r,  R = ρ · M̄_r  (ρ = 2ζω_s for a damping ratio ζ)   (phase spring and
  damping; M̄_r = mean of M_r(s) over the path, the "mass" of M_r(s) s̈ = …)
* k_pump = λ / M̄_r                 (the pump's energy-decay rate is ≈ k·q̇ᵀMq̇ ≈ k·M_r)
* sync_rate = γ (1/s), sync_ratio = r̄: the law's opt-in low-speed phase
  re-synchronisation (``PassivityGains``; γ = 0, the default, is the paper's law)

One CSV row per (gain set, seed) goes to ``--out``; a markdown summary per gain set is
printed (converged count, count with t_c ≤ ``--target-s``, median and max t_c over
converged seeds, worst final path distance and |ṡ − 1|, peak torque ratio, saturation,
unstable count). Results are deterministic (PyBullet, fixed seeds).

Examples (run from the repository root; results in ``docs/passivity_gain_study.md``)::

    python bench/passivity_gain_study.py --robot iiwa --seeds 3 --duration-s 30 \
        --grid quick --centre omega=20,omega_s=20,rho=10,lam=5,m_floor=0.1 \
        --out /tmp/pgs/iiwa_quick2.csv
    python bench/passivity_gain_study.py --robot iiwa --seeds 20 --duration-s 40 \
        --grid defaults --out /tmp/pgs/iiwa_defaults20.csv
    python bench/passivity_gain_study.py --robot iiwa --seeds 10 --duration-s 40 \
        --grid defaults --start env --out /tmp/pgs/iiwa_defaults_envstart.csv
    python bench/passivity_gain_study.py --robot two_link --seeds 3 --duration-s 30 \
        --set omega=20,omega_s=20,rho=10,lam=2,m_floor=0.1 --out /tmp/one.csv

Run one process at a time: every episode is a single-threaded PyBullet simulation.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import math
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import gymnasium as gym
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import ptrack_gym  # noqa: F401  (registers the envs)
from agents import passivity
from agents.base import ControlContext
from agents.passivity import PassivityController, PassivityGains
from agents.passivity_tables import passivity_tables
from ptrack_gym.robots import ROBOTS, home_inertia_kgm2

ENV_IDS = {name: profile.env_id for name, profile in ROBOTS.items()}

#: Convergence thresholds: path distance (rad) and |ṡ − 1| (1).
PATH_TOL_RAD = 1e-3
SPEED_TOL = 1e-2
#: Default start offset: q₀ = q_r(s₀) + U(±0.15 rad) per joint, at rest.
OFFSET_RAD = 0.15


@dataclass(frozen=True)
class GainPoint:
    """One gain set in physical terms (see the module docstring)."""

    omega: float  # ω (rad/s): K_j = ω² M_jj(q_home)
    omega_s: float  # ω_s (rad/s): κ = ω_s² M̄_r
    rho: float  # ρ (1/s): R = ρ M̄_r  (ρ = 2 ζ_s ω_s for a damping ratio ζ_s)
    lam: float  # λ (1/s): k_pump = λ / M̄_r
    pump: str = "metric"
    m_floor: float = 0.0  # kg·m²: K_j = ω² max(M_jj(q_home), m_floor)
    sync_rate: float = 0.0  # γ (1/s): low-speed phase re-synchronisation (0 = paper law)
    sync_ratio: float = 0.5  # r̄ (1): speed ratio below which sync_rate acts
    saturation_aware: bool = True  # τ_r⁰ scaled into the actuator box (the default law)

    @property
    def label(self) -> str:
        return (
            f"w={self.omega:g} ws={self.omega_s:g} rho={self.rho:g} "
            f"lam={self.lam:g} {self.pump}"
            + (f" mfloor={self.m_floor:g}" if self.m_floor else "")
            + (f" sync={self.sync_rate:g}/{self.sync_ratio:g}" if self.sync_rate else "")
            + ("" if self.saturation_aware else " unaware")
        )

    def gains(
        self,
        inertia: np.ndarray,
        mean_m_r: float,
        dt_s: float,
        torque_limits_nm: np.ndarray | None = None,
    ) -> PassivityGains:
        """The absolute gains (``PassivityGains.from_rates``, rate-aware at ``dt_s``)."""
        r = asdict(self)
        aware = r.pop("saturation_aware")
        lim = (
            tuple(float(x) for x in torque_limits_nm)
            if aware and torque_limits_nm is not None
            else None
        )
        return PassivityGains.from_rates(inertia, mean_m_r, dt_s=dt_s, torque_limits_nm=lim, **r)


def parse_set(text: str) -> GainPoint:
    """``omega=10,omega_s=4,rho=1,lam=5[,pump=metric][,m_floor=..][,sync_rate=..]
    [,sync_ratio=..]`` → GainPoint."""
    fields: dict[str, str] = dict(kv.split("=", 1) for kv in text.split(","))
    pump = fields.pop("pump", "metric")
    aware = fields.pop("saturation_aware", "1") not in ("0", "false", "False")
    return GainPoint(**{k: float(v) for k, v in fields.items()}, pump=pump, saturation_aware=aware)  # type: ignore[arg-type]


#: Centre of the quick grid, found by hand (on-path and three-seed screens, see the doc).
CENTRE = GainPoint(omega=30.0, omega_s=10.0, rho=10.0, lam=5.0, pump="metric", m_floor=0.1)


def grid(name: str, robot: str, centre: GainPoint = CENTRE) -> list[GainPoint]:
    """The gain sets of a named grid.

    ``quick`` (16 sets): around ``centre`` c (default :data:`CENTRE`): c; one factor at a
    time — ω × {2/3, 4/3}, ω_s × {1/2, 2}, ρ × {2/5, 2}, λ × {2/5, 2}, m_floor ∈ {0.025, 0},
    the "paper" pump; and four combinations (ω × 2/3 with ρ × 2/5; ω, ω_s, ρ all × 4/3,
    2, 2; ω_s, ρ, λ all × 2; ω, ω_s, ρ × 1/3, 1/2, 1/10). With the default centre these
    are ω ∈ {20, 40}, ω_s ∈ {5, 20}, ρ ∈ {4, 20}, λ ∈ {2, 10}.
    ``full``: a Cartesian product (576 sets; hours of compute — not run for the doc).
    ``defaults``: the robot profile's default rates only.
    """
    if name == "defaults":
        rates = {**passivity.DEFAULT_RATES, **ROBOTS[robot].controller_gains.get("passivity", {})}
        return [GainPoint(**rates)]
    c = centre
    w, ws, r, lam = c.omega, c.omega_s, c.rho, c.lam
    if name == "quick":
        pts = [
            c,
            replace(c, omega=w * 2 / 3),
            replace(c, omega=w * 4 / 3),
            replace(c, omega_s=ws / 2),
            replace(c, omega_s=ws * 2),
            replace(c, rho=r * 2 / 5),
            replace(c, rho=r * 2),
            replace(c, lam=lam * 2 / 5),
            replace(c, lam=lam * 2),
            replace(c, m_floor=0.025),
            replace(c, m_floor=0.0),
            replace(c, pump="paper" if c.pump == "metric" else "metric"),
            replace(c, omega=w * 2 / 3, rho=r * 2 / 5),
            replace(c, omega=w * 4 / 3, omega_s=ws * 2, rho=r * 2),
            replace(c, omega_s=ws * 2, rho=r * 2, lam=lam * 2),
            replace(c, omega=w / 3, omega_s=ws / 2, rho=r / 10),
        ]
        return list(dict.fromkeys(pts))  # drop duplicates (e.g. m_floor already 0)
    if name == "full":
        return [
            GainPoint(w, ws, r, lam, pump, mf)
            for w, ws, r, lam, pump, mf in itertools.product(
                (10.0, 20.0, 30.0, 40.0),
                (5.0, 10.0, 20.0),
                (1.0, 4.0, 10.0, 20.0),
                (2.0, 5.0, 10.0),
                ("metric", "paper"),
                (0.0, 0.1),
            )
        ]
    raise ValueError(f"unknown grid {name!r}")


@dataclass
class EpisodeResult:
    """Metrics of one episode (SI units)."""

    converged: bool
    t_conv_s: float  # NaN when not converged
    final_path_distance_rad: float
    final_speed_error: float  # |ṡ − 1| at the end
    peak_tau_ratio: float  # max_j,t |τ_j| / τ_max,j of the controller's torque
    saturated_fraction: float  # fraction of steps with any |τ_j| > τ_max,j
    unstable: bool
    steps: int
    wall_s: float


def robot_constants(env: gym.Env) -> tuple[np.ndarray, float]:
    """diag M(q_home) (kg·m²) and the mean of M_r over the path (J)."""
    u = env.unwrapped
    inertia = home_inertia_kgm2(u.model, u.robot_profile)
    return inertia, passivity_tables(u.path, u.model).mean_m_r


def start_state(env: gym.Env, seed: int, offset_rad: float) -> tuple[float, np.ndarray]:
    """s₀ ~ U[0, S) and q₀ = q_r(s₀) + U(±offset) per joint, from default_rng(seed)."""
    u = env.unwrapped
    rng = np.random.default_rng(seed)
    s0 = float(rng.uniform(0.0, u.path.period_s))
    q_ref, _, _ = u.path.evaluate(s0)
    q0 = q_ref + rng.uniform(-offset_rad, offset_rad, size=u.n)
    return s0, q0


def run_episode(
    env: gym.Env,
    gains: PassivityGains,
    seed: int,
    duration_s: float,
    offset_rad: float = OFFSET_RAD,
    log_every: int = 0,
    start: str = "study",
) -> tuple[EpisodeResult, list[dict[str, float]]]:
    """One rest start under the passivity controller; metrics and an optional coarse log.

    ``start="study"``: the start of the module docstring (rng = default_rng(seed));
    ``start="env"``: the env's own ``rest_near_path`` start after ``env.reset(seed=seed)``
    (the env must be made with ``start="rest_near_path"``, ``start_offset_rad=offset_rad``).
    """
    u = env.unwrapped
    if start == "study":
        s0, q0 = start_state(env, seed, offset_rad)
        env.reset(seed=seed, options={"s0": s0, "q": q0, "qd": np.zeros(u.n)})
    elif start == "env":  # the env's own start="rest_near_path" sampling, seeded by reset
        if u.config.start != "rest_near_path" or u.config.start_offset_rad != offset_rad:
            raise ValueError("start='env' needs an env made with start='rest_near_path'")
        env.reset(seed=seed)
        s0 = u.s0
    else:
        raise ValueError(f"unknown start {start!r}")
    q, qd = u.joint_state()
    ctrl = PassivityController(u.model, passivity_tables(u.path, u.model), gains)
    ctrl.reset(q, qd, s0)
    tau_max = u.torque_limits_nm
    dt = u.dt
    n_steps = round(duration_s / dt)
    last_bad = -1  # index of the last step where a convergence test failed
    peak, n_sat = 0.0, 0
    unstable = False
    dist = math.inf
    sd_err = math.inf
    log: list[dict[str, float]] = []
    t0 = time.perf_counter()
    k = 0
    for k in range(n_steps):
        tau = ctrl.step(q, qd, dt)
        ratio = np.abs(tau) / tau_max
        r = float(np.max(ratio)) if np.all(np.isfinite(tau)) else math.inf
        peak = max(peak, r)
        n_sat += r > 1.0
        a = np.clip(np.nan_to_num(tau / tau_max), -1.0, 1.0)
        _, _, terminated, truncated, info = env.step(a)
        q, qd = u.joint_state()
        dist = float(info["path_distance"])
        sd = float(ctrl.state.sd)
        sd_err = abs(sd - 1.0)
        if not (dist < PATH_TOL_RAD and sd_err < SPEED_TOL):
            last_bad = k
        if log_every and k % log_every == 0:
            d = ctrl.diagnostics()
            log.append({"t": (k + 1) * dt, "dist": dist, "peak_step": r, **d})
        if terminated or truncated:
            unstable = bool(info.get("unstable", terminated))
            break
    steps = k + 1
    converged = not unstable and last_bad < steps - 1 and steps == n_steps
    t_conv = (last_bad + 1) * dt if converged else math.nan
    return (
        EpisodeResult(
            converged=converged,
            t_conv_s=t_conv,
            final_path_distance_rad=dist,
            final_speed_error=sd_err,
            peak_tau_ratio=peak,
            saturated_fraction=n_sat / steps,
            unstable=unstable,
            steps=steps,
            wall_s=time.perf_counter() - t0,
        ),
        log,
    )


#: Target convergence time per robot (s): the study reports how many seeds have t_c ≤ it.
TARGET_S = {name: profile.convergence_target_s for name, profile in ROBOTS.items()}


def summarise(rows: list[dict], target_s: float) -> str:
    """A markdown table: one line per gain set.

    "converged" counts seeds whose conditions hold from t_c to the end of the episode;
    "t_c ≤ target" counts those with t_c ≤ ``target_s`` (a t_c near the end of the
    episode is only a weak claim: the conditions held for a short time).
    """
    import pandas as pd

    df = pd.DataFrame(rows)
    lines = [
        f"| gain set | K (N·m/rad) | κ | R | k_pump | converged | t_c ≤ {target_s:g} s | "
        "median t_c (s) | max t_c (s) | worst final dist (rad) | worst final abs(ṡ−1) | "
        "peak τ/τmax | sat. frac. | unstable |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for label, g in df.groupby("label", sort=False):
        conv = g[g.converged]
        within = int((conv.t_conv_s <= target_s).sum())
        med = f"{conv.t_conv_s.median():.2f}" if len(conv) else "—"
        mx = f"{conv.t_conv_s.max():.2f}" if len(conv) else "—"
        first = g.iloc[0]
        lines.append(
            f"| {label} | {first.K} | {first.kappa:.4g} | {first.R:.4g} | {first.k_pump:.4g} "
            f"| {len(conv)}/{len(g)} | {within}/{len(g)} | {med} | {mx} "
            f"| {g.final_path_distance_rad.max():.2e} "
            f"| {g.final_speed_error.max():.2e} | {g.peak_tau_ratio.max():.2f} "
            f"| {g.saturated_fraction.max():.3f} | {int(g.unstable.sum())} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robot", choices=sorted(ENV_IDS), default="two_link")
    ap.add_argument("--seeds", type=int, default=3, help="number of seeds")
    ap.add_argument(
        "--first-seed", type=int, default=0, help="seeds first-seed .. first-seed+seeds-1"
    )
    ap.add_argument("--duration-s", type=float, default=30.0)
    ap.add_argument("--grid", choices=("quick", "full", "defaults"), default="quick")
    ap.add_argument(
        "--set",
        action="append",
        default=None,
        help="explicit gain set(s) 'omega=..,omega_s=..,rho=..,lam=..[,pump=..][,m_floor=..]'"
        "; replaces --grid",
    )
    ap.add_argument(
        "--centre",
        default=None,
        help="centre of the quick grid, same syntax as --set (default: the module's CENTRE)",
    )
    ap.add_argument("--offset-rad", type=float, default=OFFSET_RAD)
    ap.add_argument(
        "--target-s",
        type=float,
        default=None,
        help="report seeds with t_c <= this (default: 20 s two_link, 30 s iiwa/panda)",
    )
    ap.add_argument(
        "--start",
        choices=("study", "env"),
        default="study",
        help="study: q0 = q_r(s0) + U(±offset) from default_rng(seed) (default); env: the "
        "env's own start='rest_near_path' after env.reset(seed=seed)",
    )
    ap.add_argument("--control-hz", type=float, default=1000.0, help="control rate (Hz)")
    ap.add_argument("--out", type=Path, required=True, help="CSV path")
    args = ap.parse_args(argv)

    if args.set:
        points = [parse_set(t) for t in args.set]
    else:
        centre = parse_set(args.centre) if args.centre else CENTRE
        points = grid(args.grid, args.robot, centre)
    env_kwargs = (
        {"start": "rest_near_path", "start_offset_rad": args.offset_rad}
        if args.start == "env"
        else {}
    )
    env = gym.make(
        ENV_IDS[args.robot], max_episode_steps=10**9, control_hz=args.control_hz, **env_kwargs
    )
    inertia, mean_m_r = robot_constants(env)
    print(
        f"# {args.robot}: diag M(q_home) = {np.round(inertia, 5).tolist()}, "
        f"mean M_r = {mean_m_r:.5g} J, tau_max = {env.unwrapped.torque_limits_nm.tolist()}, "
        f"dt = {env.unwrapped.dt} s, offset = ±{args.offset_rad} rad, start = {args.start}, "
        f"{len(points)} gain sets x {args.seeds} seeds x {args.duration_s} s",
        flush=True,
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []
    t_start = time.perf_counter()
    fieldnames: list[str] | None = None
    with args.out.open("w", newline="") as fh:
        writer = None
        for pt in points:
            gains = pt.gains(inertia, mean_m_r, env.unwrapped.dt, env.unwrapped.torque_limits_nm)
            if args.grid == "defaults" and not args.set:
                stored = passivity.default_gains(ControlContext.from_env(env))
                if stored != gains:
                    raise RuntimeError(f"the controller's defaults {stored} are not {gains}")
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                res, _ = run_episode(
                    env, gains, seed, args.duration_s, args.offset_rad, start=args.start
                )
                row = {
                    "robot": args.robot,
                    "label": pt.label,
                    **asdict(pt),
                    "K": "(" + ", ".join(f"{x:.4g}" for x in gains.K) + ")",
                    "kappa": gains.kappa,
                    "R": gains.R,
                    "k_pump": gains.k_pump,
                    "seed": seed,
                    "offset_rad": args.offset_rad,
                    "start": args.start,
                    "duration_s": args.duration_s,
                    **asdict(res),
                }
                if writer is None:
                    fieldnames = list(row)
                    writer = csv.DictWriter(fh, fieldnames=fieldnames)
                    writer.writeheader()
                writer.writerow(row)
                fh.flush()
                rows.append(row)
                print(
                    f"{pt.label} seed={seed}: conv={res.converged} t_c={res.t_conv_s:.2f} "
                    f"dist={res.final_path_distance_rad:.2e} "
                    f"|sd-1|={res.final_speed_error:.2e} peak={res.peak_tau_ratio:.2f} "
                    f"sat={res.saturated_fraction:.3f} unstable={res.unstable} "
                    f"wall={res.wall_s:.1f}s",
                    flush=True,
                )
    env.close()
    print()
    target = args.target_s if args.target_s is not None else TARGET_S[args.robot]
    print(summarise(rows, target))
    print(f"\ntotal wall time {time.perf_counter() - t_start:.0f} s; CSV: {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
