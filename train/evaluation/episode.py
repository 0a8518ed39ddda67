"""One evaluation episode: a controller on an env under one disturbance, with one seed.

This is what a worker process runs. It needs nothing from the parent but a
:class:`Task` and the :class:`EpisodeSettings`, so the process and Ray backends run the
same function and give the same rows.

Pairing: the env's reset seed depends only on (seed, episode), never on the controller,
so every controller meets the same start state and — through the env's own disturbance
stream — the same disturbance schedule.

Controllers are names of ``agents.registry`` or ``sb3:<run folder>``: a model trained by
``ptrack train`` (pure or residual), rebuilt from the run's ``config.yml`` — its
residual base, scale and control rate — with its ``vecnormalize.pkl`` statistics when
present, acting deterministically; ``sb3:<run folder>@<steps>`` runs the run's checkpoint
of that many steps instead (:mod:`train.evaluation.policies`). A model runs at its training control
rate, so it meets the same disturbance schedule in time (onsets, frequencies) but per-step
noise draws differ; its env's disturbance horizon is the sweep's episode length, as for
every other controller. A model trained to decide every k steps (``decision_every``) runs
on the unrepeated env behind :class:`~agents.hold.HeldActionPolicy`, so every env step is
recorded. Either way the episode is one loop over a policy's ``predict``.

The feedback effort ``tau_fb_rms_frac`` (:func:`ptrack_gym.metrics.episode_metrics`) needs
the controller's own reference phase: :func:`rollout` reads a model-based controller's phase
s after each step (its ``diagnostics()["s"]``, through :func:`phase_reader`) and records
the nominal feed-forward τ_ff,k = ID(q_r(s_k), q_r'(s_k), q_r''(s_k)) of the env's model and
path at s_k = s − dt, the phase step k's torque was computed at (exact for the clocked
laws, whose phase advances by dt a step; within dt·|ṡ − 1| for the passivity law's). A
learned policy (``sb3:``) has no phase: its feedback effort is NaN.

Imports are kept to what an episode needs: torch and SB3 only when a model is evaluated.
"""

from __future__ import annotations

import dataclasses
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any, Protocol

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import OrderEnforcing, PassiveEnvChecker, TimeLimit

import ptrack_gym  # noqa: F401  (registers the envs)
from agents.base import Controller
from agents.hold import HeldActionPolicy
from agents.passivity import PassivityController
from agents.path_following import PathFollowingController
from agents.policy import ControllerPolicy
from agents.registry import make_controller
from agents.time_indexed import TimeIndexedController
from ptrack_gym.errors import ControllerDivergedError
from ptrack_gym.metrics import EpisodeRecord, episode_metrics, feedforward_torques
from train.evaluation.envs import build_env, env_kwargs, trained_wrapper_kwargs

#: Columns identifying an episode, in the CSV's order.
KEY_COLUMNS: tuple[str, ...] = ("controller", "disturbance", "level", "seed", "episode")
SB3_PREFIX = "sb3:"


class Predictor(Protocol):
    """Anything with SB3's ``predict`` (a ``ControllerPolicy``, a trained model)."""

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]: ...


@dataclass(frozen=True)
class EpisodeSettings:
    """Settings shared by every episode of a sweep (see ``train/configs/*.yml``)."""

    env_id: str
    episode_s: float
    control_hz: float
    start: str
    failure_distance_rad: float
    recovery_threshold_rad: float
    gains: str | tuple[tuple[str, Any], ...] = "default"
    """The model-based controllers' gains: "default", "tuned" (``agents/tuned``), or gain rates
    as sorted (name, value) pairs (what ``ptrack tune`` tries)."""
    path: str = "default"
    """The env's reference path family ("default": the path the RL entrants trained on)."""
    path_seed: int | None = None
    """Seed of a "random" path."""
    disturbance_sizing: str = "home"
    """How joint-torque disturbances are sized: by M(q_home) ("home") or by M(q) where they
    start to act ("onset"); the env's ``disturbance_sizing``."""

    controller_rates: tuple[tuple[str, tuple[tuple[str, Any], ...]], ...] = ()
    """Gain rates of some controllers over ``gains``, as sorted (controller, sorted (name,
    value) pairs) pairs (an evaluation config's ``controller_rates``)."""

    def controller_gains(self, controller: str | None = None, robot: str | None = None) -> Any:
        """The ``gains`` argument of ``make_controller`` for ``controller`` on ``robot``:
        ``gains``, with the controller's own rates over them if it has any."""
        gains = self.gains if isinstance(self.gains, str) else dict(self.gains)
        own = dict(self.controller_rates).get(controller)
        if not own:
            return gains
        if gains == "tuned":
            from agents.registry import tuned_rates

            gains = tuned_rates(str(robot), str(controller))
        return {**(gains if isinstance(gains, dict) else {}), **dict(own)}


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


