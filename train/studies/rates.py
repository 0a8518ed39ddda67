"""The control rate as a robustness axis: ``ptrack rates``.

Every controller × robot × control rate × random admissible path × disturbance preset
(level ``level``) × seed, one episode each, started on the path; the same (path, seed) meets
every controller and every rate (the env's reset seed and disturbance stream depend on the
seed only). Writes to ``--out``:

* ``config.yml``, ``command.txt``;
* ``episodes.csv`` — one row per episode (the metrics of :mod:`ptrack_gym.metrics`, and
  ``refused``: 1 where the controller refused the rate at construction, its metrics then
  empty), appended as episodes finish; ``--resume`` skips the finished ones;
* ``report.md`` — per robot and disturbance, each controller's median path-distance RMS
  (and time-indexed error) at each rate, its ratio to the controller's own 1-kHz median,
  its failed and refused episodes, and whether it **holds** at that rate: no failed or
  refused episode and a median within ``accuracy_factor`` · (1000 Hz / rate) of its 1-kHz
  median (the default 1.5: 3× at 500 Hz, 6× at 250 Hz, 15× at 100 Hz);
* ``rates_<metric>.png`` — the medians against the rate.

Episodes run in ``workers`` processes (default: the number of cores).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from agents.registry import GAIN_CHOICES, tuned_rates
from ptrack_gym.errors import ControlRateError, InvalidConfigError
from ptrack_gym.metrics import METRIC_NAMES
from ptrack_gym.robots import ROBOTS
from train.common import arguments
from train.common.checks import check_counts, check_known, check_lists
from train.evaluation.episode import EpisodeSettings, Task, run_episode
from train.evaluation.rate_record import open_recorded_run, rate_record
from train.evaluation.results import read_episodes
from train.plots.studies import rates_figure
from train.studies.rows import run_rows

KEY_COLUMNS = ("robot", "controller", "control_hz", "path_seed", "disturbance", "seed")
COLUMNS = (*KEY_COLUMNS, "refused", *METRIC_NAMES, "steps", "wall_s")


@dataclass
class RatesConfig:
    """A control-rate study (the fields of ``--config`` / ``--set``)."""

    robots: list[str] = field(default_factory=lambda: ["two_link", "iiwa", "xarm6", "panda"])
    """Robots (keys of ``ptrack_gym.robots.ROBOTS``)."""
    controllers: list[str] = field(
        default_factory=lambda: [
            "passivity", "passivity_paper", "computed_torque", "pd_gravity", "slotine_li",
        ]
    )  # fmt: skip
    """Controllers of ``agents.registry``."""
    gains: str = "default"
    """"default" or "tuned" (``agents/tuned``: every robot × controller must have a file)."""
    control_rates: list[float] = field(default_factory=lambda: [1000.0, 500.0, 250.0, 100.0])
    """Control rates (Hz); the first is the reference of the accuracy ratio; physics 1 kHz."""
    paths: int = 12
    """Random admissible paths per robot: path seeds ``path_seed`` … + ``paths`` − 1."""
    path_seed: int = 9000
    """The first path seed."""
    disturbances: list[str] = field(default_factory=lambda: ["none", "impulse"])
    """Disturbance presets of ``ptrack_gym.disturbances.PRESETS``."""
    level: float = 1.0
    """Level of every preset but ``none``."""
    seeds: int = 1
    """Episodes per path and preset: seeds 0 … ``seeds`` − 1 (reset seed 10 000·seed)."""
    episode_s: float = 8.0
    """Episode length (s)."""
    failure_distance_rad: float = 0.5
    """An episode fails if the path distance ever exceeds this (rad), or it goes unstable."""
    accuracy_factor: float = 1.5
    """A controller holds at rate f if its median is ≤ this · (f_ref / f) × its median at
    the reference rate f_ref (the first of ``control_rates``)."""
    metric: str = "path_dist_rms"
    """The metric of the verdict and the figure."""
    workers: int = 0
    """Episode runners (0: the number of cores)."""
    out: str = "results/rates"
    """Output folder."""
    plots: bool = True
    """Write the figure."""

    def validate(self) -> None:
        """Raise :class:`InvalidConfigError` naming the first bad field, before any episode."""
        check_lists(self, ("robots", "controllers", "control_rates", "disturbances"))
        check_known(self.robots, self.controllers, self.disturbances)
        for hz in self.control_rates:
            if not (isinstance(hz, (int, float)) and math.isfinite(hz) and hz > 0):
                raise InvalidConfigError(f"control_rates must be positive, got {hz!r}")
            if abs(1000.0 / hz - round(1000.0 / hz)) > 1e-9:
                raise InvalidConfigError(
                    f"control rate {hz:g} Hz: 1000 Hz physics must be a whole multiple of it"
                )
        check_counts(self, ("paths", "seeds", "workers"))
        if isinstance(self.path_seed, bool) or not isinstance(self.path_seed, int):
            raise InvalidConfigError(f"path_seed must be an integer, got {self.path_seed!r}")
        for name in ("level", "episode_s", "failure_distance_rad", "accuracy_factor"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise InvalidConfigError(f"{name} must be a positive number, got {value!r}")
        if self.metric not in METRIC_NAMES:
            raise InvalidConfigError(f"metric {self.metric!r} is not one of {list(METRIC_NAMES)}")
        if self.gains not in GAIN_CHOICES:
            raise InvalidConfigError(f"gains must be one of {GAIN_CHOICES}, got {self.gains!r}")
        if self.gains == "tuned":
            for robot in self.robots:
                for c in self.controllers:
                    tuned_rates(robot, c)  # raises naming the missing file

    def tasks(self) -> list[tuple[str, str, float, int, str, int]]:
        """Every episode's key (robot, controller, rate, path seed, disturbance, seed)."""
        return [
            (robot, c, float(hz), self.path_seed + p, d, seed)
            for robot in self.robots
            for p in range(self.paths)
            for d in self.disturbances
            for seed in range(self.seeds)
            for hz in self.control_rates
            for c in self.controllers
        ]


