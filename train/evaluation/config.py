"""Evaluate controllers under the same random disturbances: ``ptrack evaluate``.

Runs every controller × disturbance preset × level × seed × episode (``none`` once, at
level 0), **paired**: for a given (seed, episode) every controller meets the same start
state and disturbance schedule. Writes to ``--out``:

* ``config.yml`` — the full resolved configuration, and ``command.txt``;
* ``episodes.csv`` — one row per episode (metrics of :mod:`ptrack_gym.metrics`),
  appended as episodes finish; ``--resume`` skips the finished ones;
* ``summary.csv`` — per controller × disturbance × level: mean and IQM of the main metric
  with 95% bootstrap intervals, failure rate, paired difference to the reference;
* ``robustness_<metric>.png``, ``failures.png``, ``example_<controller>.png``;
* with ``--video``, ``videos/<controller>/<controller>-episode-0.mp4``: the example
  episode, recorded through Gymnasium's ``RecordVideo`` (headless ``rgb_array``).

Episodes run in ``--workers`` processes (default: the number of cores), or on Ray with
``--backend ray`` (``--ray-address`` for a cluster; a local instance by default).

Configuration: a YAML file (``--config``, default ``train/configs/evaluate/main.yml``) whose keys
are the fields of :class:`EvalConfig`; any field can be overridden on the command line
with ``--set key=value`` (value parsed as YAML) or its own flag.
"""

from __future__ import annotations

import importlib.util
import multiprocessing as mp
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agents.registry import CONTROLLER_NAMES, GAIN_CHOICES, check_rates, tuned_rates
from ptrack_gym.disturbances import PRESETS
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.metrics import METRIC_NAMES
from ptrack_gym.robots import profile_for_env_id
from train.common import arguments
from train.evaluation.envs import check_env_kwargs, env_kwargs
from train.evaluation.episode import SB3_PREFIX, EpisodeSettings, Task, settings_kwargs

DEFAULT_CONFIG = Path(__file__).resolve().parents[1] / "configs" / "evaluate" / "main.yml"


