"""Train SAC, TD3 or PPO on a ptrack_gym env, pure or residual on a base controller.

Run from the repository root::

    ptrack train --algo sac --env ptrack_gym/TwoLinkTrack-v0 \\
        --residual passivity --disturbance impulse:0.5 --steps 50000 --out runs/sac_tl

Everything one run needs is one :class:`TrainConfig`; the CLI fills it (``--help``). The
hyperparameters come from ``train/hyperparams/<algo>.yml`` (rl-baselines3-zoo format, see
:mod:`train.rl.hyperparameters` and ``docs/rl.md``), then ``--hyperparams FILE``, then
``--hp key=value``. Every configuration error — unknown algorithm, env id, residual
base, disturbance, env argument (checked by the env's own validator), hyperparameter, a
number out of its domain or settings that contradict each other — raises
:class:`TrainConfigError` (a ``ValueError``) or an argparse error *before* any env is built
or any file written. Envs come from :func:`train.evaluation.envs.build_env`, checkpoints
from :mod:`train.rl.checkpoints`.

The run folder ``--out`` receives ``config.yml`` (the resolved config and
hyperparameters), ``command.txt`` (one line per invocation), ``versions.json``,
``model.zip`` and ``vecnormalize.pkl`` (final), ``best_model.zip`` (the evaluation's best),
``eval/`` and ``monitor/`` (per invocation), ``tb/`` (``--tensorboard``) and
``checkpoints/rl_model_<steps>_steps.zip`` with the matching VecNormalize statistics and,
for the newest checkpoint only, the replay buffer (the final state is always saved there
too, so ``--resume`` can continue any finished or interrupted run). An interrupted run —
Ctrl-C, or SIGTERM — saves ``model.zip`` and a checkpoint at the step it reached before it
exits (nothing trained is lost, and ``model.zip`` is never older than the newest
checkpoint), then re-raises ``KeyboardInterrupt``. A run that fails before its first step
(and saved no checkpoint) takes back what it wrote, so the same command can start over.
SB3's progress bar is on when standard output is a terminal (``--progress-bar``,
``--no-progress`` say otherwise).
"""

from __future__ import annotations

import dataclasses
import json
import platform
import shlex
import shutil
import sys
from collections.abc import Callable, Sequence
from functools import partial
from importlib import metadata
from pathlib import Path
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
import torch
import yaml
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, EvalCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import configure as configure_logger
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecNormalize

from ptrack_gym.robots import profile_for_env_id
from train.evaluation.envs import (
    build_decision_env,
    parse_disturbance,
)
from train.evaluation.policies import algo_class
from train.rl.actor import (
    ActorWarmupCallback,
    add_actor_bc,
    init_actor_log_std,
    scale_actor_lr,
    zero_init_actor,
)
from train.rl.checkpoints import (
    CHECKPOINT_PREFIX,
    PruningCheckpointCallback,
    SaveBestModel,
    latest_checkpoint,
    load_checkpoint,
    save_checkpoint,
    save_final,
)
from train.rl.config import (
    Resolved,
    TrainConfig,
    to_argv,
    validate,
)
from train.rl.hyperparameters import (
    action_noise,
)
from train.rl.imitation import (
    add_demo_bc,
    dagger,
    load_demonstrations,
    save_demonstrations,
)
from train.rl.imitation_config import DEMO_BC_STREAM, dagger_spec


class TrainResult(NamedTuple):
    """What :func:`run` returns."""

    model: BaseAlgorithm  # the trained model (its envs are closed)
    run_dir: Path  # the run folder
    num_timesteps: int  # the model's step count at the end


def imitate(res: Resolved, model: BaseAlgorithm, train_env: VecEnv, run_dir: Path) -> None:
    """DAgger of ``res.cfg.imitate`` into ``model``'s actor on an env built like the
    training env (``train.rl.imitation.dagger``, seeded by the run's seed); saves the
    demonstrations and a checkpoint at step 0 — the imitation alone, the first point of
    the run's learning curve (model and VecNormalize statistics; no replay buffer)."""
    cfg = res.cfg
    spec = dagger_spec(cfg)
    env = _env_factory(
        res, cfg.disturbance, cfg.train_paths, cfg.train_families, cfg.randomize_mass
    )()
    try:
        vec_normalize = train_env if isinstance(train_env, VecNormalize) else None
        demos = dagger(model, env, spec, cfg.seed, vec_normalize)  # type: ignore[arg-type]
    finally:
        env.close()
    save_demonstrations(demos, run_dir, spec)
    if isinstance(train_env, VecNormalize):
        # The actor was fitted to these statistics (round 0's): frozen from here on, or
        # the same actor would see other inputs as RL's episodes move them
        # (docs/experiments.md, the pure DAgger policy on the iiwa).
        train_env.training = False
    save_checkpoint(model, train_env, run_dir, replay_buffer=False)


