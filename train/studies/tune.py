"""Equal-budget tuning of a model-based controller's gains: ``ptrack tune``.

One Optuna study per robot × controller, the same settings for every controller:

* parameters — the controller's gain rates (``agents.registry.TUNABLE``: a bandwidth and a
  damping or phase rate each, four gain rates for the passivity law), made absolute by the
  controller's own ``gains_from_rates`` exactly as its defaults are;
* sampler — TPE, seeded, ``startup_trials`` random trials first; ``trials`` per study;
* objective — the geometric mean of the path-distance RMS (rad) over
  ``validation_seeds`` × ``disturbances`` (each preset at level 1, started on the path):
  scale-free, so the undisturbed case (~1e-4 rad) counts as much as a payload (~1e-1 rad)
  in relative terms, where an arithmetic mean would tune for the payload alone; a failed
  episode (unstable, or the path distance past ``failure_distance_rad``) counts with its
  padded RMS, so failures are penalised;
* constraint — the mean dynamic effort (``tau_dyn_rms_frac``: the RMS of (τ − g(q))/τ_max,
  the effort beyond holding the arm up, which is the same for every controller) must stay
  ≤ the budget: ``effort_budget`` if given, else ``effort_factor`` × what
  ``effort_reference`` (computed torque) uses with its default gains on the same validation
  episodes — one budget per robot, the same for every controller; TPE samples with the
  constraint and the best *feasible* trial wins;
* validation seeds must not meet the test seeds of ``test_config`` (the main job's): the
  tuned gains are chosen on other episodes than those they are judged on.

Resumable (``--resume``: the study lives in ``<out>/optuna.journal``), the episodes of a
trial run in ``workers`` processes, progress is printed per trial. ``--save`` writes the
best gain rates with the study's settings to ``agents/tuned/<robot>-<controller>.yml``, which
``make_controller(..., gains="tuned")`` and every entry point's ``gains: tuned`` read.
Needs the ``tune`` extra (Optuna).
"""

from __future__ import annotations

import dataclasses
import datetime
import math
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

import ptrack_gym  # noqa: F401  (registers the envs)
from agents.registry import TUNABLE, TUNED_DIR
from ptrack_gym.disturbances import PRESETS
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots import profile_for_env_id
from train.common import arguments
from train.common.runs import open_run, worker_count, worker_pool
from train.evaluation.episode import EpisodeSettings, Task, run_episode

DEFAULT_TEST_CONFIG = Path(__file__).resolve().parents[1] / "configs" / "evaluate" / "main.yml"


@dataclass
class TuneConfig:
    """A tuning study (the fields of ``--config`` / ``--set``)."""

    env_id: str = "ptrack_gym/IiwaTrack-v0"
    """Registered env id."""
    controllers: list[str] = field(default_factory=lambda: ["passivity"])
    """Controllers to tune, one study each (keys of ``agents.registry.TUNABLE``)."""
    trials: int = 40
    """Trials per study (the same for every controller)."""
    startup_trials: int = 10
    """Random trials before TPE models the objective."""
    seed: int = 0
    """Seed of the sampler."""
    validation_seeds: list[int] = field(default_factory=lambda: [1000, 1001, 1002])
    """Seeds of the validation episodes (reset seed 10 000·seed + episode, as in evaluation)."""
    disturbances: list[str] = field(
        default_factory=lambda: ["none", "impulse", "periodic", "payload", "noise"]
    )
    """Conditions of the objective: each preset at level 1 ("none" undisturbed)."""
    episode_s: float = 6.0
    """Episode length (s)."""
    control_hz: float = 1000.0
    """Control rate (Hz)."""
    effort_budget: float | None = None
    """Largest mean dynamic effort (``tau_dyn_rms_frac``) a feasible trial may use; None:
    ``effort_factor`` × the reference controller's with its default gains."""
    effort_reference: str = "computed_torque"
    """The controller whose default effort sets the budget (when ``effort_budget`` is None)."""
    effort_factor: float = 1.25
    """The budget as a multiple of the reference's default effort."""
    failure_distance_rad: float = 0.5
    """An episode fails past this path distance (rad), or when unstable."""
    test_config: str = str(DEFAULT_TEST_CONFIG)
    """The evaluation config whose seeds the validation seeds must avoid."""
    workers: int = 0
    """Worker processes (0: the usable cores)."""
    out: str = "results/tune"
    """Output folder (a subfolder per controller)."""

    def validate(self) -> None:
        """Raise :class:`InvalidConfigError` naming the first bad field, before any episode."""
        profile_for_env_id(self.env_id)
        bad = [c for c in self.controllers if c not in TUNABLE]
        if not self.controllers or bad:
            raise InvalidConfigError(
                f"controllers must be some of {sorted(TUNABLE)}, got {self.controllers}"
            )
        unknown = [d for d in self.disturbances if d not in PRESETS]
        if not self.disturbances or unknown:
            raise InvalidConfigError(f"disturbances must be presets of {list(PRESETS)}")
        if self.trials < 1 or not 0 <= self.startup_trials <= self.trials:
            raise InvalidConfigError(
                f"trials must be >= 1 and 0 <= startup_trials <= trials (the random trials "
                f"TPE starts from are part of the budget), got trials {self.trials}, "
                f"startup_trials {self.startup_trials}"
            )
        if not self.validation_seeds:
            raise InvalidConfigError("validation_seeds must not be empty")
        if self.effort_budget is not None and not (
            math.isfinite(self.effort_budget) and self.effort_budget > 0
        ):
            raise InvalidConfigError(f"effort_budget must be positive, got {self.effort_budget}")
        if self.effort_reference not in TUNABLE or not self.effort_factor > 0:
            raise InvalidConfigError("effort_reference must be a controller, effort_factor > 0")
        if not self.episode_s > 0:
            raise InvalidConfigError("episode_s must be positive")
        test = test_reset_seeds(Path(self.test_config))
        overlap = sorted(set(self.reset_seeds()) & test)
        if overlap:
            raise InvalidConfigError(
                f"validation seeds {self.validation_seeds} give reset seeds {overlap[:5]} that "
                f"the test config {self.test_config} uses: tune on other episodes"
            )

    def reset_seeds(self) -> list[int]:
        """The validation episodes' reset seeds (one episode per seed)."""
        return [Task("x", "none", 0.0, s, 0).reset_seed for s in self.validation_seeds]

    def tasks(self, controller: str) -> list[Task]:
        return [
            Task(controller, d, 0.0 if d == "none" else 1.0, s, 0)
            for d in self.disturbances
            for s in self.validation_seeds
        ]


