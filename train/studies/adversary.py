"""Worst case, not only the average: an adversarial disturbance search (``ptrack adversary``).

For every controller × disturbance family × energy, ``budget`` parameter sets are drawn at
random (Optuna's random sampler, seeded), then the search maximises a declared cost over the
family's parameters with Optuna's CMA-ES sampler (seeded, warm-started from the worst random
draws: WS-CMA-ES), for another ``budget`` episodes:

* cost — the path-distance RMS (rad) over the ``post_s`` seconds after the disturbance ends
  (a periodic torque acts all along: the last ``post_s`` seconds of the run); an episode that
  goes unstable counts as ``failure_distance_rad`` over the whole window;
* families and their parameters (n joints) — ``impulse``: onset (s) and a direction in
  joint-velocity space (n coordinates in [−1, 1], normalised); ``push``: onset, a world
  direction (3 coordinates) and, with several ``push_links``, the link; ``periodic``:
  frequency (log-uniform in ``frequency_hz``) and a direction (n coordinates) weighing the
  joints' amplitudes;
* every episode starts on the path from the same reset seed (``reset_seed``), so a found
  worst case is a disturbance spec that replays bit-identically (``replay``);
* the energy is the family's ``energy_j`` (an impulse or push sized for the arm at rest at
  home, a periodic torque over the run) with ``energy_mode``; the work the disturbance
  really does on the moving arm is recorded for every episode and reported beside it.

A periodic torque may first be scanned in frequency (``scan_points``: one episode per joint
at each frequency, the worst direction predicted from their superposition and verified,
:mod:`train.studies.periodic_scan`): its resonances are narrow in frequency × direction.
Last, ``polish_starts`` local CMA-ES runs of ``polish_budget`` episodes per seed, with a
small step (``polish_sigma``): the global runs' large steps jump past narrow peaks (a push's
phase and direction, a periodic torque's resonance). The first starts at the seed's worst
episode so far; each further one at the worst random draw in a basin no local run before it
started in or reached (a multistart local search: the global runs, warm-started from the
seed's best episodes, settle in the basin the random draws found first). Each start is kept
on its study, so a resume continues from it.

The same budget (``budget`` searched + ``budget`` random episodes, + ``polish_starts`` ×
``polish_budget``, + a scan's) for
every controller.
Writes to ``--out``: ``optuna.journal`` (the studies: ``--resume`` continues them),
``trials.csv``, ``worst.yml`` (the worst spec per controller × family × energy and how to
replay it), ``summary.md`` and ``adversary.png``. Episodes run in ``workers`` processes (a
CMA-ES generation, or a batch of random draws, at a time). Needs the ``tune`` extra
(Optuna, cmaes).
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import yaml

import ptrack_gym  # noqa: F401  (registers the envs)
from agents import passivity
from ptrack_gym.errors import InvalidConfigError
from train.common.arguments import RAN_AT_KEY
from train.common.runs import open_run, worker_count, worker_pool
from train.plots.studies import adversary_plot
from train.studies.adversary_config import FAMILIES, AdversaryConfig, load_config
from train.studies.adversary_summary import (
    BOUND_MARGIN,
    WORST_CHECKED,
    on_bound,
    summary_frame,
    summary_table,
)
from train.studies.periodic_scan import SCAN_STREAM, run_scan
from train.studies.worst_case import (
    Outcome,
    Searchable,
    check_targets,
    controller_gains,
    evaluate_task,
    replay,
    replay_all,
)

__all__ = [
    "FAMILIES",
    "AdversaryConfig",
    "Outcome",
    "load_config",
    "replay",
    "replay_all",
    "run_search",
]


def study_name(controller: str, family: str, energy_j: float, kind: str, seed: int) -> str:
    """``<controller>|<family>|<energy>|<kind>|seed<k>``, kind "random", "search<r>" (the
    r-th CMA-ES run, r restarts in), "polish" (the local run) or "polish<k>" (the k-th
    further local run, from another basin)."""
    return f"{controller}|{family}|{energy_j:g}|{kind}|seed{seed}"


def kinds(cfg: AdversaryConfig, family: str) -> list[str]:
    """The studies of one seed, in the order they run: the random draws, a periodic
    torque's frequency scan (where ``scan_points`` > 0), each global CMA-ES run, then the
    local ones (``polish_starts`` of them, where ``polish_budget`` > 0)."""
    scan = ["scan"] if cfg.scan_points > 0 and family == "periodic" else []
    local = ["polish", *(f"polish{k}" for k in range(1, cfg.polish_starts))]
    local = local if cfg.polish_budget > 0 else []
    return ["random", *scan, *(f"search{r}" for r in range(cfg.restarts + 1)), *local]


def run_budget(cfg: AdversaryConfig, kind: str, n: int = 0) -> int:
    """Episodes of one study: ``budget`` random ones; the searched ``budget`` split over the
    CMA-ES runs (the remainder to the last); a scan's scan_points·n + scan_top, its
    refinement's scan_refine·n·scan_top, and (scan_phases·n + 1 + scan_phase_refine·n)·
    scan_phase_top for its second stage (n joints)."""
    if kind == "random":
        return cfg.budget
    if kind.startswith("polish"):
        return cfg.polish_budget
    if kind == "scan":
        per_stage = cfg.scan_phases * n + 1 + cfg.scan_phase_refine * n
        second = per_stage * cfg.scan_phase_top if cfg.scan_phases else 0
        refine = cfg.scan_refine * n * cfg.scan_top
        return cfg.scan_points * n + cfg.scan_top + refine + second
    runs, r = cfg.restarts + 1, int(kind.removeprefix("search"))
    share = cfg.budget // runs
    return share + (cfg.budget - share * runs if r == runs - 1 else 0)


#: What a search's settings were before its ``config.yml`` recorded them (compared on resume).
SETTINGS_BEFORE = {
    "space": "box", "restarts": 0, "scan_points": 0, "scan_phases": 0, "scan_refine": 0,
    "scan_phase_top": 1, "scan_phase_refine": 0, "rates": {}, "polish_starts": 1,
}  # fmt: skip


def run_search(
    cfg: AdversaryConfig, resume: bool = False, progress: bool = True, force: bool = False
) -> Path:
    """Run (or continue) every study of ``cfg``; write the results; return the folder."""
    try:
        import optuna
        from optuna.storages import JournalStorage
        from optuna.storages.journal import JournalFileBackend
    except ImportError as exc:
        raise InvalidConfigError(
            "the adversarial search needs the 'tune' extra: pip install 'ptrack_gym[tune]'"
        ) from exc
    cfg.validate()
    check_targets(cfg)
    # the rates every controller's episodes run, recorded: a resume after a retune or a new
    # default (its earlier trials ran other gains) is refused as any other changed setting
    ran_at = {c: controller_gains(cfg, c) for c in cfg.controllers}
    run = open_run(
        cfg.out, "optuna.journal", {**_config_dict(cfg), RAN_AT_KEY: ran_at},
        resume=resume, force=force,
        # a resume may extend the budget (each run grows) or add or extend the local runs
        free=("workers", "out", "budget", "polish_budget", "polish_starts"),
        saved_required=False,
        defaults=SETTINGS_BEFORE,  # a search saved before a setting existed ran with these
    )  # fmt: skip
    out, journal = run.out, run.results
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = JournalStorage(JournalFileBackend(str(journal)))
    # spawned: no simulator client or thread is inherited
    with worker_pool(worker_count(cfg.workers), "spawn") as pool:
        ctx = _Context(optuna, storage, pool, cfg, progress)
        for controller in cfg.controllers:
            for family in cfg.families:
                for energy in cfg.energies_j:
                    target = Searchable(cfg, family, energy)
                    for seed in cfg.search_seeds:
                        for kind in kinds(cfg, family):  # each starts from all run before
                            runner = _run_scan if kind == "scan" else _run_study
                            runner(ctx, controller, target, kind, seed)
    _write_results(optuna, storage, cfg, out)
    return out


class _Context(NamedTuple):
    """What every study of a search runs with."""

    optuna: Any
    storage: Any
    pool: ProcessPoolExecutor
    cfg: AdversaryConfig
    progress: bool


def _run_study(ctx: _Context, controller: str, target: Searchable, kind: str, seed: int) -> None:
    optuna, storage, pool, cfg, progress = ctx
    name = study_name(controller, target.family, target.energy_j, kind, seed)
    budget = run_budget(cfg, kind)
    source: list[Any] = []
    start: dict[str, Any] | None = None  # where a searched run starts (its first episode)
    if kind != "random":
        # Warm-started CMA-ES (WS-CMA-ES): its initial distribution comes from the best of
        # the episodes this seed ran before (the random draws, then each earlier run).
        # Failure regions can be small and far from the centre of the box, where a search
        # started at the centre settles (seen: 0/200 searched vs 14/200 random draws
        # unstable for the passivity controller at 2 J on the iiwa). Each restart doubles
        # the population (IPOP's schedule).
        order = kinds(cfg, target.family)
        for earlier in order[: order.index(kind)]:
            source += optuna.load_study(
                study_name=study_name(controller, target.family, target.energy_j, earlier, seed),
                storage=storage,
            ).get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
        start = _start_of(max(source, key=lambda t: t.value)) if source else None
        if kind.startswith("polish"):
            start = _stored_local_start(ctx, controller, target, kind, seed, source)
        with warnings.catch_warnings():  # source_trials is "experimental" in Optuna 4-5,
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            warnings.simplefilter("ignore", FutureWarning)  # x0 and sigma0 deprecated in 4.9
            if kind.startswith("polish"):  # local: at the start, small steps
                k = int(kind.removeprefix("polish") or 0)
                stream = (POLISH_STREAM,) if k == 0 else (POLISH_STREAM, k)
                sampler = optuna.samplers.CmaEsSampler(
                    x0=start["params"], sigma0=cfg.polish_sigma,  # type: ignore[index]
                    popsize=cfg.popsize, seed=_draw_seed(seed, *stream),
                    warn_independent_sampling=False,
                )  # fmt: skip
            else:
                r = int(kind.removeprefix("search"))
                sampler = optuna.samplers.CmaEsSampler(
                    source_trials=source, popsize=cfg.popsize * 2**r,
                    # "box" is the search before issue 38, seeded as it was: it repeats exactly
                    seed=seed if cfg.space == "box" else _draw_seed(seed, 2 + r),
                    warn_independent_sampling=False,
                )  # fmt: skip
    else:
        sampler = optuna.samplers.RandomSampler(seed=_draw_seed(seed, 0))  # reseeded per draw
    study = optuna.create_study(
        study_name=name, storage=storage, sampler=sampler, direction="maximize",
        load_if_exists=True,
    )  # fmt: skip
    Running = optuna.trial.TrialState.RUNNING
    for stale in study.get_trials(deepcopy=False, states=(Running,)):  # an interrupted batch
        study.tell(stale.number, state=optuna.trial.TrialState.FAIL)
    complete = study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
    waiting = study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.WAITING,))
    unstarted = (
        not complete and not waiting  # a local run whose first episode was cut: again
        if kind.startswith("polish")
        else not study.get_trials(deepcopy=False)  # as it always was: repeats exactly
    )
    if kind != "random" and cfg.space != "box" and unstarted and start is not None:
        # the run's first episode is its start, for a global run the worst one so far: a
        # search never ends below where it started (the worst searched >= the worst random
        # draw)
        study.enqueue_trial(start["params"])
    done = len(complete)
    wall_s = float(study.user_attrs.get("wall_s", 0.0))  # summed over batches: resume-safe
    restart = int(kind.removeprefix("search")) if kind.startswith("search") else 0
    popsize = cfg.popsize * 2**restart
    while done < budget:
        t0 = time.perf_counter()
        batch = []
        # Optuna's CMA-ES learns the search space from a completed trial of its own study: a
        # generation asked before any is told is drawn independently (at random). The local
        # run therefore runs its first episode (the worst so far) alone.
        size = 1 if kind.startswith("polish") and done == 0 else min(popsize, budget - done)
        for i in range(size):
            if kind == "random":  # the k-th draw is a function of (seed, k): resume-safe
                study.sampler = optuna.samplers.RandomSampler(seed=_draw_seed(seed, 1, done + i))
            batch.append(study.ask())
        params = [target.space(trial) for trial in batch]
        specs = [target.spec(p) for p in params]
        tasks = [
            (cfg.env_id, controller, spec, cfg.reset_seed, target.episode_s(), target.window(spec),
             cfg.control_hz, cfg.failure_distance_rad, controller_gains(cfg, controller),
             p.get("s0"))
            for spec, p in zip(specs, params, strict=True)
        ]  # fmt: skip
        outcomes = pool.map(evaluate_task, tasks)
        for trial, spec, p, outcome in zip(batch, specs, params, outcomes, strict=True):
            _tell(study, trial, spec, p, outcome)
        done += len(batch)
        wall_s += time.perf_counter() - t0
        study.set_user_attr("wall_s", wall_s)
        if progress:
            print(f"{name}: {done}/{budget}, worst {study.best_value:.3g} rad", flush=True)


def _start_of(trial: Any) -> dict[str, Any]:
    """What a run's start is kept as: the episode's parameters, spec and start phase."""
    return {"params": dict(trial.params), "spec": trial.user_attrs["spec"],
            "s0": trial.user_attrs.get("s0")}  # fmt: skip


def _stored_local_start(
    ctx: _Context, controller: str, target: Searchable, kind: str, seed: int, source: list[Any]
) -> dict[str, Any]:
    """A local run's start: chosen once, when its study has no episode, and kept on the
    study (``start``), so a resume — even one that extends the budgets, which moves the
    worst episodes the choice reads — continues from the same point. A local run saved
    before the start was kept started from its first episode."""
    optuna, storage, _, cfg, _ = ctx
    optuna_study = optuna.create_study(
        study_name=study_name(controller, target.family, target.energy_j, kind, seed),
        storage=storage, direction="maximize", load_if_exists=True,
    )  # fmt: skip
    if "start" in optuna_study.user_attrs:
        return dict(optuna_study.user_attrs["start"])
    ran = optuna_study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
    if ran:  # before the start was kept (period space: its first episode is its start)
        start = _start_of(ran[0])
    else:
        order = kinds(cfg, target.family)
        earlier = order[: order.index(kind)]
        load = lambda k: optuna.load_study(  # noqa: E731
            study_name=study_name(controller, target.family, target.energy_j, k, seed),
            storage=storage,
        )
        random = load("random").get_trials(
            deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,)
        )
        local = [(_stored_local_start(ctx, controller, target, k, seed, source), load(k))
                 for k in earlier if k.startswith("polish")]  # fmt: skip
        anchors = [a for first, study in local for a in (first, _best_start(study))]
        start = local_start(target, source, random, [a for a in anchors if a is not None])
    optuna_study.set_user_attr("start", start)
    return start


def _best_start(study: Any) -> dict[str, Any] | None:
    """The start record of a study's worst episode (None when it ran none)."""
    try:
        return _start_of(study.best_trial)
    except ValueError:  # no completed trial
        return None