def _key_text(key: tuple[Any, ...]) -> tuple[str, ...]:
    robot, c, hz, path_seed, d, seed = key
    return (robot, c, f"{hz:g}", str(path_seed), d, str(seed))


def run_one(cfg: RatesConfig, key: tuple[Any, ...]) -> dict[str, Any]:
    """The CSV row of one episode (:data:`COLUMNS`); a refused rate is a row too."""
    robot, controller, hz, path_seed, disturbance, seed = key
    settings = EpisodeSettings(
        env_id=ROBOTS[robot].env_id, episode_s=cfg.episode_s, control_hz=hz, start="on_path",
        failure_distance_rad=cfg.failure_distance_rad, recovery_threshold_rad=0.01,
        gains=cfg.gains, path="random", path_seed=path_seed,
    )  # fmt: skip
    level = 0.0 if disturbance == "none" else float(cfg.level)
    row = dict(zip(KEY_COLUMNS, _key_text(key), strict=True))
    try:
        metrics = run_episode(Task(controller, disturbance, level, seed, 0), settings)[0]
    except ControlRateError:
        return {**row, "refused": 1, **dict.fromkeys(METRIC_NAMES, float("nan")),
                "failed": 1.0, "steps": 0, "wall_s": 0.0}  # fmt: skip
    return {**row, "refused": 0, **{k: metrics[k] for k in (*METRIC_NAMES, "steps", "wall_s")}}


def run_study(
    cfg: RatesConfig,
    resume: bool = False,
    progress: bool = True,
    force: bool = False,
    rerun_changed: bool = False,
) -> Path:
    """Run (or resume) the study of ``cfg``, then write its report; return the folder.

    ``config.yml`` records the rates every controller ran with (at 1 kHz, before the caps
    of each control rate: :mod:`train.evaluation.rate_record`); a resume after they changed
    is refused, or with ``rerun_changed`` reruns exactly those (robot, controller) rows.
    """
    cfg.validate()
    settings = {
        k: v for k, v in dataclasses.asdict(cfg).items() if k not in ("workers", "out", "plots")
    }
    run = open_recorded_run(
        cfg.out, "episodes.csv", settings, rate_record(cfg.robots, cfg.controllers, cfg.gains),
        resume=resume, force=force, rerun_changed=rerun_changed, free=(), columns=COLUMNS,
        key_columns=KEY_COLUMNS, pair_of=lambda row: (row["robot"], row["controller"]),
    )  # fmt: skip
    out, episodes = run.out, run.results
    finished = {
        tuple(r[k] for k in KEY_COLUMNS) for r in read_episodes(episodes, COLUMNS, KEY_COLUMNS)
    }
    todo = [k for k in cfg.tasks() if _key_text(k) not in finished]
    run_rows(run_one, [(cfg, key) for key in todo], cfg.workers, episodes, COLUMNS, progress)
    write_report(cfg, out)
    return out


def load_frame(path: Path) -> pd.DataFrame:
    """``episodes.csv`` of a rate study as a DataFrame (numeric columns parsed)."""
    rows = read_episodes(path, COLUMNS, KEY_COLUMNS, fill_missing=True)
    df = pd.DataFrame(rows, columns=list(COLUMNS))
    for col in (*METRIC_NAMES, "wall_s", "control_hz"):
        df[col] = df[col].astype(float)
    for col in ("refused", "steps", "path_seed", "seed"):
        df[col] = df[col].astype(int)
    return df


