"""The adversarial disturbance search (``ptrack adversary``) on a tiny budget: it
finds a worse push than the median random one, a found worst case replays bit-identically
from its spec, a search resumes, and bad input is refused before any episode runs."""

from __future__ import annotations

import pytest

pytest.importorskip("optuna", reason="the optional 'tune' extra (Optuna) is not installed")
pytest.importorskip("cmaes", reason="the optional 'tune' extra (cmaes) is not installed")

import numpy as np
import pandas as pd
import yaml

from ptrack_gym.errors import InvalidConfigError
from train.cli import run_command
from train.studies.adversary import AdversaryConfig, load_config, replay, replay_all, run_search

#: Two-link: impulses from 0.2 s on, over a whole path period, cost over the 0.5 s after;
#: two search seeds, each 16 random draws then two CMA-ES runs of 8 (populations 4 and 8),
#: then a local run of 4.
TINY = [
    "env_id=ptrack_gym/TwoLinkTrack-v0",
    "controllers=[pd_gravity]",
    "energies_j=[0.6]",
    "onset_s=[0.2, 0.6]",
    "post_s=0.5",
    "popsize=4",
    "polish_budget=4",
    "search_seeds=[0, 1]",
    "control_hz=250.0",
    "workers=2",
]


def main(argv: list[str]) -> int:
    """``ptrack adversary`` with ``argv``."""
    return run_command("adversary", argv)


@pytest.fixture(scope="module")
def search(tmp_path_factory):
    out = tmp_path_factory.mktemp("adv") / "run"
    cfg = load_config(None, [*TINY, "budget=16", f"out={out}"])
    run_search(cfg, progress=False)
    return out


def test_search_finds_a_worse_push_than_the_median_random_one(search) -> None:
    df = pd.read_csv(search / "trials.csv", float_precision="round_trip")
    assert len(df) == 2 * 36  # per seed 16 random + 16 searched + 4 local
    assert sorted(df["run"].unique()) == ["polish", "random", "search0", "search1"]
    searched = df[df["kind"] == "search"]["cost_rad"]
    random = df[df["kind"] == "random"]["cost_rad"]
    assert searched.max() > random.median()
    assert (df["work_j"] > 0).any()  # the delivered work is recorded
    summary = pd.read_csv(search / "summary.csv", float_precision="round_trip")
    assert summary.loc[0, "worst_search_rad"] == searched.max()
    assert summary.loc[0, "median_random_rad"] == random.median()
    assert summary.loc[0, "worst_rad"] == df["cost_rad"].max()  # searched or random
    worst = yaml.safe_load((search / "worst.yml").read_text())["worst"]
    for (controller, energy), g in df.groupby(["controller", "energy_j"]):
        entry = worst[controller]["impulse"][f"{energy:g}"]
        assert entry["cost_rad"] == g["cost_rad"].max()  # the worst episode run, either kind
        assert entry["found_by"] == g.loc[g["cost_rad"].idxmax(), "kind"]
    # every seed's search reaches at least its random worst (it starts from it)
    for _, g in df.groupby("seed"):
        assert (
            g[g["kind"] == "search"]["cost_rad"].max() >= g[g["kind"] == "random"]["cost_rad"].max()
        )
    assert bool(summary.loc[0, "search_reached_random"])
    per_seed = df.groupby("seed")["cost_rad"].max()
    assert summary.loc[0, "spread"] == pytest.approx(
        (per_seed.max() - per_seed.min()) / per_seed.median()
    )
    # the start phase and the onset span the path's whole period S
    from ptrack_gym.robots import robot_profile

    period = robot_profile("two_link").path_period_s
    s0 = df["s0"].to_numpy()
    assert s0.min() >= 0.0 and s0.max() < period and s0.max() - s0.min() > period / 2
    onsets = df["spec"].map(lambda t: yaml.safe_load(t)["onset_s"])
    assert onsets.min() >= 0.2 and onsets.max() < 0.2 + period
    assert onsets.max() - onsets.min() > period / 2
    for name in ("summary.md", "adversary.png", "worst.yml", "config.yml", "optuna.journal"):
        assert (search / name).stat().st_size > 0, name


