"""Evaluate controllers under the same random disturbances: ``python -m train.evaluate``.

Runs every controller × disturbance preset × level × seed × episode (``none`` once, at
level 0), **paired**: for a given (seed, episode) every controller meets the same start
state and disturbance schedule. Writes to ``--out``:

* ``config.yml`` — the full resolved configuration, and ``command.txt``;
* ``episodes.csv`` — one row per episode (metrics of :mod:`ptrack_gym.metrics`),
  appended as episodes finish; ``--resume`` skips the finished ones;
* ``summary.csv`` — per controller × disturbance × level: mean and IQM of the main metric
  with 95% bootstrap intervals, failure rate, paired difference to the reference;
* ``robustness_<metric>.png``, ``failures.png``, ``example_<controller>.png``;
* with ``--video``, ``videos/<controller>/<controller>-episode-0.mp4``: the example
  episode, recorded through Gymnasium's ``RecordVideo`` (headless ``rgb_array``).

Episodes run in ``--workers`` processes (default: the number of cores), or on Ray with
``--backend ray`` (``--ray-address`` for a cluster; a local instance by default).

Configuration: a YAML file (``--config``, default ``train/configs/main.yml``) whose keys
are the fields of :class:`EvalConfig`; any field can be overridden on the command line
with ``--set key=value`` (value parsed as YAML) or its own flag.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import os
import shlex
import sys
from collections.abc import Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from tqdm import tqdm

from ptrack_gym.disturbances import PRESETS
from ptrack_gym.errors import InvalidConfigError, PtrackError
from ptrack_gym.metrics import METRIC_NAMES
from train.eval_episode import (
    SB3_PREFIX,
    EpisodeSettings,
    Task,
    check_sb3_run,
    label,
    run_episode,
)
from train.results import (
    EpisodeWriter,
    done_keys,
    format_table,
    load_frame,
    read_episodes,
    summarize,
)

DEFAULT_CONFIG = Path(__file__).parent / "configs" / "main.yml"


@dataclass
class EvalConfig:
    """An evaluation sweep."""

    env_id: str = "ptrack_gym/TwoLinkTrack-v0"
    """Registered env id."""
    controllers: list[str] = field(
        default_factory=lambda: ["passivity", "computed_torque", "pd_gravity", "slotine_li"]
    )
    """Controller names of ``agents.factory``, or ``sb3:<run folder>`` of ``train.train``."""
    disturbances: list[str] = field(
        default_factory=lambda: ["none", "impulse", "periodic", "payload"]
    )
    """Disturbance presets of ``ptrack_gym.disturbances.PRESETS``."""
    levels: list[float] = field(default_factory=lambda: [0.5, 1.0, 2.0])
    """Levels of every preset but ``none`` (run once, at level 0)."""
    seeds: int = 5
    """Seeds 0..seeds−1."""
    episodes_per_seed: int = 1
    """Episodes per seed (reset seeds 10 000·seed + episode)."""
    episode_s: float = 6.0
    """Episode length (s)."""
    control_hz: float = 1000.0
    """Control rate (Hz); physics runs at 1 kHz."""
    start: str = "on_path"
    """Start mode of the env ("on_path" or "rest_near_path")."""
    reference: str = "computed_torque"
    """Controller the paired differences are taken against."""
    metric: str = "path_dist_rms"
    """Main metric of the summary and the robustness plot."""
    failure_distance_rad: float = 0.5
    """An episode fails if the path distance ever exceeds this (rad), or it goes unstable."""
    recovery_threshold_rad: float = 0.01
    """Path distance (rad) below which an arm counts as recovered after an impulse."""
    bootstrap_resamples: int = 2000
    """Bootstrap resamples of every confidence interval."""
    workers: int = 0
    """Worker processes (0: the number of cores)."""
    backend: str = "process"
    """"process" or "ray"."""
    ray_address: str | None = None
    """Ray cluster address (None: start a local instance)."""
    out: str = "results/main"
    """Output folder."""
    plots: bool = True
    """Write the PNG figures."""
    video: bool = False
    """Record one episode per controller as MP4 (``videos/``; needs the ``video`` extra)."""

    def validate(self) -> None:
        """Raise :class:`InvalidConfigError` naming the first bad field."""
        from agents.factory import CONTROLLER_NAMES

        for c in self.controllers:
            if c.startswith(SB3_PREFIX):
                check_sb3_run(c, self.env_id)
            elif c not in CONTROLLER_NAMES:
                raise InvalidConfigError(
                    f"controllers: unknown {c!r}; known {list(CONTROLLER_NAMES)} "
                    "or 'sb3:<run folder>'"
                )
        for d in self.disturbances:
            if d not in PRESETS:
                raise InvalidConfigError(f"disturbances: unknown {d!r}; known {list(PRESETS)}")
        if not self.controllers or not self.disturbances:
            raise InvalidConfigError("controllers and disturbances must not be empty")
        if any(not (np.isfinite(lv) and lv > 0) for lv in self.levels):
            raise InvalidConfigError(f"levels must be positive, got {self.levels}")
        if self.seeds < 1 or self.episodes_per_seed < 1:
            raise InvalidConfigError("seeds and episodes_per_seed must be >= 1")
        for name in ("controllers", "disturbances", "levels"):
            values = [f"{v:g}" if name == "levels" else v for v in getattr(self, name)]
            if len(set(values)) != len(values):
                raise InvalidConfigError(f"{name} has duplicates: {getattr(self, name)}")
        if self.metric not in METRIC_NAMES:
            raise InvalidConfigError(f"metric {self.metric!r} is not one of {list(METRIC_NAMES)}")
        if self.start not in ("on_path", "rest_near_path"):
            raise InvalidConfigError(
                f"start must be 'on_path' or 'rest_near_path', got {self.start!r}"
            )
        ratio = 1000.0 / self.control_hz if self.control_hz > 0 else float("nan")
        if not (np.isfinite(ratio) and ratio >= 1 and abs(ratio - round(ratio)) < 1e-9):
            raise InvalidConfigError(
                f"control_hz must divide the 1000 Hz physics rate, got {self.control_hz}"
            )
        if self.backend not in ("process", "ray"):
            raise InvalidConfigError(f"backend must be 'process' or 'ray', got {self.backend!r}")
        if self.reference not in self.controllers:
            raise InvalidConfigError(f"reference {self.reference!r} is not among the controllers")
        if not self.episode_s > 0:
            raise InvalidConfigError("episode_s must be positive")
        if self.backend == "ray":
            require_extra("ray", "ray", "backend: ray")
        if self.video:
            require_extra("moviepy", "video", "video: true")

    def settings(self) -> EpisodeSettings:
        return EpisodeSettings(
            env_id=self.env_id,
            episode_s=self.episode_s,
            control_hz=self.control_hz,
            start=self.start,
            failure_distance_rad=self.failure_distance_rad,
            recovery_threshold_rad=self.recovery_threshold_rad,
        )

    def tasks(self) -> list[Task]:
        """Every episode of the sweep, in a fixed order."""
        conditions = [("none", 0.0)] if "none" in self.disturbances else []
        conditions += [
            (d, float(lv)) for d in self.disturbances if d != "none" for lv in self.levels
        ]
        return [
            Task(c, d, lv, s, e)
            for d, lv in conditions
            for s in range(self.seeds)
            for e in range(self.episodes_per_seed)
            for c in self.controllers
        ]


def require_extra(module: str, extra: str, what: str) -> None:
    """Raise :class:`InvalidConfigError` if the optional ``module`` (of the package extra
    ``extra``) is not installed, naming the option that needs it."""
    if importlib.util.find_spec(module) is None:
        raise InvalidConfigError(
            f"{what} needs the optional '{extra}' extra ({module} is not installed): "
            f"pip install 'ptrack_gym[{extra}]'"
        )


def load_config(path: Path | None, overrides: Sequence[str]) -> EvalConfig:
    """The config of a YAML file, with ``key=value`` overrides; unknown keys raise."""
    data: dict[str, Any] = {}
    if path is not None:
        data = yaml.safe_load(path.read_text()) or {}
    for item in overrides:
        if "=" not in item:
            raise InvalidConfigError(f"--set expects key=value, got {item!r}")
        key, value = item.split("=", 1)
        data[key.strip()] = yaml.safe_load(value)
    known = {f.name for f in dataclasses.fields(EvalConfig)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise InvalidConfigError(f"unknown config key(s) {unknown}; known: {sorted(known)}")
    cfg = EvalConfig(**data)
    cfg.validate()
    return cfg


def _worker_init() -> None:
    """Keep each worker on one thread: the parallelism is across episodes."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")


