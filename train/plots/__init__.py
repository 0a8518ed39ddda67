"""Figures of the evaluation sweeps and studies: matplotlib on its headless Agg backend,
PNG files; each figure a function of results alone (a sweep's worker processes draw them).

* :mod:`train.plots.evaluation` — a sweep's robustness, failure, example and aggregate
  figures;
* :mod:`train.plots.studies` — fronts, adversarial search, control rates, the verdict;
* :mod:`train.plots.rl` — learning curves.
"""

from __future__ import annotations

from typing import Any


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
