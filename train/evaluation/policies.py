"""Trained Stable-Baselines3 runs of ``ptrack train``: the algorithms, the files
of a run folder, and a run loaded as a policy with SB3's ``predict``.

A residual run folder may hold a ``deploy.yml``: safeguards applied when the run is
*evaluated*, not when it was trained — the path-error gate (``gate_rad``,
``gate_deadband_rad``) put on a residual trained without it (:func:`deploy_safeguards`).

A run is named ``sb3:<run folder>`` (its final ``model.zip``) or ``sb3:<run folder>@<steps>``
(its checkpoint ``checkpoints/rl_model_<steps>_steps.zip`` with the matching VecNormalize
statistics): a learning curve is a sweep over a run's checkpoints.
"""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml
from gymnasium import spaces
from stable_baselines3 import PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.policies import BasePolicy

from ptrack_gym.errors import InvalidConfigError
from train.common.algorithms import ALGO_NAMES, RECURRENT_ALGOS

#: The classes of Stable-Baselines3's own algorithms (``train.common.algorithms``).
ALGOS: dict[str, type[BaseAlgorithm]] = {"sac": SAC, "td3": TD3, "ppo": PPO}

#: The learner implementations ``--backend`` accepts: Stable-Baselines3 itself (torch) and
#: sbx, the SB3 team's JAX port of the same algorithms behind the same interface (the
#: optional ``sbx`` extra).
BACKENDS = ("sb3", "sbx")

#: XLA's flags for one compute thread, set (unless the user set XLA_FLAGS) before sbx
#: imports JAX: the parallelism is across runs, one process per core.
_XLA_ONE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"


def sbx_available() -> bool:
    """Whether the optional ``sbx`` extra (sbx-rl, JAX) is installed."""
    import importlib.util

    return importlib.util.find_spec("sbx") is not None


def algo_class(algo: str, backend: str = "sb3") -> type[BaseAlgorithm]:
    """The model class of ``algo`` ("sac", "td3", "ppo"; "ppo_lstm": sb3-contrib's
    RecurrentPPO, SB3 backend only) in ``backend`` ("sb3", "sbx"): an SB3 ``BaseAlgorithm``
    either way (sbx's classes subclass SB3's, so callbacks, ``VecNormalize``, checkpoints
    and ``predict`` are SB3's).

    Raises:
        InvalidConfigError: an unknown algorithm or backend, or sbx without its extra.
    """
    if algo not in ALGO_NAMES:
        raise InvalidConfigError(f"unknown algo {algo!r}; known: {sorted(ALGO_NAMES)}")
    if backend not in BACKENDS:
        raise InvalidConfigError(f"unknown backend {backend!r}; known: {list(BACKENDS)}")
    if algo in RECURRENT_ALGOS:
        if backend != "sb3":
            raise InvalidConfigError(f"algo {algo!r} exists in the sb3 backend only")
        try:
            import sb3_contrib
        except ImportError as exc:
            raise InvalidConfigError(
                f"algo {algo!r} needs the optional 'recurrent' extra (sb3-contrib): "
                "pip install 'ptrack_gym[recurrent]'"
            ) from exc
        return getattr(sb3_contrib, RECURRENT_ALGOS[algo])
    if backend == "sb3":
        return ALGOS[algo]
    if not sbx_available():
        raise InvalidConfigError(
            "backend 'sbx' needs the optional 'sbx' extra: pip install 'ptrack_gym[sbx]' "
            "(install torch first, or pip pulls a CUDA build)"
        )
    import os

    os.environ.setdefault("XLA_FLAGS", _XLA_ONE_THREAD)
    import sbx

    return {"sac": sbx.SAC, "td3": sbx.TD3, "ppo": sbx.PPO}[algo]


SB3_PREFIX = "sb3:"


def sb3_files(name: str) -> tuple[Path, Path, Path]:
    """(run folder, model zip, VecNormalize pickle) of ``sb3:<run>`` or ``sb3:<run>@<steps>``;
    the pickle may not exist (a run without normalization)."""
    run, at, steps = name[len(SB3_PREFIX) :].partition("@")
    run_dir = Path(run)
    if not at:
        return run_dir, run_dir / "model.zip", run_dir / "vecnormalize.pkl"
    if not steps.isdigit():
        raise InvalidConfigError(f"{name}: '@' must be followed by a step count")
    ckpt = run_dir / "checkpoints"
    return (
        run_dir,
        ckpt / f"rl_model_{steps}_steps.zip",
        ckpt / f"rl_model_vecnormalize_{steps}_steps.pkl",
    )


def run_config(run_dir: Path) -> dict[str, Any]:
    """The ``config.yml`` of a run folder (``config``, ``derived``, ``hyperparams``)."""
    return yaml.safe_load((run_dir / "config.yml").read_text())


#: The keys a run's ``deploy.yml`` may set (the residual wrapper's gate, rad).
DEPLOY_KEYS = ("gate_rad", "gate_deadband_rad", "tank")


