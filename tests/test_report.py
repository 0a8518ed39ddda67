"""The generated verdict (:mod:`train.evaluation.report`) on constructed results: a difference
the seeds cannot resolve is marked unresolved, a clear one is marked, the Bonferroni adjustment
un-resolves what only an unadjusted interval would resolve, and the tail metric is the
mean of the worst episodes."""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd
import pytest

from train.common.statistics import cvar, paired_comparisons
from train.evaluation.report import (
    aggregate,
    condition_table,
    normalized_scores,
    verdict_paragraph,
    worst_case_section,
    worst_case_sentence,
    write_report,
)


def frame(values: dict[tuple[str, str, float], np.ndarray]) -> pd.DataFrame:
    """Episodes: (controller, disturbance, level) → metric per seed."""
    rows = []
    for (ctrl, dist, level), x in values.items():
        for seed, v in enumerate(x):
            rows.append(
                {"controller": ctrl, "disturbance": dist, "level": level, "seed": seed,
                 "episode": 0, "path_dist_rms": float(v), "failed": 0}
            )  # fmt: skip
    return pd.DataFrame(rows)


def standardized(n: int, mean: float, sd: float, seed: int) -> np.ndarray:
    """n values with exactly this sample mean and standard deviation."""
    z = np.random.default_rng(seed).normal(size=n)
    z = (z - z.mean()) / z.std(ddof=1)
    return mean + sd * z


REF = np.linspace(1.0, 2.0, 20)


def test_a_constructed_tie_is_unresolved_and_clear_differences_are_marked():
    df = frame({
        ("ref", "impulse", 1.0): REF,
        ("tie", "impulse", 1.0): REF + standardized(20, 0.0, 0.05, 1),
        ("worse", "impulse", 1.0): 2.0 * REF,
        ("better", "impulse", 1.0): 0.5 * REF,
    })  # fmt: skip
    c = paired_comparisons(df, "path_dist_rms", "ref").set_index("controller")
    assert c.loc["tie", "mark"] == "unresolved"
    assert c.loc["tie", "ci_low"] < 0 < c.loc["tie", "ci_high"]
    assert c.loc["worse", "mark"] == "worse" and c.loc["better", "mark"] == "better"
    assert c.loc["worse", "diff"] == pytest.approx(REF.mean())
    assert c.loc["better", "ratio"] == pytest.approx(0.5)
    assert (c["comparisons"] == 3).all()
    text = verdict_paragraph(c.reset_index(), condition_table(df, "path_dist_rms"), "ref",
                             "path_dist_rms")  # fmt: skip
    assert "tie is not resolved in 1" in text
    assert "worse is worse in 1" in text
    assert "better is better in 1" in text
    assert "3 comparisons" in text and "fewer than 7 pairs" in text


def test_bonferroni_unresolves_what_one_unadjusted_interval_would_resolve():
    # paired differences with mean / standard error = 2.24: outside a 95% interval, inside
    # a (1 - 0.05/40) one
    shift = standardized(20, 0.5, 1.0, 2)
    alone = frame({("ref", "impulse", 1.0): REF, ("b", "impulse", 1.0): REF + shift})
    assert paired_comparisons(alone, "path_dist_rms", "ref")["mark"].item() == "worse"
    crowd = {("ref", "impulse", 1.0): REF, ("b", "impulse", 1.0): REF + shift}
    for level in range(2, 41):  # 39 more conditions: K = 40 comparisons
        crowd[("ref", "periodic", float(level))] = REF
        crowd[("b", "periodic", float(level))] = REF
    c = paired_comparisons(frame(crowd), "path_dist_rms", "ref")
    row = c[c["disturbance"] == "impulse"].iloc[0]
    assert row["comparisons"] == 40 and row["confidence"] == pytest.approx(1 - 0.05 / 40)
    assert row["mark"] == "unresolved"


def test_comparisons_are_paired_by_seed():
    # a per-seed offset that the pairing removes: unpaired, b - ref would be lost in the
    # spread of the seeds; paired, it is exactly +0.01 every time
    base = np.random.default_rng(3).uniform(0.1, 10.0, 20)
    df = frame({("ref", "none", 0.0): base, ("b", "none", 0.0): base + 0.01})
    row = paired_comparisons(df, "path_dist_rms", "ref").iloc[0]
    assert row["mark"] == "worse"
    assert row["ci_low"] == pytest.approx(0.01) and row["ci_high"] == pytest.approx(0.01)


