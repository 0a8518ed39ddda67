"""Worst case, not only the average: an adversarial disturbance search (``train.adversary``).

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

The same budget (``budget`` searched + ``budget`` random episodes) for every controller.
Writes to ``--out``: ``optuna.journal`` (the studies: ``--resume`` continues them),
``trials.csv``, ``worst.yml`` (the worst spec per controller × family × energy and how to
replay it), ``summary.md`` and ``adversary.png``. Episodes run in ``workers`` processes (a
CMA-ES generation, or a batch of random draws, at a time). Needs the ``tune`` extra
(Optuna, cmaes).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
import warnings
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import yaml

import ptrack_gym  # noqa: F401  (registers the envs)
from agents.policy import ControllerPolicy
from agents.registry import CONTROLLER_NAMES, GAIN_CHOICES, make_controller, tuned_rates
from ptrack_gym.errors import InvalidConfigError, PtrackError
from ptrack_gym.robots import profile_for_env_id
from train.config_files import config_data
from train.episode import rollout
from train.threads import one_thread_defaults

#: The families the search can drive, with what it searches.
FAMILIES: tuple[str, ...] = ("impulse", "push", "periodic")


@dataclass
class AdversaryConfig:
    """An adversarial search (the fields of ``--config`` / ``--set``)."""

    env_id: str = "ptrack_gym/IiwaTrack-v0"
    """Registered env id."""
    controllers: list[str] = field(
        default_factory=lambda: ["passivity", "computed_torque", "pd_gravity", "slotine_li"]
    )
    """Controller names of ``agents.registry``."""
    gains: str = "default"
    """The controllers' gains: "default" or "tuned" (``agents/tuned``, ``train.tune``)."""
    families: list[str] = field(default_factory=lambda: ["impulse"])
    """Disturbance families searched (:data:`FAMILIES`)."""
    energies_j: list[float] = field(default_factory=lambda: [2.0])
    """Energy budgets (J) of the family's ``energy_j``."""
    energy_mode: str = "home"
    """Impulse sizing: "home" (the preset's) or "delivered" (``ImpulseTorque``)."""
    budget: int = 200
    """Searched episodes per controller × family × energy; as many random ones besides."""
    popsize: int = 8
    """CMA-ES population (episodes evaluated in parallel per generation)."""
    reset_seed: int = 0
    """Env reset seed of every episode (the start on the path)."""
    seed: int = 0
    """Seed of the samplers."""
    onset_s: tuple[float, float] = (0.5, 2.0)
    """Range of the searched onset (s)."""
    post_s: float = 1.5
    """Length of the cost window after the disturbance (s)."""
    impulse_duration_s: float = 0.05
    """Duration of an impulse (s)."""
    push_duration_s: float = 0.1
    """Duration of a push (s)."""
    push_links: list[str] = field(default_factory=list)
    """Links a push may act on (empty: the end effector)."""
    frequency_hz: tuple[float, float] = (0.2, 5.0)
    """Range of the searched frequency of a periodic torque (Hz, log-uniform)."""
    periodic_s: float = 4.0
    """Length of a periodic-torque episode (s)."""
    control_hz: float = 1000.0
    """Control rate (Hz)."""
    failure_distance_rad: float = 0.5
    """Cost of an unstable episode (rad)."""
    workers: int = 0
    """Worker processes (0: the usable cores)."""
    out: str = "results/adversary"
    """Output folder."""

    def validate(self) -> None:
        """Raise :class:`InvalidConfigError` naming the first bad field, before any episode."""
        unknown = [c for c in self.controllers if c not in CONTROLLER_NAMES]
        if not self.controllers or unknown:
            raise InvalidConfigError(
                f"controllers must be names of {list(CONTROLLER_NAMES)}, got {self.controllers}"
            )
        if self.gains not in GAIN_CHOICES:
            raise InvalidConfigError(f"gains must be one of {GAIN_CHOICES}, got {self.gains!r}")
        if self.gains == "tuned":
            robot = profile_for_env_id(self.env_id).name
            for c in self.controllers:
                tuned_rates(robot, c)  # raises naming the missing file
        bad = [f for f in self.families if f not in FAMILIES]
        if not self.families or bad:
            raise InvalidConfigError(
                f"families must be some of {list(FAMILIES)}, got {self.families}"
            )
        if not self.energies_j or not all(
            isinstance(e, (int, float)) and math.isfinite(e) and e > 0 for e in self.energies_j
        ):
            raise InvalidConfigError(f"energies_j must be positive numbers, got {self.energies_j}")
        for name in ("controllers", "families", "energies_j"):
            values = getattr(self, name)
            if len(set(values)) != len(values):
                raise InvalidConfigError(f"{name} has duplicates: {values}")
        if self.budget < 1 or self.popsize < 2:
            raise InvalidConfigError("budget must be >= 1 and popsize >= 2")
        lo, hi = self.onset_s
        if not (0 <= lo <= hi) or not (0 < self.frequency_hz[0] <= self.frequency_hz[1]):
            raise InvalidConfigError("onset_s and frequency_hz must be (low, high) ranges")
        for name in ("post_s", "impulse_duration_s", "push_duration_s", "periodic_s"):
            if not getattr(self, name) > 0:
                raise InvalidConfigError(f"{name} must be positive")
        if self.energy_mode not in ("home", "delivered"):
            raise InvalidConfigError(
                f"energy_mode must be 'home' or 'delivered', got {self.energy_mode!r}"
            )
        profile_for_env_id(self.env_id)  # a known robot
        # Every family and link must exist on the robot: one env per family checks its spec.
        for family in self.families:
            probe = Searchable(self, family, self.energies_j[0])
            for link in probe.links:
                spec = probe.spec(probe.midpoint(link))
                gym.make(self.env_id, disturbance=spec, control_hz=self.control_hz).close()