# -- environments ----------------------------------------------------------------------
def _env_factory(
    res: Resolved,
    disturbance: str | None,
    paths: list[int] | None = None,
    families: list[str] | None = None,
    randomize_mass: float = 0.0,
) -> Callable[[], gym.Env]:
    """The factory of the run's env under ``disturbance`` — or one of ``families`` per
    episode — on the pool of random ``paths`` (None: the env's default path), the plant's
    link masses and inertias scaled per episode by up to ± ``randomize_mass``."""
    c = res.cfg
    extra = dict(res.env_extra)
    if paths is not None:
        extra.update(path="random", path_seeds=tuple(paths))
    masses: list[Any] = []
    if randomize_mass > 0:
        links = profile_for_env_id(c.env_id).disturbance_scales.mismatch_links
        masses = [{"type": "mismatch", "mass_scale": (1.0 - randomize_mass,
                   1.0 + randomize_mass), "links": tuple(links)}]  # fmt: skip
    if families is not None:
        parsed = [parse_disturbance(t) for t in families]
        extra["disturbance_choices"] = tuple(
            [d for d in (p,) if d is not None] + masses if masses else p for p in parsed
        )
        disturbance = None
    elif masses:
        extra["disturbance"] = [d for d in (parse_disturbance(disturbance),) if d is not None]
        extra["disturbance"] += masses
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
        extra,
        res.residual_kwargs,
    )


def make_envs(res: Resolved, run_dir: Path, session: str) -> tuple[VecEnv, VecEnv]:
    """Training VecEnv (Monitor, optional VecNormalize) and the evaluation VecEnv (its
    own VecNormalize with training=False, norm_reward=False; EvalCallback copies the
    training obs statistics into it before every evaluation)."""
    c = res.cfg
    train_env = make_vec_env(
        _env_factory(res, c.disturbance, c.train_paths, c.train_families, c.randomize_mass),
        n_envs=res.n_envs,
        seed=c.seed,
        monitor_dir=str(run_dir / "monitor" / session),
        vec_env_cls=DummyVecEnv,
    )
    eval_dist = c.disturbance if c.eval_disturbance is None else c.eval_disturbance
    eval_env = make_vec_env(
        _env_factory(
            res,
            eval_dist,
            c.train_paths if c.eval_paths is None else c.eval_paths,
            c.eval_families
            if c.eval_families is not None
            else (c.train_families if c.eval_disturbance is None else None),
        ),
        n_envs=1,
        seed=c.seed + 1000,
        vec_env_cls=DummyVecEnv,
    )
    if res.normalize_kwargs is not None:
        train_env = VecNormalize(train_env, **res.normalize_kwargs)
        eval_kwargs = {**res.normalize_kwargs, "norm_reward": False}
        eval_env = VecNormalize(eval_env, training=False, **eval_kwargs)
    return train_env, eval_env


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
    """config.yml (resolved), command.txt (appended: ``ptrack train`` with ``argv``, or with
    the arguments that rebuild the config when ``argv`` is None), versions.json."""
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
            # the rates of the base as trained over (None: no base with rates)
            "base_rates": (
                dict(res.residual_kwargs["base_gains"])
                if isinstance(res.residual_kwargs.get("base_gains"), dict)
                else None
            ),
        },
        "hyperparams": {**res.algo_kwargs, **res.special},
    }
    (run_dir / "config.yml").write_text(yaml.safe_dump(_yaml_safe(config), sort_keys=False))
    args = list(to_argv(res.cfg) if argv is None else argv)  # None: the config's own command
    line = shlex.join(["ptrack", "train", *args])
    with (run_dir / "command.txt").open("a") as fh:
        fh.write(line + "\n")
    (run_dir / "versions.json").write_text(json.dumps(versions(), indent=2) + "\n")


def run(cfg: TrainConfig, argv: Sequence[str] | None = None) -> TrainResult:
    """Validate ``cfg``, build the envs and the model (or resume), train, save.

    A run that fails before its first training step — building the envs or the model,
    loading the checkpoint, the imitation, SB3's own set-up — takes back what it wrote
    (:class:`RunFiles`), unless it saved a checkpoint (an interruption does): the same
    command can then start over, or resume as before.

    Raises:
        TrainConfigError: a bad config, before any env is built or any file written.
    """
    res = validate(cfg)
    run_dir = Path(cfg.out)
    torch.set_num_threads(cfg.torch_threads)
    files = RunFiles(run_dir)
    started: list[BaseAlgorithm] = []  # the model, once built
    try:
        write_run_files(res, run_dir, argv)
        model = _train(res, run_dir, started)
    except BaseException:
        stepped = bool(started) and started[0].num_timesteps > files.steps
        if not stepped and latest_checkpoint(run_dir) == files.checkpoint:
            files.take_back()
        raise
    return TrainResult(model, run_dir, model.num_timesteps)


