"""Run an evaluation sweep: episodes in worker processes or on Ray, results appended as
they finish, then the summary, plots and video.

:func:`run_sweep` is what ``ptrack evaluate`` runs for an
:class:`~train.evaluation.config.EvalConfig`. With ``workers`` > 1 this process runs
episodes too, beside ``workers − 1`` worker processes (one thread each): forked from this
one where that is safe (:func:`train.common.runs.start_method`), else spawned, importing
only :mod:`train.evaluation.episode` and what an episode needs.
"""

from __future__ import annotations

import dataclasses
import sys
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import (
    FIRST_COMPLETED,
    Future,
    ProcessPoolExecutor,
    ThreadPoolExecutor,
    wait,
)
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from ptrack_gym.robots import profile_for_env_id
from train.common.runs import saved_whole, worker_count, worker_pool
from train.evaluation.config import EvalConfig
from train.evaluation.episode import (
    KEY_COLUMNS,
    SB3_PREFIX,
    EpisodeSettings,
    Task,
    label,
    run_episode,
    settings_kwargs,
)
from train.evaluation.rate_record import open_recorded_run, rate_record
from train.evaluation.results import (
    COLUMNS,
    EpisodeWriter,
    done_keys,
    format_table,
    headline_tables,
    load_frame,
    read_episodes,
    summarize,
)


def _run_processes(
    tasks: list[Task],
    settings: EpisodeSettings,
    workers: int,
    example: set[Task],
    pool: ProcessPoolExecutor | None = None,
) -> Iterator[tuple[dict[str, Any], Any, Task]]:
    """Run ``tasks`` on ``workers`` processes: this one and ``workers − 1`` worker processes
    (``pool``'s, if given — the caller then shuts it down — else a pool of its own, started
    by :func:`start_method`).

    This process runs episodes too (in a thread, while its main thread hands out tasks and
    collects results), so it starts at once, while spawned workers import; every runner
    takes its next task from one queue when it finishes one, each worker process holding
    at most one more in reserve. Results are yielded as they finish (any order;
    an episode's numbers never depend on where it ran — tested)."""
    if workers == 1:
        for task in tasks:
            row, trace = run_episode(task, settings, task in example)
            yield row, trace, task
        return
    own_pool = pool is None
    if pool is None:
        pool = worker_pool(workers - 1)
    local = ThreadPoolExecutor(1, thread_name_prefix="episodes")
    todo = deque(tasks)
    pending: dict[Future[tuple[dict[str, Any], Any]], tuple[Task, bool]] = {}
    spawned_busy = 0  # tasks given to the worker processes and not yet back
    local_busy = False
    try:
        while todo or pending:
            while todo and spawned_busy < 2 * (workers - 1):  # one running, one in reserve
                task = todo.popleft()
                pending[pool.submit(run_episode, task, settings, task in example)] = (task, True)
                spawned_busy += 1
            if todo and not local_busy:
                task = todo.popleft()
                pending[local.submit(run_episode, task, settings, task in example)] = (task, False)
                local_busy = True
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                task, spawned = pending.pop(fut)
                if spawned:
                    spawned_busy -= 1
                else:
                    local_busy = False
                row, trace = fut.result()  # a failed episode raises here...
                yield row, trace, task
    finally:  # ...and the queued ones are cancelled, not run for nothing
        todo.clear()
        for fut in pending:
            fut.cancel()
        if own_pool:
            pool.shutdown(wait=True, cancel_futures=True)
        local.shutdown(wait=True, cancel_futures=True)


def _run_ray(
    tasks: list[Task],
    settings: EpisodeSettings,
    workers: int,
    address: str | None,
    example: set[Task],
) -> Iterator[tuple[dict[str, Any], Any, Task]]:
    from train.common.ray_tasks import ray_results

    jobs = [(t, settings, t in example) for t in tasks]
    for (task, _, _), (row, trace) in ray_results(run_episode, jobs, workers, address):
        yield row, trace, task


def run_sweep(
    cfg: EvalConfig,
    resume: bool = False,
    progress: bool = True,
    show: bool = True,
    force: bool = False,
    rerun_changed: bool = False,
) -> Path:
    """Run (or resume) the sweep of ``cfg``; return the output folder. ``show`` prints
    the headline table; ``force`` starts over in a folder that holds files
    (:func:`train.common.runs.open_run`). ``config.yml`` records the rates every
    model-based controller ran with (:mod:`train.evaluation.rate_record`): a resume after
    they changed is refused, or with ``rerun_changed`` reruns exactly those controllers'
    rows."""
    for line in cfg.base_gain_mismatches():
        print(f"warning: {line}", file=sys.stderr, flush=True)
    robot = profile_for_env_id(cfg.env_id).name
    run = open_recorded_run(
        cfg.out, "episodes.csv", dataclasses.asdict(cfg),
        rate_record([robot], cfg.controllers, cfg.gains, cfg.controller_rates),
        resume=resume, force=force,
        rerun_changed=rerun_changed, free=RUN_ONLY_FIELDS, columns=COLUMNS,
        key_columns=KEY_COLUMNS, pair_of=lambda row: (robot, row["controller"]),
    )  # fmt: skip
    out, episodes = run.out, run.results
    finished = done_keys(read_episodes(episodes))  # validates the file before anything runs
    tasks = [t for t in cfg.tasks() if t.key() not in finished]
    example_condition = _example_condition(cfg)
    example = {
        t for t in cfg.tasks() if (t.disturbance, t.level, t.seed, t.episode) == example_condition
    }
    workers = worker_count(cfg.workers)
    settings = cfg.settings()
    # The worker processes outlive the episodes: they draw the plots while this process
    # writes the report.
    pool = (
        worker_pool(workers - 1, cfg.start_method)
        if cfg.backend == "process" and workers > 1
        else None
    )
    drawn: dict[str, Future[None]] = {}  # example figures already handed to the pool
    try:
        writer = EpisodeWriter(episodes)
        try:
            runner = (
                _run_ray(tasks, settings, workers, cfg.ray_address, example)
                if cfg.backend == "ray"
                else _run_processes(tasks, settings, workers, example, pool)
            )
            for row, trace, task in tqdm(
                runner, total=len(tasks), disable=not progress, desc="episodes"
            ):
                if trace is not None:  # whole, and before its row: a resume redoes both
                    _save_trace(_trace_path(out, task.controller), trace)
                writer.write(row)
                if trace is not None:
                    if cfg.plots and pool is not None:  # drawn now, among the episodes
                        drawn[task.controller] = pool.submit(
                            *_example_figure(cfg, out, task.controller)
                        )
        finally:
            writer.close()
        finish(cfg, out, show, pool, drawn)
    finally:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
    return out


