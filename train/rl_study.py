"""Learning curves and final figures of a multi-seed RL study, from its checkpoints.

A *study* is a folder of ``python -m train.train`` runs (``python -m train.rl_campaign``
trains one) that share env, algorithm, training disturbance, control rate, episode length
and start mode, and differ in seed and in their *group* — the campaign's group name when
the folder is named ``<group>_s<seed>``, else pure RL or a residual on a base controller
(``residual-<base>``, ``-gated`` with a path-error gate) —, each group with its own reward
and safeguards (the same within a group). This script evaluates **every checkpoint of
every run** and the base controllers alone (every group's base, computed torque and
PD + gravity) through one ``train.evaluate`` sweep (``sb3:<run>@<steps>`` entries), so
every policy meets the same start states and the same disturbance schedules, under the
training disturbance and undisturbed; then the **final checkpoints** under every preset
of ``--presets`` at level 1 in a second sweep (``final/``). It then writes:

* ``learning_curves.png`` — path-distance RMS (rad, log scale) against training steps:
  one thin line per run, the median over seeds thick, per group; the base controller
  and computed torque as horizontal lines; one panel per disturbance; and the runs' own
  training episodes (reward per step, from their ``Monitor`` logs) in a last panel;
* ``final.md`` (also printed) — per preset and group, at the largest step count every run
  has a checkpoint of (one budget for all), the path-distance RMS per seed and pooled, and
  the paired difference to the group's base alone (pure RL: to PD + gravity) with a
  bootstrap 95 % CI over the pooled (run, episode) pairs; the samples each run needed to
  reach its base's path distance under the training disturbance; and rliable's aggregate
  (IQM, stratified bootstrap over training seeds) over the presets;
* the sweep's own ``episodes.csv``, ``summary.csv`` and figures.

Usage::

    python -m train.rl_study --runs runs/study --out results/rl_study --episodes 10

``--resume`` continues an interrupted evaluation (the sweeps' ``episodes.csv``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from agents.residual import NETWORK_BASE
from ptrack_gym.errors import InvalidConfigError
from train.evaluate import EvalConfig
from train.report import aggregate
from train.results import bootstrap_ci, load_frame
from train.sweep import run_sweep

#: Checkpoint file names of ``train.train`` (SB3's CheckpointCallback).
_CKPT = re.compile(r"rl_model_(\d+)_steps\.zip$")

#: Run folders of ``train.rl_campaign``: ``<group>_s<seed>``.
_CAMPAIGN_RUN = re.compile(r"^(.+)_s(\d+)$")

#: The run-config keys every run of a study must share (``decision_every`` too: the steps of
#: its checkpoints and Monitor logs are decisions, so one step axis needs one period).
SHARED_KEYS = ("algo", "env_id", "disturbance", "episode_s", "start", "decision_every")
#: Their values for a run written before a key existed (it ran with the default).
SHARED_KEY_DEFAULTS: dict[str, object] = {"decision_every": 1}

#: The keys the runs of one group must share too (groups may differ in them: each has its
#: own reward, hyperparameters and safeguards).
GROUP_KEYS = (
    "reward_weights", "reward", "kernel_weights", "max_path_distance", "hyperparams",
    "overrides", "scale_fraction", "scale_accel_rad_s2", "zero_init_residual", "action_penalty",
    "gate_rad", "gate_deadband_rad", "init_log_std", "critic_warmup_steps", "actor_lr_scale",
    "actor_bc_weight", "prior_gain_per_rad", "base_model",
)  # fmt: skip

#: ``train.train.TrainConfig``'s defaults of :data:`GROUP_KEYS` (a test keeps them equal;
#: not imported, which would import torch): a run written before a key existed lacks it in
#: its config.yml and ran with the default, so it groups with runs that write the default.
GROUP_KEY_DEFAULTS: dict[str, object] = {
    "reward_weights": None, "reward": "quadratic", "kernel_weights": None,
    "max_path_distance": None, "hyperparams": None, "overrides": {}, "scale_fraction": 0.1,
    "scale_accel_rad_s2": None, "zero_init_residual": False, "action_penalty": 0.0,
    "gate_rad": None, "gate_deadband_rad": 0.0, "init_log_std": None, "critic_warmup_steps": 0,
    "actor_lr_scale": 1.0, "actor_bc_weight": 0.0, "prior_gain_per_rad": 0.0,
    "base_model": None,
}  # fmt: skip

#: The presets the final checkpoints are evaluated under (level 1), by default.
FINAL_PRESETS = ("none", "impulse", "periodic", "payload", "noise")
#: What pure RL is compared with (the issue's target: within 2x of PD + gravity).
PURE_REFERENCE = "pd_gravity"


@dataclass(frozen=True)
class Run:
    """One training run of the study."""

    path: Path
    group: str  # "pure" or "residual-<base>"
    base: str  # the residual base controller ("none" for pure RL)
    seed: int
    control_hz: float
    checkpoints: tuple[int, ...]  # step counts with a checkpoint, ascending
    config: dict[str, object]


def is_checkpoint_entry(controller: str) -> bool:
    """Whether a sweep entry is a run's checkpoint (``sb3:<run>@<steps>``), not a
    reference alone (a controller, or a network base's model ``sb3:<folder>``)."""
    return controller.startswith("sb3:") and "@" in controller


def thin(runs: Sequence[Run], every: int) -> list[Run]:
    """The runs with only the checkpoints at multiples of ``every`` steps (and each run's
    last one) kept: fewer points on the learning curves, the same final budget."""
    if every <= 0:
        raise InvalidConfigError(f"--every must be > 0, got {every}")
    return [
        dataclasses.replace(
            r,
            checkpoints=tuple(s for s in r.checkpoints if s % every == 0 or s == r.checkpoints[-1]),
        )
        for r in runs
    ]


def discover(root: Path) -> list[Run]:
    """The runs under ``root`` (folders with a ``config.yml`` and a ``model.zip``);
    raises :class:`InvalidConfigError` if there are none or they do not share
    :data:`SHARED_KEYS` and the control rate."""
    runs = []
    for cfg_file in sorted(root.glob("*/config.yml")):
        run_dir = cfg_file.parent
        if not (run_dir / "model.zip").exists():
            continue
        cfg = yaml.safe_load(cfg_file.read_text())
        c = cfg["config"]
        steps = sorted(
            int(m.group(1))
            for f in (run_dir / "checkpoints").glob("rl_model_*_steps.zip")
            if (m := _CKPT.search(f.name))
        )
        base = str(c["residual"])
        named = _CAMPAIGN_RUN.match(run_dir.name)
        if named and int(named.group(2)) == int(c["seed"]):
            group = named.group(1)  # train.rl_campaign's <group>_s<seed>: its group name
        else:
            group = "pure" if base == "none" else f"residual-{base}"
            if base != "none" and c.get("gate_rad") is not None:
                group += "-gated"
            from train.sb3_runs import deploy_safeguards  # SB3 and torch only here

            if deploy_safeguards(run_dir):  # a gate put on at evaluation only
                group += "-deploy-gated"
        runs.append(
            Run(
                path=run_dir,
                group=group,
                base=base,
                seed=int(c["seed"]),
                control_hz=float(cfg["derived"]["control_hz"]),
                checkpoints=tuple(steps),
                config=c,
            )
        )
    if not runs:
        raise InvalidConfigError(f"no finished runs (config.yml + model.zip) under {root}")
    first = runs[0]
    group_first = {}
    for r in runs:
        group_first.setdefault(r.group, r)
    for r in runs[1:]:
        pairs = [(key, first) for key in SHARED_KEYS]
        pairs += [(key, group_first[r.group]) for key in GROUP_KEYS]
        for key, other in pairs:
            default = GROUP_KEY_DEFAULTS.get(key, SHARED_KEY_DEFAULTS.get(key))
            mine = r.config.get(key, default)
            theirs = other.config.get(key, default)
            if mine != theirs:
                raise InvalidConfigError(
                    f"{r.path} has {key}={mine!r}, {other.path} has {theirs!r}"
                )
        if r.control_hz != first.control_hz:
            raise InvalidConfigError(f"{r.path} runs at {r.control_hz} Hz, {first.path} at "
                                     f"{first.control_hz} Hz")  # fmt: skip
    study_gains(runs)  # one gains setting for the controllers alone and every residual's base
    return runs


def study_gains(runs: Sequence[Run]) -> str:
    """The model-based controllers' gains of a study: the ``base_gains`` every residual run
    shares ("default" for runs written before the key existed, and for a study of pure runs
    only) and the ``imitate_gains`` of every pure run that started as a copy of a controller
    (``train.imitation``) — the controllers alone are evaluated with them, so each residual
    is compared with the very base it corrects and each imitating policy with its expert.

    Raises:
        InvalidConfigError: runs with different gains.
    """
    gains = {
        str(r.config.get("base_gains", "default"))
        for r in runs
        if r.base not in ("none", NETWORK_BASE)
    }
    gains |= {
        str(r.config.get("imitate_gains", "default"))
        for r in runs
        if r.base == "none" and r.config.get("imitate")
    }
    for r in runs:  # a network base that imitated a controller: that controller's gains
        if r.base == NETWORK_BASE:
            base = yaml.safe_load((Path(str(r.config["base_model"])) / "config.yml").read_text())
            if base["config"].get("imitate"):
                gains.add(str(base["config"].get("imitate_gains", "default")))
    if len(gains) > 1:
        raise InvalidConfigError(f"the runs' base or expert gains differ: {sorted(gains)}")
    return gains.pop() if gains else "default"


def reference_of(run: Run) -> str:
    """The controller a run is compared with: its base (a network base: its model,
    ``sb3:<base_model>``); for pure RL the controller it imitated (``imitate``), else
    PD + gravity."""
    if run.base == NETWORK_BASE:
        return f"sb3:{run.config['base_model']}"
    if run.base != "none":
        return run.base
    return str(run.config.get("imitate") or PURE_REFERENCE)


def sweep_config(
    runs: Sequence[Run],
    episodes: int,
    out: Path,
    workers: int,
    presets: Sequence[str] | None = None,
) -> EvalConfig:
    """An evaluation sweep: the base controllers alone + the runs' checkpoints,
    ``episodes`` paired episodes each. ``presets=None``: every checkpoint, under the
    training disturbance and undisturbed (the learning curves); else the final checkpoints
    (:func:`final_steps`) under ``presets`` at level 1."""
    first = runs[0].config
    preset, _, level = str(first["disturbance"]).partition(":")
    if preset in ("", "none"):
        raise InvalidConfigError("the study's runs were trained without a disturbance")
    bases = sorted({reference_of(r) for r in runs if r.base != "none" or r.config.get("imitate")})
    baselines = list(dict.fromkeys([*bases, "computed_torque", PURE_REFERENCE]))
    if presets is None:
        entries = [f"sb3:{r.path}@{s}" for r in runs for s in r.checkpoints]
        disturbances, levels = ["none", preset], [float(level) if level else 1.0]
    else:
        steps = final_steps(runs)
        entries = [f"sb3:{r.path}@{steps}" for r in runs]
        disturbances, levels = list(presets), [1.0]
    return EvalConfig(
        env_id=str(first["env_id"]),
        controllers=baselines + entries,
        disturbances=disturbances,
        levels=levels,
        seeds=episodes,
        episode_s=float(first["episode_s"]),  # type: ignore[arg-type]
        control_hz=runs[0].control_hz,
        start=str(first["start"]),
        reference=baselines[0],
        gains=study_gains(runs),
        workers=workers,
        out=str(out),
        plots=False,
    )


def curve_frame(df: pd.DataFrame, runs: Sequence[Run]) -> pd.DataFrame:
    """Mean path-distance RMS per (run, checkpoint, disturbance): columns group, seed,
    steps, disturbance, path_dist_rms, failure_rate."""
    rows = []
    for r in runs:
        for s in r.checkpoints:
            g = df[df["controller"] == f"sb3:{r.path}@{s}"]
            for dist, gd in g.groupby("disturbance"):
                rows.append(
                    {
                        "group": r.group,
                        "seed": r.seed,
                        "steps": s,
                        "disturbance": dist,
                        "path_dist_rms": float(gd["path_dist_rms"].mean()),
                        "failure_rate": float(gd["failed"].mean()),
                    }
                )
    return pd.DataFrame(rows)


def training_curves(runs: Sequence[Run], window: int = 10) -> pd.DataFrame:
    """The runs' own training episodes (their ``Monitor`` CSVs): columns group, seed,
    steps (the run's steps — decisions, with ``decision_every`` — at the episode's end),
    reward_per_step (the episode's return over its
    length, averaged over ``window`` episodes) — a curve every run has, whatever its
    reward scale or episode ends."""
    rows = []
    for r in runs:
        files = sorted(
            r.path.glob("monitor/from_*/*.monitor.csv"),
            key=lambda f: int(f.parent.name.removeprefix("from_")),
        )
        if not files:
            continue
        ep = pd.concat([pd.read_csv(f, skiprows=1) for f in files], ignore_index=True)
        rate = (ep["r"] / ep["l"]).rolling(window, min_periods=1).mean()
        for steps, value in zip(ep["l"].cumsum(), rate, strict=True):
            rows.append({"group": r.group, "seed": r.seed, "steps": int(steps),
                         "reward_per_step": float(value)})  # fmt: skip
    return pd.DataFrame(rows, columns=["group", "seed", "steps", "reward_per_step"])


def plot_curves(
    curves: pd.DataFrame,
    returns: pd.DataFrame,
    baselines: pd.DataFrame,
    path: Path,
) -> None:
    """The learning-curve figure (see the module docstring)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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


def final_steps(runs: Sequence[Run]) -> int:
    """The largest step count every run has a checkpoint of (the common budget)."""
    common = set.intersection(*(set(r.checkpoints) for r in runs))
    if not common:
        raise InvalidConfigError("the runs share no checkpoint step count")
    return max(common)


def final_table(df: pd.DataFrame, runs: Sequence[Run], resamples: int) -> str:
    """Markdown table of the final checkpoints against the controllers alone, per
    disturbance (rows of ``df``'s disturbances, in order). Every run is taken at the same
    budget (:func:`final_steps`); Δ is the paired difference to the group's reference
    (:func:`reference_of`) with a bootstrap 95 % CI over the pooled (run, episode) pairs
    (it does not carry the seed-to-seed variance: read it next to the per-seed column),
    and ×ref the ratio of the pooled means."""
    steps = final_steps(runs)
    algo = str(runs[0].config["algo"]).upper()
    lines = [
        "| disturbance | policy | path-dist RMS per seed (rad) | pooled mean (rad) | "
        "Δ vs reference alone, 95% CI | ×ref | time-indexed RMSE (rad) | failures |",
        "| --- | --- | --- | ---: | --- | ---: | ---: | ---: |",
    ]
    key = ["disturbance", "level", "seed", "episode"]
    for dist, gd in df.groupby("disturbance", sort=False):
        alone = {
            c: g.set_index(key)
            for c, g in gd.groupby("controller")
            if not is_checkpoint_entry(str(c))
        }
        for ctrl, g in alone.items():
            lines.append(
                f"| {dist} | {ctrl} alone | — | {g['path_dist_rms'].mean():.3e} | — | — | "
                f"{g['time_err_rms'].mean():.2e} | {int(g['failed'].sum())} |"
            )
        for group in sorted({r.group for r in runs}):
            members = sorted((r for r in runs if r.group == group), key=lambda r: r.seed)
            ref_name = reference_of(members[0])
            ref = alone[ref_name]["path_dist_rms"]
            per_seed, diffs, time_err, fails, mine = [], [], [], 0, []
            for r in members:
                g = gd[gd["controller"] == f"sb3:{r.path}@{steps}"].set_index(key)
                per_seed.append(float(g["path_dist_rms"].mean()))
                common = g.index.intersection(ref.index)
                diffs.extend((g.loc[common, "path_dist_rms"] - ref.loc[common]).tolist())
                mine.extend(g["path_dist_rms"].tolist())
                fails += int(g["failed"].sum())
                time_err.extend(g["time_err_rms"].tolist())
            d = np.asarray(diffs)
            lo, hi = bootstrap_ci(d, np.mean, resamples, 0)
            lines.append(
                f"| {dist} | {group} {algo} @ {steps} steps (vs {ref_name}) | "
                + ", ".join(f"{v:.2e}" for v in per_seed)
                + f" | {np.mean(mine):.3e} | {np.mean(d):+.2e} [{lo:+.2e}, {hi:+.2e}]"
                + f" | {np.mean(mine) / ref.mean():.2f} | {np.mean(time_err):.2e} | "
                + f"{fails}/{len(mine)} |"
            )
    return "\n".join(lines)


def samples_to_reach(curves: pd.DataFrame, baselines: dict, runs: Sequence[Run], dist: str) -> str:
    """Markdown table: per group, the training steps each run needed until a checkpoint's
    mean path distance under ``dist`` was at most its reference's alone (None: not within
    its checkpoints); the median over the runs that reached it."""
    lines = [
        f"| group | reference | steps to reach the reference's path distance ({dist}), "
        "per seed | reached | median (reached) |",
        "| --- | --- | --- | ---: | ---: |",
    ]
    for group in sorted({r.group for r in runs}):
        members = sorted((r for r in runs if r.group == group), key=lambda r: r.seed)
        ref_name = reference_of(members[0])
        target = float(baselines[dist][ref_name])
        reached = []
        for r in members:
            c = curves[(curves["group"] == group) & (curves["seed"] == r.seed)]
            c = c[(c["disturbance"] == dist) & (c["path_dist_rms"] <= target)]
            reached.append(int(c["steps"].min()) if len(c) else None)
        got = [x for x in reached if x is not None]
        per_seed = ", ".join("—" if x is None else str(x) for x in reached)
        median = f"{np.median(got):.0f}" if got else "—"
        lines.append(
            f"| {group} | {ref_name} ({target:.2e} rad) | {per_seed} "
            f"| {len(got)}/{len(reached)} | {median} |"
        )
    steps_of = {r.group: imitation_steps(r) for r in runs}  # a group shares its imitation
    imitated = {g: n for g, n in steps_of.items() if n is not None}
    if imitated:
        lines.append("")
        lines.append(
            "RL steps only: "
            + "; ".join(
                f"{g} also took {n} env steps of its expert's labels before step 0 "
                "(`imitation.json`)"
                for g, n in sorted(imitated.items())
            )
            + "."
        )
    return "\n".join(lines)


def imitation_steps(run: Run) -> int | None:
    """The env steps a run's imitation took before its RL (``imitation.json``), or None."""
    path = run.path / "imitation.json"
    if not path.exists():
        return None
    return int(json.loads(path.read_text())["env_steps"])


def aggregate_frame(df: pd.DataFrame, runs: Sequence[Run]) -> pd.DataFrame:
    """The final sweep's rows renamed for rliable: a group's "runs" are (training seed,
    test episode) pairs, stratified by training seed; a controller alone's are its test
    episodes."""
    steps = final_steps(runs)
    by_entry = {f"sb3:{r.path}@{steps}": r for r in runs}
    out = df.copy()
    is_run = out["controller"].isin(list(by_entry))
    run_of = out.loc[is_run, "controller"].map(by_entry)
    out.loc[is_run, "episode"] = out.loc[is_run, "seed"] * 10_000 + out.loc[is_run, "episode"]
    out.loc[is_run, "seed"] = [r.seed for r in run_of]
    out.loc[is_run, "controller"] = [r.group for r in run_of]
    out.loc[~is_run, "controller"] = out.loc[~is_run, "controller"] + " alone"
    return out


def main(argv: Sequence[str] | None = None) -> Path:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=Path, required=True, help="folder of train.train runs")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--episodes", type=int, default=10, help="paired test episodes")
    p.add_argument("--workers", type=int, default=0, help="worker processes (0: cores)")
    p.add_argument("--resume", action="store_true", help="continue an interrupted sweep")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument(
        "--presets",
        default=",".join(FINAL_PRESETS),
        help="comma-separated presets of the final checkpoints' sweep (level 1)",
    )
    p.add_argument(
        "--every", type=int, default=None, help="evaluate only checkpoints at multiples of this"
    )
    args = p.parse_args(argv)

    runs = discover(args.runs)
    if args.every is not None:
        runs = thin(runs, args.every)
    cfg = sweep_config(runs, args.episodes, args.out, args.workers)
    final_cfg = sweep_config(
        runs, args.episodes, args.out / "final", args.workers, args.presets.split(",")
    )
    cfg.validate()
    final_cfg.validate()
    progress = not args.no_progress
    out = run_sweep(cfg, resume=args.resume, progress=progress, show=False, module="train.rl_study")
    run_sweep(final_cfg, resume=args.resume, progress=progress, show=False, module="train.rl_study")
    df = load_frame(out / "episodes.csv")
    final = load_frame(out / "final" / "episodes.csv")
    curves = curve_frame(df, runs)
    curves.to_csv(out / "learning_curves.csv", index=False, float_format="%.17g")
    baselines = {
        dist: gd[~gd["controller"].map(is_checkpoint_entry)]
        .groupby("controller")["path_dist_rms"]
        .mean()
        for dist, gd in df.groupby("disturbance")
    }
    plot_curves(curves, training_curves(runs), baselines, out / "learning_curves.png")
    train_dist = str(runs[0].config["disturbance"]).partition(":")[0]
    agg = aggregate(
        aggregate_frame(final, runs), "path_dist_rms", out, cfg.bootstrap_resamples, seed=0
    )
    text = "\n\n".join(
        [
            f"## Final checkpoints ({final_steps(runs)} steps), presets at level 1",
            final_table(final, runs, cfg.bootstrap_resamples),
            "## Samples to reach the reference",
            samples_to_reach(curves, baselines, runs, train_dist),
            "## Aggregate over the presets (rliable)",
            agg,
        ]
    )
    (out / "final.md").write_text(text + "\n")
    print(text)
    return out


if __name__ == "__main__":
    main()