@dataclass(frozen=True)
class Searchable:
    """One family at one energy on one robot: its parameters, their spec, its cost window."""

    cfg: AdversaryConfig
    family: str
    energy_j: float

    @property
    def n(self) -> int:
        return profile_for_env_id(self.cfg.env_id).n

    @property
    def links(self) -> list[str | None]:
        return list(self.cfg.push_links) or [None] if self.family == "push" else [None]

    def space(self, trial: Any) -> dict[str, Any]:
        """Suggest this family's parameters on an Optuna trial."""
        c = self.cfg
        params: dict[str, Any] = {}
        if self.family == "periodic":
            params["frequency_hz"] = trial.suggest_float("frequency_hz", *c.frequency_hz, log=True)
        else:
            params["onset_s"] = trial.suggest_float("onset_s", *c.onset_s)
        dims = 3 if self.family == "push" else self.n
        params["direction"] = [trial.suggest_float(f"x{i}", -1.0, 1.0) for i in range(dims)]
        if self.family == "push" and len(self.cfg.push_links) > 1:
            params["link"] = trial.suggest_categorical("link", list(self.cfg.push_links))
        elif self.family == "push" and self.cfg.push_links:
            params["link"] = self.cfg.push_links[0]
        return params

    def midpoint(self, link: str | None) -> dict[str, Any]:
        """A valid parameter set (for the checks before running)."""
        dims = 3 if self.family == "push" else self.n
        params: dict[str, Any] = {"onset_s": self.cfg.onset_s[0], "direction": [1.0] * dims}
        if self.family == "periodic":
            params = {"frequency_hz": self.cfg.frequency_hz[0], "direction": [1.0] * dims}
        if link is not None:
            params["link"] = link
        return params

    def spec(self, params: dict[str, Any]) -> dict[str, Any]:
        """The disturbance spec of a parameter set (replays bit-identically)."""
        c = self.cfg
        direction = [float(x) for x in params["direction"]]
        if not np.any(direction):
            direction[0] = 1.0  # a zero direction (measure zero) means the first axis
        if self.family == "impulse":
            return {
                "type": "impulse", "energy_j": self.energy_j, "duration_s": c.impulse_duration_s,
                "onset_s": float(params["onset_s"]), "direction": direction,
                "energy_mode": c.energy_mode,
            }  # fmt: skip
        if self.family == "push":
            spec = {
                "type": "push", "energy_j": self.energy_j, "duration_s": c.push_duration_s,
                "onset_s": float(params["onset_s"]), "direction": direction,
            }  # fmt: skip
            if params.get("link") is not None:
                spec["link"] = params["link"]
            return spec
        return {
            "type": "periodic", "energy_j": self.energy_j,
            "frequency_hz": float(params["frequency_hz"]), "direction": direction,
        }  # fmt: skip

    def window(self, spec: dict[str, Any]) -> tuple[float, float]:
        """The cost window (s) of a spec."""
        if self.family == "periodic":
            return self.cfg.periodic_s - self.cfg.post_s, self.cfg.periodic_s
        end = spec["onset_s"] + spec["duration_s"]
        return end, end + self.cfg.post_s

    def episode_s(self) -> float:
        if self.family == "periodic":
            return self.cfg.periodic_s
        duration = (
            self.cfg.impulse_duration_s if self.family == "impulse" else self.cfg.push_duration_s
        )
        return self.cfg.onset_s[1] + duration + self.cfg.post_s