def label(controller: str) -> str:
    """A file-name-safe label of a controller name (``sb3:runs/x`` → ``sb3-x``,
    ``sb3:runs/x@2000`` → ``sb3-x-2000``)."""
    if controller.startswith(SB3_PREFIX):
        from pathlib import Path

        run, _, steps = controller[len(SB3_PREFIX) :].partition("@")
        return "sb3-" + Path(run).name + (f"-{steps}" if steps else "")
    return controller


def _disturbance_text(disturbance: str, level: float) -> str | None:
    return None if disturbance == "none" else f"{disturbance}:{level}"


#: Per-process caches: building an env (and a model's env) costs more than an episode's
#: first steps; an episode resets its env, so reuse is safe. Keyed on what the env depends
#: on (never the controller's gains: a tuning study tries a new set every trial) and
#: bounded, least recently used evicted and closed: a worker's memory stays flat however
#: many conditions it runs.
_ENV_CACHE: OrderedDict[tuple[Any, ...], gym.Env[Any, Any]] = OrderedDict()
_SB3_ENV_CACHE: OrderedDict[tuple[Any, ...], gym.Env[Any, Any]] = OrderedDict()
_POLICY_CACHE: OrderedDict[tuple[Any, ...], Predictor] = OrderedDict()
_RUN_CACHE: OrderedDict[tuple[Any, ...], tuple[Any, ...]] = OrderedDict()
#: Most envs a worker keeps (an iiwa env holds ~30 MB, mostly its PyBullet client).
CACHE_SIZE = 16
#: Most policies a worker keeps (~1 MB each): more than a study's entrants of one robot,
#: which its tasks cycle through (a smaller LRU would evict each before its next use).
POLICY_CACHE_SIZE = 128


def _cached(
    cache: OrderedDict[tuple[Any, ...], Any],
    key: tuple[Any, ...],
    build: Any,
    size: int | None = None,
) -> Any:
    """``cache[key]``, built by ``build()`` if missing; the least recently used beyond
    ``size`` (default :data:`CACHE_SIZE`, read at the call) dropped, an env closed."""
    if key in cache:
        cache.move_to_end(key)
        return cache[key]
    value = cache[key] = build()
    while len(cache) > (CACHE_SIZE if size is None else size):
        _, old = cache.popitem(last=False)
        if isinstance(old, gym.Env):
            old.close()
    return value


def _env_key(settings: EpisodeSettings) -> EpisodeSettings:
    return dataclasses.replace(settings, gains="default", controller_rates=())


def settings_kwargs(settings: EpisodeSettings) -> dict[str, Any]:
    """The env arguments the sweep's settings fix: its reference path (``path``,
    ``path_seed``) and, where not the default, ``disturbance_sizing``."""
    extra: dict[str, Any] = {"path": settings.path, "path_seed": settings.path_seed}
    if settings.disturbance_sizing != "home":
        extra["disturbance_sizing"] = settings.disturbance_sizing
    return extra


def _env(settings: EpisodeSettings, disturbance: str, level: float) -> gym.Env[Any, Any]:
    steps = round(settings.episode_s * settings.control_hz)
    return _cached(
        _ENV_CACHE,
        (_env_key(settings), disturbance, level),
        lambda: gym.make(
            settings.env_id,
            **env_kwargs(
                settings.control_hz,
                steps,
                settings.start,
                _disturbance_text(disturbance, level),
                extra=settings_kwargs(settings),
            ),
        ),
    )


