"""The main job's same work, old code against this checkout, side by side (issue 12).

Runs the first release's main job (``train/configs/main.yml`` at ``--baseline``, commit
18e8559: 4 controllers at default gains, undisturbed and 3 presets × 3 levels, 5 seeds,
6-s episodes at 1 kHz, 200 episodes) once with that commit's code, checked out in a
temporary ``git worktree``, and once with this checkout's (the same config with
``passivity_paper``, the first release's law), alternating for ``--rounds`` rounds, each a
fresh ``python -m train.evaluate`` process with ``--workers`` runners. Prints every wall
time (s), the ratio of the medians, and how far apart the two runs' rows are: the largest
relative difference of each metric over the paired episodes (the first release's
``passivity`` counted against today's ``passivity_paper``)::

    python bench/same_work.py [--rounds 2] [--workers 2]

Needs git and the repository's history (a clone has it). Both runs use this checkout's
Python environment; each is started from its own tree, so it imports its own packages.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

ROOT = Path(__file__).resolve().parent.parent
KEY = ["controller", "disturbance", "level", "seed", "episode"]
METRICS = ["path_dist_rms", "path_dist_max", "time_err_rms", "tau_rms_frac", "controller_work_j"]


def timed_sweep(tree: Path, config: Path, out: Path, workers: int) -> float:
    """Wall time (s) of one sweep run by the code in ``tree``, as a fresh process."""
    command = [sys.executable, "-m", "train.evaluate", "--config", str(config)]
    command += ["--out", str(out), "--workers", str(workers), "--no-progress"]
    start = time.perf_counter()
    subprocess.run(command, cwd=tree, check=True, capture_output=True)
    return time.perf_counter() - start


def row_differences(old: Path, new: Path) -> dict[str, float]:
    """Largest relative difference of each metric over the paired episodes."""
    a = pd.read_csv(old / "episodes.csv").replace({"controller": {"passivity": "passivity_paper"}})
    b = pd.read_csv(new / "episodes.csv")
    a, b = a.sort_values(KEY).reset_index(drop=True), b.sort_values(KEY).reset_index(drop=True)
    if not a[KEY].equals(b[KEY]):
        raise RuntimeError("the two runs did not run the same episodes")
    scale = np.maximum(np.abs(a[METRICS].to_numpy()), 1e-300)
    return dict(
        zip(
            METRICS,
            np.max(np.abs(a[METRICS].to_numpy() - b[METRICS].to_numpy()) / scale, axis=0),
            strict=True,
        )
    )


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """Command-line arguments."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", default="18e8559", help="the old code's commit")
    parser.add_argument("--rounds", type=int, default=2, help="old-new pairs, alternating")
    parser.add_argument("--workers", type=int, default=2, help="runners of each sweep")
    args = parser.parse_args(argv)
    if args.rounds < 1 or args.workers < 1:
        parser.error("--rounds and --workers must be >= 1")
    return args


def main(argv: Sequence[str] | None = None) -> None:
    """Run the comparison and print it."""
    args = parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp)
        old_tree = base / "old"
        subprocess.run(
            ["git", "worktree", "add", "--detach", str(old_tree), args.baseline],
            cwd=ROOT, check=True, capture_output=True,
        )  # fmt: skip
        try:
            old_config = old_tree / "train" / "configs" / "main.yml"
            cfg = yaml.safe_load(old_config.read_text())
            cfg["controllers"] = [
                "passivity_paper" if c == "passivity" else c for c in cfg["controllers"]
            ]
            new_config = base / "same_work.yml"
            new_config.write_text(yaml.safe_dump(cfg, sort_keys=False))
            times: dict[str, list[float]] = {"old": [], "new": []}
            for r in range(args.rounds):
                for name, tree, config in (
                    ("old", old_tree, old_config),
                    ("new", ROOT, new_config),
                ):
                    out = base / f"{name}_{r}"
                    times[name].append(timed_sweep(tree, config, out, args.workers))
                    print(f"round {r + 1}: {name} {times[name][-1]:.1f} s", flush=True)
            old_med, new_med = statistics.median(times["old"]), statistics.median(times["new"])
            print(
                f"\nmedian wall: {args.baseline} {old_med:.1f} s, this checkout {new_med:.1f} s: "
                f"{old_med / new_med:.2f}x ({args.workers} runners; every round: "
                + ", ".join(
                    f"{o / n:.2f}x" for o, n in zip(times["old"], times["new"], strict=True)
                )
                + ")"
            )
            print("largest relative difference of the rows (last round):")
            last = args.rounds - 1
            for metric, diff in row_differences(base / f"old_{last}", base / f"new_{last}").items():
                print(f"  {metric}: {diff:.1e}")
        finally:
            subprocess.run(
                ["git", "worktree", "remove", "--force", str(old_tree)],
                cwd=ROOT, check=False, capture_output=True,
            )  # fmt: skip


if __name__ == "__main__":
    main()
