"""Nothing shipped is a command's default output, and nothing is overwritten unasked.

* every shipped config writes under ``results/`` or ``runs/`` (git-ignored), never into a
  tracked folder (``docs/results``, ``agents/tuned``, …): a dry run resolves each output;
* a run folder that holds any file is refused unless ``--resume`` (continue) or
  ``--force`` (start over in place); ``tune --save`` refuses to replace tuned gains;
* tiny runs of the shipped evaluation, tuning and search configs, from a clean working
  folder, change no tracked file of the repository.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import yaml

from ptrack_gym.errors import InvalidConfigError
from train.common.runs import open_run

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted((ROOT / "train" / "configs").glob("*/*.yml"))


def _output(path: Path) -> str:
    """Where a shipped config writes, as a dry run resolves it (no file is touched)."""
    kind = path.parent.name
    if kind == "campaign":  # ptrack campaign's default --out
        return f"runs/{path.stem}"
    loaders = {
        "evaluate": "train.evaluation.config",
        "rates": "train.studies.rates",
        "tune": "train.studies.tune",
        "adversary": "train.studies.adversary",
        "verdict": "train.studies.verdict_study",
    }
    import importlib

    module = importlib.import_module(loaders[kind])
    if kind == "evaluate":
        return module.load_config(path, [], validate=False).out
    return module.load_config(path, []).out


def _git(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=False)


@pytest.mark.parametrize("path", CONFIGS, ids=[f"{p.parent.name}/{p.stem}" for p in CONFIGS])
def test_every_shipped_config_writes_outside_tracked_folders(path: Path) -> None:
    if path.parent.name in ("tune", "adversary"):
        pytest.importorskip("optuna", reason="the 'tune' extra")
    out = Path(_output(path))
    assert not out.is_absolute() and out.parts[0] in ("results", "runs"), out
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    assert _git("check-ignore", "-q", str(out / "x")).returncode == 0, f"{out} is not ignored"
    assert _git("ls-files", str(out)).stdout == "", f"{out} holds tracked files"


def test_a_folder_that_holds_files_is_refused_unless_resume_or_force(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    with pytest.raises(InvalidConfigError, match=r"already holds 1 file\(s\) \(notes.txt\)"):
        open_run(out, "episodes.csv", {"a": 1}, resume=False)
    assert (out / "notes.txt").read_text() == "mine"
    with pytest.raises(InvalidConfigError, match="not both"):
        open_run(out, "episodes.csv", {"a": 1}, resume=True, force=True)
    (out / "episodes.csv").write_text("header\nrow\n")
    run = open_run(out, "episodes.csv", {"a": 1}, resume=False, force=True)
    assert not run.resumed and not (out / "episodes.csv").exists()  # starts over
    (out / "episodes.csv").write_text("header\nrow\n")
    assert open_run(out, "episodes.csv", {"a": 1}, resume=True).resumed


def test_a_resume_never_shows_another_process_a_partial_config(tmp_path: Path) -> None:
    """Several ``tune --resume`` processes (one per controller) share one folder: each
    rewrites config.yml while the others read it on their own resume check."""
    out = tmp_path / "run"
    settings = {"a": 1, "paths": list(range(300))}
    text = yaml.safe_dump(settings, sort_keys=False)
    open_run(out, "episodes.csv", settings, resume=False)
    (out / "episodes.csv").write_text("header\nrow\n")
    stop = threading.Event()

    def rewrite() -> None:
        while not stop.is_set():
            open_run(out, "episodes.csv", settings, resume=True)

    writer = threading.Thread(target=rewrite)
    writer.start()
    try:
        seen = {(out / "config.yml").read_text() for _ in range(20000)}
    finally:
        stop.set()
        writer.join()
    assert seen == {text}
    assert sorted(p.name for p in out.iterdir()) == ["command.txt", "config.yml", "episodes.csv"]


def test_tune_save_refuses_to_replace_shipped_gains(tmp_path: Path) -> None:
    pytest.importorskip("optuna", reason="the 'tune' extra")
    from agents.registry import TUNED_DIR
    from train.studies.tune import load_config, tune

    cfg = load_config(ROOT / "train/configs/tune/tune_iiwa.yml", [f"out={tmp_path / 't'}"])
    before = {p: p.read_bytes() for p in TUNED_DIR.glob("iiwa-*.yml")}
    with pytest.raises(InvalidConfigError, match=r"--save would replace .*--force"):
        tune(cfg, save_dir=TUNED_DIR, progress=False)
    assert {p: p.read_bytes() for p in TUNED_DIR.glob("iiwa-*.yml")} == before
    assert not (tmp_path / "t").exists()


#: Tiny overrides of each shipped config (its output path left as it is).
TINY = {
    "evaluate/main.yml": [
        "seeds=1", "episode_s=4.6", "controllers=[pd_gravity, computed_torque]",
        "disturbances=[none, impulse]", "levels=[1.0]", "workers=1", "plots=false",
        "bootstrap_resamples=50", "worst_case=[]",
    ],
    "tune/tune_two_link.yml": [
        "trials=2", "startup_trials=1", "controllers=[pd_gravity]", "validation_seeds=[1000]",
        "disturbances=[none]", "episode_s=0.5", "workers=1",
    ],
    "adversary/adversary_two_link.yml": [
        "controllers=[pd_gravity]", "energies_j=[0.3]", "budget=10", "popsize=5", "workers=1",
    ],
}  # fmt: skip


def test_tiny_runs_of_the_shipped_configs_change_no_tracked_file(tmp_path: Path) -> None:
    pytest.importorskip("optuna", reason="the 'tune' extra")
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    (tmp_path / "train").symlink_to(ROOT / "train")
    (tmp_path / "models").symlink_to(ROOT / "models")
    before = _git("status", "--porcelain", "--untracked-files=no").stdout
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
    for config, sets in TINY.items():
        command = config.split("/")[0]
        words = [command, "--config", f"train/configs/{config}", "--no-progress"]
        words += [w for s in sets for w in ("--set", s)]
        done = subprocess.run(
            [sys.executable, "-m", "train.cli", *words], cwd=tmp_path, env=env,
            capture_output=True, text=True, timeout=900, check=False,
        )  # fmt: skip
        assert done.returncode == 0, f"{config}\n{done.stdout[-1500:]}\n{done.stderr[-3000:]}"
    assert _git("status", "--porcelain", "--untracked-files=no").stdout == before
    assert sorted(p.name for p in (tmp_path / "results").iterdir()) == [
        "adversary_two_link",
        "main",
        "tune",
    ]
