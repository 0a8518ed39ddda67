"""The fair tuning fight (issue 37): trials scale with the rates, one study per seed and the
best over the seeds wins, optima on a box's bound are found and widened (or reported where a
cap keeps them there), the feedback effort ``tau_fb_rms_frac``, and the ranking's stability
across seeds. The studies here tune cheap known functions (a pluggable objective): no
episode runs but in the feedback-effort tests."""

from __future__ import annotations

import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

pytest.importorskip("optuna", reason="tuning needs the 'tune' extra")

from agents import CONTROLLER_NAMES, make_controller
from agents.policy import ControllerPolicy
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.metrics import METRIC_NAMES, episode_metrics
from train.cli import run_command
from train.evaluation.episode import (
    EpisodeSettings,
    Task,
    phase_reader,
    rollout,
    run_episode,
)
from train.evaluation.results import COLUMNS, CorruptResultsError, load_frame, read_episodes
from train.studies.tune import TrialScore, TuneConfig, study_name, tune
from train.studies.tune_boxes import (
    bound_position,
    bounds_hit,
    check_boxes,
    resolve_box,
    widened_bound,
)
from train.studies.tune_fight import (
    fight_markdown,
    ranking_stability,
    seed_rankings,
    spread,
    tuned_table,
)
from train.studies.tune_study import winner

ENV = "ptrack_gym/TwoLinkTrack-v0"


class Bowl:
    """A cheap objective of computed torque's rates: J = 10⁻³ + ln²(ω/ω*) + 10 (ζ − ζ*)² (rad),
    effort 0.5 (feasible: the reference's is 0.5, the budget 1.25 × that); its response is
    (min(ω, ω_cap), ζ): a cap binds above ω_cap."""

    def __init__(self, omega: float, zeta: float, omega_cap: float = math.inf) -> None:
        self.omega, self.zeta, self.omega_cap = omega, zeta, omega_cap
        self.calls = 0

    def score(self, controller, rates):
        self.calls += 1
        if rates is None:
            return TrialScore(1.0, 0.5, 0)
        error = 1e-3 + math.log(rates["omega"] / self.omega) ** 2
        error += 10.0 * (rates["zeta"] - self.zeta) ** 2
        return TrialScore(error, 0.5, 0)

    def response(self, controller, rates):
        return np.array([min(rates["omega"], self.omega_cap), rates["zeta"]])


def fight(out: Path, **kw: object) -> TuneConfig:
    """Computed torque on the two-link (no episode runs: the objective is a :class:`Bowl`)."""
    base: dict[str, object] = dict(
        env_id=ENV,
        controllers=["computed_torque"],
        trials=6,
        trials_per_rate=1,
        startup_trials=3,
        study_seeds=[0, 1, 2],
        validation_seeds=[1000],
        disturbances=["none"],
        episode_s=0.5,
        control_hz=100.0,
        workers=1,
        out=str(out),
    )
    base.update(kw)
    return TuneConfig(**base)  # type: ignore[arg-type]


def _journal_studies(out: Path) -> dict[str, list]:
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    storage = JournalStorage(JournalFileBackend(str(out / "optuna.journal")))
    return {
        s.study_name: optuna.load_study(study_name=s.study_name, storage=storage).trials
        for s in optuna.get_all_study_summaries(storage)
    }


# -- budget and seeds ------------------------------------------------------------------------
def test_trials_scale_with_the_number_of_tuned_rates(tmp_path):
    cfg = TuneConfig(controllers=["computed_torque", "passivity"])
    assert cfg.trials_per_rate == 25 and cfg.study_seeds == [0, 1, 2]
    assert cfg.study_trials("computed_torque") == 50  # max(40, 25 x 2)
    assert cfg.study_trials("passivity") == 125  # max(40, 25 x 5): ζ is tuned too
    assert cfg.study_trials("passivity_paper") == 100  # max(40, 25 x 4): the paper fixes ζ
    assert TuneConfig(trials=140).study_trials("passivity") == 140  # the floor decides
    assert TuneConfig(trials=1, trials_per_rate=1).study_trials("adaptive_slotine_li") == 3