def test_the_local_run_starts_at_the_worst_so_far_with_small_steps(search) -> None:
    """Its first episode is the seed's worst before it, and its others stay close to it:
    within a few steps of polish_sigma (0.02 of each range) in every searched parameter."""
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    from train.studies.adversary import study_name

    storage = JournalStorage(JournalFileBackend(str(search / "optuna.journal")))
    for seed in (0, 1):
        before = []
        for kind in ("random", "search0", "search1"):
            before += optuna.load_study(
                study_name=study_name("pd_gravity", "impulse", 0.6, kind, seed), storage=storage
            ).trials
        worst = max(before, key=lambda t: t.value)
        local = optuna.load_study(
            study_name=study_name("pd_gravity", "impulse", 0.6, "polish", seed), storage=storage
        ).trials
        assert len(local) == 4 and local[0].params == worst.params
        assert max(t.value for t in local) >= worst.value
        for t in local[1:]:
            for name, value in t.params.items():
                dist = t.distributions[name]
                span = dist.high - dist.low
                assert abs(value - worst.params[name]) <= 5 * 0.02 * span, name
        # the global runs take larger steps: the same check fails for their episodes
        far = [
            name
            for t in before
            for name, value in t.params.items()
            if abs(value - worst.params[name])
            > 5 * 0.02 * (t.distributions[name].high - t.distributions[name].low)
        ]
        assert far
    assert np.isfinite([t.value for t in local]).all()


def test_worst_case_replays_bit_identically(search) -> None:
    worst = yaml.safe_load((search / "worst.yml").read_text())
    entry = worst["worst"]["pd_gravity"]["impulse"]["0.6"]
    outcome = replay(search / "worst.yml", "pd_gravity", "impulse", 0.6)
    assert outcome.cost == entry["cost_rad"]  # exactly
    assert outcome.work_j == entry["work_j"]


def test_a_worst_case_replays_under_another_controller(search) -> None:
    """``under``: the same spec, start phase and seed under another controller — itself
    gives the searched episode, another a different episode of the same disturbance."""
    worst = search / "worst.yml"
    entry = yaml.safe_load(worst.read_text())["worst"]["pd_gravity"]["impulse"]["0.6"]
    itself = replay(worst, "pd_gravity", "impulse", 0.6, under="pd_gravity")
    assert itself.cost == entry["cost_rad"]
    other = replay(worst, "pd_gravity", "impulse", 0.6, under="computed_torque")
    assert np.isfinite(other.cost) and other.cost != entry["cost_rad"]
    assert 0 <= other.peak_joint < 2 and other.peak_speed_rad_s > 0
    lines = replay_all(worst, ["computed_torque"])
    under = [line for line in lines if "under computed_torque" in line]
    assert len(under) == len(lines) // 2 and f"cost {other.cost:.6g} rad" in "".join(under)


def test_a_worst_case_replays_with_other_gain_rates(search) -> None:
    """``rates``: the searched controller's own rates given explicitly give the searched
    episode; another rate gives another episode; an unknown rate name is refused."""
    from ptrack_gym.robots import robot_profile

    worst = search / "worst.yml"
    entry = yaml.safe_load(worst.read_text())["worst"]["pd_gravity"]["impulse"]["0.6"]
    omega = robot_profile("two_link").controller_gains["pd_gravity"]["omega"]
    same = replay(worst, "pd_gravity", "impulse", 0.6, rates={"omega": omega})
    assert same.cost == entry["cost_rad"]
    stiffer = replay(worst, "pd_gravity", "impulse", 0.6, rates={"omega": 2.0 * omega})
    assert np.isfinite(stiffer.cost) and stiffer.cost != entry["cost_rad"]
    lines = replay_all(worst, rates={"omega": 2.0 * omega})
    assert f"cost {stiffer.cost:.6g} rad" in "".join(lines)
    assert all(f"omega={2.0 * omega}" in line for line in lines)
    with pytest.raises(InvalidConfigError, match="no_such_rate"):
        replay(worst, "pd_gravity", "impulse", 0.6, rates={"no_such_rate": 1.0})