def test_cvar_is_the_mean_of_the_worst_tenth():
    assert cvar(np.arange(1.0, 11.0)) == 10.0
    assert cvar(np.arange(1.0, 21.0)) == 19.5
    assert cvar(np.array([3.0, np.nan, 1.0])) == 3.0  # ceil(10% of 2) = 1 episode
    assert np.isnan(cvar(np.array([])))


def test_normalized_scores_are_decades_from_the_condition_median():
    df = frame(
        {
            ("a", "none", 0.0): np.full(4, 1e-4),
            ("b", "none", 0.0): np.full(4, 1e-3),
            ("a", "impulse", 1.0): np.full(4, 1.0),
            ("b", "impulse", 1.0): np.full(4, 0.1),
        }
    )
    scores, tasks = normalized_scores(df, "path_dist_rms")
    assert tasks == ["impulse 1", "undisturbed"]
    # medians: 0.55 and 5.5e-4
    np.testing.assert_allclose(scores["a"][0], np.log10([0.55 / 1.0, 5.5e-4 / 1e-4]))
    np.testing.assert_allclose(scores["b"][0], np.log10([0.55 / 0.1, 5.5e-4 / 1e-3]))


def test_the_aggregate_needs_no_rliable(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "rliable", None)  # import rliable raises ImportError
    df = frame({("ref", "none", 0.0): REF, ("b", "none", 0.0): 2 * REF})
    assert "| b |" in aggregate(df, "path_dist_rms", None, resamples=200)
    path = write_report(df, tmp_path, "path_dist_rms", "ref", ["missing/folder"], 2000)
    text = path.read_text()
    assert "b is worse in 1" in text
    assert "Missing: `missing/folder`" in text
    assert "| ref |" in text and (tmp_path / "aggregate.png").stat().st_size > 0
    assert (tmp_path / "comparisons.csv").exists()


def test_aggregate_is_reproducible(tmp_path):
    df = frame(
        {
            ("ref", "none", 0.0): REF,
            ("b", "none", 0.0): 2 * REF,
            ("ref", "impulse", 1.0): REF,
            ("b", "impulse", 1.0): 0.9 * REF,
        }
    )
    first = aggregate(df, "path_dist_rms", None, resamples=200)
    assert aggregate(df, "path_dist_rms", None, resamples=200) == first  # same seed, same CIs
    assert aggregate(df, "path_dist_rms", None, resamples=200, seed=1) != first
    with_plot = aggregate(df, "path_dist_rms", tmp_path, resamples=200)
    assert with_plot.startswith(first) and (tmp_path / "aggregate.png").stat().st_size > 0
    assert "| ref |" in first and "| b |" in first


def _rliable_interval(x, statistic, resamples, rng):
    """The reference: rliable's StratifiedBootstrap, its indices drawn from ``rng`` (rliable
    1.2 ignores ``random_state`` and draws from the global ``np.random``)."""
    from rliable import library as rly

    class Seeded(rly.StratifiedBootstrap):
        def update_indices(self):
            indices = self.generator.choice(self._num_items, self._args_shape, replace=True)
            return (indices, *self._strata_indices)

    bootstrap = Seeded(x, seed=rng)
    return statistic(x), bootstrap.conf_int(
        statistic, reps=resamples, size=0.95, method="percentile"
    )


@pytest.mark.parametrize("shape", [(5, 10), (24, 2), (7, 1), (3, 13)])
def test_stratified_bootstrap_equals_rliable_bit_for_bit(shape):
    pytest.importorskip("rliable", reason="the optional 'report' extra (the reference)")
    from rliable import metrics as rlm

    from train.common.statistics import iqm_and_mean, performance_profile, stratified_bootstrap

    x = np.random.default_rng(sum(shape)).standard_normal(shape) * np.linspace(0.5, 2, shape[1])
    taus = np.linspace(-2.0, 2.0, 41)
    cases = [
        (iqm_and_mean, lambda m: np.array([rlm.aggregate_iqm(m), rlm.aggregate_mean(m)])),
        (lambda b: performance_profile(b, taus), lambda m: (m.reshape(-1, 1) > taus).mean(axis=0)),
    ]
    for batch_statistic, statistic in cases:
        point, interval = stratified_bootstrap(x, batch_statistic, 300, np.random.default_rng(3))
        ref_point, ref_interval = _rliable_interval(x, statistic, 300, np.random.default_rng(3))
        np.testing.assert_array_equal(point, ref_point)
        np.testing.assert_array_equal(interval, ref_interval)


