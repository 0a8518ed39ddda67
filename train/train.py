"""Train SAC, TD3 or PPO on a ptrack_gym env, pure or residual on a base controller.

Run from the repository root::

    python -m train.train --algo sac --env ptrack_gym/TwoLinkTrack-v0 \\
        --residual passivity --disturbance impulse:0.5 --steps 50000 --out runs/sac_tl

Everything one run needs is one :class:`TrainConfig`; the CLI fills it (``--help``). The
hyperparameters come from ``train/hyperparams/<algo>.yml`` (rl-baselines3-zoo format, see
:mod:`train.hyperparameters` and ``docs/rl.md``), then ``--hyperparams FILE``, then
``--set key=value``. Every configuration error — unknown algorithm, env id, residual
base, disturbance, env argument (checked by the env's own validator) or hyperparameter —
raises :class:`TrainConfigError` (a ``ValueError``) or an argparse error *before* any env
is built or any file written. Envs come from :func:`train.envs.build_env`, checkpoints
from :mod:`train.checkpoints`.

The run folder ``--out`` receives ``config.yml`` (the resolved config and
hyperparameters), ``command.txt`` (one line per invocation), ``versions.json``,
``model.zip`` and ``vecnormalize.pkl`` (final), ``best_model.zip`` (EvalCallback),
``eval/`` and ``monitor/`` (per invocation), ``tb/`` (``--tensorboard``) and
``checkpoints/rl_model_<steps>_steps.zip`` with the matching VecNormalize statistics and,
for the newest checkpoint only, the replay buffer (the final state is always saved there
too, so ``--resume`` can continue any finished or interrupted run). An interrupted run —
Ctrl-C, or SIGTERM — saves ``model.zip`` and a checkpoint at the step it reached before it
exits (nothing trained is lost, and ``model.zip`` is never older than the newest
checkpoint), then re-raises ``KeyboardInterrupt``.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import platform
import shlex
import signal
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from functools import partial
from importlib import metadata
from pathlib import Path
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
import torch
import yaml
from stable_baselines3 import PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, EvalCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import configure as configure_logger
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecNormalize
from torch import nn

from agents.hold import check_decision_every
from agents.registry import CONTROLLER_NAMES, GAIN_CHOICES, tuned_rates
from agents.residual import (
    RESIDUAL_BASES,
    check_base_gains,
    check_base_model,
    check_prior,
    check_safeguards,
)
from ptrack_gym.envs.rewards import REWARD_MODES
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots import profile_for_env_id
from train.checkpoints import (
    CHECKPOINT_PREFIX,
    PruningCheckpointCallback,
    latest_checkpoint,
    load_checkpoint,
    save_checkpoint,
    save_final,
)
from train.envs import (
    WRAPPER_DEFAULTS,
    build_decision_env,
    build_env,
    check_env_kwargs,
    env_kwargs,
    residual_wrapper_kwargs,
)
from train.hyperparameters import (
    TrainConfigError,
    action_noise,
    load_hyperparams,
    parse_python_literal,
    parse_set,
    resolve_hyperparams,
)
from train.imitation import (
    DaggerSpec,
    add_demo_bc,
    dagger,
    load_demonstrations,
    save_demonstrations,
)
from train.sb3_runs import ALGOS, BACKENDS, algo_class

#: ``--residual`` choices: "none" (pure RL), a base controller name, or "network" (a saved
#: pure policy, ``base_model``).
RESIDUAL_CHOICES: tuple[str, ...] = ("none", *RESIDUAL_BASES)

__all__ = [
    "ALGOS",
    "TrainConfig",
    "TrainConfigError",
    "TrainResult",
    "build_env",
    "main",
    "parse_args",
    "parse_python_literal",
    "run",
    "scale_actor_lr",
    "validate",
    "zero_init_actor",
]


@dataclass
class TrainConfig:
    """Everything that defines one training run (SI units where physical)."""

    out: str
    """Run folder: config, checkpoints, final model, logs."""
    algo: str = "sac"
    """Algorithm: "sac", "td3" or "ppo"."""
    backend: str = "sb3"
    """Its implementation: "sb3" (Stable-Baselines3, torch) or "sbx" (the SB3 team's JAX port,
    the optional ``sbx`` extra; the same interface, callbacks and files). The residual
    safeguards that act on the torch actor (``zero_init_residual``, ``init_log_std``,
    ``critic_warmup_steps``, ``actor_lr_scale``, ``actor_bc_weight``) are sb3's only."""
    env_id: str = "ptrack_gym/TwoLinkTrack-v0"
    """A ptrack_gym env id (``ptrack_gym.ENV_IDS``)."""
    residual: str = "none"
    """"none" for pure RL, or the base controller of a residual policy (agents.registry)."""
    scale_fraction: float = 0.1
    """Residual authority: scale = scale_fraction · τ_max per joint (N·m)."""
    scale_accel_rad_s2: float | None = None
    """Residual only: the residual as a joint acceleration instead of ``scale_fraction``:
    τ_res = M(q) α a, α in rad/s² (``agents.residual``)."""
    base_gains: str = "default"
    """Residual only: the base controller's gains, "default" (the robot's default rates at
    the control rate) or "tuned" (``agents/tuned``, the main job's); evaluation rebuilds
    the run's env with the same."""
    base_model: str | None = None
    """``residual="network"`` only: the folder of the saved pure SAC policy that is the base
    (``model.zip``, ``vecnormalize.pkl``; ``agents.network``) — RL then learns a correction
    to a frozen policy, e.g. an imitation (``imitate``), without touching its weights."""
    disturbance: str = "none"
    """Training disturbance: "none", a preset ("impulse") or "preset:level" ("push:0.5")."""
    eval_disturbance: str | None = None
    """Disturbance of the evaluation env, same syntax; None → the training disturbance."""
    steps: int | None = None
    """Environment steps to train in this invocation (added to a resumed count); None →
    the hyperparameter file's ``n_timesteps``."""
    seed: int = 0
    """Seed of the model, the training envs (seed … seed + n_envs − 1), eval env seed + 1000."""
    hyperparams: str | None = None
    """A YAML file (same format as train/hyperparams/<algo>.yml) merged over the packaged one."""
    overrides: dict[str, Any] = field(default_factory=dict)
    """Hyperparameter overrides (``--set key=value``), applied last."""
    n_envs: int | None = None
    """Parallel training envs (DummyVecEnv); None → the YAML's ``n_envs``, else 1."""
    vec_normalize: bool | None = None
    """Wrap the envs in VecNormalize; None → the YAML's ``normalize``, else False."""
    eval_freq: int = 10_000
    """Evaluate every this many env steps (summed over envs); 0 disables evaluation."""
    eval_episodes: int = 5
    """Episodes per evaluation."""
    checkpoint_freq: int = 50_000
    """Checkpoint every this many env steps (summed over envs); 0: only the final one."""
    resume: bool = False
    """Continue from the newest checkpoint in ``out`` (model, replay buffer, VecNormalize)."""
    zero_init_residual: bool = False
    """Zero the actor's output layer (SAC/TD3 mu, PPO action_net): the policy starts at a = 0."""
    progress_bar: bool = False
    """Show SB3's progress bar (tqdm + rich)."""
    tensorboard: bool = False
    """Log to TensorBoard under ``out/tb/from_<steps>`` (progress.csv is written there always)."""
    control_hz: float | None = None
    """Control rate (Hz); None → the robot profile's ``default_control_hz``. Physics: 1 kHz."""
    episode_s: float = 5.0
    """Episode length (s): max_episode_steps = round(episode_s · control_hz)."""
    start: str = "on_path"
    """The env's start mode: "on_path" or "rest_near_path"."""
    reward_weights: list[float] | None = None
    """The env's reward weights [path, time, effort] (see ``TrackingEnv``); None → the
    env's default (10, 1, 0.01). The evaluation env uses the same."""
    reward: str = "quadratic"
    """The env's reward: "quadratic" (its default, unbounded) or "kernel" (bounded in [0, 1],
    ``ptrack_gym.envs.rewards``). The evaluation env uses the same."""
    kernel_weights: list[float] | None = None
    """With ``reward="kernel"``: its weights [path, time, effort]; None → the env's default
    (0.5, 0.4, 0.1)."""
    max_path_distance: float | None = None
    """End a training episode when the path distance exceeds this (rad); None: never."""
    action_penalty: float = 0.0
    """Residual only: w of the penalty on the learned part, r + w (1 − |a|²/n)."""
    gate_rad: float | None = None
    """Residual only: gate the residual by the path error, γ = 1 − exp(−((d − d₀)⁺/gate_rad)²)."""
    gate_deadband_rad: float = 0.0
    """Residual with a gate only: d₀ (rad), the residual is exactly 0 while d ≤ d₀."""
    init_log_std: float | None = None
    """SAC only: the actor's log-std layer starts constant at this value (exploration
    std exp(init_log_std) before tanh); None: SB3's initialisation."""
    decision_every: int = 1
    """The policy decides every this many control steps and its action is held in between
    (``agents.hold.ActionRepeat``; the env and a residual's base still run every step):
    ``steps``, checkpoints and warm-ups then count decisions, each worth this many env steps,
    and the reward of a decision is the mean of its steps'. Evaluation holds the action the
    same way (``agents.hold.HeldActionPolicy``). 1: every step."""
    critic_warmup_steps: int = 0
    """Off-policy only: the actor is frozen (its parameters get no update) for this many
    steps after ``learning_starts`` while the critic learns from what it does; with
    ``--zero-init-residual`` that is the base controller plus exploration noise."""
    actor_lr_scale: float = 1.0
    """SAC/TD3 only: the actor's learning rate is this times the schedule's (the critic's
    and the entropy coefficient's keep it): with Adam, how far the actor's output moves per
    update scales with it (``scale_actor_lr``)."""
    prior_gain_per_rad: float = 0.0
    """Residuals only: g (1/rad) of a control prior the learned action is added to,
    a_eff = clip(a + clip(g (q_r(s) − q), −1, 1), −1, 1), q_r(s) − q the base's own reference
    error (``agents.residual.PRIOR_ERROR_FEATURES``); with
    ``zero_init_residual`` the policy starts as the prior and ``actor_bc_weight`` pulls
    toward it. 0: none."""
    imitate: str | None = None
    """Pure SAC only: start the actor as a copy of this model-based controller (a name of
    ``agents.registry``) learned by DAgger before RL (``train.imitation``); None: no
    imitation. The run folder gets ``demonstrations.npz``, ``imitation.json`` and a
    checkpoint at step 0 (the imitation alone)."""
    imitate_gains: str = DaggerSpec.gains
    """The expert's gains: "default" or "tuned"."""
    imitate_rounds: int = DaggerSpec.rounds
    """DAgger rounds after round 0 (0: behaviour cloning of the expert's own runs only)."""
    imitate_steps: int = DaggerSpec.first_steps
    """Env steps of round 0 (the expert drives)."""
    imitate_round_steps: int = DaggerSpec.round_steps
    """Env steps of each further round (the network drives, the expert labels)."""
    imitate_noise: float = DaggerSpec.noise
    """Std of the Gaussian added to every executed action while imitating (a = τ/τ_max)."""
    demo_bc_weight: float = 0.0
    """With ``imitate``: λ of a pull toward the expert's labels during RL,
    λ·E_(s,a_E)[|tanh(μ(s)) − a_E|²/n] added to the actor's loss (``add_demo_bc``); 0: none."""
    actor_bc_weight: float = 0.0
    """SAC/TD3 only: λ of a behaviour-cloning term toward the base, λ·E_s[|μ(s)|²/n] added to
    the actor's loss (μ the deterministic action in [−1, 1]ⁿ, s drawn from the replay
    buffer; TD3+BC's term with the base's action 0 as the target): the actor leaves 0 only
    where the critic's action gradient exceeds 2λ|μ_j|/n (``add_actor_bc``). With a control
    prior (``prior_gain_per_rad``) a = 0 is the prior, so the pull is toward it."""
    torch_threads: int = 1
    """``torch.set_num_threads`` (the machines are shared: keep 1)."""
    device: str = "cpu"
    """Torch device."""
    verbose: int = 0
    """SB3 verbosity (0, 1, 2)."""