def local_start(
    target: Searchable,
    source: Sequence[Any],
    random: Sequence[Any],
    anchors: Sequence[dict[str, Any]],
) -> dict[str, Any]:
    """Where a local run starts. The first (no ``anchors``): at the worst episode of the
    seed so far (``source``). Each further one: at the worst of the seed's random draws
    (``random``) in a basin where no earlier local run started or found its worst
    (``anchors``: their start records; :meth:`~train.studies.worst_case.Searchable.same_basin`)
    — the random draws, not the global runs' episodes, which crowd around the basin those
    settled in; where every draw lies in such a basin, at the worst draw no local run has
    started from."""
    if not anchors:
        return _start_of(max(source, key=lambda t: t.value))
    ranked = sorted(random, key=lambda t: t.value, reverse=True)
    for trial in ranked:
        a = trial.user_attrs
        if not any(target.same_basin(a["spec"], a.get("s0"), b["spec"], b["s0"]) for b in anchors):
            return _start_of(trial)
    used = [b["params"] for b in anchors]
    return _start_of(next(t for t in ranked if dict(t.params) not in used))


def _tell(
    study: Any, trial: Any, spec: dict[str, Any], params: dict[str, Any], outcome: Outcome
) -> None:
    """Record an episode's outcome, spec and start phase on its trial, and tell its cost."""
    for key, value in dataclasses.asdict(outcome).items():
        trial.set_user_attr(key, value)
    trial.set_user_attr("spec", spec)
    if params.get("s0") is not None:
        trial.set_user_attr("s0", float(params["s0"]))
    study.tell(trial, outcome.cost)


