"""Run a :class:`~agents.base.Controller` as a policy on a ptrack_gym environment.

:class:`ControllerPolicy` satisfies Stable-Baselines3's ``predict`` protocol, so
``stable_baselines3.common.evaluation.evaluate_policy`` scores a controller exactly as
it scores a learned policy.

Where the state comes from: by default the env's measured joint state in float64
(``env.unwrapped.measured_joint_state()``: the true state seen through any sensing
disturbance) — the observation holds the same numbers rounded to float32. With
``state_source="observation"`` the adapter reads q, q̇ from the first 2n
entries of the observation instead (for wrapped or remote envs).

When the controller is reset: whenever the env has been reset since the controller last
was (the env counts its resets, ``env.unwrapped.episode``), so ``predict``, ``action``
and ``torque`` all start an episode from its own start state; also when SB3 passes
``episode_start=True``; ``reset_controller()`` does it by hand. The controller is reset
with the env's current reference phase ``s_ref = s₀ + t``.

Diagnostics: ``last_diagnostics`` is the controller's ``diagnostics()`` after the last
control step (for the passivity controller: s, ṡ, σ, s̃, s̃̇, σ̇, E and its terms, pump
power, dissipation), computed when read; with ``record=True`` each step's dict is
appended, with the torque, to ``records`` (cleared at every controller reset).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from agents.base import Controller, FloatArray
from ptrack_gym.errors import ControllerDivergedError, InvalidConfigError
from ptrack_gym.kernels import kernel


def require_finite_torque(tau_nm: FloatArray, controller: Controller, t_s: float) -> FloatArray:
    """``tau_nm`` if every entry is finite, else :class:`ControllerDivergedError` naming the
    controller, the time and the entries (a diverged controller, not a bad action)."""
    if not np.isfinite(tau_nm).all():  # the method: no Python-level reduction wrapper
        bad = np.flatnonzero(~np.isfinite(tau_nm)).tolist()
        raise ControllerDivergedError(
            f"{type(controller).__name__} returned a non-finite torque at t = {t_s:.4f} s "
            f"(joints {bad}): the controller diverged"
        )
    return tau_nm


def torque_to_action(tau_nm: FloatArray, torque_limits_nm: FloatArray) -> np.ndarray:
    """The env action that applies torque τ (N·m): a = clip(τ / τ_max, −1, 1) as float32.

    Every adapter (standalone or residual) converts through this one function, so equal
    torques give bit-identical actions.
    """
    return np.minimum(np.maximum(tau_nm / torque_limits_nm, -1.0), 1.0).astype(np.float32)


@kernel
def checked_action(tau_nm: FloatArray, torque_limits_nm: FloatArray, action: np.ndarray) -> int:
    """The compiled twin of :func:`require_finite_torque` followed by
    :func:`torque_to_action`: ``action`` (float32, (n,)) ← clip(τ / τ_max, −1, 1) when every
    τ is finite; returns the index of the first non-finite entry of τ, or −1."""
    for j in range(tau_nm.shape[0]):
        if not math.isfinite(tau_nm[j]):
            return j
    for j in range(tau_nm.shape[0]):
        action[j] = np.float32(min(max(tau_nm[j] / torque_limits_nm[j], -1.0), 1.0))
    return -1


class ControllerPolicy:
    """Adapter: a controller driving one ptrack env, with SB3's ``predict`` signature.

    Args:
        env: the environment (any wrapper of a ``TrackingEnv``; ``env.unwrapped`` is used
            for the joint state, the reference phase, ``dt`` and the torque limits).
        controller: the controller to run.
        state_source: ``"env"`` (exact, default) or ``"observation"``.
    """

    def __init__(
        self, env: Any, controller: Controller, state_source: str = "env", record: bool = False
    ) -> None:
        if state_source not in ("env", "observation"):
            raise InvalidConfigError(
                f"state_source must be 'env' or 'observation', got {state_source!r}"
            )
        self.env = env.unwrapped
        self.controller = controller
        self.state_source = state_source
        self.n = self.env.n
        if controller.n != self.n:
            raise InvalidConfigError(f"controller has {controller.n} joints, env has {self.n}")
        self.torque_limits_nm = np.asarray(self.env.torque_limits_nm, dtype=np.float64)
        self.last_tau_nm = np.zeros(self.n)
        self.record = record
        self.records: list[dict[str, Any]] = []
        self._episode: int | None = None  # the env episode the controller was reset for

    @property
    def last_diagnostics(self) -> dict[str, float]:
        """The controller's diagnostics after its last step."""
        return self.controller.diagnostics()

    def _state(self, observation: np.ndarray) -> tuple[FloatArray, FloatArray]:
        if self.state_source == "env":
            return self.env.measured_joint_state()
        obs = np.asarray(observation, dtype=np.float64).reshape(-1)
        return obs[: self.n].copy(), obs[self.n : 2 * self.n].copy()

    def reset_controller(self, observation: np.ndarray | None = None) -> None:
        """Reset the controller from the env's current state and reference phase."""
        q, qd = self._state(observation if observation is not None else np.zeros(2 * self.n))
        self.controller.reset(q, qd, self.env.s0 + self.env.t)
        self.records = []
        self._episode = self.env.episode

    def torque(self, observation: np.ndarray) -> FloatArray:
        """One control step: τ (N·m) for the env's current state (the controller is reset
        first if the env was reset since).

        Raises:
            ControllerDivergedError: the controller returned a non-finite torque.
        """
        tau = require_finite_torque(self._step(observation), self.controller, self.env.t)
        self._accept(tau)
        return tau

    def action(self, observation: np.ndarray) -> np.ndarray:
        """One control step as a normalized action, a = clip(τ / τ_max, −1, 1), float32:
        ``torque_to_action(torque(observation))``, with the check and the conversion in one
        compiled call (:func:`checked_action`, the same numbers)."""
        tau = self._step(observation)
        action = np.empty(self.n, dtype=np.float32)
        if checked_action(tau, self.torque_limits_nm, action) >= 0:
            require_finite_torque(tau, self.controller, self.env.t)  # raises, naming the joints
        self._accept(tau)
        return action

    def _step(self, observation: np.ndarray) -> FloatArray:
        """The controller's torque (N·m) for the env's current state, unchecked (the
        controller is reset first if the env was reset since)."""
        if self._episode != self.env.episode:
            self.reset_controller(observation)
        q, qd = self._state(observation)
        return self.controller.step(q, qd, self.env.dt)

    def _accept(self, tau: FloatArray) -> None:
        """Keep a checked torque as the last one (and record it, with ``record``)."""
        self.last_tau_nm = tau
        if self.record:
            self.records.append({"t_s": self.env.t, "tau_nm": tau, **self.last_diagnostics})

    def predict(
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """SB3's ``PolicyPredictor.predict``: accepts one observation (6n+2,) or a batch of
        one (1, 6n+2) and returns the action with the same leading shape."""
        obs = np.asarray(observation)
        batched = obs.ndim == 2
        if batched and obs.shape[0] != 1:
            raise InvalidConfigError("ControllerPolicy drives one env: batch size must be 1")
        if episode_start is not None and bool(np.asarray(episode_start).any()):
            self.reset_controller(obs.reshape(-1))
        action = self.action(obs.reshape(-1))
        return (action[None, :] if batched else action), state