class TrainResult(NamedTuple):
    """What :func:`run` returns."""

    model: BaseAlgorithm  # the trained model (its envs are closed)
    run_dir: Path  # the run folder
    num_timesteps: int  # the model's step count at the end


# -- validation ------------------------------------------------------------------------
class Resolved(NamedTuple):
    """A validated config with everything derived from it."""

    cfg: TrainConfig
    robot: str
    control_hz: float
    max_episode_steps: int
    algo_kwargs: dict[str, Any]
    special: dict[str, Any]
    steps: int
    n_envs: int
    normalize_kwargs: dict[str, Any] | None  # None: no VecNormalize
    env_extra: dict[str, Any]  # further env arguments (reward mode, off-path end)
    residual_kwargs: dict[str, Any]  # the residual wrapper's safeguards


def validate(cfg: TrainConfig) -> Resolved:
    """Check every field and resolve the hyperparameters; touches no file or env.

    Raises:
        TrainConfigError: the first problem found, with the valid choices.
    """
    if cfg.algo not in ALGOS:
        raise TrainConfigError(f"unknown algo {cfg.algo!r}; known: {sorted(ALGOS)}")
    if cfg.backend not in BACKENDS:
        raise TrainConfigError(f"unknown backend {cfg.backend!r}; known: {list(BACKENDS)}")
    if cfg.backend == "sbx":
        torch_only = [
            name
            for name, on in (
                ("zero_init_residual", cfg.zero_init_residual),
                ("init_log_std", cfg.init_log_std is not None),
                ("critic_warmup_steps", cfg.critic_warmup_steps != 0),
                ("actor_lr_scale", cfg.actor_lr_scale != 1.0),
                ("actor_bc_weight", cfg.actor_bc_weight != 0.0),
                ("imitate", cfg.imitate is not None),
            )
            if on
        ]
        if torch_only:
            raise TrainConfigError(
                f"{', '.join(torch_only)}: implemented on SB3's torch actor, not for backend "
                "'sbx' (use --backend sb3)"
            )
    if cfg.residual not in RESIDUAL_CHOICES:
        raise TrainConfigError(
            f"unknown residual base {cfg.residual!r}; known: {list(RESIDUAL_CHOICES)}"
        )
    if not (math.isfinite(cfg.scale_fraction) and cfg.scale_fraction >= 0):
        raise TrainConfigError(f"scale_fraction must be >= 0, got {cfg.scale_fraction}")
    if not (math.isfinite(cfg.episode_s) and cfg.episode_s > 0):
        raise TrainConfigError(f"episode_s must be positive, got {cfg.episode_s}")
    residual_kwargs = residual_wrapper_kwargs(dataclasses.asdict(cfg))
    if cfg.residual == "none":
        if residual_kwargs != WRAPPER_DEFAULTS:
            raise TrainConfigError(f"{', '.join(WRAPPER_DEFAULTS)} need a residual base")
        residual_kwargs = {}
    if cfg.critic_warmup_steps < 0:
        raise TrainConfigError(f"critic_warmup_steps must be >= 0, got {cfg.critic_warmup_steps}")
    if cfg.critic_warmup_steps and cfg.algo == "ppo":
        raise TrainConfigError("critic_warmup_steps needs an off-policy algorithm (sac, td3)")
    if not (math.isfinite(cfg.actor_lr_scale) and 0 < cfg.actor_lr_scale <= 1):
        raise TrainConfigError(f"actor_lr_scale must be in (0, 1], got {cfg.actor_lr_scale}")
    if cfg.actor_lr_scale != 1.0 and cfg.algo == "ppo":
        raise TrainConfigError("actor_lr_scale needs an actor optimizer (sac, td3)")
    if not (math.isfinite(cfg.actor_bc_weight) and cfg.actor_bc_weight >= 0):
        raise TrainConfigError(f"actor_bc_weight must be >= 0, got {cfg.actor_bc_weight}")
    if cfg.actor_bc_weight and cfg.algo == "ppo":
        raise TrainConfigError("actor_bc_weight needs an actor optimizer (sac, td3)")
    _validate_imitation(cfg)
    if cfg.init_log_std is not None and (cfg.algo != "sac" or not math.isfinite(cfg.init_log_std)):
        raise TrainConfigError("init_log_std is a finite number, for sac only")
    env_extra: dict[str, Any] = {"reward": cfg.reward}
    if cfg.kernel_weights is not None:
        env_extra["kernel_weights"] = tuple(cfg.kernel_weights)
    if cfg.max_path_distance is not None:
        env_extra["max_path_distance_rad"] = cfg.max_path_distance
    try:
        check_base_gains(cfg.base_gains)
        profile = profile_for_env_id(cfg.env_id)
        control_hz = profile.default_control_hz if cfg.control_hz is None else cfg.control_hz
        max_episode_steps = max(1, round(cfg.episode_s * control_hz))
        for text in (cfg.disturbance, cfg.eval_disturbance or cfg.disturbance):
            check_env_kwargs(
                cfg.env_id,
                env_kwargs(
                    control_hz, max_episode_steps, cfg.start, text, cfg.reward_weights, env_extra
                ),
            )
        if residual_kwargs:
            own = ("base_gains", "prior_gain_per_rad", "base_model")
            check_safeguards(**{k: v for k, v in residual_kwargs.items() if k not in own})
            check_prior(cfg.residual, cfg.prior_gain_per_rad)
            check_base_model(cfg.residual, cfg.base_model, profile.name, cfg.base_gains)
            if cfg.base_gains == "tuned":
                tuned_rates(profile.name, cfg.residual)  # raises naming the tuned files there are
        if cfg.imitate is not None and cfg.imitate_gains == "tuned":
            tuned_rates(profile.name, cfg.imitate)  # likewise, for the expert
    except InvalidConfigError as exc:
        raise TrainConfigError(str(exc)) from None
    for name in ("eval_freq", "checkpoint_freq"):
        if getattr(cfg, name) < 0:
            raise TrainConfigError(f"{name} must be >= 0")
    if cfg.eval_episodes < 1 or cfg.torch_threads < 1:
        raise TrainConfigError("eval_episodes and torch_threads must be >= 1")
    raw = load_hyperparams(cfg.algo, cfg.env_id, cfg.hyperparams, cfg.overrides)
    algo_kwargs, special = resolve_hyperparams(cfg.algo, raw, cfg.backend)
    if cfg.imitate is not None and int(algo_kwargs.get("learning_starts", 100)) != 0:
        raise TrainConfigError(
            "imitate needs learning_starts=0 (--set learning_starts=0): SB3 acts uniformly at "
            "random until learning_starts, which throws the arm off the path the imitation "
            "tracks and fills the replay buffer with it"
        )
    steps = cfg.steps if cfg.steps is not None else special.get("n_timesteps")
    if steps is None or int(steps) < 1:
        raise TrainConfigError(f"steps must be >= 1 (or n_timesteps in the YAML), got {steps}")
    n_envs = int(cfg.n_envs if cfg.n_envs is not None else special.get("n_envs", 1))
    if n_envs < 1:
        raise TrainConfigError(f"n_envs must be >= 1, got {n_envs}")
    normalize = special.get("normalize", False)
    if cfg.vec_normalize is not None:
        normalize = (normalize or {}) if cfg.vec_normalize else False
    normalize_kwargs = None
    if normalize is not False:
        normalize_kwargs = dict(normalize) if isinstance(normalize, dict) else {}
        normalize_kwargs.setdefault("gamma", float(algo_kwargs.get("gamma", 0.99)))
    run_dir = Path(cfg.out)
    if cfg.resume:
        if latest_checkpoint(run_dir) is None:
            raise TrainConfigError(f"--resume: no checkpoint in {run_dir / 'checkpoints'}")
        _check_resume_compatible(cfg, run_dir)
    elif (run_dir / "config.yml").exists():
        raise TrainConfigError(f"{run_dir} already holds a run; use --resume or a new --out")
    return Resolved(
        cfg,
        profile.name,
        float(control_hz),
        max_episode_steps,
        algo_kwargs,
        special,
        int(steps),
        n_envs,
        normalize_kwargs,
        env_extra,
        residual_kwargs,
    )