def test_reset_seeds(config: Path) -> set[int]:
    """Every reset seed of the evaluation config ``config``."""
    from train.evaluation.config import load_config

    if not config.exists():
        raise InvalidConfigError(f"test_config {config} does not exist")
    cfg = load_config(config, [], validate=False)  # its seeds, whatever else it needs
    return {t.reset_seed for t in cfg.tasks()}


def _run(args: tuple[Task, EpisodeSettings]) -> dict[str, Any]:
    return run_episode(*args)[0]


def tune(
    cfg: TuneConfig,
    resume: bool = False,
    save_dir: Path | None = None,
    progress: bool = True,
    force: bool = False,
) -> dict[str, dict[str, Any]]:
    """Run (or continue) one study per controller; return {controller: best result}.

    ``save_dir`` (``--save``: :data:`agents.registry.TUNED_DIR`) receives the best gain rates
    of each controller as ``<robot>-<controller>.yml``, with the study's settings; a file
    already there (the shipped gains) is replaced only with ``force``, which also starts a
    study over in an ``out`` that holds files.

    Raises:
        InvalidConfigError: a bad config (before any episode), an existing study without
            ``resume`` or ``force``, a tuned-gains file ``save_dir`` holds without
            ``force``, a resumed study with other settings, or no trial within the budget.
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
    settings_dict = _settings(cfg)
    run = open_run(
        cfg.out, "optuna.journal", settings_dict, resume=resume, force=force, free=("trials",),
        saved_required=False,
    )  # fmt: skip
    out, journal = run.out, run.results
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = JournalStorage(JournalFileBackend(str(journal)))
    results: dict[str, dict[str, Any]] = {}
    with worker_pool(worker_count(cfg.workers), "spawn") as pool:
        budget = cfg.effort_budget
        if budget is None:
            budget = cfg.effort_factor * _default_effort(pool, cfg)
            if progress:
                print(f"effort budget {budget:.4f} ({cfg.effort_factor} x "
                      f"{cfg.effort_reference}'s default effort)", flush=True)  # fmt: skip
        for controller in cfg.controllers:
            best = _study(optuna, storage, pool, cfg, controller, budget, progress)
            results[controller] = best
            (out / f"{controller}.yml").write_text(yaml.safe_dump(best, sort_keys=False))
            if save_dir is not None:
                save_dir.mkdir(parents=True, exist_ok=True)
                study = {**settings_dict, **best, "rates": dict(best["rates"])}  # no YAML alias
                record = {"rates": dict(best["rates"]), "study": study}
                path = save_dir / f"{robot}-{controller}.yml"
                path.write_text(
                    f"# Tuned by ptrack tune ({datetime.date.today()}); see "
                    "train/studies/tune.py for the objective.\n"
                    + yaml.safe_dump(record, sort_keys=False)
                )
    return results


def _default_effort(pool: ProcessPoolExecutor, cfg: TuneConfig) -> float:
    """The reference controller's mean dynamic effort with its default gains."""
    settings = EpisodeSettings(
        cfg.env_id, cfg.episode_s, cfg.control_hz, "on_path", cfg.failure_distance_rad, 0.01
    )
    rows = pool.map(_run, [(t, settings) for t in cfg.tasks(cfg.effort_reference)])
    return float(np.mean([r["tau_dyn_rms_frac"] for r in rows]))


def _settings(cfg: TuneConfig) -> dict[str, Any]:
    d = dataclasses.asdict(cfg)
    for k in ("workers", "out", "controllers"):
        d.pop(k)
    return d


