"""MP4 of one episode per controller, through Gymnasium's ``RecordVideo`` (headless).

The env steps at the control rate (1 kHz by default), far above a video's frame rate, so
:class:`RenderEvery` hands ``RecordVideo`` only every k-th step's frame (a one-frame list,
Gymnasium's ``rgb_array_list`` convention; an empty list on the other steps), and the
video is written at ``control_hz / k`` frames per second: real time.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import RecordVideo

from agents.policy import ControllerPolicy
from agents.registry import make_controller


class RenderEvery(gym.Wrapper[Any, Any, Any, Any]):
    """``render()`` returns ``[frame]`` on every ``every``-th step and ``[]`` otherwise."""

    def __init__(self, env: gym.Env[Any, Any], every: int) -> None:
        super().__init__(env)
        self.every = max(int(every), 1)
        self._count = 0

    def reset(self, **kwargs: Any) -> Any:
        self._count = 0
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> Any:
        self._count += 1
        return self.env.step(action)

    def render(self) -> list[np.ndarray]:
        if self._count % self.every == 0:
            return [self.env.render()]
        return []


def record_episode(
    env_id: str,
    controller: str,
    folder: Path,
    seed: int,
    env_kwargs: dict[str, Any],
    fps: int = 30,
    gains: Any = None,
) -> Path:
    """Record one episode of ``controller`` (with ``gains``, as ``make_controller`` takes
    them) on ``env_id`` as ``folder/<controller>-episode-0.mp4`` (seeded like the sweep's
    example episode)."""
    env = gym.make(env_id, render_mode="rgb_array", **env_kwargs)
    every = max(round(1.0 / (env.unwrapped.dt * fps)), 1)
    real_fps = round(1.0 / (env.unwrapped.dt * every))
    wrapped = RecordVideo(
        RenderEvery(env, every),
        str(folder),
        episode_trigger=lambda _: True,
        name_prefix=controller,
        fps=real_fps,
        disable_logger=True,
    )
    policy = ControllerPolicy(wrapped, make_controller(controller, wrapped, gains))
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*render.*has just been called.*")
        obs, _ = wrapped.reset(seed=seed)
        while True:
            obs, _, terminated, truncated, _ = wrapped.step(policy.predict(obs)[0])
            if terminated or truncated:
                break
        wrapped.close()
    return folder / f"{controller}-episode-0.mp4"