#: The demonstration pull's random stream, apart from DAgger's (seeded by the run's seed
#: alone): np.random.default_rng([seed, DEMO_BC_STREAM, steps at its start]).
DEMO_BC_STREAM = 7919


def _validate_imitation(cfg: TrainConfig) -> None:
    try:
        check_decision_every(cfg.decision_every)
    except InvalidConfigError as exc:
        raise TrainConfigError(str(exc)) from None
    if cfg.imitate is not None and cfg.decision_every != 1:
        raise TrainConfigError("imitate labels every control step: keep decision_every 1")
    if not (math.isfinite(cfg.demo_bc_weight) and cfg.demo_bc_weight >= 0):
        raise TrainConfigError(f"demo_bc_weight must be >= 0, got {cfg.demo_bc_weight}")
    if cfg.imitate is None:
        if cfg.demo_bc_weight:
            raise TrainConfigError("demo_bc_weight needs imitate (the expert's demonstrations)")
        return
    if cfg.imitate not in CONTROLLER_NAMES:
        raise TrainConfigError(
            f"unknown expert {cfg.imitate!r} for imitate; known: {list(CONTROLLER_NAMES)}"
        )
    if cfg.residual != "none" or cfg.algo != "sac":
        raise TrainConfigError("imitate is for pure SAC (residual none, algo sac)")
    if cfg.imitate_gains not in GAIN_CHOICES:
        raise TrainConfigError(
            f"imitate_gains must be one of {GAIN_CHOICES}, got {cfg.imitate_gains!r}"
        )
    if cfg.init_log_std is None:
        raise TrainConfigError(
            "imitate needs init_log_std: the fit trains the actor's mean only, so its "
            "exploration std would be whatever the shared layers make of the log-std head"
        )
    if cfg.imitate_rounds < 0 or cfg.imitate_steps < 1 or cfg.imitate_round_steps < 1:
        raise TrainConfigError("imitate_rounds must be >= 0, imitate_(round_)steps >= 1")
    if not (math.isfinite(cfg.imitate_noise) and cfg.imitate_noise >= 0):
        raise TrainConfigError(f"imitate_noise must be >= 0, got {cfg.imitate_noise}")


