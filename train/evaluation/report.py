"""The generated verdict of an evaluation sweep: ``report.md`` in its results folder.

What it holds, per condition (disturbance × level):

* each controller's mean, IQM, **CVaR₁₀** (the mean of its worst 10% episodes,
  :func:`cvar`) and failures on the sweep's metric;
* each controller's **paired difference** to the reference (controller − reference, per
  (seed, episode): the same start and the same disturbance draw), with a percentile-bootstrap
  interval, and a mark: *better* or *worse* when the interval excludes 0, *unresolved* when
  it does not.

**Multiple comparisons.** A report makes K = (conditions) × (controllers − 1) comparisons.
Its intervals are Bonferroni-adjusted: each is a (1 − α/K) interval, so with probability
≥ 1 − α (α = 5%) every interval of the report covers its true difference at once, and the
chance that any "resolved" mark is wrong is ≤ α. Bonferroni is conservative: a difference
marked unresolved may be real but is not shown by these seeds.

**Conditions in which nothing happened.** A disturbed condition with an episode in which
no disturbance acted (:func:`~train.evaluation.results.no_disturbance`: it did no work, or
it is bit-identical to its undisturbed twin) is not compared: its rows keep their
statistics but get no mark, it is left out of the comparisons (K), the verdict and the
aggregate, and the verdict says so ("impulse 1: 3 of 5 episodes saw no disturbance (no
work done): not compared"), so an undisturbed run is never reported as a result under
that disturbance.

Then: a paragraph written from those marks (:func:`verdict_paragraph`), an aggregate over
conditions in rliable's manner (IQM with stratified-bootstrap intervals and performance
profiles of a per-condition normalised score; :func:`stratified_bootstrap`, vectorised and
tested equal to rliable's bit for bit), and the
worst-case table of the adversarial searches named in the config (``worst_case``), read
from their ``summary.csv`` (``ptrack adversary``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from train.common.paired_tests import EXACT_MAX_PAIRS, TooFewPairsError
from train.common.statistics import (
    ALPHA,
    COMPARISON_COLUMNS,
    PAIR_KEY,
    cvar,
    interval_estimates,
    iqm,
    iqm_and_mean,
    paired_comparisons,
)
from train.evaluation.protocol import protocol_section
from train.evaluation.results import no_disturbance
from train.evaluation.verdict import (
    condition_name,
    failures_sentence,
    ranking_table,
    report_metrics,
    rival_comparisons,
    rival_sentence,
    rival_table,
    verdict_paragraph,
    words,
)
from train.plots.evaluation import aggregate_plot


def condition_table(df: pd.DataFrame, metric: str) -> pd.DataFrame:
    """Per condition × controller: episodes, mean, IQM, CVaR₁₀ and failures of ``metric``."""
    rows = []
    for (dist, level, ctrl), g in df.groupby(["disturbance", "level", "controller"], sort=True):
        x = g[metric].to_numpy(float)
        rows.append(
            {
                "disturbance": dist,
                "level": float(level),
                "controller": ctrl,
                "n": len(x),
                "mean": float(np.nanmean(x)),
                "iqm": float(iqm(x[np.isfinite(x)])),
                "cvar10": cvar(x),
                "failures": int(g["failed"].sum()),
            }
        )
    return pd.DataFrame(rows)


def idle_conditions(df: pd.DataFrame) -> dict[tuple[str, float], str]:
    """Per disturbed condition (disturbance, level) with episodes that saw no disturbance
    (:func:`~train.evaluation.results.no_disturbance`), what the report says of it: "3 of 5
    episodes saw no disturbance (no work done)" (episodes: (seed, episode) pairs; one counts
    if any controller's run of it saw none)."""
    flagged = df[no_disturbance(df).to_numpy()]
    out = {}
    for (dist, level), g in flagged.groupby(["disturbance", "level"], sort=True):
        cond = df[(df["disturbance"] == dist) & (df["level"] == level)]
        idle = len(g[PAIR_KEY].drop_duplicates())
        n = len(cond[PAIR_KEY].drop_duplicates())
        out[(dist, float(level))] = f"{idle} of {n} episodes saw no disturbance (no work done)"
    return out


