"""The summary of a worst-case search (``summary.csv``, ``summary.md``): per controller ×
family × energy the worst cost found, the random draws' median and worst, the seeds' worst
cases and their spread, the unstable episodes, the work done, and the parameters of the
worst episodes that sit on a bound of the searched box."""

from __future__ import annotations

from typing import Any

import numpy as np

from train.studies.worst_case import is_wrapping

__all__ = ["BOUND_MARGIN", "WORST_CHECKED", "on_bound", "summary_frame", "summary_table"]

#: The worst episodes whose non-wrapping parameters are checked against the box's bounds.
WORST_CHECKED = 10
#: A parameter within this fraction of its range (log range if log-scaled) of a bound is
#: "on the bound".
BOUND_MARGIN = 0.02


def on_bound(trials: list[Any]) -> list[str]:
    """The non-wrapping parameters (sorted) of ``trials`` within :data:`BOUND_MARGIN` of a
    bound of their distribution."""
    hits = set()
    for t in trials:
        for name, value in t.params.items():
            dist = t.distributions[name]
            if is_wrapping(name) or not hasattr(dist, "low"):
                continue
            lo, hi, v = float(dist.low), float(dist.high), float(value)
            if getattr(dist, "log", False):
                lo, hi, v = np.log(lo), np.log(hi), np.log(v)
            width = hi - lo
            if width > 0 and min(v - lo, hi - v) <= BOUND_MARGIN * width:
                hits.add(name)
    return sorted(hits)


def summary_frame(df: Any, bounds: dict[tuple[str, str, float], list[str]] | None = None) -> Any:
    """Per controller × family × energy (a DataFrame, ``summary.csv``): the worst cost
    found (either kind, any seed: the one ``worst.yml`` replays), the worst searched, the
    median and worst random cost (rad), worst searched / median random, the seeds' worst
    cases and their spread (max − min)/median, whether every seed's search reached its
    random worst, the unstable episodes of each kind, the work the disturbance did (J) and
    the non-wrapping parameters of the ten worst episodes on a bound."""
    import pandas as pd

    rows = []
    for (controller, family, energy), g in df.groupby(["controller", "family", "energy_j"]):
        s, r = g[g["kind"] == "search"], g[g["kind"] == "random"]
        worst, med = float(s["cost_rad"].max()), float(r["cost_rad"].median())
        per_seed = g.groupby("seed")["cost_rad"].max()
        search_reached = all(
            gs.loc[gs["kind"] == "search", "cost_rad"].max()
            >= gs.loc[gs["kind"] == "random", "cost_rad"].max()
            for _, gs in g.groupby("seed")
        )
        rows.append(
            {"controller": controller, "family": family, "energy_j": float(energy),
             "worst_rad": float(g["cost_rad"].max()), "worst_search_rad": worst,
             "median_random_rad": med,
             "worst_random_rad": float(r["cost_rad"].max()), "worst_over_median": worst / med,
             "seeds": len(per_seed),
             "seed_worst_rad": " ".join(f"{v:.4g}" for v in per_seed.to_numpy()),
             "spread": float((per_seed.max() - per_seed.min()) / per_seed.median()),
             "search_reached_random": search_reached,
             "unstable_search": int(s["unstable"].sum()), "n_search": len(s),
             "unstable_random": int(r["unstable"].sum()), "n_random": len(r),
             "work_min_j": float(g["work_j"].min()), "work_max_j": float(g["work_j"].max()),
             "on_bound": " ".join((bounds or {}).get((controller, family, float(energy)), []))}
        )  # fmt: skip
    return pd.DataFrame(rows)


def summary_table(summary: Any) -> str:
    """Markdown of :func:`summary_frame`'s rows."""
    lines = [
        "| controller | family | energy (J) | worst found (rad) | worst searched (rad) "
        "| median random (rad) | worst random (rad) | seeds' worst (rad) | spread "
        "| unstable (search / random) | delivered work (J), min–max | on a bound |",
        "|---|---|---:|---:|---:|---:|---:|---|---:|---:|---:|---|",
    ]
    for _, r in summary.iterrows():
        lines.append(
            f"| {r['controller']} | {r['family']} | {r['energy_j']:g} | {r['worst_rad']:.3g} "
            f"| {r['worst_search_rad']:.3g} | {r['median_random_rad']:.3g} "
            f"| {r['worst_random_rad']:.3g} | {r['seed_worst_rad']} | {r['spread']:.0%} "
            f"| {r['unstable_search']}/{r['n_search']} / {r['unstable_random']}/{r['n_random']} "
            f"| {r['work_min_j']:.2f}–{r['work_max_j']:.2f} | {r['on_bound'] or 'none'} |"
        )
    return "\n".join(lines)
