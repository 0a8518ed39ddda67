"""One training run's configuration, :class:`TrainConfig`, and its validation.

:func:`validate` checks every field and resolves the hyperparameters (``train/hyperparams/
<algo>.yml`` in rl-baselines3-zoo's format, then ``hyperparams``, then ``overrides``)
without touching a file or building an env: every configuration error — unknown algorithm,
env id, residual base, disturbance, env argument (checked by the env's own validator),
hyperparameter, a number out of its domain, settings that contradict each other (a
warm-up that outlasts the run) — raises :class:`TrainConfigError` before anything runs.

``--resume`` needs only ``--out``: :func:`from_args` takes every field the command line
did not give from the run's ``config.yml`` (:func:`resume_config`), and :func:`validate`
names every given value that differs from the run's at once.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

from agents.registry import pinned_rates, tuned_rates
from agents.residual import (
    NETWORK_BASE,
    RESIDUAL_BASES,
    ResidualSpec,
    check_base_gains,
    check_base_model,
    check_prior,
    check_safeguards,
)
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots import profile_for_env_id
from ptrack_gym.robots.profile import RobotProfile
from train.common.algorithms import ALGO_NAMES, ON_POLICY, RECURRENT_ALGOS
from train.common.arguments import (
    add_config_arguments,
    config_from_args,
)
from train.common.arguments import to_argv as config_to_argv
from train.evaluation.envs import (
    WRAPPER_DEFAULTS,
    check_env_kwargs,
    env_kwargs,
    residual_wrapper_kwargs,
)
from train.evaluation.policies import BACKENDS
from train.rl.checkpoints import (
    latest_checkpoint,
)
from train.rl.domains import check_agreement, check_numbers
from train.rl.hyperparameters import (
    TrainConfigError,
    load_hyperparams,
    parse_set,
    resolve_hyperparams,
)
from train.rl.imitation import DaggerSpec
from train.rl.imitation_config import check_imitation
from train.rl.resume import (
    check_resume_compatible,
    given_fields,
    resume_config,
    saved_config,
)
from train.rl.splits import check_split_envs, check_splits

#: ``--residual`` choices: "none" (pure RL), a base controller name, or "network" (a saved
#: pure policy, ``base_model``).
RESIDUAL_CHOICES: tuple[str, ...] = ("none", *RESIDUAL_BASES)


@dataclass
class TrainConfig:
    """Everything that defines one training run (SI units where physical)."""

    out: str
    """Run folder: config, checkpoints, final model, logs."""
    algo: str = "sac"
    """Algorithm: "sac", "td3", "ppo" or "ppo_lstm" (sb3-contrib's RecurrentPPO: the
    ``recurrent`` extra)."""
    backend: str = "sb3"
    """Its implementation: "sb3" (Stable-Baselines3, torch) or "sbx" (the SB3 team's JAX port,
    the optional ``sbx`` extra; the same interface, callbacks and files). The residual
    safeguards that act on the torch actor (``zero_init_residual``, ``init_log_std``,
    ``critic_warmup_steps``, ``actor_lr_scale``, ``actor_bc_weight``) are sb3's only."""
    env_id: str = "ptrack_gym/TwoLinkTrack-v0"
    """A ptrack_gym env id (``ptrack_gym.ENV_IDS``), or its preview id (``PREVIEW_ENV_IDS``:
    the reference ahead in the observation; hyperparameters from the ``-v0`` section)."""
    residual: str = "none"
    """"none" for pure RL, or the base controller of a residual policy (agents.registry)."""
    scale_fraction: float = 0.1
    """Residual authority: scale = scale_fraction · τ_max per joint (N·m)."""
    scale_accel_rad_s2: float | None = None
    """Residual only: the residual as a joint acceleration instead of ``scale_fraction``:
    τ_res = M(q) α a, α in rad/s² (``agents.residual``)."""
    base_gains: str = "default"
    """Residual only: the base controller's gains, "default" (the robot's default gain rates at
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
    train_families: list[str] | None = None
    """Disturbances the policy trains under, one drawn per episode (the env's
    ``disturbance_choices``; each "preset" or "preset:level"); needs ``disturbance``
    "none"."""
    eval_families: list[str] | None = None
    """The evaluation env's disturbances, one drawn per episode, none of whose presets is a
    training family: held out; None: ``eval_disturbance`` (or the training ones)."""
    randomize_mass: float = 0.0
    """f ∈ [0, 1): every training episode scales each link's mass and inertia by its own
    factor uniform in [1 − f, 1 + f] (a ``mismatch`` without damping or friction; the
    model stays nominal), on top of the training disturbance; 0: the nominal plant. The
    evaluation env stays nominal."""
    train_paths: list[int] | None = None
    """Seeds of the random admissible paths the policy trains on: a pool, one path drawn per
    episode (the env's ``path_seeds``); None: the env's default path."""
    eval_paths: list[int] | None = None
    """Seeds of the evaluation env's paths (a pool), disjoint from ``train_paths``: held out;
    None: the training paths."""
    steps: int | None = None
    """Environment steps to train in this invocation (added to a resumed count, and never
    taken from the run on ``--resume``); None → the hyperparameter file's ``n_timesteps``."""
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
    """Continue from the newest checkpoint in ``out`` (model, replay buffer, VecNormalize);
    every field not given is the run's (its ``config.yml``), and a given one that changes
    what the run is (env, reward, residual, …: ``train.rl.resume.RESUME_KEYS``) is refused."""
    zero_init_residual: bool = False
    """Zero the actor's output layer (SAC/TD3 mu, PPO action_net): the policy starts at a = 0."""
    progress_bar: bool | None = None
    """Show SB3's progress bar (tqdm + rich); None: when standard output is a terminal
    (``--progress``/``--no-progress`` say it too)."""
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
    ``--zero-init-residual`` that is the base controller plus exploration noise. It must end
    before the run does (``learning_starts`` + it < the run's last step)."""
    freeze_actor: bool = False
    """Off-policy only: the actor gets no update in the whole run (the critic still
    learns), so the policy stays as initialised — with ``--zero-init-residual`` the base
    and its control prior: a prior alone through the training harness, on purpose."""
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
    tank: bool = False
    """Residuals over a passivity law only: gate the learned torque by an energy tank filled
    by the law's own dissipation (``agents.energy_tank``; the balance storage + tank ≤ the
    start + pump, re-synchronisation and disturbance work holds whatever the policy does)."""
    tank_beta: float = 0.5
    """With ``tank``: β ∈ [0, 1], the fraction of the law's dissipation that fills the tank."""
    imitate: str | None = None
    """Pure SAC only: start the actor as a copy of this model-based controller (a name of
    ``agents.registry``) learned by DAgger before RL (``train.rl.imitation``); None: no
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
        TrainConfigError: the first problem found, with the valid choices (every number
            out of its domain, and every ``--resume`` mismatch, at once).
    """
    if cfg.algo not in ALGO_NAMES:
        raise TrainConfigError(f"unknown algo {cfg.algo!r}; known: {sorted(ALGO_NAMES)}")
    if cfg.algo in RECURRENT_ALGOS and cfg.backend != "sb3":
        raise TrainConfigError(f"algo {cfg.algo!r} exists in the sb3 backend only")
    if cfg.backend not in BACKENDS:
        raise TrainConfigError(f"unknown backend {cfg.backend!r}; known: {list(BACKENDS)}")
    check_numbers(dataclasses.asdict(cfg))
    if cfg.backend == "sbx":
        torch_only = [
            name
            for name, on in (
                ("zero_init_residual", cfg.zero_init_residual),
                ("init_log_std", cfg.init_log_std is not None),
                ("critic_warmup_steps", cfg.critic_warmup_steps != 0),
                ("freeze_actor", cfg.freeze_actor),
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
    residual_kwargs = residual_wrapper_kwargs(dataclasses.asdict(cfg))
    if cfg.residual == "none":
        if residual_kwargs != WRAPPER_DEFAULTS:
            raise TrainConfigError(f"{', '.join(WRAPPER_DEFAULTS)} need a residual base")
        residual_kwargs = {}
    if cfg.algo in ON_POLICY:
        for name in ("critic_warmup_steps", "freeze_actor"):
            if getattr(cfg, name):
                raise TrainConfigError(f"{name} needs an off-policy algorithm (sac, td3)")
        for name in ("actor_lr_scale", "actor_bc_weight"):
            if getattr(cfg, name) != _FIELD_DEFAULTS[name]:
                raise TrainConfigError(f"{name} needs an actor optimizer (sac, td3)")
    check_imitation(cfg)
    if cfg.init_log_std is not None and cfg.algo != "sac":
        raise TrainConfigError("init_log_std is for sac only")
    env_extra: dict[str, Any] = {"reward": cfg.reward}
    check_splits(cfg)
    if cfg.kernel_weights is not None:
        env_extra["kernel_weights"] = tuple(cfg.kernel_weights)
    if cfg.max_path_distance is not None:
        env_extra["max_path_distance_rad"] = cfg.max_path_distance
    try:
        check_base_gains(cfg.base_gains)
        profile = profile_for_env_id(cfg.env_id)
        control_hz = profile.default_control_hz if cfg.control_hz is None else cfg.control_hz
        max_episode_steps = round(cfg.episode_s * control_hz)
        if max_episode_steps < 1:
            raise TrainConfigError(
                f"episode_s={cfg.episode_s} at {control_hz} Hz is less than one control step"
            )
        for text in (cfg.disturbance, cfg.eval_disturbance or cfg.disturbance):
            check_env_kwargs(
                cfg.env_id,
                env_kwargs(
                    control_hz, max_episode_steps, cfg.start, text, cfg.reward_weights, env_extra
                ),
            )
        check_split_envs(cfg, control_hz, max_episode_steps, env_extra)
        if residual_kwargs:
            own = ("base_gains", "prior_gain_per_rad", "base_model", "tank", "tank_beta")
            check_safeguards(**{k: v for k, v in residual_kwargs.items() if k not in own})
            if cfg.tank_beta != _FIELD_DEFAULTS["tank_beta"] and not cfg.tank:
                raise TrainConfigError("tank_beta needs tank")
            if cfg.tank:
                ResidualSpec(base=cfg.residual, base_model=cfg.base_model, tank=cfg.tank,
                             tank_beta=cfg.tank_beta)  # fmt: skip
            check_prior(cfg.residual, cfg.prior_gain_per_rad)
            check_base_model(cfg.residual, cfg.base_model, profile.name, cfg.base_gains)
            if cfg.base_gains == "tuned":
                tuned_rates(profile.name, cfg.residual)  # raises naming the tuned files there are
        if cfg.imitate is not None and cfg.imitate_gains == "tuned":
            tuned_rates(profile.name, cfg.imitate)  # likewise, for the expert
    except InvalidConfigError as exc:
        raise TrainConfigError(str(exc)) from None
    raw = load_hyperparams(cfg.algo, cfg.env_id, cfg.hyperparams, cfg.overrides)
    algo_kwargs, special = resolve_hyperparams(cfg.algo, raw, cfg.backend)
    if cfg.imitate is not None and int(algo_kwargs.get("learning_starts", 100)) != 0:
        raise TrainConfigError(
            "imitate needs learning_starts=0 (--hp learning_starts=0): SB3 acts uniformly at "
            "random until learning_starts, which throws the arm off the path the imitation "
            "tracks and fills the replay buffer with it"
        )
    steps = cfg.steps if cfg.steps is not None else special.get("n_timesteps")
    if steps is None:
        raise TrainConfigError("steps: give --steps (or n_timesteps in the hyperparameter file)")
    n_envs = int(cfg.n_envs if cfg.n_envs is not None else special.get("n_envs", 1))
    normalize = special.get("normalize", False)
    if cfg.vec_normalize is not None:
        normalize = (normalize or {}) if cfg.vec_normalize else False
    normalize_kwargs = None
    if normalize is not False:
        normalize_kwargs = dict(normalize) if isinstance(normalize, dict) else {}
        normalize_kwargs.setdefault("gamma", float(algo_kwargs.get("gamma", 0.99)))
    run_dir = Path(cfg.out)
    done = 0  # the steps the run has taken before this invocation
    if cfg.resume:
        found = latest_checkpoint(run_dir)
        if found is None:
            raise TrainConfigError(f"--resume: no checkpoint in {run_dir / 'checkpoints'}")
        done = found[0]
        derived = {"control_hz": float(control_hz), "n_envs": n_envs,
                   "vec_normalize": normalize_kwargs is not None}  # fmt: skip
        check_resume_compatible(cfg, derived, run_dir)
    elif (run_dir / "config.yml").exists():
        found = latest_checkpoint(run_dir)
        if found is None:
            raise TrainConfigError(
                f"{run_dir} holds a run that stopped before its first checkpoint: "
                "delete the folder, or use a new --out"
            )
        raise TrainConfigError(
            f"{run_dir} already holds a run ({found[0]} steps): use --resume to continue it, "
            "or a new --out"
        )
    check_agreement(dataclasses.asdict(cfg), algo_kwargs, n_envs, done, int(steps))
    if residual_kwargs and cfg.residual != NETWORK_BASE:  # pinned: gains may be retuned
        residual_kwargs = {**residual_kwargs, "base_gains": _pinned_rates(cfg, profile)}
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


def _pinned_rates(cfg: TrainConfig, profile: RobotProfile) -> dict[str, Any]:
    """The rates of the base a run trains over: on ``--resume``, those it started with
    (its ``derived.base_rates``; a run written before they were recorded takes today's),
    else today's of its ``base_gains`` (:func:`agents.registry.pinned_rates`: the tuned
    file's, or the default's numeric rates). Written to ``config.yml`` and read back by the
    evaluation (:func:`train.evaluation.envs.trained_wrapper_kwargs`)."""
    if cfg.resume:
        saved = saved_config(Path(cfg.out)) or {}
        pinned = (saved.get("derived") or {}).get("base_rates")
        if pinned:
            return dict(pinned)
    return pinned_rates(profile, cfg.residual, cfg.base_gains)


#: TrainConfig's defaults, for the keys a run written before they existed lacks.
_FIELD_DEFAULTS: dict[str, Any] = {
    f.name: f.default
    for f in dataclasses.fields(TrainConfig)
    if f.default is not dataclasses.MISSING
}


# -- command line ----------------------------------------------------------------------
#: TrainConfig fields with no flag of their own: ``overrides`` is ``--hp key=value``.
NO_FLAG = ("overrides",)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``ptrack train``'s arguments: ``--config``, ``--set``, a flag per
    :class:`TrainConfig` field (``--env`` for ``env_id``) and ``--hp`` for the SB3
    hyperparameters (:mod:`train.common.arguments`)."""
    add_config_arguments(
        parser,
        TrainConfig,
        exclude=NO_FLAG,
        flags={"env_id": "--env", "progress_bar": "--progress"},
    )
    parser.add_argument(
        "--hp", action="append", default=[], metavar="KEY=VALUE",
        help="an SB3 hyperparameter over the YAML's (repeatable): the value read as YAML; "
        "policy_kwargs and normalize may be literals like dict(net_arch=[64, 64])",
    )  # fmt: skip


def from_args(args: argparse.Namespace) -> TrainConfig:
    """The config of parsed ``ptrack train`` arguments: the fields, with ``--hp`` merged
    over the config file's ``overrides``; with ``--resume``, every field not given is the
    run's (:func:`resume_config`)."""
    cfg = config_from_args(TrainConfig, args)
    cfg.overrides = {**cfg.overrides, **parse_set(args.hp)}
    return resume_config(cfg, given_fields(args, TrainConfig))


def parse_args(argv: Sequence[str] | None = None) -> TrainConfig:
    """A :class:`TrainConfig` from ``ptrack train`` arguments (errors exit with 2)."""
    parser = argparse.ArgumentParser(prog="ptrack train")
    add_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return from_args(args)
    except InvalidConfigError as exc:
        parser.error(str(exc))
        raise  # not reached


def to_argv(cfg: TrainConfig) -> list[str]:
    """The ``ptrack train`` arguments that :func:`parse_args` turns back into ``cfg`` (the
    fields that differ from the defaults, and ``out``): the standalone command of a run."""
    words = config_to_argv(dataclasses.replace(cfg, overrides={}))
    if "--out" not in words:
        words = ["--out", cfg.out, *words]
    return words + [w for k, v in cfg.overrides.items() for w in ("--hp", f"{k}={v}")]