def verdict_table(cfg: RatesConfig, df: pd.DataFrame) -> pd.DataFrame:
    """Per robot × disturbance × controller × rate: episodes, failed, refused, the medians of
    ``cfg.metric`` and of the time-indexed error, the ratio to the reference rate's median
    and whether the controller holds there (see the module docstring)."""
    ref_hz = float(cfg.control_rates[0])
    rows = []
    for (robot, dist, ctrl), group in df.groupby(["robot", "disturbance", "controller"]):
        ref = group[group["control_hz"] == ref_hz]
        ref_median = float(np.median(ref[cfg.metric])) if len(ref) else float("nan")
        for hz in cfg.control_rates:
            g = group[group["control_hz"] == float(hz)]
            if not len(g):
                continue
            median = float(np.median(g[cfg.metric]))
            ratio = median / ref_median if ref_median > 0 else float("nan")
            failed, refused = int(g["failed"].sum()), int(g["refused"].sum())
            allowed = cfg.accuracy_factor * ref_hz / float(hz)
            holds = failed == 0 and refused == 0 and ratio <= allowed
            rows.append({
                "robot": robot, "disturbance": dist, "controller": ctrl, "control_hz": hz,
                "episodes": len(g), "failed": failed, "refused": refused, "median": median,
                "time_err_median": float(np.median(g["time_err_rms"])), "ratio": ratio,
                "allowed_ratio": allowed, "holds": holds,
            })  # fmt: skip
    return pd.DataFrame(rows)


def _md_table(columns: Sequence[str], rows: dict[str, list[str]]) -> list[str]:
    """A markdown table: a "controller" column, then ``columns``; one row per key."""
    lines = ["| controller | " + " | ".join(columns) + " |", "|---|" + "---|" * len(columns)]
    lines += [f"| {name} | " + " | ".join(cells) + " |" for name, cells in rows.items()]
    return lines


def _cell(sub: pd.DataFrame, ctrl: str, hz: float) -> pd.Series | None:
    r = sub[(sub["controller"] == ctrl) & (sub["control_hz"] == hz)]
    return None if r.empty else r.iloc[0]


def _verdict_text(r: pd.Series | None) -> str:
    if r is None:
        return ""
    extra = (f", {r['failed']} failed" if r["failed"] else "") + (
        f", {r['refused']} refused" if r["refused"] else ""
    )
    return f"{'✓' if r['holds'] else '✗'} {r['median']:.2e} ({r['ratio']:.2g}×{extra})"


def write_report(cfg: RatesConfig, out: Path) -> None:
    """``report.md``, ``verdict.csv`` (and the figure) from ``episodes.csv``."""
    df = load_frame(out / "episodes.csv")
    table = verdict_table(cfg, df)
    table.to_csv(out / "verdict.csv", index=False, float_format="%.6g")
    rates = [f"{hz:g} Hz" for hz in cfg.control_rates]
    ref = f"{cfg.control_rates[0]:g} Hz"
    lines = [
        f"# Control rates ({cfg.gains} gains)",
        "",
        f"{cfg.paths} random admissible paths per robot (seeds {cfg.path_seed}-"
        f"{cfg.path_seed + cfg.paths - 1}) × {cfg.seeds} seed(s), {cfg.episode_s:g}-s episodes "
        f"started on the path, presets at level {cfg.level:g}; physics at 1 kHz. Each cell: "
        f"median {cfg.metric} (rad) over the episodes, its ratio to the controller's own "
        f"median at {ref}, and failed/refused episodes. **✓** the controller holds at that "
        f"rate: no failed or refused episode and a ratio ≤ {cfg.accuracy_factor:g} × ({ref} / "
        f"rate); **✗** otherwise. Below each table, the time-indexed error of the same "
        f"episodes (the passivity law tracks up to a time offset: judge it by the first).",
        "",
    ]
    for robot in cfg.robots:
        for dist in cfg.disturbances:
            sub = table[(table["robot"] == robot) & (table["disturbance"] == dist)]
            if sub.empty:
                continue
            verdicts, times = {}, {}
            for ctrl in cfg.controllers:
                cells = [_cell(sub, ctrl, hz) for hz in cfg.control_rates]
                verdicts[ctrl] = [_verdict_text(r) for r in cells]
                times[ctrl] = ["" if r is None else f"{r['time_err_median']:.2e}" for r in cells]
            lines += [f"## {robot}, {dist}", "", *_md_table(rates, verdicts), ""]
            lines += ["Time-indexed error, median RMS (rad):", "", *_md_table(rates, times), ""]
    held = table.groupby(["controller", "control_hz"])["holds"].all()
    marks = {
        c: ["✓" if held.get((c, hz), False) else "✗" for hz in cfg.control_rates]
        for c in cfg.controllers
    }
    lines += ["## Where each controller holds", "", *_md_table(rates, marks), ""]
    lines += [f"(✓: holds on every robot and under every preset above; {len(df)} episodes.)", ""]
    (out / "report.md").write_text("\n".join(lines))
    if cfg.plots:
        rates_figure(cfg, table, out / f"rates_{cfg.metric}.png")


def load_config(path: Path | None, overrides: Sequence[str]) -> RatesConfig:
    """The config of a YAML file, with ``key=value`` overrides; unknown keys raise."""
    return arguments.load_config(RatesConfig, path, overrides, validate=False)