def test_search_resumes_to_its_budget_without_repeating(search, tmp_path) -> None:
    import shutil

    out = tmp_path / "resumed"
    shutil.copytree(search, out)
    with pytest.raises(InvalidConfigError, match="--resume"):
        run_search(load_config(None, [*TINY, "budget=20", f"out={out}"]), progress=False)
    with pytest.raises(InvalidConfigError, match="different settings"):
        run_search(
            load_config(None, [*TINY, "budget=20", "search_seeds=[3]", f"out={out}"]), resume=True
        )
    run_search(load_config(None, [*TINY, "budget=20", f"out={out}"]), resume=True, progress=False)
    df = pd.read_csv(out / "trials.csv", float_precision="round_trip")
    assert len(df) == 2 * 44
    # the random draws of the resumed search are those of an uninterrupted one
    fresh = tmp_path / "fresh"
    run_search(load_config(None, [*TINY, "budget=20", f"out={fresh}"]), progress=False)
    whole = pd.read_csv(fresh / "trials.csv", float_precision="round_trip")
    rand = ["seed", "trial", "cost_rad", "spec"]
    pd.testing.assert_frame_equal(
        df[df["kind"] == "random"][rand].sort_values(["seed", "trial"]).reset_index(drop=True),
        whole[whole["kind"] == "random"][rand]
        .sort_values(["seed", "trial"])
        .reset_index(drop=True),
    )
    first = pd.read_csv(search / "trials.csv", float_precision="round_trip")
    key = ["seed", "run", "trial"]
    kept = df.merge(first[key], on=key).sort_values(key).reset_index(drop=True)
    assert len(kept) == 2 * 36  # every episode of the first search is kept, unchanged
    pd.testing.assert_series_equal(
        kept["cost_rad"], first.sort_values(key).reset_index(drop=True)["cost_rad"]
    )


