"""Results files of an evaluation sweep: the tidy per-episode table and its summary.

``episodes.csv`` gets one row per finished episode, appended and flushed to disk as soon
as the episode finishes, so an interrupted sweep loses at most the episodes in flight.
:func:`read_episodes` validates the file before a resume and refuses, with the line
number, a file with a foreign header, a row with the wrong number of fields, a truncated
last line or a duplicated episode. A file written before a metric of
:data:`LATER_COLUMNS` existed loads for reports (that metric NaN) but is refused for a
resume, naming the missing column: its new rows would not fit its header.

:func:`summarize` aggregates per controller × disturbance × level: mean and interquartile
mean (IQM) with 95% bootstrap confidence intervals (``scipy.stats.bootstrap``, percentile
method, seeded), the failure rate, and the paired difference to a reference controller
(per (seed, episode) pair, same disturbance schedule) with its interval. Failed episodes
are counted in the failure rate and kept in every mean — never dropped.

An episode of a disturbed condition in which no disturbance acted (:func:`no_disturbance`:
its disturbance did no work, or it is bit-identical to its undisturbed twin) is counted in
the summary's ``no_disturbance_n``; the headline table and the report flag its condition,
and the report does not compare it.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ptrack_gym.disturbances import preset_does_work
from ptrack_gym.errors import PtrackError
from ptrack_gym.metrics import METRIC_NAMES
from train.common.statistics import bootstrap_ci, iqm
from train.evaluation.episode import KEY_COLUMNS, label
from train.evaluation.verdict import report_metrics, words

COLUMNS: tuple[str, ...] = (*KEY_COLUMNS, *METRIC_NAMES, "steps", "wall_s")
#: Columns added after results were first written (``tau_fb_rms_frac``: issue 37; a
#: verdict's ``balance_excess_j``, ``tank_created_j`` and ``tank_arm_gained_j``: issue 39).
LATER_COLUMNS: tuple[str, ...] = (
    "tau_fb_rms_frac",
    "balance_excess_j",
    "tank_created_j",
    "tank_arm_gained_j",
)


class CorruptResultsError(PtrackError, ValueError):
    """A results file that cannot be resumed from safely."""


def read_episodes(
    path: Path,
    columns: Sequence[str] = COLUMNS,
    key_columns: Sequence[str] = KEY_COLUMNS,
    fill_missing: bool = False,
) -> list[dict[str, str]]:
    """The rows of an ``episodes.csv``, validated (see the module docstring); ``columns``
    and ``key_columns`` are another study's (e.g. ``train.studies.rates``). A file without
    some of :data:`LATER_COLUMNS` gets them as "nan" with ``fill_missing`` (to read and
    report), else is refused (to resume)."""
    columns, key_columns = tuple(columns), tuple(key_columns)
    if not path.exists():
        return []
    text = path.read_text()
    if text and not text.endswith("\n"):
        raise CorruptResultsError(
            f"{path}: the last line is incomplete (the sweep was killed mid-write?); "
            f"delete that line or the file to resume"
        )
    rows = list(csv.reader(text.splitlines()))
    if not rows:
        return []
    header = tuple(rows[0])
    missing = [c for c in columns if c not in header]
    older = set(missing) <= set(LATER_COLUMNS) and header == tuple(
        c for c in columns if c not in missing
    )  # the expected header but for columns added since
    if not older:
        raise CorruptResultsError(f"{path}: header {rows[0]} is not the expected {list(columns)}")
    if missing and not fill_missing:
        raise CorruptResultsError(
            f"{path} was written before the column(s) {missing} existed: it still loads "
            "for reports, but cannot be resumed (new rows have more fields); rerun it "
            "with --force, or into another --out"
        )
    out, seen = [], set()
    for lineno, fields in enumerate(rows[1:], start=2):
        if len(fields) != len(header):
            raise CorruptResultsError(
                f"{path}, line {lineno}: {len(fields)} fields, expected {len(header)}"
            )
        row = {**dict(zip(header, fields, strict=True)), **dict.fromkeys(missing, "nan")}
        key = tuple(row[k] for k in key_columns)
        if key in seen:
            raise CorruptResultsError(f"{path}, line {lineno}: episode {key} appears twice")
        seen.add(key)
        out.append(row)
    return out


class EpisodeWriter:
    """Appends rows to ``episodes.csv`` (header first if the file is new), each one
    flushed and fsynced before :meth:`write` returns; ``columns``: another study's."""

    def __init__(self, path: Path, columns: Sequence[str] = COLUMNS) -> None:
        new = not path.exists() or path.stat().st_size == 0
        self._columns = tuple(columns)
        self._file = path.open("a", newline="")
        self._writer = csv.DictWriter(self._file, fieldnames=list(columns), extrasaction="raise")
        if new:
            self._writer.writeheader()
            self._flush()

    def _flush(self) -> None:
        self._file.flush()
        os.fsync(self._file.fileno())

    def write(self, row: dict[str, Any]) -> None:
        self._writer.writerow({k: _fmt(row[k]) for k in self._columns})
        self._flush()

    def close(self) -> None:
        self._file.close()


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return repr(value)  # round-trips exactly
    return str(value)


