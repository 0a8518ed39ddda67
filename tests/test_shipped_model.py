"""The residual SAC model shipped in ``models/`` (issue 6): the main job's second sweep
(``train/configs/main_rl.yml``) must be able to run it without training."""

from __future__ import annotations

import pytest

pytest.importorskip(
    "stable_baselines3", reason="the optional 'train' extra (SB3, torch) is not installed"
)

from pathlib import Path

import numpy as np
import yaml

from train.episode import EpisodeSettings, Task, run_episode
from train.evaluate import load_config
from train.sb3_runs import sb3_files

ROOT = Path(__file__).resolve().parents[1]
MODEL = "sb3:models/sac_residual_passivity_twolink"


def test_main_rl_config_includes_the_shipped_model_and_validates(monkeypatch) -> None:
    monkeypatch.chdir(ROOT)  # the config names the model relative to the repository
    cfg = load_config(ROOT / "train/configs/main_rl.yml", [])
    assert MODEL in cfg.controllers
    cfg.validate()  # the model's files exist and it was trained on the config's env
    run_dir, model_zip, _ = sb3_files(MODEL)
    assert model_zip.stat().st_size < 5_000_000  # "a few MB at most"
    trained = yaml.safe_load((run_dir / "config.yml").read_text())
    assert trained["config"]["residual"] == "passivity"


def test_shipped_model_runs_deterministically_and_acts(monkeypatch) -> None:
    """Two runs of one episode give identical metrics, and the policy's correction is
    not zero: the loaded network drives the residual (a broken observation layout or a
    failed load would not give a finite, repeatable, non-trivial run)."""
    monkeypatch.chdir(ROOT)
    cfg = load_config(ROOT / "train/configs/main_rl.yml", ["episode_s=1.0"])
    settings: EpisodeSettings = cfg.settings()
    task = Task(MODEL, "impulse", 1.0, 0, 0)
    row_a, trace = run_episode(task, settings, keep_trace=True)
    row_b, _ = run_episode(task, settings, keep_trace=False)
    assert row_a["steps"] == 250  # 1 s at the model's 250 Hz
    for key, value in row_a.items():
        if key != "wall_s":
            assert row_b[key] == value or (value != value and row_b[key] != row_b[key]), key
    assert np.isfinite(row_a["path_dist_rms"]) and not row_a["failed"]
    base_task = Task("passivity", "impulse", 1.0, 0, 0)
    base, _ = run_episode(base_task, settings, keep_trace=False)
    assert base["steps"] == 250
    assert row_a["tau_rms_frac"] != base["tau_rms_frac"]  # the residual changed the torque
    assert trace is not None