@dataclass(frozen=True)
class Outcome:
    """What one episode gave the search."""

    cost: float  # path-distance RMS over the window (rad); failure distance if unstable
    unstable: bool
    work_j: float  # ∫ q̇ᵀτ_d over the episode (J)
    peak_speed_rad_s: float  # max |q̇| over the episode
    peak_tau_frac: float  # max |τ| / τ_max of the applied (clipped) torque


def evaluate(
    env_id: str,
    controller: str,
    spec: dict[str, Any],
    reset_seed: int,
    episode_s: float,
    window: tuple[float, float],
    control_hz: float,
    failure_distance_rad: float,
    gains: str | dict[str, Any] = "default",
) -> Outcome:
    """One episode of ``controller`` (with ``gains``) under ``spec`` from ``reset_seed``;
    deterministic."""
    steps = round(episode_s * control_hz)
    env = gym.make(
        env_id,
        disturbance=spec,
        control_hz=control_hz,
        horizon_s=episode_s,
        max_episode_steps=steps,
    )
    try:
        policy = ControllerPolicy(env, make_controller(controller, env, gains))
        record, _ = rollout(env, policy, reset_seed)
    finally:
        env.close()
    t, dist = record.t_s, record.path_distance
    inside = (t > window[0]) & (t <= window[1] + 1e-9)
    if record.unstable:
        cost = failure_distance_rad
    else:
        cost = float(np.sqrt(np.mean(dist[inside] ** 2))) if np.any(inside) else float("nan")
    return Outcome(
        cost=cost,
        unstable=record.unstable,
        work_j=record.disturbance_work_j,
        peak_speed_rad_s=float(np.max(np.abs(record.qd))),
        peak_tau_frac=float(np.max(np.abs(record.tau_nm) / record.torque_limits_nm)),
    )


def _evaluate_task(args: tuple[Any, ...]) -> Outcome:
    return evaluate(*args)


def controller_gains(cfg: AdversaryConfig, controller: str) -> str | dict[str, Any]:
    """The gains argument of ``controller``'s episodes: "default", or the tuned rates
    themselves (recorded in ``worst.yml``, so a replay does not depend on a later tuning)."""
    if cfg.gains == "tuned":
        return tuned_rates(profile_for_env_id(cfg.env_id).name, controller)
    return cfg.gains


def study_name(controller: str, family: str, energy_j: float, kind: str) -> str:
    return f"{controller}|{family}|{energy_j:g}|{kind}"


