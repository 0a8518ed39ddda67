"""Learning curves and final figures of a multi-seed RL study, from its checkpoints.

A *study* is a folder of ``ptrack train`` runs (``ptrack campaign``
trains one) that share env, training disturbance, control rate, episode length and start
mode, and differ in seed and in their *group* — the campaign's group name when the folder
is named ``<group>_s<seed>``, else pure RL or a residual on a base controller
(``residual-<base>``, ``-gated`` with a path-error gate) —, each group with its own
algorithm, reward and safeguards (the same within a group). This script evaluates
**every checkpoint of every run** and the base controllers alone (every group's base,
computed torque and PD + gravity) through one ``train.evaluation.config`` sweep
(``sb3:<run>@<steps>`` entries), so
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

    ptrack study --runs runs/study --out results/rl_study --episodes 10

``--resume`` continues an interrupted evaluation (the sweeps' ``episodes.csv``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ptrack_gym.errors import InvalidConfigError
from train.evaluation.report import aggregate
from train.evaluation.results import load_frame
from train.evaluation.sweep import run_sweep
from train.plots.rl import plot_curves

#: Checkpoint file names of ``train.rl.run`` (SB3's CheckpointCallback).
from train.rl.study_runs import (
    FINAL_PRESETS,
    GROUP_KEY_DEFAULTS,
    GROUP_KEYS,
    SHARED_KEY_DEFAULTS,
    discover,
    final_steps,
    is_checkpoint_entry,
    reference_of,
    sweep_config,
    thin,
    training_conditions,
)
from train.rl.study_tables import (
    aggregate_frame,
    curve_frame,
    final_table,
    protocol_table,
    samples_to_reach,
    training_curves,
)

__all__ = [
    "GROUP_KEYS",
    "GROUP_KEY_DEFAULTS",
    "SHARED_KEY_DEFAULTS",
    "StudyConfig",
    "discover",
    "is_checkpoint_entry",
    "reference_of",
    "run_study",
    "samples_to_reach",
    "sweep_config",
    "thin",
]


@dataclass
class StudyConfig:
    """An RL study: which runs, how many test episodes, where the results go."""

    runs: str
    """The folder of ``ptrack train`` runs (``ptrack campaign --out``)."""
    out: str
    """Output folder."""
    episodes: int = 10
    """Paired test episodes per policy and disturbance (>= 2: the bootstrap intervals of
    the paired differences need two)."""
    workers: int = 0
    """Episode runners (0: the number of cores)."""
    presets: list[str] = field(default_factory=lambda: list(FINAL_PRESETS))
    """Presets of the final checkpoints' sweep (level 1)."""
    every: int | None = None
    """Evaluate only the checkpoints at multiples of this many steps (None: all)."""

    def validate(self) -> None:
        """Raise :class:`InvalidConfigError` naming every bad field."""
        bad = []
        if self.episodes < 2:
            bad.append(
                f"episodes must be >= 2, got {self.episodes}: a bootstrap interval of the "
                "paired differences needs two episodes"
            )
        if self.workers < 0:
            bad.append(f"workers must be >= 0, got {self.workers}")
        if self.every is not None and self.every < 1:
            bad.append(f"every must be >= 1, got {self.every}")
        if not self.presets:
            bad.append("presets must not be empty")
        if bad:
            raise InvalidConfigError("; ".join(bad))


def run_study(
    cfg: StudyConfig,
    resume: bool = False,
    progress: bool = True,
    force: bool = False,
    rerun_changed: bool = False,
) -> Path:
    """Evaluate every checkpoint of ``cfg.runs`` and the final ones under every preset;
    write the curves, ``final.md`` and the figures (module docstring); return the folder.
    ``resume`` continues both sweeps, ``force`` starts both over in folders that hold files
    (:func:`train.common.runs.open_run`), ``rerun_changed`` reruns the rows of baselines
    whose gains changed since (:mod:`train.evaluation.rate_record`)."""
    out = Path(cfg.out)
    runs = discover(Path(cfg.runs))
    if cfg.every is not None:
        runs = thin(runs, cfg.every)
    sweep_cfg = sweep_config(runs, cfg.episodes, out, cfg.workers)
    final_cfg = sweep_config(runs, cfg.episodes, out / "final", cfg.workers, cfg.presets)
    sweep_cfg.validate()
    final_cfg.validate()
    for sweep in (sweep_cfg, final_cfg):
        run_sweep(sweep, resume=resume, progress=progress, show=False, force=force,
                  rerun_changed=rerun_changed)  # fmt: skip
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
    # the training disturbance (of runs trained on families: the first family)
    train_dist = training_conditions(runs[0].config)[0][0]
    resamples = sweep_cfg.bootstrap_resamples
    agg = aggregate(aggregate_frame(final, runs), "path_dist_rms", out, resamples, seed=0)
    test = (
        f"path {sweep_cfg.path}"
        + (f" (seed {sweep_cfg.path_seed})" if sweep_cfg.path_seed is not None else "")
        + f", presets {', '.join(dict.fromkeys(final['disturbance'].astype(str)))}"
    )
    text = "\n\n".join(
        [
            "## Protocol: what each group trained on, and what it is judged on",
            protocol_table(runs, test),
            f"## Final checkpoints ({final_steps(runs)} steps), presets at level 1",
            final_table(final, runs, resamples),
            "## Samples to reach the reference",
            samples_to_reach(curves, baselines, runs, train_dist),
            "## Aggregate over the presets (rliable)",
            agg,
        ]
    )
    (out / "final.md").write_text(text + "\n")
    return out