def test_one_study_per_seed_resumable_and_the_best_seed_wins(tmp_path):
    out = tmp_path / "fight"
    bowl = Bowl(omega=30.0, zeta=1.2)
    result = tune(fight(out), progress=False, objective=bowl)["computed_torque"]
    studies = _journal_studies(out)
    names = {study_name("computed_torque", s) for s in (0, 1, 2)}
    assert set(studies) == names and len(names) == 3
    assert all(len(t) == 6 for t in studies.values())
    per_seed = {s: r["error_rad"] for s, r in result["seeds"].items()}
    assert result["error_rad"] == min(per_seed.values())
    assert result["seed"] == min(per_seed, key=per_seed.get)
    assert result["rates"] == result["seeds"][result["seed"]]["rates"]
    assert result["trials"] == 18 and result["trials_per_study"] == 6
    assert result["spread"] == pytest.approx(spread(list(per_seed.values())))
    assert result["effort_budget"] == pytest.approx(1.25 * 0.5)
    assert yaml.safe_load((out / "computed_torque.yml").read_text())["seed"] == result["seed"]
    assert "Kendall" in (out / "fight.md").read_text() or "n/a" in (out / "fight.md").read_text()

    before = {k: [t.params for t in v] for k, v in studies.items()}
    with pytest.raises(InvalidConfigError, match="--resume"):
        tune(fight(out, trials=8), progress=False, objective=bowl)
    tune(fight(out, trials=8), resume=True, progress=False, objective=bowl)
    after = _journal_studies(out)
    for name, trials in after.items():
        assert len(trials) == 8 and [t.params for t in trials[:6]] == before[name]

    # the resumed studies asked what uninterrupted ones ask
    whole = tmp_path / "whole"
    tune(fight(whole, trials=8), progress=False, objective=bowl)
    assert {k: [t.params for t in v] for k, v in _journal_studies(whole).items()} == {
        k: [t.params for t in v] for k, v in after.items()
    }


def test_a_study_of_the_one_seed_protocol_is_not_resumed(tmp_path):
    out = tmp_path / "old"
    out.mkdir()
    (out / "optuna.journal").write_text("{}\n")
    (out / "config.yml").write_text(yaml.safe_dump({"seed": 0, "trials": 40}))
    with pytest.raises(InvalidConfigError, match="one-seed protocol"):
        tune(fight(out), resume=True, progress=False, objective=Bowl(30.0, 1.0))


def test_the_winner_is_the_best_seed_and_the_spread_is_max_minus_min_over_median():
    assert spread([1.0, 2.0, 4.0]) == pytest.approx((4.0 - 1.0) / 2.0)
    assert spread([3.0]) == 0.0
    assert math.isnan(spread([]))

    def seed(error: float, omega: float) -> dict:
        return {
            "error_rad": error, "effort": 0.1, "failures": 0,
            "rates": {"omega": omega, "zeta": 1.0},
            "trial": f"x#{omega:g}", "trials": 10, "feasible_trials": 7, "widenings": 0,
            "box": {}, "on_bound": [], "on_bound_why": {}, "wall_s": 1.0,
        }  # fmt: skip

    cfg = TuneConfig(trials=10, trials_per_rate=1)
    best = winner(cfg, "computed_torque", {0: seed(2e-3, 10.0), 1: seed(1e-3, 20.0), 2: None}, 0.3)
    assert best["seed"] == 1 and best["rates"]["omega"] == 20.0 and best["error_rad"] == 1e-3
    assert best["spread"] == pytest.approx((2e-3 - 1e-3) / 1.5e-3)
    assert best["trials"] == 20 and best["feasible_trials"] == 14 and best["seeds"][2] is None
    # the budget in env steps: 20 trials x the default config's 3 seeds x 5 presets x 6-s
    # episodes at 1 kHz (one path)
    assert best["env_steps"] == 20 * (3 * 5) * 6000
    # the trials of a seed without a feasible one were spent too
    spent = winner(cfg, "computed_torque", {0: seed(2e-3, 10.0), 2: None}, 0.3, spent=25)
    assert spent["trials"] == 25 and spent["env_steps"] == 25 * (3 * 5) * 6000
    with pytest.raises(InvalidConfigError, match="no trial completed"):
        winner(cfg, "computed_torque", {0: None}, 0.3)


