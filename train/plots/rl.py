"""Learning curves of an RL study (:mod:`train.rl.study`)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from train.plots import pyplot


def plot_curves(
    curves: pd.DataFrame,
    returns: pd.DataFrame,
    baselines: pd.DataFrame,
    path: Path,
) -> None:
    """The learning-curve figure (see the module docstring)."""
    plt = pyplot()

    dists = sorted(curves["disturbance"].unique(), key=lambda d: d != "none")
    fig, axes = plt.subplots(1, len(dists) + 1, figsize=(5.2 * (len(dists) + 1), 4.2))
    colors = {g: f"C{i}" for i, g in enumerate(sorted(curves["group"].unique()))}
    for ax, dist in zip(axes, dists, strict=False):
        sub = curves[curves["disturbance"] == dist]
        for group, gg in sub.groupby("group"):
            for _, gs in gg.groupby("seed"):
                ax.plot(gs["steps"], gs["path_dist_rms"], color=colors[group], lw=0.8, alpha=0.4)
            med = gg.groupby("steps")["path_dist_rms"].median()
            ax.plot(med.index, med.values, color=colors[group], lw=2.2, marker="o",
                    label=f"{group} (median of {gg['seed'].nunique()} seeds)")  # fmt: skip
        for i, (ctrl, value) in enumerate(baselines[dist].items()):
            ax.axhline(value, color="k", ls=["--", ":", "-."][i % 3], lw=1.2, label=f"{ctrl} alone")
        ax.set_yscale("log")
        ax.set_xlabel("training steps")
        ax.set_ylabel("path distance RMS (rad), mean over test episodes")
        ax.set_title(f"test episodes, disturbance: {dist}")
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7)
    ax = axes[-1]
    for group, gg in returns.groupby("group"):
        for _, gs in gg.groupby("seed"):
            ax.plot(gs["steps"], gs["reward_per_step"], color=colors.get(group, "k"), lw=0.8,
                    alpha=0.6, label=None)  # fmt: skip
        ax.plot([], [], color=colors.get(group, "k"), lw=2.2, label=group)
    ax.set_xlabel("training steps")
    ax.set_ylabel("training reward per step (10-episode mean)")
    ax.set_title("training episodes (Monitor; each group its own reward)")
    if returns.empty:
        ax.text(0.5, 0.5, "no Monitor logs", ha="center", transform=ax.transAxes)
    ax.grid(alpha=0.3, which="both")
    if not returns.empty:
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
