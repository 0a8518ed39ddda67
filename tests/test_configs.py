"""Every shipped config validates: the main job, the tuning studies, the adversarial
searches and the RL configs name controllers, presets and tuned gains that exist."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted((ROOT / "train" / "configs").glob("*/*.yml"))


def _loader(path: Path):
    """The loader of the command whose folder holds the config (its schema)."""
    kind, name = path.parent.name, path.stem
    if kind == "tune":
        pytest.importorskip("optuna", reason="the 'tune' extra")
        from train.studies.tune import load_config

        return lambda p: load_config(p, []).validate()
    if kind == "adversary":
        pytest.importorskip("optuna", reason="the 'tune' extra")
        from train.studies.adversary import load_config

        def check_search(p: Path) -> None:
            cfg = load_config(p, [])
            if cfg.gains == "tuned" and p.stem.startswith("worst_"):  # tuned where a fight ran:
                cfg.gains = "default"  # test_the_verdict_has_tuned_gains_on_every_robot
            cfg.validate()

        return check_search
    if kind == "rates":  # the control-rate studies (train.studies.rates)
        from train.studies.rates import load_config

        return lambda p: load_config(p, []).validate()
    if kind == "verdict":  # the study across robots (train.studies.verdict_study)
        from train.studies.verdict_study import load_config

        def check(p: Path) -> None:
            cfg = load_config(p, [])
            runs = [n.removeprefix("sb3:") for ns in cfg.entrants.values() for n in ns]
            if any(not (ROOT / r).is_dir() for r in runs if r.startswith("runs/")):
                pytest.skip(f"{name} judges local training runs (runs/, made by its campaign)")
            # tuned gains exist only where a fight ran (test_the_verdict_has_tuned_gains_on_
            # every_robot); entrants are refused beside controllers at other gains than their
            # base's, so a config with local runs keeps its own
            if cfg.gains == "tuned" and not runs:
                cfg.gains = "default"
            cfg.validate()

        return check
    if kind == "campaign":  # the RL studies (train.rl.campaign)
        pytest.importorskip("stable_baselines3", reason="training needs the 'train' extra")
        from train.rl.campaign import validate_campaign

        return validate_campaign
    assert kind == "evaluate", f"{path}: configs live in train/configs/<command>/"
    text = path.read_text()
    if "sb3:" in text:
        pytest.importorskip("stable_baselines3", reason="a trained model needs the 'train' extra")
    raw = yaml.safe_load(text)
    named = [*raw.get("controllers", []), raw.get("reference", "")]
    entrants = [  # the sb3 entrants' run folders ("sb3:<folder>[@<steps>]")
        Path(c.removeprefix("sb3:").split("@")[0])
        for c in named
        if isinstance(c, str) and c.startswith("sb3:")
    ]
    local = [run for run in entrants if run.parts[0] == "runs"]  # not shipped models
    if any(not (ROOT / run).is_dir() for run in local):
        pytest.skip(f"{name} evaluates local training runs (runs/, made by its make target)")
    from train.evaluation.config import load_config

    return lambda p: load_config(p, [])  # validates


@pytest.mark.parametrize("path", CONFIGS, ids=[p.stem for p in CONFIGS])
def test_shipped_config_validates(path: Path, monkeypatch) -> None:
    monkeypatch.chdir(ROOT)  # configs name repository paths
    _loader(path)(path)


def test_the_main_job_compares_tuned_gains_on_enough_seeds() -> None:
    from train.evaluation.config import load_config

    cfg = load_config(ROOT / "train/configs/evaluate/main.yml", [])
    assert cfg.gains == "tuned" and cfg.seeds >= 20
    assert {"passivity", "passivity_paper"} <= set(cfg.controllers)
    # an impulse ends by the top of its onset range + 50 ms: >= 3 s of recovery is measured
    from ptrack_gym.disturbances.base import DISTURBANCES

    onset = DISTURBANCES["impulse"].__dataclass_fields__["onset_s"].default
    assert cfg.episode_s - (onset[1] + 0.05) >= 3.0


def test_the_verdict_has_tuned_gains_on_every_robot(monkeypatch) -> None:
    """The verdict and the unboxed worst-case searches (``worst_<robot>.yml``) at tuned gains."""
    pytest.importorskip("optuna", reason="the 'tune' extra")
    from train.studies.adversary import load_config as search_config
    from train.studies.verdict_study import load_config

    monkeypatch.chdir(ROOT)
    load_config(ROOT / "train/configs/verdict/verdict.yml", []).validate()
    for robot in ("two_link", "iiwa", "panda", "xarm6"):
        search_config(ROOT / f"train/configs/adversary/worst_{robot}.yml", []).validate()
