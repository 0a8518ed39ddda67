"""Learned entrants in the verdict (:mod:`train.studies.verdict_study`): trained runs
(``sb3:<run folder>``) judged on the verdict's test paths beside the model-based
controllers — paths they never trained or were evaluated on during training.

An entrant runs at its own control rate and in its own observation (plain or preview),
with the disturbance draws of the same (path, seed) as every controller, so it is paired with
them like any controller. Each is compared with its **reference** — the base controller of a
residual, the controller a pure policy imitated, else PD + gravity — by the exact paired
sign-flip test over the (path, seed) pairs (:func:`train.common.paired_tests.
paired_comparisons`), Holm's step-down over one robot, one metric and one reference (every
entrant of that reference in every condition). The entrants are not rivals in the
passivity controller's verdict: that one compares the model-based laws.

Refused before any episode: an entrant that is not ``sb3:``, a run of another robot, a run
whose training or evaluation paths include a test path, a residual whose base ran with other
gains than the verdict's (a pure policy that imitated a controller: its expert's gains), a
reference that is not among the verdict's controllers — which refuses a residual over a
network base, whose reference is another run (``sb3:…``), not a controller — and a run at
another control rate than the verdict's (a residual's base and its reference would then
differ in rate as well as in the residual).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from agents.registry import still_pinned
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots import ROBOTS
from train.common.paired_tests import TooFewPairsError, paired_comparisons
from train.common.statistics import iqm
from train.evaluation.verdict import BOTH_METRICS, condition_name, words

#: What a pure policy that imitated nothing is compared with.
PURE_REFERENCE = "pd_gravity"


def _run(name: str) -> dict[str, Any]:
    """The whole ``config.yml`` of entrant ``name`` (``config``, ``derived``, ...)."""
    from train.evaluation.policies import run_config, sb3_files

    return dict(run_config(sb3_files(name)[0]))


def _run_config(name: str) -> dict[str, Any]:
    return dict(_run(name)["config"])


def entrant_reference(name: str) -> str:
    """The controller entrant ``name`` (``sb3:<run>``) is compared with: a residual's base
    (a network base: its model), a pure policy's imitated controller, else PD + gravity."""
    c = _run_config(name)
    base = str(c["residual"])
    if base == "network":
        return f"sb3:{c['base_model']}"
    if base != "none":
        return base
    return str(c.get("imitate") or PURE_REFERENCE)


def check_entrants(
    entrants: Mapping[str, Sequence[str]],
    robots: Sequence[str],
    controllers: Sequence[str],
    test_paths: Sequence[int],
    gains: str,
    control_hz: float | None = None,
) -> None:
    """Raise :class:`InvalidConfigError` for a bad entrant (module docstring); with
    ``control_hz``, also one that runs at another rate than the verdict's controllers."""
    from train.evaluation.policies import SB3_PREFIX, check_sb3_run

    if not isinstance(entrants, Mapping):
        raise InvalidConfigError(f"entrants must map robots to sb3:<run> lists, got {entrants!r}")
    for robot, names in entrants.items():
        if robot not in robots:
            raise InvalidConfigError(f"entrants: {robot!r} is not one of the robots {robots}")
        if not isinstance(names, list) or len(set(map(str, names))) != len(names):
            raise InvalidConfigError(
                f"entrants of {robot}: a list of distinct names, got {names!r}"
            )
        for name in names:
            if not (isinstance(name, str) and name.startswith(SB3_PREFIX)):
                raise InvalidConfigError(f"entrants of {robot}: {name!r} is not sb3:<run folder>")
            check_sb3_run(name, ROBOTS[robot].env_id)
            run = _run(name)
            c = run["config"]
            seen = {int(p) for key in ("train_paths", "eval_paths") for p in c.get(key) or []}
            shared = sorted(seen & set(test_paths))
            if shared:
                raise InvalidConfigError(
                    f"{name} trained or was evaluated on paths {shared}, test paths here: an "
                    "entrant is judged on paths it never saw"
                )
            if c["residual"] not in ("none", "network"):
                own, what = c.get("base_gains", "default"), "base ran"
            elif c["residual"] == "none" and c.get("imitate"):
                own, what = c.get("imitate_gains", "default"), "expert ran"
            else:
                own, what = gains, ""
            if own != gains:
                raise InvalidConfigError(
                    f"{name}'s {what} with {own} gains, the verdict's controllers with "
                    f"{gains}: compare an entrant with the controller it was built on"
                )
            residual = c["residual"] not in ("none", "network")
            pinned = (run.get("derived") or {}).get("base_rates") if residual else None
            if pinned and not still_pinned(ROBOTS[robot], c["residual"], gains, pinned):
                raise InvalidConfigError(
                    f"{name}'s base ran at {gains} rates since changed ({pinned}); the "
                    f"verdict's {c['residual']} runs today's: compare an entrant with the "
                    "controller it was built on"
                )
            own_hz = float((run.get("derived") or {}).get("control_hz") or 0.0)
            if control_hz is not None and own_hz and abs(own_hz - control_hz) > 1e-9:
                raise InvalidConfigError(
                    f"{name} runs at {own_hz:g} Hz, the verdict's controllers at "
                    f"{control_hz:g} Hz: its comparison with its reference would measure the "
                    f"rate as well; set control_hz: {own_hz:g}"
                )
            reference = entrant_reference(name)
            if reference not in controllers:
                raise InvalidConfigError(
                    f"{name} is compared with {reference}, which is not among the controllers"
                )


