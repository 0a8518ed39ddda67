"""The models shipped in ``models/``: the main job's RL sweeps
(``train/configs/evaluate/main_rl.yml``, the two-link;
``train/configs/evaluate/main_rl_iiwa.yml``, the iiwa) and the held-out sweep of issue 39's
residuals (``train/configs/evaluate/heldout_rl_two_link.yml``)
must be able to run each without training, and each must be the small, reproducible artefact
its README describes."""

from __future__ import annotations

import dataclasses

import pytest

pytest.importorskip(
    "stable_baselines3", reason="the optional 'train' extra (SB3, torch) is not installed"
)

import shlex
from pathlib import Path

import numpy as np
import yaml

from train.evaluation.config import load_config
from train.evaluation.episode import EpisodeSettings, Task, run_episode
from train.evaluation.policies import deploy_safeguards, sb3_files
from train.rl.config import parse_args
from train.studies.action_probe import action_usage

ROOT = Path(__file__).resolve().parents[1]
MAIN_RL = (
    ROOT / "train/configs/evaluate/main_rl.yml",
    ROOT / "train/configs/evaluate/main_rl_iiwa.yml",
    ROOT / "train/configs/evaluate/heldout_rl_two_link.yml",
)
#: Each shipped model with the main-job config that evaluates it.
CONFIG_OF = {
    c: config
    for config in MAIN_RL
    for c in yaml.safe_load(config.read_text())["controllers"]
    if c.startswith("sb3:")
}
MODELS = sorted(CONFIG_OF)


def test_main_rl_configs_include_every_shipped_model_and_validate(monkeypatch) -> None:
    monkeypatch.chdir(ROOT)  # the configs name the models relative to the repository
    shipped = {f"sb3:models/{p.name}" for p in (ROOT / "models").iterdir() if p.is_dir()}
    assert shipped == set(MODELS)
    for config in MAIN_RL:
        load_config(config, []).validate()  # the files exist, trained on the config's env


@pytest.mark.parametrize("model", MODELS)
def test_shipped_model_is_small_and_its_command_reproduces_its_config(model: str) -> None:
    run_dir, model_zip, _ = sb3_files(model)
    run_dir = ROOT / run_dir
    assert (ROOT / model_zip).stat().st_size < 5_000_000  # "a few MB at most"
    assert (run_dir / "README.md").exists()
    saved = yaml.safe_load((run_dir / "config.yml").read_text())["config"]
    command = (run_dir / "command.txt").read_text().splitlines()[-1]
    argv = shlex.split(command)
    if argv[:2] == ["ptrack", "train"]:  # a campaign's run (train.rl.campaign)
        args = argv[2:]
    else:  # recorded before 0.3, whose `--set key=value` was an SB3 hyperparameter: `--hp`
        assert argv[1:3] == ["-m", "train.train"]  # now (CHANGELOG.md); the rest as it stands
        args = ["--hp" if word == "--set" else word for word in argv[3:]]
    rebuilt = parse_args(args)
    for key, value in saved.items():
        if key not in ("out", "resume", "steps", "progress_bar"):  # per invocation
            assert getattr(rebuilt, key) == value, key


@pytest.mark.parametrize("model", MODELS)
def test_shipped_model_runs_deterministically_and_acts(model: str, monkeypatch) -> None:
    """Two runs of one episode give identical metrics, and the policy acts: a residual's
    correction changes its base's torque, a pure policy keeps the arm near the path (a
    broken observation layout or a failed load would not give a finite, repeatable,
    non-trivial run). A residual with a control prior acts even with a dead network, so for
    residuals the network's own deterministic action must be non-zero too."""
    monkeypatch.chdir(ROOT)
    # 1-s episodes: no preset with an onset (1-4 s) fits; periodic acts from t = 0
    cfg = load_config(CONFIG_OF[model], ["episode_s=1.0", "disturbances=[none, periodic]"])
    run_dir = ROOT / sb3_files(model)[0]
    base = yaml.safe_load((run_dir / "config.yml").read_text())["config"]
    if base["residual"] != "none":  # the learned part, one undisturbed episode (action_probe)
        assert action_usage(run_dir, seed=0).mean_abs > 1e-3
    settings: EpisodeSettings = cfg.settings()
    task = Task(model, "periodic", 1.0, 0, 0)
    row_a, trace = run_episode(task, settings, keep_trace=True)
    row_b, _ = run_episode(task, settings, keep_trace=False)
    assert row_a["steps"] == round(cfg.control_hz)  # 1 s at the model's rate
    for key, value in row_a.items():
        if key != "wall_s":
            assert row_b[key] == value or (value != value and row_b[key] != row_b[key]), key
    assert np.isfinite(row_a["path_dist_rms"]) and not row_a["failed"]
    assert trace is not None
    gated = (run_dir / "deploy.yml").exists()
    if base["residual"] != "none" and not gated:
        base_name = (  # a network base is a shipped model of its own
            f"sb3:{base['base_model']}" if base["residual"] == "network" else base["residual"]
        )
        alone, _ = run_episode(Task(base_name, "periodic", 1.0, 0, 0), settings)
        assert row_a["tau_rms_frac"] != alone["tau_rms_frac"]  # the residual acted
    elif gated:  # on the path it is its base, bit for bit; pushed off it, it acts
        gate = yaml.safe_load((run_dir / "deploy.yml").read_text())
        band = gate["gate_deadband_rad"]
        pinned = yaml.safe_load((run_dir / "config.yml").read_text())["derived"].get("base_rates")
        # its base alone at the rates it trained over (pinned), not agents/tuned's of today
        own = dataclasses.replace(settings, gains=tuple(pinned.items())) if pinned else settings
        for disturbance, same in (("none", True), ("noise", False)):
            level = 0.0 if disturbance == "none" else 2.0  # noise: off the band within 1 s
            row, _ = run_episode(Task(model, disturbance, level, 0, 0), settings)
            alone, _ = run_episode(Task(base["residual"], disturbance, level, 0, 0), own)
            assert (alone["path_dist_max"] > band) != same  # the base left the band or not
            assert (row["tau_rms_frac"] == alone["tau_rms_frac"]) == same, disturbance
    else:
        assert row_a["path_dist_rms"] < 0.1  # a pure policy that tracks, roughly