def run_search(cfg: AdversaryConfig, resume: bool = False, progress: bool = True) -> Path:
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
    out = Path(cfg.out)
    journal = out / "optuna.journal"
    if journal.exists() and not resume:
        raise InvalidConfigError(
            f"{journal} exists: pass --resume to continue it, or another --out"
        )
    saved = out / "config.yml"
    if resume and saved.exists():
        old = yaml.safe_load(saved.read_text())
        new = _config_dict(cfg)
        free = ("workers", "out", "budget")  # a resume may extend the budget
        changed = [k for k in new if k not in free and old.get(k) != new[k]]
        if changed:
            raise InvalidConfigError(f"--resume with a different search: {changed}")
    out.mkdir(parents=True, exist_ok=True)
    saved.write_text(yaml.safe_dump(_config_dict(cfg), sort_keys=False))
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = JournalStorage(JournalFileBackend(str(journal)))
    workers = cfg.workers or len(os.sched_getaffinity(0))
    import multiprocessing as mp

    ctx = mp.get_context("spawn")  # no simulator client or thread is inherited
    one_thread_defaults()
    with ProcessPoolExecutor(workers, mp_context=ctx) as pool:
        for controller in cfg.controllers:
            for family in cfg.families:
                for energy in cfg.energies_j:
                    target = Searchable(cfg, family, energy)
                    for kind in ("random", "search"):  # the search starts at the random best
                        _run_study(optuna, storage, pool, cfg, controller, target, kind, progress)
    _write_results(optuna, storage, cfg, out)
    return out


def _run_study(
    optuna: Any,
    storage: Any,
    pool: ProcessPoolExecutor,
    cfg: AdversaryConfig,
    controller: str,
    target: Searchable,
    kind: str,
    progress: bool,
) -> None:
    name = study_name(controller, target.family, target.energy_j, kind)
    if kind == "search":
        # Warm-started CMA-ES (WS-CMA-ES): its initial distribution comes from the best of
        # the random draws. Failure regions can be small and far from the centre of the
        # box, where a search started at the centre settles (seen: 0/200 searched vs 14/200
        # random draws unstable for the passivity controller at 2 J on the iiwa).
        random_name = study_name(controller, target.family, target.energy_j, "random")
        source = optuna.load_study(study_name=random_name, storage=storage).get_trials(
            deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,)
        )
        with warnings.catch_warnings():  # source_trials is "experimental" in Optuna 4-5
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            sampler = optuna.samplers.CmaEsSampler(
                source_trials=list(source),
                seed=cfg.seed,
                popsize=cfg.popsize,
                warn_independent_sampling=False,
            )
    else:
        sampler = optuna.samplers.RandomSampler(seed=_draw_seed(cfg.seed, 0))  # reseeded per draw
    study = optuna.create_study(
        study_name=name, storage=storage, sampler=sampler, direction="maximize",
        load_if_exists=True,
    )  # fmt: skip
    Running = optuna.trial.TrialState.RUNNING
    for stale in study.get_trials(deepcopy=False, states=(Running,)):  # an interrupted batch
        study.tell(stale.number, state=optuna.trial.TrialState.FAIL)
    done = len(study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,)))
    wall_s = float(study.user_attrs.get("wall_s", 0.0))  # summed over batches: resume-safe
    while done < cfg.budget:
        t0 = time.perf_counter()
        batch = []
        for i in range(min(cfg.popsize, cfg.budget - done)):
            if kind == "random":  # the k-th draw is a function of (seed, k): resume-safe
                study.sampler = optuna.samplers.RandomSampler(seed=_draw_seed(cfg.seed, done + i))
            batch.append(study.ask())
        specs = [target.spec(target.space(trial)) for trial in batch]
        tasks = [
            (cfg.env_id, controller, spec, cfg.reset_seed, target.episode_s(), target.window(spec),
             cfg.control_hz, cfg.failure_distance_rad, controller_gains(cfg, controller))
            for spec in specs
        ]  # fmt: skip
        for trial, spec, outcome in zip(batch, specs, pool.map(_evaluate_task, tasks), strict=True):
            for key, value in dataclasses.asdict(outcome).items():
                trial.set_user_attr(key, value)
            trial.set_user_attr("spec", spec)
            study.tell(trial, outcome.cost)
        done += len(batch)
        wall_s += time.perf_counter() - t0
        study.set_user_attr("wall_s", wall_s)
        if progress:
            print(f"{name}: {done}/{cfg.budget}, worst {study.best_value:.3g} rad", flush=True)


def _draw_seed(seed: int, k: int) -> int:
    """The seed of the k-th random draw: an interrupted and resumed search draws exactly
    what an uninterrupted one does (a sampler seeded once would repeat its first draws)."""
    return int(np.random.SeedSequence([seed, 1, k]).generate_state(1)[0])


