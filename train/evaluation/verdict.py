"""The verdict's words and tables, written from the paired tests (:mod:`train.common.paired_tests`).

* :func:`report_metrics` — the two metrics every report states side by side: distance to
  the path (``path_dist_rms``: what a controller that tracks up to a time offset is judged
  by) and the time-indexed error (``time_err_rms``: |q − q_r(t)|, what a time-indexed
  controller is built to reduce);
* :func:`verdict_paragraph` — per controller against the reference, where it is better,
  worse or unresolved on one metric;
* :func:`rival_comparisons` and :func:`rival_sentence` — one controller (the *focus*, the
  passivity controller in the main job) against the **strongest rival** in each condition:
  the controller with the lowest mean on that metric there among those that are not
  variants of the focus (a name containing the focus's: ``passivity_paper``, a residual
  ``…_residual_passivity_…``); wins, ties and losses
  are the marks of a paired sign-flip test with Holm's correction over the conditions (one
  family per metric). The rival is chosen on the same episodes it is tested on, which can
  only make the focus look worse (a rival picked for its low mean), never better;
* :func:`grid_table` — the focus over its rival, condition by condition (rows) and robot by
  robot (columns), with its outcome: the verdict across robots at a glance;
* :func:`ranking_table` — per condition, the controllers ordered by mean under each metric;
* :func:`ranking_agreement` — whether two sweeps (e.g. disturbances sized at the home pose
  and at the onset) rank the controllers alike: leaders and Kendall's τ per condition.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from train.common.paired_tests import ALPHA, paired_comparisons

#: The metrics every report states side by side (the first is a sweep's default).
BOTH_METRICS = ("path_dist_rms", "time_err_rms")
#: How each metric is named in the words of a report.
METRIC_WORDS = {"path_dist_rms": "path distance", "time_err_rms": "time-indexed error"}
#: A focus controller's outcome against its rival, from the rival's mark against it.
OUTCOME = {"worse": "wins", "better": "loses", "unresolved": "ties"}


def condition_name(dist: str, level: float) -> str:
    """ "undisturbed" or e.g. "impulse 1"."""
    return "undisturbed" if dist == "none" else f"{dist} {level:g}"


def words(metric: str) -> str:
    """The metric in words ("path distance"), or its column name."""
    return METRIC_WORDS.get(metric, metric)


def report_metrics(metric: str, columns: pd.Index | list[str]) -> tuple[str, ...]:
    """``metric`` first, then the other of :data:`BOTH_METRICS` where ``columns`` has it."""
    others = [m for m in BOTH_METRICS if m != metric and m in columns]
    return (metric, *others)


def verdict_paragraph(
    comparisons: pd.DataFrame, table: pd.DataFrame, reference: str, metric: str
) -> str:
    """One paragraph on ``metric``, written from the marks: per controller, where it is
    better than, worse than or not resolved from the reference; which controller has the
    lowest mean and the lowest CVaR₁₀ most often (``table``: :func:`condition_table`'s
    columns for this metric); and the failures."""
    if comparisons.empty:
        return f"Only {reference} was evaluated: there is nothing to compare."
    k = int(comparisons["comparisons"].iloc[0])
    n_cond = len(comparisons[["disturbance", "level"]].drop_duplicates())
    pairs = int(comparisons["pairs"].min())
    need = int(comparisons["pairs_needed"].iloc[0])
    parts = [
        f"On {words(metric)} ({metric}; lower is better), against {reference}, over {n_cond} "
        f"conditions with {pairs} paired episodes each ({k} comparisons: exact sign-flip tests, "
        f"Holm's correction, family-wise error {100 * ALPHA:.0f}%; nothing can be resolved "
        f"with fewer than {need} pairs):"
    ]
    if pairs < need:
        parts.append(f"**{pairs} pairs cannot resolve anything in this family.**")
    for ctrl, g in comparisons.groupby("controller", sort=True):
        counts = {m: g[g["mark"] == m] for m in ("better", "worse", "unresolved")}
        pieces = []
        for mark, word in (("better", "better"), ("worse", "worse")):
            sub = counts[mark]
            if len(sub):
                names = ", ".join(
                    condition_name(d, lv)
                    for d, lv in zip(sub["disturbance"], sub["level"], strict=True)
                )
                med = float(np.median(sub["ratio"]))
                pieces.append(f"{word} in {len(sub)} ({names}; median ratio of means {med:.2g})")
        pieces.append(f"not resolved in {len(counts['unresolved'])}")
        parts.append(f"{ctrl} is " + ", ".join(pieces) + ".")
    best_mean = table.loc[table.groupby(["disturbance", "level"])["mean"].idxmin(), "controller"]
    best_tail = table.loc[table.groupby(["disturbance", "level"])["cvar10"].idxmin(), "controller"]
    parts.append(
        "Lowest mean: "
        + ", ".join(f"{c} in {n}" for c, n in best_mean.value_counts().items())
        + " of the conditions; lowest CVaR₁₀ (worst 10% of episodes): "
        + ", ".join(f"{c} in {n}" for c, n in best_tail.value_counts().items())
        + " (point estimates, not marks)."
    )
    return " ".join(parts)


def failures_sentence(table: pd.DataFrame) -> str:
    """ "Failed episodes: a 2/100." from :func:`condition_table`'s failures and n."""
    failures = table.groupby("controller")["failures"].sum()
    episodes = table.groupby("controller")["n"].sum()
    failed = [f"{c} {int(failures[c])}/{int(episodes[c])}" for c in failures.index if failures[c]]
    return "Failed episodes: " + ("; ".join(failed) if failed else "none") + "."


