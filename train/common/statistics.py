"""Statistics of the reports: paired comparisons with simultaneous intervals, bootstrap
intervals, the interquartile mean, CVaR, and rliable's stratified bootstrap and
performance profiles.

* :func:`paired_comparisons` — every controller against a reference in every condition:
  the paired difference of a metric over the episodes two controllers share (same seed,
  same episode: the same start and disturbance), with a percentile-bootstrap interval at
  the Bonferroni-adjusted confidence 1 − α/K (K comparisons), marked "better" or "worse"
  only when the interval excludes 0;
* :func:`bootstrap_ci`, :func:`iqm`, :func:`cvar`;
* :func:`stratified_bootstrap`, :func:`iqm_and_mean`, :func:`interval_estimates`,
  :func:`performance_profile` — rliable's (Agarwal et al., NeurIPS 2021) aggregate over
  conditions, vectorised (equal to rliable's bit for bit: ``tests/test_report.py``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

#: The family-wise error rate of a report's marks.
ALPHA = 0.05
#: The fraction of worst episodes the tail metric averages.
TAIL_FRACTION = 0.1
#: The columns that pair two controllers' episodes: the same start and disturbance.
PAIR_KEY = ["seed", "episode"]


def cvar(values: np.ndarray, fraction: float = TAIL_FRACTION) -> float:
    """CVaR of an error: the mean of the worst (largest) ⌈fraction · n⌉ values; NaN if empty."""
    x = np.sort(np.asarray(values, dtype=float)[np.isfinite(values)])
    if x.size == 0:
        return float("nan")
    k = max(1, math.ceil(fraction * x.size))
    return float(np.mean(x[-k:]))


#: The columns of :func:`paired_comparisons`, in order.
COMPARISON_COLUMNS = (
    "disturbance", "level", "controller", "pairs", "reference_mean", "mean", "diff", "ratio",
    "ci_low", "ci_high", "mark", "comparisons", "confidence",
)  # fmt: skip


def paired_comparisons(
    df: pd.DataFrame,
    metric: str,
    reference: str,
    alpha: float = ALPHA,
    resamples: int = 20_000,
    seed: int = 0,
) -> pd.DataFrame:
    """Every controller against ``reference`` in every condition (module docstring).

    Columns: disturbance, level, controller, pairs, reference_mean, mean, diff, ratio
    (mean / reference_mean), ci_low, ci_high (Bonferroni-adjusted), mark ("better",
    "worse" — lower is better — or "unresolved"), comparisons (K), confidence.
    """
    conditions = (
        df[["disturbance", "level"]].drop_duplicates().sort_values(["disturbance", "level"])
    )
    others = sorted(c for c in df["controller"].unique() if c != reference)
    k = max(1, len(conditions) * len(others))
    confidence = 1.0 - alpha / k
    rows = []
    for _, (dist, level) in conditions.iterrows():
        cond = df[(df["disturbance"] == dist) & (df["level"] == level)]
        ref = cond[cond["controller"] == reference].set_index(PAIR_KEY)[metric]
        for ctrl in others:
            x = cond[cond["controller"] == ctrl].set_index(PAIR_KEY)[metric]
            common = x.index.intersection(ref.index)
            diff = x.loc[common].to_numpy(float) - ref.loc[common].to_numpy(float)
            lo, hi = bootstrap_ci(diff, np.mean, resamples, seed, confidence)
            if not (np.isfinite(lo) and np.isfinite(hi)):
                mark = "unresolved"
            elif hi < 0:
                mark = "better"
            elif lo > 0:
                mark = "worse"
            else:
                mark = "unresolved"
            ref_mean = float(ref.loc[common].mean()) if len(common) else float("nan")
            mean = float(x.loc[common].mean()) if len(common) else float("nan")
            rows.append(
                {
                    "disturbance": dist,
                    "level": float(level),
                    "controller": ctrl,
                    "pairs": len(common),
                    "reference_mean": ref_mean,
                    "mean": mean,
                    "diff": float(np.mean(diff)) if len(diff) else float("nan"),
                    "ratio": mean / ref_mean if ref_mean else float("nan"),
                    "ci_low": lo,
                    "ci_high": hi,
                    "mark": mark,
                    "comparisons": k,
                    "confidence": confidence,
                }
            )
    return pd.DataFrame(rows, columns=COMPARISON_COLUMNS)  # the columns even with no others


def iqm(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """Interquartile mean: the mean of the middle 50% (scipy's trim_mean at 25%)."""
    return stats.trim_mean(x, 0.25, axis=axis)


def bootstrap_ci(
    values: np.ndarray, statistic: Any, resamples: int, seed: int, confidence: float = 0.95
) -> tuple[float, float]:
    """Percentile-bootstrap interval at ``confidence`` (95% by default) of ``statistic`` over
    the finite values; NaN for fewer than 2 values, a point for identical ones."""
    values = values[np.isfinite(values)]
    if len(values) < 2:
        return float("nan"), float("nan")
    if np.ptp(values) == 0.0:
        v = float(statistic(values))
        return v, v
    res = stats.bootstrap(
        (values,),
        statistic,
        n_resamples=resamples,
        confidence_level=confidence,
        method="percentile",
        vectorized=True,
        rng=np.random.default_rng(seed),
    )
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def stratified_bootstrap(
    x: np.ndarray,
    statistic: Callable[[np.ndarray], np.ndarray],
    resamples: int,
    rng: np.random.Generator,
    confidence: float = 0.95,
) -> tuple[np.ndarray, np.ndarray]:
    """rliable's stratified bootstrap (Agarwal et al., NeurIPS 2021) of a score matrix x
    (runs × tasks): each resample redraws, within every task (column), its runs (rows) with
    replacement; the interval is the percentile one at ``confidence``.

    ``statistic`` maps a batch of matrices (B × runs × tasks) to estimates (B × k); it runs
    once on all ``resamples`` instead of once per resample (rliable 1.2 loops in Python
    through arch: ~0.3 s per controller at 2 000 resamples, most of a sweep's serial tail).
    Returns (the estimate on x, shape k; [lower, upper], shape 2 × k). The indices are drawn
    from ``rng`` as rliable's ``StratifiedBootstrap`` draws them with a seeded generator (one
    ``choice(runs, x.shape)`` per resample): the results equal its ``conf_int(...,
    method="percentile")`` bit for bit (tested against rliable)."""
    runs, tasks = x.shape
    rows = np.stack([rng.choice(runs, x.shape, replace=True) for _ in range(resamples)])
    estimates = statistic(x[rows, np.arange(tasks)])
    alpha = (1.0 - confidence) / 2  # arch's percentiles, computed the way it computes them
    lower_upper = np.percentile(estimates, [100 * alpha, 100 * (1.0 - alpha)], axis=0)
    return statistic(x[np.newaxis])[0], lower_upper


def iqm_and_mean(batch: np.ndarray) -> np.ndarray:
    """rliable's ``aggregate_iqm`` (25% trimmed mean of every score) and ``aggregate_mean``
    (mean over tasks of the mean over runs) of each matrix of a batch (B × runs × tasks):
    shape B × 2."""
    per_matrix_iqm = iqm(batch.reshape(batch.shape[0], -1), axis=1)
    return np.stack([per_matrix_iqm, np.mean(np.mean(batch, axis=1), axis=1)], axis=1)


def interval_estimates(
    scores: dict[str, np.ndarray],
    statistic: Callable[[np.ndarray], np.ndarray],
    resamples: int,
    seed: int,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """rliable's ``get_interval_estimates`` (stratified bootstrap over runs, percentile 95%),
    seeded: :func:`stratified_bootstrap` of each controller (in sorted order) with one
    ``np.random.Generator`` per controller spawned from ``seed``."""
    point, interval = {}, {}
    streams = np.random.SeedSequence(seed).spawn(len(scores))
    for (key, x), stream in zip(sorted(scores.items()), streams, strict=True):
        point[key], interval[key] = stratified_bootstrap(
            x, statistic, resamples, np.random.default_rng(stream)
        )
    return point, interval


def performance_profile(batch: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """rliable's performance profile of each matrix of a batch (B × runs × tasks): the
    fraction of its scores (pooled over tasks) above each τ; shape B × len(taus). Counted
    in blocks of resamples, so memory stays ~ 8 MB whatever the batch."""
    flat = batch.reshape(batch.shape[0], -1)
    out = np.empty((flat.shape[0], taus.size))
    block = max(1, 8_000_000 // max(1, flat.shape[1] * taus.size))
    for start in range(0, flat.shape[0], block):
        chunk = flat[start : start + block, :, np.newaxis] > taus
        out[start : start + block] = chunk.mean(axis=1)
    return out


def pareto_front(effort: np.ndarray, error: np.ndarray) -> np.ndarray:
    """Indices of the points no other point beats on both effort and error (lower is
    better on each), by rising effort; along them the error strictly falls."""
    effort, error = np.asarray(effort, float), np.asarray(error, float)
    ok = np.flatnonzero(np.isfinite(effort) & np.isfinite(error))
    order = ok[np.lexsort((error[ok], effort[ok]))]  # by effort, ties by error
    front, best = [], math.inf
    for i in order:
        if error[i] < best:
            front.append(i)
            best = error[i]
    return np.array(front, dtype=int)