def _config_dict(cfg: AdversaryConfig) -> dict[str, Any]:
    d = dataclasses.asdict(cfg)
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


def _write_results(optuna: Any, storage: Any, cfg: AdversaryConfig, out: Path) -> None:
    import pandas as pd

    rows, worst, wall_s = [], {}, 0.0
    for controller in cfg.controllers:
        for family in cfg.families:
            for energy in cfg.energies_j:
                for kind in ("search", "random"):
                    name = study_name(controller, family, energy, kind)
                    study = optuna.load_study(study_name=name, storage=storage)
                    wall_s += float(study.user_attrs.get("wall_s", 0.0))
                    complete = study.get_trials(states=(optuna.trial.TrialState.COMPLETE,))
                    for t in complete[: cfg.budget]:
                        attrs = dict(t.user_attrs)
                        spec = yaml.safe_dump(attrs.pop("spec"), default_flow_style=True).strip()
                        rows.append(
                            {"controller": controller, "family": family, "energy_j": energy,
                             "kind": kind, "trial": t.number, "cost_rad": t.value, **attrs,
                             "spec": spec}
                        )  # fmt: skip
                    # the worst case is the worst episode run, searched or random (a
                    # random draw can hit a failure region the search's Gaussian missed)
                    best = max(complete[: cfg.budget], key=lambda t: t.value, default=None)
                    cell = worst.setdefault(controller, {}).setdefault(family, {})
                    key = f"{energy:g}"
                    if best is not None and (key not in cell or best.value > cell[key]["cost_rad"]):
                        cell[key] = {
                            "cost_rad": best.value,
                            "found_by": kind,
                            "unstable": best.user_attrs["unstable"],
                            "work_j": best.user_attrs["work_j"],
                            "spec": best.user_attrs["spec"],
                            "gains": controller_gains(cfg, controller),
                        }
    df = pd.DataFrame(rows)
    df.to_csv(out / "trials.csv", index=False, float_format="%.17g")
    replay = {
        "env_id": cfg.env_id, "reset_seed": cfg.reset_seed, "control_hz": cfg.control_hz,
        "replay": f"python -m train.adversary --replay {out / 'worst.yml'}", "worst": worst,
    }  # fmt: skip
    (out / "worst.yml").write_text(yaml.safe_dump(replay, sort_keys=False))
    summary_frame(df).to_csv(out / "summary.csv", index=False, float_format="%.17g")
    table = summary_table(df)
    (out / "summary.md").write_text(
        f"{table}\n\nSearch wall time {wall_s:.0f} s ({cfg.budget} searched + {cfg.budget} "
        f"random episodes per row, reset seed {cfg.reset_seed}, {cfg.env_id}).\n"
    )
    print(table)
    _plot(df, out / "adversary.png")


def summary_frame(df: Any) -> Any:
    """Per controller × family × energy (a DataFrame, ``summary.csv``): the worst cost
    found by either kind (``worst_rad``, the one ``worst.yml`` replays), the worst searched
    and the median and worst random cost (rad), worst searched / median random, the
    unstable episodes of each kind, and the range of the work the disturbance really did
    (J)."""
    import pandas as pd

    rows = []
    for (controller, family, energy), g in df.groupby(["controller", "family", "energy_j"]):
        s, r = g[g["kind"] == "search"], g[g["kind"] == "random"]
        worst, med = float(s["cost_rad"].max()), float(r["cost_rad"].median())
        rows.append(
            {"controller": controller, "family": family, "energy_j": float(energy),
             "worst_rad": float(g["cost_rad"].max()), "worst_search_rad": worst,
             "median_random_rad": med,
             "worst_random_rad": float(r["cost_rad"].max()), "worst_over_median": worst / med,
             "unstable_search": int(s["unstable"].sum()), "n_search": len(s),
             "unstable_random": int(r["unstable"].sum()), "n_random": len(r),
             "work_min_j": float(g["work_j"].min()), "work_max_j": float(g["work_j"].max())}
        )  # fmt: skip
    return pd.DataFrame(rows)