def _compared(frame: pd.DataFrame, idle: dict[tuple[str, float], str]) -> np.ndarray:
    """Which rows of ``frame`` belong to a condition that is compared (not in ``idle``)."""
    return np.array(
        [
            (d, float(lv)) not in idle
            for d, lv in zip(frame["disturbance"], frame["level"], strict=True)
        ],
        dtype=bool,
    )


def idle_sentence(idle: dict[tuple[str, float], str]) -> str:
    """The verdict's sentence on the conditions left out (empty if none)."""
    if not idle:
        return ""
    notes = "; ".join(
        f"{condition_name(d, lv)}: {note}: not compared" for (d, lv), note in idle.items()
    )
    return f"{notes} (onsets after the episode's end? Rerun with longer episodes)."


def normalized_scores(df: pd.DataFrame, metric: str) -> tuple[dict[str, np.ndarray], list[str]]:
    """rliable's score matrices (runs × tasks) per controller: a task is a condition, a run a
    (seed, episode); score = log₁₀(m_c / x), x the episode's ``metric`` and m_c the median of
    every controller's episodes in condition c — decades better than the field's median,
    higher is better, comparable across conditions whose errors differ by decades."""
    df = df.copy()
    df["condition"] = [
        condition_name(d, lv) for d, lv in zip(df["disturbance"], df["level"], strict=True)
    ]
    tasks = sorted(df["condition"].unique())
    median = df.groupby("condition")[metric].median()
    floor = 1e-12  # a zero error (never seen) would be an infinite score
    df["score"] = np.log10(
        median.loc[df["condition"]].to_numpy() / np.maximum(df[metric].to_numpy(float), floor)
    )
    scores = {}
    for ctrl, g in df.groupby("controller", sort=True):
        wide = g.pivot_table(index=PAIR_KEY, columns="condition", values="score")
        scores[ctrl] = wide.reindex(columns=tasks).to_numpy(float)
    return scores, tasks


def aggregate(
    df: pd.DataFrame,
    metric: str,
    out: Path | None,
    resamples: int = 2000,
    seed: int = 0,
    draw: Callable[..., Any] | None = None,
) -> str:
    """The rliable-style aggregate: IQM and mean of :func:`normalized_scores` with stratified
    bootstrap 95% intervals (:func:`stratified_bootstrap`; a markdown table) and, with
    ``out``, ``aggregate.png`` (the intervals and the performance profiles) — drawn by
    ``draw(function, *args)`` when given (a sweep hands it to its worker processes), else
    here. Each controller's resamples come from its own generator, derived from ``seed``."""
    scores, tasks = normalized_scores(df, metric)
    scores = {c: s for c, s in scores.items() if np.isfinite(s).all()}
    if not scores:
        return "Aggregate scores: no controller has every condition's episodes."
    point, interval = interval_estimates(scores, iqm_and_mean, resamples, seed)
    lines = [
        f"Score = log₁₀(condition median / episode {metric}) over {len(tasks)} conditions "
        "(higher is better; 1 = ten times closer to the path than the field's median); "
        "stratified-bootstrap 95% intervals (rliable's method).",
        "",
        "| controller | IQM | IQM 95% CI | mean | mean 95% CI |",
        "|---|---:|---|---:|---|",
    ]
    for ctrl in sorted(point, key=lambda c: -point[c][0]):
        p, ci = point[ctrl], interval[ctrl]
        lines.append(
            f"| {ctrl} | {p[0]:.3f} | [{ci[0][0]:.3f}, {ci[1][0]:.3f}] | {p[1]:.3f} "
            f"| [{ci[0][1]:.3f}, {ci[1][1]:.3f}] |"
        )
    if out is not None:
        args = (scores, point, interval, out / "aggregate.png", resamples, seed)
        if draw is None:
            aggregate_plot(*args)
        else:
            draw(aggregate_plot, *args)
        lines += ["", "![aggregate](aggregate.png)"]
    return "\n".join(lines)


def _gains_label(cfg: dict[str, Any], folder: Path) -> str:
    """A search's gains in words: ``default``, ``tuned``, ``given``, or ``tuned earlier,
    stale`` (``default earlier, stale``) for a search whose recorded rates (``worst.yml``)
    are no longer the shipped tuned (default) ones — its worst cases are of gains the
    comparison no longer runs."""
    gains = cfg.get("gains", "default")
    if not isinstance(gains, str):
        return "given"
    if stale_search(folder, cfg):
        return f"{gains} earlier, stale"
    words = {g for used in _cell_gains(folder).values() for g in used if isinstance(g, str)}
    return f"{gains}, rates unrecorded" if words & GAIN_WORDS else gains


