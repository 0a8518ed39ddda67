"""The house's layout: every module imports, imports run one way, modules stay small.

The rule (the README's "Layout"): ``train`` → ``agents`` → ``ptrack_gym``; inside
``train``, ``rl`` and ``studies`` → ``evaluation`` → ``plots`` → ``common``; ``train.cli``
and the two thin entry points (``train.evaluate``, ``train.train``) sit above them all.
Every import counts — at module level, inside functions, under ``TYPE_CHECKING`` — read
from the source with :mod:`ast`, so a lazy import cannot hide a circle.
"""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("ptrack_gym", "agents", "train")
MODULES = sorted(
    ".".join(p.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
    for pkg in PACKAGES
    for p in (ROOT / pkg).rglob("*.py")
)

#: Layers, lowest first: a module may import its own layer and those below it only.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("ptrack_gym",),
    ("agents",),
    ("train.common",),
    ("train.plots",),
    ("train.evaluation",),
    ("train.rl", "train.studies"),
    ("train.cli", "train.evaluate", "train.train", "train"),
)

#: Within a layer, these pairs must not import each other either.
SIBLINGS_APART = (("train.rl", "train.studies"),)

MAX_LINES = {"train": 500, "agents.residual": 400}


def _layer(module: str) -> int:
    best, depth = -1, -1
    for i, names in enumerate(LAYERS):
        for name in names:
            if (module == name or module.startswith(name + ".")) and len(name) > depth:
                best, depth = i, len(name)
    assert best >= 0, f"{module} is in no layer"
    return best


def _imports(module: str) -> set[str]:
    """Every package module ``module`` imports anywhere in its source."""
    path = ROOT / Path(*module.split("."))
    path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found.update(f"{node.module}.{a.name}" for a in node.names)
    return {m for m in found if m.split(".")[0] in PACKAGES and m in MODULES}


def _group(module: str) -> str | None:
    for a, b in SIBLINGS_APART:
        for name in (a, b):
            if module == name or module.startswith(name + "."):
                return name
    return None


@pytest.mark.parametrize("module", MODULES)
def test_every_module_imports(module: str) -> None:
    importlib.import_module(module)


def test_imports_run_one_way() -> None:
    upward = []
    for module in MODULES:
        for imported in _imports(module):
            if _layer(imported) > _layer(module):
                upward.append(f"{module} -> {imported}")
            a, b = _group(module), _group(imported)
            if a and b and a != b:
                upward.append(f"{module} -> {imported} (siblings)")
    assert not upward, "imports against the layers:\n" + "\n".join(sorted(upward))


def test_no_import_cycle_between_modules() -> None:
    graph = {m: _imports(m) - {m} for m in MODULES}
    # a package's __init__ re-exporting its own modules is not a cycle of two jobs
    for m in graph:
        graph[m] = {i for i in graph[m] if not m.startswith(i + ".") and i != m}
    state: dict[str, int] = {}
    cycle: list[str] = []

    def visit(node: str, stack: list[str]) -> bool:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1 and not nxt.startswith(node + "."):
                if not node.startswith(nxt + "."):
                    cycle.extend([*stack, node, nxt])
                    return True
            if state.get(nxt) is None and visit(nxt, [*stack, node]):
                return True
        state[node] = 2
        return False

    for m in MODULES:
        if m not in state and visit(m, []):
            break
    assert not cycle, " -> ".join(cycle)


def test_modules_stay_small() -> None:
    big = []
    for module in MODULES:
        limit = next(
            (n for k, n in MAX_LINES.items() if module == k or module.startswith(k + ".")), None
        )
        if limit is None:
            continue
        path = ROOT / Path(*module.split("."))
        path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
        lines = len(path.read_text().splitlines())
        if lines > limit:
            big.append(f"{module}: {lines} lines > {limit}")
    assert not big, "\n".join(big)


def test_train_is_split_by_job() -> None:
    top = {p.name for p in (ROOT / "train").iterdir() if p.suffix == ".py"}
    assert top == {"__init__.py", "cli.py", "evaluate.py", "train.py"}
    for job in ("evaluation", "rl", "studies", "common", "plots"):
        assert (ROOT / "train" / job / "__init__.py").exists(), job


def test_paired_comparisons_is_importable_from_the_train_package() -> None:
    from train.common.statistics import paired_comparisons

    assert callable(paired_comparisons)
