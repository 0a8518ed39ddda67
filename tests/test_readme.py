"""The README's promises: its first lines are the two commands (``make run``, ``make test``),
and every other command it shows runs — here, on tiny settings — or in CI (``make docs``:
``.ci/run``).

The commands are read from the README itself, so a command added there is run here: a
``ptrack`` line runs as written plus overrides that shrink it (one seed, short episodes,
two controllers, no figures), in a scratch folder; ``make experiment CONFIG=... ARGS=...``
runs as the Makefile's recipe says it does (``make -n`` prints it: checked); the Python
quick start runs as it is.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()

#: Overrides that shrink each command's work (later --set wins over the README's).
TINY: dict[str, list[str]] = {
    "evaluate": [
        "seeds=1", "episode_s=4.6", "controllers=[pd_gravity, computed_torque]",
        "reference=computed_torque", "disturbances=[none, impulse]", "levels=[1.0]",
        "plots=false", "workers=1", "bootstrap_resamples=50", "worst_case=[]",
    ],
    "rates": [
        "robots=[two_link]", "controllers=[pd_gravity]", "control_rates=[1000.0, 500.0]",
        "paths=1", "disturbances=[none]", "episode_s=0.3", "plots=false", "workers=1",
    ],
}  # fmt: skip
#: Commands CI runs itself (.ci/run), and the two the README's first lines promise.
RUN_ELSEWHERE = ("make run", "make test", "make docs")


def _blocks(language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", README, flags=re.S)


def _commands() -> list[str]:
    lines = [ln.strip() for block in _blocks("bash") for ln in block.splitlines()]
    return [ln for ln in lines if ln and not ln.startswith("#")]


def test_the_first_lines_are_the_two_commands() -> None:
    lines = [ln.strip() for ln in README.splitlines()[1:] if ln.strip()]
    assert lines[0].startswith("make run") and lines[1].startswith("make test")
    ci = (ROOT / ".ci" / "run").read_text()
    assert "make test" in ci and "make docs" in ci


def test_the_readme_shows_commands_and_they_are_known() -> None:
    commands = _commands()
    assert any(c.startswith("ptrack evaluate") for c in commands)
    for command in commands:
        word = shlex.split(command)[0]
        assert word in ("ptrack", "make"), command
        if command.startswith("make"):
            assert command in RUN_ELSEWHERE or command.startswith("make experiment"), command


def _ptrack(words: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "train.cli", *words], cwd=cwd, env=env,
        capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip


def _shrunk(words: list[str]) -> list[str]:
    command = words[0]
    return [*words, *(w for s in TINY.get(command, []) for w in ("--set", s))]


def _experiment(command: str) -> list[str]:
    """The ptrack words of ``make experiment CONFIG=... [ARGS=...]``, as ``make -n``
    prints the recipe (the command is the config's folder)."""
    assignments = dict(w.split("=", 1) for w in shlex.split(command)[2:])
    make = ["make", "-n", "--no-print-directory", "experiment"]
    printed = subprocess.run(
        [*make, *(f"{k}={v}" for k, v in assignments.items())],
        cwd=ROOT, capture_output=True, text=True, check=True,
    ).stdout.strip().splitlines()[-1]  # fmt: skip
    words = shlex.split(printed)
    assert Path(words[0]).name == "ptrack", printed
    config = assignments["CONFIG"]
    assert words[1:4] == [Path(config).parent.name, "--config", config], printed
    return words[1:]


@pytest.fixture(scope="module")
def scratch(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A working folder where the README's relative paths resolve: ``train/configs`` is
    the repository's, ``results/`` is new."""
    folder = tmp_path_factory.mktemp("readme")
    (folder / "train").symlink_to(ROOT / "train")
    (folder / "models").symlink_to(ROOT / "models")
    return folder


def test_every_command_runs_on_tiny_settings(scratch: Path) -> None:
    ran = 0
    for command in _commands():
        if command in RUN_ELSEWHERE:
            continue
        if command.startswith("make experiment"):
            words = _experiment(command)
            words = [*words, "--set", "out=results/experiment"]
        else:
            words = shlex.split(command)[1:]
        if "--help" not in words:
            words = _shrunk(words)
        result = _ptrack(words, scratch)
        output = f"{result.stdout[-2000:]}\n{result.stderr[-4000:]}"
        assert result.returncode == 0, f"{command}\n{output}"
        ran += 1
    assert ran >= 3


def test_the_quick_start_runs(monkeypatch) -> None:
    (code,) = [b for b in _blocks("python") if "gym.make" in b]
    monkeypatch.chdir(ROOT)
    exec(compile(code, "README.md", "exec"), {"__name__": "readme"})
