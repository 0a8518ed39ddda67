"""``ptrack tune``: a tiny study runs, resumes, refuses seeds the test config uses,
and the gains it saves are the ones ``gains="tuned"`` builds (the fight's seeds, boxes,
widening and feedback effort: ``tests/test_tune_fight.py``)."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("optuna", reason="tuning needs the 'tune' extra")

import agents.registry as registry
from agents import computed_torque, make_controller
from agents.base import ControlContext
from ptrack_gym.errors import InvalidConfigError
from train.cli import run_command
from train.studies.tune import TuneConfig, load_config, study_name, tune

ENV = "ptrack_gym/TwoLinkTrack-v0"


def main(argv: list[str]) -> int:
    """``ptrack tune`` with ``argv``."""
    return run_command("tune", argv)


def tiny(out: Path, **kw: object) -> TuneConfig:
    """Two trials of computed torque on the two-link (one study seed, the fewest trials
    deciding): 1-s episodes at 250 Hz."""
    base: dict[str, object] = dict(
        env_id=ENV,
        controllers=["computed_torque"],
        trials=2,
        trials_per_rate=1,
        study_seeds=[0],
        startup_trials=1,
        validation_seeds=[1000],
        disturbances=["none", "periodic"],
        episode_s=1.0,
        control_hz=250.0,
        workers=1,
        out=str(out),
    )
    base.update(kw)
    return TuneConfig(**base)  # type: ignore[arg-type]


def _trials(out: Path) -> list:
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    storage = JournalStorage(JournalFileBackend(str(out / "optuna.journal")))
    return optuna.load_study(study_name=study_name("computed_torque", 0), storage=storage).trials


def test_tiny_study_runs_resumes_and_its_saved_gains_load(tmp_path, monkeypatch):
    out, saved = tmp_path / "study", tmp_path / "tuned"
    first = tune(tiny(out), progress=False)["computed_torque"]
    assert first["trials"] == 2
    assert np.isfinite(first["error_rad"]) and first["error_rad"] > 0
    assert first["effort"] <= first["effort_budget"]
    before = [t.params for t in _trials(out)]

    with pytest.raises(InvalidConfigError, match="--resume"):
        tune(tiny(out, trials=3), progress=False)
    with pytest.raises(InvalidConfigError, match="different settings"):
        tune(tiny(out, trials=3, episode_s=2.0), resume=True, progress=False)

    best = tune(tiny(out, trials=3), resume=True, save_dir=saved, progress=False)
    with pytest.raises(InvalidConfigError, match="--force"):  # the saved gains are kept
        tune(tiny(out, trials=3), resume=True, save_dir=saved, progress=False)
    # --resume --force: the studies continue (nothing reruns), the saved gains are replaced
    (saved / "two_link-computed_torque.yml").write_text("rates: {}\n")
    again = tune(tiny(out, trials=3), resume=True, save_dir=saved, progress=False, force=True)
    assert again["computed_torque"]["rates"] == best["computed_torque"]["rates"]
    assert "study:" in (saved / "two_link-computed_torque.yml").read_text()
    trials = _trials(out)
    assert len(trials) == 3  # two kept, one new
    assert [t.params for t in trials[:2]] == before
    assert all(t.constraints for t in trials)  # the effort constraint reaches the sampler

    # the resumed study asked what an uninterrupted one asks
    whole = tmp_path / "whole"
    tune(tiny(whole, trials=3), progress=False)
    assert [t.params for t in _trials(whole)] == [t.params for t in trials]

    rates = best["computed_torque"]["rates"]
    monkeypatch.setattr(registry, "TUNED_DIR", saved)
    assert registry.tuned_rates("two_link", "computed_torque") == rates
    env = gym.make(ENV, control_hz=250.0)
    try:
        env.reset(seed=0)
        built = make_controller("computed_torque", env, "tuned")
        expected = computed_torque.gains_from_rates(ControlContext.from_env(env), rates)
        assert built.gains == expected
        default = make_controller("computed_torque", env, "default")
        assert built.gains != default.gains
    finally:
        env.close()


def test_an_interrupted_trial_is_failed_and_replaced_on_resume(tmp_path):
    out = tmp_path / "study"
    tune(tiny(out), progress=False)  # two trials: max(2, 1 per rate x 2 rates)
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    storage = JournalStorage(JournalFileBackend(str(out / "optuna.journal")))
    optuna.load_study(study_name=study_name("computed_torque", 0), storage=storage).ask()
    tune(tiny(out, trials=3), resume=True, progress=False)
    states = [t.state.name for t in _trials(out)]
    assert states == ["COMPLETE", "COMPLETE", "FAIL", "COMPLETE"]


def test_validation_seeds_that_the_test_config_uses_are_refused(tmp_path):
    # the main job uses seeds 0..4 (reset seeds 0, 10 000, ...): seed 2 is one of them
    with pytest.raises(InvalidConfigError, match="test config"):
        tune(tiny(tmp_path, validation_seeds=[1000, 2]), progress=False)
    assert not (tmp_path / "optuna.journal").exists()  # refused before anything ran


def test_validation_paths_run_every_seed_and_disturbance_on_each_path(tmp_path):
    cfg = tiny(tmp_path, validation_paths=[9001, 9002], validation_seeds=[1000, 1001])
    episodes = cfg.episodes("computed_torque", "default")
    assert len(episodes) == 2 * 2 * 2  # paths x seeds x disturbances
    by_path = {s.path_seed: [t.key() for t, s2 in episodes if s2 == s] for _, s in episodes}
    assert sorted(by_path) == [9001, 9002]
    assert by_path[9001] == by_path[9002]  # the same episodes on each path
    assert all(s.path == "random" for _, s in episodes)
    # no validation paths: the default path, as before
    assert {s.path for _, s in tiny(tmp_path).episodes("computed_torque", "default")} == {"default"}


def test_a_paired_validation_design_runs_the_ith_disturbance_on_the_ith_path(tmp_path):
    cfg = tiny(tmp_path, validation_paths=[9001, 9002], validation_seeds=[1000, 1001],
               validation_design="paired")  # fmt: skip
    episodes = cfg.episodes("computed_torque", "default")
    assert len(episodes) == 2 * 2  # paths x seeds
    seen = {(s.path_seed, t.disturbance, t.seed) for t, s in episodes}
    (d0, d1) = cfg.disturbances
    assert seen == {(9001, d0, 1000), (9001, d0, 1001), (9002, d1, 1000), (9002, d1, 1001)}
    with pytest.raises(InvalidConfigError, match="as many validation_paths as disturbances"):
        tiny(tmp_path, validation_paths=[9001], validation_design="paired").validate()
    with pytest.raises(InvalidConfigError, match="validation_design must be one of"):
        tiny(tmp_path, validation_design="latin").validate()


def test_validation_paths_that_the_test_config_runs_on_are_refused(tmp_path):
    test = tmp_path / "test.yml"
    test.write_text(f"env_id: {ENV}\ncontrollers: [computed_torque]\npath: random\n"
                    "path_seed: 7\nseeds: 2\n")  # fmt: skip
    with pytest.raises(InvalidConfigError, match=r"validation paths \[7\] are test paths"):
        tune(tiny(tmp_path / "o", validation_paths=[3, 7], test_config=str(test)), progress=False)
    # on other paths, the test's reset seeds may repeat: the episodes differ by their path
    cfg = tiny(tmp_path / "o", validation_paths=[3], validation_seeds=[1], test_config=str(test))
    cfg.validate()


def test_a_validation_path_seed_without_an_admissible_path_is_refused(tmp_path, no_admissible_path):
    no_admissible_path(5)
    with pytest.raises(InvalidConfigError, match="validation path seed 5: no admissible"):
        tune(tiny(tmp_path, validation_paths=[4, 5]), progress=False)
    assert not (tmp_path / "optuna.journal").exists()


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("controllers", ["residual"], "controllers"),
        ("validation_paths", [3, 3], "validation_paths"),
        ("controllers", [], "controllers"),
        ("disturbances", ["wind"], "disturbances"),
        ("trials", 0, "trials"),
        ("startup_trials", 50, r"startup_trials <= trials .*got trials \d+, startup_trials 50"),
        ("validation_seeds", [], "validation_seeds"),
        ("effort_budget", -0.1, "effort_budget"),
        ("effort_budget", float("nan"), "effort_budget"),
        ("env_id", "ptrack_gym/Nope-v0", "Nope"),
        ("test_config", "missing.yml", "does not exist"),
    ],
)
def test_bad_configs_fail_before_any_episode(tmp_path, field, value, match):
    with pytest.raises(InvalidConfigError, match=match):
        tune(tiny(tmp_path, **{field: value}), progress=False)
    assert not (tmp_path / "optuna.journal").exists()


def test_a_preset_that_does_not_fit_the_episode_is_refused_before_any_episode(tmp_path):
    # the impulse's onset window [1, 4] s and its recovery window need 4.55 s
    with pytest.raises(InvalidConfigError, match="impulse: onset_s"):
        tune(tiny(tmp_path, disturbances=["none", "impulse"], episode_s=4.0), progress=False)
    assert not (tmp_path / "optuna.journal").exists()


def test_cli_refuses_unknown_keys(capsys):
    with pytest.raises(SystemExit):
        main(["--set", "trails=3"])
    assert "unknown field(s) ['trails']" in capsys.readouterr().err
    with pytest.raises(InvalidConfigError, match="field=value"):
        load_config(None, ["trials"])


def test_episode_workers_reuse_envs_across_gains_and_keep_few(monkeypatch):
    # a tuning worker runs a new gain set every trial: the env it steps must not be built
    # (and kept) per gain set — that grew a worker by ~37 MB per episode until it was killed
    from train.evaluation import episode
    from train.evaluation.episode import EpisodeSettings, Task, run_episode

    monkeypatch.setattr(episode, "CACHE_SIZE", 2)
    monkeypatch.setattr(episode, "_ENV_CACHE", type(episode._ENV_CACHE)())
    for omega in (10.0, 20.0, 30.0):
        settings = EpisodeSettings(ENV, 0.1, 250.0, "on_path", 0.5, 0.01, (("omega", omega),))
        run_episode(Task("computed_torque", "none", 0.0, 1000, 0), settings)
    assert len(episode._ENV_CACHE) == 1
    (first,) = episode._ENV_CACHE.values()
    for dist in ("periodic", "noise"):
        run_episode(Task("computed_torque", dist, 1.0, 1000, 0), settings)
    assert len(episode._ENV_CACHE) == 2
    assert first not in episode._ENV_CACHE.values()
    assert not first.unwrapped.sim.connected  # the evicted env was closed
    for env in episode._ENV_CACHE.values():
        env.close()


def test_a_study_folder_from_before_validation_design_resumes_only_as_crossed(tmp_path):
    import yaml

    from train.studies.tune import TrialScore

    class Flat:  # a cheap objective: the folder's settings are what is checked, not scores
        def score(self, controller, rates):
            return TrialScore(1.0, 0.5, 0)

        def response(self, controller, rates):
            return np.array([0.0])

    out = tmp_path / "study"
    tune(tiny(out, validation_paths=[9001, 9002]), progress=False, objective=Flat())
    saved = yaml.safe_load((out / "config.yml").read_text())
    saved.pop("validation_design")  # as a folder written before the setting existed
    (out / "config.yml").write_text(yaml.safe_dump(saved))
    paired = tiny(out, validation_paths=[9001, 9002], validation_design="paired", trials=3)
    with pytest.raises(InvalidConfigError, match="validation_design 'crossed' -> 'paired'"):
        tune(paired, resume=True, progress=False, objective=Flat())
    tune(tiny(out, validation_paths=[9001, 9002], trials=3), resume=True, progress=False,
         objective=Flat())  # fmt: skip
