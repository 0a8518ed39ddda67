"""Paired comparisons whose "resolved" marks keep their promise: an exact sign-flip test
per comparison, Holm's step-down over the family, the effect with a BCa interval.

The unit is a **pair**: two controllers' episodes that share everything random — the same
seed and episode (the start and the disturbance draw) and, once paths vary, the same path.
For a comparison (controller c against the reference, in one condition) with paired
differences d_i = x_c,i − x_ref,i, i = 1…n:

* **the test** — H₀: the two controllers are exchangeable within a pair, so each d_i is
  symmetric about 0 and, given |d_1|…|d_n|, every sign pattern is equally likely. The
  statistic is the mean difference d̄; its two-sided p-value is

  .. math::

      p = \\frac{\\#\\{\\epsilon \\in \\{\\pm1\\}^n : |\\textstyle\\sum_i \\epsilon_i |d_i||
          \\ge |\\sum_i d_i|\\}}{2^n},

  counted exactly for n ≤ :data:`EXACT_MAX_PAIRS` (a meet-in-the-middle count: the 2^(n/2)
  sums of each half, one sorted, ``searchsorted``) and otherwise by Monte Carlo,
  p = (1 + #{|S*| ≥ |S|}) / (1 + R) over R random sign patterns — also a valid p-value
  (P(p ≤ a) ≤ a under H₀). No distributional assumption beyond symmetry under H₀;
* **the family** — Holm's step-down (Holm 1979) over the K comparisons of one call (one
  metric; a report calls once per metric): with p₍₁₎ ≤ … ≤ p₍K₎, reject H₍₁₎…H₍j₎ for the
  largest j with p₍i₎ ≤ α / (K − i + 1) for every i ≤ j. It controls the family-wise error
  at α under any dependence between the comparisons; ``p_holm`` is the adjusted p-value
  max_{j≤i} min(1, (K − j + 1) p₍j₎), rejected where ≤ α;
* **the mark** — "better" (lower is better) or "worse" by the sign of d̄ where Holm rejects,
  else "unresolved";
* **the effect** — d̄ with a BCa bootstrap interval (Efron 1987; scipy's) at the Bonferroni
  level 1 − α/K, so the intervals are simultaneous; the interval describes the size of the
  effect, the mark comes from the test alone.

**Pairs needed.** The smallest p an exact sign-flip test can give with n pairs is 2/2ⁿ,
and Holm's first step needs p ≤ α/K, so nothing can be resolved unless
n ≥ :func:`pairs_needed` (K, α) = ⌈log₂(2K/α)⌉: 6 for one comparison, 9 for K = 8, 12 for
K = 52 — a 5-seed sweep cannot resolve anything in a family of more than one comparison.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence

import numpy as np
import pandas as pd
from scipy import stats

from ptrack_gym.errors import InvalidConfigError


class TooFewPairsError(InvalidConfigError):
    """A comparison with fewer than 2 paired episodes: no paired test can be made."""


#: The family-wise error rate of a report's marks.
ALPHA = 0.05
#: The columns that pair two controllers' episodes: the same start and disturbance draw
#: (and ``path`` too, where the table has that column).
PAIR_KEY = ["seed", "episode"]
#: Up to this many pairs the sign-flip p-value is counted exactly (2ⁿ patterns).
EXACT_MAX_PAIRS = 26
#: The statistics :func:`paired_comparisons` tests and estimates.
STATISTICS = ("mean",)
#: The columns of :func:`paired_comparisons`, in order.
COMPARISON_COLUMNS = (
    "disturbance", "level", "controller", "pairs", "reference_mean", "mean", "diff", "ratio",
    "ci_low", "ci_high", "p_value", "p_holm", "mark", "comparisons", "confidence",
    "pairs_needed", "metric",
)  # fmt: skip


def pairs_needed(comparisons: int, alpha: float = ALPHA) -> int:
    """The fewest pairs n for which an exact two-sided sign-flip test can reach Holm's first
    threshold α/K: 2/2ⁿ ≤ α/K, n = ⌈log₂(2K/α)⌉ (module docstring)."""
    if comparisons < 1 or not 0.0 < alpha < 1.0:
        raise InvalidConfigError(f"need K ≥ 1 and 0 < α < 1, got K={comparisons}, α={alpha}")
    return math.ceil(math.log2(2.0 * comparisons / alpha) - 1e-12)


def _sign_patterns(n: int) -> np.ndarray:
    """Every ε ∈ {±1}ⁿ, as the rows of a (2ⁿ, n) matrix."""
    bits = (np.arange(2**n)[:, np.newaxis] >> np.arange(n)) & 1
    return 1.0 - 2.0 * bits


def sign_flip_pvalues(
    diffs: np.ndarray, rng: np.random.Generator | None = None, resamples: int = 20_000
) -> np.ndarray:
    """Two-sided sign-flip p-values of the mean of paired differences, one per row of
    ``diffs`` (k, n) (module docstring): exact for n ≤ :data:`EXACT_MAX_PAIRS` (each half's
    2^(n/2) signed sums by one product with every sign pattern, then a sorted count), Monte
    Carlo beyond with ``resamples`` sign patterns from ``rng`` (shared by the rows: each
    p-value stays valid, and Holm needs no independence). A row with a zero sum: p = 1.

    Raises:
        InvalidConfigError: fewer than 2 pairs, a non-finite difference, or Monte Carlo
            without ``rng``.
    """
    d = np.asarray(diffs, dtype=float)
    if d.ndim != 2 or d.shape[1] < 2 or not np.isfinite(d).all():
        raise InvalidConfigError(
            f"a paired test needs ≥ 2 finite differences per row, got shape {d.shape}"
        )
    k, n = d.shape
    a = np.abs(d)
    # sums equal in exact arithmetic may differ by rounding: count them as at least as extreme
    threshold = np.abs(d.sum(axis=1)) - 1e-9 * a.sum(axis=1)  # (k,)
    if n <= EXACT_MAX_PAIRS:
        half = n // 2
        left = a[:, :half] @ _sign_patterns(half).T  # (k, 2^half)
        right = np.sort(a[:, half:] @ _sign_patterns(n - half).T, axis=1)  # (k, 2^(n−half))
        count = np.empty(k)
        for i in range(k):  # #{l + r ≥ t} + #{l + r ≤ −t}: disjoint sets for t > 0
            upper = right.shape[1] - np.searchsorted(right[i], threshold[i] - left[i], "left")
            lower = np.searchsorted(right[i], -threshold[i] - left[i], "right")
            count[i] = upper.sum() + lower.sum()
        p = count / 2.0**n
    else:
        if rng is None:
            raise InvalidConfigError(f"{n} pairs: a Monte Carlo p-value needs a generator")
        signs = 1.0 - 2.0 * rng.integers(0, 2, size=(resamples, n))
        extreme = np.count_nonzero(np.abs(signs @ a.T) >= threshold, axis=0)  # (k,)
        p = (1.0 + extreme) / (1.0 + resamples)
    return np.where(threshold > 0.0, p, 1.0)


def sign_flip_pvalue(
    diff: np.ndarray, rng: np.random.Generator | None = None, resamples: int = 20_000
) -> float:
    """:func:`sign_flip_pvalues` of one set of paired differences (n,)."""
    d = np.asarray(diff, dtype=float)
    if d.ndim != 1:
        raise InvalidConfigError(f"expected one set of differences (n,), got shape {d.shape}")
    return float(sign_flip_pvalues(d[np.newaxis], rng, resamples)[0])


def holm(pvalues: Sequence[float] | np.ndarray) -> np.ndarray:
    """Holm's step-down adjusted p-values (module docstring): reject where ≤ α."""
    p = np.asarray(pvalues, dtype=float)
    k = p.size
    order = np.argsort(p, kind="stable")
    adjusted = np.minimum(1.0, np.maximum.accumulate((k - np.arange(k)) * p[order]))
    out = np.empty(k)
    out[order] = adjusted
    return out


