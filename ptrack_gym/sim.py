"""The one owner of PyBullet: a physics client, an arm loaded in it, IK and rendering.

No other module of the package imports ``pybullet``.

:class:`BulletSim` connects a client (``p.DIRECT`` by default, ``p.GUI`` on request),
sets a fixed time step and explicit gravity, steps, renders, and disconnects
(idempotently). :class:`BulletArm` is the joint bookkeeping of one fixed-base arm in that
client: it reads and resets joint states, applies clipped joint torques and external
forces, solves position IK and answers PyBullet's kinematics and dynamics queries with
validated Python lists (PyBullet crashes on some numpy inputs and silently accepts lists
of the wrong length).

Conventions of every arm loaded here:

* ``URDF_USE_INERTIA_FROM_FILE``: the inertia tensors of the URDF are used, not ones
  PyBullet would compute from collision shapes;
* the default velocity motors that PyBullet attaches to every joint are disabled
  (``VELOCITY_CONTROL`` with zero force), so the only joint torques are ours;
* linear, angular and joint damping are set to zero, so the plant is exactly
  ``M(q) q̈ + C(q, q̇) q̇ + g(q) = τ`` (friction, when wanted, is modelled explicitly);
* self-collision is off and there is no ground plane: the arm moves in free space.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Sequence
from dataclasses import dataclass
from operator import itemgetter

import numpy as np
import pybullet as p
from numpy.typing import NDArray

from ptrack_gym.errors import InvalidConfigError, SimulationClosedError

FloatArray = NDArray[np.float64]


def _disconnect(client_id: int) -> None:
    """Disconnect a client if it is still connected (used by the finaliser)."""
    try:
        if p.isConnected(physicsClientId=client_id):
            p.disconnect(physicsClientId=client_id)
    except p.error:  # pragma: no cover - interpreter shutdown
        pass


_POSITION, _VELOCITY = itemgetter(0), itemgetter(1)


def _positions_velocities(
    states: Sequence[tuple[float, ...]], n: int
) -> tuple[FloatArray, FloatArray]:
    """(q, q̇) as two float64 arrays from ``getJointStates``'s tuples (position, velocity,
    reaction wrench, applied torque): ``np.fromiter`` over the first two entries, the
    quickest conversion measured for 2–7 joints."""
    return np.fromiter(map(_POSITION, states), np.float64, n), np.fromiter(
        map(_VELOCITY, states), np.float64, n
    )


class BulletSim:
    """One PyBullet physics client with a fixed time step.

    Args:
        timestep_s: physics time step (s); 1e-3 gives the default 1 kHz.
        gravity_mps2: magnitude of gravity (m/s²), applied along −z.
        gui: open a ``p.GUI`` window instead of a headless ``p.DIRECT`` client.

    The client is disconnected by :meth:`close`, by a context manager exit, or when the
    object is garbage-collected, whichever comes first.
    """

    def __init__(
        self, timestep_s: float = 1e-3, gravity_mps2: float = 9.81, gui: bool = False
    ) -> None:
        if not (np.isfinite(timestep_s) and timestep_s > 0.0):
            raise InvalidConfigError(f"timestep_s must be a positive number, got {timestep_s!r}")
        if not np.isfinite(gravity_mps2):
            raise InvalidConfigError(f"gravity_mps2 must be finite, got {gravity_mps2!r}")
        self.timestep_s = float(timestep_s)
        self.gravity_mps2 = float(gravity_mps2)
        self.client_id: int = p.connect(p.GUI if gui else p.DIRECT)
        if self.client_id < 0:
            raise RuntimeError("PyBullet could not connect a physics client")
        self._finalizer = weakref.finalize(self, _disconnect, self.client_id)
        p.resetSimulation(physicsClientId=self.client_id)
        p.setGravity(0.0, 0.0, -self.gravity_mps2, physicsClientId=self.client_id)
        p.setTimeStep(self.timestep_s, physicsClientId=self.client_id)
        # One internal step per stepSimulation call: the time step is exactly timestep_s.
        p.setPhysicsEngineParameter(numSubSteps=0, physicsClientId=self.client_id)

    @property
    def connected(self) -> bool:
        """Whether the client is still connected."""
        return self._finalizer.alive

    def _require_connected(self) -> int:
        if not self._finalizer.alive:
            raise SimulationClosedError("this BulletSim has been closed")
        return self.client_id

    def load_arm(
        self, urdf_path: str, joint_names: Sequence[str], torque_limits_nm: Sequence[float]
    ) -> BulletArm:
        """Load a fixed-base arm and return its handle (see the module conventions)."""
        cid = self._require_connected()
        body_id = p.loadURDF(
            urdf_path,
            basePosition=[0.0, 0.0, 0.0],
            useFixedBase=True,
            flags=p.URDF_USE_INERTIA_FROM_FILE,
            physicsClientId=cid,
        )
        return BulletArm(self, body_id, joint_names, torque_limits_nm)

    def step(self) -> None:
        """Advance the simulation by one time step (``timestep_s``)."""
        p.stepSimulation(physicsClientId=self._require_connected())

    def render_rgb(
        self,
        target_m: Sequence[float],
        distance_m: float,
        width: int = 320,
        height: int = 240,
        yaw_deg: float = 0.0,
        pitch_deg: float = -10.0,
    ) -> NDArray[np.uint8]:
        """An RGB image (height, width, 3) of the scene by PyBullet's software renderer
        (headless), from a camera looking at ``target_m`` from ``distance_m`` (m)."""
        cid = self._require_connected()
        view = p.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=list(target_m),
            distance=distance_m,
            yaw=yaw_deg,
            pitch=pitch_deg,
            roll=0.0,
            upAxisIndex=2,
            physicsClientId=cid,
        )
        proj = p.computeProjectionMatrixFOV(
            fov=60.0, aspect=width / height, nearVal=0.05, farVal=10.0, physicsClientId=cid
        )
        img = p.getCameraImage(
            width, height, view, proj, renderer=p.ER_TINY_RENDERER, physicsClientId=cid
        )
        rgba = np.reshape(np.asarray(img[2], dtype=np.uint8), (height, width, 4))
        return rgba[:, :, :3].copy()

    def close(self) -> None:
        """Disconnect the client. Safe to call more than once."""
        self._finalizer()

    def __enter__(self) -> BulletSim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class JointInfo:
    """What the URDF says about one movable joint (SI units)."""

    name: str
    index: int
    lower: float
    upper: float
    link_name: str


class BulletArm:
    """Joint bookkeeping and dynamics queries of one fixed-base arm in a :class:`BulletSim`.

    Only the joints named in ``joint_names`` are controlled. The URDF must have no other
    movable joint (lock others by making them ``fixed`` in the URDF), so that PyBullet's
    degrees of freedom are exactly the controlled joints, in order.
    """

    def __init__(
        self,
        sim: BulletSim,
        body_id: int,
        joint_names: Sequence[str],
        torque_limits_nm: Sequence[float],
    ) -> None:
        self.sim = sim
        self.body_id = body_id
        cid = sim.client_id
        by_name: dict[str, JointInfo] = {}
        movable: list[str] = []
        self.num_links = p.getNumJoints(body_id, physicsClientId=cid)
        self._link_range = list(range(self.num_links))
        for j in range(self.num_links):
            info = p.getJointInfo(body_id, j, physicsClientId=cid)
            name = info[1].decode()
            if info[2] != p.JOINT_FIXED:
                movable.append(name)
            by_name[name] = JointInfo(name, j, float(info[8]), float(info[9]), info[12].decode())
        if list(joint_names) != movable:
            raise InvalidConfigError(
                f"the URDF's movable joints {movable} must be exactly the controlled joints "
                f"{list(joint_names)}, in order"
            )
        self.joints = tuple(by_name[n] for n in joint_names)
        self.joint_indices = [j.index for j in self.joints]
        self.n = len(self.joints)
        self.torque_limits_nm = np.asarray(torque_limits_nm, dtype=np.float64)
        if self.torque_limits_nm.shape != (self.n,) or np.any(self.torque_limits_nm <= 0):
            raise InvalidConfigError("torque_limits_nm must be n positive numbers")
        self._link_index = {by_name[n].link_name: by_name[n].index for n in by_name}
        # Nominal (mass kg, local inertia diagonal kg·m²) of every link, read once at load.
        self._nominal_dynamics = {
            j: (
                float(p.getDynamicsInfo(body_id, j, physicsClientId=cid)[0]),
                tuple(p.getDynamicsInfo(body_id, j, physicsClientId=cid)[2]),
            )
            for j in range(self.num_links)
        }
        self._mass_changes: dict[int, tuple[float, float]] = {}
        self._com_points: dict[int, list[float]] = {}  # com_jacobian's point, per link
        for link in range(-1, self.num_links):
            p.changeDynamics(
                body_id,
                link,
                linearDamping=0.0,
                angularDamping=0.0,
                jointDamping=0.0,
                physicsClientId=cid,
            )
        p.setJointMotorControlArray(
            body_id,
            self.joint_indices,
            p.VELOCITY_CONTROL,
            forces=[0.0] * self.n,
            physicsClientId=cid,
        )

    # -- validation ----------------------------------------------------------------
    def as_list(self, x: FloatArray | Sequence[float], what: str) -> list[float]:
        """Return ``x`` as a list of n floats, or raise ``ValueError`` naming ``what``."""
        arr = np.asarray(x, dtype=np.float64)
        if arr.shape != (self.n,):
            raise ValueError(f"{what} must have shape ({self.n},), got {arr.shape}")
        values = arr.tolist()
        # One float sum is finite iff every entry is (barring overflow, rechecked).
        if not math.isfinite(sum(values)) and not all(map(math.isfinite, values)):
            raise ValueError(
                f"{what} has non-finite entries at {np.flatnonzero(~np.isfinite(arr))}"
            )
        return values

    @property
    def link_names(self) -> tuple[str, ...]:
        """Names of the arm's links (the fixed base excluded)."""
        return tuple(self._link_index)

    def link_index(self, link_name: str) -> int:
        """PyBullet link index of the link called ``link_name``."""
        try:
            return self._link_index[link_name]
        except KeyError:
            raise InvalidConfigError(
                f"unknown link {link_name!r}; known: {sorted(self._link_index)}"
            ) from None

    # -- state ---------------------------------------------------------------------
    def reset_state(self, q: FloatArray, qd: FloatArray) -> None:
        """Teleport the joints to positions ``q`` (rad) and velocities ``qd`` (rad/s)."""
        cid = self.sim._require_connected()
        ql, qdl = self.as_list(q, "q"), self.as_list(qd, "qd")
        p.resetJointStatesMultiDof(
            self.body_id,
            self.joint_indices,
            targetValues=[[v] for v in ql],
            targetVelocities=[[v] for v in qdl],
            physicsClientId=cid,
        )

    def state(self) -> tuple[FloatArray, FloatArray]:
        """Joint positions (rad) and velocities (rad/s), each of shape (n,)."""
        cid = self.sim._require_connected()
        states = p.getJointStates(self.body_id, self.joint_indices, physicsClientId=cid)
        return _positions_velocities(states, self.n)

    def clip_torque(self, tau_nm: FloatArray) -> FloatArray:
        """Clip joint torques (N·m) to ±``torque_limits_nm`` (PyBullet does not)."""
        return np.minimum(np.maximum(tau_nm, -self.torque_limits_nm), self.torque_limits_nm)

    def apply_torque(self, tau_nm: FloatArray) -> None:
        """Command joint torques (N·m) for the next step, clipped to the limits.

        PyBullet keeps no reliable hold of torque commands across steps, so callers
        re-send the command before every ``stepSimulation``.
        """
        cid = self.sim._require_connected()
        forces = self.as_list(self.clip_torque(np.asarray(tau_nm, dtype=np.float64)), "tau")
        p.setJointMotorControlArray(
            self.body_id, self.joint_indices, p.TORQUE_CONTROL, forces=forces, physicsClientId=cid
        )

    def apply_torque_list(self, forces_nm: list[float]) -> None:
        """Hot path of :meth:`apply_torque` for callers that already validated and clipped
        the torques: ``forces_nm`` must be a list of n finite floats within the limits."""
        p.setJointMotorControlArray(
            self.body_id,
            self.joint_indices,
            p.TORQUE_CONTROL,
            forces=forces_nm,
            physicsClientId=self.sim._require_connected(),
        )

    def run_torque(self, forces_nm: list[float], steps: int) -> tuple[FloatArray, FloatArray]:
        """Hold the torques ``forces_nm`` (a list of n finite floats within the limits, N·m)
        for ``steps`` physics steps, re-sent before each, and return the new (q, q̇): the
        hot path of an undisturbed control step."""
        cid = self.sim._require_connected()
        body, joints, mode = self.body_id, self.joint_indices, p.TORQUE_CONTROL
        for _ in range(steps):
            p.setJointMotorControlArray(body, joints, mode, forces=forces_nm, physicsClientId=cid)
            p.stepSimulation(physicsClientId=cid)
        states = p.getJointStates(body, joints, physicsClientId=cid)
        return _positions_velocities(states, self.n)

    # -- plant editing (disturbances) ----------------------------------------------
    def set_mass_changes(self, changes: dict[str, tuple[float, float]]) -> None:
        """Set every link's mass to nominal·scale + added (kg), inertia to nominal·scale.

        ``changes`` maps link names to ``(scale, added_kg)``; links not named return to
        nominal. An added mass is a point mass at the link's centre of mass, so it adds no
        inertia about it. Only links whose values change are sent to PyBullet.
        """
        cid = self.sim._require_connected()
        wanted = {self.link_index(name): (float(s), float(m)) for name, (s, m) in changes.items()}
        for j in set(wanted) | set(self._mass_changes):
            scale, added = wanted.get(j, (1.0, 0.0))
            if self._mass_changes.get(j, (1.0, 0.0)) == (scale, added):
                continue
            mass0, inertia0 = self._nominal_dynamics[j]
            p.changeDynamics(
                self.body_id,
                j,
                mass=mass0 * scale + added,
                localInertiaDiagonal=[scale * i for i in inertia0],
                physicsClientId=cid,
            )
        self._mass_changes = {j: v for j, v in wanted.items() if v != (1.0, 0.0)}

    def link_mass(self, link_name: str) -> float:
        """Current mass (kg) of a link of this body (reads the plant; not a dynamics query)."""
        cid = self.sim._require_connected()
        return float(
            p.getDynamicsInfo(self.body_id, self.link_index(link_name), physicsClientId=cid)[0]
        )

    def apply_link_force(self, link_name: str, force_n: FloatArray) -> None:
        """Apply a world-frame force (N) at a link's centre of mass for the next step only."""
        cid = self.sim._require_connected()
        j = self.link_index(link_name)
        com = p.getLinkState(self.body_id, j, computeForwardKinematics=1, physicsClientId=cid)[0]
        p.applyExternalForce(
            self.body_id, j, list(map(float, force_n)), com, p.WORLD_FRAME, physicsClientId=cid
        )

    def com_jacobian(self, link_name: str, q: FloatArray) -> FloatArray:
        """Translational Jacobian (m/rad) of a link's centre of mass at pose q, (3, n).

        PyBullet's ``calculateJacobian`` takes its point relative to the link frame's origin
        in the axes of the link's inertial frame (its docs say "around its centre of mass";
        at point 0 it gives the frame origin's Jacobian, up to 0.23 m/rad off the centre of
        mass's on these arms). The point passed is therefore the centre of mass in those
        axes, R_iᵀ p_i (p_i, R_i: the inertial frame's position and rotation in the link
        frame, from the URDF), checked against finite differences of the centre of mass on
        every robot (tests/test_sim.py)."""
        cid = self.sim._require_connected()
        j = self.link_index(link_name)
        point = self._com_points.get(j)
        if point is None:
            info = p.getDynamicsInfo(self.body_id, j, physicsClientId=cid)
            rot = np.array(p.getMatrixFromQuaternion(info[4])).reshape(3, 3)
            point = self._com_points[j] = (rot.T @ np.asarray(info[3], dtype=np.float64)).tolist()
        zeros = [0.0] * self.n
        jac = p.calculateJacobian(
            self.body_id, j, point, self.as_list(q, "q"), zeros, zeros, physicsClientId=cid
        )[0]
        return np.array(jac)

    # -- dynamics queries (state-free: they take q, qd explicitly) ----------------
    def mass_matrix(self, q: FloatArray) -> FloatArray:
        """Joint-space inertia matrix M(q) (kg·m²), shape (n, n)."""
        cid = self.sim._require_connected()
        return np.array(
            p.calculateMassMatrix(self.body_id, self.as_list(q, "q"), physicsClientId=cid)
        )

    def inverse_dynamics(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        """τ = M(q) q̈ + C(q, q̇) q̇ + g(q) (N·m), by PyBullet's recursive Newton–Euler."""
        cid = self.sim._require_connected()
        return np.array(
            p.calculateInverseDynamics(
                self.body_id,
                self.as_list(q, "q"),
                self.as_list(qd, "qd"),
                self.as_list(qdd, "qdd"),
                physicsClientId=cid,
            )
        )

    def link_masses(self) -> FloatArray:
        """Masses (kg) of the links 0..num_links-1 (the fixed base excluded)."""
        cid = self.sim._require_connected()
        return np.array(
            [
                p.getDynamicsInfo(self.body_id, j, physicsClientId=cid)[0]
                for j in range(self.num_links)
            ]
        )

    def link_coms(self, q: FloatArray) -> FloatArray:
        """World centre-of-mass positions (m) of links 0..num_links-1 at pose ``q``, (L, 3).

        Moves the arm's joints to ``q`` (zero velocity): use only on a query-only body.
        """
        cid = self.sim._require_connected()
        self.reset_state(q, np.zeros(self.n))
        states = p.getLinkStates(
            self.body_id,
            list(range(self.num_links)),
            computeForwardKinematics=1,
            physicsClientId=cid,
        )
        return np.array([s[0] for s in states])

    def com_heights(self) -> list[float]:
        """Heights z (m) of the centres of mass of links 0..num_links-1 at the arm's
        current joint state (forward kinematics recomputed: PyBullet's cached link poses
        lag one step behind ``stepSimulation``)."""
        states = p.getLinkStates(
            self.body_id,
            self._link_range,
            computeForwardKinematics=1,
            physicsClientId=self.sim._require_connected(),
        )
        return [s[0][2] for s in states]

    def position_ik(
        self,
        link_name: str,
        target_m: FloatArray,
        q0: FloatArray,
        rest_q: FloatArray,
        iterations: int = 100,
        damping: float = 1e-6,
        null_gain: float = 0.1,
    ) -> tuple[FloatArray, float]:
        """Position IK of a link's centre of mass by damped least squares with a
        null-space pull towards ``rest_q``; moves this arm (use a query-only body).

        Iterates q ← q + J⁺ e + (I − J⁺J) k (q_rest − q), J⁺ = Jᵀ(JJᵀ + λ²I)⁻¹, with J the
        translational Jacobian of the link's centre of mass and e the position error (m),
        from ``q0``. Returns the solution (rad) and its final position error (m).
        """
        cid, idx, n = self.sim._require_connected(), self.link_index(link_name), self.n
        q = np.array(q0, dtype=np.float64)
        err = np.inf
        for _ in range(iterations):
            self.reset_state(q, np.zeros(n))
            pos = np.array(
                p.getLinkState(self.body_id, idx, computeForwardKinematics=1, physicsClientId=cid)[
                    0
                ]
            )
            e = np.asarray(target_m, dtype=np.float64) - pos
            err = float(np.linalg.norm(e))
            jac = self.com_jacobian(link_name, q)  # (3, n)
            jjt = jac @ jac.T + damping * np.eye(3)
            pinv = jac.T @ np.linalg.solve(jjt, np.eye(3))  # (n, 3)
            null = (np.eye(n) - pinv @ jac) @ (null_gain * (rest_q - q))
            if err < 1e-12:
                break
            q = q + pinv @ e + null
        return q, err

    def link_pose(self, link_name: str) -> tuple[FloatArray, FloatArray]:
        """World position (m) and quaternion (x, y, z, w) of a link frame, current state."""
        cid = self.sim._require_connected()
        st = p.getLinkState(
            self.body_id,
            self.link_index(link_name),
            computeForwardKinematics=1,
            physicsClientId=cid,
        )
        return np.array(st[4]), np.array(st[5])