def _run_scan(ctx: _Context, controller: str, target: Searchable, kind: str, seed: int) -> None:
    """A periodic torque's frequency scan for search seed ``seed``
    (:func:`train.studies.periodic_scan.run_scan`), from a start phase of the seed's own
    stream."""
    optuna, storage, pool, cfg, progress = ctx
    name = study_name(controller, target.family, target.energy_j, kind, seed)
    study = optuna.create_study(
        study_name=name, storage=storage, direction="maximize", load_if_exists=True,
        sampler=optuna.samplers.RandomSampler(seed=_draw_seed(seed, SCAN_STREAM)),
    )  # fmt: skip
    Running = optuna.trial.TrialState.RUNNING
    for stale in study.get_trials(deepcopy=False, states=(Running,)):  # an interrupted batch
        study.tell(stale.number, state=optuna.trial.TrialState.FAIL)
    phase = float(np.random.default_rng(_draw_seed(seed, SCAN_STREAM)).uniform())
    t0 = time.perf_counter()
    run_scan(study, pool, cfg, controller, target, phase, controller_gains(cfg, controller),
             _tell, progress)  # fmt: skip
    wall_s = float(study.user_attrs.get("wall_s", 0.0)) + time.perf_counter() - t0
    study.set_user_attr("wall_s", wall_s)