def load_frame(path: Path) -> pd.DataFrame:
    """``episodes.csv`` as a DataFrame with numeric metric columns, its rows sorted by
    their key (controller, disturbance, level, seed, episode): the file holds them in the
    order they finished, which parallel runners change from run to run, and the bootstrap
    intervals computed from the frame must not depend on it."""
    df = pd.DataFrame(read_episodes(path, fill_missing=True), columns=list(COLUMNS))
    for col in (*METRIC_NAMES, "wall_s", "level"):
        df[col] = df[col].astype(float)  # parses "nan" and repr() floats exactly
    for col in ("steps", "seed", "episode"):
        df[col] = df[col].astype(int)
    return df.sort_values(list(KEY_COLUMNS), kind="stable").reset_index(drop=True)


def no_disturbance(df: pd.DataFrame) -> pd.Series:
    """Per row of an episodes table: whether the episode is one of a disturbed condition
    (disturbance ≠ "none") in which no disturbance acted —

    * its ``disturbance_work_j`` is exactly 0 and its preset acts through a torque or a
      force (:func:`~ptrack_gym.disturbances.preset_does_work`): nothing pushed the arm; or
    * its ``disturbance_work_j`` is 0 and every metric equals (NaN equal to NaN) that of
      its undisturbed twin, the episode of the same controller, seed and episode under
      "none" (same reset seed, same start): the only way to tell that a payload, whose
      work the ledger does not count, never acted.

    Such an episode (an onset after the episode's end, in results made before onsets were
    checked against the episode) is an undisturbed run under a disturbed label. A table
    without ``disturbance_work_j`` has none.
    """
    if "disturbance_work_j" not in df.columns:
        return pd.Series(False, index=df.index, name="no_disturbance")
    disturbed = (df["disturbance"] != "none").to_numpy()
    idle = disturbed & (df["disturbance_work_j"].to_numpy(float) == 0.0)
    does_work = {d: preset_does_work(str(d)) for d in df["disturbance"].unique()}
    works = df["disturbance"].map(does_work).to_numpy(bool)
    flag = idle & works
    key = ["controller", "seed", "episode"]
    metrics = [m for m in METRIC_NAMES if m in df.columns]
    none = df[df["disturbance"] == "none"].drop_duplicates(key).set_index(key)[metrics]
    check = idle & ~works
    if check.any() and len(none):
        rows = df.loc[check]
        index = pd.MultiIndex.from_frame(rows[key])
        twin = none.reindex(index).to_numpy(float)
        own = rows[metrics].to_numpy(float)
        same = ((twin == own) | (np.isnan(twin) & np.isnan(own))).all(axis=1)
        same &= index.isin(none.index)
        flag[np.flatnonzero(check)] = same
    return pd.Series(flag, index=df.index, name="no_disturbance")


def summarize(
    df: pd.DataFrame,
    metric: str = "path_dist_rms",
    reference: str | None = None,
    resamples: int = 2000,
    seed: int = 0,
) -> pd.DataFrame:
    """One row per controller × disturbance × level (see the module docstring)."""
    out = []
    df = df.assign(no_disturbance=no_disturbance(df))
    groups = df.groupby(["controller", "disturbance", "level"], sort=True)
    ref_rows = (
        df[df["controller"] == reference].set_index(["disturbance", "level", "seed", "episode"])
        if reference is not None
        else None
    )
    for (ctrl, dist, level), g in groups:
        x = g[metric].to_numpy(dtype=float)
        x = x[np.isfinite(x)]  # the point estimates use the same values as the intervals
        mean_lo, mean_hi = bootstrap_ci(x, np.mean, resamples, seed)
        iqm_lo, iqm_hi = bootstrap_ci(x, iqm, resamples, seed)
        row: dict[str, Any] = {
            "controller": ctrl,
            "disturbance": dist,
            "level": level,
            "n": len(x),
            "failure_rate": float(g["failed"].mean()),
            f"{metric}_mean": float(np.mean(x)),
            "mean_ci_low": mean_lo,
            "mean_ci_high": mean_hi,
            f"{metric}_iqm": float(iqm(x)),
            "iqm_ci_low": iqm_lo,
            "iqm_ci_high": iqm_hi,
            "time_err_rms_mean": float(g["time_err_rms"].mean()),
            "speed_ratio_err_mean": float(g["speed_ratio_err"].mean()),
            # Never recovered (NaN) counts as +inf, so the median cannot hide failures.
            "recovery_s_median": float(np.median(g["recovery_s"].fillna(np.inf))),
            "recovered_frac": float(g["recovery_s"].notna().mean()),
            "tau_rms_frac_mean": float(g["tau_rms_frac"].mean()),
        }
        if ref_rows is not None:
            keyed = g.set_index(["disturbance", "level", "seed", "episode"])[metric]
            common = keyed.index.intersection(ref_rows.index)
            diff = keyed.loc[common].to_numpy(float) - ref_rows.loc[common, metric].to_numpy(float)
            lo, hi = bootstrap_ci(diff, np.mean, resamples, seed)
            row.update(
                {
                    f"diff_vs_{reference}": float(np.mean(diff)) if len(diff) else float("nan"),
                    "diff_ci_low": lo,
                    "diff_ci_high": hi,
                }
            )
        row["no_disturbance_n"] = int(g["no_disturbance"].sum())
        out.append(row)
    return pd.DataFrame(out)