def test_a_seed_within_the_budget_beats_any_over_it_and_with_none_the_least_over_wins():
    def seed(error: float, effort: float, over: bool) -> dict:
        return {
            "error_rad": error, "effort": effort, "failures": 0, "over_budget": over,
            "rates": {"omega": 1.0 / error, "zeta": 1.0}, "trial": "x", "trials": 10,
            "feasible_trials": 0 if over else 3, "widenings": 0, "box": {}, "on_bound": [],
            "on_bound_why": {}, "wall_s": 1.0,
        }  # fmt: skip

    cfg = TuneConfig(trials=10, trials_per_rate=1)
    mixed = {0: seed(1e-4, 0.5, True), 1: seed(3e-3, 0.29, False), 2: seed(2e-3, 0.3, False)}
    best = winner(cfg, "computed_torque", mixed, 0.3)
    assert best["seed"] == 2 and not best["over_budget"]  # a lower J over budget cannot win
    over = {0: seed(1e-4, 0.5, True), 1: seed(3e-3, 0.35, True), 2: seed(2e-3, 0.4, True)}
    best = winner(cfg, "computed_torque", over, 0.3)
    assert best["seed"] == 1 and best["over_budget"] and best["effort"] == 0.35
    text = fight_markdown({"computed_torque": best}, "t")
    assert "over budget by 16.7 %" in text


class Heavy(Bowl):
    """A :class:`Bowl` whose effort falls with ω towards 0.7 but never to the budget (1.25 ×
    the reference's 0.5 = 0.625): no trial is feasible."""

    def score(self, controller, rates):
        base = super().score(controller, rates)
        if rates is None:
            return base
        return TrialScore(base.error_rad, 0.7 + 1.0 / rates["omega"], 0)


def test_a_controller_that_never_meets_the_budget_is_tuned_at_its_least_over_budget_trial(
    tmp_path,
):
    out = tmp_path / "fight"
    cfg = fight(out, study_seeds=[0, 1], widen_on_bound=True, trials=20)
    result = tune(cfg, progress=False, objective=Heavy(30.0, 1.2))
    best = result["computed_torque"]
    assert best["over_budget"] and best["feasible_trials"] == 0
    # each seed's least effort sits at ω's upper edge (20 trials find it), yet no seed
    # widened: widening follows an optimum of J within the budget, which it has not found
    assert all(r["on_bound"] == ["omega"] for r in best["seeds"].values())
    assert all("not widened: no trial within the effort budget" in r["on_bound_why"]["omega"]
               for r in best["seeds"].values())  # fmt: skip
    studies = _journal_studies(out)
    assert set(studies) == {study_name("computed_torque", s) for s in (0, 1)}
    trials = [t for ts in studies.values() for t in ts]
    efforts = [t.user_attrs["effort"] for t in trials]
    assert min(efforts) > best["effort_budget"]  # nothing was feasible
    assert best["effort"] == pytest.approx(min(efforts))  # the least over budget won
    assert all(r["over_budget"] for r in best["seeds"].values())
    assert "over budget by" in (out / "fight.md").read_text()


# -- boxes -----------------------------------------------------------------------------------
def test_bound_detection_at_exactly_five_percent_linear_and_log():
    lin = {"zeta": (0.0, 100.0, False)}
    assert bound_position(5.0, 0.0, 100.0, False) == 0.05
    assert bounds_hit({"zeta": 5.0}, lin) == {}  # exactly at 5 %: inside
    assert bounds_hit({"zeta": 95.0}, lin) == {}
    assert bounds_hit({"zeta": 4.99}, lin) == {"zeta": "low"}
    assert bounds_hit({"zeta": 95.01}, lin) == {"zeta": "high"}
    log = {"omega": (1.0, 1e20, True)}  # log space: 10 is 5 % of the way, 1e19 95 %
    assert bound_position(10.0, 1.0, 1e20, True) == pytest.approx(0.05, abs=1e-15)
    assert bounds_hit({"omega": 10.0}, log) == {}
    assert bounds_hit({"omega": 1e19}, log) == {}
    assert bounds_hit({"omega": 9.9}, log) == {"omega": "low"}
    assert bounds_hit({"omega": 1.01e19}, log) == {"omega": "high"}
    # 5 % in linear space is not 5 % in log space: 6 of [1, 101] is 5 % linear, 39 % log
    assert bounds_hit({"omega": 6.0}, {"omega": (1.0, 101.0, True)}) == {}
    assert bounds_hit({"omega": 5.9}, {"omega": (1.0, 101.0, False)}) == {"omega": "low"}


