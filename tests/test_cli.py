"""``ptrack``: every command answers ``--help`` with its config's fields and their
docstrings, a bad command or config exits 2 with one line, and the old entry points
(``python -m train.evaluate``, ``python -m train.train``) still run."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from train.cli import COMMANDS, main, results_kind
from train.common.arguments import field_docs

ROOT = Path(__file__).resolve().parents[1]


def _help(command: str, capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0
    return capsys.readouterr().out


@pytest.mark.parametrize(
    ("command", "module", "cls"),
    [
        ("evaluate", "train.evaluation.config", "EvalConfig"),
        ("train", "train.rl.config", "TrainConfig"),
        ("study", "train.rl.study", "StudyConfig"),
        ("tune", "train.studies.tune", "TuneConfig"),
        ("fronts", "train.studies.fronts", "FrontConfig"),
        ("adversary", "train.studies.adversary_config", "AdversaryConfig"),
        ("rates", "train.studies.rates", "RatesConfig"),
    ],
)
def test_help_lists_every_field_with_its_docstring(command, module, cls, capsys) -> None:
    import importlib

    config = getattr(importlib.import_module(module), cls)
    text = " ".join(_help(command, capsys).split())
    assert "--config" in text and "--set" in text
    for name, doc in field_docs(config).items():
        if name == "overrides":  # TrainConfig's SB3 hyperparameters: --hp
            assert "--hp" in text
            continue
        assert "--" + name.replace("_", "-") in text, name
        first_words = " ".join(doc.split()[:4]).replace("%", "%%")
        assert " ".join(first_words.split()).replace("%%", "%") in text, (name, first_words)


def test_every_command_has_help(capsys) -> None:
    for command in COMMANDS:
        with pytest.raises(SystemExit) as exc:
            main([command, "--help"])
        assert exc.value.code == 0, command
        assert "usage: ptrack " + command in capsys.readouterr().out


def test_an_unknown_command_or_field_exits_2_with_one_line(capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["evalute"])
    assert exc.value.code == 2
    assert "invalid choice: 'evalute'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", "--set", "sedes=2"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "unknown field(s) ['sedes'] in --set; did you mean ['seeds']" in err


def test_report_refuses_a_folder_that_holds_no_results(tmp_path, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["report", str(tmp_path)])
    assert exc.value.code == 2
    assert "no config.yml and episodes.csv" in capsys.readouterr().err
    assert results_kind(ROOT / "docs" / "results" / "control_rates") == "rates"


@pytest.mark.parametrize("module", ["train.evaluate", "train.train", "train.cli"])
def test_the_module_entry_points_run(module: str) -> None:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    args = ["--help"] if module != "train.cli" else ["evaluate", "--help"]
    done = subprocess.run(
        [sys.executable, "-m", module, *args], cwd=ROOT, env=env, capture_output=True,
        text=True, timeout=120, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "--config" in done.stdout


def test_a_missing_file_is_a_usage_error_and_a_failure_is_status_1(
    tmp_path, capsys, monkeypatch
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["replay", str(tmp_path)])
    assert exc.value.code == 2
    assert "worst.yml does not exist" in capsys.readouterr().err
    (tmp_path / "worst.yml").write_text("worst: {}\n")
    with pytest.raises(SystemExit) as exc:
        main(["replay", str(tmp_path), "--under", "no_such_controller"])
    assert exc.value.code == 2
    assert "no_such_controller" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["replay", str(tmp_path), "--rate", "damping_ratio"])
    assert exc.value.code == 2
    assert "--rate expects rate=value, got 'damping_ratio'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["replay", str(tmp_path), "--rate", "damping_ratio=[0.5"])
    assert exc.value.code == 2
    assert "--rate damping_ratio: not YAML" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["verdict", "--set", "seeds=1", "--out", str(tmp_path / "v"), "--rerun-changed"])
    assert exc.value.code == 2
    assert "--rerun-changed acts on a resume" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", "--config", str(tmp_path / "nope.yml")])
    assert exc.value.code == 2
    assert "nope.yml" in capsys.readouterr().err

    def broken(args, parser):
        raise RuntimeError("the pool died")

    summary, build, _ = COMMANDS["report"]
    monkeypatch.setitem(COMMANDS, "report", (summary, build, broken))
    monkeypatch.delenv("PTRACK_TRACEBACK", raising=False)
    assert main(["report", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.strip() == (
        "ptrack report: failed: RuntimeError: the pool died (PTRACK_TRACEBACK=1 shows where)"
    )


def test_an_interrupted_command_says_how_to_continue(monkeypatch, capsys, tmp_path) -> None:
    """Ctrl-C (or a scheduler's SIGINT) in any command: no traceback, status 130, and the
    message names --resume (the sweeps, tunings and searches append their results)."""

    def interrupted(args, parser):
        raise KeyboardInterrupt

    summary, build, _ = COMMANDS["report"]
    monkeypatch.setitem(COMMANDS, "report", (summary, build, interrupted))
    assert main(["report", str(tmp_path)]) == 130
    err = capsys.readouterr().err
    assert err.startswith("ptrack report: interrupted;") and "--resume" in err
    assert "Traceback" not in err


def test_report_against_another_sweep_prints_how_alike_they_rank(capsys) -> None:
    main_job = ROOT / "docs" / "results" / "main"
    assert main(["report", str(main_job), "--no-rewrite", "--against", str(main_job)]) == 0
    out = capsys.readouterr().out
    assert "Rankings, main against main, path_dist_rms:" in out
    assert "Rankings, main against main, time_err_rms:" in out
    assert "Same leader in 13 of 13 conditions; Kendall τ mean 1.00, min 1.00." in out
    with pytest.raises(SystemExit) as exc:
        main(["report", str(main_job), "--no-rewrite", "--against",
              str(ROOT / "docs" / "results" / "control_rates")])  # fmt: skip
    assert exc.value.code == 2
    assert "not an evaluation's results folder" in capsys.readouterr().err