def entrant_comparisons(
    entrants: Mapping[str, Sequence[str]], df: pd.DataFrame, resamples: int
) -> pd.DataFrame:
    """Per robot, metric and reference: each of its entrants against it in every condition
    (``paired_comparisons``; pairs (path, seed, episode)); a ``robot`` and a ``reference``
    column added. Empty when no entrant has two pairs yet."""
    parts = []
    for robot, names in entrants.items():
        by_reference: dict[str, list[str]] = {}
        for name in names:
            by_reference.setdefault(entrant_reference(name), []).append(name)
        for reference, group in by_reference.items():
            sub = df[(df["robot"] == robot) & df["controller"].isin([reference, *group])]
            if not set(group) & set(sub["controller"]) or reference not in set(sub["controller"]):
                continue
            for metric in BOTH_METRICS:
                try:
                    table = paired_comparisons(sub, metric, reference, resamples=resamples)
                except TooFewPairsError:  # a partial run
                    continue
                parts.append(table.assign(robot=robot, reference=reference))
    if not parts:
        return pd.DataFrame()
    out = pd.concat(parts, ignore_index=True)
    return out[["robot", "reference", *[c for c in out.columns if c not in ("robot", "reference")]]]


#: What a verdict with entrants records of each entrant's energy per episode (NaN where it
#: does not apply): its tank's deepest level below zero, J — the gate predicts the
#: residual's work on the nominal model, the plant may differ — and the energy the gate
#: held back, J (``agents.energy_tank.EnergyTank``; a tank entrant only); and, for a
#: residual over a passivity law (tank or not), the balance's largest excess over the
#: episode, J: storage + tank against their start, the pump's, re-synchronisation's and
#: disturbance's work (``agents.energy_tank.BalanceLedger``; added 2026-11-28, NaN in
#: files written before) — and the same of a passivity law run alone, T = 0
#: (:class:`EpisodeBalance`; added later on 2026-11-28, NaN in the controllers' rows of
#: files written before); then the energy the sampled law created and its tank paid
#: (``EnergyTank.created_j``, J; added 2026-11-28 with the tank's port fill, NaN before);
#: then the energy the arm gained beyond the commanded torque's work and its tank paid
#: (``EnergyTank.arm_gained_j``, J: a delayed or noisy sensor's, a disturbance's; added
#: 2026-11-28 with the arm's observer, NaN before).
TANK_COLUMNS = (
    "tank_overdrawn_j",
    "tank_withheld_j",
    "balance_excess_j",
    "tank_created_j",
    "tank_arm_gained_j",
)


