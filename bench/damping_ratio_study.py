"""Which default joint damping ratio ζ (``damping_ratio``) for the passivity law.

The default rates with ζ ∈ {0, 0.5, 0.7, 1}, on the tuning's validation paths (path seeds
9001-9005, disjoint from the verdict's test paths), 5-s episodes started on the path, reset
seed 0, at 1 kHz and 250 Hz: undisturbed and under the impulse and periodic presets at
level 1; and at 1 kHz under the sensor-delay preset at levels 1 and 2 (2 and 4 ms). One CSV
row per episode (path distance RMS and max, rad; failed: the path distance passed 0.5 rad).

    python bench/damping_ratio_study.py --out docs/results/zeta_default/episodes.csv

About 10 min on one core. Results and the choice they led to (ζ = 0.7): docs/experiments.md
(#default-damping-ratio).
"""

from __future__ import annotations

import argparse
import csv
import itertools
from pathlib import Path

from ptrack_gym.robots import ROBOTS
from train.evaluation.episode import EpisodeSettings, Task, run_episode

ZETAS = (0.0, 0.5, 0.7, 1.0)
PATHS = (9001, 9002, 9003, 9004, 9005)
#: (control rate in Hz, disturbance, level) of each condition.
CONDITIONS = (
    *((hz, d, 0.0 if d == "none" else 1.0) for hz in (1000.0, 250.0)
      for d in ("none", "impulse", "periodic")),
    (1000.0, "delay", 1.0),
    (1000.0, "delay", 2.0),
)  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True, help="the CSV to write")
    args = parser.parse_args()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fields = ["robot", "control_hz", "disturbance", "level", "zeta", "path_seed",
              "path_dist_rms", "path_dist_max", "failed"]  # fmt: skip
    with args.out.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields)
        writer.writeheader()
        for robot, (hz, dist, level), zeta, path_seed in itertools.product(
            ROBOTS, CONDITIONS, ZETAS, PATHS
        ):
            settings = EpisodeSettings(
                env_id=ROBOTS[robot].env_id, episode_s=5.0, control_hz=hz, start="on_path",
                failure_distance_rad=0.5, recovery_threshold_rad=0.01,
                gains=(("damping_ratio", zeta),), path="random", path_seed=path_seed,
            )  # fmt: skip
            row, _ = run_episode(Task("passivity", dist, level, 0, 0), settings)
            writer.writerow({
                "robot": robot, "control_hz": hz, "disturbance": dist, "level": level,
                "zeta": zeta, "path_seed": path_seed, "path_dist_rms": row["path_dist_rms"],
                "path_dist_max": row["path_dist_max"], "failed": row["failed"],
            })  # fmt: skip
            fh.flush()


if __name__ == "__main__":
    main()
