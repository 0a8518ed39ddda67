"""Figures of the studies: error–effort fronts, the adversarial search, control rates, the
verdict across robots."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from train.common.statistics import pareto_front
from train.plots import pyplot


def fronts_plot(rows: list[dict[str, Any]], path: Path, reference: str) -> None:
    plt = pyplot()

    panels = sorted({r["panel"] for r in rows}, key=lambda p: (p == "all", p))
    controllers = sorted({r["controller"] for r in rows})
    fig, axes = plt.subplots(1, len(panels), figsize=(3.8 * len(panels), 3.6), squeeze=False)
    for ax, panel in zip(axes[0], panels, strict=True):
        for i, c in enumerate(controllers):
            pts = sorted((r for r in rows if r["panel"] == panel and r["controller"] == c),
                         key=lambda r: r["scale"])  # fmt: skip
            eff = np.array([p["effort"] for p in pts])
            err = np.array([p["error_rad"] for p in pts])
            color = f"C{i}"
            lo = np.array([[p["effort_ci_low"], p["error_ci_low"]] for p in pts])
            hi = np.array([[p["effort_ci_high"], p["error_ci_high"]] for p in pts])
            ax.errorbar(
                eff, err, xerr=[eff - lo[:, 0], hi[:, 0] - eff],
                yerr=[err - lo[:, 1], hi[:, 1] - err], fmt="o", ms=3, color=color, alpha=0.5,
                lw=0.8,
            )  # fmt: skip
            front = pareto_front(eff, err)
            ax.plot(eff[front], err[front], color=color, label=c)
            unit = [p for p in pts if p["scale"] == 1.0]
            if unit:
                ax.plot(unit[0]["effort"], unit[0]["error_rad"], "s", color=color, ms=6)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(panel)
        ax.set_xlabel("dynamic effort RMS((τ−g)/τ_max)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("path-distance RMS (rad), mean, 95% CI")
    axes[0][-1].legend(fontsize=7)
    fig.suptitle("Error vs effort, one gain scale per controller (square: scale 1)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def adversary_plot(df: Any, path: Path) -> None:
    """The worst cost so far against the episodes run, per family × energy: one line per
    controller and search seed (the random draws first, then the CMA-ES runs: the grey
    line marks where the search starts, the dashed one where the local runs do)."""
    plt = pyplot()

    groups = list(df.groupby(["family", "energy_j"]))
    fig, axes = plt.subplots(1, len(groups), figsize=(6 * len(groups), 4), squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, ((family, energy), g) in zip(axes[0], groups, strict=True):
        for i, (controller, gc) in enumerate(g.groupby("controller")):
            seeds = gc["seed"].unique() if "seed" in gc else [None]
            for k, seed in enumerate(seeds):
                run = gc if seed is None else gc[gc["seed"] == seed]
                order = "evaluation" if "evaluation" in run else "trial"
                run = run.sort_values(["kind", order], kind="stable")  # "random" < "search"
                ax.plot(
                    np.maximum.accumulate(run["cost_rad"].to_numpy()),
                    color=colours[i % len(colours)], lw=1.2,
                    label=controller if k == 0 else None,
                )  # fmt: skip
            ax.axvline((gc["kind"] == "random").sum() / max(len(seeds), 1), color="0.6", lw=0.8)
            if "run" in gc and (gc["run"] == "polish").any():  # where the local runs start
                local = gc["run"].str.startswith("polish")
                ax.axvline((~local).sum() / max(len(seeds), 1), color="0.6",
                           lw=0.8, ls="--")  # fmt: skip
        ax.set_yscale("log")
        ax.set_xlabel("episodes run (random draws, then the search)")
        ax.set_ylabel("worst cost so far (rad)")
        ax.set_title(f"{family}, {energy:g} J (one line per search seed)")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def rates_figure(cfg: Any, table: pd.DataFrame, path: Path) -> None:
    """Median ``cfg.metric`` against the control rate, one panel per robot × disturbance
    (``cfg``: a :class:`~train.studies.rates.RatesConfig`)."""
    plt = pyplot()

    panels = [(r, d) for r in cfg.robots for d in cfg.disturbances]
    cols = len(cfg.disturbances)
    fig, axes = plt.subplots(len(cfg.robots), cols, figsize=(4.2 * cols, 2.8 * len(cfg.robots)),
                             squeeze=False, sharex=True)  # fmt: skip
    for ax, (robot, dist) in zip(axes.ravel(), panels, strict=True):
        sub = table[(table["robot"] == robot) & (table["disturbance"] == dist)]
        for ctrl in cfg.controllers:
            c = sub[sub["controller"] == ctrl].sort_values("control_hz")
            ax.plot(c["control_hz"], c["median"], marker="o", ms=3, label=ctrl)
            bad = c[~c["holds"]]
            ax.plot(bad["control_hz"], bad["median"], "x", color="k", ms=6)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.invert_xaxis()
        ax.set_title(f"{robot}, {dist}", fontsize=9)
        ax.set_ylabel(f"median {cfg.metric} (rad)", fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("control rate (Hz)")
    axes[0, -1].legend(fontsize=7)
    fig.suptitle("× : does not hold at that rate (a failure, a refusal or too much accuracy lost)",
                 fontsize=9)  # fmt: skip
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


#: How :func:`verdict_plot` marks an outcome of the focus against its rival.
_OUTCOME_STYLE = {"wins": ("tab:green", "wins"), "ties": ("0.55", "ties"),
                  "loses": ("tab:red", "loses")}  # fmt: skip


def verdict_plot(
    rivals: pd.DataFrame,
    robots: list[str],
    path: Path,
    name_of: Callable[[str, float], str],
    conditions: Sequence[tuple[str, float]],
) -> None:
    """The verdict across robots: one panel per robot, the focus's mean over its strongest
    rival's (log scale, < 1: the focus is lower) in every condition (``conditions``, in
    their order along the axis, each named by ``name_of(disturbance, level)``), path
    distance (circles) and time-indexed error (squares), coloured by the paired test's outcome
    (:func:`train.studies.verdict_study.rivals`' table)."""
    plt = pyplot()
    x_of = {c: i for i, c in enumerate(conditions)}
    fig, axes = plt.subplots(1, len(robots), figsize=(3.2 * len(robots) + 1, 4.2),
                             squeeze=False, sharey=True)  # fmt: skip
    shown: set[str] = set()
    for ax, robot in zip(axes[0], robots, strict=True):
        sub = rivals[rivals["robot"] == robot]
        for metric, marker, shift in (("path_dist_rms", "o", -0.15), ("time_err_rms", "s", 0.15)):
            m = sub[sub["metric"] == metric]
            for outcome, (colour, label) in _OUTCOME_STYLE.items():
                o = m[m["outcome"] == outcome]
                x = [x_of[(d, lv)] + shift for d, lv in zip(o["disturbance"], o["level"],
                                                              strict=True)]  # fmt: skip
                key = f"{label}, {'path distance' if marker == 'o' else 'time-indexed error'}"
                ax.scatter(x, o["ratio"], marker=marker, color=colour, s=22,
                           label=key if key not in shown else None)  # fmt: skip
                shown.add(key)
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_yscale("log")
        ax.set_xticks(range(len(conditions)))
        ax.set_xticklabels([name_of(d, lv) for d, lv in conditions], rotation=90, fontsize=7)
        ax.set_title(robot, fontsize=9)
        ax.grid(True, axis="y", which="both", alpha=0.3)
    axes[0][0].set_ylabel("passivity / strongest rival (mean; < 1: passivity lower)", fontsize=8)
    handles, labels = axes[0][0].get_legend_handles_labels()
    columns = 3 if len(robots) > 1 else 2  # one panel is too narrow for three columns
    fig.legend(handles, labels, fontsize=7, loc="upper center", ncol=columns)
    fig.tight_layout(rect=(0, 0, 1, 0.86 if columns == 3 else 0.80))
    fig.savefig(path, dpi=110, bbox_inches="tight")  # nothing of the legend cut off
    plt.close(fig)