def dagger_spec(cfg: TrainConfig) -> DaggerSpec:
    """The imitation a config asks for (``cfg.imitate`` set)."""
    assert cfg.imitate is not None
    return DaggerSpec(
        controller=cfg.imitate,
        gains=cfg.imitate_gains,
        rounds=cfg.imitate_rounds,
        first_steps=cfg.imitate_steps,
        round_steps=cfg.imitate_round_steps,
        noise=cfg.imitate_noise,
    )


def imitate(res: Resolved, model: BaseAlgorithm, train_env: VecEnv, run_dir: Path) -> None:
    """DAgger of ``res.cfg.imitate`` into ``model``'s actor on an env built like the
    training env (``train.imitation.dagger``, seeded by the run's seed); saves the
    demonstrations and a checkpoint at step 0 — the imitation alone, the first point of
    the run's learning curve (model and VecNormalize statistics; no replay buffer)."""
    cfg = res.cfg
    spec = dagger_spec(cfg)
    env = _env_factory(res, cfg.disturbance)()
    try:
        vec_normalize = train_env if isinstance(train_env, VecNormalize) else None
        demos = dagger(model, env, spec, cfg.seed, vec_normalize)  # type: ignore[arg-type]
    finally:
        env.close()
    save_demonstrations(demos, run_dir, spec)
    if isinstance(train_env, VecNormalize):
        # The actor was fitted to these statistics (round 0's): frozen from here on, or
        # the same actor would see other inputs as RL's episodes move them (measured: one
        # seed's frozen actor went from 0 to 10 of 10 test episodes failed in 10 000 steps).
        train_env.training = False
    save_checkpoint(model, train_env, run_dir, replay_buffer=False)


