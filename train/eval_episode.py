"""One evaluation episode: a controller on an env under one disturbance, with one seed.

This is what a worker process runs. It needs nothing from the parent but a
:class:`Task` and the :class:`EpisodeSettings`, so the process and Ray backends run the
same function and give the same rows.

Pairing: the env's reset seed depends only on (seed, episode), never on the controller,
so every controller meets the same start state and — through the env's own disturbance
stream — the same disturbance schedule.

Controllers are names of ``agents.factory`` or ``sb3:<run folder>``: a model trained by
``python -m train.train`` (pure or residual), rebuilt from the run's ``config.yml`` — its
residual base, scale and control rate — with its ``vecnormalize.pkl`` statistics when
present, acting deterministically; ``sb3:<run folder>@<steps>`` runs the run's checkpoint
of that many steps instead (``checkpoints/rl_model_<steps>_steps.zip`` with its
VecNormalize statistics): a learning curve is a sweep over a run's checkpoints. A model
runs at its training control rate, so it meets the same disturbance schedule in time
(onsets, frequencies) but per-step noise draws differ; its env's disturbance horizon is
the sweep's episode length, as for every other controller.
"""

from __future__ import annotations

import pickle
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import yaml

import ptrack_gym  # noqa: F401  (registers the envs)
from agents.factory import make_controller
from agents.policy import ControllerPolicy
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.metrics import EpisodeRecord, episode_metrics

#: Columns identifying an episode, in the CSV's order.
KEY_COLUMNS: tuple[str, ...] = ("controller", "disturbance", "level", "seed", "episode")


@dataclass(frozen=True)
class EpisodeSettings:
    """Settings shared by every episode of a sweep (see ``train/configs/*.yml``)."""

    env_id: str
    episode_s: float
    control_hz: float
    start: str
    failure_distance_rad: float
    recovery_threshold_rad: float


@dataclass(frozen=True)
class Task:
    """One episode to run: who, under what, with which seed."""

    controller: str
    disturbance: str
    level: float
    seed: int
    episode: int

    def key(self) -> tuple[str, str, str, str, str]:
        """The CSV key of this task (strings, as read back from the CSV)."""
        return (
            self.controller,
            self.disturbance,
            f"{self.level:g}",
            str(self.seed),
            str(self.episode),
        )

    @property
    def reset_seed(self) -> int:
        """The env reset seed: a function of (seed, episode) only — the pairing."""
        return 10_000 * self.seed + self.episode


_ENV_CACHE: dict[tuple[Any, ...], gym.Env[Any, Any]] = {}


def _env(settings: EpisodeSettings, disturbance: str, level: float) -> gym.Env[Any, Any]:
    """A per-process cache of envs (building path tables costs ~0.2 s)."""
    key = (settings, disturbance, level)
    if key not in _ENV_CACHE:
        steps = round(settings.episode_s * settings.control_hz)
        _ENV_CACHE[key] = gym.make(
            settings.env_id,
            control_hz=settings.control_hz,
            start=settings.start,
            disturbance=None if disturbance == "none" else (disturbance, level),
            horizon_s=settings.episode_s,
            max_episode_steps=steps,
        )
    return _ENV_CACHE[key]


SB3_PREFIX = "sb3:"


def label(controller: str) -> str:
    """A file-name-safe label of a controller name (``sb3:runs/x`` → ``sb3-x``,
    ``sb3:runs/x@2000`` → ``sb3-x-2000``)."""
    if controller.startswith(SB3_PREFIX):
        run, _, steps = controller[len(SB3_PREFIX) :].partition("@")
        return "sb3-" + Path(run).name + (f"-{steps}" if steps else "")
    return controller


def sb3_files(controller: str) -> tuple[Path, Path, Path]:
    """(run folder, model zip, VecNormalize pickle) of ``sb3:<run>`` or ``sb3:<run>@<steps>``;
    the pickle may not exist (a run without normalization)."""
    run, at, steps = controller[len(SB3_PREFIX) :].partition("@")
    run_dir = Path(run)
    if not at:
        return run_dir, run_dir / "model.zip", run_dir / "vecnormalize.pkl"
    if not steps.isdigit():
        raise InvalidConfigError(f"{controller}: '@' must be followed by a step count")
    ckpt = run_dir / "checkpoints"
    return (
        run_dir,
        ckpt / f"rl_model_{steps}_steps.zip",
        ckpt / f"rl_model_vecnormalize_{steps}_steps.pkl",
    )


def check_sb3_run(controller: str, env_id: str) -> Path:
    """The run folder of an ``sb3:`` controller, checked; raises InvalidConfigError."""
    run_dir, model_zip, _ = sb3_files(controller)
    for path in (run_dir / "config.yml", model_zip):
        if not path.exists():
            raise InvalidConfigError(f"{controller}: {path} does not exist")
    trained_on = yaml.safe_load((run_dir / "config.yml").read_text())["config"]["env_id"]
    if trained_on != env_id:
        raise InvalidConfigError(f"{controller} was trained on {trained_on}, not {env_id}")
    return run_dir


_SB3_CACHE: dict[tuple[Any, ...], tuple[gym.Env[Any, Any], Callable[[np.ndarray], np.ndarray]]] = {}


