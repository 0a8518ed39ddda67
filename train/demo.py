"""A short demo rollout that prints tracking figures (the main job until the evaluation
harness replaces it): each robot's env, a gravity-compensating PD policy is not yet
available here, so the demo holds the nominal inverse-dynamics feed-forward torque of
the reference, τ = τ_r(s₀ + t), and reports how far the arm drifts from the path.

Run: ``python -m train.demo``.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

import ptrack_gym


def main() -> None:
    """Run one 2-s episode per robot with the feed-forward torque and print figures."""
    print(f"{'env id':28s} {'steps':>6s} {'final path dist (rad)':>22s} {'max |e(t)| (rad)':>17s}")
    for env_id in ptrack_gym.ENV_IDS:
        env = gym.make(env_id)
        u = env.unwrapped
        env.reset(seed=0)
        info: dict = {}
        worst, steps = 0.0, 2000
        for _ in range(steps):
            point = u.tables(u.s0 + u.t)
            action = np.clip(point.tau / u.torque_limits_nm, -1.0, 1.0)
            _obs, _reward, terminated, truncated, info = env.step(action)
            worst = max(worst, info["tracking_error"])
            if terminated or truncated:
                break
        print(f"{env_id:28s} {steps:6d} {info['path_distance']:22.3e} {worst:17.3e}")
        env.close()


if __name__ == "__main__":
    main()
