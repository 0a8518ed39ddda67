"""The verdict path by path (:mod:`train.studies.verdict_study`'s ``paths.csv``): on each
random test path alone, where the passivity controller wins, ties and loses against that
path's strongest rival, beside the path's period and amplitude."""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
import pandas as pd

from ptrack_gym.paths import make_path
from ptrack_gym.robots import ROBOTS, PinocchioModel
from train.common.paired_tests import TooFewPairsError
from train.evaluation.verdict import BOTH_METRICS, rival_comparisons

FOCUS = "passivity"


@functools.cache
def _model(robot: str) -> PinocchioModel:
    """One nominal model per robot (the test paths' admissibility uses its M(q))."""
    return PinocchioModel(ROBOTS[robot])


def path_features(robot: str, path_seed: int) -> dict[str, float]:
    """The random test path ``path_seed`` of ``robot`` (the one its env builds): its period
    (s) and its largest joint amplitude (rad, half the peak-to-peak range over a period)."""
    profile = ROBOTS[robot]
    path = make_path("random", profile, path_seed, _model(robot).mass_matrix)
    q = path.evaluate(np.linspace(0.0, path.period_s, 512, endpoint=False))[0]
    return {"period_s": path.period_s, "amplitude_rad": float(np.max(np.ptp(q, axis=0)) / 2)}


def path_outcomes(
    robots: Sequence[str], controllers: Sequence[str], resamples: int, df: pd.DataFrame
) -> pd.DataFrame:
    """Per robot, test path and metric: :func:`rival_comparisons` on that path's (seed)
    pairs alone — the strongest rival on the path in each condition, Holm over the robot's
    conditions — counted as wins, ties and losses, with the path's :func:`path_features`.
    With 10 seeds a path's test can resolve (the exact sign-flip test's smallest p-value,
    2/1024, is below Holm's first threshold 0.05/15); with fewer it may not, and the
    ``pairs_needed`` column says so."""
    rows = []
    for robot in robots:
        sub = df[(df["robot"] == robot) & df["controller"].isin(controllers)]
        for path, g in sub.groupby("path", sort=False):
            feats = path_features(robot, int(path))
            for metric in BOTH_METRICS:
                try:
                    r = rival_comparisons(g, metric, FOCUS, resamples=resamples, seed=0)
                except TooFewPairsError:
                    continue
                if not len(r):
                    continue
                counts = r["outcome"].value_counts()
                rows.append({
                    "robot": robot, "path": int(path), **feats, "metric": metric,
                    "wins": int(counts.get("wins", 0)), "ties": int(counts.get("ties", 0)),
                    "losses": int(counts.get("loses", 0)), "conditions": len(r),
                    "pairs": int(r["pairs"].min()), "pairs_needed": int(r["pairs_needed"].max()),
                    "ratio_median": float(r["ratio"].median()),
                })  # fmt: skip
    return pd.DataFrame(rows)


def path_table(paths: pd.DataFrame) -> str:
    """Markdown: per test path, its period and amplitude and the focus's wins / ties /
    losses against the path's strongest rival under each metric."""
    if paths.empty:
        return ""
    lines = [
        "| path | period (s) | amplitude (rad) | path distance: W / T / L | median focus / rival "
        "| time-indexed error: W / T / L | median focus / rival | pairs |",
        "|---:|---:|---:|---|---:|---|---:|---:|",
    ]
    for path, g in paths.groupby("path", sort=True):
        cells = []
        for metric in BOTH_METRICS:
            m = g[g["metric"] == metric]
            if m.empty:
                cells += ["–", "–"]
                continue
            r = m.iloc[0]
            cells += [f"{r['wins']} / {r['ties']} / {r['losses']}", f"{r['ratio_median']:.2f}"]
        r0 = g.iloc[0]
        lines.append(f"| {path} | {r0['period_s']:.2f} | {r0['amplitude_rad']:.2f} | "
                     + " | ".join(cells) + f" | {int(g['pairs'].min())} |")  # fmt: skip
    return "\n".join(lines)
