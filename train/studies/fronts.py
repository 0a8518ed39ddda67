"""Effort-matched comparison: error-vs-effort fronts, ``ptrack fronts``.

For each controller, one knob — a scale ``k`` on its gain rates (``BANDWIDTHS`` of its
module: ω for the baselines, ω and ω_s for the passivity law), applied to its ``gains``
(tuned or default) — is swept over ``scales``; every (controller, k) runs the same paired
episodes (``seeds`` × each preset at ``level``, "none" undisturbed). Each point is the mean
path-distance RMS (rad) against the mean dynamic effort ``tau_dyn_rms_frac`` (the RMS of
(τ − g(q))/τ_max), with 95% bootstrap intervals over the seeds.

* **front** — :func:`pareto_front`: of a controller's points, those that no other point of
  its own beats on both error and effort; on it, error falls as effort rises;
* **error at a common effort** — :func:`error_at`: the front read at one effort, log-log
  linear between its points, NaN outside its effort range (never extrapolated). The common
  effort of a panel is what ``reference`` spends there with its ``gains`` at k = 1 (the
  "all" panel: the mean over the presets, the same quantity the tuning budget bounds).

Writes ``points.csv`` (per episode), ``fronts.csv`` (per controller × scale × panel),
``common_effort.md`` and ``fronts.png`` (one panel per preset and "all"; the front as a line,
every point with its intervals) to ``out``; ``--resume`` continues ``points.csv``.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import ptrack_gym  # noqa: F401  (registers the envs)
from agents.registry import GAIN_CHOICES, RATE_MODULES, scaled_rates
from ptrack_gym.disturbances import PRESETS
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots import profile_for_env_id
from train.common import arguments
from train.common.runs import open_run, worker_count, worker_pool, write_atomic
from train.common.statistics import bootstrap_ci, pareto_front
from train.evaluation.episode import EpisodeSettings, Task, run_episode
from train.plots.studies import fronts_plot


@dataclass
class FrontConfig:
    """A front sweep (the fields of ``--config`` / ``--set``)."""

    env_id: str = "ptrack_gym/IiwaTrack-v0"
    controllers: list[str] = field(
        default_factory=lambda: ["passivity", "computed_torque", "pd_gravity", "slotine_li"]
    )
    gains: str = "tuned"
    """The gains the scale multiplies: "tuned" or "default"."""
    scales: list[float] = field(
        default_factory=lambda: [0.25, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0]
    )
    disturbances: list[str] = field(
        default_factory=lambda: ["none", "impulse", "periodic", "payload", "noise"]
    )
    level: float = 1.0
    seeds: int = 5
    """Seeds 0..seeds-1 (reset seed 10 000·seed, as in evaluation)."""
    episode_s: float = 8.0
    control_hz: float = 1000.0
    reference: str = "computed_torque"
    """Whose effort at scale 1 is the common effort."""
    failure_distance_rad: float = 0.5
    workers: int = 0
    out: str = "results/fronts"

    def validate(self) -> None:
        """Raise :class:`InvalidConfigError` naming the first bad field, before any episode."""
        profile = profile_for_env_id(self.env_id)
        bad = [c for c in self.controllers if c not in RATE_MODULES]
        if not self.controllers or bad:
            raise InvalidConfigError(f"controllers must be some of {sorted(RATE_MODULES)}")
        if self.reference not in self.controllers:
            raise InvalidConfigError(f"reference {self.reference!r} is not among the controllers")
        if self.gains not in GAIN_CHOICES:
            raise InvalidConfigError(f"gains must be one of {GAIN_CHOICES}, got {self.gains!r}")
        if not self.scales or 1.0 not in self.scales:
            raise InvalidConfigError("scales must include 1.0 (the gains themselves)")
        for c in self.controllers:
            for k in self.scales:
                scaled_rates(profile, c, self.gains, k)  # positive scales, tuned files exist
        unknown = [d for d in self.disturbances if d not in PRESETS]
        if not self.disturbances or unknown:
            raise InvalidConfigError(f"disturbances must be presets of {list(PRESETS)}")
        if self.seeds < 2:
            raise InvalidConfigError("seeds must be >= 2 (the intervals)")
        if not (math.isfinite(self.level) and self.level > 0 and self.episode_s > 0):
            raise InvalidConfigError("level and episode_s must be positive")

    def jobs(self) -> list[tuple[str, float, Task, EpisodeSettings]]:
        """Every episode: (controller, scale, task, settings), in a fixed order."""
        profile = profile_for_env_id(self.env_id)
        out = []
        for c in self.controllers:
            for k in self.scales:
                rates = scaled_rates(profile, c, self.gains, k)
                settings = EpisodeSettings(
                    self.env_id, self.episode_s, self.control_hz, "on_path",
                    self.failure_distance_rad, 0.01, gains=tuple(sorted(rates.items())),
                )  # fmt: skip
                for d in self.disturbances:
                    level = 0.0 if d == "none" else self.level
                    for seed in range(self.seeds):
                        out.append((c, float(k), Task(c, d, level, seed, 0), settings))
        return out


POINT_COLUMNS = ("controller", "scale", "disturbance", "seed", "error_rad", "effort", "failed")


def _run(job: tuple[str, float, Task, EpisodeSettings]) -> dict[str, Any]:
    controller, scale, task, settings = job
    row = run_episode(task, settings)[0]
    return {
        "controller": controller, "scale": scale, "disturbance": task.disturbance,
        "seed": task.seed, "error_rad": row["path_dist_rms"],
        "effort": row["tau_dyn_rms_frac"], "failed": int(row["failed"]),
    }  # fmt: skip


def error_at(effort: np.ndarray, error: np.ndarray, target: float) -> float:
    """The front of (effort, error) read at ``target`` effort: log-log linear between the
    two front points around it; NaN outside the front's effort range."""
    idx = pareto_front(effort, error)
    if idx.size == 0 or not math.isfinite(target):
        return float("nan")
    e, r = np.asarray(effort, float)[idx], np.asarray(error, float)[idx]
    if target < e[0] or target > e[-1] or np.any(e <= 0) or np.any(r <= 0):
        return float("nan")
    if idx.size == 1:
        return float(r[0])
    return float(np.exp(np.interp(np.log(target), np.log(e), np.log(r))))


