"""A preview of the reference ahead: :class:`ReferencePreview`, and the preview envs.

A policy that sees only q_r(s₀ + t) and q_r'(s₀ + t) (the ``-v0`` observation) cannot
anticipate the path: on a path it never trained on it must react to every bend. The preview
envs (``ptrack_gym/<Robot>TrackPreview-v0``) append, for each preview time δ of ``preview_s``
(default 0.05, 0.1, 0.2 and 0.4 s), where the reference will be relative to the arm and how
fast it will move; the ``-v0`` envs are unchanged.

Observation of a preview env (m = len(preview_s), n joints): the ``-v0`` observation (6n + 2
entries, ``TrackingEnv``'s table), then for i = 1..m

| index (after the v0 block)   | quantity                            | unit  | bound   |
|------------------------------|-------------------------------------|-------|---------|
| 2n(i−1) : 2n(i−1) + n        | q_r(s₀ + t + δ_i) − q (measured q)  | rad   | ±8π     |
| 2n(i−1) + n : 2n i           | q_r'(s₀ + t + δ_i)                  | rad/s | ±v_max  |

clipped to the bounds, float32. The reference is the time-indexed one the env rewards
(``TrackingEnv``); q is the measured joint position (sensor disturbances included).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ptrack_gym.errors import InvalidConfigError

#: The preview times of the preview envs (s).
DEFAULT_PREVIEW_S: tuple[float, ...] = (0.05, 0.1, 0.2, 0.4)


class ReferencePreview(gym.ObservationWrapper[np.ndarray, np.ndarray, np.ndarray]):
    """Append the reference ``preview_s`` ahead to a ptrack_gym env's observation (module
    docstring).

    Args:
        env: a ptrack_gym env (any wrapper of a ``TrackingEnv``).
        preview_s: the preview times δ (s), each finite and > 0, at least one.

    Raises:
        InvalidConfigError: (a ``ValueError``) an empty, non-finite or non-positive
            preview time.
    """

    def __init__(self, env: gym.Env[np.ndarray, np.ndarray], preview_s: Sequence[float]) -> None:
        times = tuple(preview_s)
        if not times or not all(
            isinstance(d, (int, float)) and not isinstance(d, bool) and math.isfinite(d) and d > 0
            for d in times
        ):
            raise InvalidConfigError(
                f"preview_s must be one or more finite times > 0 (s), got {preview_s!r}"
            )
        super().__init__(env)
        self.preview_s = np.array(times, dtype=np.float64)
        u = env.unwrapped
        n, vmax = int(u.n), float(u.max_speed)
        inner = env.observation_space
        assert isinstance(inner, spaces.Box)
        block = np.concatenate([np.full(n, 8.0 * math.pi), np.full(n, vmax)])
        high = np.concatenate([inner.high.astype(np.float64), np.tile(block, len(times))])
        self._high = high.astype(np.float32).astype(np.float64)
        self.observation_space = spaces.Box(
            -high.astype(np.float32), high.astype(np.float32), dtype=np.float32
        )

    def observation(self, observation: np.ndarray) -> np.ndarray:
        u = self.env.unwrapped
        q, _ = u.measured_joint_state()
        q_ahead, qd_ahead, _ = u.path.evaluate(u.s0 + u.t + self.preview_s)  # (m, n) each
        extra = np.concatenate([q_ahead - q, qd_ahead], axis=1).ravel()
        full = np.concatenate([observation.astype(np.float64), extra])
        return np.clip(full, -self._high, self._high).astype(np.float32)


def make_preview_env(preview_s: Sequence[float] = DEFAULT_PREVIEW_S, **kwargs: Any) -> gym.Env:
    """The entry point of the preview ids: a ``TrackingEnv`` of ``kwargs`` in a
    :class:`ReferencePreview` of ``preview_s``."""
    from ptrack_gym.envs.tracking import TrackingEnv

    env = TrackingEnv(**kwargs)
    try:
        return ReferencePreview(env, preview_s)
    except BaseException:
        env.close()
        raise