#: TrainConfig's defaults, for the keys a run written before they existed lacks.
_FIELD_DEFAULTS: dict[str, Any] = {
    f.name: f.default
    for f in dataclasses.fields(TrainConfig)
    if f.default is not dataclasses.MISSING
}


def _check_resume_compatible(cfg: TrainConfig, run_dir: Path) -> None:
    path = run_dir / "config.yml"
    if not path.exists():
        return
    saved = yaml.safe_load(path.read_text()).get("config", {})
    for key in ("algo", "backend", "env_id", "residual", "scale_fraction", "scale_accel_rad_s2",
                "base_gains", "base_model", "decision_every", "start", "episode_s",
                "reward_weights", "reward", "kernel_weights",
                "max_path_distance", "action_penalty", "gate_rad",
                "gate_deadband_rad", "prior_gain_per_rad", "imitate", "imitate_gains",
                "imitate_rounds", "imitate_steps", "imitate_round_steps", "imitate_noise",
                "demo_bc_weight"):  # fmt: skip
        mine = getattr(cfg, key)
        theirs = saved.get(key, _FIELD_DEFAULTS.get(key, mine))  # a key the run predates
        if theirs != mine:
            raise TrainConfigError(f"--resume: {key}={mine!r} differs from the run's {theirs!r}")


# -- environments ----------------------------------------------------------------------
def _env_factory(res: Resolved, disturbance: str | None) -> Callable[[], gym.Env]:
    c = res.cfg
    return partial(
        build_decision_env,
        c.decision_every,
        c.env_id,
        c.residual,
        c.scale_fraction,
        res.control_hz,
        res.max_episode_steps,
        c.start,
        disturbance,
        c.reward_weights,
        res.env_extra,
        res.residual_kwargs,
    )


def make_envs(res: Resolved, run_dir: Path, session: str) -> tuple[VecEnv, VecEnv]:
    """Training VecEnv (Monitor, optional VecNormalize) and the evaluation VecEnv (its
    own VecNormalize with training=False, norm_reward=False; EvalCallback copies the
    training obs statistics into it before every evaluation)."""
    c = res.cfg
    train_env = make_vec_env(
        _env_factory(res, c.disturbance),
        n_envs=res.n_envs,
        seed=c.seed,
        monitor_dir=str(run_dir / "monitor" / session),
        vec_env_cls=DummyVecEnv,
    )
    eval_dist = c.disturbance if c.eval_disturbance is None else c.eval_disturbance
    eval_env = make_vec_env(
        _env_factory(res, eval_dist), n_envs=1, seed=c.seed + 1000, vec_env_cls=DummyVecEnv
    )
    if res.normalize_kwargs is not None:
        train_env = VecNormalize(train_env, **res.normalize_kwargs)
        eval_kwargs = {**res.normalize_kwargs, "norm_reward": False}
        eval_env = VecNormalize(eval_env, training=False, **eval_kwargs)
    return train_env, eval_env


# -- model -------------------------------------------------------------------------------
def _last_linear(module: nn.Module) -> nn.Linear:
    linears = [m for m in module.modules() if isinstance(m, nn.Linear)]
    if not linears:
        raise TrainConfigError(f"no linear layer in {module}")
    return linears[-1]


def zero_init_actor(model: BaseAlgorithm) -> None:
    """Zero the weights and bias of the actor's output layer, so the deterministic action
    is exactly 0 (SAC: ``actor.mu``; TD3: the last linear layer of ``actor.mu``, copied to
    the target actor; PPO: ``policy.action_net``)."""
    policy: Any = model.policy
    if isinstance(model, SAC):
        layers = [_last_linear(policy.actor.mu)]
    elif isinstance(model, TD3):
        layers = [_last_linear(policy.actor.mu)]
    elif isinstance(model, PPO):
        layers = [_last_linear(policy.action_net)]
    else:
        raise TrainConfigError(f"zero init is not implemented for {type(model).__name__}")
    with torch.no_grad():
        for layer in layers:
            layer.weight.zero_()
            layer.bias.zero_()
    if isinstance(model, TD3):
        policy.actor_target.load_state_dict(policy.actor.state_dict())


def init_actor_log_std(model: BaseAlgorithm, log_std: float) -> None:
    """SAC: make the actor's log-std head constant at ``log_std`` (zero weights, bias =
    ``log_std``): exploration starts with std exp(log_std) before the tanh squashing."""
    if not isinstance(model, SAC):
        raise TrainConfigError(f"init_log_std is implemented for SAC, not {type(model).__name__}")
    head = model.policy.actor.log_std  # type: ignore[union-attr]
    with torch.no_grad():
        head.weight.zero_()
        head.bias.fill_(log_std)


def scale_actor_lr(model: BaseAlgorithm, scale: float) -> None:
    """SAC/TD3: every step of the actor's optimizer uses ``scale`` times the learning rate
    SB3 set for it (its schedule's value; SB3 resets it before each ``train`` call), which
    is restored right after the step, so the scale never compounds and the critic's and
    the entropy coefficient's optimizers are untouched. Hooks are not saved with a model:
    apply again after loading one (``run`` does, on ``--resume``)."""
    if not isinstance(model, (SAC, TD3)):
        raise TrainConfigError(f"actor_lr_scale is for SAC and TD3, not {type(model).__name__}")
    optimizer = model.actor.optimizer  # type: ignore[union-attr]
    saved: list[float] = []

    def before(opt: torch.optim.Optimizer, args: Any, kwargs: Any) -> None:
        saved[:] = [group["lr"] for group in opt.param_groups]
        for group in opt.param_groups:
            group["lr"] = group["lr"] * scale

    def after(opt: torch.optim.Optimizer, args: Any, kwargs: Any) -> None:
        for group, lr in zip(opt.param_groups, saved, strict=True):
            group["lr"] = lr

    optimizer.register_step_pre_hook(before)
    optimizer.register_step_post_hook(after)