def deploy_safeguards(run_dir: Path) -> dict[str, Any]:
    """The evaluation-time safeguards of a run: ``deploy.yml``'s mapping (keys of
    :data:`DEPLOY_KEYS`), or {} without one. They override the training config's own
    gate — and, with ``tank: true``, put the residual behind an energy tank of the
    default parameters (:mod:`agents.energy_tank`; a passivity base only) — when the run's
    env is rebuilt for evaluation; the policy is unchanged (its observation includes
    neither the gate nor the tank).

    Raises:
        InvalidConfigError: an unknown key, a bad value (``check_safeguards``), or a
            deploy.yml on a run without a residual base.
    """
    from agents.residual import check_safeguards

    path = run_dir / "deploy.yml"
    if not path.exists():
        return {}
    data = yaml.safe_load(path.read_text()) or {}
    if not isinstance(data, dict) or set(data) - set(DEPLOY_KEYS):
        raise InvalidConfigError(f"{path}: expected a mapping of {DEPLOY_KEYS}, got {data!r}")
    if run_config(run_dir)["config"]["residual"] == "none":
        raise InvalidConfigError(f"{path}: deployment safeguards need a residual run")
    check_safeguards(0.0, data.get("gate_rad"), data.get("gate_deadband_rad", 0.0))
    if not isinstance(data.get("tank", False), bool):
        raise InvalidConfigError(f"{path}: tank must be true or false, got {data['tank']!r}")
    return dict(data)


def check_sb3_run(name: str, env_id: str) -> Path:
    """The run folder of ``sb3:…``, checked: its config and model exist, it was trained
    on ``env_id``'s robot (either observation version: the run is evaluated in its own,
    the same task and dynamics), its network base (if any) is a pure policy there and its
    ``deploy.yml`` (if any) is valid; raises :class:`InvalidConfigError`."""
    run_dir, model_zip, _ = sb3_files(name)
    for path in (run_dir / "config.yml", model_zip):
        if not path.exists():
            raise InvalidConfigError(f"{name}: {path} does not exist")
    from ptrack_gym.robots import profile_for_env_id

    config = run_config(run_dir)["config"]
    trained_on = config["env_id"]
    if profile_for_env_id(trained_on).name != profile_for_env_id(env_id).name:
        raise InvalidConfigError(f"{name} was trained on {trained_on}, not on {env_id}'s robot")
    if config.get("base_model") is not None:  # a network base: it must be there, and pure
        from agents.residual import check_base_model

        check_base_model(config["residual"], config["base_model"], profile_for_env_id(env_id).name)
    deploy_safeguards(run_dir)  # a bad deploy.yml is named before anything runs
    return run_dir


class SB3Policy:
    """A trained model acting deterministically on raw observations: SB3's ``predict``,
    with the run's VecNormalize observation statistics applied first when it has them.

    A recurrent model (RecurrentPPO) keeps its hidden state here between calls when the
    caller passes none (the episode loop does not): ``episode_start`` true starts it over,
    as SB3's ``evaluate_policy`` does; a caller that does not say where episodes start
    calls :meth:`reset` before each. A caller that passes ``state`` keeps its own."""

    def __init__(self, model: BaseAlgorithm, obs_stats: Any | None) -> None:
        self.model = model
        self.obs_stats = obs_stats
        self.recurrent = type(model).__name__ in RECURRENT_ALGOS.values()
        self._state: Any = None
        # SB3's own torch policies (not sbx's JAX ones, which subclass them; not a
        # recurrent one): :meth:`_predict`
        policy = getattr(model, "policy", None)
        self._fast = (
            not self.recurrent
            and isinstance(policy, BasePolicy)
            and type(policy).__module__.startswith("stable_baselines3.")
        )

    def reset(self) -> None:
        """Forget a recurrent model's hidden state: the next call starts an episode."""
        self._state = None

    def _predict(self, x: np.ndarray) -> np.ndarray:
        """SB3's ``BasePolicy.predict`` (deterministic, no hidden state) step for step, the
        same torch operations on the same tensors — bit for bit its action — without its
        per-call ``set_training_mode(False)``, a walk over every module (a call of a
        [64, 64] SAC actor 430 → 300 µs, measured beside two training runs): the policy is
        put in eval mode once, and again only if something switched it back."""
        policy = self.model.policy
        if policy.training:
            policy.set_training_mode(False)
        obs_tensor, vectorized = policy.obs_to_tensor(x)
        with torch.no_grad():
            actions = policy._predict(obs_tensor, deterministic=True)
        actions = actions.cpu().numpy().reshape((-1, *policy.action_space.shape))
        if isinstance(policy.action_space, spaces.Box):
            if policy.squash_output:
                actions = policy.unscale_action(actions)
            else:
                actions = np.clip(actions, policy.action_space.low, policy.action_space.high)
        return actions if vectorized else actions.squeeze(axis=0)

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        x = self.obs_stats.normalize_obs(observation) if self.obs_stats is not None else observation
        if self._fast and deterministic:
            return self._predict(x), state
        if not self.recurrent or state is not None:
            return self.model.predict(x, state, episode_start, deterministic)
        if episode_start is None:  # no episode boundary given: a new episode once, then on
            episode_start = np.array([self._state is None])
        action, self._state = self.model.predict(x, self._state, episode_start, deterministic)
        return action, self._state


def load_sb3_policy(name: str, env_id: str) -> tuple[SB3Policy, dict[str, Any]]:
    """The run ``name`` as an :class:`SB3Policy`, and the run's config (to rebuild its env:
    residual base, scale, control rate)."""
    run_dir = check_sb3_run(name, env_id)
    _, model_zip, stats_pkl = sb3_files(name)
    cfg = run_config(run_dir)
    config = cfg["config"]
    model = algo_class(config["algo"], config.get("backend", "sb3")).load(
        str(model_zip), device="cpu"
    )
    if cfg["derived"].get("vec_normalize") and not stats_pkl.exists():
        raise InvalidConfigError(
            f"{name}: the run normalizes observations but {stats_pkl} is missing"
        )
    stats = None
    if stats_pkl.exists():
        with stats_pkl.open("rb") as fh:
            stats = pickle.load(fh)  # a VecNormalize without its venv: normalize_obs works
    return SB3Policy(model, stats), cfg