def _study(
    optuna: Any,
    storage: Any,
    pool: ProcessPoolExecutor,
    cfg: TuneConfig,
    controller: str,
    budget: float,
    progress: bool,
) -> dict[str, Any]:
    space = TUNABLE[controller]

    sampler = optuna.samplers.TPESampler(seed=cfg.seed, n_startup_trials=cfg.startup_trials)
    study = optuna.create_study(
        study_name=controller, storage=storage, sampler=sampler, direction="minimize",
        load_if_exists=True,
    )  # fmt: skip
    running = study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.RUNNING,))
    for stale in running:  # an interrupted trial
        study.tell(stale.number, state=optuna.trial.TrialState.FAIL)
    complete = optuna.trial.TrialState.COMPLETE
    done = len(study.get_trials(deepcopy=False, states=(complete,)))
    tasks = cfg.tasks(controller)
    while done < cfg.trials:
        # TPE rebuilds its model from the history at every ask: a sampler seeded by
        # (seed, trial index) makes a resumed study ask exactly what an uninterrupted one
        # does (one seeded once would repeat its first random startup draws)
        study.sampler = optuna.samplers.TPESampler(
            seed=int(np.random.SeedSequence([cfg.seed, done]).generate_state(1)[0]),
            n_startup_trials=cfg.startup_trials,
        )
        trial = study.ask()
        rates = {
            name: trial.suggest_float(name, low, high, log=log)
            for name, (low, high, log) in space.items()
        }
        settings = EpisodeSettings(
            cfg.env_id, cfg.episode_s, cfg.control_hz, "on_path", cfg.failure_distance_rad,
            0.01, gains=tuple(sorted(rates.items())),
        )  # fmt: skip
        rows = list(pool.map(_run, [(t, settings) for t in tasks]))
        error = float(np.exp(np.mean(np.log([max(r["path_dist_rms"], 1e-12) for r in rows]))))
        effort = float(np.mean([r["tau_dyn_rms_frac"] for r in rows]))
        failures = int(sum(r["failed"] for r in rows))
        trial.set_user_attr("effort", effort)
        trial.set_user_attr("failures", failures)
        trial.set_constraint("effort", effort - budget)  # feasible when <= 0
        study.tell(trial, error)
        done += 1
        if progress:
            feasible = "feasible" if effort <= budget else "over budget"
            print(
                f"{controller} trial {done}/{cfg.trials}: error {error:.3e} rad, effort "
                f"{effort:.4f} ({feasible}), failures {failures}, "
                + ", ".join(f"{k}={v:.3g}" for k, v in rates.items()),
                flush=True,
            )
    trials = study.get_trials(deepcopy=False, states=(complete,))[: cfg.trials]
    feasible = [t for t in trials if t.user_attrs["effort"] <= budget]
    if not feasible:
        raise InvalidConfigError(f"{controller}: no trial met the effort budget {budget:.4g}")
    best = min(feasible, key=lambda t: t.value)
    return {
        "controller": controller,
        "rates": {k: float(v) for k, v in best.params.items()},
        "error_rad": float(best.value),
        "effort": float(best.user_attrs["effort"]),
        "failures": int(best.user_attrs["failures"]),
        "trial": int(best.number),
        "trials": len(trials),
        "feasible_trials": len(feasible),
        "effort_budget": float(budget),
        # the trials' own durations: right across interruptions and resumes
        "wall_s": round(
            sum((t.datetime_complete - t.datetime_start).total_seconds() for t in trials), 1
        ),
    }


def tuned_table(tuned_dir: Path = TUNED_DIR) -> str:
    """Markdown: every tuned file's gain rates next to the robot's defaults, with the study's
    validation error, effort (budget) and wall time (``ptrack tune --table``)."""
    from agents.registry import RATE_MODULES, effective_rates
    from ptrack_gym.robots import robot_profile

    lines = [
        "| robot | controller | tuned gain rates | default gain rates | validation error (rad) "
        "| effort (budget) | feasible trials | wall (s) |",
        "|---|---|---|---|---:|---|---:|---:|",
    ]
    for path in sorted(tuned_dir.glob("*.yml")):
        data = yaml.safe_load(path.read_text())
        robot, controller = path.stem.split("-", 1)
        study = data["study"]
        space = RATE_MODULES[controller].TUNABLE
        default = effective_rates(robot_profile(robot), controller)
        tuned_text = ", ".join(f"{k} {data['rates'][k]:.3g}" for k in space)
        default_text = ", ".join(f"{k} {default[k]:.3g}" for k in space)
        lines.append(
            f"| {robot} | {controller} | {tuned_text} | {default_text} "
            f"| {study['error_rad']:.3g} | {study['effort']:.4f} ({study['effort_budget']:.4f}) "
            f"| {study['feasible_trials']}/{study['trials']} | {study['wall_s']:.0f} |"
        )
    return "\n".join(lines)


def load_config(path: Path | None, overrides: Sequence[str]) -> TuneConfig:
    """The config of a YAML file, with ``key=value`` overrides; unknown keys raise."""
    return arguments.load_config(TuneConfig, path, overrides, validate=False)