def _search_label(cfg: dict[str, Any], gains: str) -> str:
    """A search's robot and its gains label (:func:`_gains_label`), e.g. ``Iiwa (tuned)``:
    one robot may be searched at several gain choices."""
    return f"{cfg['env_id'].split('/')[-1].replace('Track-v0', '')} ({gains})"


#: The gains a search's worst.yml cell records as a word, before cells recorded the rates.
GAIN_WORDS = frozenset({"default", "tuned"})


def _cell_gains(folder: Path) -> dict[str, list[Any]]:
    """controller → the gains every cell of a search's ``worst.yml`` records (a word, or the
    rates; empty without the file)."""
    import yaml

    worst = folder / "worst.yml"
    if not worst.exists():
        return {}
    return {
        controller: [cell.get("gains") for levels in families.values() for cell in levels.values()]
        for controller, families in (yaml.safe_load(worst.read_text()).get("worst") or {}).items()
    }


def stale_search(folder: Path, cfg: dict[str, Any]) -> bool:
    """Whether a search at tuned or default gains ran any controller at rates other than
    those it would run today — its ``worst.yml`` cells record them: the tuned file's or the
    default's (:func:`agents.registry.pinned_rates`), with the config's ``rates`` for that
    controller over them. A controller no longer tuned is stale; a cell that records only
    the word (written before rates were recorded) cannot be checked and is not called stale
    (:func:`_gains_label` says "rates unrecorded")."""
    from agents.registry import GAIN_CHOICES, pinned_rates
    from ptrack_gym.errors import InvalidConfigError
    from ptrack_gym.robots import profile_for_env_id

    gains = cfg.get("gains", "default")
    if gains not in GAIN_CHOICES:
        return False
    profile = profile_for_env_id(cfg["env_id"])
    for controller, used in _cell_gains(folder).items():
        try:
            today = pinned_rates(
                profile, controller, gains, (cfg.get("rates") or {}).get(controller)
            )
        except InvalidConfigError:  # no tuned gains any more
            if any(isinstance(g, dict) for g in used):
                return True
            continue
        if any(isinstance(g, dict) and g != today for g in used):
            return True
    return False