def tank_record(env: Any) -> dict[str, float]:
    """:data:`TANK_COLUMNS` of the episode ``env`` just ran (its residual wrapper's tank
    and balance ledger, found through the wrappers; NaN where there is none)."""
    from agents.residual_wrapper import ResidualWrapper

    layer = env
    while layer is not None and not isinstance(layer, ResidualWrapper):
        layer = getattr(layer, "env", None)
    out = dict.fromkeys(TANK_COLUMNS, math.nan)
    if layer is None:
        return out
    out["balance_excess_j"] = float(layer.balance.excess_max_j)
    tank = layer.tank
    if tank is not None:
        out["tank_overdrawn_j"] = float(tank.overdrawn_j)
        out["tank_withheld_j"] = float(tank.withheld_j)
        out["tank_created_j"] = float(tank.created_j)
        out["tank_arm_gained_j"] = float(tank.arm_gained_j)
    return out


class EpisodeBalance:
    """The balance's largest excess of one verdict episode, whoever ran it: a residual's
    from its wrapper's ledger (:func:`tank_record`), a passivity law run alone from a
    ledger kept here (``BalanceLedger`` with T = 0: the law's own storage against its pump,
    re-synchronisation and the disturbance's work) — so the base's own excess under a
    plant or sensor other than its model stands beside its residuals' (issue 39).

    One per episode: pass :meth:`on_step` to ``run_episode`` as ``on_step`` and
    :meth:`inspect` as ``inspect``."""

    def __init__(self) -> None:
        from agents.energy_tank import BalanceLedger

        self.ledger = BalanceLedger()
        self._storage: bool | None = None  # whether the policy's law has one (first step)

    def on_step(self, env: Any, policy: Any, info: dict[str, Any] | None) -> None:
        """Record the step a controller policy (:class:`agents.policy.ControllerPolicy`)
        just took, where its law has a storage (``agents.energy_tank.has_storage``);
        ``info=None``: it diverged (+inf for a law with a storage, even at its first
        step)."""
        from agents.energy_tank import has_storage
        from agents.policy import ControllerPolicy

        if not isinstance(policy, ControllerPolicy):
            return
        if self._storage is None:
            self._storage = has_storage(policy.last_diagnostics)
        if not self._storage:
            return
        if info is None:
            self.ledger.diverged(storage=True)
            return
        work_j = float(info.get("disturbance_work_j", 0.0))
        self.ledger.record(policy.last_diagnostics, 0.0, work_j, float(env.unwrapped.dt))

    def inspect(self, env: Any) -> dict[str, float]:
        """:data:`TANK_COLUMNS` of the episode: the residual wrapper's (:func:`tank_record`),
        or the controller's own balance where it kept one."""
        out = tank_record(env)
        if math.isnan(out["balance_excess_j"]):
            out["balance_excess_j"] = float(self.ledger.excess_max_j)
        return out


def balance_markdown(df: pd.DataFrame) -> str:
    """Markdown: per robot, group of seeds (:func:`entrant_group`) and condition of the
    residuals over a passivity law and of the passivity laws run alone, the balance's
    largest excess per episode (:data:`TANK_COLUMNS`): its median and maximum over the
    episodes (J)."""
    if "balance_excess_j" not in df.columns:
        return ""
    kept = df[df["balance_excess_j"].notna()]
    if kept.empty:
        return ""
    kept = kept.assign(group=kept["controller"].map(entrant_group))
    lines = [
        "| robot | group | condition | episodes | median excess (J) | largest excess (J) |",
        "|---|---|---|---:|---:|---:|",
    ]
    for (robot, group, dist, level), g in kept.groupby(
        ["robot", "group", "disturbance", "level"], sort=True
    ):
        x = g["balance_excess_j"]
        lines.append(
            f"| {robot} | {group} | {condition_name(dist, level)} | {len(g)} | {x.median():.3g} "
            f"| {x.max():.3g} |"
        )
    return "\n".join(lines)