#: Config fields that do not change any episode's numbers: a resume may change them.
RUN_ONLY_FIELDS = ("out", "workers", "backend", "start_method", "ray_address", "plots", "video",
                    "bootstrap_resamples", "reference", "worst_case")  # fmt: skip


def _example_condition(cfg: EvalConfig) -> tuple[str, float, int, int]:
    """The (disturbance, level, seed, episode) whose episodes are plotted: the first
    disturbed preset at its middle level, seed 0."""
    disturbed = [d for d in cfg.disturbances if d != "none"]
    if not disturbed:
        return ("none", 0.0, 0, 0)
    levels = sorted(cfg.levels)
    return (disturbed[0], float(levels[len(levels) // 2]), 0, 0)


def _save_trace(path: Path, trace: dict[str, Any]) -> None:
    """``np.savez_compressed``, renamed into place (:func:`~train.common.runs.saved_whole`):
    an interrupted sweep leaves no cut trace behind the row it records."""

    def save(tmp: Path) -> None:
        with tmp.open("wb") as f:
            np.savez_compressed(f, **trace)

    saved_whole(path, save)


def _trace_path(out: Path, controller: str) -> Path:
    """Where the sweep in ``out`` saves ``controller``'s example episode (its trace)."""
    return out / f"trace_{label(controller)}.npz"


def _example_figure(
    cfg: EvalConfig, out: Path, controller: str
) -> tuple[Callable[..., None], Path, str, Path]:
    """(draw, trace file, title, figure file) of ``controller``'s example episode."""
    from train.plots.evaluation import example_plot_file

    cond = _example_condition(cfg)
    return (
        example_plot_file,
        _trace_path(out, controller),
        f"{controller}: {cond[0]} level {cond[1]:g}, seed 0",
        out / f"example_{label(controller)}.png",
    )


def finish(
    cfg: EvalConfig,
    out: Path,
    show: bool = True,
    pool: ProcessPoolExecutor | None = None,
    drawn: dict[str, Future[None]] | None = None,
) -> None:
    """Summary, report, plots and video of the sweep in ``out``. With a ``pool``, its
    processes draw the plots while this one writes the summary and the report (the same
    files: each plot is a function of the results alone); ``drawn`` holds the example
    figures handed to it already, as their episodes finished."""
    df = load_frame(out / "episodes.csv")
    wanted = {t.key() for t in cfg.tasks()}
    keys = df[["controller", "disturbance", "level", "seed", "episode"]].astype(str)
    keys["level"] = df["level"].map(lambda v: f"{v:g}")
    df = df[[tuple(r) in wanted for r in keys.itertuples(index=False)]]
    plots: list[Future[None]] = []

    def draw(fn: Callable[..., None], *args: Any) -> None:
        if pool is None:
            fn(*args)
        else:
            plots.append(pool.submit(fn, *args))

    if cfg.plots:
        from train.plots.evaluation import failure_plot, robustness_plot

        draw(failure_plot, df, out / "failures.png")
        for ctrl in cfg.controllers:
            if drawn and ctrl in drawn:
                plots.append(drawn[ctrl])
            elif _trace_path(out, ctrl).exists():  # e.g. saved before a resume
                draw(*_example_figure(cfg, out, ctrl))
    summary = summarize(df, cfg.metric, cfg.reference, cfg.bootstrap_resamples)
    summary.to_csv(out / "summary.csv", index=False, float_format="%.17g")
    table = format_table(summary, cfg.metric)
    (out / "summary.md").write_text(table + "\n")
    if cfg.plots:
        draw(robustness_plot, summary, cfg.metric, out / f"robustness_{cfg.metric}.png")
    from train.evaluation.report import write_report

    own = "; ".join(f"{c} with {dict(r)}" for c, r in sorted(cfg.controller_rates.items()))
    write_report(
        df, out, cfg.metric, cfg.reference, cfg.worst_case,
        title=cfg.env_id + (f" ({cfg.gains} gains; {own})" if own else ""),
        figures=cfg.plots, draw=draw,
    )  # fmt: skip
    if pool is not None:  # no more work: the workers exit after their plots (the caller's
        pool.shutdown(wait=False)  # shutdown joins them)
    if show:
        print(f"\n{out / 'report.md'}:\n")
        print(headline_tables(summary, cfg.metric))
    for fut in plots:
        fut.result()  # a failed plot raises here
    if cfg.video:
        from train.evaluation.video import record_episode

        dist, level, seed, episode = _example_condition(cfg)
        settings = cfg.settings()
        for ctrl in [c for c in cfg.controllers if not c.startswith(SB3_PREFIX)]:
            record_episode(  # the sweep's path, sizing and gains (its own rates included)
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
                    **settings_kwargs(settings),
                },
                gains=settings.controller_gains(ctrl, profile_for_env_id(cfg.env_id).name),
            )
