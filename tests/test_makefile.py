"""The Makefile's interpreter choice: python3.1x first, then python3, checked for 3.10-3.14."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _path_with(tmp_path: Path, python_name: str | None) -> str:
    """A PATH holding only sh, make and (as ``python_name``) this interpreter."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for tool in ("sh", "make"):
        found = shutil.which(tool)
        if found is None:
            pytest.skip(f"{tool} is not installed")
        (bin_dir / tool).symlink_to(found)
    if python_name is not None:
        (bin_dir / python_name).symlink_to(os.path.realpath(sys.executable))
    return str(bin_dir)


def _check_python(path: str) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHON"} | {"PATH": path}
    return subprocess.run(
        ["make", "--no-print-directory", "check-python"],
        cwd=ROOT, env=env, capture_output=True, text=True, check=False,
    )  # fmt: skip


def test_make_falls_back_to_python3(tmp_path: Path) -> None:
    """Where python3 is the only Python on PATH (and is 3.10-3.14), make uses it."""
    done = _check_python(_path_with(tmp_path, "python3"))
    assert done.returncode == 0, done.stderr


def test_make_without_any_python_says_what_to_install(tmp_path: Path) -> None:
    done = _check_python(_path_with(tmp_path, None))
    assert done.returncode != 0
    assert "no python3.1x or python3 found on PATH" in done.stderr
