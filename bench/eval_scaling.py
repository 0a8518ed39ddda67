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

Run: ``python bench/eval_scaling.py [--seeds 24] [--episode-s 8] [--repeats 3]
[--max-workers N] [--config train/configs/main.yml]`` (``--config``: that sweep instead,
plots off).
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from train.evaluate import load_config
from train.sweep import _finish, run_sweep


def worker_counts(cores: int) -> list[int]:
    """1, 2, 4, … up to ``cores``, ending with ``cores`` itself."""
    counts = [1]
    while counts[-1] * 2 <= cores:
        counts.append(counts[-1] * 2)
    if counts[-1] != cores:
        counts.append(cores)
    return counts


def sweep_seconds(
    workers: int, seeds: int, episode_s: float, folder: Path, config: Path | None = None
) -> tuple[float, float, int]:
    """Wall time (s) of the benchmark sweep (or of the sweep of ``config``, without plots)
    with ``workers`` processes, the time (s) of its serial tail (summary, bootstrap
    intervals, report: timed by running it once more) and the episode count."""
    small = [
        "env_id=ptrack_gym/TwoLinkTrack-v0",
        "controllers=[computed_torque, passivity]",
        "disturbances=[impulse, periodic]",
        "levels=[1.0]",
        f"seeds={seeds}",
        f"episode_s={episode_s}",
    ]
    run = ["plots=false", f"workers={workers}", f"out={folder / f'w{workers}'}"]
    cfg = load_config(config, run if config is not None else [*small, *run])
    t0 = time.perf_counter()
    run_sweep(cfg, progress=False, show=False)
    wall = time.perf_counter() - t0
    t0 = time.perf_counter()
    _finish(cfg, Path(cfg.out), show=False)  # the serial tail again: report, bootstrap
    return wall, time.perf_counter() - t0, len(cfg.tasks())


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
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1, got {args.repeats}")
    cores = args.max_workers or len(os.sched_getaffinity(0))
    counts = worker_counts(cores)
    timings: dict[int, list[tuple[float, float, int]]] = {w: [] for w in counts}
    for repeat in range(args.repeats):
        for workers in counts:  # alternating: a load change hits every count alike
            with tempfile.TemporaryDirectory() as tmp:
                timings[workers].append(
                    sweep_seconds(workers, args.seeds, args.episode_s, Path(tmp), args.config)
                )
            print(f"repeat {repeat + 1}, {workers} workers: {timings[workers][-1][0]:.1f} s")
    rows = [
        (
            w,
            timings[w][0][2],
            statistics.median(t[0] for t in timings[w]),
            statistics.median(t[1] for t in timings[w]),
        )
        for w in counts
    ]
    base, base_tail = rows[0][2], rows[0][3]
    print(f"cores available: {len(os.sched_getaffinity(0))}")
    print(
        "| workers | episodes | wall (s) | serial tail (s) | episodes/s | speed-up "
        "| efficiency | speed-up, episodes only |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|")
    for workers, n, wall, tail in rows:
        speedup = base / wall
        episodes_only = (base - base_tail) / (wall - tail)
        print(
            f"| {workers} | {n} | {wall:.1f} | {tail:.1f} | {n / wall:.2f} | {speedup:.2f} "
            f"| {speedup / workers:.2f} | {episodes_only:.2f} |"
        )


if __name__ == "__main__":
    main()