def actor_bc_loss(model: BaseAlgorithm, obs: torch.Tensor, weight: float) -> torch.Tensor:
    """λ·mean over the batch and the n action dimensions of μ(s)², μ the actor's
    deterministic action (SAC: tanh of the Gaussian's mean; TD3: the actor's output), in the
    policy's [−1, 1]ⁿ: TD3+BC's (π(s) − a)² with the residual's base action a = 0."""
    actor: Any = model.actor  # type: ignore[attr-defined]
    if isinstance(model, SAC):
        mean_actions, _, _ = actor.get_action_dist_params(obs)
        mu = torch.tanh(mean_actions)
    elif isinstance(model, TD3):
        mu = actor(obs)
    else:
        raise TrainConfigError(f"actor_bc_weight is for SAC and TD3, not {type(model).__name__}")
    return weight * (mu**2).mean()


def add_actor_bc(model: BaseAlgorithm, weight: float) -> None:
    """SAC/TD3: before every step of the actor's optimizer, add the gradient of
    :func:`actor_bc_loss` on a fresh replay-buffer batch (SB3's batch size, observations
    normalised as SB3's ``train`` does) to the actor's loss gradient SB3 has just computed:
    an unbiased gradient of actor loss + BC term from two independent batches, without
    copying SB3's update. Skipped while the actor is frozen (critic warm-up). Hooks are not
    saved with a model: apply again after loading one (``run`` does, on ``--resume``)."""
    if not isinstance(model, (SAC, TD3)):
        raise TrainConfigError(f"actor_bc_weight is for SAC and TD3, not {type(model).__name__}")
    algo: Any = model
    params = list(algo.actor.parameters())

    def before(opt: torch.optim.Optimizer, args: Any, kwargs: Any) -> None:
        if not any(p.requires_grad for p in params):
            return
        batch = algo.replay_buffer.sample(algo.batch_size, env=algo._vec_normalize_env)
        actor_bc_loss(algo, batch.observations, weight).backward()

    algo.actor.optimizer.register_step_pre_hook(before)


class ActorWarmupCallback(BaseCallback):
    """Freeze the actor (its parameters get no gradient, so no update) until the model
    has taken ``until_steps`` env steps, while the critic trains on what the frozen actor
    does. In SB3's SAC and TD3 the critic is updated before the actor and the actor loss
    reaches the actor only through its parameters, so a frozen actor leaves the critic's
    and the entropy coefficient's updates as they are."""

    def __init__(self, until_steps: int) -> None:
        super().__init__()
        self.until_steps = int(until_steps)
        self.frozen = False

    def _set(self, frozen: bool) -> None:
        for p in self.model.actor.parameters():  # type: ignore[attr-defined]
            p.requires_grad_(not frozen)
        self.frozen = frozen

    def _on_training_start(self) -> None:
        if self.num_timesteps < self.until_steps:
            self._set(True)

    def _on_step(self) -> bool:
        if self.frozen and self.num_timesteps >= self.until_steps:
            self._set(False)
        return True

    def _on_training_end(self) -> None:
        if self.frozen:
            self._set(False)


def versions() -> dict[str, str]:
    """Python, platform and the versions of the packages a run depends on."""
    out = {"python": sys.version.split()[0], "platform": platform.platform()}
    for pkg in (
        "ptrack_gym",
        "gymnasium",
        "stable-baselines3",
        "torch",
        "numpy",
        "scipy",
        "pybullet",
        "PyYAML",
        "sbx-rl",
        "jax",
    ):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def _yaml_safe(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _yaml_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_yaml_safe(v) for v in value]
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, type):
        return f"{value.__module__}.{value.__qualname__}"
    return repr(value)


def write_run_files(res: Resolved, run_dir: Path, argv: Sequence[str] | None) -> None:
    """config.yml (resolved), command.txt (appended), versions.json."""
    run_dir.mkdir(parents=True, exist_ok=True)
    config = {
        "config": dataclasses.asdict(res.cfg),
        "derived": {
            "robot": res.robot,
            "control_hz": res.control_hz,
            "physics_hz": 1000.0,
            "max_episode_steps": res.max_episode_steps,
            "steps": res.steps,
            "n_envs": res.n_envs,
            "vec_normalize": res.normalize_kwargs,
        },
        "hyperparams": {**res.algo_kwargs, **res.special},
    }
    (run_dir / "config.yml").write_text(yaml.safe_dump(_yaml_safe(config), sort_keys=False))
    args = list(sys.argv[1:] if argv is None else argv)
    line = shlex.join([sys.executable, "-m", "train.train", *args])
    with (run_dir / "command.txt").open("a") as fh:
        fh.write(line + "\n")
    (run_dir / "versions.json").write_text(json.dumps(versions(), indent=2) + "\n")