def test_widening_moves_by_three_or_the_width_and_never_to_the_floor():
    assert widened_bound("omega", 3.0, 100.0, True, "high") == 300.0
    assert widened_bound("omega", 3.0, 100.0, True, "low") == 1.0
    assert widened_bound("zeta", 0.5, 2.0, False, "high") == 3.5
    assert widened_bound("zeta", 2.0, 3.0, False, "low") == 1.0
    assert widened_bound("zeta", 0.5, 2.0, False, "low") == 0.25  # 0.5 − 1.5 < 0: halfway
    assert widened_bound("zeta", 1e-9, 2.0, False, "low") is None  # at the floor


def test_box_overrides_apply_and_are_validated():
    box = resolve_box("computed_torque", {"omega": [1.0, 1000.0, True]})
    assert box == {"omega": (1.0, 1000.0, True), "zeta": (0.5, 2.0, False)}
    check_boxes({"computed_torque": {"omega": [1, 1000, True], "zeta": [0.1, 4.0, False]}})
    bad = [
        ({"nope": {"omega": [1, 2, True]}}, "not a tunable controller"),
        ({"computed_torque": {"gamma": [1, 2, True]}}, "tunes no rate 'gamma'"),
        ({"computed_torque": {"omega": [10, 1, True]}}, "lo < hi"),
        ({"computed_torque": {"omega": [0, 10, True]}}, "log scale needs lo > 0"),
        ({"computed_torque": {"zeta": [-1, 2, False]}}, "zeta must stay > 0"),
        ({"computed_torque": {"omega": [1, 10]}}, r"\[lo, hi, log\]"),
        ({"computed_torque": {"omega": [1, 10, "yes"]}}, r"\[lo, hi, log\]"),
        ({"computed_torque": [1, 2]}, "must map rates"),
    ]
    for boxes, match in bad:
        with pytest.raises(InvalidConfigError, match=match):
            check_boxes(boxes)


def test_widening_finds_an_interior_optimum_beyond_the_box(tmp_path):
    # ω* = 300 lies past the box [3, 100]: round 0 stops on the bound, round 1 ([3, 300])
    # on the new one, round 2 ([3, 900]) finds it inside
    bowl = Bowl(omega=300.0, zeta=1.0)
    cfg = fight(tmp_path, study_seeds=[0], trials=25, startup_trials=8, widen_on_bound=True)
    result = tune(cfg, progress=False, objective=bowl)["computed_torque"]
    assert result["seeds"][0]["widenings"] == 2
    assert result["box"]["omega"] == [3.0, 900.0, True]
    assert result["box"]["zeta"] == [0.5, 2.0, False]
    assert result["on_bound"] == []
    assert result["rates"]["omega"] == pytest.approx(300.0, rel=0.25)
    assert result["trials"] == 75  # 25 new trials a round; the copies are history
    studies = _journal_studies(tmp_path)
    assert len(studies[study_name("computed_torque", 0, 2)]) == 75  # 50 copied + 25 new


def test_an_optimum_past_the_floor_widens_towards_it_and_is_reported(tmp_path):
    bowl = Bowl(omega=20.0, zeta=0.01)  # ζ* = 0.01: below any box the floor allows
    cfg = fight(tmp_path, study_seeds=[0], trials=20, startup_trials=6, widen_on_bound=True)
    result = tune(cfg, progress=False, objective=bowl)["computed_torque"]
    low = result["box"]["zeta"][0]
    assert 0.0 < low < 0.5 and result["box"]["zeta"][1] == 2.0
    assert result["on_bound"] == ["zeta"]
    assert result["on_bound_why"]["zeta"].startswith("low, still after 2 widening(s)")


def test_a_capped_rate_is_not_widened_and_stays_on_its_bound(tmp_path):
    # the controller caps ω at 60 rad/s (its per-sample cap): a winner near 100 does what one
    # at 300 would, so the bound is not widened and the rate is reported as capped
    bowl = Bowl(omega=300.0, zeta=1.0, omega_cap=60.0)
    cfg = fight(tmp_path, study_seeds=[0], trials=25, startup_trials=8, widen_on_bound=True)
    result = tune(cfg, progress=False, objective=bowl)["computed_torque"]
    assert result["seeds"][0]["widenings"] == 0
    assert result["box"]["omega"] == [3.0, 100.0, True]
    assert result["on_bound"] == ["omega"]
    assert (
        "capped" in result["on_bound_why"]["omega"]
        and "per-sample cap" in (result["on_bound_why"]["omega"])
    )
    assert set(_journal_studies(tmp_path)) == {study_name("computed_torque", 0)}
    # without widening, the bound is reported all the same
    off = tune(fight(tmp_path / "off", study_seeds=[0], trials=25, startup_trials=8),
               progress=False, objective=Bowl(300.0, 1.0))["computed_torque"]  # fmt: skip
    assert off["on_bound_why"]["omega"] == "high, not widened (widen_on_bound off)"