def rival_comparisons(
    df: pd.DataFrame, metric: str, focus: str, resamples: int = 20_000, seed: int = 0
) -> pd.DataFrame:
    """``focus`` against its strongest rival in each condition on ``metric`` (module
    docstring): one row per condition with the rival, the focus's and the rival's means,
    their ratio (focus / rival), the Holm-adjusted p-value over the conditions and the
    outcome ("wins", "ties", "loses"). Empty if ``focus`` is absent or has no rival."""
    if focus not in set(df["controller"]):
        return pd.DataFrame()
    means = df.groupby(["disturbance", "level", "controller"])[metric].mean()
    parts = []
    for (dist, level), g in df.groupby(["disturbance", "level"], sort=True):
        rivals = means.loc[(dist, level)]
        rivals = rivals[[focus not in str(c) for c in rivals.index]]
        if rivals.empty:
            continue
        rival = str(rivals.idxmin())
        parts.append(g[g["controller"].isin([focus, rival])])
    if not parts:
        return pd.DataFrame()
    tested = paired_comparisons(pd.concat(parts), metric, focus, resamples=resamples, seed=seed)
    return pd.DataFrame(
        {
            "disturbance": tested["disturbance"],
            "level": tested["level"],
            "metric": metric,
            "rival": tested["controller"],
            "focus_mean": tested["reference_mean"],
            "rival_mean": tested["mean"],
            "ratio": tested["reference_mean"] / tested["mean"],
            "p_holm": tested["p_holm"],
            "outcome": tested["mark"].map(OUTCOME),
            "pairs": tested["pairs"],
            "pairs_needed": tested["pairs_needed"],
        }
    )


def rival_sentence(rivals: pd.DataFrame, focus: str) -> str:
    """ "Against the strongest rival in each condition, passivity on path distance wins in 3
    (…), ties in 8, loses in 2 (…); on time-indexed error …" (empty if no rows)."""
    if rivals.empty:
        return ""
    pieces = []
    for metric, g in rivals.groupby("metric", sort=False):
        counts = []
        for outcome in ("wins", "ties", "loses"):
            sub = g[g["outcome"] == outcome]
            names = ", ".join(
                f"{condition_name(d, lv)} vs {r}"
                for d, lv, r in zip(sub["disturbance"], sub["level"], sub["rival"], strict=True)
            )
            listed = f" ({names})" if names and outcome != "ties" else ""
            counts.append(f"{outcome} in {len(sub)}{listed}")
        pieces.append(f"on {words(metric)} " + ", ".join(counts))
    return f"Against the strongest rival in each condition, {focus} " + "; ".join(pieces) + "."


