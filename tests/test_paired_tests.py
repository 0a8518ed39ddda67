"""The report's paired tests keep their promise (``train.common.paired_tests``).

* the sign-flip p-value equals a brute-force count over every sign pattern;
* Holm's adjusted p-values equal a direct step-down;
* under the null (every controller = reference + symmetric noise) the family-wise error of
  the marks is ≤ 5% within Monte Carlo error, for normal, t₃ and Laplace noise, n = 5, 10,
  20, 50 pairs and K = 8 or 52 comparisons (2,000 families each) — the old percentile
  bootstrap marked a difference in 59% of families at n = 5;
* the power to resolve a shift of one noise standard deviation at n = 20 among K = 8 is
  ≥ 80%;
* :func:`paired_comparisons` is those two functions on the tidy table (pairs by seed,
  episode and path), and refuses what it cannot test.
"""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest

from ptrack_gym.errors import InvalidConfigError
from train.common.paired_tests import (
    EXACT_MAX_PAIRS,
    TooFewPairsError,
    holm,
    pairs_needed,
    sign_flip_pvalue,
    sign_flip_pvalues,
)
from train.common.statistics import paired_comparisons

FAMILIES = 2000
ALPHA = 0.05


def brute_force_pvalue(d: np.ndarray) -> float:
    """#{ε: |Σ ε_i |d_i|| ≥ |Σ d_i|} / 2ⁿ by enumeration (float ties within 1e-9·Σ|d|)."""
    observed = abs(d.sum())
    count = sum(
        abs(np.dot(e, np.abs(d))) >= observed - 1e-9 * np.abs(d).sum()
        for e in itertools.product((-1.0, 1.0), repeat=d.size)
    )
    return count / 2.0**d.size


@pytest.mark.parametrize("n", [2, 3, 5, 8, 11])
def test_the_exact_pvalue_is_the_count_over_every_sign_pattern(n):
    rng = np.random.default_rng(n)
    for trial in range(15):
        d = rng.normal(size=n) + 0.4
        if trial % 3 == 0:
            d[0] = 0.0  # a zero difference
        if trial % 4 == 0:
            d = np.round(d, 1)  # ties of |d|
        assert sign_flip_pvalue(d) == pytest.approx(brute_force_pvalue(d), abs=1e-15)


def test_the_smallest_pvalue_is_two_over_two_to_the_n():
    for n in (5, 9, 12):
        assert sign_flip_pvalue(np.ones(n)) == pytest.approx(2.0 / 2**n)
    assert sign_flip_pvalue(np.zeros(6)) == 1.0
    assert sign_flip_pvalue(np.array([1.0, -1.0, 2.0, -2.0])) == 1.0
    # n ≥ ⌈log₂(2K/α)⌉ is needed for p ≤ α/K
    for k in (1, 8, 52, 80):
        n = pairs_needed(k)
        assert 2.0 / 2**n <= ALPHA / k < 2.0 / 2 ** (n - 1)
    assert (pairs_needed(1), pairs_needed(8), pairs_needed(52)) == (6, 9, 12)


def test_the_monte_carlo_pvalue_agrees_with_the_exact_one():
    rng = np.random.default_rng(7)
    d = rng.normal(size=EXACT_MAX_PAIRS) + 0.3
    exact = sign_flip_pvalue(d)
    # the same differences past the exact limit: a duplicate of each, sum doubled
    mc = sign_flip_pvalue(np.repeat(d, 2) / np.sqrt(2.0), np.random.default_rng(0), 40_000)
    assert 0.0 < exact < 1.0 and 0.0 < mc < 1.0
    # a Monte Carlo p-value is never 0: (1 + b) / (1 + R)
    tiny = sign_flip_pvalue(np.ones(60), np.random.default_rng(0), 1000)
    assert tiny == pytest.approx(1.0 / 1001.0)
    with pytest.raises(InvalidConfigError, match="generator"):
        sign_flip_pvalue(np.ones(EXACT_MAX_PAIRS + 1))


def test_a_batch_of_pvalues_is_each_row_alone():
    rng = np.random.default_rng(5)
    for n in (4, 13, 30):
        d = rng.normal(size=(6, n)) + 0.2
        batch = sign_flip_pvalues(d, np.random.default_rng(1), 3000)
        for row, p in zip(d, batch, strict=True):
            # exact rows are equal; Monte Carlo rows share the batch's patterns
            alone = sign_flip_pvalue(row, np.random.default_rng(1), 3000)
            assert p == pytest.approx(alone) if n <= EXACT_MAX_PAIRS else abs(p - alone) < 0.05