def test_further_local_runs_start_in_other_basins_and_resume_onto_a_search(
    search, tmp_path
) -> None:
    """``polish_starts`` added on resume: the episodes run are kept, and each seed's second
    local run starts from the worst random draw lying in no basin the first local run
    started in or reached — not from the worst episode — and runs its budget from there.
    Its start is kept on its study: a resume that extends the budgets (and so moves the
    worst episodes) goes on from the same start."""
    import shutil

    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    from train.studies.adversary import study_name
    from train.studies.worst_case import Searchable

    out = tmp_path / "more"
    shutil.copytree(search, out)
    cfg = load_config(None, [*TINY, "budget=16", "polish_starts=2", f"out={out}"])
    run_search(cfg, resume=True, progress=False)
    df = pd.read_csv(out / "trials.csv", float_precision="round_trip")
    assert len(df) == 2 * 40 and sorted(df["run"].unique())[:2] == ["polish", "polish1"]
    first = pd.read_csv(search / "trials.csv", float_precision="round_trip")
    key = ["seed", "run", "trial"]
    kept = df.merge(first[key], on=key).sort_values(key).reset_index(drop=True)
    pd.testing.assert_series_equal(
        kept["cost_rad"], first.sort_values(key).reset_index(drop=True)["cost_rad"]
    )
    storage = JournalStorage(JournalFileBackend(str(out / "optuna.journal")))
    target = Searchable(cfg, "impulse", 0.6)

    def study(kind: str, seed: int):  # type: ignore[no-untyped-def]
        name = study_name("pd_gravity", "impulse", 0.6, kind, seed)
        return optuna.load_study(study_name=name, storage=storage)

    def basin(t, spec, s0) -> bool:  # type: ignore[no-untyped-def]
        return target.same_basin(t.user_attrs["spec"], t.user_attrs.get("s0"), spec, s0)

    starts = {}
    for seed in (0, 1):
        random, local = study("random", seed).trials, study("polish", seed).trials
        worst_local = max(local, key=lambda t: t.value)
        assert study("polish", seed).user_attrs["start"]["params"] == local[0].params
        anchors = [(t.user_attrs["spec"], t.user_attrs.get("s0")) for t in (local[0], worst_local)]
        outside = [t for t in random if not any(basin(t, *a) for a in anchors)]
        second = study("polish1", seed)
        assert outside and len(second.trials) == 4
        expected = max(outside, key=lambda t: t.value)
        assert second.trials[0].params == expected.params == second.user_attrs["start"]["params"]
        assert expected.value < max(t.value for t in random + local)  # not the worst so far
        starts[seed] = second.user_attrs["start"]
    assert "2 local runs of 4" in (out / "summary.md").read_text()
    # more budget: more random draws and longer runs, the local runs' starts as they were
    more = load_config(None, [*TINY, "budget=20", "polish_budget=8", "polish_starts=2",
                              f"out={out}"])  # fmt: skip
    run_search(more, resume=True, progress=False)
    for seed in (0, 1):
        second = study("polish1", seed)
        assert second.user_attrs["start"] == starts[seed] and len(second.trials) == 8
        assert second.trials[0].params == starts[seed]["params"]


def test_episodes_share_a_basin_by_direction_path_phase_and_frequency() -> None:
    import math

    from ptrack_gym.robots import robot_profile
    from train.studies.worst_case import BASIN_ANGLE, BASIN_PHASE, Searchable

    cfg = load_config(None, TINY)
    period = robot_profile("two_link").path_period_s
    pulse = Searchable(cfg, "impulse", 0.6)
    a = {"onset_s": 1.0, "direction": [1.0, 0.0]}

    def turned(angle: float) -> list[float]:
        return [math.cos(angle), math.sin(angle)]

    assert pulse.same_basin(a, 0.0, a, 0.0)
    assert pulse.same_basin(a, 0.0, {**a, "direction": turned(0.9 * BASIN_ANGLE)}, 0.0)
    assert not pulse.same_basin(a, 0.0, {**a, "direction": turned(1.1 * BASIN_ANGLE)}, 0.0)
    assert not pulse.same_basin(a, 0.0, {**a, "direction": [-1.0, 0.0]}, 0.0)
    # the path phase at the onset, (s0 + onset) mod S, wrapping; not the split between them
    assert pulse.same_basin(a, 0.0, {**a, "onset_s": 0.5}, 0.5)
    near, far = 0.9 * BASIN_PHASE * period, 1.1 * BASIN_PHASE * period
    assert pulse.same_basin(a, 0.0, a, period - near)  # across the seam of the period
    assert not pulse.same_basin(a, 0.0, a, far)
    assert not pulse.same_basin(a, 0.0, a, period - far)
    assert not pulse.same_basin(a, None, {**a, "link": "link2"}, None)  # another link
    wave = Searchable(cfg, "periodic", 0.6)
    f = {"frequency_hz": 2.0, "direction": [0.0, 1.0]}
    assert wave.same_basin(f, 0.0, {**f, "frequency_hz": 2.9}, 5.0)  # the phase is free
    assert not wave.same_basin(f, 0.0, {**f, "frequency_hz": 3.1}, 0.0)
    assert not wave.same_basin(f, 0.0, {**f, "frequency_hz": 1.3}, 0.0)
    assert wave.same_basin(f, 0.0, {**f, "direction": [0.0, -1.0]}, 0.0)  # −d: half a period on
    assert not pulse.same_basin(a, 0.0, {**a, "direction": [-1.0, 0.0]}, 0.0)  # a pulse: not


