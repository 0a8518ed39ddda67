"""The runs of an RL study (:mod:`train.rl.study`): discovering a folder's runs and their
checkpoints, their groups and references, and the evaluation sweeps that test them."""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from agents.residual import NETWORK_BASE
from ptrack_gym.errors import InvalidConfigError
from train.common.algorithms import ON_POLICY
from train.evaluation.config import EvalConfig

#: Checkpoint file names of ``train.rl.run`` (SB3's CheckpointCallback).
_CKPT = re.compile(r"rl_model_(\d+)_steps\.zip$")

#: Run folders of ``train.rl.campaign``: ``<group>_s<seed>``.
_CAMPAIGN_RUN = re.compile(r"^(.+)_s(\d+)$")

#: The run-config keys every run of a study must share (``decision_every`` too: the steps of
#: its checkpoints and Monitor logs are decisions, so one step axis needs one period). The
#: algorithm is a group's: the steps are env steps whatever learns from them.
SHARED_KEYS = ("env_id", "disturbance", "episode_s", "start", "decision_every")
#: Their values for a run written before a key existed (it ran with the default).
SHARED_KEY_DEFAULTS: dict[str, object] = {"decision_every": 1}

#: The keys the runs of one group must share too (groups may differ in them: each has its
#: own reward, hyperparameters and safeguards).
GROUP_KEYS = (
    "algo", "tank", "tank_beta", "reward_weights", "reward", "kernel_weights",
    "max_path_distance", "hyperparams",
    "overrides", "scale_fraction", "scale_accel_rad_s2", "zero_init_residual", "action_penalty",
    "gate_rad", "gate_deadband_rad", "init_log_std", "critic_warmup_steps", "actor_lr_scale",
    "actor_bc_weight", "prior_gain_per_rad", "base_model", "freeze_actor",
)  # fmt: skip

#: ``train.rl.run.TrainConfig``'s defaults of :data:`GROUP_KEYS` (a test keeps them equal;
#: not imported, which would import torch): a run written before a key existed lacks it in
#: its config.yml and ran with the default, so it groups with runs that write the default.
GROUP_KEY_DEFAULTS: dict[str, object] = {
    "algo": "sac", "tank": False, "tank_beta": 0.5, "reward_weights": None,
    "reward": "quadratic", "kernel_weights": None,
    "max_path_distance": None, "hyperparams": None, "overrides": {}, "scale_fraction": 0.1,
    "scale_accel_rad_s2": None, "zero_init_residual": False, "action_penalty": 0.0,
    "gate_rad": None, "gate_deadband_rad": 0.0, "init_log_std": None, "critic_warmup_steps": 0,
    "actor_lr_scale": 1.0, "actor_bc_weight": 0.0, "prior_gain_per_rad": 0.0,
    "base_model": None, "freeze_actor": False,
}  # fmt: skip

#: The presets the final checkpoints are evaluated under (level 1), by default.
FINAL_PRESETS = ("none", "impulse", "periodic", "payload", "noise")
#: What pure RL is compared with (the issue's target: within 2x of PD + gravity).
PURE_REFERENCE = "pd_gravity"


@dataclass(frozen=True)
class Run:
    """One training run of the study."""

    path: Path
    group: str  # "pure" or "residual-<base>"
    base: str  # the residual base controller ("none" for pure RL)
    seed: int
    control_hz: float
    checkpoints: tuple[int, ...]  # step counts with a checkpoint, ascending
    config: dict[str, object]
    #: The last step count whose checkpoint holds the actor as initialised
    #: (:func:`actor_untrained_through`).
    untrained_through: float = -1
    #: The rates its base ran at when it trained (``derived.base_rates``; None: a run
    #: written before pins, or no model-based base).
    base_rates: Mapping[str, Any] | None = None


def actor_untrained_through(saved: dict) -> float:
    """The last step count at which a run's checkpoint still holds its actor as initialised,
    from its ``config.yml`` (``saved``): off-policy, ``learning_starts`` +
    ``critic_warmup_steps`` (SB3 updates only past ``learning_starts``; the warm-up holds
    the actor until it ends; a checkpoint is saved before that step's update); PPO, its
    first rollout (``n_steps`` · ``n_envs``); ``freeze_actor``: every step (inf). A run that
    imitated a controller (``imitate``) was trained before step 0: -1."""
    c, hp = saved["config"], saved.get("hyperparams") or {}
    if c.get("freeze_actor"):
        return float("inf")
    if c.get("imitate"):
        return -1
    if c.get("algo") in ON_POLICY:
        return int(hp.get("n_steps", 2048)) * int((saved.get("derived") or {}).get("n_envs", 1))
    return int(hp.get("learning_starts", 0)) + int(c.get("critic_warmup_steps") or 0)


