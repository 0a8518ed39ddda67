"""The tables of an RL study (:mod:`train.rl.study`): learning curves from the checkpoints'
episodes and the runs' Monitor logs, the final checkpoints against their bases with paired
bootstrap intervals, the samples each run needed to reach its base, and the frame of
rliable's aggregate."""

from __future__ import annotations

import json
from collections.abc import Sequence

import numpy as np
import pandas as pd

from train.common.statistics import bootstrap_ci
from train.evaluation.protocol import tuning_env_steps
from train.rl.study_runs import Run, final_steps, is_checkpoint_entry, reference_of


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


def protocol_table(runs: Sequence[Run], test: str) -> str:
    """Markdown: per group, what its runs trained on — paths, disturbance families, the
    plant's randomisation, the env steps of a run beside those the tuning fight spent on
    its base (a residual with tuned base gains) — and ``test``, what the study evaluates
    them on (the generalization protocol, issue 39; a run predating a field trained
    without it)."""
    from ptrack_gym.robots import profile_for_env_id

    lines = [
        "| group | seeds | algorithm | env steps a run | tuning of its base (env steps) "
        "| trained on paths | trained under | randomized masses | evaluated during training on |",
        "| --- | ---: | --- | ---: | ---: | --- | --- | ---: | --- |",
    ]
    for group in sorted({r.group for r in runs}):
        members = [r for r in runs if r.group == group]
        c = members[0].config
        paths = c.get("train_paths")
        families = c.get("train_families")
        eval_on = ", ".join(
            x for x in (
                f"paths {c['eval_paths']}" if c.get("eval_paths") else "",
                f"families {c['eval_families']}" if c.get("eval_families") else "",
            ) if x
        ) or "the training distribution"  # fmt: skip
        tuned = None
        if c.get("residual") not in (None, "none", "network") and c.get("base_gains") == "tuned":
            tuned = tuning_env_steps(profile_for_env_id(c["env_id"]).name, c["residual"])
        # its last checkpoint, in env steps (checkpoints count decisions)
        budget = max(max(r.checkpoints, default=0) for r in members)
        budget *= int(c.get("decision_every", 1))
        lines.append(
            f"| {group} | {len(members)} | {c.get('algo', 'sac')} | {budget} "
            f"| {tuned if tuned is not None else '–'} "
            f"| {paths if paths else 'the default path'} | "
            f"{families if families else c.get('disturbance', 'none')} | "
            f"±{float(c.get('randomize_mass', 0.0)):g} | {eval_on} |"
        )
    return "\n".join(lines) + f"\n\nThis study evaluates them on: {test}."


def final_table(df: pd.DataFrame, runs: Sequence[Run], resamples: int) -> str:
    """Markdown table of the final checkpoints against the controllers alone, per
    disturbance (rows of ``df``'s disturbances, in order). Every run is taken at the same
    budget (:func:`final_steps`); Δ is the paired difference to the group's reference
    (:func:`reference_of`) with a bootstrap 95 % CI over the pooled (run, episode) pairs
    (it does not carry the seed-to-seed variance: read it next to the per-seed column; it
    is unadjusted for the table's other comparisons: a description of the effect, not a
    test — the tests are the study's ``report.md``, ``train.common.paired_tests``), and ×ref
    the ratio of the pooled means."""
    steps = final_steps(runs)
    lines = [
        "| disturbance | policy | path-dist RMS per seed (rad) | pooled mean (rad) | "
        "Δ vs reference alone, 95% CI (unadjusted, not a test) | ×ref | time-indexed RMSE (rad) "
        "| failures |",
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
            algo = str(members[0].config.get("algo", "sac")).upper()  # the group's learner
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
    mean path distance under ``dist`` was at most its reference's alone ("—": not within
    its checkpoints); the median over the runs that reached it. Only checkpoints whose
    actor has trained count (past ``Run.untrained_through``): a zero-initialised residual
    is its base until then and would "reach" it at once; a run with no such checkpoint
    is "never trained" and has not reached it."""
    lines = [
        f"| group | reference | steps to reach the reference's path distance ({dist}), "
        "per seed | reached | median (reached) |",
        "| --- | --- | --- | ---: | ---: |",
    ]
    for group in sorted({r.group for r in runs}):
        members = sorted((r for r in runs if r.group == group), key=lambda r: r.seed)
        ref_name = reference_of(members[0])
        target = float(baselines[dist][ref_name])
        reached: list[int | str | None] = []
        for r in members:
            if not r.checkpoints or r.checkpoints[-1] <= r.untrained_through:
                reached.append("never trained")
                continue
            c = curves[(curves["group"] == group) & (curves["seed"] == r.seed)]
            c = c[(c["disturbance"] == dist) & (c["steps"] > r.untrained_through)]
            c = c[c["path_dist_rms"] <= target]
            reached.append(int(c["steps"].min()) if len(c) else None)
        got = [x for x in reached if isinstance(x, int)]
        per_seed = ", ".join("—" if x is None else str(x) for x in reached)
        median = f"{np.median(got):.0f}" if got else "—"
        lines.append(
            f"| {group} | {ref_name} ({target:.2e} rad) | {per_seed} "
            f"| {len(got)}/{len(reached)} | {median} |"
        )
    if any(r.checkpoints and r.checkpoints[-1] <= r.untrained_through for r in runs):
        lines.append("")
        lines.append(
            "Never trained: the run's last checkpoint is within its learning_starts + "
            "critic_warmup_steps (or it froze its actor): its policy is its initialisation."
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