@dataclass
class EvalConfig:
    """An evaluation sweep."""

    env_id: str = "ptrack_gym/TwoLinkTrack-v0"
    """Registered env id."""
    controllers: list[str] = field(
        default_factory=lambda: ["passivity", "computed_torque", "pd_gravity", "slotine_li"]
    )
    """Controller names of ``agents.registry``, or ``sb3:<run folder>`` of ``train.rl.run``."""
    disturbances: list[str] = field(
        default_factory=lambda: ["none", "impulse", "periodic", "payload"]
    )
    """Disturbance presets of ``ptrack_gym.disturbances.PRESETS``."""
    levels: list[float] = field(default_factory=lambda: [0.5, 1.0, 2.0])
    """Levels of every preset but ``none`` (run once, at level 0)."""
    seeds: int = 5
    """Seeds 0..seeds−1."""
    episodes_per_seed: int = 1
    """Episodes per seed (reset seeds 10 000·seed + episode)."""
    episode_s: float = 6.0
    """Episode length (s)."""
    control_hz: float = 1000.0
    """Control rate (Hz); physics runs at 1 kHz."""
    start: str = "on_path"
    """Start mode of the env ("on_path" or "rest_near_path")."""
    path: str = "default"
    """The reference path family of the env ("default", "circle", "random"): another
    path than the one the RL entrants were trained on is a held-out check."""
    path_seed: int | None = None
    """Seed of a "random" path (the same path for every episode of the sweep)."""
    disturbance_sizing: str = "home"
    """Joint-torque disturbances sized by M(q_home) ("home") or by M(q) where they start to
    act ("onset"; the env's ``disturbance_sizing``): does the ranking survive?"""
    reference: str = "computed_torque"
    """Controller the paired differences are taken against."""
    gains: str = "default"
    """Gains of the model-based controllers: "default" or "tuned" (``agents/tuned``)."""
    controller_rates: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Gain rates of some controllers over ``gains``, e.g. ``{passivity: {damping_ratio:
    0.0}}`` — a residual's base alone at the rates it trained over; the report's title
    names them."""
    metric: str = "path_dist_rms"
    """Main metric of the summary, the report and the robustness plot."""
    worst_case: list[str] = field(default_factory=list)
    """Folders of adversarial searches (``ptrack adversary``) whose worst-case
    table ``report.md`` shows beside the sweep's."""
    failure_distance_rad: float = 0.5
    """An episode fails if the path distance ever exceeds this (rad), or it goes unstable."""
    recovery_threshold_rad: float = 0.01
    """Path distance (rad) below which an arm counts as recovered after an impulse."""
    bootstrap_resamples: int = 2000
    """Bootstrap resamples of every confidence interval."""
    workers: int = 0
    """Episode runners (0: the number of cores): with the process backend, this process
    and ``workers − 1`` worker processes."""
    backend: str = "process"
    """"process" or "ray"."""
    start_method: str = "auto"
    """How the process backend starts its workers: "auto" (fork on Linux, Python >= 3.11,
    while this process runs one thread and has not imported torch or JAX, else spawn:
    :func:`train.evaluation.sweep.start_method`), "fork", "spawn" or "forkserver". Never changes an
    episode's numbers."""
    ray_address: str | None = None
    """Ray cluster address (None: start a local instance)."""
    out: str = "results/main"
    """Output folder."""
    plots: bool = True
    """Write the PNG figures."""
    video: bool = False
    """Record one episode per controller as MP4 (``videos/``; needs the ``video`` extra)."""

    def validate(self) -> None:
        """Raise :class:`InvalidConfigError` naming the first bad field. The env arguments
        of every condition are checked by the env's own validator, without building it."""
        for c in self.controllers:
            if c.startswith(SB3_PREFIX):
                from train.evaluation.policies import check_sb3_run  # SB3 only for a model entry

                check_sb3_run(c, self.env_id)
            elif c not in CONTROLLER_NAMES:
                raise InvalidConfigError(
                    f"controllers: unknown {c!r}; known {list(CONTROLLER_NAMES)} "
                    "or 'sb3:<run folder>'"
                )
        for d in self.disturbances:
            if d not in PRESETS:
                raise InvalidConfigError(f"disturbances: unknown {d!r}; known {list(PRESETS)}")
        if not self.controllers or not self.disturbances:
            raise InvalidConfigError("controllers and disturbances must not be empty")
        if not (
            isinstance(self.worst_case, list) and all(isinstance(f, str) for f in self.worst_case)
        ):
            raise InvalidConfigError(
                f"worst_case must be a list of search folders ([] for none), "
                f"got {self.worst_case!r}"
            )
        if any(not (np.isfinite(lv) and lv > 0) for lv in self.levels):
            raise InvalidConfigError(f"levels must be positive, got {self.levels}")
        if self.seeds < 1 or self.episodes_per_seed < 1:
            raise InvalidConfigError("seeds and episodes_per_seed must be >= 1")
        for name in ("controllers", "disturbances", "levels"):
            values = [f"{v:g}" if name == "levels" else v for v in getattr(self, name)]
            if len(set(values)) != len(values):
                raise InvalidConfigError(f"{name} has duplicates: {getattr(self, name)}")
        if self.metric not in METRIC_NAMES:
            raise InvalidConfigError(f"metric {self.metric!r} is not one of {list(METRIC_NAMES)}")
        if not (np.isfinite(self.episode_s) and self.episode_s > 0):
            raise InvalidConfigError("episode_s must be positive")
        steps = max(1, round(self.episode_s * self.control_hz)) if self.control_hz > 0 else 1
        path = settings_kwargs(self.settings())
        for d in self.disturbances:
            for level in [0.0] if d == "none" else self.levels:
                text = None if d == "none" else f"{d}:{level}"
                check_env_kwargs(
                    self.env_id, env_kwargs(self.control_hz, steps, self.start, text, extra=path)
                )
        if self.workers < 0 or self.bootstrap_resamples < 1:
            raise InvalidConfigError(
                f"workers must be >= 0 (0: the cores) and bootstrap_resamples >= 1, got "
                f"{self.workers} and {self.bootstrap_resamples}"
            )
        if self.backend not in ("process", "ray"):
            raise InvalidConfigError(f"backend must be 'process' or 'ray', got {self.backend!r}")
        methods = ["auto", *mp.get_all_start_methods()]  # no fork on Windows
        if self.start_method not in methods:
            raise InvalidConfigError(
                f"start_method must be one of {methods} here, got {self.start_method!r}"
            )
        if self.reference not in self.controllers:
            raise InvalidConfigError(f"reference {self.reference!r} is not among the controllers")
        if self.gains not in GAIN_CHOICES:
            raise InvalidConfigError(f"gains must be one of {GAIN_CHOICES}, got {self.gains!r}")
        if self.gains == "tuned":
            robot = profile_for_env_id(self.env_id).name
            for c in self.controllers:
                if not c.startswith(SB3_PREFIX):
                    tuned_rates(robot, c)  # raises naming the missing file
        check_controller_rates(self.controller_rates, self.controllers, self.env_id)
        if self.backend == "ray":
            require_extra("ray", "ray", "backend: ray")
        if self.video:
            require_extra("moviepy", "video", "video: true")

    def base_gain_mismatches(self) -> list[str]:
        """One line per trained residual entrant whose base controller, compared alone in
        this sweep, runs at other gains here than the residual was trained over (its run's
        ``base_gains``): an unfair pairing the sweep warns about (``ptrack study`` builds
        its sweeps with the runs' own gains)."""
        from agents.registry import still_pinned
        from ptrack_gym.robots import robot_profile
        from train.evaluation.policies import run_config, sb3_files

        lines = []
        for c in self.controllers:
            if not c.startswith(SB3_PREFIX):
                continue
            run = run_config(sb3_files(c)[0])
            trained, pinned = run["config"], (run.get("derived") or {}).get("base_rates")
            base, gains = trained.get("residual", "none"), trained.get("base_gains", "default")
            if base not in self.controllers:
                continue
            if gains != self.gains:
                lines.append(
                    f"{c} was trained over {base} at {gains} gains; {base} alone runs here at "
                    f"{self.gains} gains (the residual keeps its own base's)"
                )
            elif pinned and not still_pinned(
                robot_profile(self._robot), base, gains, pinned, self.controller_rates.get(base)
            ):
                since = "retuned" if gains == "tuned" else "changed"
                lines.append(
                    f"{c} was trained over {base} at {gains} rates since {since} ({pinned}); "
                    f"{base} alone runs here at today's {gains} rates (the residual keeps its "
                    "own base's)"
                )
        return lines

    @property
    def _robot(self) -> str:
        from ptrack_gym.robots import profile_for_env_id

        return profile_for_env_id(self.env_id).name

    def settings(self) -> EpisodeSettings:
        return EpisodeSettings(
            env_id=self.env_id,
            episode_s=self.episode_s,
            control_hz=self.control_hz,
            start=self.start,
            path=self.path,
            path_seed=self.path_seed,
            disturbance_sizing=self.disturbance_sizing,
            failure_distance_rad=self.failure_distance_rad,
            recovery_threshold_rad=self.recovery_threshold_rad,
            gains=self.gains,
            controller_rates=tuple(
                (c, tuple(sorted(r.items()))) for c, r in sorted(self.controller_rates.items())
            ),
        )

    def tasks(self) -> list[Task]:
        """Every episode of the sweep, in a fixed order."""
        conditions = [("none", 0.0)] if "none" in self.disturbances else []
        conditions += [
            (d, float(lv)) for d in self.disturbances if d != "none" for lv in self.levels
        ]
        return [
            Task(c, d, lv, s, e)
            for d, lv in conditions
            for s in range(self.seeds)
            for e in range(self.episodes_per_seed)
            for c in self.controllers
        ]