def is_checkpoint_entry(controller: str) -> bool:
    """Whether a sweep entry is a run's checkpoint (``sb3:<run>@<steps>``), not a
    reference alone (a controller, or a network base's model ``sb3:<folder>``)."""
    return controller.startswith("sb3:") and "@" in controller


def thin(runs: Sequence[Run], every: int) -> list[Run]:
    """The runs with only the checkpoints at multiples of ``every`` steps (and each run's
    last one) kept: fewer points on the learning curves, the same final budget."""
    if every <= 0:
        raise InvalidConfigError(f"--every must be > 0, got {every}")
    return [
        dataclasses.replace(
            r,
            checkpoints=tuple(s for s in r.checkpoints if s % every == 0 or s == r.checkpoints[-1]),
        )
        for r in runs
    ]


def discover(root: Path) -> list[Run]:
    """The runs under ``root`` (folders with a ``config.yml`` and a ``model.zip``);
    raises :class:`InvalidConfigError` if there are none or they do not share
    :data:`SHARED_KEYS` and the control rate."""
    runs = []
    for cfg_file in sorted(root.glob("*/config.yml")):
        run_dir = cfg_file.parent
        if not (run_dir / "model.zip").exists():
            continue
        cfg = yaml.safe_load(cfg_file.read_text())
        c = cfg["config"]
        steps = sorted(
            int(m.group(1))
            for f in (run_dir / "checkpoints").glob("rl_model_*_steps.zip")
            if (m := _CKPT.search(f.name))
        )
        base = str(c["residual"])
        named = _CAMPAIGN_RUN.match(run_dir.name)
        if named and int(named.group(2)) == int(c["seed"]):
            group = named.group(1)  # train.rl.campaign's <group>_s<seed>: its group name
        else:
            group = "pure" if base == "none" else f"residual-{base}"
            if base != "none" and c.get("gate_rad") is not None:
                group += "-gated"
            from train.evaluation.policies import deploy_safeguards  # SB3 and torch only here

            if deploy_safeguards(run_dir):  # a gate put on at evaluation only
                group += "-deploy-gated"
        runs.append(
            Run(
                path=run_dir,
                group=group,
                base=base,
                seed=int(c["seed"]),
                control_hz=float(cfg["derived"]["control_hz"]),
                checkpoints=tuple(steps),
                config=c,
                untrained_through=actor_untrained_through(cfg),
                base_rates=(cfg.get("derived") or {}).get("base_rates"),
            )
        )
    if not runs:
        raise InvalidConfigError(f"no finished runs (config.yml + model.zip) under {root}")
    first = runs[0]
    group_first = {}
    for r in runs:
        group_first.setdefault(r.group, r)
    for r in runs[1:]:
        pairs = [(key, first) for key in SHARED_KEYS]
        pairs += [(key, group_first[r.group]) for key in GROUP_KEYS]
        for key, other in pairs:
            default = GROUP_KEY_DEFAULTS.get(key, SHARED_KEY_DEFAULTS.get(key))
            mine = r.config.get(key, default)
            theirs = other.config.get(key, default)
            if mine != theirs:
                raise InvalidConfigError(
                    f"{r.path} has {key}={mine!r}, {other.path} has {theirs!r}"
                )
        if r.control_hz != first.control_hz:
            raise InvalidConfigError(f"{r.path} runs at {r.control_hz} Hz, {first.path} at "
                                     f"{first.control_hz} Hz")  # fmt: skip
    study_gains(runs)  # one gains setting for the controllers alone and every residual's base
    return runs


def study_gains(runs: Sequence[Run]) -> str:
    """The model-based controllers' gains of a study: the ``base_gains`` every residual run
    shares ("default" for runs written before the key existed, and for a study of pure runs
    only) and the ``imitate_gains`` of every pure run that started as a copy of a controller
    (``train.rl.imitation``) — the controllers alone are evaluated with them, so each residual
    is compared with the very base it corrects and each imitating policy with its expert.

    Raises:
        InvalidConfigError: runs with different gains.
    """
    gains = {
        str(r.config.get("base_gains", "default"))
        for r in runs
        if r.base not in ("none", NETWORK_BASE)
    }
    gains |= {
        str(r.config.get("imitate_gains", "default"))
        for r in runs
        if r.base == "none" and r.config.get("imitate")
    }
    for r in runs:  # a network base that imitated a controller: that controller's gains
        if r.base == NETWORK_BASE:
            base = yaml.safe_load((Path(str(r.config["base_model"])) / "config.yml").read_text())
            if base["config"].get("imitate"):
                gains.add(str(base["config"].get("imitate_gains", "default")))
    if len(gains) > 1:
        raise InvalidConfigError(f"the runs' base or expert gains differ: {sorted(gains)}")
    return gains.pop() if gains else "default"


