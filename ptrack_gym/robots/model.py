"""Dynamics models: the :class:`RobotModel` protocol and two implementations.

A model answers questions about ``M(q) q̈ + C(q, q̇) q̇ + g(q) = τ`` at any state it is
given; it holds no state of the simulated arm, so perturbing the simulated body (payload,
``changeDynamics``) never changes it: controllers keep the nominal model on purpose.

* :class:`PinocchioModel` — the nominal model every env and controller uses: Pinocchio's
  CRBA, RNEA and generalized gravity on the robot's URDF, its ``Data`` reused across calls.
  The mass matrix and the potential at the last q are cached (keyed on the bytes of q), so
  the env, the controller and the metrics evaluating them at the same measured state share
  one evaluation; a cache keyed on q stays correct under sensing noise (another q, another
  entry).
* :class:`BulletModel` — the same quantities from PyBullet, on a private, query-only copy
  of the arm in its own client: the tests' independent cross-check (≤ 1e-12 relative).
  (PyBullet's dynamics queries on a body go stale after ``changeDynamics``, bullet3 issue
  4809 — another reason never to query the plant.)
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from ptrack_gym.kernels.linalg import quadratic_forms_upper, symmetrize_upper
from ptrack_gym.robots.profile import FloatArray, RobotProfile


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


class PinocchioModel:
    """:class:`RobotModel` by Pinocchio (the field's rigid-body dynamics library).

    Args:
        profile: the robot; its URDF is parsed by ``pinocchio.buildModelFromUrdf`` (fixed
            base; fixed joints merge their links' inertias into the parent body).
        gravity_mps2: gravity magnitude (m/s²), along −z.

    Raises:
        ValueError: the URDF's joints are not exactly the profile's controlled joints.
    """

    def __init__(self, profile: RobotProfile, gravity_mps2: float = 9.81) -> None:
        import pinocchio as pin

        self._pin = pin
        self.profile = profile
        self.gravity_mps2 = float(gravity_mps2)
        self._model = pin.buildModelFromUrdf(profile.urdf_path)
        self._model.gravity.linear = np.array([0.0, 0.0, -self.gravity_mps2])
        names = tuple(self._model.names[i] for i in range(1, self._model.njoints))
        if names != profile.joint_names or self._model.nq != profile.n:
            raise ValueError(
                f"{profile.name}: Pinocchio's joints {names} are not the controlled joints "
                f"{profile.joint_names}"
            )
        self._data = self._model.createData()
        self.n = profile.n
        self.cache_key = ("pinocchio", profile.urdf_path, self.gravity_mps2)
        """Equal keys, equal models (for caches of model-derived tables)."""
        self._zeros = np.zeros(self.n)
        self._mass_key: bytes | None = None
        self._mass: FloatArray = np.zeros((self.n, self.n))
        self._potential_key: bytes | None = None
        self._potential = 0.0

    def mass_matrix(self, q: FloatArray) -> FloatArray:
        """M(q) (kg·m²), shape (n, n), by the composite-rigid-body algorithm (CRBA).

        Returns a read-only array shared with later calls at the same q (cached).
        """
        q = np.ascontiguousarray(q, dtype=np.float64)
        key = q.tobytes()
        if key != self._mass_key:
            upper = self._pin.crba(self._model, self._data, q)  # upper triangle filled
            mass = np.empty((self.n, self.n))
            symmetrize_upper(upper, mass)
            mass.setflags(write=False)
            self._mass, self._mass_key = mass, key
        return self._mass

    def potential(self, q: FloatArray) -> float:
        """U(q) = Σ_bodies m_i g z_i(q) (J), z the height of a body's centre of mass (cached)."""
        q = np.ascontiguousarray(q, dtype=np.float64)
        key = q.tobytes()
        if key != self._potential_key:
            self._potential = float(self._pin.computePotentialEnergy(self._model, self._data, q))
            self._potential_key = key
        return self._potential

    def gravity(self, q: FloatArray) -> FloatArray:
        """g(q) = ∂U/∂q (N·m)."""
        q = np.ascontiguousarray(q, dtype=np.float64)
        return self._pin.computeGeneralizedGravity(self._model, self._data, q).copy()

    def inverse_dynamics(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        """τ = M(q) q̈ + C(q, q̇) q̇ + g(q) (N·m), by recursive Newton–Euler (RNEA)."""
        return self._pin.rnea(
            self._model,
            self._data,
            np.ascontiguousarray(q, dtype=np.float64),
            np.ascontiguousarray(qd, dtype=np.float64),
            np.ascontiguousarray(qdd, dtype=np.float64),
        ).copy()

    def coriolis(self, q: FloatArray, qd: FloatArray) -> FloatArray:
        """C(q, q̇) q̇ = RNEA(q, q̇, 0) − g(q) (N·m)."""
        return self.inverse_dynamics(q, qd, self._zeros) - self.gravity(q)

    def coriolis_matrix(self, q: FloatArray, qd: FloatArray) -> FloatArray:
        """The Christoffel Coriolis matrix C(q, q̇) (N·m·s/rad), shape (n, n), for which
        Ṁ − 2C is skew-symmetric."""
        return self._pin.computeCoriolisMatrix(
            self._model,
            self._data,
            np.ascontiguousarray(q, dtype=np.float64),
            np.ascontiguousarray(qd, dtype=np.float64),
        ).copy()

    def kinetic_energy(self, q: FloatArray, qd: FloatArray) -> float:
        """½ q̇ᵀ M(q) q̇ (J)."""
        qd = np.ascontiguousarray(qd, dtype=np.float64)
        return 0.5 * float(qd @ self.mass_matrix(q) @ qd)

    def metric_norms2(self, q: FloatArray, v: FloatArray) -> FloatArray:
        """v_kᵀ M(q_k) v_k for every row k of q, v (T, n) (kg·m²·(rad/s)² = J·2 for v = q̇):
        one CRBA per row, bypassing the one-entry cache (for whole trajectories)."""
        q = np.ascontiguousarray(q, dtype=np.float64)
        v = np.ascontiguousarray(v, dtype=np.float64)
        if q.shape != v.shape or q.ndim != 2 or q.shape[1] != self.n:
            raise ValueError(
                f"q and v must have the same shape (T, {self.n}), got {q.shape} and {v.shape}"
            )
        pin, model, data = self._pin, self._model, self._data
        uppers = np.empty((q.shape[0], self.n, self.n))
        for k, qk in enumerate(q):
            uppers[k] = pin.crba(model, data, qk)  # upper triangle filled (the rest unread)
        return quadratic_forms_upper(uppers, v)

    def gravity_many(self, q: FloatArray) -> FloatArray:
        """g(q_k) (N·m) for every row k of q (T, n): :meth:`gravity` of each row, in one
        loop (for whole trajectories)."""
        q = np.ascontiguousarray(q, dtype=np.float64)
        pin, model, data = self._pin, self._model, self._data
        out = np.empty_like(q)
        for k, qk in enumerate(q):
            out[k] = pin.computeGeneralizedGravity(model, data, qk)
        return out

    def joint_torque_regressor(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        """Y(q, q̇, q̈), shape (n, 10·nb), with τ = M q̈ + C(q, q̇) q̇ + g = Y θ for θ =
        :meth:`dynamic_parameters`: linear in θ (Pinocchio's joint-torque regressor; nb the
        bodies the joints move). Units: N·m per unit of each parameter."""
        return self._pin.computeJointTorqueRegressor(
            self._model,
            self._data,
            np.ascontiguousarray(q, dtype=np.float64),
            np.ascontiguousarray(qd, dtype=np.float64),
            np.ascontiguousarray(qdd, dtype=np.float64),
        ).copy()

    def dynamic_parameters(self) -> FloatArray:
        """θ, shape (10·nb,): per moved body, in joint order, its ten standard parameters
        (m, m c_x, m c_y, m c_z, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz) at the joint frame
        (kg, kg·m, kg·m²), fixed links merged (``Inertia.toDynamicParameters``)."""
        inertias = self._model.inertias
        return np.concatenate(
            [inertias[i].toDynamicParameters() for i in range(1, self._model.njoints)]
        )

    def close(self) -> None:
        """Nothing to release (for symmetry with :class:`BulletModel`)."""


class BulletModel:
    """:class:`RobotModel` computed by PyBullet on a private, query-only copy of the arm.

    Args:
        profile: the robot; its URDF is loaded into a new ``p.DIRECT`` client.
        gravity_mps2: gravity magnitude (m/s²) used by ``gravity``/``potential``.
    """

    def __init__(self, profile: RobotProfile, gravity_mps2: float = 9.81) -> None:
        from ptrack_gym.sim import BulletSim  # PyBullet only when this model is used

        self.profile = profile
        self.gravity_mps2 = float(gravity_mps2)
        self._sim = BulletSim(gravity_mps2=gravity_mps2)
        self._arm = self._sim.load_arm(
            profile.urdf_path, profile.joint_names, profile.torque_limits_nm
        )
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

    def kinetic_energy(self, q: FloatArray, qd: FloatArray) -> float:
        """½ q̇ᵀ M(q) q̇ (J)."""
        qd = np.ascontiguousarray(qd, dtype=np.float64)
        return 0.5 * float(qd @ self._arm.mass_matrix(q) @ qd)

    def close(self) -> None:
        """Disconnect the model's private client (idempotent)."""
        self._sim.close()


def home_inertia_kgm2(model: RobotModel, profile: RobotProfile) -> FloatArray:
    """diag M(q_home) (kg·m²), shape (n,): the joint inertias the default gains scale by."""
    return np.diag(model.mass_matrix(profile.home())).copy()