def test_the_iiwa_residuals_keep_the_base_they_trained_over(monkeypatch) -> None:
    """The shipped iiwa residuals trained over the one-seed tuned gains; the tuning fight
    retuned agents/tuned since. Each runs over its pinned rates (derived.base_rates), and a
    sweep that runs its base alone at today's tuned gains says so."""
    from agents.registry import tuned_rates
    from train.evaluation.config import load_config
    from train.evaluation.envs import trained_wrapper_kwargs
    from train.evaluation.policies import run_config

    monkeypatch.chdir(ROOT)
    shipped = (("sac_residual_passivity_iiwa_gated", "passivity"),
               ("sac_residual_computed_torque_iiwa_gated", "computed_torque"))  # fmt: skip
    for model, base in shipped:
        run = run_config(ROOT / "models" / model)
        pinned = trained_wrapper_kwargs(run)["base_gains"]
        assert pinned == run["derived"]["base_rates"] != tuned_rates("iiwa", base)
    cfg = load_config(ROOT / "train/configs/evaluate/main_rl_iiwa.yml", [])
    lines = cfg.base_gain_mismatches()
    assert sum("at tuned rates since retuned" in line for line in lines) == 2


def test_every_shipped_residual_pins_the_rates_of_its_base() -> None:
    """A shipped residual over a controller (not a network) names the rates its base ran
    (``derived.base_rates``), each a rate that base knows, so moving a default or retuning
    cannot silently change the base it learned to correct."""
    from agents.registry import pinned_rates
    from agents.residual import NETWORK_BASE
    from ptrack_gym.robots import robot_profile
    from train.evaluation.policies import run_config

    residuals = 0
    for folder in sorted((ROOT / "models").iterdir()):
        run = run_config(folder)
        base = run["config"].get("residual", "none")
        if base in ("none", NETWORK_BASE):
            continue
        residuals += 1
        pinned = run["derived"].get("base_rates")
        assert pinned, folder.name
        every = pinned_rates(robot_profile(run["derived"]["robot"]), base, "default")
        assert set(pinned) == set(every), folder.name  # complete: no rate left to a default
    assert residuals >= 6


def test_the_two_link_sweeps_run_the_residuals_bases_alone_at_their_pins(monkeypatch) -> None:
    """The two-link residuals pinned the default passivity rates of their day (ζ = 0): the
    RL sweeps run passivity alone at them too (``controller_rates``), so no pairing warns;
    without it, passivity alone would run today's default against their ζ = 0 base."""
    import dataclasses

    from agents.passivity_gains import DEFAULT_RATES

    monkeypatch.chdir(ROOT)
    moved = DEFAULT_RATES["damping_ratio"] != 0.0
    for name in ("main_rl", "heldout_paths_rl"):
        cfg = load_config(ROOT / f"train/configs/evaluate/{name}.yml", [])
        assert cfg.base_gain_mismatches() == [], name
        bare = dataclasses.replace(cfg, controller_rates={})
        assert bool(bare.base_gain_mismatches()) == moved, name


TANKED = [m for m in MODELS if deploy_safeguards(ROOT / sb3_files(m)[0]).get("tank")]


@pytest.mark.parametrize("model", TANKED)
@pytest.mark.parametrize("disturbance", ["delay", "noise", "periodic"])
def test_a_shipped_tank_residual_keeps_the_storage_balance(
    model: str, disturbance: str, monkeypatch
) -> None:
    """A shipped residual deployed behind an energy tank (its ``deploy.yml``): storage +
    tank never above their start and the pump's, re-synchronisation's and disturbance's
    work by more than the law's own residue, behind a delayed or noisy sensor too — on a
    test path it never saw (2 s, random path 1)."""
    from train.studies.verdict_entrants import tank_record

    monkeypatch.chdir(ROOT)
    cfg = load_config(CONFIG_OF[model], ["episode_s=2.0", "disturbances=[none, periodic]"])
    settings = dataclasses.replace(cfg.settings(), path="random", path_seed=1)
    row, _ = run_episode(Task(model, disturbance, 1.0, 0, 0), settings, inspect=tank_record)
    assert not row["failed"]
    assert row["balance_excess_j"] <= 0.01  # J; the law's residue here is ≤ 0.007 J
    assert row["tank_withheld_j"] == row["tank_withheld_j"]  # the tank ran (not NaN)