def tank_markdown(df: pd.DataFrame) -> str:
    """Markdown: per robot and tank entrant, in how many of its episodes the tank went below
    zero, the deepest overdraw, the median energy withheld, the energy the sampled law
    created and the energy the arm gained beyond the commanded torque's work, both of which
    the tank paid (median and largest; "–" in files written before)."""
    if "tank_overdrawn_j" not in df.columns:
        return ""
    tanked = df[df["tank_overdrawn_j"].notna()]
    if tanked.empty:
        return ""
    lines = [
        "| robot | entrant | episodes | tank overdrawn in | deepest overdraw (J) "
        "| median withheld (J) | law created, median (J) | law created, largest (J) "
        "| arm gained, median (J) | arm gained, largest (J) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]

    def spread(g: pd.DataFrame, column: str) -> str:
        x = g[column] if column in g else pd.Series(dtype=float)
        return f"{x.median():.3g} | {x.max():.3g}" if x.notna().any() else "– | –"

    for (robot, name), g in tanked.groupby(["robot", "controller"], sort=True):
        over = g["tank_overdrawn_j"] > 0.0
        lines.append(
            f"| {robot} | {name} | {len(g)} | {int(over.sum())} | "
            f"{g['tank_overdrawn_j'].max():.3g} | {g['tank_withheld_j'].median():.3g} | "
            f"{spread(g, 'tank_created_j')} | {spread(g, 'tank_arm_gained_j')} |"
        )
    return "\n".join(lines)


def entrants_markdown(table: pd.DataFrame) -> str:
    """Markdown: per robot, each entrant against its reference in every condition, both
    metrics (ratio of means, Holm-adjusted p, mark)."""
    if not len(table):
        return "No entrant has two pairs with its reference yet."
    lines = [
        "| robot | entrant | reference | condition | metric | entrant / reference | p (Holm) "
        "| mark | pairs |",
        "|---|---|---|---|---|---:|---:|---|---:|",
    ]
    for _, r in table.iterrows():
        lines.append(
            f"| {r['robot']} | {r['controller']} | {r['reference']} | "
            f"{condition_name(r['disturbance'], float(r['level']))} | {words(r['metric'])} | "
            f"{r['ratio']:.3g} | {r['p_holm']:.3g} | {r['mark']} | {int(r['pairs'])} |"
        )
    return "\n".join(lines)


def entrant_group(name: str) -> str:
    """The group of entrant ``name`` — its run folder's name without the ``_s<seed>``
    suffix a campaign gives it (``sb3:runs/x/residual-passivity_s3`` → ``residual-passivity``)."""
    folder = name.removeprefix("sb3:").partition("@")[0].rstrip("/").rsplit("/", 1)[-1]
    return re.sub(r"_s\d+$", "", folder)


def seed_groups(table: pd.DataFrame, df: pd.DataFrame) -> pd.DataFrame:
    """Per robot, reference, group of seeds (:func:`entrant_group`), condition and metric:
    the seeds, the IQM over seeds of each seed's entrant / reference ratio of means (and
    its range), how many seeds were resolved better or worse than the reference (Holm
    marks of ``table``, :func:`entrant_comparisons`) and the group's failed episodes
    (issue 39: "the spread over seeds ... and the IQM over seeds")."""
    if not len(table):
        return pd.DataFrame()
    t = table.assign(group=table["controller"].map(entrant_group))
    failed = df.groupby(["robot", "controller", "disturbance", "level"])["failed"].sum()
    rows = []
    keys = ["robot", "reference", "group", "disturbance", "level", "metric"]
    for key, g in t.groupby(keys, sort=False):
        ratios = g["ratio"].to_numpy(dtype=float)
        robot, _, _, dist, level, _ = key
        fails = sum(int(failed.get((robot, c, dist, level), 0)) for c in g["controller"])
        rows.append({
            **dict(zip(keys, key, strict=True)), "seeds": len(g),
            "iqm_ratio": float(iqm(ratios)), "min_ratio": float(ratios.min()),
            "max_ratio": float(ratios.max()), "better": int((g["mark"] == "better").sum()),
            "worse": int((g["mark"] == "worse").sum()), "failed": fails,
        })  # fmt: skip
    return pd.DataFrame(rows)


def representative_seed(table: pd.DataFrame, group: str, metric: str = "path_dist_rms") -> str:
    """The entrant of ``group`` shipped as its model: the seed whose geometric mean of the
    ``metric`` ratios over every condition is the median of the group's (the lower median
    for an even count) — a typical seed, not the best."""
    t = table[(table["controller"].map(entrant_group) == group) & (table["metric"] == metric)]
    score = t.groupby("controller")["ratio"].apply(lambda r: float(np.exp(np.log(r).mean())))
    ordered = score.sort_values(kind="stable")
    return str(ordered.index[(len(ordered) - 1) // 2])


def seed_groups_markdown(groups: pd.DataFrame) -> str:
    """Markdown of :func:`seed_groups`."""
    if not len(groups):
        return ""
    lines = [
        "| robot | group | reference | condition | metric | seeds | IQM of ratios "
        "| range | better / worse (seeds) | failed episodes |",
        "|---|---|---|---|---|---:|---:|---|---|---:|",
    ]
    for _, r in groups.iterrows():
        lines.append(
            f"| {r['robot']} | {r['group']} | {r['reference']} | "
            f"{condition_name(r['disturbance'], float(r['level']))} | {words(r['metric'])} | "
            f"{int(r['seeds'])} | {r['iqm_ratio']:.3g} | {r['min_ratio']:.3g}–"
            f"{r['max_ratio']:.3g} | {int(r['better'])} / {int(r['worse'])} | "
            f"{int(r['failed'])} |"
        )
    return "\n".join(lines)


def entrants_section(
    entrants: Mapping[str, Sequence[str]], df: pd.DataFrame, resamples: int, out: Path
) -> list[str]:
    """The verdict report's lines on its learned entrants — over the seeds of each group,
    each seed against its reference, what each trained on, their energy tanks — writing
    ``entrants.csv`` and ``entrant_groups.csv`` into ``out``."""
    from train.evaluation.protocol import protocol_markdown

    table = entrant_comparisons(entrants, df, resamples)
    table.to_csv(out / "entrants.csv", index=False, float_format="%.6g")
    groups = seed_groups(table, df)
    groups.to_csv(out / "entrant_groups.csv", index=False, float_format="%.6g")
    lines = ["", "## Learned entrants on the test paths", ""]
    if len(groups):
        names = sorted(set(map(entrant_group, table["controller"])))
        typical = ", ".join(f"{g}: {representative_seed(table, g)}" for g in names)
        lines += [
            "Over the seeds of each group (every seed's final model, none selected): "
            "the IQM over seeds of each seed's entrant / reference ratio of means, its "
            "range, and in how many seeds the exact paired test (below) resolved the "
            "entrant better or worse than its reference; `entrant_groups.csv`.", "",
            seed_groups_markdown(groups), "",
            f"A typical seed of each group (median geometric-mean ratio on path "
            f"distance over the conditions; the one a model card ships): {typical}.", "",
        ]  # fmt: skip
    lines += [
        "Each seed against its reference (a residual's base, else PD + gravity or the "
        "controller it imitated): exact paired sign-flip tests over the (path, seed) "
        "pairs, Holm over one robot, metric and reference; `entrants.csv`.", "",
        entrants_markdown(table), "", "What each entrant trained on (the test paths "
        "above are none of its training or evaluation paths):", "",
        protocol_markdown([n for names in entrants.values() for n in names]),
    ]  # fmt: skip
    balance = balance_markdown(df)
    if balance:
        alone = df["balance_excess_j"].notna() & ~df["controller"].str.startswith("sb3:")
        beside = (
            ", beside the passivity laws' own run alone (tank 0): what a plant or sensor "
            "other than the law's model adds without any residual"
            if alone.any()
            else ""
        )
        lines += [
            "", "The storage balance of the residuals over a passivity law (the largest "
            "excess of storage + tank over their start, the pump's, re-synchronisation's "
            "and disturbance's work in each episode; ≤ the discrete residue on the exact "
            "closed loop with a tank, `../shared/TANK.md`; the law's own storage, on its "
            f"model and its measured state){beside}:", "", balance,
        ]  # fmt: skip
    tanks = tank_markdown(df)
    if tanks:
        lines += [
            "", "The energy tanks (a tank entrant's residual spends only what its tank "
            "holds, `../shared/TANK.md`; the tank is filled with what the law dissipated "
            "at its sampled port and pays what the sampled law created and what the arm "
            "gained beyond the commanded torque's work, as the law measures it — a "
            "disturbance's, a delayed or noisy sensor's; the gate predicts the residual's "
            "work on the nominal model, so an overdraw is where the plant differed or the "
            "tank paid more than it held):", "", tanks,
        ]  # fmt: skip
    return lines
