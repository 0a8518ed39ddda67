"""Checkpoints of a training run: the newest one, saving the final state, resuming.

Files in ``<run>/checkpoints/``: ``rl_model_<steps>_steps.zip`` (SB3's
``CheckpointCallback``), the matching ``rl_model_vecnormalize_<steps>_steps.pkl`` and, for
the newest checkpoint only, ``rl_model_replay_buffer_<steps>_steps.pkl``. The final state is
always saved there too, so ``--resume`` continues any finished or interrupted run. Every
save here runs :func:`~train.common.signals.uninterrupted` — Ctrl-C or SIGTERM during one
is delivered once the files are whole — and writes each file under a temporary name
renamed into place (:func:`~train.common.runs.saved_whole`), a checkpoint's zip last: a
process killed outright (SIGKILL, out of memory) leaves no half-written file under a
checkpoint's name, and a checkpoint's zip is there only once its replay buffer and
statistics are.
"""

from __future__ import annotations

from pathlib import Path

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from train.common.checkpoint_files import CHECKPOINT_PREFIX, latest_checkpoint
from train.common.checkpoint_files import REPLAY_RE as _REPLAY_RE
from train.common.runs import saved_whole
from train.common.signals import uninterrupted
from train.rl.hyperparameters import TrainConfigError


def prune_replay_buffers(folder: Path, keep_steps: int) -> None:
    """Delete the checkpoint replay buffers of ``folder`` older than ``keep_steps``.

    A replay buffer is saved whole (SAC's default 300 000 transitions of the residual
    TwoLink env: ~60 MB), so only the newest one, the one ``--resume`` uses, is kept.
    """
    for path in folder.glob(f"{CHECKPOINT_PREFIX}_replay_buffer_*_steps.pkl"):
        m = _REPLAY_RE.match(path.name)
        if m and int(m.group(1)) < keep_steps:
            path.unlink()


class PruningCheckpointCallback(CheckpointCallback):
    """SB3's CheckpointCallback (its file names, every ``save_freq`` calls) saving through
    :func:`write_checkpoint`: uninterrupted, each file renamed into place, only the newest
    replay buffer kept."""

    def _on_step(self) -> bool:
        if self.n_calls % self.save_freq == 0:
            write_checkpoint(
                self.model, self.model.get_vec_normalize_env() if self.save_vecnormalize else None,
                Path(self.save_path), replay_buffer=self.save_replay_buffer,
            )  # fmt: skip
        return True


class SaveBestModel(BaseCallback):
    """``EvalCallback``'s ``callback_on_new_best``: writes ``best_model.zip`` uninterrupted
    and renamed into place (in place of the EvalCallback's own save, which a signal could
    cut short)."""

    def __init__(self, path: Path) -> None:
        super().__init__()
        self.path = path

    def _on_step(self) -> bool:
        with uninterrupted():
            saved_whole(self.path, self.model.save)
        return True


def write_checkpoint(
    model: BaseAlgorithm, vecnormalize: VecEnv | None, folder: Path, replay_buffer: bool = True
) -> None:
    """``<folder>/rl_model_<steps>_steps.zip`` with, before it, its VecNormalize statistics
    (``vecnormalize``, where one is given) and, with ``replay_buffer``, an off-policy
    model's replay buffer (older ones pruned). Uninterrupted, each file renamed into
    place."""
    steps = model.num_timesteps
    folder.mkdir(parents=True, exist_ok=True)
    with uninterrupted():
        if replay_buffer and isinstance(model, OffPolicyAlgorithm):
            saved_whole(
                folder / f"{CHECKPOINT_PREFIX}_replay_buffer_{steps}_steps.pkl",
                model.save_replay_buffer,
            )
        if isinstance(vecnormalize, VecNormalize):
            saved_whole(
                folder / f"{CHECKPOINT_PREFIX}_vecnormalize_{steps}_steps.pkl",
                lambda p: vecnormalize.save(str(p)),
            )
        saved_whole(folder / f"{CHECKPOINT_PREFIX}_{steps}_steps.zip", model.save)
        if replay_buffer:
            prune_replay_buffers(folder, steps)


def save_checkpoint(
    model: BaseAlgorithm, train_env: VecEnv, run_dir: Path, replay_buffer: bool = True
) -> Path:
    """``checkpoints/rl_model_<steps>_steps.zip`` of ``run_dir`` and its VecNormalize
    statistics (``train_env``'s, where it is one); with ``replay_buffer``, an off-policy
    model's replay buffer too (:func:`write_checkpoint`). Returns the checkpoint folder."""
    ckpt = run_dir / "checkpoints"
    write_checkpoint(model, train_env, ckpt, replay_buffer)
    return ckpt


def save_final(model: BaseAlgorithm, train_env: VecEnv, run_dir: Path) -> None:
    """model.zip / vecnormalize.pkl, and the same state as a checkpoint for --resume
    (with the replay buffer of an off-policy model); uninterrupted, each file renamed into
    place."""
    with uninterrupted():
        saved_whole(run_dir / "model.zip", model.save)
        save_checkpoint(model, train_env, run_dir)
        if isinstance(train_env, VecNormalize):
            saved_whole(run_dir / "vecnormalize.pkl", lambda p: train_env.save(str(p)))


def load_checkpoint(
    algo: type[BaseAlgorithm],
    run_dir: Path,
    train_env: VecEnv,
    eval_env: VecEnv,
    normalized: bool,
    device: str,
    tensorboard: bool,
) -> tuple[BaseAlgorithm, VecEnv]:
    """The newest checkpoint of ``run_dir`` (model, VecNormalize statistics into both
    envs, replay buffer) to continue training; returns the model and the training env."""
    found = latest_checkpoint(run_dir)
    if found is None:
        raise TrainConfigError(f"--resume: no checkpoint in {run_dir / 'checkpoints'}")
    steps, path = found
    ckpt = run_dir / "checkpoints"
    vecnorm = ckpt / f"{CHECKPOINT_PREFIX}_vecnormalize_{steps}_steps.pkl"
    if normalized:
        if not vecnorm.exists():
            raise TrainConfigError(f"--resume: {vecnorm} is missing")
        assert isinstance(train_env, VecNormalize) and isinstance(eval_env, VecNormalize)
        train_env = VecNormalize.load(str(vecnorm), train_env.venv)
        train_env.training = True
        eval_env.obs_rms = train_env.obs_rms.copy()
    model = algo.load(
        path,
        env=train_env,
        device=device,
        tensorboard_log=str(run_dir / "tb") if tensorboard else None,
        print_system_info=False,
    )
    replay = ckpt / f"{CHECKPOINT_PREFIX}_replay_buffer_{steps}_steps.pkl"
    if isinstance(model, OffPolicyAlgorithm) and replay.exists():
        model.load_replay_buffer(replay)
    return model, train_env