def test_stratified_bootstrap_resamples_runs_within_each_task():
    from train.common.statistics import iqm_and_mean, stratified_bootstrap

    # Every run equal within a task: any resample of runs within tasks is x itself, so the
    # interval collapses to the point (a bootstrap mixing tasks would not).
    x = np.tile(np.array([[0.0, 1.0, 5.0]]), (6, 1))
    point, interval = stratified_bootstrap(x, iqm_and_mean, 200, np.random.default_rng(0))
    np.testing.assert_array_equal(interval, np.vstack([point, point]))
    np.testing.assert_allclose(point, [1.6, 2.0])  # IQM of {0,1,5}×6: mean of 0,0,1×6,5,5
    # A wider spread of runs widens the interval; it always brackets the point here.
    y = np.random.default_rng(1).standard_normal((20, 3))
    p1, ci1 = stratified_bootstrap(y, iqm_and_mean, 500, np.random.default_rng(0))
    p3, ci3 = stratified_bootstrap(3 * y, iqm_and_mean, 500, np.random.default_rng(0))
    assert np.all(ci1[0] <= p1) and np.all(p1 <= ci1[1])
    np.testing.assert_allclose(ci3, 3 * ci1, rtol=1e-12)  # the same draws, scaled scores
    np.testing.assert_allclose(p3, 3 * p1, rtol=1e-12)


#: One row of a search's summary.csv: passivity's worst impulse at 2 J.
SEARCH_ROW = {
    "controller": "passivity", "family": "impulse", "energy_j": 2.0, "worst_rad": 0.06,
    "worst_search_rad": 0.06, "median_random_rad": 0.01, "worst_random_rad": 0.03,
    "worst_over_median": 6.0, "unstable_search": 0, "n_search": 200,
    "unstable_random": 0, "n_random": 200, "work_min_j": 0.5, "work_max_j": 3.5,
}  # fmt: skip


def search_folder(tmp_path):
    """A search folder with the config.yml of an impulse search at tuned gains on the iiwa."""
    import yaml

    folder = tmp_path / "adv"
    folder.mkdir()
    (folder / "config.yml").write_text(yaml.safe_dump({
        "env_id": "ptrack_gym/IiwaTrack-v0", "families": ["impulse"], "gains": "tuned",
        "budget": 200, "post_s": 1.5, "failure_distance_rad": 0.5}))  # fmt: skip
    return folder


def test_worst_case_section_reads_a_search_summary(tmp_path):

    folder = search_folder(tmp_path)
    row = dict(SEARCH_ROW)
    # a random draw found what the search missed: it is the worst case, and it is counted
    paper = {**row, "controller": "passivity_paper", "worst_rad": 0.5, "worst_search_rad": 0.04,
             "worst_random_rad": 0.5, "worst_over_median": 4.0, "unstable_random": 1}  # fmt: skip
    pd.DataFrame([row, paper]).to_csv(folder / "summary.csv", index=False)
    text = worst_case_section([folder])
    rows = text.splitlines()
    assert (
        "| Iiwa (tuned) | passivity | 2 | 0.06 | 0.06 | 0.01 | 6.0 | 0/200 | 0/200 | 0.50–3.50 |"
        in rows
    )
    assert (
        "| Iiwa (tuned) | passivity_paper | 2 | 0.5 | 0.04 | 0.01 | 4.0 | 0/200 | 1/200 "
        "| 0.50–3.50 |" in rows
    )
    sentence = worst_case_sentence([folder])
    assert "lowest worst case passivity (0.06 rad)" in sentence
    assert "unstable: passivity_paper 0/200 searched, 1/200 random" in sentence