def require_extra(module: str, extra: str, what: str) -> None:
    """Raise :class:`InvalidConfigError` if the optional ``module`` (of the package extra
    ``extra``) is not installed, naming the option that needs it."""
    if importlib.util.find_spec(module) is None:
        raise InvalidConfigError(
            f"{what} needs the optional '{extra}' extra ({module} is not installed): "
            f"pip install 'ptrack_gym[{extra}]'"
        )


def load_config(path: Path | None, overrides: Sequence[str], validate: bool = True) -> EvalConfig:
    """The config of a YAML file, with ``key=value`` overrides; unknown keys raise; with
    ``validate``, every field is checked (:meth:`EvalConfig.validate`)."""
    return arguments.load_config(EvalConfig, path, overrides, validate=validate)


def check_controller_rates(
    given: Mapping[str, Any], controllers: Sequence[str], env_id: str
) -> None:
    """Raise :class:`InvalidConfigError` unless ``given`` maps controllers of the sweep
    (model-based ones) to rates each can run (:func:`agents.registry.check_rates`)."""
    if not isinstance(given, Mapping):
        raise InvalidConfigError(f"controller_rates must be a mapping, got {given!r}")
    profile = profile_for_env_id(env_id)
    for c, rates in given.items():
        if c not in controllers or c not in CONTROLLER_NAMES:
            raise InvalidConfigError(
                f"controller_rates: {c!r} is not a model-based controller of the sweep"
            )
        check_rates(profile, c, rates, f"controller_rates of {c}")