def _run_files(controller: str) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any] | None]:
    """A run's ``config`` and ``derived`` and its residual wrapper's arguments (None for a
    pure policy), read once per worker (``_RUN_CACHE``), not once per episode."""
    from train.evaluation.policies import deploy_safeguards, run_config, sb3_files

    run_dir = sb3_files(controller)[0]
    cfg = run_config(run_dir)
    c = cfg["config"]
    wrapper = (
        {  # the gate acts on the torque; the penalty only on the reward
            **trained_wrapper_kwargs(cfg),  # the base's rates as it trained over
            **deploy_safeguards(run_dir),  # deploy.yml's gate wins
        }
        if c["residual"] != "none"
        else None
    )
    return c, cfg["derived"], wrapper


def _sb3_env_and_policy(
    controller: str, settings: EpisodeSettings, disturbance: str, level: float
) -> tuple[gym.Env[Any, Any], Predictor]:
    """The env a run ``controller`` (``sb3:…``) acts in under the condition, and its policy.

    Both cached per worker, apart: the policy per run (loading one costs ~0.1–1 s), the env
    per what builds it — the run's observation, residual base, scale, rate, wrapper
    arguments and the condition — so the seeds of one campaign group share their envs
    (a residual env's base tables cost ~1 s a path). An env's episode starts from
    ``reset(seed)`` alone, so which run used it before changes nothing."""
    from train.evaluation.policies import load_sb3_policy

    c, derived, wrapper = _cached(_RUN_CACHE, (controller,), lambda: _run_files(controller),
                                  POLICY_CACHE_SIZE)  # fmt: skip
    build_args = (
        c["env_id"],  # the run's own observation (plain, or the preview id's)
        c["residual"],
        c["scale_fraction"],
        derived["control_hz"],
        round(settings.episode_s * derived["control_hz"]),
        settings.start,
        _disturbance_text(disturbance, level),
    )
    env_key = (*build_args, repr(wrapper), _env_key(settings), disturbance, level)
    env = _cached(
        _SB3_ENV_CACHE,
        env_key,
        lambda: build_env(*build_args, extra=settings_kwargs(settings), residual_kwargs=wrapper),
    )

    def load() -> Predictor:
        import torch

        # One observation per call: more torch threads only contend with the sweep's other
        # runners (the sweep's own process runs episodes too, beside its spawned workers).
        torch.set_num_threads(1)
        policy, _ = load_sb3_policy(controller, settings.env_id)
        k = int(c.get("decision_every", 1))
        return policy if k == 1 else HeldActionPolicy(policy, k)

    return env, _cached(_POLICY_CACHE, (controller, settings.env_id), load, POLICY_CACHE_SIZE)


def phase_reader(controller: Controller) -> Callable[[], float]:
    """A function returning ``controller.diagnostics()["s"]``, the controller's reference
    phase after its last step (s), read without the rest of the diagnostics (a Slotine–Li
    law's cost a mass matrix, ~20% of an episode when read every step): the clock of a
    time-indexed law, the inner clock of the path-following one, s of the passivity law's
    (s, ṡ, σ); ``diagnostics()`` itself for any other controller."""
    if isinstance(controller, TimeIndexedController):
        clock = controller.clock
        return lambda: float(clock.s)  # type: ignore[arg-type]
    if isinstance(controller, PathFollowingController):
        inner = controller.inner.clock
        return lambda: float(inner.s)  # type: ignore[arg-type]
    if isinstance(controller, PassivityController):
        return lambda: controller.state.s
    return lambda: float(controller.diagnostics()["s"])


#: ``on_step(env, policy, info)``: what :func:`rollout` calls after every step (``info`` the
#: step's), and with ``info=None`` once when the policy diverged before a step.
StepHook = Callable[[gym.Env[Any, Any], Any, dict[str, Any] | None], None]


