"""Convergence of the passivity controller with its default gains, from rest off the path.

Claim (issue 3): from 10 seeded starts at rest, 0.15 rad off the path per joint (the
env's ``start="rest_near_path"`` sampler, seeds 0–9), path distance < 1e-3 rad and
|ṡ − 1| < 1e-2 hold from a stated time to the end of the run in ≥ 9 of 10.

Measured (``docs/passivity_gain_study.md``, 40-s runs): two-link 10/10, the last converged
by 13.1 s (the paper's law); iiwa 10/10, the last by 18.9 s, with the iiwa default's
low-speed phase re-synchronisation of σ (``PassivityGains.sync_rate``, not in the paper).
With the paper's law the iiwa got 7/10: three starts stalled at ṡ ≈ 0.02. Panda (franka_ros
inertials): 0/10 with the paper's law at any rates tried (a steady phase defect of σ holds the
arm a few mrad off the path for minutes); 10/10 by 10.2 s with the re-synchronisation acting
at nominal speed too (``sync_ratio`` 2).
"""

from __future__ import annotations

import gymnasium as gym

import ptrack_gym  # noqa: F401
from agents.policy import ControllerPolicy
from agents.registry import make_controller


def converged_by(env_id: str, seed: int, settle_s: float, hold_s: float) -> bool:
    """Whether the run of ``seed`` meets both thresholds from ``settle_s`` to the end
    (``settle_s + hold_s``)."""
    env = gym.make(
        env_id,
        start="rest_near_path",
        start_offset_rad=0.15,
        max_episode_steps=round((settle_s + hold_s) * 1000),
    )
    ctrl = make_controller("passivity", env)
    policy = ControllerPolicy(env, ctrl)
    obs, _ = env.reset(seed=seed)
    policy.reset_controller(obs)
    ok = True
    while True:
        obs, _, terminated, truncated, info = env.step(policy.action(obs))
        if info["t_s"] >= settle_s - 1e-9:
            sd = ctrl.diagnostics()["sd"]
            ok &= info["path_distance"] < 1e-3 and abs(sd - 1.0) < 1e-2
        if terminated:
            ok = False
        if terminated or truncated or not ok:
            break
    env.close()
    return ok


def count_converged(env_id: str, settle_s: float, hold_s: float, needed: int) -> int:
    """Converged starts among seeds 0–9; stops as soon as ``needed`` is reached or out of
    reach (the claim is "≥ ``needed`` of 10")."""
    hits, misses = 0, 0
    for seed in range(10):
        if converged_by(env_id, seed, settle_s, hold_s):
            hits += 1
        else:
            misses += 1
        if hits >= needed or misses > 10 - needed:
            break
    return hits


def test_two_link_converges_from_rest_within_20_s() -> None:
    assert count_converged("ptrack_gym/TwoLinkTrack-v0", settle_s=20.0, hold_s=5.0, needed=9) >= 9


def test_iiwa_converges_from_rest_within_25_s() -> None:
    assert count_converged("ptrack_gym/IiwaTrack-v0", settle_s=25.0, hold_s=5.0, needed=9) >= 9


def test_panda_converges_from_rest_within_12_s() -> None:
    # the Panda default re-synchronises σ at nominal speed too (sync_ratio 2): measured
    # 10/10 on seeds 0-9 and 10/10 on 10-19, the last by 10.2 s (docs/passivity_gain_study.md)
    assert count_converged("ptrack_gym/PandaTrack-v0", settle_s=12.0, hold_s=3.0, needed=9) >= 9