def worst_case_section(folders: Sequence[str | Path]) -> str:
    """The worst-case table of the adversarial searches in ``folders`` (their
    ``summary.csv`` and ``config.yml``), or what is missing and how to make it."""
    if not folders:
        return "No adversarial search is named in the config (`worst_case`)."
    import yaml

    blocks = []
    lines = [
        "| robot (gains) | controller | energy (J) | worst found (rad) | worst searched (rad) "
        "| median random (rad) | searched / median | unstable, searched | unstable, random "
        "| delivered work (J) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for folder in map(Path, folders):
        summary, config = folder / "summary.csv", folder / "config.yml"
        if not (summary.exists() and config.exists()):
            blocks.append(
                f"Missing: `{folder}` has no search results (run `ptrack adversary "
                f"--out {folder}` with its config)."
            )
            continue
        cfg = yaml.safe_load(config.read_text())
        gains = _gains_label(cfg, folder)
        robot = _search_label(cfg, gains)
        s = pd.read_csv(summary)
        for _, r in s.iterrows():
            lines.append(
                f"| {robot} | {r['controller']} | {r['energy_j']:g} | {r['worst_rad']:.3g} "
                f"| {r['worst_search_rad']:.3g} "
                f"| {r['median_random_rad']:.3g} | {r['worst_over_median']:.1f} "
                f"| {r['unstable_search']}/{r['n_search']} "
                f"| {r['unstable_random']}/{r['n_random']} "
                f"| {r['work_min_j']:.2f}–{r['work_max_j']:.2f} |"
            )
        blocks.append(
            f"`{folder}`: {cfg['env_id']}, {', '.join(cfg['families'])}, "
            f"gains {gains}, {cfg['budget']} searched + "
            f"{cfg['budget']} "
            f"random episodes per row, cost = path-distance RMS over the {cfg['post_s']:g} s "
            f"after the disturbance (unstable = {cfg['failure_distance_rad']:g} rad)."
        )
    return "\n".join(lines) + "\n\n" + "\n".join(f"- {b}" for b in blocks)


def worst_case_sentence(folders: Sequence[str | Path]) -> str:
    """The worst-case verdict, from the searches' ``summary.csv``: per robot and energy, the
    controller with the lowest worst case (searched or random), and every controller that
    an episode made unstable (how often, searched and random)."""
    parts = []
    for folder in map(Path, folders):
        summary = folder / "summary.csv"
        if not summary.exists():
            continue
        import yaml

        cfg = yaml.safe_load((folder / "config.yml").read_text())
        robot = _search_label(cfg, _gains_label(cfg, folder))
        s = pd.read_csv(summary)
        for (family, energy), g in s.groupby(["family", "energy_j"]):
            best = g.loc[g["worst_rad"].idxmin()]
            unstable = [
                f"{r['controller']} {r['unstable_search']}/{r['n_search']} searched, "
                f"{r['unstable_random']}/{r['n_random']} random"
                for _, r in g.iterrows()
                if r["unstable_search"] or r["unstable_random"]
            ]
            parts.append(
                f"{robot}, {family} {energy:g} J: lowest worst case {best['controller']} "
                f"({best['worst_rad']:.3g} rad); "
                + ("unstable: " + ", ".join(unstable) if unstable else "none unstable")
            )
    return ("Worst case — " + "; ".join(parts) + ".") if parts else ""


def _comparisons(df: pd.DataFrame, metric: str, reference: str, resamples: int) -> pd.DataFrame:
    """:func:`paired_comparisons` on ``metric``, or an empty table where a comparison has
    fewer than 2 pairs (a one-seed sweep: nothing can be tested)."""
    try:
        return paired_comparisons(df, metric, reference, resamples=resamples)
    except TooFewPairsError:
        return pd.DataFrame(columns=list(COMPARISON_COLUMNS))


def _cell(r: pd.Series, metric: str, is_ref: bool, note: str | None) -> str:
    """The difference, interval, Holm p and mark cells of one metric (blank for the
    reference, "not compared" for a condition in which nothing happened)."""
    if note:
        return " | | not compared"
    if is_ref:
        return "reference | |"
    if pd.isna(r.get(f"mark_{metric}")):
        return " | | no test (< 2 pairs)"
    return (
        f"{r[f'diff_{metric}']:+.3g} [{r[f'ci_low_{metric}']:+.3g}, {r[f'ci_high_{metric}']:+.3g}]"
        f" | {r[f'p_holm_{metric}']:.2g} | {r[f'mark_{metric}']}"
    )


def write_report(
    df: pd.DataFrame,
    out: Path,
    metric: str,
    reference: str,
    worst_case: Sequence[str | Path] = (),
    resamples: int = 20_000,
    title: str = "",
    figures: bool = True,
    draw: Callable[..., Any] | None = None,
    focus: str = "passivity",
) -> Path:
    """Write ``out/report.md`` (and ``comparisons.csv`` — every metric's comparisons, a
    ``metric`` column apart; ``rivals.csv`` where ``focus`` ran; with ``figures``
    ``aggregate.png``, drawn by ``draw`` if given: see :func:`aggregate`); return its path.

    Both metrics of :func:`~train.evaluation.verdict.report_metrics` are tested (Holm's
    family is one metric's comparisons) and shown side by side; ``focus`` is compared with
    its strongest rival in each condition on each."""
    idle = idle_conditions(df)
    compared = df[_compared(df, idle)] if idle else df
    metrics = report_metrics(metric, df.columns)
    # First, so that a ``draw`` handing the figure to other processes overlaps the rest.
    aggregate_section = (
        aggregate(compared, metric, out if figures else None, draw=draw)
        if len(compared)
        else "Aggregate scores: no condition is compared."
    )
    comparisons = {m: _comparisons(compared, m, reference, resamples) for m in metrics}
    pd.concat(comparisons.values()).to_csv(
        out / "comparisons.csv", index=False, float_format="%.17g"
    )
    tables = {m: condition_table(df, m) for m in metrics}
    table = tables[metric]
    try:  # the same refusal as _comparisons: fewer than 2 pairs, nothing to test
        rivals = pd.concat([rival_comparisons(compared, m, focus, resamples) for m in metrics])
    except TooFewPairsError:
        rivals = pd.DataFrame()
    if len(rivals):
        rivals.to_csv(out / "rivals.csv", index=False, float_format="%.17g")
    verdicts = [
        verdict_paragraph(comparisons[m], tables[m][_compared(tables[m], idle)], reference, m)
        if len(compared)
        else "No condition is compared."
        for m in metrics
    ]
    merged = table
    for m in metrics:
        merged = merged.merge(
            tables[m][["disturbance", "level", "controller", "mean"]].rename(
                columns={"mean": f"mean_{m}"}
            ),
            on=["disturbance", "level", "controller"],
        )
        cols = ["diff", "ci_low", "ci_high", "p_holm", "mark"]
        merged = merged.merge(
            comparisons[m][["disturbance", "level", "controller", *cols]].rename(
                columns={c: f"{c}_{m}" for c in cols}
            ),
            on=["disturbance", "level", "controller"],
            how="left",
        )
    head = " | ".join(f"{words(m)} mean | Δ vs ref [CI] | p (Holm) | mark" for m in metrics)
    lines = [
        f"# Verdict{': ' + title if title else ''}",
        "",
        " ".join(
            p
            for p in (
                *verdicts,
                rival_sentence(rivals, focus),
                failures_sentence(table[_compared(table, idle)] if len(compared) else table),
                idle_sentence(idle),
                worst_case_sentence(worst_case),
            )
            if p
        ),
        "",
        f"## Per condition (rad; paired difference to {reference})",
        "",
        f"| condition | controller | n | failures | {head} | IQM ({words(metric)}) "
        f"| CVaR₁₀ ({words(metric)}) |",
        "|---|---|---:|---:|" + "---:|---|---:|---|" * len(metrics) + "---:|---:|",
    ]
    for _, r in merged.iterrows():
        is_ref = r["controller"] == reference
        note = idle.get((r["disturbance"], float(r["level"])))
        cells = " | ".join(f"{r[f'mean_{m}']:.3g} | {_cell(r, m, is_ref, note)}" for m in metrics)
        lines.append(
            f"| {condition_name(r['disturbance'], r['level'])} | {r['controller']} | {r['n']} "
            f"| {r['failures']} | {cells} | {r['iqm']:.3g} | {r['cvar10']:.3g} |"
        )
    some = next((c for c in comparisons.values() if len(c)), None)
    if some is not None:
        k, confidence = int(some["comparisons"].iloc[0]), float(some["confidence"].iloc[0])
        need, pairs = int(some["pairs_needed"].iloc[0]), int(some["pairs"].min())
        lines += [
            "",
            f"Paired tests: per metric a family of {k} comparisons; each an exact sign-flip test "
            f"of the mean paired difference (Monte Carlo beyond {EXACT_MAX_PAIRS} pairs), marked "
            f"only where Holm's step-down rejects at family-wise {100 * ALPHA:.0f}%; the "
            f"intervals are BCa bootstrap intervals at {100 * confidence:.3f}% (Bonferroni, "
            f"simultaneous; {resamples} resamples) and describe the effect, they do not mark it. "
            f"This family needs ≥ {need} pairs before anything can be resolved; it has {pairs}."
            + (" **Nothing here can be resolved.**" if pairs < need else "")
            + " CVaR₁₀ = mean of the worst ⌈10%·n⌉ episodes.",
        ]
    else:
        lines += ["", "Paired tests: none (fewer than 2 paired episodes per comparison)."]
    if len(rivals):
        lines += [
            "",
            f"## {focus} against the strongest rival",
            "",
            "The rival is the other controller with the lowest mean in the condition, on each "
            "metric; outcome from a paired sign-flip test with Holm's correction over the "
            "conditions (one family per metric).",
            "",
            rival_table(rivals),
        ]
    lines += protocol_section(list(dict.fromkeys(df["controller"])))
    lines += [
        "",
        "## Rankings",
        "",
        ranking_table(compared if len(compared) else df, metrics),
        "",
        "## Aggregate over conditions",
        "",
        aggregate_section,
        "",
        "## Worst case (adversarial search)",
        "",
        worst_case_section(worst_case),
        "",
    ]
    path = out / "report.md"
    path.write_text("\n".join(lines))
    return path
