"""Equal-budget tuning of a model-based controller's gains: ``ptrack tune``.

A *fight*: one Optuna study per robot × controller × study seed, the same rules for every
controller, so that a ranking of tuned controllers is a ranking of laws, not of luck:

* parameters — the controller's gain rates (``agents.registry.TUNABLE``: bandwidths ω (rad/s),
  damping ratios ζ, phase and adaptation rates; k_c rates for controller c), searched in its
  box (rate → [lo, hi, log]; ``boxes`` overrides it per rate) and made absolute by the
  controller's own ``gains_from_rates`` exactly as its defaults are;
* budget — N_c = max(``trials``, ``trials_per_rate`` · k_c) trials per study: a law with
  more rates gets proportionally more (TPE's needs grow with the dimension); the first
  ``startup_trials`` are random;
* seeds — one study per seed of ``study_seeds`` (≥ 3 for a fight); TPE is seeded by
  (study seed, round, trial index), so a resumed study asks what an uninterrupted one does;
* objective — J = exp(mean_e log max(d_e, 10⁻¹²)) (rad), the geometric mean over the
  validation episodes e ∈ V = ``validation_paths`` × ``validation_seeds`` × ``disturbances``
  (each preset at level 1, started on the path; random admissible paths, or the default
  path when ``validation_paths`` is empty; ``validation_design: paired`` runs the i-th
  disturbance on the i-th path only, |V| = paths × seeds) of the path-distance RMS d_e:
  scale-free, so the undisturbed case (~1e-4 rad) counts as much as a payload (~1e-1 rad)
  in relative terms, where an arithmetic mean would tune for the payload alone; a failed
  episode (unstable, or the path distance past ``failure_distance_rad``) counts with its
  padded RMS;
* constraint — the mean effort E = (1/|V|) Σ_e m_e of ``effort_metric`` m must stay ≤ the
  budget B: ``effort_budget`` if given, else ``effort_factor`` × E of ``effort_reference``
  (computed torque) with its default gains on the same episodes — one budget per robot.
  m = ``tau_fb_rms_frac`` (default): the RMS over steps and joints of (τ − τ_ff)/τ_max,
  τ_ff = ID(q_r(s), q_r'(s), q_r''(s)) the nominal inverse dynamics along the controller's
  own reference phase s at ṡ = 1 — the feedback part of the torque, which a gain buys
  (the feed-forward is the same for every model-based law and made τ_dyn's budget hardly
  bind); ``tau_dyn_rms_frac``, the RMS of (τ − g(q))/τ_max, is still selectable. TPE
  samples with the constraint; a feasible trial beats every infeasible one;
* winner — per seed its best feasible trial; the gains saved are the best of those over the
  seeds (the lowest J: every seed scores on the same validation episodes). A controller
  none of whose trials meets the budget is tuned at its
  least-over-budget trial (lowest effort, then J; Optuna's order for infeasible trials),
  flagged ``over_budget`` with the excess in every table, never dropped. The seeds'
  disagreement is reported: spread = (max − min)/median of the per-seed bests, and for the
  fight the controllers' ranking per seed and Kendall's τ between seeds
  (:mod:`train.studies.tune_fight`, ``fight.md``);
* boxes — a winning rate within 5 % of a bound of its box (in log space for log-scaled
  rates, :mod:`train.studies.tune_boxes`) is reported (``on_bound``). With
  ``widen_on_bound``, that seed reruns as a new study — its earlier trials copied in as
  history, N_c new trials — with the bound widened (÷ or × 3 in log space, ± the box width in
  linear space, never to the rate's floor), at most ``max_widenings`` times. A bound is not
  widened where moving the rate there changes nothing the controller does (its torques at a
  probe state are equal: ``gains_from_rates`` caps the rate at the control rate, the
  per-sample cap), nor past a floor; such a rate is reported as "capped" or "at the floor".
  With ``carry_boxes`` (default) the next study seed starts in the box the seed before it
  ended in: a bound one seed found too tight is not found again, at N_c trials a widening,
  by every seed (each seed still widens its own box where its optimum sits on it);
* validation paths must not be test paths of ``test_config`` (the main job's), and on the
  same path the validation seeds must not meet its test seeds: the tuned gains are chosen
  on other episodes than those they are judged on.

Studies live in ``<out>/optuna.journal`` as ``<controller>.seed<k>`` (round 0) and
``<controller>.seed<k>.widen<r>``; ``--resume`` continues them (a larger budget, more seeds
or widenings are allowed; a study of the one-seed protocol is refused). Outputs:
``<out>/<controller>.yml`` (the winner, every seed's best, the boxes) and ``<out>/fight.md``.
``--save`` writes the winner's rates with the study's record to
``agents/tuned/<robot>-<controller>.yml`` (``rates:`` and ``study:``), which
``make_controller(..., gains="tuned")`` and every entry point's ``gains: tuned`` read;
``ptrack tune --table`` lists them with their seeds, spread and rates on a bound, and per
robot the ranking stability across the seeds its controllers share. The objective is
pluggable (:class:`TrialObjective`): the tests tune cheap functions. Needs the ``tune``
extra (Optuna).
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import math
from pathlib import Path
from typing import Any

import yaml

import ptrack_gym  # noqa: F401  (registers the envs)
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots import profile_for_env_id
from train.common.runs import CONFIG_FILE, has_results, open_run, worker_count, worker_pool
from train.studies.tune_config import EFFORT_METRICS, TuneConfig, load_config
from train.studies.tune_fight import fight_markdown, tuned_table
from train.studies.tune_study import (
    EpisodeObjective,
    SeedStudies,
    TrialObjective,
    TrialScore,
    study_name,
    winner,
)

__all__ = [
    "EFFORT_METRICS",
    "TrialObjective",
    "TrialScore",
    "TuneConfig",
    "load_config",
    "study_name",
    "tune",
    "tuned_table",
]
#: What a study folder written before these settings existed ran with.
SETTING_DEFAULTS = {"validation_design": "crossed"}
#: Settings a resume may change: a larger budget, more seeds, more widenings, the boxes the
#: later seeds start in.
FREE_FIELDS = (
    "trials",
    "trials_per_rate",
    "study_seeds",
    "widen_on_bound",
    "max_widenings",
    "carry_boxes",
)


def tune(
    cfg: TuneConfig,
    resume: bool = False,
    save_dir: Path | None = None,
    progress: bool = True,
    force: bool = False,
    objective: TrialObjective | None = None,
) -> dict[str, dict[str, Any]]:
    """Run (or continue) the studies of every controller and seed; return {controller:
    result}, a result holding the winner over the seeds and every seed's best (``seeds``).

    ``save_dir`` (``--save``: :data:`agents.registry.TUNED_DIR`) receives each winner as
    ``<robot>-<controller>.yml``; a file already there (the shipped gains) is replaced only
    with ``force``. Without ``resume``, ``force`` also starts the studies over in an ``out``
    that holds files; with it, the studies continue and ``force`` only lets the winners
    replace the shipped gains (the last run of a fight: ``--resume --save --force``).
    ``objective`` replaces the validation episodes (tests).

    Raises:
        InvalidConfigError: a bad config (before any episode), an existing study without
            ``resume`` or ``force``, a tuned-gains file ``save_dir`` holds without
            ``force``, a resumed study with other settings or of the one-seed protocol, or
            no feasible trial in any seed.
    """
    try:
        import optuna
        from optuna.storages import JournalStorage
        from optuna.storages.journal import JournalFileBackend
    except ImportError as exc:
        raise InvalidConfigError(
            "tuning needs the 'tune' extra: pip install 'ptrack_gym[tune]'"
        ) from exc
    cfg.validate()
    robot = profile_for_env_id(cfg.env_id).name
    if save_dir is not None and not force:
        shipped = [p for c in cfg.controllers if (p := save_dir / f"{robot}-{c}.yml").exists()]
        if shipped:
            raise InvalidConfigError(
                f"--save would replace {', '.join(map(str, shipped))}: add --force to "
                "replace the tuned gains, or tune without --save"
            )
    _refuse_one_seed_study(Path(cfg.out), resume)
    settings_dict = _settings(cfg)
    run = open_run(
        cfg.out, "optuna.journal", settings_dict, resume=resume, force=force and not resume,
        free=FREE_FIELDS, defaults=SETTING_DEFAULTS,
        saved_required=False,
    )  # fmt: skip
    out = run.out
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = JournalStorage(JournalFileBackend(str(run.results)))
    results: dict[str, dict[str, Any]] = {}
    with contextlib.ExitStack() as stack:
        if objective is None:
            pool = stack.enter_context(worker_pool(worker_count(cfg.workers), "spawn"))
            episodes = EpisodeObjective(cfg, pool)
            stack.callback(episodes.close)
            objective = episodes
        budget = cfg.effort_budget
        if budget is None:
            reference = objective.score(cfg.effort_reference, None).effort
            if not (math.isfinite(reference) and reference > 0):
                raise InvalidConfigError(
                    f"{cfg.effort_reference}'s default {cfg.effort_metric} is {reference}: "
                    "no budget; give effort_budget"
                )
            budget = cfg.effort_factor * reference
            if progress:
                print(f"effort budget {budget:.4f} ({cfg.effort_factor} x {cfg.effort_reference}'s "
                      f"default {cfg.effort_metric})", flush=True)  # fmt: skip
        study = SeedStudies(optuna, storage, objective, cfg, budget, progress)
        for controller in cfg.controllers:
            seeds = {seed: study.seed_result(controller, seed) for seed in cfg.study_seeds}
            spent = sum(study.spent_trials(controller, seed) for seed in cfg.study_seeds)
            best = winner(cfg, controller, seeds, budget, spent)
            results[controller] = best
            (out / f"{controller}.yml").write_text(_yaml(best))
            if save_dir is not None:
                save_dir.mkdir(parents=True, exist_ok=True)
                study_record = {**settings_dict, **best, "rates": dict(best["rates"])}
                record = {"rates": dict(best["rates"]), "study": study_record}
                path = save_dir / f"{robot}-{controller}.yml"
                path.write_text(
                    f"# Tuned by ptrack tune ({datetime.date.today()}); see "
                    "train/studies/tune.py for the protocol.\n" + _yaml(record)
                )
    title = f"Tuning fight: {robot}, {cfg.control_hz:g} Hz, seeds {list(cfg.study_seeds)}"
    (out / "fight.md").write_text(fight_markdown(results, title))
    return results


class _NoAliases(yaml.SafeDumper):
    def ignore_aliases(self, data: Any) -> bool:
        return True


def _yaml(data: Any) -> str:
    """``data`` as block YAML in its own key order, a shared object written out each time."""
    return yaml.dump(data, Dumper=_NoAliases, sort_keys=False)


def _refuse_one_seed_study(out: Path, resume: bool) -> None:
    """A journal of the one-seed protocol (no ``study_seeds`` in its config) is not resumed:
    its studies are named per controller and its effort was ``tau_dyn_rms_frac``."""
    saved = out / CONFIG_FILE
    if resume and has_results(out / "optuna.journal") and saved.exists():
        if "study_seeds" not in (yaml.safe_load(saved.read_text()) or {}):
            raise InvalidConfigError(
                f"{out} holds a study of the one-seed protocol (one study per controller, "
                "effort tau_dyn_rms_frac): this version cannot resume it; tune into another "
                "--out, or --force without --resume to start over"
            )


def _settings(cfg: TuneConfig) -> dict[str, Any]:
    d = dataclasses.asdict(cfg)
    for k in ("workers", "out", "controllers"):
        d.pop(k)
    return d
