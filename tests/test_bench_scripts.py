"""Every benchmark script in ``bench/`` imports (its imports follow the code they measure)
and parses its default arguments: a refactor that moves what a benchmark uses fails here,
not when someone next runs the benchmark. Nothing is timed."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parent.parent / "bench"
#: Scripts whose optional extra may be missing: script → (the modules it needs, the extra).
NEEDS = {
    "panda_gym_compare": (("panda_gym",), "bench"),
    "train_throughput": (("torch", "stable_baselines3"), "train"),
}


@pytest.mark.parametrize("path", sorted(BENCH.glob("*.py")), ids=lambda p: p.stem)
def test_bench_script_imports_and_parses_its_defaults(path: Path, monkeypatch) -> None:
    modules, extra = NEEDS.get(path.stem, ((), ""))
    for name in modules:
        pytest.importorskip(name, reason=f"{path.stem} needs the {extra!r} extra")
    monkeypatch.syspath_prepend(str(BENCH))
    spec = importlib.util.spec_from_file_location(f"bench_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)
    spec.loader.exec_module(module)
    assert callable(module.main)
    if hasattr(module, "parse_args"):
        module.parse_args([])


def test_eval_scaling_refuses_zero_repeats_before_any_sweep(monkeypatch, capsys) -> None:
    spec = importlib.util.spec_from_file_location("bench_eval_scaling", BENCH / "eval_scaling.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(module, "sweep_seconds", lambda *a: pytest.fail("a sweep ran"))
    monkeypatch.setattr(sys, "argv", ["eval_scaling.py", "--repeats", "0"])
    with pytest.raises(SystemExit) as exc:
        module.main()
    assert exc.value.code == 2 and "--repeats must be >= 1" in capsys.readouterr().err