@pytest.mark.parametrize(
    ("override", "match"),
    [
        ("energies_j=[-1.0]", "energies_j"),
        ("families=[]", "families"),
        ("families=[earthquake]", "families"),
        ("budget=0", "budget"),
        ("budget=9", r"budget must be >= 10 \(the search starts from the best tenth"),
        ("controllers=[lqr]", "controllers"),
        ("push_links=[no_such_link]", "no link 'no_such_link'"),
        ("energy_mode=kinetic", "energy_mode"),
        ("onset_s=[2.0, 1.0]", "onset_s"),
        ("search_seeds=[]", "search_seeds"),
        ("search_seeds=[1, 1]", "search_seeds"),
        ("restarts=3", "restarts"),
        ("polish_budget=3", "polish_budget must be 0 or an integer >= popsize"),
        ("polish_starts=0", "polish_starts must be an integer from 1 to budget"),
        ("polish_starts=11", "polish_starts must be an integer from 1 to budget"),
        ("polish_sigma=0", "polish_sigma"),  # 10 episodes over 4 runs: fewer than a population each
        ("space=cube", "space"),
        # an empty search space: a box onset range of zero width, a single frequency
        ("space=box;onset_s=[1.0, 1.0]", r"onset_s \[1, 1\] is an empty search range"),
        ("families=[periodic];frequency_hz=[1.0, 1.0]", "frequency_hz .* empty search range"),
        ("gains=fancy", "gains"),
        ("rates={computed_torque: {omega: 3.0}}", "rates must map searched controllers"),
        ("rates={pd_gravity: 3.0}", "rates of pd_gravity: a non-empty mapping"),
        ("rates={pd_gravity: {no_such_rate: 1.0}}", "no_such_rate"),
        ("rates={pd_gravity: {omega: -3.0}}", "kind"),
    ],
)
def test_bad_input_is_refused_before_any_episode(tmp_path, override, match, capsys) -> None:
    overrides = override.split(";")
    extra = ["families=[push]"] if "push_links" in override else []
    cfg = load_config(None, [*TINY, "budget=10", *extra, *overrides, f"out={tmp_path / 'x'}"])
    with pytest.raises(InvalidConfigError, match=match):
        run_search(cfg, progress=False)
    assert not (tmp_path / "x").exists()
    with pytest.raises(SystemExit) as exc:
        main([*[a for t in [*TINY, "budget=10", *extra, *overrides] for a in ("--set", t)],
              "--out", str(tmp_path / "y")])  # fmt: skip
    assert exc.value.code == 2
    assert not (tmp_path / "y").exists()


def test_a_search_with_other_gain_rates_runs_and_replays_with_them(tmp_path) -> None:
    """``rates``: the episodes run the controller with them, ``worst.yml`` records them (a
    replay reproduces the worst case exactly), the summary names them."""
    out = tmp_path / "rated"
    run_search(load_config(None, cfg_args(out)), progress=False)
    entry = yaml.safe_load((out / "worst.yml").read_text())["worst"]["pd_gravity"]["impulse"]
    entry = entry["0.6"]
    assert entry["gains"] == {"zeta": 1.0, "omega": 40.0}  # the default's, its omega over them
    assert replay(out / "worst.yml", "pd_gravity", "impulse", 0.6).cost == entry["cost_rad"]
    default = replay(out / "worst.yml", "pd_gravity", "impulse", 0.6, rates={"omega": 20.0})
    assert default.cost != entry["cost_rad"]
    assert "pd_gravity with {'omega': 40.0}" in (out / "summary.md").read_text()
    # a resume with other rates, or with rates over a search saved before they existed
    # (it ran without), would mix two controllers in one journal: refused
    other = [a.replace("40.0", "30.0") for a in cfg_args(out)]
    with pytest.raises(InvalidConfigError, match="different settings"):
        run_search(load_config(None, other), resume=True, progress=False)
    saved = yaml.safe_load((out / "config.yml").read_text())
    assert saved["ran_at"] == {"pd_gravity": entry["gains"]}  # the rates its trials ran
    # ptrack adversary --config <search>/config.yml reads the record back as no setting
    assert load_config(out / "config.yml", []) == load_config(None, cfg_args(out))
    (out / "config.yml").write_text(yaml.safe_dump({**saved, "rates": None}))
    with pytest.raises(InvalidConfigError, match="different settings"):
        run_search(load_config(None, cfg_args(out)), resume=True, progress=False)


