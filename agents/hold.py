"""A policy that decides every k control steps: the training wrapper and its run-time twin.

Why: at 1 kHz one action changes the return by O(dt) of its value — the advantage a critic
must resolve shrinks with the control period while its approximation error does not
(Tallec, Blier & Ollivier, "Making deep Q-learning methods robust to time discretization",
ICML 2019). Holding each decision for k steps (action repeat, as the DeepMind Control
benchmarks do) makes each decision's effect k times larger, and a γ per decision of
γ_step^k keeps the horizon in seconds. The base controller of a residual still runs at the
full rate, every step, underneath.

* :class:`ActionRepeat` (training): one ``step`` applies the action for k env steps (fewer
  when the episode ends first) and returns the last observation, the *mean* of the k
  rewards (the per-step scale of the reward is kept), whether any step terminated or
  truncated, and the last step's info with ``info["decision_steps"]`` the steps taken. A
  decision cut short by the episode's end scores the mean over the steps it lasted, as
  every other decision does; with the bounded kernel reward (≥ 0) ending early still never
  pays, since every later decision's reward is lost.
* :class:`HeldActionPolicy` (evaluation): wraps anything with SB3's ``predict`` and asks it
  only every k calls, returning the held action in between — run on the unrepeated env,
  it takes exactly the decisions :class:`ActionRepeat` trains on (same observations, same
  actions, same env steps; ``tests/test_hold.py``), and every env step is recorded.
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from ptrack_gym.errors import InvalidConfigError


def check_decision_every(k: object) -> int:
    """``k`` as an int ≥ 1, else :class:`InvalidConfigError`."""
    if isinstance(k, bool) or not isinstance(k, int) or k < 1:
        raise InvalidConfigError(f"decision_every must be an integer >= 1, got {k!r}")
    return k


class ActionRepeat(gym.Wrapper[Any, Any, Any, Any]):
    """Each action held for ``k`` env steps (module docstring); k = 1 is the env itself."""

    def __init__(self, env: gym.Env[Any, Any], k: int) -> None:
        super().__init__(env)
        self.k = check_decision_every(k)

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        """Up to k env steps with ``action``; reward = mean of their rewards."""
        total, taken = 0.0, 0
        terminated = truncated = False
        obs: Any = None
        info: dict[str, Any] = {}
        while taken < self.k and not (terminated or truncated):
            obs, reward, terminated, truncated, info = self.env.step(action)
            total += float(reward)
            taken += 1
        info["decision_steps"] = taken
        return obs, total / taken, terminated, truncated, info


class HeldActionPolicy:
    """Ask ``policy`` (SB3's ``predict``) every ``k`` calls, hold its action in between; a
    call with ``episode_start`` set (or the first call) starts a new decision."""

    def __init__(self, policy: Any, k: int) -> None:
        self.policy = policy
        self.k = check_decision_every(k)
        self._held: np.ndarray | None = None
        self._age = 0

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """The held action, or a fresh one every k calls and at an episode's start."""
        starting = episode_start is not None and bool(np.any(episode_start))
        if self._held is None or starting or self._age >= self.k:
            self._held, _ = self.policy.predict(observation, state, episode_start, deterministic)
            self._age = 0
        self._age += 1
        return self._held, None
