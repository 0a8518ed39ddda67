"""``ptrack campaign``: the study's runs from its YAML, what is skipped,
resumed or started, and a tiny campaign end to end (then interrupted and completed)."""

from __future__ import annotations

import pytest

pytest.importorskip("stable_baselines3", reason="the optional 'train' extra is not installed")

import os
import shlex
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import yaml

from train.rl.campaign import load_campaign, main, plan, validate_campaign
from train.rl.checkpoints import latest_checkpoint
from train.rl.config import parse_args
from train.rl.hyperparameters import TrainConfigError

ROOT = Path(__file__).resolve().parents[1]

TINY = {
    "seeds": [0, 1],
    "common": {
        "env_id": "ptrack_gym/TwoLinkTrack-v0",
        "steps": 120,
        "episode_s": 0.2,
        "reward": "kernel",
        "checkpoint_freq": 60,
        "eval_freq": 0,
        "overrides": {
            "learning_starts": 20,
            "batch_size": 16,
            "buffer_size": 500,
            "policy_kwargs": "dict(net_arch=[16])",
        },
    },
    "groups": {
        "pure": {"residual": "none"},
        "residual-passivity": {
            "residual": "passivity",
            "zero_init_residual": True,
            "action_penalty": 0.05,
            "overrides": {"learning_starts": 0},
        },
    },
}


def write(tmp_path: Path, data: dict) -> Path:
    path = tmp_path / "study.yml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_the_packaged_study_loads_with_equal_budgets() -> None:
    runs = load_campaign(
        ROOT / "train/configs/campaign/rl_study_two_link.yml", Path("/nonexistent")
    )
    assert len(runs) == 20 and len({r.steps for r in runs}) == 1
    assert {r.seed for r in runs} == {0, 1, 2, 3, 4}
    assert {r.residual for r in runs} == {"none", "passivity", "computed_torque"}
    residual = next(r for r in runs if r.residual == "passivity")
    assert residual.overrides["policy_kwargs"] == "dict(net_arch=[64, 64])"  # common kept
    assert residual.overrides["learning_starts"] == 0  # group override merged over it


@pytest.mark.parametrize(
    "name", ["rl_study_two_link", "rl_ablation_two_link", "rl_deadband_two_link"]
)
def test_every_packaged_campaign_validates(name: str) -> None:
    assert validate_campaign(ROOT / f"train/configs/campaign/{name}.yml") >= 10


@pytest.mark.parametrize(
    ("name", "runs"), [("rl_generalize_two_link", 70), ("rl_generalize_iiwa", 4)]
)
def test_issue_39s_campaigns_validate_with_their_runs(name: str, runs: int) -> None:
    """The protocol's campaigns (7 groups x 10 seeds on the two-link; the iiwa's 4-seed
    screen) parse into the runs their headers say."""
    assert validate_campaign(ROOT / f"train/configs/campaign/{name}.yml") == runs


def test_groups_merge_overrides_key_by_key(tmp_path: Path) -> None:
    runs = load_campaign(write(tmp_path, TINY), tmp_path / "out")
    assert [Path(r.out).name for r in runs] == [
        "pure_s0", "pure_s1", "residual-passivity_s0", "residual-passivity_s1",
    ]  # fmt: skip
    assert runs[2].overrides == {**TINY["common"]["overrides"], "learning_starts": 0}


@pytest.mark.parametrize(
    "bad",
    [
        {**TINY, "extra": 1},
        {**TINY, "seeds": []},
        {**TINY, "groups": {}},
        {**TINY, "groups": {"pure": {"no_such_field": 1}}},
        {**TINY, "groups": {"pure": {"out": "x"}}},
    ],
)
def test_bad_study_files_raise(tmp_path: Path, bad: dict) -> None:
    with pytest.raises(TrainConfigError):
        load_campaign(write(tmp_path, bad), tmp_path / "out")


def test_a_part_of_a_campaign_is_its_runs_with_their_own_folders(tmp_path: Path) -> None:
    path = write(tmp_path, TINY)
    whole = {c.out: c for c in load_campaign(path, tmp_path / "runs")}
    part = load_campaign(path, tmp_path / "runs", groups=["residual-passivity"], seeds=[1])
    assert [c.out for c in part] == [str(tmp_path / "runs" / "residual-passivity_s1")]
    assert part[0] == whole[part[0].out]  # the same run as in the whole campaign
    assert len(load_campaign(path, tmp_path / "runs", seeds=[0])) == 2
    assert len(load_campaign(path, tmp_path / "runs", groups=["pure"])) == 2
    with pytest.raises(TrainConfigError, match=r"no group \['pur'\]"):
        load_campaign(path, tmp_path / "runs", groups=["pur"])
    with pytest.raises(TrainConfigError, match=r"no seed \[7\]"):
        load_campaign(path, tmp_path / "runs", seeds=[0, 7])