def done_keys(rows: Iterable[dict[str, str]]) -> set[tuple[str, ...]]:
    """The keys of finished episodes."""
    return {tuple(r[k] for k in KEY_COLUMNS) for r in rows}


def format_table(summary: pd.DataFrame, metric: str, columns: Sequence[str] | None = None) -> str:
    """A compact markdown table of a summary (for the console and the README)."""
    cols = columns or [
        "controller",
        "disturbance",
        "level",
        "n",
        f"{metric}_mean",
        "mean_ci_low",
        "mean_ci_high",
        f"{metric}_iqm",
        "failure_rate",
        "time_err_rms_mean",
        "speed_ratio_err_mean",
    ]
    cols = [c for c in cols if c in summary.columns] + [
        c for c in summary.columns if c.startswith("diff")
    ]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, r in summary.iterrows():
        cells = [f"{r[c]:.3g}" if isinstance(r[c], float) else str(r[c]) for c in cols]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def headline_table(summary: pd.DataFrame, metric: str) -> str:
    """Markdown: the mean of ``metric`` per condition (rows: "undisturbed", then each
    disturbance × level) and controller (columns, trained entrants by their run folder's
    name), the lowest of each row in bold — the table ``make run`` ends with."""
    df = summary.copy()
    df["condition"] = [
        "undisturbed" if d == "none" else f"{d} {float(lv):g}"
        for d, lv in zip(df["disturbance"], df["level"], strict=True)
    ]
    table = df.pivot_table(
        index="condition", columns="controller", values=f"{metric}_mean", sort=False
    )
    controllers = list(dict.fromkeys(df["controller"]))
    rows = sorted(table.index, key=lambda c: c != "undisturbed")  # stable: the rest in order
    idle = _idle_notes(df)
    lines = [
        "| condition | " + " | ".join(label(c) for c in controllers) + " |",
        "|---|" + "---:|" * len(controllers),
    ]
    for condition, row in table.loc[rows].iterrows():
        best = row[controllers].min()
        cells = [
            "" if pd.isna(row[c]) else (f"**{row[c]:.2e}**" if row[c] == best else f"{row[c]:.2e}")
            for c in controllers
        ]
        mark = " †" if condition in idle else ""
        lines.append(f"| {condition}{mark} | " + " | ".join(cells) + " |")
    if idle:
        lines += ["", *(f"† {condition}: {note}" for condition, note in idle.items())]
    return "\n".join(lines)


def headline_tables(summary: pd.DataFrame, metric: str) -> str:
    """:func:`headline_table` of ``metric`` and, where the summary has it, of the other
    metric a report states beside it (path distance ↔ time-indexed error), each titled."""
    columns = [c.removesuffix("_mean") for c in summary.columns if c.endswith("_mean")]
    return "\n\n".join(
        f"Mean {words(m)} ({m}, rad; bold: lowest)\n\n" + headline_table(summary, m)
        for m in report_metrics(metric, columns)
    )


def _idle_notes(summary: pd.DataFrame) -> dict[str, str]:
    """The conditions of a summary in which some episodes saw no disturbance (its
    ``no_disturbance_n``; none for a summary made before that column), each with a note:
    ``"3 of 5 episodes saw no disturbance (no work done): not compared"``."""
    if "no_disturbance_n" not in summary.columns:
        return {}
    out = {}
    for (dist, level), g in summary.groupby(["disturbance", "level"], sort=True):
        idle = int(g["no_disturbance_n"].max())
        if dist != "none" and idle > 0:
            n = int(g["n"].max()) if "n" in g.columns else idle
            out[f"{dist} {float(level):g}"] = (
                f"{idle} of {n} episodes saw no disturbance (no work done): not compared"
            )
    return out