def cfg_args(out):
    """The rated search's settings (``test_a_search_with_other_gain_rates_…``)."""
    return [*TINY, "budget=10", "polish_budget=0", "search_seeds=[0]",
            "rates={pd_gravity: {omega: 40.0}}", f"out={out}"]  # fmt: skip


def test_tuned_gains_that_do_not_exist_are_refused_before_any_episode(
    tmp_path, monkeypatch
) -> None:
    import agents.registry

    monkeypatch.setattr(agents.registry, "TUNED_DIR", tmp_path / "none")
    cfg = load_config(None, [*TINY, "budget=10", "gains=tuned", f"out={tmp_path / 'x'}"])
    with pytest.raises(InvalidConfigError, match="no tuned gains for pd_gravity"):
        run_search(cfg, progress=False)
    assert not (tmp_path / "x").exists()


def test_unknown_config_keys_are_refused() -> None:
    with pytest.raises(InvalidConfigError, match=r"unknown field\(s\) \['budjet'\]"):
        load_config(None, ["budjet=3"])
    assert isinstance(load_config(None, []), AdversaryConfig)


def test_sphere_angles_give_unit_directions_that_wrap() -> None:
    import math

    from train.studies.worst_case import ANGLE_RANGE, is_wrapping, sphere_point

    rng = np.random.default_rng(0)
    for d in (2, 3, 7):
        for _ in range(20):
            a = rng.uniform(*ANGLE_RANGE, size=d - 1)
            x = np.array(sphere_point(a))
            assert x.shape == (d,) and abs(np.linalg.norm(x) - 1.0) < 1e-12
            np.testing.assert_allclose(sphere_point(a + 2 * math.pi), x, atol=1e-12)
    # every direction is reached: the angles of a point give it back (d = 3)
    target = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    phi1 = math.acos(target[0])
    phi2 = math.atan2(target[2], target[1])
    np.testing.assert_allclose(sphere_point([phi1, phi2]), target, atol=1e-12)
    assert is_wrapping("a0") and is_wrapping("start_phase") and is_wrapping("onset_phase")
    assert not is_wrapping("frequency_hz") and not is_wrapping("x0") and not is_wrapping("alpha")


def test_parameters_within_2_percent_of_a_bound_are_flagged() -> None:
    import optuna

    from train.studies.adversary import on_bound

    f = optuna.distributions.FloatDistribution(0.2, 5.0, log=True)
    a = optuna.distributions.FloatDistribution(-3.0, 9.0)
    lin = optuna.distributions.FloatDistribution(0.0, 1.0)

    def trial(**params):
        dists = {"frequency_hz": f, "a0": a, "x0": lin}
        return optuna.trial.create_trial(
            params=params, distributions={k: dists[k] for k in params}, value=1.0
        )

    # log space: 4.7 Hz is 1.9 % of the log range below 5 Hz; a wrapping angle never counts
    assert on_bound([trial(frequency_hz=4.7, a0=-3.0)]) == ["frequency_hz"]
    assert on_bound([trial(frequency_hz=4.0, a0=9.0)]) == []
    assert on_bound([trial(frequency_hz=1.0, x0=0.015)]) == ["x0"]
    assert on_bound([trial(frequency_hz=1.0, x0=0.5), trial(frequency_hz=0.205)]) == [
        "frequency_hz"
    ]


