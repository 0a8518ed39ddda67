"""The gains a study's rows ran at, recorded in its ``config.yml``, and what a resume does
when they have changed since (a controller tuned again, other defaults).

A record is robot → controller → every rate the controller runs with there
(:func:`agents.registry.effective_rates`: the generic defaults, the robot's, the tuned
file's or the given ones). :func:`check_resume` compares a saved record with today's: a
changed pair is refused by name, or — ``rerun_changed`` — its rows are dropped from the
results file so that the resume runs them again, every other row kept. Learned entrants
(``sb3:<run folder>``) have no rates here and their rows are never dropped (a residual
pins every numeric rate of its base in its own ``config.yml``, ``derived.base_rates``; an
older run takes today's, with a warning: :func:`train.evaluation.envs.trained_wrapper_kwargs`).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from agents.registry import CONTROLLER_NAMES, effective_rates, entry
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots import ROBOTS
from train.common.arguments import RATES_KEY  # the key of config.yml that holds the record
from train.common.runs import (
    CONFIG_FILE,
    RunFolder,
    check_saved_settings,
    has_results,
    open_run,
    write_atomic,
)
from train.evaluation.results import read_episodes

#: robot → controller → rate → value.
Record = dict[str, dict[str, dict[str, Any]]]
#: The key of a controller's record that holds its builder's revision (absent: the first).
GAIN_RULES_KEY = "gain_rules"


def rate_record(
    robots: Iterable[str],
    controllers: Iterable[str],
    gains: Any,
    given: Mapping[str, Mapping[str, Any]] | None = None,
) -> Record:
    """robot → controller → its rates at ``gains`` ("default", "tuned" or a mapping), with
    ``given[controller]`` over them, for every registry controller of ``controllers``
    (learned entrants skipped); with ``gain_rules`` beside them where the controller's
    builder has been revised (:class:`agents.registry.ControllerEntry`), so that a resume
    sees the change although the rates are the same."""
    names = [c for c in controllers if c in CONTROLLER_NAMES]
    own = given or {}

    def rates(robot: str, c: str) -> dict[str, Any]:
        # the rates it is built with: its own over the sweep's, then what its law fixes
        out = effective_rates(
            ROBOTS[robot], c, {**effective_rates(ROBOTS[robot], c, gains), **(own.get(c) or {})}
        )
        revision = entry(c).gain_rules
        return out if revision == 1 else {**out, GAIN_RULES_KEY: revision}

    return {robot: {c: rates(robot, c) for c in names} for robot in robots}


def changed_pairs(saved: Mapping[str, Any], now: Record) -> list[tuple[str, str]]:
    """(robot, controller) of every pair of ``now`` whose rates differ from the ``saved``
    record (a pair the record lacks counts as changed)."""
    return [
        (robot, c)
        for robot, table in now.items()
        for c, rates in table.items()
        if (saved.get(robot) or {}).get(c) != rates
    ]


def check_resume(
    out: Path,
    results: str,
    now: Record,
    *,
    rerun_changed: bool,
    settings: Mapping[str, Any],
    free: Collection[str],
    columns: Sequence[str],
    key_columns: Sequence[str],
    pair_of: Callable[[Mapping[str, str]], tuple[str, str]],
) -> None:
    """Before a resume of the run in ``out``: first the other ``settings`` (but ``free``)
    must equal the saved ones (:func:`train.common.runs.check_saved_settings`: a resume
    that is refused loses nothing); then nothing to do without results or where the saved
    record equals ``now``; else refuse, naming the changed pairs, or with ``rerun_changed``
    rewrite ``out/results`` without their rows (``pair_of(row)`` is a row's (robot,
    controller)).

    A saved ``config.yml`` without a record (a run written before records) counts every
    pair as changed: refused, or with ``rerun_changed`` every registry controller's rows run
    again. A results file with no rows is not checked.

    Raises:
        InvalidConfigError: other settings, a changed pair without ``rerun_changed``, or a
            saved ``config.yml`` that records no rates without ``rerun_changed``.
    """
    check_saved_settings(out, results, settings, (*free, RATES_KEY))
    episodes, saved_file = out / results, out / CONFIG_FILE
    if not (has_results(episodes) and saved_file.exists()):
        return
    rows = read_episodes(episodes, columns, key_columns)
    if not rows:  # a header alone: nothing ran at any gains
        return
    saved = yaml.safe_load(saved_file.read_text()) or {}
    if RATES_KEY not in saved and not rerun_changed:
        raise InvalidConfigError(
            f"{saved_file} records no rates (a run written before they were recorded): its "
            "rows cannot be checked against today's gains; --rerun-changed runs every "
            "model-based controller's rows again (learned entrants' rows are kept), --force "
            "starts over"
        )
    changed = changed_pairs(saved.get(RATES_KEY) or {}, now)  # no record: every pair
    if not changed:
        return
    named = ", ".join(f"{c} on {r}" for r, c in changed)
    if not rerun_changed:
        raise InvalidConfigError(
            f"the gains of {named} changed since {out} ran them (agents/tuned or the "
            "defaults): --rerun-changed drops those rows and runs them again"
        )
    drop = set(changed)
    kept = [r for r in rows if pair_of(r) not in drop]
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=list(columns), lineterminator="\n")
    writer.writeheader()
    writer.writerows(kept)
    write_atomic(episodes, text.getvalue())
    print(f"--rerun-changed: dropped {len(rows) - len(kept)} rows of {named}", flush=True)


def open_recorded_run(
    out: str | Path,
    results: str,
    settings: Mapping[str, Any],
    record: Record,
    *,
    resume: bool,
    force: bool,
    rerun_changed: bool,
    free: Collection[str],
    columns: Sequence[str],
    key_columns: Sequence[str],
    pair_of: Callable[[Mapping[str, str]], tuple[str, str]],
) -> RunFolder:
    """:func:`train.common.runs.open_run` for a study whose ``config.yml`` also records
    ``record`` (the rates its rows run at): on resume (not ``force``) first
    :func:`check_resume` — other settings, then changed gains refused or, with
    ``rerun_changed``, their rows dropped — then the folder opened with the record written.

    Raises:
        InvalidConfigError: ``rerun_changed`` without ``resume``, or as :func:`check_resume`
            and :func:`train.common.runs.open_run`.
    """
    settings = {**settings, RATES_KEY: record}
    if rerun_changed and not resume:
        raise InvalidConfigError("--rerun-changed acts on a resume: add --resume")
    if resume and not force:
        check_resume(
            Path(out), results, record, rerun_changed=rerun_changed, settings=settings,
            free=free, columns=columns, key_columns=key_columns, pair_of=pair_of,
        )  # fmt: skip
    return open_run(out, results, settings, resume=resume, force=force, free=(*free, RATES_KEY))