def _first_impulse_end(schedule: list[dict[str, Any]]) -> float | None:
    ends = [d["onset_s"] + d["duration_s"] for d in schedule if d["type"] in ("impulse", "push")]
    return min(ends) if ends else None


def rollout(
    env: gym.Env[Any, Any],
    policy: Predictor,
    reset_seed: int,
    keep_trace: bool = False,
    lean: bool = True,
    reset_options: dict[str, Any] | None = None,
    on_step: StepHook | None = None,
) -> tuple[EpisodeRecord, np.ndarray | None]:
    """One episode of ``policy`` on ``env`` from ``env.reset(seed=reset_seed)`` until it
    terminates or is truncated (``reset_options``: the env's, e.g. ``{"s0": …}``): the
    :class:`EpisodeRecord` and, with ``keep_trace``, the
    policy's storage terms per step (the passivity controller's H + W_r(σ), H_r, φ, ψ, E;
    NaN for other policies). The record of a :class:`~agents.policy.ControllerPolicy` holds
    the nominal feed-forward along the controller's phase (``tau_ff_nm``, module docstring);
    any other policy's none. A controller that diverges (a non-finite torque,
    :class:`~ptrack_gym.errors.ControllerDivergedError`) ends the episode as unstable at
    the step it would have taken. The one episode loop of the package, for anything with SB3's
    ``predict``. ``on_step(env, policy, info)`` is called after every step with its info
    (after the policy acted on the state that step began from), and once with ``info=None``
    when the policy diverged before a step (:data:`StepHook`).

    With ``lean`` (default), a :class:`~agents.policy.ControllerPolicy` on an env that
    ``gym.make`` wrapped only in ``TimeLimit``, ``OrderEnforcing`` and ``PassiveEnvChecker``
    runs on ``env.unwrapped`` with the policy's ``action`` and the time limit counted here:
    the same calls in the same order as the wrapped loop, so the episode is bit-identical
    (tested), 2–3 µs (7–9%) cheaper per step on the iiwa. Anything else runs through ``env`` and
    ``predict``."""
    u = env.unwrapped
    rows: dict[str, list[Any]] = {
        k: [] for k in ("t", "q", "qd", "s_ref", "tau", "d", "path_s", "e", "energy")
    }
    unstable, info = False, {}
    limit = _lean_limit(env, policy) if lean else None
    phase = phase_reader(policy.controller) if isinstance(policy, ControllerPolicy) else None
    phases: list[float] = []
    if limit is not None:  # the same calls, in the same order, without the layers around
        assert isinstance(policy, ControllerPolicy)
        obs, _ = u.reset(seed=reset_seed, options=reset_options)
        policy.reset_controller(obs)  # what predict does when episode_start is set
        act, step = policy.action, u.step
    else:
        obs, _ = env.reset(seed=reset_seed, options=reset_options)
        starts = [np.ones(1, dtype=bool)]

        def act(observation: np.ndarray) -> np.ndarray:
            action, _ = policy.predict(observation, episode_start=starts[0], deterministic=True)
            starts[0] = np.zeros(1, dtype=bool)
            return action

        step = env.step
    steps = 0
    while True:
        try:
            action = act(obs)
        except ControllerDivergedError:  # a non-finite torque: the closed loop is unstable
            unstable = True
            if on_step is not None:
                on_step(env, policy, None)
            break
        obs, _, terminated, truncated, info = step(action)
        if on_step is not None:
            on_step(env, policy, info)
        steps += 1
        if limit is not None and steps >= limit:  # gymnasium's TimeLimit, inlined
            truncated = True
        q, qd = u.joint_state()
        rows["t"].append(info["t_s"])
        rows["q"].append(q)
        rows["qd"].append(qd)
        rows["s_ref"].append(info["s_ref"])
        rows["tau"].append(info["tau_nm"])
        rows["d"].append(info["path_distance"])
        rows["path_s"].append(info["path_s"])
        rows["e"].append(info["tracking_error"])
        if phase is not None:
            phases.append(phase())
        if keep_trace:
            diag: dict[str, float] = getattr(policy, "last_diagnostics", {})
            rows["energy"].append(
                [diag.get(k, np.nan) for k in ("h_plus_w", "h_r", "phi", "psi", "energy")]
            )
        if terminated or truncated:
            unstable = bool(info["unstable"])
            break
    n = u.n  # (steps, n) arrays even when no step was taken
    record = EpisodeRecord(
        t_s=np.array(rows["t"]),
        q=np.array(rows["q"]).reshape(-1, n),
        qd=np.array(rows["qd"]).reshape(-1, n),
        s_ref=np.array(rows["s_ref"]),
        tau_nm=np.array(rows["tau"]).reshape(-1, n),
        torque_limits_nm=u.torque_limits_nm,
        disturbance_work_j=float(info.get("disturbance_work_j", 0.0)),  # {} if none stepped
        unstable=unstable,
        impulse_end_s=_first_impulse_end(u.disturbance_schedule()),
        intended_steps=env.spec.max_episode_steps if env.spec is not None else None,
        path_distance=np.array(rows["d"]),
        path_s=np.array(rows["path_s"]),
        tracking_error=np.array(rows["e"]),
        tau_ff_nm=feedforward_torques(u.model, u.path, np.array(phases) - u.dt).reshape(-1, n)
        if phase is not None
        else None,
    )
    return record, (np.array(rows["energy"]) if keep_trace else None)


