"""A trained pure policy run as a :class:`~agents.base.Controller`, so it can be a base.

:class:`NetworkController` turns a saved pure SB3 SAC policy (observation → normalized
torque, no controller inside) back into the controller interface: from the measured (q, q̇)
and its own clock s it builds the env's observation with the env's own function
(``TrackingTask.observation_numpy``: 6n + 2 entries, q, q̇, q_r(s), q_r'(s), the errors,
sin/cos of 2π s / S, clipped and rounded to float32), normalizes it with the run's frozen
``VecNormalize`` statistics (SB3's ``normalize_obs``, o' = clip((o − μ)/√(σ² + ε), ±c)),
and returns

.. math::

    \\tau = \\tau_{max} \\odot \\tanh(\\mu_\\theta(o')),

SAC's deterministic action tanh(μ(s)) times the torque limits (N·m). The actor runs in
NumPy (float32, weights copied out of the torch module once), so no torch thread runs in
the control loop. Its clock starts at the ``s_ref = s₀ + t`` of :meth:`reset` and advances
by dt per step — the env's own s_ref, so on the env that trained it, run through
:class:`~agents.policy.ControllerPolicy`, it acts as ``model.predict(obs,
deterministic=True)`` does (to float32 rounding; ``tests/test_network_base.py``).

Why: the residual wrapper (:mod:`agents.residual_wrapper`) adds a learned correction to any
controller; with this adapter its base can be a frozen imitation (``train.rl.imitation``),
so RL refines a pure policy without touching its weights — residual policy learning over a
learned initial policy (Silver et al., 2018; Ankile et al., "From imitation to refinement",
2024), instead of fine-tuning the imitation itself (``docs/rl.md``).
Imports torch and SB3 only in :func:`load_network_controller`.
"""

from __future__ import annotations

import pickle
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agents.base import FloatArray
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.paths import ReferencePath
from ptrack_gym.robots import is_preview_env_id

#: The files of a pure model folder (``train.rl.run``'s run folder or a ``models/`` copy).
MODEL_FILE = "model.zip"
VECNORMALIZE_FILE = "vecnormalize.pkl"


@dataclass(frozen=True)
class NumpyMlp:
    """A ReLU MLP's layers as float32 arrays: hidden (W, b) pairs with ReLU, then the output
    (W, b) without activation; W of shape (out, in) as torch stores it."""

    hidden: tuple[tuple[np.ndarray, np.ndarray], ...]
    output: tuple[np.ndarray, np.ndarray]

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """The output for one input vector x (float32)."""
        for w, b in self.hidden:
            x = np.maximum(w @ x + b, 0.0, dtype=np.float32)
        w, b = self.output
        return w @ x + b


class NetworkController:
    """A pure policy's deterministic action as a torque controller (see module docstring).

    Args:
        actor: μ_θ, the normalized observation → pre-tanh action map.
        normalize: the frozen observation map (a loaded ``VecNormalize``'s ``normalize_obs``;
            None: the raw observation).
        observe: the env's observation of (q_meas, q̇_meas, q_r, q_r', s_ref)
            (``TrackingTask.observation_numpy``).
        path: the reference path q_r(s) the observation describes.
        torque_limits_nm: τ_max per joint (N·m).
    """

    def __init__(
        self,
        actor: NumpyMlp,
        normalize: Callable[[np.ndarray], np.ndarray] | None,
        observe: Callable[..., np.ndarray],
        path: ReferencePath,
        torque_limits_nm: FloatArray,
    ) -> None:
        self.n = len(torque_limits_nm)
        self.actor = actor
        self.normalize = normalize
        self.observe = observe
        self.path = path
        self.torque_limits_nm = np.asarray(torque_limits_nm, dtype=np.float64)
        self.s = 0.0
        self._last_action = np.zeros(self.n)

    def reset(self, q: FloatArray, qd: FloatArray, s_ref: float) -> None:
        """Start the clock at ``s_ref`` (s); the network has no other state."""
        self.s = float(s_ref)
        self._last_action = np.zeros(self.n)

    def observation(self, q: FloatArray, qd: FloatArray) -> np.ndarray:
        """The env's observation (float32) of measured (q, q̇) at the clock's s."""
        q_ref, qd_ref, _ = self.path.evaluate(self.s)
        return self.observe(q, qd, q_ref, qd_ref, self.s)

    def step(self, q: FloatArray, qd: FloatArray, dt: float) -> FloatArray:
        """τ = τ_max ⊙ tanh(μ_θ(o')) (N·m) at the clock's s; then s += dt."""
        obs = self.observation(q, qd)
        x = self.normalize(obs) if self.normalize is not None else obs
        a = np.tanh(self.actor(x)).astype(np.float64)
        self._last_action = a
        self.s += dt
        return a * self.torque_limits_nm

    def diagnostics(self) -> dict[str, float]:
        """The clock s (s) and the last action's largest magnitude (normalized)."""
        return {"s": self.s, "max_abs_action": float(np.max(np.abs(self._last_action)))}