def step_down(p: np.ndarray) -> np.ndarray:
    """Holm's adjusted p-values, written as the definition reads."""
    k, order = p.size, np.argsort(p, kind="stable")
    adjusted, running = np.empty(k), 0.0
    for i, j in enumerate(order):
        running = max(running, min(1.0, (k - i) * p[j]))
        adjusted[j] = running
    return adjusted


def test_holm_is_the_step_down():
    rng = np.random.default_rng(1)
    for _ in range(50):
        p = rng.uniform(0.0, 0.2, size=rng.integers(1, 30))
        np.testing.assert_allclose(holm(p), step_down(p))
    np.testing.assert_allclose(holm([0.01, 0.04, 0.03, 0.5]), [0.04, 0.09, 0.09, 0.5])


LAWS = {
    "normal": lambda rng, size: rng.normal(size=size),
    # unit standard deviation: t₃ has variance 3, Laplace(b) 2b²
    "t3": lambda rng, size: rng.standard_t(3, size=size) / np.sqrt(3.0),
    "laplace": lambda rng, size: rng.laplace(scale=1.0 / np.sqrt(2.0), size=size),
}


def family_rejections(rng, law, n, k, families=FAMILIES, shift=0.0, resamples=2000):
    """Holm's rejections (families, k) of families of k comparisons of n pairs each;
    comparison 0 of each is shifted by ``shift`` (noise standard deviations), the rest are
    null. The Monte Carlo p-values (n > 26) use ``resamples`` patterns per family."""
    d = LAWS[law](rng, (families, k, n))
    d[:, 0] += shift
    if n <= EXACT_MAX_PAIRS:
        p = sign_flip_pvalues(d.reshape(-1, n)).reshape(families, k)
    else:
        p = np.stack([sign_flip_pvalues(f, rng, resamples) for f in d])
    return np.stack([holm(row) <= ALPHA for row in p])


def mc_bound(rate: float, trials: int) -> float:
    """Three Monte Carlo standard errors of a rate."""
    return 3.0 * np.sqrt(rate * (1.0 - rate) / trials)


@pytest.mark.parametrize("law", sorted(LAWS))
@pytest.mark.parametrize("n, k", [(5, 8), (10, 8), (20, 8), (50, 8), (5, 52), (12, 52), (50, 52)])
def test_the_family_wise_error_is_at_most_five_percent_under_the_null(law, n, k):
    rng = np.random.default_rng([n, k, len(law)])
    wrong = int(family_rejections(rng, law, n, k).any(axis=1).sum())
    assert wrong / FAMILIES <= ALPHA + mc_bound(ALPHA, FAMILIES)
    if n < pairs_needed(k):
        assert wrong == 0  # no sign pattern can reach α/K


@pytest.mark.parametrize(
    "law", ["normal", pytest.param("t3", marks=pytest.mark.slow),
            pytest.param("laplace", marks=pytest.mark.slow)],
)  # fmt: skip
def test_the_family_wise_error_at_fifty_two_comparisons_of_twenty_pairs(law):
    rng = np.random.default_rng([20, 52, len(law)])
    wrong = int(family_rejections(rng, law, 20, 52).any(axis=1).sum())
    assert wrong / FAMILIES <= ALPHA + mc_bound(ALPHA, FAMILIES)


@pytest.mark.parametrize("law", sorted(LAWS))
def test_a_shift_of_one_standard_deviation_is_resolved_four_times_in_five_at_twenty_pairs(law):
    rng = np.random.default_rng([3, len(law)])
    trials = 600
    hits = int(family_rejections(rng, law, 20, 8, trials, shift=1.0)[:, 0].sum())
    assert hits / trials >= 0.80 - mc_bound(0.8, trials)