def summarize(points: list[dict[str, Any]], resamples: int = 2000) -> list[dict[str, Any]]:
    """Per controller × scale × panel (each preset, and "all": per seed, the mean over the
    presets): mean error and effort with 95% bootstrap intervals over the seeds."""
    import pandas as pd

    df = pd.DataFrame(points)
    pooled = df.groupby(["controller", "scale", "seed"], as_index=False)[
        ["error_rad", "effort", "failed"]
    ].mean()
    pooled["disturbance"] = "all"
    rows = []
    for (c, k, d), g in pd.concat([df, pooled]).groupby(["controller", "scale", "disturbance"]):
        err, eff = g["error_rad"].to_numpy(float), g["effort"].to_numpy(float)
        e_lo, e_hi = bootstrap_ci(err, np.mean, resamples, 0)
        f_lo, f_hi = bootstrap_ci(eff, np.mean, resamples, 0)
        rows.append(
            {"controller": c, "scale": float(k), "panel": d, "n": len(g),
             "error_rad": float(np.mean(err)), "error_ci_low": e_lo, "error_ci_high": e_hi,
             "effort": float(np.mean(eff)), "effort_ci_low": f_lo, "effort_ci_high": f_hi,
             "failures": float(np.sum(g["failed"]))}
        )  # fmt: skip
    return rows


