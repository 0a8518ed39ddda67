"""Figures of an evaluation sweep (matplotlib, headless Agg backend, PNG).

* ``robustness_<metric>.png`` — the metric's mean vs disturbance level, one panel per
  disturbance preset, one line per controller, shaded 95% bootstrap interval; level 0 is
  the undisturbed run;
* ``failures.png`` — failure rate per controller and disturbance (all levels pooled);
* ``example_<controller>.png`` — one episode: joints 1–2 against the reference, the path
  distance, and the energy terms (the passivity controller's storage function and its
  parts; H(q, q̇) for every controller);
* ``aggregate.png`` — the aggregate scores' intervals and performance profiles.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from train.common.statistics import interval_estimates, performance_profile
from train.plots import pyplot

plt = pyplot()


def robustness_plot(summary: pd.DataFrame, metric: str, path: Path) -> None:
    """Mean metric vs level per preset with CI bands (see the module docstring)."""
    presets = [d for d in summary["disturbance"].unique() if d != "none"]
    fig, axes = plt.subplots(
        1,
        max(len(presets), 1),
        figsize=(4.2 * max(len(presets), 1), 3.6),
        squeeze=False,
        sharey=True,
    )
    base = summary[summary["disturbance"] == "none"]
    for ax, preset in zip(axes[0], presets, strict=False):
        sub = summary[summary["disturbance"] == preset]
        for ctrl, g in sub.groupby("controller"):
            b = base[base["controller"] == ctrl]
            g = pd.concat([b.assign(level=0.0), g]).sort_values("level")
            line = ax.plot(g["level"], g[f"{metric}_mean"], marker="o", label=ctrl)[0]
            ax.fill_between(
                g["level"], g["mean_ci_low"], g["mean_ci_high"], color=line.get_color(), alpha=0.2
            )
        ax.set_title(preset)
        ax.set_xlabel("disturbance level")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel(f"{metric} (mean, 95% CI)")
    axes[0][-1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def failure_plot(df: pd.DataFrame, path: Path) -> None:
    """Failure rate per controller and disturbance, all levels pooled."""
    rates = df.groupby(["disturbance", "controller"])["failed"].mean().unstack("controller")
    fig, ax = plt.subplots(figsize=(7, 3.6))
    rates.plot.bar(ax=ax, rot=0)
    ax.set_ylabel("failure rate")
    ax.set_ylim(0, 1)
    ax.set_title("failed episodes (unstable or path distance above the bound)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def example_plot(trace: dict[str, np.ndarray], title: str, path: Path) -> None:
    """One episode's joints, path distance and energy terms."""
    t = trace["t_s"]
    fig, axes = plt.subplots(3, 1, figsize=(7, 7.5), sharex=True)
    for j in range(min(2, trace["q"].shape[1])):
        line = axes[0].plot(t, trace["q"][:, j], label=f"q{j + 1}")[0]
        axes[0].plot(t, trace["q_ref"][:, j], "--", color=line.get_color(), label=f"q_r{j + 1}(t)")
    axes[0].set_ylabel("rad")
    axes[0].legend(fontsize=7, ncol=2)
    axes[1].semilogy(t, np.maximum(trace["path_distance"], 1e-12))
    axes[1].set_ylabel("path distance (rad)")
    # The passivity controller's storage function and its terms (left axis; NaN for the
    # other controllers) and the arm's energy H(q, q̇) (right axis: ~100× larger).
    names = ["H + W_r(σ)", "H_r", "φ", "ψ", "E (storage)"]
    for k, name in enumerate(names):
        series = trace["energy"][:, k]
        if np.all(np.isfinite(series)):
            axes[2].plot(t, series, label=name)
    axes[2].set_ylabel("storage terms (J)")
    twin = axes[2].twinx()
    twin.plot(t, trace["energy"][:, 5], color="0.5", ls=":", label="H(q, q̇)")
    twin.set_ylabel("H(q, q̇) (J)")
    twin.legend(fontsize=7, loc="lower right")
    axes[2].set_xlabel("t (s)")
    if axes[2].get_lines():
        axes[2].legend(fontsize=7, ncol=3)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def example_plot_file(trace_path: Path, title: str, path: Path) -> None:
    """:func:`example_plot` of a trace saved by the sweep (``trace_<controller>.npz``): what
    a worker process draws, given file names instead of arrays."""
    with np.load(trace_path) as z:
        trace = {k: z[k] for k in z.files}
    example_plot(trace, title, path)


def aggregate_plot(
    scores: dict[str, np.ndarray],
    point: dict[str, np.ndarray],
    interval: dict[str, np.ndarray],
    path: Path,
    resamples: int,
    seed: int,
) -> None:
    names = sorted(point, key=lambda c: point[c][0])
    color = {c: f"C{i}" for i, c in enumerate(sorted(point))}  # the same in both panels
    lo = min(float(np.min(s)) for s in scores.values())
    hi = max(float(np.max(s)) for s in scores.values())
    taus = np.linspace(lo, hi, 101)

    # rliable's performance profile (the fraction of runs with score > τ, pooled over
    # tasks) with its stratified-bootstrap bands, seeded (see _interval_estimates).
    profiles, profile_ci = interval_estimates(
        scores, lambda batch: performance_profile(batch, taus), resamples, seed
    )
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 3.8))
    for i, c in enumerate(names):
        ci = interval[c]
        ax1.errorbar(
            point[c][0],
            i,
            xerr=[[point[c][0] - ci[0][0]], [ci[1][0] - point[c][0]]],
            fmt="o",
            capsize=4,
            color=color[c],
        )
        ax2.plot(taus, profiles[c], label=c, color=color[c])
        ax2.fill_between(taus, profile_ci[c][0], profile_ci[c][1], color=color[c], alpha=0.2)
    ax1.set_yticks(range(len(names)), names)
    ax1.set_xlabel("IQM of the normalised score (95% CI)")
    ax1.grid(True, alpha=0.3)
    ax2.set_xlabel("τ: score (decades better than the condition median)")
    ax2.set_ylabel("fraction of episodes with score > τ")
    ax2.grid(True, alpha=0.3)
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