# -- configs ---------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("effort_metric", "tau_nope", "effort_metric must be one of"),
        ("study_seeds", [], "study_seeds"),
        ("study_seeds", [1, 1], "study_seeds"),
        ("trials_per_rate", 0, "trials_per_rate must be >= 1"),
        ("max_widenings", -1, "max_widenings"),
        ("boxes", {"computed_torque": {"omega": [5, 1, True]}}, "lo < hi"),
    ],
)
def test_bad_fight_configs_fail_before_any_trial(tmp_path, field, value, match):
    bowl = Bowl(30.0, 1.0)
    with pytest.raises(InvalidConfigError, match=match):
        tune(fight(tmp_path, **{field: value}), progress=False, objective=bowl)
    assert bowl.calls == 0 and not (tmp_path / "optuna.journal").exists()


def test_the_cli_has_the_fight_fields_and_the_fight_configs_load(capsys):
    with pytest.raises(SystemExit) as done:
        run_command("tune", ["--help"])
    assert done.value.code == 0
    text = capsys.readouterr().out
    for flag in ("--trials-per-rate", "--study-seeds", "--effort-metric", "--boxes",
                 "--widen-on-bound", "--max-widenings"):  # fmt: skip
        assert flag in text
    from agents.registry import TUNABLE
    from train.studies.tune import load_config

    root = Path(__file__).resolve().parents[1] / "train" / "configs" / "tune"
    for robot in ("iiwa", "two_link"):
        cfg = load_config(root / f"tune_fight_{robot}.yml", [])
        cfg.validate()
        assert cfg.controllers == list(TUNABLE) and cfg.study_seeds == [0, 1, 2]
        assert cfg.widen_on_bound and cfg.effort_metric == "tau_fb_rms_frac"


# -- the feedback effort ---------------------------------------------------------------------
def test_feedback_effort_is_zero_on_the_reference_and_not_when_disturbed():
    settings = EpisodeSettings(ENV, 0.5, 250.0, "on_path", 0.5, 0.01)
    calm, _ = run_episode(Task("computed_torque", "none", 0.0, 1000, 0), settings)
    assert calm["tau_dyn_rms_frac"] > 5e-3  # the feed-forward moves the arm
    assert calm["tau_fb_rms_frac"] <= 1e-2 * calm["tau_dyn_rms_frac"]  # ~0: zero-order hold only
    pushed, _ = run_episode(Task("computed_torque", "periodic", 1.0, 1000, 0), settings)
    assert pushed["tau_fb_rms_frac"] > 100 * calm["tau_fb_rms_frac"]
    assert pushed["tau_fb_rms_frac"] > 1e-3


def test_every_controller_phase_is_read_as_its_diagnostics_say():
    env = gym.make(ENV, control_hz=100.0, max_episode_steps=20, disturbance=("noise", 1.0))
    try:
        for name in CONTROLLER_NAMES:
            obs, _ = env.reset(seed=3)
            policy = ControllerPolicy(env, make_controller(name, env))
            read = phase_reader(policy.controller)
            for _ in range(5):
                obs, *_ = env.step(policy.action(obs))
                assert read() == policy.controller.diagnostics()["s"], name
    finally:
        env.close()


class _Zero:
    """A policy without a phase (as a learned one): zero torque."""

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        return np.zeros(2, dtype=np.float32), None


def test_a_policy_without_a_phase_has_no_feedback_effort():
    env = gym.make(ENV, control_hz=100.0, max_episode_steps=10)
    try:
        record, _ = rollout(env, _Zero(), 1000)
        assert record.tau_ff_nm is None
        u = env.unwrapped
        metrics = episode_metrics(record, u.model, u.projector)
        assert math.isnan(metrics["tau_fb_rms_frac"]) and math.isfinite(metrics["tau_dyn_rms_frac"])
    finally:
        env.close()