def numpy_actor(model: Any) -> NumpyMlp:
    """The deterministic-action network μ_θ of an SB3 SAC model as a :class:`NumpyMlp`.

    Raises:
        InvalidConfigError: not a SAC actor of Linear and ReLU layers on flat observations.
    """
    import torch

    actor = getattr(getattr(model, "policy", None), "actor", None)
    if actor is None or not hasattr(actor, "latent_pi") or not hasattr(actor, "mu"):
        raise InvalidConfigError("a network base must be a pure SAC policy (an SB3 SAC model)")
    if type(actor.features_extractor).__name__ != "FlattenExtractor":
        raise InvalidConfigError("a network base must use SB3's flat observation features")
    hidden: list[tuple[np.ndarray, np.ndarray]] = []
    layers = list(actor.latent_pi)
    for k, layer in enumerate(layers):
        if isinstance(layer, torch.nn.Linear):
            if k + 1 >= len(layers) or not isinstance(layers[k + 1], torch.nn.ReLU):
                raise InvalidConfigError("a network base's hidden layers must be Linear + ReLU")
            hidden.append(_weights(layer))
        elif not isinstance(layer, torch.nn.ReLU):
            raise InvalidConfigError(
                f"a network base's hidden layers must be Linear + ReLU, got {type(layer).__name__}"
            )
    if not isinstance(actor.mu, torch.nn.Linear):
        raise InvalidConfigError("a network base's output must be one Linear layer")
    return NumpyMlp(tuple(hidden), _weights(actor.mu))


def _weights(layer: Any) -> tuple[np.ndarray, np.ndarray]:
    w = layer.weight.detach().cpu().numpy().astype(np.float32)
    b = layer.bias.detach().cpu().numpy().astype(np.float32)
    return w, b


def check_network_folder(model_dir: str | Path, robot: str | None = None) -> None:
    """Check that ``model_dir`` holds a pure policy a network base can run, before anything
    is built: ``model.zip``; and, when the folder has the ``config.yml`` of its training
    run, that it was a pure (``residual: none``) SB3 SAC run deciding every step, on
    ``robot`` (when given) and its ``-v0`` observation, with its ``vecnormalize.pkl`` if it
    normalized observations.

    Raises:
        InvalidConfigError: naming the first mismatch.
    """
    import yaml

    folder = Path(model_dir)
    if not (folder / MODEL_FILE).is_file():
        raise InvalidConfigError(f"base_model {str(model_dir)!r}: no {MODEL_FILE} there")
    cfg_file = folder / "config.yml"
    if not cfg_file.is_file():
        return  # a model saved by hand: its observation size is checked when it is loaded
    saved = yaml.safe_load(cfg_file.read_text()) or {}
    config, derived = saved.get("config", {}), saved.get("derived", {})
    wanted = {"residual": "none", "algo": "sac", "backend": "sb3", "decision_every": 1}
    defaults = {"backend": "sb3", "decision_every": 1}
    for key, value in wanted.items():
        if config.get(key, defaults.get(key)) != value:
            raise InvalidConfigError(
                f"base_model {str(model_dir)!r} must be a pure SB3 SAC policy deciding every "
                f"step; its run has {key}={config.get(key)!r}"
            )
    if is_preview_env_id(str(config.get("env_id", ""))):
        raise InvalidConfigError(
            f"base_model {str(model_dir)!r} was trained on the preview observation "
            f"({config['env_id']}): a network base sees the plain -v0 observation"
        )
    if robot is not None and derived.get("robot") not in (None, robot):
        raise InvalidConfigError(
            f"base_model {str(model_dir)!r} was trained on {derived['robot']}, not {robot}"
        )
    if derived.get("vec_normalize") and not (folder / VECNORMALIZE_FILE).is_file():
        raise InvalidConfigError(
            f"base_model {str(model_dir)!r} normalizes observations but has no {VECNORMALIZE_FILE}"
        )


def load_network_controller(model_dir: str | Path, env: Any) -> NetworkController:
    """The pure policy saved in ``model_dir`` (``model.zip``, and ``vecnormalize.pkl`` when
    the run normalized observations) as a controller for ``env`` (any wrapper of a
    ``TrackingEnv`` of the robot it was trained on).

    Raises:
        InvalidConfigError: no such folder or model, not a pure SAC policy of this robot
            (:func:`check_network_folder`), or an observation size that does not match the env.
    """
    folder = Path(model_dir)
    u = env.unwrapped
    check_network_folder(folder, u.robot_profile.name)
    from stable_baselines3 import SAC

    try:
        model = SAC.load(folder / MODEL_FILE, device="cpu")
    except (ValueError, KeyError, TypeError, AttributeError) as err:  # another algorithm's zip
        raise InvalidConfigError(f"{folder / MODEL_FILE} is not a SAC model: {err}") from None
    normalize = None
    if (folder / VECNORMALIZE_FILE).is_file():
        with (folder / VECNORMALIZE_FILE).open("rb") as f:
            normalize = pickle.load(f).normalize_obs  # a VecNormalize without its venv
    shape = model.observation_space.shape
    if shape != u.observation_space.shape:
        raise InvalidConfigError(
            f"{folder} observes {shape}, the env {u.observation_space.shape}: "
            "a network base must be a pure policy of this robot"
        )
    return NetworkController(
        numpy_actor(model), normalize, u.task.observation_numpy, u.path,
        np.asarray(u.torque_limits_nm),
    )  # fmt: skip