def worked(values: dict[tuple[str, str, float], np.ndarray], idle: dict) -> pd.DataFrame:
    """:func:`frame` with the work ledger: 0.3 J per disturbed episode, except 0 J in the
    seeds ``idle[(disturbance, level)]`` (0 J throughout "none" and "payload")."""
    df = frame(values)
    work = np.where(df["disturbance"].isin(["none", "payload"]), 0.0, 0.3)
    for (dist, level), seeds in idle.items():
        work[((df["disturbance"] == dist) & (df["level"] == level) & df["seed"].isin(seeds))] = 0.0
    return df.assign(disturbance_work_j=work)


def test_a_condition_whose_disturbance_did_no_work_is_flagged_and_not_compared(tmp_path):
    """impulse 1: 3 of 5 episodes did no work (their onset came after the episode's end):
    the condition keeps its statistics but gets no mark, is out of K and the verdict."""
    ref = np.linspace(1.0, 2.0, 8)
    df = worked(
        {
            ("ref", "none", 0.0): ref, ("b", "none", 0.0): 2 * ref,
            ("ref", "impulse", 1.0): ref, ("b", "impulse", 1.0): 2 * ref,
            ("ref", "periodic", 1.0): ref, ("b", "periodic", 1.0): 2 * ref,
        },
        idle={("impulse", 1.0): [0, 2, 4]},
    )  # fmt: skip
    text = write_report(df, tmp_path, "path_dist_rms", "ref", [], 200, figures=False).read_text()
    assert "impulse 1: 3 of 8 episodes saw no disturbance (no work done): not compared" in text
    assert "over 2 conditions" in text and "b is worse in 2 (undisturbed, periodic 1" in text
    rows = [line for line in text.splitlines() if line.startswith("| impulse 1 |")]
    assert len(rows) == 2 and all("| not compared |" in line for line in rows)
    assert "| impulse 1 | b | 8 | 0 | 3 |" in text  # its statistics are still shown
    comparisons = pd.read_csv(tmp_path / "comparisons.csv")
    assert "impulse" not in set(comparisons["disturbance"])
    assert (comparisons["comparisons"] == 2).all()  # K: the compared conditions only
    # Every episode did work: the report is the one a table without the ledger gives.
    df.loc[df["disturbance"] == "impulse", "disturbance_work_j"] = 0.3

    def report(frame: pd.DataFrame) -> str:
        return write_report(frame, tmp_path, "path_dist_rms", "ref", [], 200, figures=False
                            ).read_text()  # fmt: skip

    every = report(df)
    assert every == report(df.drop(columns="disturbance_work_j"))
    assert "not compared" not in every and "over 3 conditions" in every


def test_a_payload_is_flagged_only_when_its_episode_equals_its_undisturbed_twin():
    """A payload does no work on the ledger (0 J when it acts): an episode of it saw no
    disturbance only if every metric equals the same controller's, seed's and episode's
    run under "none"."""
    from train.evaluation.results import no_disturbance

    ref = np.linspace(1.0, 2.0, 4)
    df = worked({("a", "none", 0.0): ref, ("a", "payload", 1.0): ref * [1, 3, 1, 3]}, idle={})
    assert no_disturbance(df).tolist() == [False] * 4 + [True, False, True, False]
    impulse = worked({("a", "impulse", 1.0): ref}, idle={("impulse", 1.0): [1]})
    assert no_disturbance(impulse).tolist() == [False, True, False, False]  # no twin needed


def test_the_summary_counts_and_the_headline_marks_episodes_without_a_disturbance():
    from train.evaluation.results import headline_table, summarize

    ref = np.linspace(1.0, 2.0, 5)
    df = worked(
        {("a", "none", 0.0): ref, ("a", "impulse", 1.0): ref, ("a", "periodic", 1.0): ref},
        idle={("impulse", 1.0): [1, 3]},
    )
    summary = summarize(df.assign(time_err_rms=0.0, speed_ratio_err=0.0, recovery_s=np.nan,
                                  tau_rms_frac=0.0), resamples=50)  # fmt: skip
    assert summary.set_index("disturbance")["no_disturbance_n"].to_dict() == {
        "impulse": 2, "none": 0, "periodic": 0,
    }  # fmt: skip
    lines = headline_table(summary, "path_dist_rms").splitlines()
    assert lines[3].startswith("| impulse 1 † |") and lines[4].startswith("| periodic 1 |")
    assert lines[-1] == (
        "† impulse 1: 2 of 5 episodes saw no disturbance (no work done): not compared"
    )