def _run_processes(
    tasks: list[Task], settings: EpisodeSettings, workers: int, example: set[Task]
) -> Iterator[tuple[dict[str, Any], Any, Task]]:
    if workers == 1:
        for task in tasks:
            row, trace = run_episode(task, settings, task in example)
            yield row, trace, task
        return
    import multiprocessing as mp

    ctx = mp.get_context("spawn")  # no PyBullet client or thread is inherited
    pool = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_worker_init)
    try:
        pending = {pool.submit(run_episode, t, settings, t in example): t for t in tasks}
        while pending:
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                task = pending.pop(fut)
                row, trace = fut.result()  # a failed episode raises here...
                yield row, trace, task
    finally:  # ...and the queued ones are cancelled, not run for nothing
        pool.shutdown(wait=True, cancel_futures=True)


def _run_ray(
    tasks: list[Task],
    settings: EpisodeSettings,
    workers: int,
    address: str | None,
    example: set[Task],
) -> Iterator[tuple[dict[str, Any], Any, Task]]:
    import ray  # validate() checked that the extra is installed

    started = not ray.is_initialized()
    if started:
        if address:
            ray.init(address=address, include_dashboard=False, log_to_driver=False)
        else:
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
    remote = ray.remote(num_cpus=1)(run_episode)
    refs = {remote.remote(t, settings, t in example): t for t in tasks}
    try:
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1)
            for ref in done:
                task = refs.pop(ref)
                row, trace = ray.get(ref)
                yield row, trace, task
    finally:
        if started:
            ray.shutdown()