def tidy(values: dict[tuple[str, str, float], np.ndarray], paths: int = 1) -> pd.DataFrame:
    """The episodes table: (controller, disturbance, level) → metric per (path, seed)."""
    rows = []
    for (ctrl, dist, level), x in values.items():
        for i, v in enumerate(x):
            rows.append(
                {"controller": ctrl, "disturbance": dist, "level": level, "path": i % paths,
                 "seed": i // paths, "episode": 0, "path_dist_rms": float(v)}
            )  # fmt: skip
    return pd.DataFrame(rows)


def test_the_comparisons_are_the_tests_of_the_paired_differences():
    rng = np.random.default_rng(11)
    ref = rng.uniform(1.0, 2.0, 12)
    values = {("ref", "none", 0.0): ref}
    shifts = {"a": 0.0, "b": 0.5, "c": -0.8}
    noise = {c: rng.normal(scale=0.3, size=12) for c in shifts}
    for c, s in shifts.items():
        values[(c, "none", 0.0)] = ref + s + noise[c]
    out = paired_comparisons(tidy(values), "path_dist_rms", "ref").set_index("controller")
    p = np.array([sign_flip_pvalue(shifts[c] + noise[c]) for c in sorted(shifts)])
    np.testing.assert_allclose(out.loc[sorted(shifts), "p_value"], p)
    np.testing.assert_allclose(out.loc[sorted(shifts), "p_holm"], holm(p))
    means = np.array([np.mean(shifts[c] + noise[c]) for c in sorted(shifts)])
    expected = np.where(holm(p) <= ALPHA, np.where(means < 0, "better", "worse"), "unresolved")
    assert list(out.loc[sorted(shifts), "mark"]) == list(expected)
    assert out.loc["b", "mark"] == "worse" and out.loc["c", "mark"] == "better"
    for c in shifts:  # the BCa interval of the mean contains the mean
        assert out.loc[c, "ci_low"] <= out.loc[c, "diff"] <= out.loc[c, "ci_high"]
    assert (out["comparisons"] == 3).all() and (out["pairs_needed"] == 7).all()
    assert (out["metric"] == "path_dist_rms").all()


def test_five_pairs_resolve_nothing_in_a_family_of_eight():
    ref = np.linspace(1.0, 2.0, 5)
    values = {("ref", "none", 0.0): ref}
    for i in range(8):
        values[(f"c{i}", "none", 0.0)] = ref * 10.0  # ten times worse, every pair
    out = paired_comparisons(tidy(values), "path_dist_rms", "ref")
    assert (out["mark"] == "unresolved").all()
    np.testing.assert_allclose(out["p_value"], 2 / 32)
    assert (out["pairs_needed"] == 9).all()


def test_pairs_are_matched_by_path_as_well_as_seed():
    # a path offset the pairing removes: by (path, seed), b − ref is +0.01 every time
    base = np.random.default_rng(3).uniform(0.1, 10.0, 24)
    df = tidy({("ref", "none", 0.0): base, ("b", "none", 0.0): base + 0.01}, paths=4)
    row = paired_comparisons(df, "path_dist_rms", "ref").iloc[0]
    assert row["pairs"] == 24 and row["mark"] == "worse"
    assert row["ci_low"] == pytest.approx(0.01) and row["ci_high"] == pytest.approx(0.01)
    shuffled = df.sample(frac=1.0, random_state=0)
    again = paired_comparisons(shuffled, "path_dist_rms", "ref").iloc[0]
    assert again["p_value"] == row["p_value"] and again["diff"] == pytest.approx(row["diff"])


def test_a_controller_absent_from_a_condition_is_not_in_the_family():
    ref = np.linspace(1.0, 2.0, 10)
    df = tidy({("ref", "none", 0.0): ref, ("a", "none", 0.0): ref + 1.0,
               ("ref", "impulse", 1.0): ref})  # fmt: skip
    out = paired_comparisons(df, "path_dist_rms", "ref")
    assert len(out) == 1 and out["comparisons"].item() == 1


def test_what_cannot_be_tested_is_refused_clearly():
    ref = np.linspace(1.0, 2.0, 6)
    df = tidy({("ref", "none", 0.0): ref, ("a", "none", 0.0): ref + 1.0})
    with pytest.raises(InvalidConfigError, match="unknown statistic 'median'"):
        paired_comparisons(df, "path_dist_rms", "ref", statistic="median")
    with pytest.raises(InvalidConfigError, match="no column"):
        paired_comparisons(df, "time_err_rms", "ref")
    with pytest.raises(InvalidConfigError, match="reference 'nobody'"):
        paired_comparisons(df, "path_dist_rms", "nobody")
    with pytest.raises(InvalidConfigError, match="alpha"):
        paired_comparisons(df, "path_dist_rms", "ref", alpha=1.5)
    one = tidy({("ref", "none", 0.0): ref[:1], ("a", "none", 0.0): ref[:1]})
    with pytest.raises(TooFewPairsError, match="needs ≥ 2"):
        paired_comparisons(one, "path_dist_rms", "ref")
    nan = df.copy()
    nan.loc[(nan["controller"] == "a") & (nan["seed"] > 0), "path_dist_rms"] = np.nan
    with pytest.raises(TooFewPairsError, match="1 paired episode"):
        paired_comparisons(nan, "path_dist_rms", "ref")
    with pytest.raises(InvalidConfigError, match="≥ 2 finite"):
        sign_flip_pvalue(np.array([1.0]))