def test_a_search_at_gains_no_longer_shipped_is_labelled_stale(tmp_path):
    """The worst case of a search at tuned gains is only the shipped controller's while its
    recorded rates (worst.yml) are the ones in agents/tuned."""
    import yaml

    from agents.registry import pinned_rates, still_pinned, tuned_rates
    from ptrack_gym.robots import robot_profile

    folder = search_folder(tmp_path)
    pd.DataFrame([SEARCH_ROW]).to_csv(folder / "summary.csv", index=False)

    def record(rates: dict) -> None:
        cell = {"cost_rad": 0.06, "gains": rates}
        (folder / "worst.yml").write_text(
            yaml.safe_dump({"worst": {"passivity": {"impulse": {"2": cell}}}})
        )

    shipped = pinned_rates(robot_profile("iiwa"), "passivity", "tuned")  # what it records
    record(tuned_rates("iiwa", "passivity"))  # written before pins were complete: stale
    assert "| Iiwa (tuned earlier, stale) | passivity |" in worst_case_section([folder])
    record(shipped)
    assert "| Iiwa (tuned) | passivity |" in worst_case_section([folder])
    record({**shipped, "lam": shipped["lam"] * 2})
    text = worst_case_section([folder])
    assert "| Iiwa (tuned earlier, stale) | passivity |" in text
    assert "gains tuned earlier, stale" in text
    assert "Iiwa (tuned earlier, stale), impulse 2 J" in worst_case_sentence([folder])
    iiwa = robot_profile("iiwa")
    assert still_pinned(iiwa, "passivity", "tuned", shipped)
    assert not still_pinned(iiwa, "passivity", "tuned", {**shipped, "lam": shipped["lam"] * 2})
    assert not still_pinned(iiwa, "passivity", "tuned", tuned_rates("iiwa", "passivity"))
    assert not still_pinned(iiwa, "no_such_controller", "tuned", shipped)  # unknown: stale


def test_a_search_at_default_gains_since_changed_is_labelled_stale(tmp_path, monkeypatch):
    """A default-gain search records every numeric default rate it ran (worst.yml); once the
    default moves, it is labelled stale, and a search with rates of its own over the default
    (a given ζ) is judged against the default with those rates."""
    import yaml

    from agents import passivity, passivity_gains
    from agents.registry import pinned_rates
    from ptrack_gym.robots import robot_profile
    from train.evaluation.report import stale_search
    from train.studies.adversary_config import load_config as load_adversary
    from train.studies.worst_case import controller_gains

    folder = search_folder(tmp_path)
    cfg = yaml.safe_load((folder / "config.yml").read_text())
    cfg["gains"] = "default"
    search = load_adversary(None, ["env_id=ptrack_gym/IiwaTrack-v0", "gains=default"])
    ran = controller_gains(search, "passivity")  # what the search runs and records
    assert ran == pinned_rates(robot_profile("iiwa"), "passivity", "default")
    (folder / "worst.yml").write_text(
        yaml.safe_dump({"worst": {"passivity": {"impulse": {"2": {"gains": ran}}}}})
    )
    given = {**cfg, "rates": {"passivity": {"damping_ratio": 0.5}}}
    assert not stale_search(folder, cfg) and stale_search(folder, given)
    moved = {**passivity_gains.DEFAULT_RATES, "damping_ratio": 0.3}
    for where in (passivity, passivity_gains):
        monkeypatch.setattr(where, "DEFAULT_RATES", moved)
    assert stale_search(folder, cfg)
    (folder / "worst.yml").write_text(  # a search at the default with a ζ of its own
        yaml.safe_dump({"worst": {"passivity": {"impulse": {"2": {"gains": {
            **ran, "damping_ratio": 0.5}}}}}})
    )  # fmt: skip
    assert not stale_search(folder, given)  # its own ζ, over a default that moved elsewhere
    (folder / "worst.yml").write_text(  # written before rates were recorded: not checkable
        yaml.safe_dump({"worst": {"passivity": {"impulse": {"2": {"gains": "default"}}}}})
    )
    assert not stale_search(folder, cfg)
    pd.DataFrame([SEARCH_ROW]).to_csv(folder / "summary.csv", index=False)
    (folder / "config.yml").write_text(yaml.safe_dump(cfg))
    assert "| Iiwa (default, rates unrecorded) | passivity |" in worst_case_section([folder])
