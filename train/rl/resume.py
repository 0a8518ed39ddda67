"""``ptrack train --out RUN --resume``: the run's saved configuration fills what the command
line did not give, and what it did give is compared with the run's, every mismatch in one
error.

The functions work on any config dataclass (they read its fields), so this module does not
import :class:`~train.rl.config.TrainConfig` (which uses it); the key lists name its fields.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Iterable
from pathlib import Path
from typing import Any, TypeVar

import yaml

from train.rl.hyperparameters import TrainConfigError

#: The fields a resumed run must keep: what its env, reward, residual and imitation are,
#: and its hyperparameters (the checkpoint's are loaded: a changed one would be ignored;
#: ``overrides`` but ``n_timesteps``). The control rate, the env count and the
#: normalisation are compared too, as resolved (``derived``). The others may change between
#: invocations: the steps, evaluation, checkpoints, seed, and the actor hooks applied again
#: on every resume (warm-up, actor_*).
RESUME_KEYS = (
    "algo", "backend", "env_id", "residual", "scale_fraction", "scale_accel_rad_s2",
    "base_gains", "base_model", "decision_every", "start", "episode_s", "reward_weights",
    "reward", "kernel_weights", "max_path_distance", "action_penalty", "gate_rad",
    "gate_deadband_rad", "prior_gain_per_rad", "imitate", "imitate_gains", "imitate_rounds",
    "imitate_steps", "imitate_round_steps", "imitate_noise", "demo_bc_weight", "hyperparams",
    "overrides",
)  # fmt: skip
#: The fields a resumed invocation never takes from the run: where it is, that it resumes,
#: the steps to add, how it shows its progress.
PER_INVOCATION = ("out", "resume", "steps", "progress_bar", "verbose")

Config = TypeVar("Config")


def saved_config(run_dir: Path) -> dict[str, Any] | None:
    """The run's ``config.yml`` (sections ``config``, ``derived``, ``hyperparams``), or
    None without one.

    Raises:
        TrainConfigError: a ``config.yml`` without a ``config`` section.
    """
    path = run_dir / "config.yml"
    if not path.is_file():
        return None
    data = yaml.safe_load(path.read_text())
    if not isinstance(data, dict) or not isinstance(data.get("config"), dict):
        raise TrainConfigError(f"{path}: not a run's config (no 'config' section)")
    return data


def resume_config(cfg: Config, given: Iterable[str]) -> Config:
    """The config of ``--resume`` into ``cfg.out``: the fields named in ``given`` (what the
    command line set, :func:`given_fields`) as in ``cfg``, every other one as the run's
    ``config.yml`` saved it — a field the run predates keeps ``cfg``'s default, which the
    run ran with —, but :data:`PER_INVOCATION`'s (``steps`` is the steps to add: given,
    or the hyperparameter file's ``n_timesteps``); ``overrides`` are the run's updated by
    the given ones. Without ``cfg.resume`` or a run there, ``cfg`` itself (validation then
    says there is nothing to resume). The given values are compared with the run's by
    :func:`check_resume_compatible`."""
    saved = saved_config(Path(cfg.out)) if cfg.resume else None  # type: ignore[attr-defined]
    if saved is None:
        return cfg
    given, theirs = set(given), saved["config"]
    taken = {
        f.name: theirs[f.name]
        for f in dataclasses.fields(cfg)  # type: ignore[arg-type]
        if f.name in theirs and f.name not in given and f.name not in PER_INVOCATION
    }
    if "overrides" in given:
        taken["overrides"] = {**(theirs.get("overrides") or {}), **cfg.overrides}  # type: ignore[attr-defined]
    return dataclasses.replace(cfg, **taken)  # type: ignore[type-var]


def given_fields(args: argparse.Namespace, cls: type) -> set[str]:
    """The fields of the dataclass ``cls`` that parsed arguments set: by a flag, ``--set``,
    the ``--config`` file, or ``--hp`` (``overrides``). The parser stores a flag only when
    it is given (``train.common.arguments``)."""
    names = {f.name for f in dataclasses.fields(cls)}
    given = {name for name in names if hasattr(args, name)}
    given |= {item.partition("=")[0].strip() for item in getattr(args, "set", None) or []}
    if getattr(args, "config", None):
        given |= set(yaml.safe_load(Path(args.config).read_text()) or {})
    if getattr(args, "hp", None):
        given.add("overrides")
    return given & names


def check_resume_compatible(cfg: Any, derived: dict[str, Any], run_dir: Path) -> None:
    """Every :data:`RESUME_KEYS` value of ``cfg``, and every ``derived`` value (the
    resolved control rate, env count and normalisation), equal to the run's in ``run_dir``
    (a key the run predates: the field's default, which the run ran with).

    Raises:
        TrainConfigError: listing every mismatch, the run's value → the given one.
    """
    saved = saved_config(run_dir)
    if saved is None:
        return
    defaults = {
        f.name: f.default for f in dataclasses.fields(cfg) if f.default is not dataclasses.MISSING
    }
    theirs, differ = saved["config"], []
    for key in RESUME_KEYS:
        mine = getattr(cfg, key)
        old = theirs.get(key, defaults.get(key, mine))
        if key == "overrides":  # the steps to add may come from n_timesteps
            old, mine = ({k: v for k, v in d.items() if k != "n_timesteps"} for d in (old, mine))
        if old != mine:
            differ.append(f"{key}: {old!r} → {mine!r}")
    before = dict(saved.get("derived") or {})
    if "vec_normalize" in before:  # saved as the VecNormalize arguments, or None
        before["vec_normalize"] = before["vec_normalize"] is not None
    for key, mine in derived.items():
        if key in before and before[key] != mine:
            differ.append(f"{key}: {before[key]!r} → {mine!r}")
    if differ:
        raise TrainConfigError(
            f"--resume: {len(differ)} setting(s) differ from the run's in {run_dir} (the "
            f"run's → given): {'; '.join(differ)}. Leave them out to continue the run as it "
            "was, or train into a new --out"
        )