def common_effort_table(rows: list[dict[str, Any]], reference: str) -> tuple[str, dict]:
    """Markdown: per panel, each controller's error read from its front at the reference's
    effort at scale 1 ("—": that effort is outside the controller's front)."""
    panels = sorted({r["panel"] for r in rows}, key=lambda p: (p == "all", p))
    controllers = sorted({r["controller"] for r in rows})
    found: dict[str, dict[str, float]] = {}
    lines = [
        "| panel | common effort | " + " | ".join(controllers) + " |",
        "|---|---:|" + "---:|" * len(controllers),
    ]
    for panel in panels:
        sub = [r for r in rows if r["panel"] == panel]
        ref = [r for r in sub if r["controller"] == reference and r["scale"] == 1.0]
        target = ref[0]["effort"] if ref else float("nan")
        cells = []
        for c in controllers:
            pts = [r for r in sub if r["controller"] == c]
            value = error_at(
                np.array([p["effort"] for p in pts]),
                np.array([p["error_rad"] for p in pts]),
                target,
            )
            found.setdefault(panel, {})[c] = value
            cells.append(f"{value:.3g}" if math.isfinite(value) else "—")
        lines.append(f"| {panel} | {target:.4f} | " + " | ".join(cells) + " |")
    return "\n".join(lines), found


def _read_points(path: Path) -> list[dict[str, Any]]:
    """The finished episodes of ``points.csv``; a last line cut by an interruption is
    dropped (and the file rewritten without it), so a resume re-runs that episode."""
    if not path.exists():
        return []
    with path.open() as f:
        raw = list(csv.DictReader(f))
    whole = [r for r in raw if all(r.get(k) not in (None, "") for k in POINT_COLUMNS)]
    if len(whole) != len(raw):  # rewritten whole or not at all: a Ctrl-C here loses nothing
        text = io.StringIO(newline="")
        writer = csv.DictWriter(text, fieldnames=list(POINT_COLUMNS))
        writer.writeheader()
        writer.writerows(whole)
        write_atomic(path, text.getvalue())
    return [
        {**r, "scale": float(r["scale"]), "seed": int(r["seed"]),
         "error_rad": float(r["error_rad"]), "effort": float(r["effort"]),
         "failed": int(r["failed"])}
        for r in whole
    ]  # fmt: skip


def run_fronts(
    cfg: FrontConfig, resume: bool = False, progress: bool = True, force: bool = False
) -> Path:
    """Run (or continue) the sweep of ``cfg``; write the results; return the folder."""
    cfg.validate()
    settings = {k: v for k, v in dataclasses.asdict(cfg).items() if k not in ("workers", "out")}
    run = open_run(
        cfg.out, "points.csv", settings, resume=resume, force=force, saved_required=False
    )
    out, points_csv = run.out, run.results
    done = _read_points(points_csv)
    keys = {(r["controller"], r["scale"], r["disturbance"], r["seed"]) for r in done}
    jobs = [j for j in cfg.jobs() if (j[0], j[1], j[2].disturbance, j[2].seed) not in keys]
    new = not points_csv.exists()
    with (
        points_csv.open("a", newline="") as f,
        worker_pool(worker_count(cfg.workers), "spawn") as pool,
    ):
        writer = csv.DictWriter(f, fieldnames=list(POINT_COLUMNS))
        if new:
            writer.writeheader()
        for i, row in enumerate(pool.map(_run, jobs, chunksize=4), start=1):
            writer.writerow({k: repr(v) if isinstance(v, float) else v for k, v in row.items()})
            f.flush()
            done.append(row)
            if progress and (i % 50 == 0 or i == len(jobs)):
                print(f"fronts: {i}/{len(jobs)} episodes", flush=True)
    rows = summarize(done)
    with (out / "fronts.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows({k: repr(v) if isinstance(v, float) else v for k, v in r.items()}
                         for r in rows)  # fmt: skip
    table, _ = common_effort_table(rows, cfg.reference)
    (out / "common_effort.md").write_text(
        f"Error (path-distance RMS, rad) at a common dynamic effort, read from each "
        f"controller's front ({cfg.env_id}, {cfg.gains} gains, {cfg.seeds} seeds, presets at "
        f"level {cfg.level:g}); the common effort is {cfg.reference}'s at scale 1.\n\n"
        f"{table}\n"
    )
    fronts_plot(rows, out / "fronts.png", cfg.reference)
    if progress:
        print(table)
    return out


def load_config(path: Path | None, overrides: Sequence[str]) -> FrontConfig:
    """The config of a YAML file, with ``key=value`` overrides; unknown keys raise."""
    return arguments.load_config(FrontConfig, path, overrides, validate=False)