def rival_table(rivals: pd.DataFrame) -> str:
    """Markdown: per condition and metric, the rival, the means, focus / rival and the
    outcome with its Holm-adjusted p-value."""
    lines = [
        "| condition | metric | strongest rival | focus mean | rival mean | focus / rival "
        "| p (Holm) | outcome |",
        "|---|---|---|---:|---:|---:|---:|---|",
    ]
    for _, r in rivals.sort_values(["disturbance", "level"], kind="stable").iterrows():
        lines.append(
            f"| {condition_name(r['disturbance'], r['level'])} | {words(r['metric'])} "
            f"| {r['rival']} | {r['focus_mean']:.3g} | {r['rival_mean']:.3g} | {r['ratio']:.2f} "
            f"| {r['p_holm']:.2g} | {r['outcome']} |"
        )
    return "\n".join(lines)


def condition_order(frame: pd.DataFrame) -> list[tuple[str, float]]:
    """The conditions (disturbance, level) of ``frame``'s rows as the verdict's tables and
    figure list them: undisturbed first, then by preset and level."""
    conditions = {
        (str(d), float(lv)) for d, lv in zip(frame["disturbance"], frame["level"], strict=True)
    }
    return sorted(conditions, key=lambda c: (c[0] != "none", c[0], c[1]))


def grid_table(
    rivals: pd.DataFrame, robots: list[str], metric: str, episodes: pd.DataFrame, focus: str
) -> str:
    """Markdown, one row per condition and one column per robot: the focus's mean over its
    strongest rival's on ``metric`` (:func:`rival_comparisons` rows with a ``robot``
    column) and the test's outcome, with the focus's failed episodes where it had any
    (``episodes``: the rows with ``robot``, ``controller``, ``failed``)."""
    rows = rivals[rivals["metric"] == metric] if len(rivals) else rivals
    robots = [r for r in robots if len(rows) and r in set(rows["robot"])]
    if not robots:
        return ""
    mine = episodes[episodes["controller"] == focus]
    failed = {
        (robot, dist, float(level)): (int(g["failed"].sum()), len(g))
        for (robot, dist, level), g in mine.groupby(["robot", "disturbance", "level"])
    }
    cells: dict[tuple[str, str, float], str] = {}
    for _, r in rows.iterrows():
        key = (str(r["robot"]), str(r["disturbance"]), float(r["level"]))
        ratio = float(r["ratio"])
        text = f"{ratio:.2g}" if ratio < 100 else f"{ratio:,.0f}"
        text += f" {r['outcome']}"
        n, size = failed.get(key, (0, 0))
        if n:
            text += f" ({n}/{size} failed)"
        cells[key] = f"**{text}**" if r["outcome"] == "wins" else text
    conditions = condition_order(rows)
    lines = [
        "| condition | " + " | ".join(robots) + " |",
        "|---|" + "---|" * len(robots),
    ]
    for d, lv in conditions:
        row = [cells.get((robot, d, lv), "–") for robot in robots]
        lines.append(f"| {condition_name(d, lv)} | " + " | ".join(row) + " |")
    return "\n".join(lines)


