"""Episodes per second of the evaluation sweep with 1 and 2 worker processes, in one run.

The same small sweep (two-link, 2 controllers × 2 presets × ``--seeds`` seeds,
``--episode-s``-second episodes) runs once with ``workers=1`` and once with
``workers=2`` into temporary folders; the ratio is the parallel speed-up (issue target:
≥ 1.7 on 2 cores). Process start-up is included: it is part of what a user waits for.

Run: ``python bench/eval_scaling.py [--seeds 8] [--episode-s 4]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from train.evaluate import load_config, run_sweep


def sweep_seconds(workers: int, seeds: int, episode_s: float, folder: Path) -> tuple[float, int]:
    """Wall time (s) and episode count of the benchmark sweep with ``workers`` processes."""
    cfg = load_config(
        None,
        [
            "env_id=ptrack_gym/TwoLinkTrack-v0",
            "controllers=[computed_torque, passivity]",
            "disturbances=[impulse, periodic]",
            "levels=[1.0]",
            f"seeds={seeds}",
            f"episode_s={episode_s}",
            "plots=false",
            f"workers={workers}",
            f"out={folder / f'w{workers}'}",
        ],
    )
    t0 = time.perf_counter()
    run_sweep(cfg, progress=False, show=False)
    return time.perf_counter() - t0, len(cfg.tasks())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--episode-s", type=float, default=4.0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        t1, n = sweep_seconds(1, args.seeds, args.episode_s, Path(tmp))
        t2, _ = sweep_seconds(2, args.seeds, args.episode_s, Path(tmp))
    print("| workers | episodes | wall (s) | episodes/s |")
    print("|---:|---:|---:|---:|")
    print(f"| 1 | {n} | {t1:.1f} | {n / t1:.2f} |")
    print(f"| 2 | {n} | {t2:.1f} | {n / t2:.2f} |")
    print(f"\nspeed-up 2 vs 1 worker: {t1 / t2:.2f}")


if __name__ == "__main__":
    main()