def test_results_without_the_feedback_column_load_but_do_not_resume(tmp_path):
    assert "tau_fb_rms_frac" in METRIC_NAMES and "tau_fb_rms_frac" in COLUMNS
    old = [c for c in COLUMNS if c != "tau_fb_rms_frac"]
    row = {c: "0.1" for c in old}
    row.update(controller="pd_gravity", disturbance="none", level="0", seed="0", episode="0")
    row.update(steps="10", failed="0.0")
    path = tmp_path / "episodes.csv"
    path.write_text(",".join(old) + "\n" + ",".join(row[c] for c in old) + "\n")
    df = load_frame(path)
    assert list(df.columns) == list(COLUMNS) and df["tau_fb_rms_frac"].isna().all()
    assert df["tau_dyn_rms_frac"].iloc[0] == 0.1
    with pytest.raises(CorruptResultsError, match=r"tau_fb_rms_frac.*cannot be resumed"):
        read_episodes(path)


# -- ranking stability and the table ---------------------------------------------------------
def test_kendall_tau_of_identical_and_reversed_rankings():
    same = {
        "a": {0: 1.0, 1: 1.0, 2: 2.0},
        "b": {0: 2.0, 1: 2.0, 2: 3.0},
        "c": {0: 3.0, 1: 3.0, 2: 4.0},
    }
    st = ranking_stability(same)
    assert st.mean == pytest.approx(1.0) and st.min == pytest.approx(1.0) and len(st.pairs) == 3
    assert seed_rankings(same) == {0: ["a", "b", "c"], 1: ["a", "b", "c"], 2: ["a", "b", "c"]}
    reversed_ = {"a": {0: 1.0, 1: 3.0}, "b": {0: 2.0, 1: 2.0}, "c": {0: 3.0, 1: 1.0}}
    st = ranking_stability(reversed_)
    assert st.pairs == {(0, 1): pytest.approx(-1.0)} and st.min == pytest.approx(-1.0)
    mixed = {**same, "d": {0: 4.0, 1: 0.5, 2: 5.0}}  # seed 1 ranks d first
    st = ranking_stability(mixed)
    assert st.min < st.mean < 1.0
    assert math.isnan(ranking_stability({"a": {0: 1.0, 1: 2.0}}).mean)  # one controller


def test_the_table_shows_seeds_spread_bounds_and_the_ranking_stability(tmp_path):
    saved = tmp_path / "tuned"
    cfg = fight(tmp_path / "study", controllers=["computed_torque", "pd_gravity"])
    results = tune(cfg, save_dir=saved, progress=False, objective=Bowl(300.0, 1.0))
    data = yaml.safe_load((saved / "two_link-computed_torque.yml").read_text())
    assert data["rates"] == results["computed_torque"]["rates"]
    study = data["study"]
    assert set(study["seeds"]) == {0, 1, 2} and study["effort_metric"] == "tau_fb_rms_frac"
    assert study["on_bound"] == ["omega"] and "spread" in study
    # a file of the one-seed protocol still reads
    (saved / "two_link-slotine_li.yml").write_text(yaml.safe_dump({
        "rates": {"omega": 99.8, "kd_ratio": 1.0},
        "study": {"seed": 0, "error_rad": 1e-3, "effort": 0.01, "effort_budget": 0.02,
                  "feasible_trials": 30, "trials": 40, "wall_s": 100.0},
    }))  # fmt: skip
    table = tuned_table(saved)
    assert "omega (high of (3.0, 100.0))" in table  # where a one-seed optimum sat
    assert "| seeds | spread |" in table and "| 0, 1, 2 |" in table
    assert "omega (high, not widened" in table
    assert "| two_link | slotine_li |" in table and "| 0 | – |" in table
    assert "two_link: ranking stability across study seeds [0, 1, 2] (2 controllers)" in table


def test_the_table_reads_the_shipped_tuned_gains_and_marks_rates_tuned_before_they_were(
    tmp_path,
):
    """``ptrack tune --table`` on ``agents/tuned``; a file that predates a tunable rate
    (the passivity law's ``damping_ratio``) shows that rate's default, marked."""
    from agents.registry import TUNED_DIR

    table = tuned_table(TUNED_DIR)
    for path in sorted(TUNED_DIR.glob("*.yml")):
        robot, controller = path.stem.split("-", 1)
        assert f"| {robot} | {controller} |" in table
    data = yaml.safe_load((TUNED_DIR / "two_link-passivity.yml").read_text())
    data["rates"].pop("damping_ratio", None)
    (tmp_path / "two_link-passivity.yml").write_text(yaml.safe_dump(data))
    from agents.passivity_gains import DEFAULT_RATES

    marked = f"damping_ratio {DEFAULT_RATES['damping_ratio']:.3g} (not tuned)"
    assert marked in tuned_table(tmp_path)