#: The wrappers ``gym.make`` adds that change no number of an episode run to its end.
_PASSIVE_WRAPPERS = (TimeLimit, OrderEnforcing, PassiveEnvChecker)


def _lean_limit(env: gym.Env[Any, Any], policy: Predictor) -> int | None:
    """The step limit of ``env``'s ``TimeLimit`` when :func:`rollout` may run ``policy``
    on ``env.unwrapped`` (see there), else None."""
    if not isinstance(policy, ControllerPolicy) or policy.env is not env.unwrapped:
        return None
    limit, layer = None, env
    while isinstance(layer, gym.Wrapper):
        if not isinstance(layer, _PASSIVE_WRAPPERS):
            return None
        if isinstance(layer, TimeLimit):
            limit = layer._max_episode_steps
        layer = layer.env
    return limit


def run_episode(
    task: Task,
    settings: EpisodeSettings,
    keep_trace: bool = False,
    inspect: Callable[[gym.Env[Any, Any]], dict[str, Any]] | None = None,
    on_step: StepHook | None = None,
) -> tuple[dict[str, Any], dict[str, np.ndarray] | None]:
    """Run ``task`` and return its CSV row (keys + metrics + wall time, and what
    ``inspect(env)`` reads off the env once the episode ended) and, with ``keep_trace``, the
    time series for the example-episode plots (``on_step``: :func:`rollout`'s)."""
    wall0 = time.perf_counter()
    policy: Predictor
    if task.controller.startswith(SB3_PREFIX):
        env, policy = _sb3_env_and_policy(task.controller, settings, task.disturbance, task.level)
    else:
        env = _env(settings, task.disturbance, task.level)
        gains = settings.controller_gains(task.controller, env.unwrapped.robot_profile.name)
        controller = make_controller(task.controller, env, gains)
        policy = ControllerPolicy(env, controller)
    u = env.unwrapped
    record, storage = rollout(env, policy, task.reset_seed, keep_trace, on_step=on_step)
    metrics = episode_metrics(
        record,
        u.model,
        u.projector,
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
    if inspect is not None:
        row.update(inspect(env))
    trace = None
    if keep_trace:
        assert storage is not None
        trace = {
            "t_s": record.t_s,
            "q": record.q,
            "q_ref": u.path.evaluate(record.s_ref)[0],
            "path_distance": record.path_distance,
            # H+W_r(σ), H_r, φ, ψ, E (passivity), and the arm's H(q, q̇) by the nominal model
            "energy": np.column_stack(
                [
                    storage,
                    [
                        u.model.kinetic_energy(q, qd) + u.model.potential(q)
                        for q, qd in zip(record.q, record.qd, strict=True)
                    ],
                ]
            ),
        }
    return row, trace