def run_sweep(
    cfg: EvalConfig,
    resume: bool = False,
    progress: bool = True,
    show: bool = True,
    module: str = "train.evaluate",
) -> Path:
    """Run (or resume) the sweep of ``cfg``; return the output folder. ``show`` prints
    the summary table; ``module`` names the entry point recorded in ``command.txt``."""
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    episodes = out / "episodes.csv"
    if episodes.exists() and episodes.stat().st_size > 0 and not resume:
        raise InvalidConfigError(
            f"{episodes} exists: pass --resume to continue it, or another --out"
        )
    finished = done_keys(read_episodes(episodes))  # validates the file before anything runs
    if finished:
        _check_same_sweep(cfg, out / "config.yml")
    (out / "config.yml").write_text(yaml.safe_dump(dataclasses.asdict(cfg), sort_keys=False))
    (out / "command.txt").write_text(
        shlex.join([sys.executable, "-m", module, *sys.argv[1:]]) + "\n"
    )
    tasks = [t for t in cfg.tasks() if t.key() not in finished]
    example_condition = _example_condition(cfg)
    example = {
        t for t in cfg.tasks() if (t.disturbance, t.level, t.seed, t.episode) == example_condition
    }
    workers = cfg.workers or len(os.sched_getaffinity(0))
    settings = cfg.settings()
    writer = EpisodeWriter(episodes)
    traces: dict[str, Any] = {}
    try:
        runner = (
            _run_ray(tasks, settings, workers, cfg.ray_address, example)
            if cfg.backend == "ray"
            else _run_processes(tasks, settings, workers, example)
        )
        for row, trace, task in tqdm(
            runner, total=len(tasks), disable=not progress, desc="episodes"
        ):
            writer.write(row)
            if trace is not None:
                np.savez_compressed(out / f"trace_{label(task.controller)}.npz", **trace)
                traces[task.controller] = trace
    finally:
        writer.close()
    _finish(cfg, out, show)
    return out


#: Config fields that do not change any episode's numbers: a resume may change them.
_RUN_ONLY_FIELDS = ("out", "workers", "backend", "ray_address", "plots", "video",
                    "bootstrap_resamples", "reference")  # fmt: skip


