"""How fair and how settled a tuning fight is: the spread of a controller's per-seed optima,
the controllers' ranking per study seed and its stability across seeds (Kendall's τ), the
fight's ``fight.md`` and ``ptrack tune --table`` (:mod:`train.studies.tune`).

* spread of a controller: (max − min) / median of its per-seed best objectives (rad / rad,
  dimensionless; 0 with one seed): how much the optimum found depends on the sampler's seed;
* ranking of seed k: the controllers sorted by their best objective of study seed k;
* stability: Kendall's τ (``scipy.stats.kendalltau``, τ-b) between the objectives of every
  pair of seeds over the controllers both have, reported as its mean and minimum — 1 when
  every seed ranks the controllers alike, −1 when two seeds rank them in reverse.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import yaml

from agents.registry import TUNED_DIR
from train.studies.tune_boxes import bounds_hit, resolve_box


def spread(objectives: Sequence[float]) -> float:
    """(max − min) / median of the per-seed best objectives (finite ones; NaN if none;
    0 for one)."""
    x = np.asarray([v for v in objectives if math.isfinite(v)], dtype=float)
    if x.size == 0:
        return float("nan")
    return float((x.max() - x.min()) / np.median(x))


def seed_rankings(objectives: Mapping[str, Mapping[int, float]]) -> dict[int, list[str]]:
    """seed → the controllers ranked best first by their best objective of that seed;
    ``objectives`` controller → {seed: objective} (a controller without a finite objective
    at a seed is left out of that seed's ranking)."""
    seeds = sorted({s for per in objectives.values() for s in per})
    return {
        s: sorted(
            (c for c, per in objectives.items() if math.isfinite(per.get(s, math.nan))),
            key=lambda c, s=s: (objectives[c][s], c),
        )
        for s in seeds
    }


class RankingStability(NamedTuple):
    """Kendall's τ between the seeds' rankings: per pair of seeds, their mean and minimum
    (NaN with fewer than two seeds or two ranked controllers)."""

    pairs: dict[tuple[int, int], float]
    mean: float
    min: float


def ranking_stability(objectives: Mapping[str, Mapping[int, float]]) -> RankingStability:
    """Kendall's τ-b between every pair of seeds' objectives over the controllers with a
    finite objective at both (``objectives``: controller → {seed: objective})."""
    from scipy.stats import kendalltau

    seeds = sorted({s for per in objectives.values() for s in per})
    pairs = {}
    for a, b in itertools.combinations(seeds, 2):
        both = [
            c
            for c, per in objectives.items()
            if math.isfinite(per.get(a, math.nan)) and math.isfinite(per.get(b, math.nan))
        ]
        if len(both) < 2:
            continue
        tau = kendalltau([objectives[c][a] for c in both], [objectives[c][b] for c in both])
        pairs[(a, b)] = float(tau.statistic)
    taus = [t for t in pairs.values() if math.isfinite(t)]
    if not taus:
        return RankingStability(pairs, float("nan"), float("nan"))
    return RankingStability(pairs, float(np.mean(taus)), float(np.min(taus)))


def stability_line(objectives: Mapping[str, Mapping[int, float]]) -> str:
    """One line: the ranking stability of ``objectives`` across their seeds."""
    st = ranking_stability(objectives)
    seeds = sorted({s for per in objectives.values() for s in per})
    if not st.pairs:
        return (
            f"ranking stability across study seeds {seeds}: n/a (needs two seeds, two controllers)"
        )
    return (
        f"ranking stability across study seeds {seeds} ({len(objectives)} controllers): "
        f"Kendall's tau mean {st.mean:.2f}, min {st.min:.2f}"
    )


def per_seed_objectives(results: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[int, float]]:
    """controller → {seed: best objective (rad)} of tuning results (a result's ``seeds``)."""
    return {
        c: {int(s): float(r["error_rad"]) for s, r in (res.get("seeds") or {}).items() if r}
        for c, res in results.items()
    }


def effort_text(result: Mapping[str, Any]) -> str:
    """The "effort (budget)" cell, with "over budget by x %" for a controller no trial of which met
    the budget (its least-over-budget trial won: :func:`train.studies.tune_study.winner`)."""
    effort, budget = float(result["effort"]), float(result["effort_budget"])
    text = f"{effort:.4f} ({budget:.4f})"
    if result.get("over_budget"):
        text += f" **over budget by {100 * (effort / budget - 1):.1f} %**"
    return text


def fight_markdown(results: Mapping[str, Mapping[str, Any]], title: str) -> str:
    """``fight.md``: per controller its best objective, per-seed objectives, spread, trials,
    effort and rates on a bound; each seed's ranking and their stability."""
    objectives = per_seed_objectives(results)
    seeds = sorted({s for per in objectives.values() for s in per})
    head = " | ".join(f"seed {s} (rad)" for s in seeds)
    lines = [
        f"# {title}",
        "",
        "Objective: geometric mean path-distance RMS (rad) on the validation episodes; the "
        "best feasible trial over all study seeds wins (train/studies/tune.py); a controller "
        "with no trial within the effort budget is tuned at its least-over-budget trial (its "
        "best and per-seed columns are then those trials' errors, not the lowest).",
        "",
        f"| controller | best (rad) | {head} | spread | trials | env steps | effort (budget) "
        "| on bound |",
        "|---|---:|" + "---:|" * len(seeds) + "---:|---:|---:|---|---|",
    ]
    for c, res in results.items():
        cells = " | ".join(f"{objectives[c][s]:.3g}" if s in objectives[c] else "–" for s in seeds)
        bound = ", ".join(f"{k} ({v})" for k, v in (res.get("on_bound_why") or {}).items()) or "–"
        lines.append(
            f"| {c} | {res['error_rad']:.3g} | {cells} | {res['spread']:.2f} | {res['trials']} "
            f"| {res.get('env_steps', '–')} | {effort_text(res)} "
            f"| {bound} |"
        )
    lines += ["", "Rankings (best first):", ""]
    for s, ranked in seed_rankings(objectives).items():
        lines.append(f"* seed {s}: {' < '.join(ranked)}")
    lines += ["", stability_line(objectives), ""]
    return "\n".join(lines)


def tuned_table(tuned_dir: Path = TUNED_DIR) -> str:
    """Markdown: every tuned file's gain rates next to the robot's defaults, with the study's
    validation error, study seeds and spread, effort (budget), trials, wall time and the rates
    on a bound (``ptrack tune --table``); then, per robot, the ranking stability across the
    seeds its controllers share. Files of the one-seed protocol show one seed, no spread, and
    the rates on a bound of the controller's TUNABLE box (5 %, :mod:`train.studies.tune_boxes`)."""
    from agents.registry import RATE_MODULES, effective_rates
    from ptrack_gym.robots import robot_profile

    lines = [
        "| robot | controller | tuned gain rates | default gain rates | validation error (rad) "
        "| seeds | spread | effort (budget) | feasible trials | wall (s) | on bound |",
        "|---|---|---|---|---:|---|---:|---|---:|---:|---|",
    ]
    robots: dict[str, dict[str, dict[int, float]]] = {}
    for path in sorted(tuned_dir.glob("*.yml")):
        data = yaml.safe_load(path.read_text())
        robot, controller = path.stem.split("-", 1)
        study = data["study"]
        space = RATE_MODULES[controller].TUNABLE
        default = effective_rates(robot_profile(robot), controller)
        tuned = {**default, **data["rates"]}  # a rate tuned before it was tunable: its default
        tuned_text = ", ".join(
            f"{k} {tuned[k]:.3g}" + ("" if k in data["rates"] else " (not tuned)") for k in space
        )
        default_text = ", ".join(f"{k} {default[k]:.3g}" for k in space)
        seeds = study.get("seeds")
        if seeds:
            seed_text = ", ".join(str(s) for s in seeds)
            spread_text = f"{study['spread']:.2f}"
            robots.setdefault(robot, {})[controller] = {
                int(s): float(r["error_rad"]) for s, r in seeds.items() if r
            }
        else:
            seed_text, spread_text = str(study.get("seed", "–")), "–"
        bound = study.get("on_bound_why")
        if bound is None:  # a one-seed file: where its rates sit in TUNABLE's box
            bound = {k: f"{side} of {tuple(space[k][:2])}" for k, side in
                     bounds_hit(data["rates"], resolve_box(controller)).items()}  # fmt: skip
        bound_text = ", ".join(f"{k} ({v})" for k, v in bound.items()) if bound else "–"
        lines.append(
            f"| {robot} | {controller} | {tuned_text} | {default_text} "
            f"| {study['error_rad']:.3g} | {seed_text} | {spread_text} "
            f"| {effort_text(study)} "
            f"| {study['feasible_trials']}/{study['trials']} | {study['wall_s']:.0f} "
            f"| {bound_text} |"
        )
    for robot, objectives in robots.items():
        lines += ["", f"{robot}: {stability_line(objectives)}"]
    return "\n".join(lines)


def journal_status(out: Path, budget: float | None = None) -> str:
    """Markdown: every study of the fight in ``out`` (its ``optuna.journal``, read without
    running anything) — the new trials done, the box searched, the best trial within
    ``budget`` (the effort constraint as recorded, when None) with its rates, and the rates
    of that trial on a bound of the box (5 %): where a running fight stands (``ptrack tune
    --status``)."""
    from train.common.runs import has_results

    path = out / "optuna.journal"
    if not has_results(path):
        return f"{out}: no journal yet"
    try:
        import optuna
        from optuna.storages import JournalStorage
        from optuna.storages.journal import JournalFileBackend
    except ImportError as exc:
        from ptrack_gym.errors import InvalidConfigError

        raise InvalidConfigError(
            "reading a fight needs the 'tune' extra: pip install 'ptrack_gym[tune]'"
        ) from exc
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = JournalStorage(JournalFileBackend(str(path)))
    lines = [
        "| study | new trials | box | best (rad) | its rates | on bound |",
        "|---|---:|---|---:|---|---|",
    ]
    for summary in sorted(optuna.get_all_study_summaries(storage), key=lambda s: s.study_name):
        study = optuna.load_study(study_name=summary.study_name, storage=storage)
        done = [t for t in study.get_trials(deepcopy=False)
                if t.state == optuna.trial.TrialState.COMPLETE]  # fmt: skip
        new = sum("copied_from" not in t.user_attrs for t in done)
        feasible = [
            t for t in done
            if (t.user_attrs["effort"] <= budget if budget is not None
                else all(c <= 0 for c in dict(t.constraints or {}).values()))
        ]  # fmt: skip
        box = {k: (lo, hi, log) for k, (lo, hi, log) in study.user_attrs.get("box", {}).items()}
        box_text_ = ", ".join(f"{k} [{lo:g}, {hi:g}]" for k, (lo, hi, _) in box.items())
        if feasible:
            best = min(feasible, key=lambda t: t.value)
            rates = ", ".join(f"{k} {v:.3g}" for k, v in best.params.items())
            bound = ", ".join(f"{k} {side}" for k, side in bounds_hit(best.params, box).items())
            lines.append(f"| {summary.study_name} | {new} | {box_text_} | {best.value:.4g} "
                         f"| {rates} | {bound or '–'} |")  # fmt: skip
        else:
            lines.append(f"| {summary.study_name} | {new} | {box_text_} | – | – | – |")
    return "\n".join(lines)