#: The seed stream of the local run's sampler (the global runs' are 2 + r).
POLISH_STREAM = 1_000


def _draw_seed(seed: int, *stream: int) -> int:
    """The seed of a sampler of search seed ``seed``: (seed, 1, k) for the k-th random draw
    — an interrupted and resumed search draws exactly what an uninterrupted one does (a
    sampler seeded once would repeat its first draws) — (seed, 0), (seed, 2 + r) and
    (seed, :data:`POLISH_STREAM`) for the others."""
    return int(np.random.SeedSequence([seed, *stream]).generate_state(1)[0])


def _config_dict(cfg: AdversaryConfig) -> dict[str, Any]:
    d = dataclasses.asdict(cfg)
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


def _write_results(optuna: Any, storage: Any, cfg: AdversaryConfig, out: Path) -> None:
    import pandas as pd

    rows, worst, bounds, wall_s = [], {}, {}, 0.0
    for controller in cfg.controllers:
        for family in cfg.families:
            for energy in cfg.energies_j:
                cell = worst.setdefault(controller, {}).setdefault(family, {})
                n = Searchable(cfg, family, energy).n
                key = f"{energy:g}"
                runs = []
                for seed in cfg.search_seeds:
                    evaluation = 0
                    for kind in kinds(cfg, family):
                        name = study_name(controller, family, energy, kind, seed)
                        study = optuna.load_study(study_name=name, storage=storage)
                        wall_s += float(study.user_attrs.get("wall_s", 0.0))
                        complete = study.get_trials(states=(optuna.trial.TrialState.COMPLETE,))
                        complete = complete[: run_budget(cfg, kind, n)]
                        runs += complete
                        for t in complete:
                            attrs = dict(t.user_attrs)
                            spec = yaml.safe_dump(attrs.pop("spec"), default_flow_style=True)
                            rows.append(
                                {"controller": controller, "family": family, "energy_j": energy,
                                 "seed": seed, "kind": "random" if kind == "random" else "search",
                                 "run": kind, "trial": t.number, "evaluation": evaluation,
                                 "cost_rad": t.value, **attrs, "spec": spec.strip()}
                            )  # fmt: skip
                            evaluation += 1
                        # the worst case is the worst episode run, searched or random (a
                        # random draw can hit a failure region the search's Gaussian missed)
                        best = max(complete, key=lambda t: t.value, default=None)
                        if best is not None and (
                            key not in cell or best.value > cell[key]["cost_rad"]
                        ):
                            cell[key] = {
                                "cost_rad": best.value,
                                "found_by": "random" if kind == "random" else "search",
                                "seed": seed,
                                "unstable": best.user_attrs["unstable"],
                                "work_j": best.user_attrs["work_j"],
                                "spec": best.user_attrs["spec"],
                                "s0": best.user_attrs.get("s0"),
                                "gains": controller_gains(cfg, controller),
                                # the passivity law's direction guard it ran with
                                "direction_guard": passivity.DIRECTION_GUARD,
                            }
                ten = sorted(runs, key=lambda t: t.value, reverse=True)[:WORST_CHECKED]
                bounds[(controller, family, float(energy))] = on_bound(ten)
    df = pd.DataFrame(rows)
    df.to_csv(out / "trials.csv", index=False, float_format="%.17g")
    replay = {
        "env_id": cfg.env_id, "reset_seed": cfg.reset_seed, "control_hz": cfg.control_hz,
        "replay": f"ptrack replay {out / 'worst.yml'}", "worst": worst,
    }  # fmt: skip
    (out / "worst.yml").write_text(yaml.safe_dump(replay, sort_keys=False))
    summary = summary_frame(df, bounds)
    summary.to_csv(out / "summary.csv", index=False, float_format="%.17g")
    table = summary_table(summary)
    space = (
        "onset and start phase over a whole path period (wrapping), directions on the sphere"
        if cfg.space == "period"
        else f"onset in {list(cfg.onset_s)} s, start phase of reset seed {cfg.reset_seed}"
    )
    (out / "summary.md").write_text(
        f"{table}\n\nSearch wall time {wall_s:.0f} s: per row and search seed "
        f"({cfg.search_seeds}) {cfg.budget} random + {cfg.budget} searched episodes "
        f"({cfg.restarts + 1} CMA-ES runs, population {cfg.popsize} doubling)"
        + (
            (
                f" + {cfg.polish_budget} of a local run (step {cfg.polish_sigma:g} of each range, "
                "from the worst so far)"
                if cfg.polish_starts == 1
                else f" + {cfg.polish_starts} local runs of {cfg.polish_budget} (step "
                f"{cfg.polish_sigma:g} of each range; the first from the worst so far, each "
                "further one from the worst random draw in a basin no local run before it "
                "started in or reached)"
            )
            if cfg.polish_budget
            else ""
        )
        + f"; {space}; "
        f"energy {cfg.energy_mode}; {cfg.env_id}, {cfg.gains} gains"
        + "".join(f", {c} with {r}" for c, r in cfg.rates.items())
        + ". Spread: (max − min) / median of the seeds' "
        f"worst cases. On a bound: a non-wrapping parameter of the {WORST_CHECKED} worst "
        f"episodes within {BOUND_MARGIN:.0%} of its range of a bound.\n"
    )
    print(table)
    adversary_plot(df, out / "adversary.png")
