"""Statistics of the reports: paired comparisons with simultaneous intervals, bootstrap
intervals, the interquartile mean, CVaR, and rliable's stratified bootstrap and
performance profiles.

* :func:`paired_comparisons` — every controller against a reference in every condition:
  an exact sign-flip test per pair set, Holm's step-down over the family, the effect with a
  BCa interval (:mod:`train.common.paired_tests`, re-exported here);
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
from scipy import stats

from train.common.paired_tests import (  # noqa: F401  (re-exported)
    ALPHA,
    COMPARISON_COLUMNS,
    PAIR_KEY,
    paired_comparisons,
    pairs_needed,
)

#: The fraction of worst episodes the tail metric averages.
TAIL_FRACTION = 0.1


def cvar(values: np.ndarray, fraction: float = TAIL_FRACTION) -> float:
    """CVaR of an error: the mean of the worst (largest) ⌈fraction · n⌉ values; NaN if empty."""
    x = np.sort(np.asarray(values, dtype=float)[np.isfinite(values)])
    if x.size == 0:
        return float("nan")
    k = max(1, math.ceil(fraction * x.size))
    return float(np.mean(x[-k:]))


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


def hierarchical_bootstrap(
    values: np.ndarray,
    clusters: np.ndarray,
    resamples: int,
    seed: int,
    confidence: float = 0.95,
) -> tuple[float, float, float]:
    """The mean over clusters of each cluster's mean, with a two-stage percentile-bootstrap
    interval: clusters (paths) drawn with replacement, then within each drawn cluster its
    units (seeds) with replacement — each draw of a cluster resampled on its own.

    Returns (estimate, low, high): estimate = (1/P) Σ_p mean_i x_pi over the P clusters of
    ``clusters`` (each weighs the same, whatever its size); NaN values are dropped, and a
    cluster left empty with them. (NaN, NaN, NaN) without values; with one cluster the
    interval is its seeds' bootstrap only (the path-to-path spread is then unknown).
    """
    x = np.asarray(values, dtype=float)
    keys = np.asarray(clusters)
    ok = np.isfinite(x)
    x, keys = x[ok], keys[ok]
    if x.size == 0:
        return float("nan"), float("nan"), float("nan")
    labels, inverse = np.unique(keys, return_inverse=True)
    groups = [x[inverse == k] for k in range(len(labels))]
    estimate = float(np.mean([g.mean() for g in groups]))
    sizes = np.array([g.size for g in groups])
    padded = np.zeros((len(groups), sizes.max()))
    for k, g in enumerate(groups):
        padded[k, : g.size] = g
    rng = np.random.default_rng(seed)
    p = len(groups)
    drawn = rng.integers(0, p, size=(resamples, p))  # stage 1: the clusters
    n = sizes[drawn]  # (R, P)
    u = rng.random((resamples, p, sizes.max()))
    picks = np.minimum((u * n[..., None]).astype(int), n[..., None] - 1)  # stage 2: units
    taken = padded[drawn[..., None], picks]  # (R, P, max n)
    valid = np.arange(sizes.max()) < n[..., None]
    means = np.where(valid, taken, 0.0).sum(axis=2) / n
    stat = means.mean(axis=1)
    tail = (1.0 - confidence) / 2.0
    low, high = np.quantile(stat, [tail, 1.0 - tail])
    return estimate, float(low), float(high)
