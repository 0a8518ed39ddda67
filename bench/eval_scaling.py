"""Episodes per second of the evaluation sweep against the number of worker processes.

The same small sweep (two-link, 2 controllers × 2 presets × ``--seeds`` seeds,
``--episode-s``-second episodes) runs with 1, 2, 4, … workers, up to the cores this
process may use (``os.sched_getaffinity``; the last count is the core count itself when
it is not a power of two), each into a temporary folder, in one run. It prints each
count's wall time, episodes/s, speed-up over one worker and parallel efficiency
(speed-up / workers), and the speed-up of the episodes alone: the sweep's serial tail
(summary, bootstrap intervals, report; about 1 s, the same for every count) timed by
running it once more and taken out. Worker-process start-up is included in both: it is
part of what a user waits for. Each count runs ``--repeats`` times, the counts alternating
(1, 2, …, 1, 2, …), and the table gives each count's median wall time: single timings
of the small sweep on this 2-core VM spread by ±3% (its 2-worker speed-up 1.77–1.87 in
five runs of one worker count each).

Every sweep is a fresh ``ptrack evaluate`` process, as a user runs it (interpreter
start and imports included, nothing warm from an earlier sweep). Counts above 1 are timed
once per ``--start-methods`` entry (default: ``fork`` — what ``start_method: auto`` picks
for that command on Linux, Python >= 3.11: :func:`train.common.runs.start_method` — and
``spawn``), so the two ways of starting the workers are compared in the same run; a second
table gives what one worker costs before its first episode under each (in a fresh process
that has imported what the CLI imports and run no episode, ``--repeats`` times).

Run: ``python bench/eval_scaling.py [--seeds 24] [--episode-s 8] [--repeats 3]
[--max-workers N] [--start-methods fork spawn] [--config train/configs/evaluate/main.yml]``
(``--config``: that sweep instead, plots off).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from train.common.threads import ONE_THREAD_VARS
from train.evaluation.config import load_config
from train.evaluation.sweep import finish


def worker_counts(cores: int) -> list[int]:
    """1, 2, 4, … up to ``cores``, ending with ``cores`` itself."""
    counts = [1]
    while counts[-1] * 2 <= cores:
        counts.append(counts[-1] * 2)
    if counts[-1] != cores:
        counts.append(cores)
    return counts


def sweep_seconds(
    workers: int,
    seeds: int,
    episode_s: float,
    folder: Path,
    config: Path | None = None,
    method: str = "auto",
) -> tuple[float, float, int]:
    """Wall time (s) of ``ptrack evaluate`` running the benchmark sweep (or the
    sweep of ``config``, without plots) with ``workers`` processes started by ``method``,
    in a fresh process as a user runs it (interpreter start and imports included, nothing
    warm from an earlier run); the time (s) of its serial tail (summary, bootstrap
    intervals, report: timed here by running it once more) and the episode count."""
    small = [
        "env_id=ptrack_gym/TwoLinkTrack-v0",
        "controllers=[computed_torque, passivity]",
        "disturbances=[impulse, periodic]",
        "levels=[1.0]",
        f"seeds={seeds}",
        f"episode_s={episode_s}",
    ]
    run = [
        "plots=false",
        f"workers={workers}",
        f"start_method={method}",
        f"out={folder / f'w{workers}'}",
    ]
    overrides = run if config is not None else [*small, *run]
    cfg = load_config(config, overrides)
    argv = [sys.executable, "-m", "train.evaluate", "--no-progress"]
    if config is not None:
        argv += ["--config", str(config)]
    for item in overrides:
        argv += ["--set", item]
    t0 = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    t0 = time.perf_counter()
    finish(cfg, Path(cfg.out), show=False)  # the serial tail again: report, bootstrap
    return wall, time.perf_counter() - t0, len(cfg.tasks())


_START_PROBE = """
import sys, time
from train.evaluation.episode import run_episode
from train.evaluation.config import load_config
from train.common.runs import worker_pool
cfg = load_config(None, ["episode_s=0.1", "plots=false", "seeds=1", "disturbances=[none]"])
task, settings = cfg.tasks()[0], cfg.settings()
t0 = time.perf_counter()
pool = worker_pool(1, sys.argv[1])
pool.submit(run_episode, task, settings, False).result()
first = time.perf_counter() - t0
t0 = time.perf_counter()
pool.submit(run_episode, task, settings, False).result()
print(first - (time.perf_counter() - t0))
pool.shutdown()
"""


def worker_start_seconds(method: str) -> float:
    """What a worker started by ``method`` costs before its first episode, in a fresh
    process as a sweep's is when it makes its pool (imports done, no episode run yet):
    the seconds from making a one-worker pool to the result of a 0.1-s episode, less the
    same episode's time once the worker is warm. A forked worker inherits the imports but
    still loads the compiled kernels and builds its first env; a spawned one also imports."""
    out = subprocess.run(
        [sys.executable, "-c", _START_PROBE, method],
        check=True,
        capture_output=True,
        text=True,
        env={**os.environ, **dict.fromkeys(ONE_THREAD_VARS, "1")},  # as the CLI sets them
    )
    return float(out.stdout.split()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=24)
    parser.add_argument("--episode-s", type=float, default=8.0)
    parser.add_argument("--repeats", type=int, default=3, help="timings per worker count")
    parser.add_argument(
        "--max-workers", type=int, default=None, help="default: the cores this process may use"
    )
    parser.add_argument(
        "--config", type=Path, default=None, help="time this evaluation config instead"
    )
    parser.add_argument(
        "--start-methods",
        nargs="+",
        default=["fork", "spawn"],
        choices=["auto", *mp.get_all_start_methods()],
        help="how the worker processes start, each timed for every count above 1",
    )
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1, got {args.repeats}")
    cores = args.max_workers or len(os.sched_getaffinity(0))
    methods = list(dict.fromkeys(args.start_methods))
    runs = [(1, methods[0])] + [(w, m) for w in worker_counts(cores)[1:] for m in methods]
    timings: dict[tuple[int, str], list[tuple[float, float, int]]] = {r: [] for r in runs}
    for repeat in range(args.repeats):
        for workers, method in runs:  # alternating: a load change hits every run alike
            with tempfile.TemporaryDirectory() as tmp:
                timings[workers, method].append(
                    sweep_seconds(
                        workers, args.seeds, args.episode_s, Path(tmp), args.config, method
                    )
                )
            wall = timings[workers, method][-1][0]
            how = f" ({method})" if workers > 1 else ""
            print(f"repeat {repeat + 1}, {workers} workers{how}: {wall:.1f} s")
    rows = [
        (
            w,
            m,
            timings[w, m][0][2],
            statistics.median(t[0] for t in timings[w, m]),
            statistics.median(t[1] for t in timings[w, m]),
        )
        for w, m in runs
    ]
    starts = {m: [] for m in methods}
    for _ in range(args.repeats):
        for m in methods:
            starts[m].append(worker_start_seconds(m))
    print("| start | worker start before its first episode (s), median | runs |")
    print("|---|---:|---|")
    for m, seconds in starts.items():
        runs_s = ", ".join(f"{x:.2f}" for x in seconds)
        print(f"| {m} | {statistics.median(seconds):.2f} | {runs_s} |")
    base, base_tail = rows[0][3], rows[0][4]
    print(f"cores available: {len(os.sched_getaffinity(0))}")
    print(
        "| workers | start | episodes | wall (s) | serial tail (s) | episodes/s | speed-up "
        "| efficiency | speed-up, episodes only |"
    )
    print("|---:|---|---:|---:|---:|---:|---:|---:|---:|")
    for workers, method, n, wall, tail in rows:
        speedup = base / wall
        episodes_only = (base - base_tail) / (wall - tail)
        start = "—" if workers == 1 else method
        print(
            f"| {workers} | {start} | {n} | {wall:.1f} | {tail:.1f} | {n / wall:.2f} "
            f"| {speedup:.2f} | {speedup / workers:.2f} | {episodes_only:.2f} |"
        )


if __name__ == "__main__":
    main()