def _sb3_policy(
    controller: str, settings: EpisodeSettings, disturbance: str, level: float
) -> tuple[gym.Env[Any, Any], Callable[[np.ndarray], np.ndarray]]:
    """(env, act) for a trained model; cached per process like the envs."""
    key = (controller, settings, disturbance, level)
    if key in _SB3_CACHE:
        return _SB3_CACHE[key]
    from train.train import ALGOS, build_env  # torch and SB3 only when a model is evaluated

    run_dir = check_sb3_run(controller, settings.env_id)
    _, model_zip, stats_pkl = sb3_files(controller)
    cfg = yaml.safe_load((run_dir / "config.yml").read_text())
    c, derived = cfg["config"], cfg["derived"]
    env = build_env(
        settings.env_id,
        c["residual"],
        c["scale_fraction"],
        derived["control_hz"],
        round(settings.episode_s * derived["control_hz"]),
        settings.start,
        None if disturbance == "none" else f"{disturbance}:{level}",
    )
    model = ALGOS[c["algo"]].load(str(model_zip), device="cpu")
    stats = None
    if derived.get("vec_normalize") and not stats_pkl.exists():
        raise InvalidConfigError(
            f"{controller}: the run normalizes observations but {stats_pkl} is missing"
        )
    if stats_pkl.exists():
        with stats_pkl.open("rb") as fh:
            stats = pickle.load(fh)  # a VecNormalize without its venv: normalize_obs works

    def act(obs: np.ndarray) -> np.ndarray:
        x = stats.normalize_obs(obs) if stats is not None else obs
        return model.predict(x, deterministic=True)[0]

    _SB3_CACHE[key] = (env, act)
    return env, act


def _first_impulse_end(schedule: list[dict[str, Any]]) -> float | None:
    ends = [d["onset_s"] + d["duration_s"] for d in schedule if d["type"] in ("impulse", "push")]
    return min(ends) if ends else None


def run_episode(
    task: Task, settings: EpisodeSettings, keep_trace: bool = False
) -> tuple[dict[str, Any], dict[str, np.ndarray] | None]:
    """Run ``task`` and return its CSV row (keys + metrics + wall time) and, with
    ``keep_trace``, the time series for the example-episode plots."""
    wall0 = time.perf_counter()
    diagnostics: Callable[[], dict[str, float]]
    if task.controller.startswith(SB3_PREFIX):
        env, act = _sb3_policy(task.controller, settings, task.disturbance, task.level)
        diagnostics = dict
        obs, _ = env.reset(seed=task.reset_seed)
    else:
        env = _env(settings, task.disturbance, task.level)
        policy = ControllerPolicy(env, make_controller(task.controller, env))
        act, diagnostics = policy.action, lambda: policy.last_diagnostics
        obs, _ = env.reset(seed=task.reset_seed)
        policy.reset_controller(obs)
    u = env.unwrapped
    rows: dict[str, list[Any]] = {k: [] for k in ("t", "q", "qd", "s_ref", "tau", "d", "energy")}
    unstable, info = False, {}
    while True:
        obs, _, terminated, truncated, info = env.step(act(obs))
        q, qd = u.joint_state()
        rows["t"].append(info["t_s"])
        rows["q"].append(q)
        rows["qd"].append(qd)
        rows["s_ref"].append(info["s_ref"])
        rows["tau"].append(info["tau_nm"])
        if keep_trace:
            rows["d"].append(info["path_distance"])
            diag = diagnostics()
            rows["energy"].append(
                [
                    diag.get("h_plus_w", np.nan),
                    diag.get("h_r", np.nan),
                    diag.get("phi", np.nan),
                    diag.get("psi", np.nan),
                    diag.get("energy", np.nan),
                    info["energy_j"],
                ]
            )
        if terminated or truncated:
            unstable = bool(info["unstable"])
            break
    record = EpisodeRecord(
        t_s=np.array(rows["t"]),
        q=np.array(rows["q"]),
        qd=np.array(rows["qd"]),
        s_ref=np.array(rows["s_ref"]),
        tau_nm=np.array(rows["tau"]),
        torque_limits_nm=u.torque_limits_nm,
        disturbance_work_j=float(info["disturbance_work_j"]),
        unstable=unstable,
        impulse_end_s=_first_impulse_end(u.disturbance_schedule()),
        intended_steps=env.spec.max_episode_steps if env.spec is not None else None,
    )
    metrics = episode_metrics(
        record,
        u.model,
        u.tables,
        failure_distance_rad=settings.failure_distance_rad,
        recovery_threshold_rad=settings.recovery_threshold_rad,
    )
    row = {
        **asdict(task),
        **metrics,
        "steps": len(record.t_s),
        "wall_s": time.perf_counter() - wall0,
    }
    row["level"] = f"{task.level:g}"
    trace = None
    if keep_trace:
        trace = {
            "t_s": record.t_s,
            "q": record.q,
            "q_ref": u.path.evaluate(record.s_ref)[0],
            "path_distance": np.array(rows["d"]),
            "energy": np.array(rows["energy"]),  # H+W_r(σ), H_r, φ, ψ, E (passivity), H
        }
    return row, trace