def study_base_rates(runs: Sequence[Run], gains: str) -> dict[str, dict[str, Any]]:
    """The ``controller_rates`` of a study's sweep: each base whose residual runs pinned rates
    (``derived.base_rates``) other than those it runs today at ``gains`` — a retune or a new
    default since they trained — runs alone at the pinned ones, so each residual is still
    compared with the base it corrects. Runs written before pins take today's rates.

    Raises:
        InvalidConfigError: runs over one base that pinned different rates.
    """
    from agents.registry import still_pinned
    from ptrack_gym.robots import profile_for_env_id

    pins: dict[str, list[dict[str, Any]]] = {}
    for r in runs:
        if r.base not in ("none", NETWORK_BASE) and r.base_rates:
            pins.setdefault(r.base, []).append(dict(r.base_rates))
    own = {}
    for base, pinned in pins.items():
        if any(p != pinned[0] for p in pinned):
            raise InvalidConfigError(
                f"the runs over {base} pinned different base rates: "
                f"{sorted(map(str, {tuple(sorted(p.items())) for p in pinned}))}"
            )
        profile = profile_for_env_id(str(runs[0].config["env_id"]))
        if not still_pinned(profile, base, gains, pinned[0]):
            own[base] = pinned[0]
    return own


def reference_of(run: Run) -> str:
    """The controller a run is compared with: its base (a network base: its model,
    ``sb3:<base_model>``); for pure RL the controller it imitated (``imitate``), else
    PD + gravity."""
    if run.base == NETWORK_BASE:
        return f"sb3:{run.config['base_model']}"
    if run.base != "none":
        return run.base
    return str(run.config.get("imitate") or PURE_REFERENCE)


def sweep_config(
    runs: Sequence[Run],
    episodes: int,
    out: Path,
    workers: int,
    presets: Sequence[str] | None = None,
) -> EvalConfig:
    """An evaluation sweep: the base controllers alone + the runs' checkpoints,
    ``episodes`` paired episodes each. ``presets=None``: every checkpoint, under the
    training disturbance (each training family: :func:`training_conditions`) and
    undisturbed (the learning curves); else the final checkpoints
    (:func:`final_steps`) under ``presets`` at level 1."""
    first = runs[0].config
    trained = training_conditions(first)
    if not trained:
        raise InvalidConfigError("the study's runs were trained without a disturbance")
    if len({lv for _, lv in trained}) > 1:
        raise InvalidConfigError(
            f"the runs trained under families at different levels {trained}: the curves "
            "take one level for every preset"
        )
    bases = sorted({reference_of(r) for r in runs if r.base != "none" or r.config.get("imitate")})
    baselines = list(dict.fromkeys([*bases, "computed_torque", PURE_REFERENCE]))
    if presets is None:
        entries = [f"sb3:{r.path}@{s}" for r in runs for s in r.checkpoints]
        disturbances, levels = ["none", *(p for p, _ in trained)], [trained[0][1]]
    else:
        steps = final_steps(runs)
        entries = [f"sb3:{r.path}@{steps}" for r in runs]
        disturbances, levels = list(presets), [1.0]
    return EvalConfig(
        env_id=str(first["env_id"]),
        controllers=baselines + entries,
        disturbances=disturbances,
        levels=levels,
        seeds=episodes,
        episode_s=float(first["episode_s"]),  # type: ignore[arg-type]
        control_hz=runs[0].control_hz,
        start=str(first["start"]),
        reference=baselines[0],
        gains=study_gains(runs),
        controller_rates=study_base_rates(runs, study_gains(runs)),
        workers=workers,
        out=str(out),
        plots=False,
    )


def training_conditions(config: Mapping[str, Any]) -> list[tuple[str, float]]:
    """(preset, level) of what a run trained under: its ``disturbance``, or each of its
    ``train_families`` (a level not given is 1); [] for an undisturbed run."""
    texts = list(config.get("train_families") or []) or [str(config.get("disturbance"))]
    out = []
    for text in texts:
        preset, _, level = str(text).partition(":")
        if preset not in ("", "none", "None"):
            out.append((preset, float(level) if level else 1.0))
    return out


def final_steps(runs: Sequence[Run]) -> int:
    """The largest step count every run has a checkpoint of (the common budget)."""
    common = set.intersection(*(set(r.checkpoints) for r in runs))
    if not common:
        raise InvalidConfigError("the runs share no checkpoint step count")
    return max(common)