def run(cfg: TrainConfig, argv: Sequence[str] | None = None) -> TrainResult:
    """Validate ``cfg``, build the envs and the model (or resume), train, save.

    Raises:
        TrainConfigError: a bad config, before any env is built or any file written.
    """
    res = validate(cfg)
    run_dir = Path(cfg.out)
    torch.set_num_threads(cfg.torch_threads)
    write_run_files(res, run_dir, argv)
    start_steps = 0 if not cfg.resume else latest_checkpoint(run_dir)[0]  # type: ignore[index]
    train_env, eval_env = make_envs(res, run_dir, session=f"from_{start_steps}")
    try:
        if cfg.resume:
            model, train_env = load_checkpoint(
                algo_class(cfg.algo, cfg.backend), run_dir, train_env, eval_env,
                res.normalize_kwargs is not None, cfg.device, cfg.tensorboard,
            )  # fmt: skip
            if cfg.imitate is not None and isinstance(train_env, VecNormalize):
                train_env.training = False  # the imitation's statistics stay frozen
        else:
            kwargs = dict(res.algo_kwargs)
            noise = action_noise(res.special, int(np.prod(train_env.action_space.shape)))
            if noise is not None:
                kwargs["action_noise"] = noise
            model = algo_class(cfg.algo, cfg.backend)(
                env=train_env,
                tensorboard_log=str(run_dir / "tb") if cfg.tensorboard else None,
                verbose=cfg.verbose,
                seed=cfg.seed,
                device=cfg.device,
                **kwargs,
            )
            if cfg.zero_init_residual:
                zero_init_actor(model)
            if cfg.init_log_std is not None:
                init_actor_log_std(model, cfg.init_log_std)
            if cfg.imitate is not None:
                try:
                    imitate(res, model, train_env, run_dir)
                except BaseException:
                    # Interrupted or failed: nothing trained yet to keep. Free the folder,
                    # so the same command starts over (a config.yml alone would make it
                    # refuse, with no checkpoint to --resume from).
                    (run_dir / "config.yml").unlink(missing_ok=True)
                    raise
        if cfg.actor_lr_scale != 1.0:  # fresh or resumed: the hooks are not saved
            scale_actor_lr(model, cfg.actor_lr_scale)
        if cfg.actor_bc_weight:  # likewise
            add_actor_bc(model, cfg.actor_bc_weight)
        if cfg.demo_bc_weight:  # likewise, from the run's saved demonstrations
            demo_obs, demo_act = load_demonstrations(run_dir)
            add_demo_bc(
                model,
                demo_obs,
                demo_act,
                cfg.demo_bc_weight,
                [cfg.seed, DEMO_BC_STREAM, model.num_timesteps],  # type: ignore[arg-type]
            )
        # An explicit logger in the run folder: without one SB3 creates /tmp/SB3-<date>.
        formats = (
            ["csv"]
            + (["stdout"] if cfg.verbose else [])
            + (["tensorboard"] if cfg.tensorboard else [])
        )
        model.set_logger(configure_logger(str(run_dir / "tb" / f"from_{start_steps}"), formats))
        callbacks: list[BaseCallback] = []
        if cfg.critic_warmup_steps > 0:
            until = int(model.learning_starts) + cfg.critic_warmup_steps  # type: ignore[attr-defined]
            callbacks.append(ActorWarmupCallback(until))
        if cfg.checkpoint_freq > 0:
            callbacks.append(
                PruningCheckpointCallback(
                    save_freq=max(cfg.checkpoint_freq // res.n_envs, 1),
                    save_path=str(run_dir / "checkpoints"),
                    name_prefix=CHECKPOINT_PREFIX,
                    save_replay_buffer=True,
                    save_vecnormalize=True,
                )
            )
        if cfg.eval_freq > 0:
            callbacks.append(
                EvalCallback(
                    eval_env,
                    n_eval_episodes=cfg.eval_episodes,
                    eval_freq=max(cfg.eval_freq // res.n_envs, 1),
                    best_model_save_path=str(run_dir),
                    log_path=str(run_dir / "eval" / f"from_{start_steps}"),
                    deterministic=True,
                    verbose=cfg.verbose,
                )
            )
        try:
            model.learn(
                total_timesteps=res.steps,
                callback=callbacks,
                reset_num_timesteps=not cfg.resume,
                tb_log_name=cfg.algo,
                progress_bar=cfg.progress_bar,
            )
        except KeyboardInterrupt:
            # Ctrl-C (or SIGTERM, see sigterm_as_interrupt): keep every step taken, as
            # rl-zoo3 does — model.zip and a checkpoint at this step; --resume goes on.
            save_final(model, train_env, run_dir)
            raise
        save_final(model, train_env, run_dir)
    finally:
        train_env.close()
        eval_env.close()
    return TrainResult(model, run_dir, model.num_timesteps)


# -- CLI ---------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    """The argparse parser of ``python -m train.train``."""
    d = TrainConfig(out="")
    p = argparse.ArgumentParser(
        prog="python -m train.train",
        description="Train SAC/TD3/PPO on a ptrack_gym env, pure or residual (docs/rl.md).",
    )
    p.add_argument("--algo", choices=sorted(ALGOS), default=d.algo)
    p.add_argument(
        "--backend", choices=BACKENDS, default=d.backend, help="sbx: the JAX port (extra 'sbx')"
    )
    p.add_argument("--env", dest="env_id", default=d.env_id, help="a ptrack_gym env id")
    p.add_argument("--residual", choices=RESIDUAL_CHOICES, default=d.residual)
    p.add_argument("--scale-fraction", type=float, default=d.scale_fraction)
    p.add_argument(
        "--scale-accel-rad-s2", type=float, default=None,
        help="the residual as a joint acceleration M(q) alpha a, alpha in rad/s^2",
    )  # fmt: skip
    p.add_argument(
        "--base-gains", choices=GAIN_CHOICES, default=d.base_gains,
        help="the residual's base controller gains (tuned: agents/tuned)",
    )  # fmt: skip
    p.add_argument(
        "--base-model", default=None,
        help="--residual network: the folder of the saved pure policy that is the base",
    )  # fmt: skip
    p.add_argument("--disturbance", default=d.disturbance, help="none | preset | preset:level")
    p.add_argument("--eval-disturbance", default=None, help="default: --disturbance")
    p.add_argument("--steps", type=int, default=None, help="default: the YAML's n_timesteps")
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--out", required=True, help="run folder")
    p.add_argument("--hyperparams", default=None, help="YAML merged over the packaged one")
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="hyperparameter override (repeatable), e.g. --set learning_rate=1e-3",
    )
    p.add_argument("--n-envs", type=int, default=None)
    p.add_argument(
        "--vec-normalize",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="default: the YAML's 'normalize'",
    )
    p.add_argument("--eval-freq", type=int, default=d.eval_freq)
    p.add_argument("--eval-episodes", type=int, default=d.eval_episodes)
    p.add_argument("--checkpoint-freq", type=int, default=d.checkpoint_freq)
    p.add_argument("--resume", action="store_true")
    p.add_argument("--zero-init-residual", action="store_true")
    p.add_argument("--progress-bar", action="store_true")
    p.add_argument("--tensorboard", action="store_true")
    p.add_argument("--control-hz", type=float, default=None, help="default: per robot")
    p.add_argument("--episode-s", type=float, default=d.episode_s)
    p.add_argument("--start", choices=("on_path", "rest_near_path"), default=d.start)
    p.add_argument(
        "--reward-weights", type=float, nargs=3, default=None,
        metavar=("W_PATH", "W_TIME", "W_EFFORT"), help="the env's reward weights",
    )  # fmt: skip
    p.add_argument("--reward", choices=REWARD_MODES, default=d.reward)
    p.add_argument(
        "--kernel-weights", type=float, nargs=3, default=None,
        metavar=("W_PATH", "W_TIME", "W_EFFORT"), help="weights of --reward kernel",
    )  # fmt: skip
    p.add_argument("--max-path-distance", type=float, default=None, help="rad; end an episode")
    p.add_argument("--action-penalty", type=float, default=d.action_penalty)
    p.add_argument("--gate-rad", type=float, default=None)
    p.add_argument("--gate-deadband-rad", type=float, default=d.gate_deadband_rad)
    p.add_argument(
        "--prior-gain-per-rad", type=float, default=d.prior_gain_per_rad,
        help="residuals: g (1/rad) of the control prior clip(g (q_r(s) - q)), the base's own error",
    )  # fmt: skip
    p.add_argument("--init-log-std", type=float, default=None)
    p.add_argument("--critic-warmup-steps", type=int, default=d.critic_warmup_steps)
    p.add_argument(
        "--decision-every", type=int, default=d.decision_every,
        help="the policy decides every k control steps, holding its action in between",
    )  # fmt: skip
    p.add_argument(
        "--actor-lr-scale", type=float, default=d.actor_lr_scale,
        help="SAC/TD3: the actor's learning rate as a fraction of the critic's",
    )  # fmt: skip
    p.add_argument(
        "--actor-bc-weight", type=float, default=d.actor_bc_weight,
        help="SAC/TD3: weight of a term pulling the actor's action toward 0 (the base or prior)",
    )  # fmt: skip
    p.add_argument(
        "--imitate", choices=CONTROLLER_NAMES, default=None,
        help="pure SAC: start the actor by DAgger of this controller (train.imitation)",
    )  # fmt: skip
    p.add_argument("--imitate-gains", choices=GAIN_CHOICES, default=d.imitate_gains)
    p.add_argument("--imitate-rounds", type=int, default=d.imitate_rounds)
    p.add_argument("--imitate-steps", type=int, default=d.imitate_steps, help="round 0")
    p.add_argument("--imitate-round-steps", type=int, default=d.imitate_round_steps)
    p.add_argument("--imitate-noise", type=float, default=d.imitate_noise, help="std, a units")
    p.add_argument(
        "--demo-bc-weight", type=float, default=d.demo_bc_weight,
        help="with --imitate: weight of a pull toward the expert's labels during RL",
    )  # fmt: skip
    p.add_argument("--torch-threads", type=int, default=d.torch_threads)
    p.add_argument("--device", default=d.device)
    p.add_argument("--verbose", type=int, default=d.verbose)
    return p


def to_argv(cfg: TrainConfig) -> list[str]:
    """The command-line arguments that :func:`parse_args` turns back into ``cfg`` (only
    the fields that differ from the defaults): the standalone command of a run."""
    d = TrainConfig(out="")
    flags = {a.dest: a for a in build_parser()._actions if a.option_strings}
    out: list[str] = []
    for f in dataclasses.fields(TrainConfig):
        value = getattr(cfg, f.name)
        if f.name != "out" and value == getattr(d, f.name):
            continue
        action = flags[f.name]
        flag = action.option_strings[0]
        if f.name == "overrides":
            for key, v in value.items():
                out += ["--set", f"{key}={v}"]
        elif isinstance(action, argparse.BooleanOptionalAction):
            out.append(flag if value else f"--no-{flag[2:]}")
        elif isinstance(value, bool):
            out.append(flag)
        elif isinstance(value, (list, tuple)):
            out += [flag, *(str(v) for v in value)]
        else:
            out += [flag, str(value)]
    return out


def parse_args(argv: Sequence[str] | None = None) -> TrainConfig:
    """A :class:`TrainConfig` from command-line arguments (argparse errors exit with 2)."""
    parser = build_parser()
    ns = parser.parse_args(argv)
    values = vars(ns)
    try:
        values["overrides"] = parse_set(values["overrides"])
    except TrainConfigError as exc:
        parser.error(str(exc))
    return TrainConfig(**values)


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM raises ``KeyboardInterrupt`` in this process (enter it
    from the main thread), so a run terminated while it trains saves its state as an
    interrupted one does: the CLI and the campaign's worker processes (which
    ``Pool.terminate`` stops with SIGTERM). The previous handler is restored on exit — an
    idle worker terminated after its run then exits quietly."""

    def _raise(signum: int, frame: Any) -> None:
        # One-shot: a second SIGTERM (Pool.terminate's, after a signal to the whole process
        # group) is ignored, so it cannot cut the save it started short.
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise KeyboardInterrupt(f"signal {signum}")

    previous = signal.signal(signal.SIGTERM, _raise)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def main(argv: Sequence[str] | None = None) -> int:
    """CLI entry point: parse, train, print where the run went."""
    cfg = parse_args(argv)
    with sigterm_as_interrupt():
        result = run(cfg, argv)
    print(f"trained {result.num_timesteps} steps; run folder: {result.run_dir}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