class RunFiles:
    """What a run folder held before an invocation wrote to it: its paths, the text of its
    run files (config.yml, command.txt, versions.json) and its newest checkpoint.
    :meth:`take_back` removes every path added since and restores the run files (a folder
    it created goes whole), so a failed fresh start leaves nothing behind and a failed
    resume leaves the run as it was."""

    RUN_FILES = ("config.yml", "command.txt", "versions.json")

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = run_dir
        self.created = run_dir  # the outermost folder that does not exist yet
        while not self.created.parent.exists():
            self.created = self.created.parent
        self.existed = run_dir.exists()
        self.paths = set(run_dir.rglob("*")) if self.existed else set()
        self.texts = {n: (run_dir / n).read_bytes() for n in self.RUN_FILES
                      if (run_dir / n).is_file()}  # fmt: skip
        self.checkpoint = latest_checkpoint(run_dir)
        self.steps = self.checkpoint[0] if self.checkpoint else 0

    def take_back(self) -> None:
        """Undo what was written since this snapshot."""
        if not self.existed:
            shutil.rmtree(self.created, ignore_errors=True)
            return
        for path in sorted(set(self.run_dir.rglob("*")) - self.paths, reverse=True):
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)
        for name, text in self.texts.items():
            (self.run_dir / name).write_bytes(text)


def progress_bar_on(cfg: TrainConfig) -> bool:
    """``cfg.progress_bar``, or with None whether standard output is a terminal (and SB3's
    progress bar can be drawn: tqdm and rich, the ``train`` extra)."""
    if cfg.progress_bar is not None:
        return cfg.progress_bar
    if not sys.stdout.isatty():
        return False
    try:
        import rich  # noqa: F401
        import tqdm  # noqa: F401
    except ImportError:
        return False
    return True


def _model(res: Resolved, run_dir: Path, train_env: VecEnv, eval_env: VecEnv) -> BaseAlgorithm:
    """A new model (its actor set up as ``res.cfg`` says, imitation included), or the
    resumed one; either with the actor hooks, which are not saved with a model."""
    cfg = res.cfg
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
            imitate(res, model, train_env, run_dir)
    if cfg.actor_lr_scale != 1.0:
        scale_actor_lr(model, cfg.actor_lr_scale)
    if cfg.actor_bc_weight:
        add_actor_bc(model, cfg.actor_bc_weight)
    if cfg.demo_bc_weight:  # from the run's saved demonstrations
        demo_obs, demo_act = load_demonstrations(run_dir)
        add_demo_bc(
            model,
            demo_obs,
            demo_act,
            cfg.demo_bc_weight,
            [cfg.seed, DEMO_BC_STREAM, model.num_timesteps],  # type: ignore[arg-type]
        )
    return model


def _callbacks(
    res: Resolved, model: BaseAlgorithm, run_dir: Path, eval_env: VecEnv, session: str
) -> list[BaseCallback]:
    cfg = res.cfg
    callbacks: list[BaseCallback] = []
    if cfg.freeze_actor:
        callbacks.append(ActorWarmupCallback(None))
    elif cfg.critic_warmup_steps > 0:
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
                # best_model.zip written by SaveBestModel, uninterrupted
                callback_on_new_best=SaveBestModel(run_dir / "best_model.zip"),
                log_path=str(run_dir / "eval" / session),
                deterministic=True,
                verbose=cfg.verbose,
            )
        )
    return callbacks


def _train(res: Resolved, run_dir: Path, started: list[BaseAlgorithm]) -> BaseAlgorithm:
    cfg = res.cfg
    start_steps = 0 if not cfg.resume else latest_checkpoint(run_dir)[0]  # type: ignore[index]
    session = f"from_{start_steps}"
    train_env, eval_env = make_envs(res, run_dir, session=session)
    try:
        model = _model(res, run_dir, train_env, eval_env)
        train_env = model.get_env()  # type: ignore[assignment]  # resumed: the loaded VecNormalize
        started.append(model)
        # An explicit logger in the run folder: without one SB3 creates /tmp/SB3-<date>.
        formats = (
            ["csv"]
            + (["stdout"] if cfg.verbose else [])
            + (["tensorboard"] if cfg.tensorboard else [])
        )
        model.set_logger(configure_logger(str(run_dir / "tb" / session), formats))
        try:
            model.learn(
                total_timesteps=res.steps,
                callback=_callbacks(res, model, run_dir, eval_env, session),
                reset_num_timesteps=not cfg.resume,
                tb_log_name=cfg.algo,
                progress_bar=progress_bar_on(cfg),
            )
        except KeyboardInterrupt:
            # Ctrl-C (or SIGTERM, see train.common.signals): keep every step taken, as
            # rl-zoo3 does — model.zip and a checkpoint at this step; --resume goes on.
            save_final(model, train_env, run_dir)
            raise
        save_final(model, train_env, run_dir)
    finally:
        train_env.close()
        eval_env.close()
    return model