def summary_table(df: Any) -> str:
    """Per controller × family × energy: the worst cost found (either kind), worst searched
    cost, median and worst random cost, worst searched / median random, unstable counts,
    and the work the disturbance really did."""
    lines = [
        "| controller | family | energy (J) | worst found (rad) | worst searched (rad) "
        "| median random (rad) | worst random (rad) | searched / median | unstable (search / "
        "random) | delivered work (J), min–max |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for (controller, family, energy), g in df.groupby(["controller", "family", "energy_j"]):
        s, r = g[g["kind"] == "search"], g[g["kind"] == "random"]
        worst, med = float(s["cost_rad"].max()), float(r["cost_rad"].median())
        lines.append(
            f"| {controller} | {family} | {energy:g} | {float(g['cost_rad'].max()):.3g} "
            f"| {worst:.3g} | {med:.3g} "
            f"| {float(r['cost_rad'].max()):.3g} | {worst / med:.1f} "
            f"| {int(s['unstable'].sum())}/{len(s)} / {int(r['unstable'].sum())}/{len(r)} "
            f"| {g['work_j'].min():.2f}–{g['work_j'].max():.2f} |"
        )
    return "\n".join(lines)


def _plot(df: Any, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = list(df.groupby(["family", "energy_j"]))
    fig, axes = plt.subplots(1, len(groups), figsize=(6 * len(groups), 4), squeeze=False)
    for ax, ((family, energy), g) in zip(axes[0], groups, strict=True):
        for controller, gc in g.groupby("controller"):
            s = gc[gc["kind"] == "search"].sort_values("trial")
            (line,) = ax.plot(np.maximum.accumulate(s["cost_rad"].to_numpy()), label=controller)
            med = gc[gc["kind"] == "random"]["cost_rad"].median()
            ax.axhline(med, color=line.get_color(), ls=":", lw=1)
        ax.set_yscale("log")
        ax.set_xlabel("searched episodes")
        ax.set_ylabel("worst cost so far (rad; dotted: median random)")
        ax.set_title(f"{family}, {energy:g} J")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def replay(worst_yml: Path, controller: str, family: str, energy_j: float) -> Outcome:
    """Re-run a worst case of ``worst.yml`` (bit-identical to the searched episode)."""
    data = yaml.safe_load(worst_yml.read_text())
    entry = data["worst"][controller][family][f"{energy_j:g}"]
    cfg = AdversaryConfig(**{**yaml.safe_load((worst_yml.parent / "config.yml").read_text())})
    target = Searchable(cfg, family, energy_j)
    spec = entry["spec"]
    return evaluate(
        cfg.env_id, controller, spec, cfg.reset_seed, target.episode_s(), target.window(spec),
        cfg.control_hz, cfg.failure_distance_rad, entry.get("gains", cfg.gains),
    )  # fmt: skip


def load_config(path: Path | None, overrides: Sequence[str]) -> AdversaryConfig:
    """The config of a YAML file, with ``key=value`` overrides; unknown keys raise."""
    data = config_data(AdversaryConfig, path, overrides)
    for key in ("onset_s", "frequency_hz"):
        if key in data:
            data[key] = tuple(data[key])
    return AdversaryConfig(**data)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m train.adversary", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--config", type=Path, help="YAML config (fields of AdversaryConfig)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--out", help="output folder")
    parser.add_argument("--resume", action="store_true", help="continue the studies in --out")
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument("--replay", type=Path, help="a worst.yml: re-run its worst cases")
    args = parser.parse_args(argv)
    try:
        if args.replay is not None:
            data = yaml.safe_load(args.replay.read_text())
            for controller, families in data["worst"].items():
                for family, energies in families.items():
                    for energy, entry in energies.items():
                        outcome = replay(args.replay, controller, family, float(energy))
                        print(
                            f"{controller} {family} {energy} J: cost {outcome.cost:.6g} rad "
                            f"(searched {entry['cost_rad']:.6g}), unstable={outcome.unstable}"
                        )
            return 0
        overrides = list(args.set) + ([f"out={args.out}"] if args.out else [])
        cfg = load_config(args.config, overrides)
        run_search(cfg, resume=args.resume, progress=not args.no_progress)
    except PtrackError as exc:
        parser.error(str(exc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
