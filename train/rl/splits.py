"""The generalization protocol's fields of a training run (issue 39): the paths and
disturbance families it trains on and is evaluated on, and the plant's mass randomisation —
checked before anything is trained or written (:func:`check_splits`,
:func:`check_split_envs`)."""

from __future__ import annotations

from typing import Any

from train.evaluation.envs import check_env_kwargs, env_kwargs, parse_disturbance
from train.rl.hyperparameters import TrainConfigError


def check_splits(cfg: Any) -> None:
    """Raise :class:`TrainConfigError` for bad or overlapping splits of ``cfg`` (a
    ``TrainConfig``): path seeds that are not distinct integers, evaluation paths or
    families that are training ones, families beside a training disturbance, a mass
    randomisation outside [0, 1), or imitation over a pool of paths."""
    for name in ("train_paths", "eval_paths"):
        seeds = getattr(cfg, name)
        if seeds is not None and (
            not isinstance(seeds, list)
            or not seeds
            or len(set(seeds)) != len(seeds)
            or any(isinstance(k, bool) or not isinstance(k, int) for k in seeds)
        ):
            raise TrainConfigError(f"{name} must be distinct integer path seeds, got {seeds!r}")
    for name in ("train_families", "eval_families"):
        texts = getattr(cfg, name)
        if texts is not None and (
            not isinstance(texts, list) or not texts or not all(isinstance(t, str) for t in texts)
        ):
            raise TrainConfigError(f"{name} must be a list of disturbances, got {texts!r}")
    if not (
        isinstance(cfg.randomize_mass, (int, float))
        and not isinstance(cfg.randomize_mass, bool)
        and 0.0 <= cfg.randomize_mass < 1.0
    ):
        raise TrainConfigError(f"randomize_mass must be in [0, 1), got {cfg.randomize_mass!r}")
    if cfg.train_families is not None and cfg.disturbance != "none":
        raise TrainConfigError("train_families replaces disturbance: leave disturbance 'none'")
    if cfg.eval_families is not None and cfg.eval_disturbance is not None:
        raise TrainConfigError("give eval_families or eval_disturbance, not both")
    if cfg.train_families and cfg.eval_families:
        presets = {t.partition(":")[0] for t in cfg.train_families}
        shared = sorted(p for p in {t.partition(":")[0] for t in cfg.eval_families} if p in presets)
        if shared:
            raise TrainConfigError(f"eval_families {shared} are training families: hold them out")
    if cfg.train_paths is not None and cfg.imitate is not None:
        raise TrainConfigError(
            "imitate over a pool of paths (train_paths) is not supported yet: the expert is "
            "built for one path"
        )
    if cfg.eval_paths is not None and cfg.train_paths is None:
        raise TrainConfigError("eval_paths holds paths out of train_paths: give train_paths")
    if cfg.train_paths and cfg.eval_paths and set(cfg.train_paths) & set(cfg.eval_paths):
        shared = sorted(set(cfg.train_paths) & set(cfg.eval_paths))
        raise TrainConfigError(f"eval_paths {shared} are training paths: hold them out")


def check_split_envs(
    cfg: Any, control_hz: float, max_episode_steps: int, env_extra: dict[str, Any]
) -> None:
    """Each family list of ``cfg`` is one the env accepts (its presets, their onsets)."""
    for families in (cfg.train_families, cfg.eval_families):
        if families is not None:
            choices = {"disturbance_choices": [parse_disturbance(t) for t in families]}
            check_env_kwargs(
                cfg.env_id,
                env_kwargs(control_hz, max_episode_steps, cfg.start, None,
                           cfg.reward_weights, {**env_extra, **choices}),
            )  # fmt: skip