def test_a_search_of_the_old_protocol_still_replays(tmp_path) -> None:
    """A config.yml written before issue 38 (one ``seed``, the box) loads as that search."""
    from train.studies.adversary_config import saved_config

    old = dataclass_dict(AdversaryConfig())
    old.pop("search_seeds")
    old.pop("space")
    old.pop("restarts")
    old["seed"] = 4
    old.pop("polish_budget")
    cfg = saved_config(old)
    assert cfg.search_seeds == [4] and cfg.space == "box" and cfg.restarts == 0
    assert cfg.polish_budget == 0  # it ran no local run


def dataclass_dict(cfg: AdversaryConfig) -> dict:
    import dataclasses

    return dataclasses.asdict(cfg)


def test_a_committed_worst_case_replays_at_the_rates_it_records() -> None:
    """A published default-gain search records the rates its episodes ran (every numeric
    default rate), and its worst case replays from them bit for bit — whatever the default
    is today."""
    from pathlib import Path

    from agents.registry import effective_rates
    from ptrack_gym.robots import robot_profile
    from train.studies.worst_case import replay

    worst = Path(__file__).resolve().parents[1] / "docs/results/worst_passivity_default_two_link"
    data = yaml.safe_load((worst / "worst.yml").read_text())["worst"]["passivity"]["impulse"]
    ((energy, cell),) = data.items()
    known = effective_rates(robot_profile("two_link"), "passivity")
    assert isinstance(cell["gains"], dict) and set(cell["gains"]) < set(known)
    outcome = replay(worst / "worst.yml", "passivity", "impulse", float(energy))
    assert outcome.cost == cell["cost_rad"] and outcome.unstable == cell["unstable"]


def test_a_resume_after_the_default_gains_moved_is_refused(tmp_path, monkeypatch) -> None:
    """A search records the rates its controllers ran (``ran_at``); the day a default (or a
    tuned file) changes, resuming it would add trials at other gains to its journal:
    refused, naming the record."""
    from agents.registry import entry

    out = tmp_path / "moved"
    args = [*TINY, "budget=10", "polish_budget=0", "search_seeds=[0]", f"out={out}"]
    run_search(load_config(None, args), progress=False)
    run_search(load_config(None, args), resume=True, progress=False)  # nothing moved: fine
    monkeypatch.setitem(entry("pd_gravity").rates.DEFAULT_RATES, "zeta", 0.8)
    with pytest.raises(InvalidConfigError, match="different settings: ran_at"):
        run_search(load_config(None, args), resume=True, progress=False)


def test_a_further_local_run_starts_at_an_unused_draw_when_every_draw_shares_a_basin() -> None:
    from types import SimpleNamespace

    from train.studies.adversary import local_start
    from train.studies.worst_case import Searchable

    target = Searchable(load_config(None, TINY), "impulse", 0.6)

    def draw(value: float, onset: float, x: float):  # type: ignore[no-untyped-def]
        spec = {"onset_s": onset, "direction": [1.0, 0.0]}
        return SimpleNamespace(value=value, params={"x": x}, user_attrs={"spec": spec, "s0": 0.0})

    near = [draw(0.3, 1.0, 0.0), draw(0.2, 1.01, 1.0), draw(0.1, 1.02, 2.0)]
    far = draw(0.05, 2.0, 3.0)
    worst = {"params": {"x": 0.0}, "spec": near[0].user_attrs["spec"], "s0": 0.0}
    assert local_start(target, near, near, [])["params"] == {"x": 0.0}  # the first: the worst
    assert local_start(target, near, [*near, far], [worst])["params"] == {"x": 3.0}  # elsewhere
    # every draw in the searched basin: the worst draw no local run started from
    assert local_start(target, near, near, [worst])["params"] == {"x": 1.0}
