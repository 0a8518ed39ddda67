"""``ptrack verdict``: the study across robots and random test paths runs, resumes, pairs by
(path, seed), refuses bad input before any episode; the hierarchical bootstrap it
aggregates with resamples paths, then seeds."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest

import train.studies.verdict_paths as verdict_paths
import train.studies.verdict_study as vs
from ptrack_gym.errors import InvalidConfigError
from train.common.statistics import bootstrap_ci, hierarchical_bootstrap
from train.evaluation.rate_record import RATES_KEY
from train.studies.verdict_entrants import tank_markdown
from train.studies.verdict_study import VerdictConfig, load_frame, run_verdict


def tiny(out, **kw) -> VerdictConfig:
    """Two-link, 3 controllers, 2 test paths, undisturbed + periodic, 3 seeds: 1-s episodes
    at 250 Hz (36 episodes)."""
    base = dict(
        robots=["two_link"], controllers=["passivity", "computed_torque", "pd_gravity"],
        gains="default", test_paths=[1, 2], disturbances=["none", "periodic"], levels=[1.0],
        seeds=3, episode_s=1.0, control_hz=250.0, resamples=2000, workers=1, out=str(out),
    )  # fmt: skip
    base.update(kw)
    return VerdictConfig(**base)


def test_a_tiny_study_runs_pairs_by_path_and_seed_and_resumes(tmp_path):
    cfg = tiny(tmp_path / "v")
    out = run_verdict(cfg, progress=False)
    df = load_frame(out / "episodes.csv")
    assert len(df) == 1 * 2 * 2 * 3 * 3
    assert set(df["path"]) == {"1", "2"} and set(df["robot"]) == {"two_link"}
    # the two paths are different paths: the same seed gives other numbers on each
    one = df[(df["controller"] == "pd_gravity") & (df["disturbance"] == "none")]
    assert one.groupby("path")["path_dist_rms"].mean().nunique() == 2
    rivals = pd.read_csv(out / "rivals.csv")
    assert set(rivals["metric"]) == {"path_dist_rms", "time_err_rms"}
    assert (rivals["pairs"] == 2 * 3).all()  # (path, seed) pairs, not seeds alone
    agg = pd.read_csv(out / "aggregates.csv")
    assert (agg["paths"] == 2).all() and (agg["episodes"] == 6).all()
    text = (out / "verdict.md").read_text()
    assert "| two_link | path distance |" in text and "## two_link" in text
    # path by path: each path's own test on its 3 seeds, every condition counted once
    paths = pd.read_csv(out / "paths.csv")
    assert len(paths) == 2 * 2 and set(paths["path"]) == {1, 2}
    assert (paths["pairs"] == 3).all()
    assert (paths[["wins", "ties", "losses"]].sum(axis=1) == paths["conditions"]).all()
    assert (paths["conditions"] == 2).all()
    assert "Path by path" in text and (out / "verdict.png").stat().st_size > 0
    assert "| condition | two_link |" in text and "| periodic 1 |" in text  # the grid

    # an interrupted run: drop the last 5 rows; the resume runs exactly those again
    lines = (out / "episodes.csv").read_text().splitlines(keepends=True)
    (out / "episodes.csv").write_text("".join(lines[:-5]))
    calls = []
    real = vs.run_one

    def counting(*args):
        calls.append(args[1:])
        return real(*args)

    vs.run_one = counting
    try:
        run_verdict(cfg, resume=True, progress=False)
    finally:
        vs.run_one = real
    assert len(calls) == 5
    again = load_frame(out / "episodes.csv")
    pd.testing.assert_frame_equal(
        again.drop(columns="wall_s"), df.drop(columns="wall_s"), check_exact=True
    )


def test_the_grid_reads_each_robots_ratio_outcome_and_failures_in_its_cell():
    rivals = pd.DataFrame(
        {
            "robot": ["a", "a", "b", "b", "a"],
            "disturbance": ["push", "none", "push", "none", "push"],
            "level": [1, 0, 1, 0, 1],
            "metric": ["path_dist_rms"] * 4 + ["time_err_rms"],
            "ratio": [0.44, 2.8, 14716.0, 1.0, 30.0],
            "outcome": ["wins", "loses", "loses", "ties", "loses"],
        }
    )
    episodes = pd.DataFrame(
        {
            "robot": ["b"] * 3 + ["a"],
            "controller": ["passivity", "passivity", "rival", "passivity"],
            "disturbance": ["push", "push", "push", "push"],
            "level": ["1", "1", "1", "1"],
            "failed": [True, False, True, False],
        }
    )
    text = vs.grid_table(rivals, ["b", "c", "a"], "path_dist_rms", episodes, "passivity")
    lines = text.splitlines()
    assert lines[0] == "| condition | b | a |"  # a robot without rows gets no column
    assert lines[2] == "| undisturbed | 1 ties | 2.8 loses |"  # undisturbed first
    # the focus's own failures (not the rival's), a large ratio in full, a win in bold
    assert lines[3] == "| push 1 | 14,716 loses (1/2 failed) | **0.44 wins** |"
    assert len(lines) == 4
    time = vs.grid_table(rivals, ["a", "b"], "time_err_rms", episodes, "passivity")
    assert time.splitlines() == ["| condition | a |", "|---|---|", "| push 1 | 30 loses |"]
    assert vs.grid_table(rivals.iloc[:0], ["a"], "path_dist_rms", episodes, "passivity") == ""


def test_a_paths_features_are_those_of_the_path_its_env_builds():
    import gymnasium as gym

    from ptrack_gym.robots import ROBOTS

    for robot, seed in (("two_link", 3), ("iiwa", 1)):
        feats = verdict_paths.path_features(robot, seed)
        env = gym.make(ROBOTS[robot].env_id, path="random", path_seed=seed)
        try:
            path = env.unwrapped.path
            q = path.evaluate(np.linspace(0.0, path.period_s, 512, endpoint=False))[0]
        finally:
            env.close()
        assert feats["period_s"] == path.period_s and 4.0 <= feats["period_s"] <= 8.0
        assert feats["amplitude_rad"] == pytest.approx(np.ptp(q, axis=0).max() / 2, rel=1e-12)


def test_path_outcomes_are_the_rival_test_on_each_paths_pairs_alone():
    """A path where the focus is clearly lower everywhere counts wins, one where it is
    clearly higher counts losses: the per-path test does not pool the paths."""

    rng = np.random.default_rng(0)
    rows = []
    for path, focus_scale in (("1", 0.5), ("2", 2.0)):
        for dist in ("none", "impulse"):
            for seed in range(10):
                base = 1.0 + 0.05 * rng.standard_normal()
                for ctrl, scale in (("passivity", focus_scale), ("computed_torque", 1.0),
                                    ("pd_gravity", 3.0)):  # fmt: skip
                    value = base * scale
                    rows.append({"robot": "two_link", "path": path, "controller": ctrl,
                                 "disturbance": dist, "level": 1.0, "seed": seed, "episode": 0,
                                 "path_dist_rms": value, "time_err_rms": value})  # fmt: skip
    controllers = ["passivity", "computed_torque", "pd_gravity"]
    out = verdict_paths.path_outcomes(["two_link"], controllers, 2000, pd.DataFrame(rows))
    out = out.set_index(["path", "metric"])
    assert (
        out.loc[(1, "path_dist_rms"), "wins"] == 2 and out.loc[(1, "path_dist_rms"), "losses"] == 0
    )
    assert (
        out.loc[(2, "path_dist_rms"), "losses"] == 2 and out.loc[(2, "path_dist_rms"), "wins"] == 0
    )
    assert out.loc[(2, "time_err_rms"), "ratio_median"] == pytest.approx(2.0)


def test_a_resume_at_changed_gains_is_refused_or_reruns_exactly_those_rows(tmp_path, monkeypatch):
    """``config.yml`` records every controller's rates; a resume after one controller was
    tuned again is refused naming it, and with ``rerun_changed`` runs exactly its rows again
    (at the new gains) and keeps every other row."""
    import shutil

    import yaml

    import agents.registry as registry

    tuned = tmp_path / "tuned"
    tuned.mkdir()
    controllers = ["passivity", "computed_torque", "pd_gravity"]
    for c in controllers:
        shutil.copy(registry.TUNED_DIR / f"two_link-{c}.yml", tuned)
    monkeypatch.setattr(registry, "TUNED_DIR", tuned)
    monkeypatch.setattr(vs, "TUNED_DIR", tuned)  # where it reads the validation paths
    cfg = tiny(tmp_path / "v", gains="tuned", disturbances=["none"], seeds=2)
    out = run_verdict(cfg, progress=False)
    before = load_frame(out / "episodes.csv")
    omega = yaml.safe_load((tuned / "two_link-passivity.yml").read_text())["rates"]["omega"]
    saved = yaml.safe_load((out / "config.yml").read_text())
    assert saved[RATES_KEY]["two_link"]["passivity"]["omega"] == omega
    run_verdict(cfg, resume=True, progress=False)  # same gains: resumes, nothing to run

    record = yaml.safe_load((tuned / "two_link-passivity.yml").read_text())
    record["rates"]["omega"] = 0.5 * omega  # passivity tuned again
    (tuned / "two_link-passivity.yml").write_text(yaml.safe_dump(record))
    with pytest.raises(InvalidConfigError, match="gains of passivity on two_link changed"):
        run_verdict(cfg, resume=True, progress=False)
    pd.testing.assert_frame_equal(load_frame(out / "episodes.csv"), before)  # nothing lost

    calls = []
    real_run = vs.run_one

    def counting(*args):
        calls.append(args[3].controller)
        return real_run(*args)

    monkeypatch.setattr(vs, "run_one", counting)
    run_verdict(cfg, resume=True, progress=False, rerun_changed=True)
    assert calls == ["passivity"] * 4  # 2 paths x 2 seeds; the others' rows kept
    after = load_frame(out / "episodes.csv")
    key = ["controller", "path", "seed"]
    old = before.set_index(key).sort_index()["path_dist_rms"]
    new = after.set_index(key).sort_index()["path_dist_rms"]
    assert len(after) == len(before)
    others = old.index.get_level_values(0) != "passivity"
    pd.testing.assert_series_equal(new[others], old[others])
    assert (new[~others] != old[~others]).all()  # ran again, at the new ω
    saved = yaml.safe_load((out / "config.yml").read_text())
    assert saved[RATES_KEY]["two_link"]["passivity"]["omega"] == 0.5 * omega

    # the same rates, but recorded before the passivity laws' gain rules changed (loop 6 of
    # docs/control_rates.md: no gain_rules key): refused, then only passivity runs again
    assert saved[RATES_KEY]["two_link"]["passivity"]["gain_rules"] == 2
    assert "gain_rules" not in saved[RATES_KEY]["two_link"]["computed_torque"]
    earlier = yaml.safe_load(yaml.safe_dump(saved))
    del earlier[RATES_KEY]["two_link"]["passivity"]["gain_rules"]
    (out / "config.yml").write_text(yaml.safe_dump(earlier))
    with pytest.raises(InvalidConfigError, match="gains of passivity on two_link changed"):
        run_verdict(cfg, resume=True, progress=False)
    calls.clear()
    run_verdict(cfg, resume=True, progress=False, rerun_changed=True)
    assert calls == ["passivity"] * 4
    pd.testing.assert_series_equal(  # the same gains: the same numbers
        load_frame(out / "episodes.csv").set_index(key).sort_index()["path_dist_rms"], new
    )
    saved = yaml.safe_load((out / "config.yml").read_text())

    del saved[RATES_KEY]  # a run written before the record: cannot be checked
    (out / "config.yml").write_text(yaml.safe_dump(saved))
    with pytest.raises(InvalidConfigError, match="records no rates"):
        run_verdict(cfg, resume=True, progress=False)
    calls.clear()  # ... unless every model-based row runs again
    run_verdict(cfg, resume=True, progress=False, rerun_changed=True)
    assert sorted(calls) == sorted(controllers * 4)
    pd.testing.assert_series_equal(
        load_frame(out / "episodes.csv").set_index(key).sort_index()["path_dist_rms"], new
    )
    # a results file with a header alone and no record: nothing ran, nothing to check
    header = (out / "episodes.csv").read_text().splitlines()[0] + "\n"
    (out / "episodes.csv").write_text(header)
    (out / "config.yml").write_text(yaml.safe_dump(saved))  # still without a record
    calls.clear()
    run_verdict(cfg, resume=True, progress=False)
    assert len(calls) == len(before)


def test_an_existing_study_is_refused_without_resume_or_force(tmp_path):
    cfg = tiny(tmp_path / "v", test_paths=[1], seeds=1, disturbances=["none"])
    run_verdict(cfg, progress=False)
    with pytest.raises(InvalidConfigError):
        run_verdict(cfg, progress=False)


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("robots", ["atlas"], "unknown 'atlas'"),
        ("robots", [], "robots must be a non-empty list"),
        ("controllers", ["nope"], "unknown 'nope'"),
        ("disturbances", ["wind"], "unknown 'wind'"),
        ("test_paths", [], "test_paths must be a non-empty list"),
        ("test_paths", [1, 1], "duplicates"),
        ("levels", [0.0], "levels must be positive"),
        ("levels_of", {"periodic": []}, "levels must be positive"),
        ("levels_of", {"push": [1.0]}, "levels_of: presets of disturbances"),
        ("levels_of", {"none": [1.0]}, "levels_of: presets of disturbances"),
        ("seeds", 0, "seeds must be an integer >= 1"),
        ("gains", "best", "gains must be one of"),
        # a preset the robot cannot take here: the impulse's onset window does not fit 1 s
        ("disturbances", ["none", "impulse"], "two_link cannot take impulse 1: .*onset_s"),
    ],
)
def test_bad_input_is_refused_before_any_episode(tmp_path, field, value, match):
    with pytest.raises(InvalidConfigError, match=match):
        run_verdict(tiny(tmp_path / "v", **{field: value}), progress=False)
    assert not (tmp_path / "v" / "episodes.csv").exists()


def test_a_preset_may_have_its_own_levels() -> None:
    cfg = tiny("/nonexistent", disturbances=["none", "periodic", "noise"], levels=[1.0],
               levels_of={"noise": [1.0, 2.0]})  # fmt: skip
    cfg.validate()
    assert cfg.conditions() == [("none", 0.0), ("periodic", 1.0), ("noise", 1.0), ("noise", 2.0)]


def test_a_test_path_seed_without_an_admissible_path_is_refused(tmp_path, no_admissible_path):
    no_admissible_path(2)
    with pytest.raises(InvalidConfigError, match="test path seed 2 on two_link: no admissible"):
        run_verdict(tiny(tmp_path / "v"), progress=False)
    assert not (tmp_path / "v" / "episodes.csv").exists()


def test_tuned_gains_chosen_on_a_test_path_are_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(vs, "tuned_rates", lambda robot, c: {})
    monkeypatch.setattr(vs, "tuned_validation_paths", lambda robot, c: {2, 9001})
    with pytest.raises(InvalidConfigError, match=r"tuned on paths \[2\], which are test paths"):
        run_verdict(tiny(tmp_path / "v", gains="tuned"), progress=False)
    monkeypatch.setattr(vs, "tuned_validation_paths", lambda robot, c: {9001})
    tiny(tmp_path / "w", gains="tuned").validate()  # other paths: accepted


def test_missing_tuned_gains_are_refused_naming_the_pair(tmp_path, monkeypatch):
    import agents.registry as registry

    monkeypatch.setattr(registry, "TUNED_DIR", tmp_path / "tuned")  # no tuned gains at all
    with pytest.raises(InvalidConfigError, match="no tuned gains for passivity on two_link"):
        tiny(tmp_path / "v", gains="tuned").validate()


# -- the hierarchical bootstrap --------------------------------------------------------------
def test_hierarchical_estimate_weighs_every_path_the_same_and_drops_nan():
    x = np.array([1.0, 1.0, 1.0, 1.0, 5.0, np.nan])
    c = np.array(["a", "a", "a", "a", "b", "b"])
    est, lo, hi = hierarchical_bootstrap(x, c, 500, seed=1)
    assert est == pytest.approx(3.0)  # (1 + 5) / 2, not the pooled mean 1.8
    assert 1.0 <= lo <= est <= hi <= 5.0
    assert hierarchical_bootstrap(x, c, 500, seed=1) == (est, lo, hi)  # seeded
    assert all(np.isnan(hierarchical_bootstrap(np.array([np.nan]), np.array([0]), 10, 0)))


def test_hierarchical_interval_covers_where_a_flat_one_does_not():
    """Paths differ (σ_path = σ_seed): over 200 simulated studies of 8 paths × 10 seeds the
    two-stage 95 % interval covers the true mean far more often than a flat bootstrap over
    episodes, which ignores the path-to-path spread. (Percentile intervals over 8 clusters
    undercover a little: ~0.88 here.)"""
    rng = np.random.default_rng(0)
    hits_h = hits_f = 0
    for r in range(200):
        x = (rng.normal(0, 1, 8)[:, None] + rng.normal(0, 1, (8, 10))).ravel()
        c = np.repeat(np.arange(8), 10)
        _, lo, hi = hierarchical_bootstrap(x, c, 1000, seed=r)
        hits_h += lo <= 0.0 <= hi
        lo_f, hi_f = bootstrap_ci(x, np.mean, 1000, seed=r)
        hits_f += lo_f <= 0.0 <= hi_f
    assert hits_h / 200 >= 0.82
    assert hits_f / 200 <= hits_h / 200 - 0.2


# -- learned entrants ----------------------------------------------------------------------
@pytest.fixture(scope="module")
def residual_run(tmp_path_factory):
    """A 100-step SAC residual over PD + gravity on the two-link (250 Hz, 1-s episodes)."""
    pytest.importorskip("stable_baselines3")
    from train.rl.config import parse_args
    from train.rl.run import run

    out = tmp_path_factory.mktemp("entrant") / "run"
    run(parse_args([
        "--algo", "sac", "--residual", "pd_gravity", "--steps", "100", "--out", str(out),
        "--episode-s", "1.0", "--eval-freq", "1000", "--checkpoint-freq", "1000",
        "--disturbance", "periodic:1.0", "--hp", "learning_starts=50", "--hp",
        "batch_size=16", "--hp", "policy_kwargs=dict(net_arch=[16])",
    ]))  # fmt: skip
    return out


def test_an_entrant_is_judged_on_the_test_paths_against_its_base(tmp_path, residual_run):
    name = f"sb3:{residual_run}"
    cfg = tiny(tmp_path / "v", seeds=2, entrants={"two_link": [name]})
    out = run_verdict(cfg, progress=False)
    df = load_frame(out / "episodes.csv")
    mine = df[df["controller"] == name]
    assert set(mine["path"]) == {"1", "2"} and len(mine) == 2 * 2 * 2
    assert (mine["steps"] == 250).all()  # its own control rate, 1-s episodes
    entrants = pd.read_csv(out / "entrants.csv")
    assert set(entrants["controller"]) == {name} and set(entrants["reference"]) == {"pd_gravity"}
    assert set(entrants["metric"]) == {"path_dist_rms", "time_err_rms"}
    assert (entrants["pairs"] == 2 * 2).all()  # (path, seed) pairs
    rivals = pd.read_csv(out / "rivals.csv")
    assert name not in set(rivals["rival"])  # not a rival of the passivity controller
    text = (out / "verdict.md").read_text()
    assert "## Learned entrants on the test paths" in text
    groups = pd.read_csv(out / "entrant_groups.csv")  # one seed: its own ratio is the IQM
    assert len(groups) == len(entrants) and (groups["seeds"] == 1).all()
    assert np.allclose(groups["iqm_ratio"], entrants["ratio"], rtol=1e-5)
    assert f"the one a model card ships): run: {name}." in text
    assert (
        f"| {name} | two_link | sac | 100 | – | the default path | periodic:1.0 | ±0 | – |" in text
    )


#: The tank entrant's balance bound here: the tiny study's episodes of the passivity law
#: with no residual at all reach 0.007 J of excess at most (its discrete residue at 250 Hz;
#: the bound leaves room for the residue of the trajectory the residual makes).
RESIDUE_J = 0.05


@pytest.fixture(scope="module")
def tank_run(tmp_path_factory):
    """A 100-step SAC residual over the passivity controller through an energy tank."""
    pytest.importorskip("stable_baselines3")
    from train.rl.config import parse_args
    from train.rl.run import run

    out = tmp_path_factory.mktemp("tank") / "run"
    run(parse_args([
        "--algo", "sac", "--residual", "passivity", "--tank", "--steps", "100", "--out",
        str(out), "--episode-s", "1.0", "--eval-freq", "1000", "--checkpoint-freq", "1000",
        "--disturbance", "periodic:1.0", "--hp", "learning_starts=50", "--hp",
        "batch_size=16", "--hp", "policy_kwargs=dict(net_arch=[16])",
    ]))  # fmt: skip
    return out


def test_a_tank_entrants_tank_is_recorded_in_every_episode(tmp_path, residual_run, tank_run):
    tank, plain = f"sb3:{tank_run}", f"sb3:{residual_run}"
    cfg = tiny(tmp_path / "v", seeds=2, entrants={"two_link": [tank, plain]})
    out = run_verdict(cfg, progress=False)
    assert vs.columns(cfg)[-5:] == (
        "tank_overdrawn_j",
        "tank_withheld_j",
        "balance_excess_j",
        "tank_created_j",
        "tank_arm_gained_j",
    )
    df = load_frame(out / "episodes.csv", vs.columns(cfg))
    mine = df[df["controller"] == tank]
    assert len(mine) == 2 * 2 * 2 and mine["tank_withheld_j"].notna().all()
    # the plant is the model here: the gate's prediction holds, the tank goes below 0 only
    # by what it paid for the periodic disturbance's work on the arm (0.14 J) or the law
    # created, never undisturbed, and storage + tank stay near the law's own discrete
    # residue (≤ 0.007 J measured at 250 Hz on these paths with no residual at all)
    paid = mine["tank_created_j"] + mine["tank_arm_gained_j"]
    assert (mine["tank_overdrawn_j"] <= paid).all()
    assert (mine.loc[mine["disturbance"] == "none", "tank_overdrawn_j"] == 0.0).all()
    assert mine["balance_excess_j"].notna().all() and (mine["balance_excess_j"] <= RESIDUE_J).all()
    # the passivity law run alone keeps its own ledger (T = 0), the same residue bound:
    # what a residual's excess is read against
    law = df[df["controller"] == "passivity"]
    assert len(law) == 2 * 2 * 2 and law["tank_overdrawn_j"].isna().all()
    assert law["balance_excess_j"].notna().all() and (law["balance_excess_j"] <= RESIDUE_J).all()
    assert (law["balance_excess_j"] >= 0.0).all()  # x_0 = 0 is among the steps
    others = ~df["controller"].isin([tank, "passivity"])  # no storage, no ledger
    assert df.loc[others, list(vs.TANK_COLUMNS)].isna().all().all()
    text = (out / "verdict.md").read_text()
    over = int((mine["tank_overdrawn_j"] > 0.0).sum())
    assert "The energy tanks" in text and f"| two_link | {tank} | 8 | {over} |" in text
    assert "The storage balance" in text and "| two_link | run | periodic 1 | 4 |" in text
    assert "| two_link | passivity | periodic 1 | 4 |" in text
    assert (mine["tank_created_j"] >= 0.0).all() and (mine["tank_arm_gained_j"] >= 0.0).all()
    # files written before the balance, the created-energy and the arm's columns load, NaN
    lines = (out / "episodes.csv").read_text().splitlines()
    older = tmp_path / "older.csv"
    older.write_text("\n".join(line.rsplit(",", 3)[0] for line in lines) + "\n")
    later = ["balance_excess_j", "tank_created_j", "tank_arm_gained_j"]
    assert load_frame(older)[later].isna().all().all()
    assert "| – | – | – | – |" in tank_markdown(load_frame(older))
    # a study without entrants keeps its columns (the committed verdict's)
    assert vs.columns(tiny(tmp_path / "w")) == vs.COLUMNS


def test_the_laws_own_ledger_balances_a_pushs_work_and_not_a_wrong_model():
    """The balance of the passivity law run alone (``EpisodeBalance``, T = 0) on the exact
    plant stays at its undisturbed discrete residue however much work an impulse does (W_d
    is in the ledger, at the step's end as the residual wrapper counts it: one step late
    shows as ~0.03 J here, left out ~0.4 J), and grows by orders of magnitude when the
    plant's masses are not the model's (``mismatch``: the law's storage is of its model) —
    the base's share a residual's excess is read against. A controller without a storage
    keeps no ledger; a law that diverges is +inf, at its first step too."""
    import gymnasium as gym

    from agents.policy import ControllerPolicy
    from agents.registry import make_controller
    from train.evaluation.episode import EpisodeSettings, Task, rollout, run_episode
    from train.studies.verdict_entrants import EpisodeBalance

    settings = EpisodeSettings(
        "ptrack_gym/TwoLinkTrack-v0", 5.0, 250.0, "on_path", 0.5, 0.01, path="random",
        path_seed=1,
    )  # fmt: skip

    def run(controller: str, dist: str, seed: int) -> dict:
        balance = EpisodeBalance()
        return run_episode(
            Task(controller, dist, 1.0, seed, 0), settings, inspect=balance.inspect,
            on_step=balance.on_step,
        )[0]  # fmt: skip

    excess, pushed_off = {}, {}
    for dist in ("none", "impulse", "mismatch"):
        for seed in (0, 1):
            row = run("passivity", dist, seed)
            excess[dist, seed] = row["balance_excess_j"]
            pushed_off[dist, seed] = row["path_dist_max"]
            assert math.isnan(row["tank_overdrawn_j"])
    for seed in (0, 1):
        assert pushed_off["impulse", seed] > 5 * pushed_off["none", seed]  # it was pushed
        assert 0.0 <= excess["none", seed] <= RESIDUE_J
        assert excess["none", seed] <= excess["impulse", seed] <= excess["none", seed] + 1e-3
        assert excess["mismatch", seed] > 10 * excess["none", seed]
    assert math.isnan(run("pd_gravity", "none", 0)["balance_excess_j"])
    # a law whose torque turns non-finite ends the episode (rollout's divergence branch)
    env = gym.make("ptrack_gym/TwoLinkTrack-v0", control_hz=250.0, path="random", path_seed=1)
    for at_step in (0, 3):
        ctrl = make_controller("passivity", env, "default")
        law_step, calls = ctrl.step, [0]

        def failing_step(q, qd, dt, law_step=law_step, calls=calls, at_step=at_step):
            calls[0] += 1
            tau = law_step(q, qd, dt)
            return tau * np.nan if calls[0] > at_step else tau

        ctrl.step = failing_step
        balance = EpisodeBalance()
        record, _ = rollout(env, ControllerPolicy(env, ctrl), 0, on_step=balance.on_step)
        assert record.unstable and len(record.t_s) == at_step
        assert balance.inspect(env)["balance_excess_j"] == math.inf
    env.close()


def test_bad_entrants_are_refused_before_any_episode(tmp_path, residual_run):
    import shutil

    import yaml

    name = f"sb3:{residual_run}"
    with pytest.raises(InvalidConfigError, match="not sb3:<run folder>"):
        tiny(tmp_path / "a", entrants={"two_link": ["pd_gravity"]}).validate()
    with pytest.raises(InvalidConfigError, match="a list of distinct names"):
        tiny(tmp_path / "a", entrants={"two_link": None}).validate()
    with pytest.raises(InvalidConfigError, match="not one of the robots"):
        tiny(tmp_path / "a", entrants={"iiwa": [name]}).validate()
    with pytest.raises(InvalidConfigError, match="is compared with pd_gravity, which is not"):
        tiny(tmp_path / "a", controllers=["passivity", "computed_torque"],
             entrants={"two_link": [name]}).validate()  # fmt: skip
    with pytest.raises(InvalidConfigError, match="base ran with default gains"):
        with pytest.MonkeyPatch.context() as m:
            m.setattr(vs, "tuned_rates", lambda robot, c: {})
            m.setattr(vs, "tuned_validation_paths", lambda robot, c: set())
            tiny(tmp_path / "a", gains="tuned", entrants={"two_link": [name]}).validate()
    seen = tmp_path / "seen"  # a copy of the run that trained on test path 2
    shutil.copytree(residual_run, seen)
    saved = yaml.safe_load((seen / "config.yml").read_text())
    saved["config"]["train_paths"] = [2, 40]
    (seen / "config.yml").write_text(yaml.safe_dump(saved))
    with pytest.raises(InvalidConfigError, match=r"paths \[2\], test paths here"):
        run_verdict(tiny(tmp_path / "b", entrants={"two_link": [f"sb3:{seen}"]}), progress=False)
    assert not (tmp_path / "b" / "episodes.csv").exists()
    moved = tmp_path / "moved"  # a copy whose base ran at default rates since changed
    shutil.copytree(residual_run, moved)
    saved = yaml.safe_load((moved / "config.yml").read_text())
    assert saved["derived"]["base_rates"]  # pinned when it trained
    saved["derived"]["base_rates"]["omega"] = 7.0
    (moved / "config.yml").write_text(yaml.safe_dump(saved))
    with pytest.raises(InvalidConfigError, match="base ran at default rates since changed"):
        tiny(tmp_path / "c", entrants={"two_link": [f"sb3:{moved}"]}).validate()
    with pytest.raises(InvalidConfigError, match=r"runs at 250 Hz, the verdict's controllers "
                       r"at 1000 Hz: .* set control_hz: 250"):  # fmt: skip
        tiny(tmp_path / "d", control_hz=1000.0, entrants={"two_link": [name]}).validate()


# -- Ray -------------------------------------------------------------------------------------
def test_a_bad_backend_and_ray_without_its_extra_are_refused(tmp_path, monkeypatch):
    import importlib.util

    with pytest.raises(InvalidConfigError, match="backend must be 'process' or 'ray'"):
        tiny(tmp_path / "v", backend="dask").validate()
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "ray" else real(name, *a)
    )
    with pytest.raises(InvalidConfigError, match="needs the optional 'ray' extra"):
        tiny(tmp_path / "v", backend="ray").validate()


@pytest.mark.slow  # Ray's start takes most of a minute: make test-slow
def test_the_ray_backend_gives_the_rows_of_the_process_pool(tmp_path):
    pytest.importorskip("ray")
    pool = load_frame(run_verdict(tiny(tmp_path / "p", seeds=2), progress=False) / "episodes.csv")
    ray_out = run_verdict(tiny(tmp_path / "r", seeds=2, backend="ray", workers=2), progress=False)
    on_ray = load_frame(ray_out / "episodes.csv")
    cols = [c for c in pool.columns if c != "wall_s"]
    pd.testing.assert_frame_equal(pool[cols], on_ray[cols])


def test_no_task_starts_no_ray():
    from train.common.ray_tasks import ray_results

    ray = pytest.importorskip("ray")
    assert list(ray_results(print, [], 2)) == [] and not ray.is_initialized()


def test_a_recorded_runs_config_reads_back_as_its_settings() -> None:
    """A study's ``config.yml`` holds its settings and the record of the gains it ran at
    (``rates``); ``--config`` of it gives the same study (the record skipped), and a config
    with a field of that name (the adversary's ``rates``) still reads it."""
    from pathlib import Path

    import yaml

    from train.common.arguments import RECORD_KEYS
    from train.studies.adversary_config import load_config as load_adversary
    from train.studies.verdict_study import load_config

    root = Path(__file__).resolve().parents[1]

    assert RATES_KEY in RECORD_KEYS
    recorded = root / "docs/results/verdict/config.yml"
    assert RATES_KEY in yaml.safe_load(recorded.read_text())
    cfg = load_config(recorded, [])
    assert cfg.robots == ["two_link", "iiwa", "panda", "xarm6"] and cfg.gains == "tuned"
    assert cfg == load_config(root / "train/configs/verdict/verdict.yml", [f"out={cfg.out}"])
    damped = load_adversary(root / "train/configs/adversary/worst_passivity_damped_xarm6.yml", [])
    assert damped.rates == {"passivity": {"damping_ratio": 0.5}}


def test_the_committed_verdict_is_what_its_episodes_say(tmp_path):
    """The README's and the docs' verdict (``docs/results/verdict``): every pair of the
    protocol is there (43,200 episodes, 80 (path, seed) pairs per condition), and the
    committed outcomes against the strongest rival come back from the committed episodes
    (fewer resamples than the report's 20,000: the outcomes, not the last digit of p)."""
    import gzip
    from pathlib import Path

    folder = Path(__file__).resolve().parents[1] / "docs" / "results" / "verdict"
    csv = tmp_path / "episodes.csv"
    csv.write_bytes(gzip.decompress((folder / "episodes.csv.gz").read_bytes()))
    df = load_frame(csv)
    cfg = vs.load_config(folder / "config.yml", [])
    assert len(df) == len(cfg.tasks()) == 43_200
    committed = pd.read_csv(folder / "rivals.csv")
    assert set(committed["pairs"]) == {80}
    again = vs.rivals(dataclasses.replace(cfg, resamples=4000), df)
    key = ["robot", "disturbance", "level", "metric"]
    both = committed.merge(again, on=key, suffixes=("", "_again"))
    assert len(both) == len(committed) == 4 * 15 * 2
    assert (both["rival"] == both["rival_again"]).all()
    assert (both["outcome"] == both["outcome_again"]).all()
    np.testing.assert_allclose(both["ratio"], both["ratio_again"], rtol=1e-5)
