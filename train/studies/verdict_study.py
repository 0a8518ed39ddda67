"""The verdict across robots and paths: ``ptrack verdict``.

Every robot × random admissible test path × controller × (disturbance preset, level) × seed,
one episode each at ``control_hz``, started on the path, every model-based controller at
``gains`` (``tuned``: its gains of ``agents/tuned/<robot>-<controller>.yml``, tuned on
*validation* paths — the study refuses test paths a tuning ran on). The env's reset seed and
disturbance stream depend on (seed, episode) only, so the same (path, seed) meets every
controller: the unit of every test is a (path, seed) pair.

Writes to ``--out``:

* ``config.yml``, ``command.txt``;
* ``episodes.csv`` — one row per episode (``robot``, ``path``, the evaluation's key columns
  and metrics), appended as episodes finish; ``--resume`` skips the finished ones;
* ``rivals.csv`` — per robot, condition and metric (path distance and time-indexed error),
  the passivity controller against its strongest rival there (the lowest mean that is not a
  passivity variant): the exact paired sign-flip test over the (path, seed) pairs, Holm's
  step-down over the robot's conditions per metric (:func:`train.evaluation.verdict.
  rival_comparisons`), and "wins", "ties" or "loses";
* ``paths.csv`` — per robot, test path and metric, the same test on that path's pairs alone
  (its strongest rival per condition, Holm over the robot's conditions): where the focus
  wins, ties and loses path by path, beside the path's period and amplitude
  (:func:`train.studies.verdict_paths.path_outcomes`);
* ``verdict.png`` — per robot, focus / rival in every condition under both metrics, marked
  by the outcome (:func:`train.plots.studies.verdict_plot`);
* ``aggregates.csv`` — per robot, condition and controller, the mean of each metric over
  paths of the per-path means over seeds, with a two-stage bootstrap interval (paths, then
  seeds: :func:`train.common.statistics.hierarchical_bootstrap`), and the failed episodes;
* ``verdict.md`` — the table across robots (wins / ties / losses per robot and metric), then
  per robot the rival table and a ranking.

Episodes run in ``workers`` processes (0: the cores).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd
import yaml

from agents.registry import GAIN_CHOICES, TUNED_DIR, tuned_rates
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.metrics import METRIC_NAMES
from ptrack_gym.robots import ROBOTS
from train.common import arguments
from train.common.checks import check_counts, check_known, check_lists, check_path_seeds
from train.common.paired_tests import TooFewPairsError
from train.common.statistics import hierarchical_bootstrap
from train.evaluation.config import require_extra
from train.evaluation.envs import check_env_kwargs, env_kwargs
from train.evaluation.episode import EpisodeSettings, Task, run_episode
from train.evaluation.rate_record import open_recorded_run, rate_record
from train.evaluation.results import read_episodes
from train.evaluation.verdict import (
    BOTH_METRICS,
    condition_name,
    condition_order,
    grid_table,
    ranking_table,
    rival_comparisons,
    rival_table,
    words,
)
from train.studies.rows import run_rows
from train.studies.verdict_entrants import TANK_COLUMNS, EpisodeBalance
from train.studies.verdict_paths import FOCUS, path_outcomes, path_table

KEY_COLUMNS = ("robot", "path", "controller", "disturbance", "level", "seed", "episode")
COLUMNS = (*KEY_COLUMNS, *METRIC_NAMES, "steps", "wall_s")
#: A study with entrants also records each episode's energy tank (NaN without one).
ENTRANT_COLUMNS = (*COLUMNS, *TANK_COLUMNS)
#: The controller the verdict is about.


@dataclass
class VerdictConfig:
    """The verdict study (the fields of ``--config`` / ``--set``)."""

    robots: list[str] = field(default_factory=lambda: ["two_link", "iiwa", "panda", "xarm6"])
    """Robots (keys of ``ptrack_gym.robots.ROBOTS``)."""
    controllers: list[str] = field(
        default_factory=lambda: [
            "passivity", "passivity_paper", "computed_torque", "pd_gravity", "slotine_li",
            "pid_gravity", "computed_torque_observer", "adaptive_slotine_li",
            "computed_torque_path",
        ]
    )  # fmt: skip
    """Controllers of ``agents.registry`` (the focus, ``passivity``, among them)."""
    gains: str = "tuned"
    """"tuned" (``agents/tuned``: every robot × controller must have a file) or "default"."""
    entrants: dict[str, list[str]] = field(default_factory=dict)
    """Learned entrants per robot, ``{robot: ["sb3:<run folder>", …]}``: judged on the same
    test paths (never their training or evaluation paths) against their reference, not as
    rivals of the passivity controller (:mod:`train.studies.verdict_entrants`)."""
    test_paths: list[int] = field(default_factory=lambda: list(range(1, 9)))
    """Seeds of the random admissible test paths (each robot draws its own path per seed)."""
    disturbances: list[str] = field(
        default_factory=lambda: [
            "none", "impulse", "push", "periodic", "payload", "noise", "mismatch", "delay",
        ]
    )  # fmt: skip
    """Presets of ``ptrack_gym.disturbances.PRESETS`` ("none": undisturbed, one level)."""
    levels: list[float] = field(default_factory=lambda: [1.0, 2.0])
    """Levels of every preset but ``none``."""
    levels_of: dict[str, list[float]] = field(default_factory=dict)
    """Per preset, its levels in place of ``levels`` (``{mismatch: [1.0, 2.0]}``)."""
    seeds: int = 10
    """Episodes per path and condition: seeds 0 … ``seeds`` − 1 (reset seed 10 000·seed)."""
    episode_s: float = 8.0
    """Episode length (s)."""
    control_hz: float = 1000.0
    """Control rate (Hz; the physics runs at 1 kHz)."""
    failure_distance_rad: float = 0.5
    """An episode fails if the path distance ever exceeds this (rad), or it goes unstable."""
    resamples: int = 20_000
    """Sign patterns of the Monte Carlo sign-flip test beyond 26 pairs, and resamples of the
    hierarchical bootstrap (at most 2 000 of those)."""
    workers: int = 0
    """Episode runners (0: the number of cores)."""
    backend: str = "process"
    """"process" (a pool of ``workers`` processes) or "ray" (Ray tasks: the ``ray`` extra)."""
    ray_address: str | None = None
    """With ``backend: ray``, the address of a running cluster; None: a local instance of
    ``workers`` CPUs."""
    out: str = "results/verdict"
    """Output folder."""

    def validate(self) -> None:
        """Raise :class:`InvalidConfigError` naming the first bad field, before any episode:
        bad lists, an unknown robot, controller or preset, a preset a robot cannot take at a
        level (or that does not fit the episode), a test path seed that gives a robot no
        admissible path, missing tuned gains, or tuned gains chosen on a test path."""
        check_lists(self, ("robots", "controllers", "disturbances", "test_paths"))
        check_known(self.robots, self.controllers, self.disturbances)
        if any(d != "none" for d in self.disturbances) and not self.levels:
            raise InvalidConfigError("levels must not be empty when a preset is disturbed")
        if not isinstance(self.levels_of, dict) or not set(self.levels_of) <= set(
            self.disturbances
        ) - {"none"}:
            raise InvalidConfigError(f"levels_of: presets of disturbances, got {self.levels_of}")
        for levels in (self.levels, *self.levels_of.values()):
            if not isinstance(levels, list) or not levels or not all(
                isinstance(lv, (int, float)) and not isinstance(lv, bool)
                and math.isfinite(lv) and lv > 0 for lv in levels
            ):  # fmt: skip
                raise InvalidConfigError(f"levels must be positive numbers, got {levels}")
        for p in self.test_paths:
            if isinstance(p, bool) or not isinstance(p, int):
                raise InvalidConfigError(f"test_paths must be integer seeds, got {p!r}")
        check_counts(self, ("seeds", "resamples", "workers"))
        if self.backend not in ("process", "ray"):
            raise InvalidConfigError(f"backend must be 'process' or 'ray', got {self.backend!r}")
        if self.backend == "ray":
            require_extra("ray", "ray", "backend: ray")
        for name in ("episode_s", "control_hz", "failure_distance_rad"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise InvalidConfigError(f"{name} must be a positive number, got {value!r}")
        if self.gains not in GAIN_CHOICES:
            raise InvalidConfigError(f"gains must be one of {GAIN_CHOICES}, got {self.gains!r}")
        steps = max(1, round(self.episode_s * self.control_hz))
        for robot in self.robots:
            env_id = ROBOTS[robot].env_id
            for d, level in self.conditions():
                text = None if d == "none" else f"{d}:{level}"
                try:
                    check_env_kwargs(env_id, env_kwargs(self.control_hz, steps, "on_path", text))
                except InvalidConfigError as exc:
                    raise InvalidConfigError(
                        f"{robot} cannot take {condition_name(d, level)}: {exc}"
                    ) from exc
            check_path_seeds(
                ROBOTS[robot].env_id, self.test_paths, f"test path seed {{seed}} on {robot}"
            )
            if self.gains == "tuned":
                for c in self.controllers:
                    tuned_rates(robot, c)  # raises naming the missing file
                    tuned_on = tuned_validation_paths(robot, c)
                    shared = sorted(tuned_on & set(self.test_paths))
                    if shared:
                        raise InvalidConfigError(
                            f"{c} on {robot} was tuned on paths {shared}, which are test paths "
                            "here: test on other path seeds"
                        )

        if self.entrants:
            from train.studies.verdict_entrants import check_entrants

            check_entrants(
                self.entrants, self.robots, self.controllers, self.test_paths, self.gains,
                self.control_hz,
            )  # fmt: skip

    def conditions(self) -> list[tuple[str, float]]:
        """(preset, level) of every condition: "none" once at level 0, the others at each level."""
        out = [("none", 0.0)] if "none" in self.disturbances else []
        return out + [
            (d, float(lv))
            for d in self.disturbances
            if d != "none"
            for lv in self.levels_of.get(d, self.levels)
        ]

    def tasks(self) -> list[tuple[str, int, Task]]:
        """Every episode: (robot, path seed, task), the controllers (then the robot's
        entrants) innermost (a pair's episodes run side by side, so a partial run holds whole
        pairs)."""
        return [
            (robot, p, Task(c, d, lv, s, 0))
            for robot in self.robots
            for p in self.test_paths
            for d, lv in self.conditions()
            for s in range(self.seeds)
            for c in [*self.controllers, *self.entrants.get(robot, [])]
        ]

    def settings(self, robot: str, path_seed: int) -> EpisodeSettings:
        return EpisodeSettings(
            env_id=ROBOTS[robot].env_id, episode_s=self.episode_s, control_hz=self.control_hz,
            start="on_path", failure_distance_rad=self.failure_distance_rad,
            recovery_threshold_rad=0.01, gains=self.gains, path="random", path_seed=path_seed,
        )  # fmt: skip


def load_config(path: Path | None, overrides: Sequence[str]) -> VerdictConfig:
    """The config of a YAML file, with ``field=value`` overrides; unknown keys raise."""
    return arguments.load_config(VerdictConfig, path, overrides, validate=False)


def tuned_validation_paths(robot: str, controller: str) -> set[int]:
    """The validation path seeds ``controller``'s tuned gains on ``robot`` were chosen on
    (its file's ``study.validation_paths``; empty for a study on the default path)."""
    record = yaml.safe_load((TUNED_DIR / f"{robot}-{controller}.yml").read_text()) or {}
    return {int(p) for p in (record.get("study") or {}).get("validation_paths") or []}


def _key_text(robot: str, path_seed: int, task: Task) -> tuple[str, ...]:
    return (robot, str(path_seed), *task.key())


def columns(cfg: VerdictConfig) -> tuple[str, ...]:
    """The columns of the study's ``episodes.csv``: :data:`ENTRANT_COLUMNS` with entrants,
    else :data:`COLUMNS`."""
    return ENTRANT_COLUMNS if cfg.entrants else COLUMNS


def run_one(cfg: VerdictConfig, robot: str, path_seed: int, task: Task) -> dict[str, Any]:
    """The CSV row of one episode (:func:`columns`)."""
    if not cfg.entrants:
        row = run_episode(task, cfg.settings(robot, path_seed))[0]
    else:
        balance = EpisodeBalance()
        row = run_episode(
            task, cfg.settings(robot, path_seed), inspect=balance.inspect, on_step=balance.on_step
        )[0]
    return {**row, "robot": robot, "path": str(path_seed)}


def run_verdict(
    cfg: VerdictConfig,
    resume: bool = False,
    progress: bool = True,
    force: bool = False,
    rerun_changed: bool = False,
) -> Path:
    """Run (or resume) the study of ``cfg``, then write its report; return the folder.

    ``config.yml`` records the rates every controller ran with (:func:`rate_record`). A
    resume whose gains changed since (a controller tuned again, other defaults) is refused,
    naming the pairs; with ``rerun_changed`` their rows are dropped and run again.
    """
    cfg.validate()
    settings = {
        k: v
        for k, v in dataclasses.asdict(cfg).items()
        if k not in ("workers", "out", "backend", "ray_address")
    }
    run = open_recorded_run(
        cfg.out, "episodes.csv", settings, rate_record(cfg.robots, cfg.controllers, cfg.gains),
        resume=resume, force=force, rerun_changed=rerun_changed, free=("resamples",),
        columns=columns(cfg), key_columns=KEY_COLUMNS,
        pair_of=lambda row: (row["robot"], row["controller"]),
    )  # fmt: skip
    out, episodes = run.out, run.results
    finished = {
        tuple(r[k] for k in KEY_COLUMNS) for r in read_episodes(episodes, columns(cfg), KEY_COLUMNS)
    }
    todo = [t for t in cfg.tasks() if _key_text(*t) not in finished]
    run_rows(run_one, [(cfg, *t) for t in todo], cfg.workers, episodes, columns(cfg),
             progress, cfg.backend, cfg.ray_address)  # fmt: skip
    write_report(cfg, out)
    return out


def load_frame(path: Path, names: Sequence[str] | None = None) -> pd.DataFrame:
    """``episodes.csv`` of a verdict study as a DataFrame, sorted by its key; its columns
    ``names`` (:func:`columns`), by default those its header shows (with or without the
    entrants' tank columns)."""
    if names is None:
        header: list[str] = []
        if path.exists():
            with path.open() as f:
                header = f.readline().strip().split(",")
        names = ENTRANT_COLUMNS if TANK_COLUMNS[0] in header else COLUMNS  # later ones NaN
    rows = read_episodes(path, names, KEY_COLUMNS, fill_missing=True)
    df = pd.DataFrame(rows, columns=list(names))
    for col in (*METRIC_NAMES, *[c for c in TANK_COLUMNS if c in names], "wall_s", "level"):
        df[col] = df[col].astype(float)
    for col in ("steps", "seed", "episode"):
        df[col] = df[col].astype(int)
    return df.sort_values(list(KEY_COLUMNS), kind="stable").reset_index(drop=True)


def rivals(cfg: VerdictConfig, df: pd.DataFrame) -> pd.DataFrame:
    """Per robot and metric, :func:`rival_comparisons` of the focus over the robot's
    conditions (Holm's family: one robot, one metric); pairs are (path, seed, episode)."""
    parts = []
    for robot in cfg.robots:  # the model-based controllers only: entrants are not rivals
        sub = df[(df["robot"] == robot) & df["controller"].isin(cfg.controllers)]
        if sub.empty:
            continue
        for metric in BOTH_METRICS:
            try:
                r = rival_comparisons(sub, metric, FOCUS, resamples=cfg.resamples, seed=0)
            except TooFewPairsError:  # a partial run: the table says "no test yet"
                continue
            if len(r):
                parts.append(r.assign(robot=robot))
    if not parts:
        return pd.DataFrame()
    out = pd.concat(parts, ignore_index=True)
    return out[["robot", *[c for c in out.columns if c != "robot"]]]


def aggregates(cfg: VerdictConfig, df: pd.DataFrame) -> pd.DataFrame:
    """Per robot, condition and controller: the paths, the episodes, the failed ones and,
    per metric, the mean over paths of the per-path means with its hierarchical
    bootstrap interval (95 %)."""
    rows = []
    resamples = min(cfg.resamples, 2000)
    for (robot, dist, level, ctrl), g in df.groupby(
        ["robot", "disturbance", "level", "controller"], sort=True
    ):
        row: dict[str, Any] = {
            "robot": robot, "disturbance": dist, "level": level, "controller": ctrl,
            "paths": g["path"].nunique(), "episodes": len(g), "failed": int(g["failed"].sum()),
        }  # fmt: skip
        for metric in BOTH_METRICS:
            est, lo, hi = hierarchical_bootstrap(
                g[metric].to_numpy(float), g["path"].to_numpy(), resamples, seed=0
            )
            row.update({metric: est, f"{metric}_low": lo, f"{metric}_high": hi})
        rows.append(row)
    return pd.DataFrame(rows)


def across_table(cfg: VerdictConfig, table: pd.DataFrame, df: pd.DataFrame) -> str:
    """Markdown: per robot and metric, the focus's wins, ties and losses against the
    strongest rival over the robot's conditions, and the (path, seed) pairs per condition."""
    lines = [
        "| robot | metric | wins | ties | losses | conditions | paths | pairs per condition "
        "| pairs needed |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for robot in cfg.robots:
        paths = df.loc[df["robot"] == robot, "path"].nunique()
        for metric in BOTH_METRICS:
            t = (
                table[(table["robot"] == robot) & (table["metric"] == metric)]
                if len(table)
                else table
            )
            if not len(t):
                lines.append(
                    f"| {robot} | {words(metric)} | – | – | – | 0 (< 2 pairs) | {paths} | – | – |"
                )
                continue
            counts = t["outcome"].value_counts()
            lines.append(
                f"| {robot} | {words(metric)} | {counts.get('wins', 0)} | {counts.get('ties', 0)} "
                f"| {counts.get('loses', 0)} | {len(t)} | {paths} | {int(t['pairs'].min())}"
                f"–{int(t['pairs'].max())} | {int(t['pairs_needed'].max())} |"
            )
    return "\n".join(lines)


def grid_lines(cfg: VerdictConfig, table: pd.DataFrame, df: pd.DataFrame) -> list[str]:
    """The section of ``verdict.md`` with :func:`grid_table` under each metric."""
    lines = []
    for metric in BOTH_METRICS:
        grid = grid_table(table, cfg.robots, metric, df, FOCUS)
        if grid:
            lines += [
                f"By {words(metric)}, condition by condition: {FOCUS}'s mean over its "
                "strongest rival's, the outcome, and its failed episodes where it had any:",
                "", grid, "",
            ]  # fmt: skip
    return lines


def write_report(cfg: VerdictConfig, out: Path) -> None:
    """``rivals.csv``, ``aggregates.csv`` and ``verdict.md`` from ``out/episodes.csv``."""
    df = load_frame(out / "episodes.csv", columns(cfg))
    if df.empty:
        (out / "verdict.md").write_text("# Verdict across robots and paths\n\nNo episodes yet.\n")
        return
    table = rivals(cfg, df)
    table.to_csv(out / "rivals.csv", index=False, float_format="%.6g")
    agg = aggregates(cfg, df)
    agg.to_csv(out / "aggregates.csv", index=False, float_format="%.6g")
    paths = path_outcomes(cfg.robots, cfg.controllers, cfg.resamples, df)
    paths.to_csv(out / "paths.csv", index=False, float_format="%.6g")
    if len(table):
        from train.plots.studies import verdict_plot

        verdict_plot(table, [r for r in cfg.robots if r in set(table["robot"])],
                     out / "verdict.png", condition_name, condition_order(table))  # fmt: skip
    wall_h = df["wall_s"].sum() / 3600.0
    lines = [
        "# Verdict across robots and paths",
        "",
        f"{len(df)} episodes ({wall_h:.1f} core-hours): robots {', '.join(cfg.robots)}; "
        f"{len(cfg.test_paths)} random test paths each (seeds {cfg.test_paths}); "
        f"{len(cfg.conditions())} conditions (presets {', '.join(cfg.disturbances)} at levels "
        f"{', '.join(f'{lv:g}' for lv in cfg.levels)}"
        + "".join(f", {d} at {', '.join(f'{v:g}' for v in lv)}" for d, lv in cfg.levels_of.items())
        + f"); {cfg.seeds} seeds per path; "
        f"{cfg.control_hz:g} Hz; {cfg.gains} gains.",
        "",
        f"**{FOCUS} against the strongest rival** in each condition (the lowest mean that is "
        "not a passivity variant), per robot and metric: an exact paired sign-flip test over "
        "the (path, seed) pairs, Holm's step-down over the robot's conditions, 5 %. "
        "The rival is picked on the same episodes it is tested on.",
        "",
        across_table(cfg, table, df),
        "",
        *(["![focus / rival per condition](verdict.png)", ""] if len(table) else []),
        *grid_lines(cfg, table, df),
        "Every path holds the same seeds, so the means below (over episodes) are the means "
        "over paths of the per-path means; `aggregates.csv` has them with two-stage "
        "bootstrap intervals (paths, then seeds).",
    ]
    for robot in cfg.robots:
        sub = df[df["robot"] == robot]
        if sub.empty:
            continue
        lines += ["", f"## {robot}", ""]
        t = table[table["robot"] == robot] if len(table) else table
        if len(t):
            lines += [rival_table(t.drop(columns="robot")), ""]
        p = paths[paths["robot"] == robot] if len(paths) else paths
        if len(p):
            lines += [
                "Path by path (each path's own strongest rival per condition, Holm over the "
                "conditions; W / T / L: wins, ties, losses of the focus):", "",
                path_table(p), "",
            ]  # fmt: skip
        failed = sub.groupby("controller")["failed"].sum()
        failed = failed[failed > 0]
        lines.append(
            "Failed episodes: "
            + (", ".join(f"{c} {int(n)}" for c, n in failed.items()) if len(failed) else "none")
            + "."
        )
        lines += ["", ranking_table(sub, BOTH_METRICS)]
    if cfg.entrants:
        from train.studies.verdict_entrants import entrants_section

        lines += entrants_section(cfg.entrants, df, cfg.resamples, out)
    (out / "verdict.md").write_text("\n".join(lines) + "\n")