def _check_same_sweep(cfg: EvalConfig, saved: Path) -> None:
    """Refuse to resume a sweep whose saved config differs in a field that changes results
    (the rows would mix episodes of different settings)."""
    if not saved.exists():
        raise InvalidConfigError(
            f"{saved} is missing: cannot check that --resume continues the same sweep"
        )
    old = yaml.safe_load(saved.read_text()) or {}
    new = dataclasses.asdict(cfg)
    changed = sorted(k for k in new if k not in _RUN_ONLY_FIELDS and k in old and old[k] != new[k])
    if changed:
        diffs = ", ".join(f"{k} {old[k]!r} -> {new[k]!r}" for k in changed)
        raise InvalidConfigError(f"--resume with a different sweep: {diffs}; use another --out")


def _example_condition(cfg: EvalConfig) -> tuple[str, float, int, int]:
    """The (disturbance, level, seed, episode) whose episodes are plotted: the first
    disturbed preset at its middle level, seed 0."""
    disturbed = [d for d in cfg.disturbances if d != "none"]
    if not disturbed:
        return ("none", 0.0, 0, 0)
    levels = sorted(cfg.levels)
    return (disturbed[0], float(levels[len(levels) // 2]), 0, 0)


def _finish(cfg: EvalConfig, out: Path, show: bool = True) -> None:
    df = load_frame(out / "episodes.csv")
    wanted = {t.key() for t in cfg.tasks()}
    keys = df[["controller", "disturbance", "level", "seed", "episode"]].astype(str)
    keys["level"] = df["level"].map(lambda v: f"{v:g}")
    df = df[[tuple(r) in wanted for r in keys.itertuples(index=False)]]
    summary = summarize(df, cfg.metric, cfg.reference, cfg.bootstrap_resamples)
    summary.to_csv(out / "summary.csv", index=False)
    table = format_table(summary, cfg.metric)
    (out / "summary.md").write_text(table + "\n")
    if show:
        print(table)
    if cfg.plots:
        from train.plots import example_plot, failure_plot, robustness_plot

        robustness_plot(summary, cfg.metric, out / f"robustness_{cfg.metric}.png")
        failure_plot(df, out / "failures.png")
        cond = _example_condition(cfg)
        for ctrl in cfg.controllers:
            path = out / f"trace_{label(ctrl)}.npz"
            if path.exists():
                with np.load(path) as z:
                    trace = {k: z[k] for k in z.files}
                example_plot(
                    trace,
                    f"{ctrl}: {cond[0]} level {cond[1]:g}, seed 0",
                    out / f"example_{label(ctrl)}.png",
                )
    if cfg.video:
        from train.video import record_episode

        dist, level, seed, episode = _example_condition(cfg)
        for ctrl in [c for c in cfg.controllers if not c.startswith(SB3_PREFIX)]:
            record_episode(
                cfg.env_id,
                ctrl,
                out / "videos" / ctrl,
                seed=Task(ctrl, dist, level, seed, episode).reset_seed,
                env_kwargs={
                    "control_hz": cfg.control_hz,
                    "start": cfg.start,
                    "disturbance": None if dist == "none" else (dist, level),
                    "horizon_s": cfg.episode_s,
                    "max_episode_steps": round(cfg.episode_s * cfg.control_hz),
                },
            )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m train.evaluate", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG, help="YAML config file")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config field (value parsed as YAML); repeatable",
    )
    parser.add_argument("--out", help="output folder (overrides the config)")
    parser.add_argument("--workers", type=int, help="worker processes (0: cores)")
    parser.add_argument("--backend", choices=["process", "ray"])
    parser.add_argument("--ray-address", help="Ray cluster address")
    parser.add_argument("--resume", action="store_true", help="continue an interrupted sweep")
    parser.add_argument("--video", action="store_true", help="record one MP4 per controller")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    overrides = list(args.set)
    if args.video:
        overrides.append("video=true")
    for name in ("out", "workers", "backend", "ray_address"):
        value = getattr(args, name)
        if value is not None:
            overrides.append(f"{name}={value}")
    try:
        cfg = load_config(args.config, overrides)
        run_sweep(cfg, resume=args.resume, progress=not args.no_progress)
    except PtrackError as exc:  # bad config, corrupt results: a clear message, exit 2
        parser.error(str(exc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
