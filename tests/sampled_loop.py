"""Shared by the control-rate tests: the passivity controller on an exact plant (the model
itself, integrated by RK4 under the controller's zero-order hold), so that what is measured
is the controller's discretization alone, not PyBullet's."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agents.passivity import PassivityController
from agents.passivity_tables import PassivityTables
from ptrack_gym.robots.model import RobotModel


def hold_step(
    model: RobotModel, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, dt: float, substeps: int
) -> tuple[np.ndarray, np.ndarray]:
    """(q, q̇) after ``dt`` of M q̈ + C q̇ + g = τ with τ held (RK4, ``substeps`` steps)."""

    def accel(q_: np.ndarray, qd_: np.ndarray) -> np.ndarray:
        return np.linalg.solve(
            model.mass_matrix(q_), tau - model.coriolis(q_, qd_) - model.gravity(q_)
        )

    h = dt / substeps
    for _ in range(substeps):
        k1q, k1v = qd, accel(q, qd)
        k2q, k2v = qd + 0.5 * h * k1v, accel(q + 0.5 * h * k1q, qd + 0.5 * h * k1v)
        k3q, k3v = qd + 0.5 * h * k2v, accel(q + 0.5 * h * k2q, qd + 0.5 * h * k2v)
        k4q, k4v = qd + h * k3v, accel(q + h * k3q, qd + h * k3v)
        q = q + h / 6.0 * (k1q + 2.0 * k2q + 2.0 * k3q + k4q)
        qd = qd + h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
    return q, qd


def frozen_loop_eigenvalues(
    ctrl: PassivityController,
    model: RobotModel,
    tables: PassivityTables,
    s0: float,
    dt: float,
    substeps: int = 4,
    eps: float = 1e-6,
) -> np.ndarray:
    """Eigenvalues of one control period's map of x = (q, q̇, s, ṡ, σ) — the controller's
    step, then the plant under the held torque — linearised by central differences at the
    reference point of s0 (q_r(s0), q_r'(s0), s0, 1, s0): the per-step growth of every mode
    of the sampled closed loop, frozen at s0."""
    n = model.n
    ref = tables(s0)
    x0 = np.concatenate([ref.q, ref.qd, [s0, 1.0, s0]])

    def period(x: np.ndarray) -> np.ndarray:
        q, qd = x[:n], x[n : 2 * n]
        ctrl.reset(q, qd, s0=x[2 * n], sd0=x[2 * n + 1], sigma0=x[2 * n + 2])
        tau = ctrl.step(q, qd, dt)
        q1, qd1 = hold_step(model, q, qd, tau, dt, substeps)
        st = ctrl.state
        return np.concatenate([q1, qd1, [st.s, st.sd, st.sigma]])

    jac = np.empty((len(x0), len(x0)))
    for i in range(len(x0)):
        e = np.zeros(len(x0))
        e[i] = eps
        jac[:, i] = (period(x0 + e) - period(x0 - e)) / (2.0 * eps)
    return np.linalg.eigvals(jac)


@dataclass(frozen=True)
class StorageRun:
    """The storage E at every sample of a run, and the dissipation the law reports (J)."""

    energy: np.ndarray
    dissipated: float

    @property
    def residue(self) -> float:
        """Σ_k max(0, E_{k+1} − E_k): what the discretization adds where E should fall."""
        return float(np.sum(np.maximum(np.diff(self.energy), 0.0)))


def storage_run(
    ctrl: PassivityController,
    model: RobotModel,
    tables: PassivityTables,
    q0: np.ndarray,
    qd0: np.ndarray,
    s0: float,
    sd0: float,
    dt: float,
    duration_s: float,
    substeps: int = 10,
) -> StorageRun:
    """E_k of the law at each sample of ``duration_s`` of the exact sampled closed loop."""
    ctrl.reset(q0, qd0, s0=s0, sd0=sd0, sigma0=s0)
    q, qd = np.asarray(q0, dtype=np.float64), np.asarray(qd0, dtype=np.float64)
    energy, dissipated = [], 0.0
    for _ in range(round(duration_s / dt)):
        tau = ctrl.step(q, qd, dt)
        out = ctrl.last
        assert out is not None
        energy.append(out.energy)
        dissipated += out.dissipation * dt
        q, qd = hold_step(model, q, qd, tau, dt, substeps)
        assert np.all(np.isfinite(q)), "the sampled closed loop diverged"
    return StorageRun(np.array(energy), dissipated)