def bca_interval(
    diff: np.ndarray, confidence: float, resamples: int, rng: np.random.Generator
) -> tuple[float, float]:
    """BCa bootstrap interval of the mean of ``diff`` at ``confidence`` (scipy's); a point
    for identical values; the percentile interval where BCa is undefined (a bootstrap
    distribution with no spread on one side, seen with few pairs)."""
    if np.ptp(diff) == 0.0:
        v = float(diff[0])
        return v, v
    for method in ("BCa", "percentile"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # scipy warns where BCa is degenerate
            res = stats.bootstrap(
                (diff,), np.mean, n_resamples=resamples, confidence_level=confidence,
                method=method, vectorized=True, rng=rng,
            )  # fmt: skip
        lo, hi = float(res.confidence_interval.low), float(res.confidence_interval.high)
        if np.isfinite(lo) and np.isfinite(hi):
            return lo, hi
    return float(np.min(diff)), float(np.max(diff))


def _pair_key(df: pd.DataFrame) -> list[str]:
    """The columns that make a pair in ``df``: seed and episode, and path where present."""
    return (["path"] if "path" in df.columns else []) + PAIR_KEY


def paired_comparisons(
    df: pd.DataFrame,
    metric: str,
    reference: str,
    alpha: float = ALPHA,
    resamples: int = 20_000,
    seed: int = 0,
    statistic: str = "mean",
) -> pd.DataFrame:
    """Every controller against ``reference`` in every condition (module docstring).

    ``df`` is the tidy episodes table: columns disturbance, level, controller, seed,
    episode (and path, where paths vary) and ``metric``; lower is better. Pairs whose metric
    is not finite for either controller are left out (``pairs`` counts those used). The
    family is every comparison of this call: each other controller in each condition it ran
    in (K = conditions × other controllers when all ran everywhere).

    Columns (:data:`COMPARISON_COLUMNS`): disturbance, level, controller, pairs,
    reference_mean, mean, diff (mean paired difference), ratio (mean / reference_mean),
    ci_low, ci_high (BCa at ``confidence`` = 1 − α/K), p_value (sign-flip), p_holm, mark
    ("better", "worse" or "unresolved"), comparisons (K), confidence, pairs_needed
    (:func:`pairs_needed` of K), metric.

    Raises:
        InvalidConfigError: an unknown ``statistic`` or ``metric`` column, no ``reference``
            episodes, a bad ``alpha``; :class:`TooFewPairsError` (one of them) a
            comparison with fewer than 2 pairs (a controller that ran in the condition but
            shares fewer than 2 finite episodes with the reference there).
    """
    if statistic not in STATISTICS:
        raise InvalidConfigError(f"unknown statistic {statistic!r}; known: {list(STATISTICS)}")
    if not 0.0 < alpha < 1.0:
        raise InvalidConfigError(f"alpha must lie in (0, 1), got {alpha!r}")
    key = _pair_key(df)
    missing = [c for c in ("disturbance", "level", "controller", *key, metric) if c not in df]
    if missing:
        raise InvalidConfigError(f"the episodes table has no column(s) {missing}")
    if reference not in set(df["controller"]):
        raise InvalidConfigError(f"no episodes of the reference {reference!r}")
    conditions = (
        df[["disturbance", "level"]].drop_duplicates().sort_values(["disturbance", "level"])
    )
    by_condition = dict(iter(df.groupby(["disturbance", "level"], sort=False)))
    family = [  # (condition, controller): every controller that ran in the condition
        ((dist, level), ctrl)
        for dist, level in conditions.itertuples(index=False)
        for ctrl in sorted(set(by_condition[(dist, level)]["controller"]) - {reference})
    ]
    k = max(1, len(family))
    confidence = 1.0 - alpha / k
    streams = iter(np.random.SeedSequence(seed).spawn(k))
    rows = []
    for (dist, level), ctrl in family:
        cond = by_condition[(dist, level)]
        ref = cond[cond["controller"] == reference].set_index(key)[metric]
        rng = np.random.default_rng(next(streams))
        x = cond[cond["controller"] == ctrl].set_index(key)[metric]
        common = x.index.intersection(ref.index)
        a, b = x.loc[common].to_numpy(float), ref.loc[common].to_numpy(float)
        ok = np.isfinite(a) & np.isfinite(b)
        a, b = a[ok], b[ok]
        if a.size < 2:
            raise TooFewPairsError(
                f"{ctrl} vs {reference} under {dist} {level} on {metric}: {a.size} "
                "paired episode(s) with finite values; a paired test needs ≥ 2"
            )
        diff = a - b
        lo, hi = bca_interval(diff, confidence, resamples, rng)
        rows.append(
            {
                "disturbance": dist,
                "level": float(level),
                "controller": ctrl,
                "pairs": int(a.size),
                "reference_mean": float(b.mean()),
                "mean": float(a.mean()),
                "diff": float(diff.mean()),
                "ratio": float(a.mean() / b.mean()) if b.mean() else float("nan"),
                "ci_low": lo,
                "ci_high": hi,
                "p_value": sign_flip_pvalue(diff, rng, resamples),
            }
        )
    out = pd.DataFrame(rows, columns=COMPARISON_COLUMNS[:11])
    out["p_holm"] = holm(out["p_value"].to_numpy()) if len(out) else []
    rejected = out["p_holm"] <= alpha
    out["mark"] = np.where(
        rejected, np.where(out["diff"] < 0, "better", "worse"), "unresolved"
    ).astype(object)
    out["comparisons"] = k
    out["confidence"] = confidence
    out["pairs_needed"] = pairs_needed(k, alpha)
    out["metric"] = metric
    return out[list(COMPARISON_COLUMNS)]
