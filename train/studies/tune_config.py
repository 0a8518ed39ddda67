"""The configuration of a tuning fight (``ptrack tune``): :class:`TuneConfig` and its checks.
The protocol is :mod:`train.studies.tune`'s."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from agents.registry import TUNABLE
from ptrack_gym.disturbances import PRESETS
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots import profile_for_env_id
from train.common import arguments
from train.common.checks import check_path_seeds
from train.evaluation.envs import check_env_kwargs, env_kwargs
from train.evaluation.episode import EpisodeSettings, Task
from train.studies.tune_boxes import Box, check_boxes, resolve_box

DEFAULT_TEST_CONFIG = Path(__file__).resolve().parents[1] / "configs" / "evaluate" / "main.yml"
#: The episode metrics the effort constraint may use.
EFFORT_METRICS = ("tau_fb_rms_frac", "tau_dyn_rms_frac", "tau_rms_frac")
#: How the validation paths meet the disturbances (:attr:`TuneConfig.validation_design`).
VALIDATION_DESIGNS = ("crossed", "paired")


@dataclass
class TuneConfig:
    """A tuning study (the fields of ``--config`` / ``--set``)."""

    env_id: str = "ptrack_gym/IiwaTrack-v0"
    """Registered env id."""
    controllers: list[str] = field(default_factory=lambda: ["passivity"])
    """Controllers to tune (keys of ``agents.registry.TUNABLE``)."""
    trials: int = 40
    """The fewest trials of a study, whatever its number of rates."""
    trials_per_rate: int = 25
    """Trials per tuned rate: a study runs max(trials, trials_per_rate × its rates)."""
    startup_trials: int = 10
    """Random trials before TPE models the objective."""
    study_seeds: list[int] = field(default_factory=lambda: [0, 1, 2])
    """Sampler seeds: one study per controller and seed; the best over the seeds wins."""
    validation_seeds: list[int] = field(default_factory=lambda: [1000, 1001, 1002])
    """Seeds of the validation episodes (reset seed 10 000·seed + episode, as in evaluation)."""
    validation_paths: list[int] = field(default_factory=list)
    """Seeds of the random admissible validation paths (``path: random``); every validation
    seed and disturbance runs on each. Empty: the env's default path. They must not be
    paths of ``test_config`` (tuned gains are judged on other paths than they were tuned on)."""
    validation_design: str = "crossed"
    """How paths meet disturbances: "crossed", every disturbance on every validation path
    (paths × disturbances × seeds episodes); "paired", the i-th path runs only the i-th
    disturbance (as many paths as disturbances; paths × seeds episodes): every path and every
    disturbance is seen at 1/|disturbances| of the cost."""
    disturbances: list[str] = field(
        default_factory=lambda: ["none", "impulse", "periodic", "payload", "noise"]
    )
    """Conditions of the objective: each preset at level 1 ("none" undisturbed)."""
    episode_s: float = 6.0
    """Episode length (s)."""
    control_hz: float = 1000.0
    """Control rate (Hz)."""
    effort_metric: str = "tau_fb_rms_frac"
    """The episode metric the effort constraint bounds (tau_fb_rms_frac: the feedback
    torque beyond the nominal feed-forward; tau_dyn_rms_frac: beyond gravity)."""
    effort_budget: float | None = None
    """Largest mean effort a feasible trial may use; None: ``effort_factor`` × the
    reference controller's with its default gains."""
    effort_reference: str = "computed_torque"
    """The controller whose default effort sets the budget (when ``effort_budget`` is None)."""
    effort_factor: float = 1.25
    """The budget as a multiple of the reference's default effort."""
    failure_distance_rad: float = 0.5
    """An episode fails past this path distance (rad), or when unstable."""
    boxes: dict[str, dict[str, list[Any]]] = field(default_factory=dict)
    """Search boxes overriding TUNABLE's: {controller: {rate: [lo, hi, log]}}."""
    widen_on_bound: bool = False
    """Rerun a seed whose winning rate lies within 5% of a bound, with that bound widened."""
    max_widenings: int = 2
    """Most reruns with widened bounds per controller and seed."""
    carry_boxes: bool = True
    """A study seed starts in the box the previous seed ended in (its widenings kept);
    False: every seed starts in the controller's box."""
    test_config: str = str(DEFAULT_TEST_CONFIG)
    """The evaluation config whose seeds the validation seeds must avoid."""
    workers: int = 0
    """Worker processes (0: the usable cores)."""
    out: str = "results/tune"
    """Output folder (the journal, a result per controller, fight.md)."""

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
        if self.trials_per_rate < 1:
            raise InvalidConfigError(f"trials_per_rate must be >= 1, got {self.trials_per_rate}")
        if not self.study_seeds or len(set(self.study_seeds)) != len(self.study_seeds):
            raise InvalidConfigError(
                f"study_seeds must be distinct and not empty, got {self.study_seeds}"
            )
        if self.max_widenings < 0:
            raise InvalidConfigError(f"max_widenings must be >= 0, got {self.max_widenings}")
        if not self.validation_seeds:
            raise InvalidConfigError("validation_seeds must not be empty")
        if len(set(self.validation_paths)) != len(self.validation_paths) or any(
            isinstance(p, bool) or not isinstance(p, int) for p in self.validation_paths
        ):
            raise InvalidConfigError(
                f"validation_paths must be distinct integer path seeds, got {self.validation_paths}"
            )
        check_path_seeds(self.env_id, self.validation_paths, "validation path seed {seed}")
        if self.validation_design not in VALIDATION_DESIGNS:
            raise InvalidConfigError(
                f"validation_design must be one of {list(VALIDATION_DESIGNS)}, got "
                f"{self.validation_design!r}"
            )
        if self.validation_design == "paired" and len(self.validation_paths) != len(
            self.disturbances
        ):
            raise InvalidConfigError(
                f"validation_design 'paired' runs the i-th disturbance on the i-th validation "
                f"path: it needs as many validation_paths as disturbances, got "
                f"{len(self.validation_paths)} paths and {len(self.disturbances)} disturbances"
            )
        if self.effort_metric not in EFFORT_METRICS:
            raise InvalidConfigError(
                f"effort_metric must be one of {list(EFFORT_METRICS)}, got {self.effort_metric!r}"
            )
        if self.effort_budget is not None and not (
            math.isfinite(self.effort_budget) and self.effort_budget > 0
        ):
            raise InvalidConfigError(f"effort_budget must be positive, got {self.effort_budget}")
        if self.effort_reference not in TUNABLE or not self.effort_factor > 0:
            raise InvalidConfigError("effort_reference must be a controller, effort_factor > 0")
        if not self.episode_s > 0:
            raise InvalidConfigError("episode_s must be positive")
        steps = max(1, round(self.episode_s * self.control_hz)) if self.control_hz > 0 else 1
        for d in self.disturbances:  # each preset fits the episode, at the control rate
            text = None if d == "none" else f"{d}:1.0"
            check_env_kwargs(self.env_id, env_kwargs(self.control_hz, steps, "on_path", text))
        check_boxes(self.boxes)
        test, test_paths = test_episodes(Path(self.test_config))
        shared = sorted(set(self.validation_paths) & test_paths)
        if shared:
            raise InvalidConfigError(
                f"validation paths {shared} are test paths of {self.test_config}: tune on "
                "other paths"
            )
        overlap = sorted(set(self.reset_seeds()) & test)
        if overlap and not self.validation_paths and None in test_paths:  # the same path
            raise InvalidConfigError(
                f"validation seeds {self.validation_seeds} give reset seeds {overlap[:5]} that "
                f"the test config {self.test_config} uses: tune on other episodes"
            )

    def reset_seeds(self) -> list[int]:
        """The validation episodes' reset seeds (one episode per seed)."""
        return [Task("x", "none", 0.0, s, 0).reset_seed for s in self.validation_seeds]

    def tasks(self, controller: str, disturbances: Sequence[str] | None = None) -> list[Task]:
        """The validation episodes of one path: each disturbance (of ``disturbances``, all
        by default) at level 1 × each seed."""
        return [
            Task(controller, d, 0.0 if d == "none" else 1.0, s, 0)
            for d in (self.disturbances if disturbances is None else disturbances)
            for s in self.validation_seeds
        ]

    def episodes(
        self, controller: str, gains: str | tuple[tuple[str, Any], ...]
    ) -> list[tuple[Task, EpisodeSettings]]:
        """Every validation episode of ``controller`` at ``gains`` (a sorted tuple of rates,
        or "default") with its settings: :meth:`tasks` on each validation path (crossed), or
        the i-th disturbance's on the i-th path (paired)."""
        paths: list[int | None] = list(self.validation_paths) or [None]
        out = []
        for i, p in enumerate(paths):
            only = [self.disturbances[i]] if self.validation_design == "paired" else None
            settings = EpisodeSettings(
                self.env_id, self.episode_s, self.control_hz, "on_path",
                self.failure_distance_rad, 0.01, gains=gains,
                path="default" if p is None else "random", path_seed=p,
            )  # fmt: skip
            out += [(t, settings) for t in self.tasks(controller, only)]
        return out

    def trial_env_steps(self, controller: str) -> int:
        """Control steps one trial of ``controller`` runs: its validation episodes × the
        steps of an episode."""
        steps = max(1, round(self.episode_s * self.control_hz))
        return len(self.episodes(controller, "default")) * steps

    def box(self, controller: str) -> Box:
        """The box ``controller``'s rates are first searched in (TUNABLE's, with ``boxes``)."""
        return resolve_box(controller, self.boxes.get(controller))

    def study_trials(self, controller: str) -> int:
        """N_c = max(trials, trials_per_rate × the rates ``controller`` tunes)."""
        return max(self.trials, self.trials_per_rate * len(self.box(controller)))


def test_episodes(config: Path) -> tuple[set[int], set[int | None]]:
    """Every reset seed of the evaluation config ``config``, and its path seeds (None: the
    default path, or a path family with no seed)."""
    from train.evaluation.config import load_config

    if not config.exists():
        raise InvalidConfigError(f"test_config {config} does not exist")
    cfg = load_config(config, [], validate=False)  # its seeds, whatever else it needs
    return {t.reset_seed for t in cfg.tasks()}, {cfg.path_seed if cfg.path == "random" else None}


def load_config(path: Path | None, overrides: Sequence[str]) -> TuneConfig:
    """The config of a YAML file, with ``key=value`` overrides; unknown keys raise."""
    return arguments.load_config(TuneConfig, path, overrides, validate=False)