def test_an_unknown_group_or_seed_is_a_usage_error_before_any_run(tmp_path: Path) -> None:
    path = write(tmp_path, TINY)
    for extra in (["--groups", "pur"], ["--seeds", "7"]):
        with pytest.raises(SystemExit) as exc:
            main(["--config", str(path), "--out", str(tmp_path / "runs"), *extra])
        assert exc.value.code == 2
    assert not (tmp_path / "runs").exists()


def test_campaign_trains_skips_and_resumes(tmp_path: Path) -> None:
    study, out = write(tmp_path, TINY), tmp_path / "out"
    assert main(["--config", str(study), "--out", str(out), "--workers", "2"]) == 0
    runs = load_campaign(study, out)
    for r in runs:
        assert latest_checkpoint(Path(r.out))[0] == 120
        assert plan(r) is None  # trained: skipped next time
    # interrupt one run: drop its final checkpoint; the campaign continues it from 60
    victim = Path(runs[3].out) / "checkpoints"
    for f in victim.glob("*_120_steps*"):
        f.unlink()
    again = plan(runs[3])
    assert again is not None and again.resume and again.steps == 60
    plan_of_resume = again
    assert main(["--config", str(study), "--out", str(out), "--workers", "1"]) == 0
    assert latest_checkpoint(Path(runs[3].out))[0] == 120
    lines = (Path(runs[3].out) / "command.txt").read_text().splitlines()
    assert len(lines) == 2
    # each line is the standalone `ptrack train` command of its invocation
    assert all(shlex.split(line)[:2] == ["ptrack", "train"] for line in lines)
    first, second = (parse_args(shlex.split(line)[2:]) for line in lines)
    quiet = {"progress_bar": False}  # the workers share a terminal: no progress bars
    assert first == replace(runs[3], **quiet) and second == replace(plan_of_resume, **quiet)


def _workers(parent: int) -> list[int]:
    """The pool's worker processes of ``parent`` (Linux ``/proc``)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == parent and b"spawn_main" in cmdline:
            found.append(int(entry.name))
    return found


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_sigterm_to_the_campaign_stops_its_workers_and_each_run_saves(tmp_path: Path) -> None:
    """``kill <campaign>`` is an interruption: the workers are stopped (not orphaned to
    train on), each running run saves the steps it took, the same command resumes them."""
    long = {**TINY, "seeds": [0], "groups": {"pure": {"residual": "none"}}}
    long["common"] = {**TINY["common"], "steps": 1_000_000, "checkpoint_freq": 100}
    study, out = write(tmp_path, long), tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "train.rl.campaign", "--config", str(study), "--out", str(out),
         "--workers", "1"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    run_dir = out / "pure_s0"
    deadline = time.monotonic() + 120
    while latest_checkpoint(run_dir) is None:  # training is under way
        assert proc.poll() is None and time.monotonic() < deadline, proc.stdout.read()  # type: ignore[union-attr]
        time.sleep(0.2)
    workers = _workers(proc.pid)
    assert workers
    proc.send_signal(signal.SIGTERM)
    output, _ = proc.communicate(timeout=120)
    assert proc.returncode == 130, output
    assert "interrupted" in output
    for pid in workers:  # gone with the campaign, not training on
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
    steps = latest_checkpoint(run_dir)[0]  # type: ignore[index]
    assert (run_dir / "model.zip").exists() and 0 < steps < 1_000_000
    again = plan(load_campaign(study, out)[0])
    assert again is not None and again.resume and again.steps == 1_000_000 - steps


def test_a_ray_backend_without_its_extra_is_a_usage_error(tmp_path: Path, monkeypatch) -> None:
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "ray" else real(name, *a)
    )
    with pytest.raises(SystemExit) as exc:
        main(["--config", str(write(tmp_path, TINY)), "--out", str(tmp_path / "o"),
              "--backend", "ray"])  # fmt: skip
    assert exc.value.code == 2 and not (tmp_path / "o").exists()


@pytest.mark.slow  # Ray's start takes most of a minute: make test-slow
def test_a_campaign_on_ray_trains_the_runs_the_process_pool_does(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    import torch
    from stable_baselines3 import SAC

    one = {**TINY, "seeds": [0], "groups": {"pure": TINY["groups"]["pure"]}}
    study = write(tmp_path, one)
    assert main(["--config", str(study), "--out", str(tmp_path / "p"), "--workers", "1"]) == 0
    assert main(["--config", str(study), "--out", str(tmp_path / "r"), "--workers", "1",
                 "--backend", "ray"]) == 0  # fmt: skip
    a = SAC.load(tmp_path / "p" / "pure_s0" / "model.zip", device="cpu").policy.state_dict()
    b = SAC.load(tmp_path / "r" / "pure_s0" / "model.zip", device="cpu").policy.state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
