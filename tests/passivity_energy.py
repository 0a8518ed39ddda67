"""Shared by the energy-balance tests: the passivity controller run in PyBullet with its
storage function E and every energy flow integrated alongside."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

import ptrack_gym  # noqa: F401  (registers the envs)
from agents.passivity import PassivityController, PassivityGains
from agents.passivity_tables import passivity_tables


@dataclass(frozen=True)
class EnergyRun:
    """E at the start of every control step, and the flows over [0, T − dt] (J)."""

    energy: np.ndarray
    dissipated: float  # ∫ R s̃̇² dt
    pumped: float  # ∫ pump power dt
    work: float  # ∫ q̇ᵀτ_d dt (the env's ledger)
    saturated: bool  # any commanded torque beyond the limits (would void passivity)

    @property
    def mismatch(self) -> float:
        """E(T) − E(0) − (−∫R s̃̇² + ∫pump power + ∫q̇ᵀτ_d): zero in continuous time."""
        return float(self.energy[-1] - self.energy[0] + self.dissipated - self.pumped - self.work)


def run_passivity_energy(hz: float, k_pump: float, disturbance: Any = None) -> EnergyRun:
    """One second on the two-link arm at ``hz`` (physics = control), K = 20, κ = 2, R = 0.5,
    from a moving start 0.05 rad off the path at s₀ = 0.5 s."""
    env = gym.make(
        "ptrack_gym/TwoLinkTrack-v0", physics_hz=hz, control_hz=hz, disturbance=disturbance
    ).unwrapped
    gains = PassivityGains(K=20.0, kappa=2.0, R=0.5, k_pump=k_pump)
    tables = passivity_tables(env.path, env.model)
    ctrl = PassivityController(env.model, tables, gains)
    ref = tables.exact(0.5)
    env.reset(seed=0, options={"s0": 0.5, "q": ref.q + np.array([0.05, -0.04]), "qd": ref.qd})
    q, qd = env.measured_joint_state()
    ctrl.reset(q, qd, env.s0)
    steps = int(hz)
    energy, dissipated, pumped, work, saturated = [], 0.0, 0.0, 0.0, False
    for i in range(steps):
        tau = ctrl.step(q, qd, env.dt)
        saturated |= bool(np.any(np.abs(tau) > env.torque_limits_nm))
        energy.append(ctrl.last.energy)
        _, _, _, _, info = env.step(tau / env.torque_limits_nm)
        q, qd = env.measured_joint_state()
        if i < steps - 1:  # E[-1] is at the start of the last step
            dissipated += ctrl.last.dissipation * env.dt
            pumped += ctrl.last.pump_power * env.dt
            work = info["disturbance_work_j"]
    env.close()
    return EnergyRun(np.array(energy), dissipated, pumped, work, saturated)
