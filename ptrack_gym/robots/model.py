"""Dynamics models: the :class:`RobotModel` protocol and a PyBullet-backed implementation.

A model answers questions about ``M(q) q̈ + C(q, q̇) q̇ + g(q) = τ`` at any state it is
given; it holds no state of the simulated arm. :class:`BulletModel` owns a private
PyBullet client with its own copy of the URDF, so perturbing the simulated body
(payload, ``changeDynamics``) never changes the model: the controller keeps the nominal
model on purpose. (PyBullet's dynamics queries on a body go stale after
``changeDynamics``, bullet3 issue 4809 — another reason never to query the plant.)
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from ptrack_gym.robots.spec import FloatArray, RobotSpec
from ptrack_gym.sim import BulletSim


@runtime_checkable
class RobotModel(Protocol):
    """Rigid-body dynamics of an n-joint arm (SI units; q in rad, τ in N·m)."""

    n: int

    def mass_matrix(self, q: FloatArray) -> FloatArray:
        """M(q), symmetric positive definite, shape (n, n) (kg·m²)."""
        ...

    def gravity(self, q: FloatArray) -> FloatArray:
        """g(q) = ∂U/∂q, shape (n,) (N·m)."""
        ...

    def potential(self, q: FloatArray) -> float:
        """Gravitational potential energy U(q) (J), up to a constant."""
        ...

    def coriolis(self, q: FloatArray, qd: FloatArray) -> FloatArray:
        """The Coriolis and centrifugal product C(q, q̇) q̇, shape (n,) (N·m)."""
        ...

    def inverse_dynamics(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        """τ = M(q) q̈ + C(q, q̇) q̇ + g(q), shape (n,) (N·m)."""
        ...


class BulletModel:
    """:class:`RobotModel` computed by PyBullet on a private, query-only copy of the arm.

    Args:
        spec: the robot; its URDF is loaded into a new ``p.DIRECT`` client.
        gravity_mps2: gravity magnitude (m/s²) used by ``gravity``/``potential``.
    """

    def __init__(self, spec: RobotSpec, gravity_mps2: float = 9.81) -> None:
        self.spec = spec
        self.gravity_mps2 = float(gravity_mps2)
        self._sim = BulletSim(gravity_mps2=gravity_mps2)
        self._arm = self._sim.load_arm(spec.urdf_path, spec.joint_names, spec.torque_limits_nm)
        self.n = self._arm.n
        self.link_masses_kg: FloatArray = self._arm.link_masses()
        """Nominal masses (kg) of links 0..L−1 (PyBullet order, fixed base excluded)."""
        self._zeros = np.zeros(self.n)

    def mass_matrix(self, q: FloatArray) -> FloatArray:
        """M(q) (kg·m²), shape (n, n), by PyBullet's composite-rigid-body algorithm."""
        return self._arm.mass_matrix(q)

    def inverse_dynamics(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        """τ = M(q) q̈ + C(q, q̇) q̇ + g(q) (N·m), by recursive Newton–Euler."""
        return self._arm.inverse_dynamics(q, qd, qdd)

    def gravity(self, q: FloatArray) -> FloatArray:
        """g(q) = τ(q, 0, 0) (N·m)."""
        return self._arm.inverse_dynamics(q, self._zeros, self._zeros)

    def coriolis(self, q: FloatArray, qd: FloatArray) -> FloatArray:
        """C(q, q̇) q̇ = τ(q, q̇, 0) − g(q) (N·m)."""
        return self._arm.inverse_dynamics(q, qd, self._zeros) - self.gravity(q)

    def potential(self, q: FloatArray) -> float:
        """U(q) = Σ_links m_i g z_i(q) (J), z_i the height of link i's centre of mass."""
        coms = self._arm.link_coms(q)  # (L, 3)
        return float(self.gravity_mps2 * (self.link_masses_kg @ coms[:, 2]))

    def com_jacobian(self, link_name: str, q: FloatArray) -> FloatArray:
        """Translational Jacobian (m/rad) of a link's centre of mass at q, shape (3, n)."""
        return self._arm.com_jacobian(link_name, q)

    def kinetic_energy(self, q: FloatArray, qd: FloatArray) -> float:
        """½ q̇ᵀ M(q) q̇ (J)."""
        return 0.5 * float(qd @ self._arm.mass_matrix(q) @ qd)

    def close(self) -> None:
        """Disconnect the model's private client (idempotent)."""
        self._sim.close()