def ranking_table(df: pd.DataFrame, metrics: tuple[str, ...]) -> str:
    """Markdown: per condition, the controllers by rising mean under each metric."""
    header = " | ".join(f"by {words(m)} (mean)" for m in metrics)
    lines = [f"| condition | {header} |", "|---|" + "---|" * len(metrics)]
    for (dist, level), g in df.groupby(["disturbance", "level"], sort=True):
        cells = [
            " < ".join(g.groupby("controller")[m].mean().sort_values(kind="stable").index)
            for m in metrics
        ]
        lines.append(f"| {condition_name(dist, level)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def ranking_agreement(
    a: pd.DataFrame, b: pd.DataFrame, metric: str, focus: str | None = None
) -> pd.DataFrame:
    """Whether two sweeps of the same controllers rank them alike, per condition both ran.

    ``a`` and ``b`` are summaries (``controller``, ``disturbance``, ``level``,
    ``<metric>_mean``), e.g. the main job with disturbances sized at the home pose and at
    the onset. Per condition: each sweep's leader (lowest mean), whether they agree,
    Kendall's τ-b between the two orderings of the controllers both ran
    (``scipy.stats.kendalltau``; 1 = the same order) and, given ``focus``, its place in each
    (1 = best).

    Raises:
        ValueError: the sweeps share no condition, or fewer than 2 controllers in one.
    """
    from scipy.stats import kendalltau

    col = f"{metric}_mean"
    rows = []
    keys = ["disturbance", "level"]
    shared = a[keys].drop_duplicates().merge(b[keys].drop_duplicates())
    if shared.empty:
        raise ValueError("the two sweeps share no condition")
    for dist, level in shared.itertuples(index=False):
        ma = a[(a.disturbance == dist) & (a.level == level)].set_index("controller")[col]
        mb = b[(b.disturbance == dist) & (b.level == level)].set_index("controller")[col]
        both = sorted(set(ma.index) & set(mb.index))
        if len(both) < 2:
            raise ValueError(f"{condition_name(dist, level)}: fewer than 2 shared controllers")
        ma, mb = ma[both], mb[both]
        row = {
            "condition": condition_name(dist, level),
            "leader_a": ma.idxmin(),
            "leader_b": mb.idxmin(),
            "same_leader": ma.idxmin() == mb.idxmin(),
            "kendall_tau": float(kendalltau(ma.to_numpy(), mb.to_numpy()).statistic),
        }
        if focus is not None and focus in both:
            row["focus_place_a"] = int(ma.rank(method="min")[focus])
            row["focus_place_b"] = int(mb.rank(method="min")[focus])
        rows.append(row)
    return pd.DataFrame(rows)


def agreement_table(agreement: pd.DataFrame, names: tuple[str, str] = ("a", "b")) -> str:
    """Markdown of :func:`ranking_agreement`, with its mean and minimum τ underneath."""
    has_focus = "focus_place_a" in agreement
    head = f"| condition | leader, {names[0]} | leader, {names[1]} | Kendall τ |"
    head += f" focus place, {names[0]} | focus place, {names[1]} |" if has_focus else ""
    lines = [head, "|---|---|---|---:|" + ("---:|---:|" if has_focus else "")]
    for r in agreement.itertuples(index=False):
        line = f"| {r.condition} | {r.leader_a} | {r.leader_b} | {r.kendall_tau:.2f} |"
        line += f" {r.focus_place_a} | {r.focus_place_b} |" if has_focus else ""
        lines.append(line)
    tau = agreement["kendall_tau"]
    lines.append(
        f"\nSame leader in {int(agreement['same_leader'].sum())} of {len(agreement)} "
        f"conditions; Kendall τ mean {tau.mean():.2f}, min {tau.min():.2f}."
    )
    return "\n".join(lines)


def folder_agreement(folder: Path, against: Path) -> str:
    """Whether two evaluation results folders rank their controllers alike
    (:func:`ranking_agreement` on their ``summary.csv``), on both metrics; the focus is the
    passivity controller where both ran it (``ptrack report --against``)."""
    a, b = pd.read_csv(folder / "summary.csv"), pd.read_csv(against / "summary.csv")
    focus = "passivity" if "passivity" in set(a.controller) & set(b.controller) else None
    blocks = []
    for metric in BOTH_METRICS:
        if f"{metric}_mean" in a and f"{metric}_mean" in b:
            table = agreement_table(
                ranking_agreement(a, b, metric, focus), (folder.name, against.name)
            )
            blocks.append(f"Rankings, {folder.name} against {against.name}, {metric}:\n\n{table}")
    return "\n\n".join(blocks)
