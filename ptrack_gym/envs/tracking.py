"""The trajectory-tracking environment: a torque-controlled arm follows a periodic path.

This module is glue: it composes a :class:`~ptrack_gym.robots.spec.RobotSpec`, a
:class:`~ptrack_gym.sim.BulletSim` that owns the plant, a nominal
:class:`~ptrack_gym.robots.model.BulletModel` and a reference path with its
:class:`~ptrack_gym.paths.PathTables`.
"""

from __future__ import annotations

import math
import numbers
import operator
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
import pybullet as p
from gymnasium import spaces

from ptrack_gym.disturbances import (
    DisturbanceContext,
    DisturbanceSet,
    DisturbanceSpec,
    build_disturbances,
)
from ptrack_gym.errors import InvalidActionError, InvalidConfigError
from ptrack_gym.paths import (
    PathTables,
    ReferencePath,
    check_joint_limits,
    default_path,
    ee_circle_path,
    random_multisine,
)
from ptrack_gym.robots import BulletModel, make_robot
from ptrack_gym.robots.spec import FloatArray, RobotSpec
from ptrack_gym.sim import BulletSim

#: Default end-effector circles (centre m, radius m, normal) for ``path="circle"``.
_CIRCLES: dict[str, tuple[tuple[float, float, float], float, tuple[float, float, float]]] = {
    "two_link": ((0.5, 0.0, -0.3), 0.15, (0.0, 1.0, 0.0)),
    "iiwa": ((0.5, 0.0, 0.6), 0.1, (1.0, 0.0, 0.0)),
    "panda": ((0.45, 0.0, 0.4), 0.1, (1.0, 0.0, 0.0)),
}

_START_MODES = ("on_path", "rest_near_path")


class TrackingEnv(gym.Env[np.ndarray, np.ndarray]):
    """A torque-controlled arm must follow a periodic reference path.

    ## Description
    The arm (two-link planar, KUKA iiwa or Franka Panda) is simulated by PyBullet at
    ``physics_hz``; the agent commands joint torques at ``control_hz`` (an integer
    divisor of ``physics_hz``), held constant over the physics sub-steps. The reference
    is a periodic joint path q_r(s) with s in seconds; at episode time t the
    time-indexed reference is q_r(s₀ + t), s₀ the episode's start phase.

    ## Action space
    ``Box(-1, 1, (n,), float32)``: joint torque normalized by the robot's torque limits,
    τ_j = clip(a_j, −1, 1) · τ_max,j (N·m). An out-of-range action acts exactly as the
    clipped one. A wrong shape or a NaN/inf entry raises ``ValueError`` and leaves the
    state untouched.

    ## Observation space
    ``Box(float32)`` of size 6n + 2, clipped to its bounds:

    | index        | quantity                              | unit  | bound       |
    |--------------|---------------------------------------|-------|-------------|
    | 0 : n        | joint positions q                     | rad   | ±4π         |
    | n : 2n       | joint velocities q̇                    | rad/s | ±v_max      |
    | 2n : 3n      | reference q_r(s₀ + t)                 | rad   | ±4π         |
    | 3n : 4n      | reference velocity q_r'(s₀ + t)        | rad/s | ±v_max      |
    | 4n : 5n      | time-indexed error q_r − q            | rad   | ±8π         |
    | 5n : 6n      | velocity error q_r' − q̇               | rad/s | ±2 v_max    |
    | 6n : 6n + 2  | phase (sin, cos) of 2π(s₀ + t)/S      | —     | ±1          |

    v_max = ``spec.max_joint_speed_rad_s`` (50 rad/s).

    ## Reward
    r = −(w_path · d² + w_time · |q_r − q|² + w_effort · |a|²/n), with d the path
    distance min_s |q − q_r(s)| (rad). Defaults w = (10, 1, 0.01). The three terms are
    ``info["reward_path"]``, ``info["reward_time"]`` and ``info["reward_effort"]``.

    ## Starting state
    s₀ is uniform in [0, S) (seeded by ``reset``). ``start="on_path"``: q = q_r(s₀),
    q̇ = q_r'(s₀), plus Gaussian noise of std ``start_noise_rad`` on q.
    ``start="rest_near_path"``: q = q_r(s₀) + u, u uniform in ±``start_offset_rad``,
    q̇ = 0. ``reset(options={"s0": …, "q": …, "qd": …})`` overrides any of them.

    ## Episode end
    ``terminated=True`` when the simulation is unstable: a non-finite state, or a joint
    speed above v_max (below PyBullet's internal 100 rad/s clamp). Then
    ``info["unstable"]`` is True, the observation is finite (clipped) and the reward is
    ``-unstable_penalty``. Time limits come from ``TimeLimit`` (``max_episode_steps``
    at registration); the env itself never truncates.

    ## Info
    ``t_s`` (s), ``s_ref`` (s), ``path_distance`` (rad), ``path_s`` (s, the nearest
    path parameter), ``tracking_error`` (rad, |q_r(s₀+t) − q|), ``energy_j`` (H(q, q̇)
    by the nominal model, J), ``tau_nm`` (commanded torque after clipping), the reward
    terms, ``disturbance_torque_nm`` (joint-space disturbance torque of the last physics
    sub-step, pushes as JᵀF), ``disturbance_work_j`` (∫ q̇ᵀτ_d since reset, J), ``unstable``.
    Path distance, errors and energy use the true state; the observation holds the
    *measured* state (sensing disturbances), as does ``measured_joint_state()``.

    ## Arguments
    ``robot`` ("two_link", "iiwa", "panda"); ``path`` ("default", "circle", "random",
    or a :class:`~ptrack_gym.paths.ReferencePath`); ``path_seed`` (for "random");
    ``physics_hz`` (1000), ``control_hz`` (1000); ``start``, ``start_noise_rad``,
    ``start_offset_rad``; ``reward_weights``; ``unstable_penalty``; ``disturbance`` (see
    :mod:`ptrack_gym.disturbances`: a preset name, ``(preset, level)``, specs or a list);
    ``horizon_s`` (the nominal episode length the disturbances draw onsets and energy
    budgets for, 10 s); ``render_mode`` ("rgb_array" works headless); ``gui``. Unknown
    arguments raise ``TypeError``.

    ## Version history
    v0: first release.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(
        self,
        robot: str = "two_link",
        path: str | ReferencePath = "default",
        path_seed: int | None = None,
        physics_hz: float = 1000.0,
        control_hz: float = 1000.0,
        start: str = "on_path",
        start_noise_rad: float = 0.0,
        start_offset_rad: float = 0.1,
        reward_weights: tuple[float, float, float] = (10.0, 1.0, 0.01),
        unstable_penalty: float = 100.0,
        disturbance: DisturbanceSpec | list[DisturbanceSpec] | None = None,
        horizon_s: float = 10.0,
        render_mode: str | None = None,
        gui: bool = False,
    ) -> None:
        self._init_kwargs = {
            "robot": robot,
            "path": path,
            "path_seed": path_seed,
            "physics_hz": physics_hz,
            "control_hz": control_hz,
            "start": start,
            "start_noise_rad": start_noise_rad,
            "start_offset_rad": start_offset_rad,
            "reward_weights": reward_weights,
            "unstable_penalty": unstable_penalty,
            "disturbance": disturbance,
            "horizon_s": horizon_s,
            "render_mode": render_mode,
            "gui": gui,
        }
        rates_ok = all(
            isinstance(r, numbers.Real) and math.isfinite(r) and r > 0
            for r in (physics_hz, control_hz)
        )
        substeps = physics_hz / control_hz if rates_ok else math.nan
        if not (
            math.isfinite(substeps) and 1.0 <= substeps and abs(substeps - round(substeps)) < 1e-9
        ):
            raise InvalidConfigError(
                f"physics_hz ({physics_hz}) must be a positive integer multiple of "
                f"control_hz ({control_hz})"
            )
        if start not in _START_MODES:
            raise InvalidConfigError(f"start must be one of {_START_MODES}, got {start!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise InvalidConfigError(
                f"render_mode must be None or 'rgb_array', got {render_mode!r}"
            )
        if len(reward_weights) != 3 or min(reward_weights) < 0:
            raise InvalidConfigError("reward_weights must be three non-negative numbers")
        self.robot_spec: RobotSpec = make_robot(robot)
        self.render_mode = render_mode
        self.substeps = round(substeps)
        self.physics_dt = 1.0 / physics_hz
        self.dt = self.substeps * self.physics_dt
        self.reward_weights = tuple(float(w) for w in reward_weights)
        self.unstable_penalty = float(unstable_penalty)
        self.start_mode = start
        self.start_noise_rad = float(start_noise_rad)
        self.start_offset_rad = float(start_offset_rad)
        if not (math.isfinite(horizon_s) and horizon_s > 0):
            raise InvalidConfigError(f"horizon_s must be positive, got {horizon_s!r}")
        self.disturbances = DisturbanceSet(build_disturbances(disturbance, robot))

        spec = self.robot_spec
        self.model = BulletModel(spec)
        try:
            self.path = self._build_path(path, path_seed)
            check_joint_limits(self.path, *spec.limits())
            self.tables = PathTables(self.path, self.model)
            self.sim = BulletSim(timestep_s=self.physics_dt, gui=gui)
            self.arm = self.sim.load_arm(spec.urdf_path, spec.joint_names, spec.torque_limits_nm)
        except BaseException:
            self.close()  # no PyBullet client outlives a failed construction
            raise
        self.n = spec.n
        self.torque_limits_nm = np.array(spec.torque_limits_nm)
        self.max_speed = spec.max_joint_speed_rad_s

        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.n,), dtype=np.float32)
        ang, vel = np.full(self.n, 4 * np.pi), np.full(self.n, self.max_speed)
        high = np.concatenate([ang, vel, ang, vel, 2 * ang, 2 * vel, [1.0, 1.0]])
        self._obs_high = high.astype(np.float32)
        self._obs_high64 = self._obs_high.astype(np.float64)
        self._obs_low64 = -self._obs_high64
        self._obs_buf = np.zeros(6 * self.n + 2)
        self._link_weights_n = (self.model.gravity_mps2 * self.model.link_masses_kg).tolist()
        self.observation_space = spaces.Box(-self._obs_high, self._obs_high, dtype=np.float32)

        self._steps = 0  # control steps this episode; time is steps · dt (no drift)
        self._s0 = 0.0
        self._q = np.array(spec.home_q_rad)
        self._qd = np.zeros(self.n)
        self._q_meas, self._qd_meas = self._q, self._qd
        self._dist_tau = np.zeros(self.n)
        self._dist_work = 0.0
        home = np.array(spec.home_q_rad)
        grid_speed = np.linalg.norm(self.path.evaluate(self.tables.grid_s)[1], axis=1)
        self.disturbance_context = DisturbanceContext(
            n=self.n,
            torque_limits_nm=self.torque_limits_nm.copy(),
            physics_dt_s=self.physics_dt,
            control_dt_s=self.dt,
            horizon_s=float(horizon_s),
            ee_link=spec.ee_link,
            home_mass_matrix=self.model.mass_matrix(home),
            ee_jacobian_home=self.model.com_jacobian(spec.ee_link, home),
            mean_path_speed_rad_s=float(np.mean(grid_speed)),
        )
        self._substep_accounting = self.disturbances.needs_substep_state
        self._was_reset = False  # disturbances have no episode schedule before reset

    # -- construction helpers ------------------------------------------------------
    def _build_path(self, path: str | ReferencePath, path_seed: int | None) -> ReferencePath:
        spec = self.robot_spec
        if isinstance(path, ReferencePath):
            if path.n != spec.n:
                raise InvalidConfigError(
                    f"path has {path.n} joints, robot {spec.name} has {spec.n}"
                )
            return path
        if path == "default":
            return default_path(spec)
        if path == "random":
            return random_multisine(spec, np.random.default_rng(path_seed))
        if path == "circle":
            center, radius, normal = _CIRCLES[spec.name]
            return ee_circle_path(spec, np.array(center), radius, np.array(normal))
        raise InvalidConfigError(
            f"path must be 'default', 'circle', 'random' or a ReferencePath, got {path!r}"
        )

    # -- Gymnasium API -------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - {"s0", "q", "qd"}
        if unknown:
            raise InvalidConfigError(f"unknown reset options {sorted(unknown)}; known: s0, q, qd")
        # Two child streams, always two draws: the start state and the disturbances'
        # schedule never depend on each other, nor on the actions.
        rng, dist_rng = self.np_random.spawn(2)
        s0 = float(options.get("s0", rng.uniform(0.0, self.path.period_s)))
        q_ref, qd_ref, _ = self.path.evaluate(s0)
        if self.start_mode == "on_path":
            q = q_ref + self.start_noise_rad * rng.standard_normal(self.n)
            qd = qd_ref.copy()
        else:
            q = q_ref + rng.uniform(-self.start_offset_rad, self.start_offset_rad, size=self.n)
            qd = np.zeros(self.n)
        q = np.asarray(options.get("q", q), dtype=np.float64)
        qd = np.asarray(options.get("qd", qd), dtype=np.float64)
        self.arm.reset_state(q, qd)  # validates shapes and finiteness
        self._s0, self._steps = s0, 0
        self._q, self._qd = self.arm.state()
        self.disturbances.reset(dist_rng, self.disturbance_context)
        self._apply_plant_changes()
        self._dist_tau = np.zeros(self.n)
        self._dist_work = 0.0
        self._was_reset = True
        self._q_meas, self._qd_meas = self.disturbances.sense(self._q, self._qd)
        obs, info = self._observe(np.zeros(self.n), np.zeros(self.n), unstable=False)
        return obs, info

    def _apply_plant_changes(self) -> None:
        changes = self.disturbances.plant(self.t)
        self.arm.set_mass_changes({k: (v.scale, v.added_kg) for k, v in changes.items()})

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        a = self._validate_action(action)
        tau = a * self.torque_limits_nm  # within limits: a is validated and clipped
        if self.disturbances.items:
            q, qd = self._disturbed_substeps(tau)
        else:
            forces = tau.tolist()
            for _ in range(self.substeps):
                self.arm.apply_torque_list(forces)
                self.sim.step()
            q, qd = self.arm.state()
        self._steps += 1
        # max|q̇| is NaN when any q̇ is, and then fails the comparison; a non-finite (or
        # overflowing) q makes its sum non-finite.
        speed = float(np.max(np.abs(qd)))
        unstable = not (speed <= self.max_speed and math.isfinite(float(q.sum())))
        if unstable:
            q = np.nan_to_num(q, nan=0.0, posinf=0.0, neginf=0.0)
            qd = np.clip(np.nan_to_num(qd, nan=0.0), -self.max_speed, self.max_speed)
        self._q, self._qd = q, qd
        self._q_meas, self._qd_meas = self.disturbances.sense(q, qd)
        obs, info = self._observe(a, tau, unstable)
        if unstable:
            reward = -self.unstable_penalty
        else:
            reward = info["reward_path"] + info["reward_time"] + info["reward_effort"]
        return obs, float(reward), unstable, False, info

    def _disturbed_substeps(self, tau_cmd: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Physics sub-steps with disturbances; returns the new true (q, q̇).

        Per sub-step k starting at t_k: τ_d = (actuated − commanded torque) + Σ joint
        torques + Σ Jᵀ(q_k) F for pushes; the plant gets τ_cmd + that; the ledger adds
        τ_dᵀ (q_{k+1} − q_k), the exact work of a torque held over a semi-implicit Euler step.
        """
        self._apply_plant_changes()
        dist = self.disturbances
        tau_act = dist.actuate(tau_cmd)
        actuation_error = tau_act - tau_cmd
        q, qd = self._q, self._qd
        for k in range(self.substeps):
            t_k = (self._steps * self.substeps + k) * self.physics_dt
            tau_d = actuation_error.copy()
            joint = dist.joint_torque(t_k, q, qd)
            if joint is not None:
                tau_d = tau_d + joint
            self.arm.apply_torque_list((tau_cmd + tau_d).tolist())
            for link, force in dist.wrenches(t_k):
                self.arm.apply_link_force(link, force)
                tau_d = tau_d + self.model.com_jacobian(link, q).T @ force
            self.sim.step()
            q_next, qd = self.arm.state()
            if np.all(np.isfinite(q_next)):
                self._dist_work += float(tau_d @ (q_next - q))
            q = q_next
            self._dist_tau = tau_d
        return q, qd

    def _validate_action(self, action: np.ndarray) -> FloatArray:
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (self.n,):
            raise InvalidActionError(f"action must have shape ({self.n},), got {a.shape}")
        if not math.isfinite(float(a.sum())):  # one cheap test; the details only on failure
            bad = ~np.isfinite(a)
            if np.any(bad):
                raise InvalidActionError(
                    f"action has non-finite entries at indices {np.flatnonzero(bad).tolist()}: "
                    f"{a[bad].tolist()}"
                )
        return np.minimum(np.maximum(a, -1.0), 1.0)

    def _observe(
        self, a: FloatArray, tau: FloatArray, unstable: bool
    ) -> tuple[np.ndarray, dict[str, Any]]:
        q, qd = self._q, self._qd
        qm, qdm = self._q_meas, self._qd_meas  # what the sensors report
        s_ref = self._s0 + self.t
        q_ref, qd_ref, _ = self.path.evaluate(s_ref)
        e = q_ref - q
        omega = 2.0 * np.pi * s_ref / self.path.period_s
        n, buf = self.n, self._obs_buf
        buf[:n], buf[n : 2 * n], buf[2 * n : 3 * n], buf[3 * n : 4 * n] = qm, qdm, q_ref, qd_ref
        np.subtract(q_ref, qm, out=buf[4 * n : 5 * n])
        np.subtract(qd_ref, qdm, out=buf[5 * n : 6 * n])
        buf[6 * n], buf[6 * n + 1] = math.sin(omega), math.cos(omega)
        # np.minimum/maximum: same result as np.clip, a few µs cheaper on small arrays.
        obs = np.minimum(np.maximum(buf, self._obs_low64), self._obs_high64).astype(np.float32)
        near = self.tables.nearest(q)
        w_path, w_time, w_effort = self.reward_weights
        e2 = float(e @ e)
        # H = ½ q̇ᵀM(q)q̇ + U(q) by the nominal model. U = Σ m_i g z_i uses the nominal
        # masses and the simulated arm's link heights at q (same URDF kinematics, so the
        # model's U(q) exactly, without moving the model's body; tested); after a blow-up
        # the simulator's state is not q, and the model computes U itself.
        if unstable:
            potential = self.model.potential(q)
        else:
            heights = self.arm.com_heights()
            potential = math.fsum(map(operator.mul, self._link_weights_n, heights))
        info = {
            "t_s": self.t,
            "s_ref": s_ref,
            "path_distance": near.distance,
            "path_s": near.s,
            "tracking_error": math.sqrt(e2),
            "energy_j": self.model.kinetic_energy(q, qd) + potential,
            "tau_nm": tau,
            "reward_path": -w_path * near.distance**2,
            "reward_time": -w_time * e2,
            "reward_effort": -w_effort * float(a @ a) / self.n,
            "disturbance_torque_nm": self._dist_tau.copy(),
            "disturbance_work_j": self._dist_work,
            "unstable": unstable,
        }
        return obs, info

    # -- state access for controllers and tests --------------------------------------
    @property
    def t(self) -> float:
        """Episode time (s): control steps taken times dt."""
        return self._steps * self.dt

    @property
    def s0(self) -> float:
        """The episode's start phase s₀ (s)."""
        return self._s0

    def joint_state(self) -> tuple[FloatArray, FloatArray]:
        """Current true (q, q̇) of the plant (rad, rad/s), copies."""
        return self._q.copy(), self._qd.copy()

    def measured_joint_state(self) -> tuple[FloatArray, FloatArray]:
        """Current (q, q̇) as the sensors report it (noise, delay), float64 copies: what
        the observation holds and what controllers should use."""
        return np.array(self._q_meas, dtype=np.float64), np.array(self._qd_meas, dtype=np.float64)

    def disturbance_schedule(self) -> list[dict[str, Any]]:
        """This episode's drawn disturbance parameters, one dict per disturbance."""
        if not self._was_reset:
            raise RuntimeError("no disturbance schedule before the first reset()")
        return self.disturbances.schedules()

    # -- rendering and lifetime ------------------------------------------------------
    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        cid = self.sim._require_connected()
        spec = self.robot_spec
        width, height = 320, 240
        view = p.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=list(spec.camera_target_m),
            distance=spec.camera_distance_m,
            yaw=0.0,
            pitch=-10.0,
            roll=0.0,
            upAxisIndex=2,
            physicsClientId=cid,
        )
        proj = p.computeProjectionMatrixFOV(
            fov=60.0,
            aspect=width / height,
            nearVal=0.05,
            farVal=10.0,
            physicsClientId=cid,
        )
        img = p.getCameraImage(
            width,
            height,
            view,
            proj,
            renderer=p.ER_TINY_RENDERER,
            physicsClientId=cid,
        )
        rgba = np.reshape(np.asarray(img[2], dtype=np.uint8), (height, width, 4))
        return rgba[:, :, :3].copy()

    def close(self) -> None:
        """Disconnect the plant's and the model's PyBullet clients (idempotent)."""
        if hasattr(self, "sim"):
            self.sim.close()
        if hasattr(self, "model"):
            self.model.close()

    # -- pickling: rebuild the clients, restore the state ----------------------------
    def __getstate__(self) -> dict[str, Any]:
        return {
            "init_kwargs": self._init_kwargs,
            "np_random": self._np_random,
            "np_random_seed": self._np_random_seed,
            "env_spec": self.spec,
            "steps": self._steps,
            "s0": self._s0,
            "q": self._q.copy(),
            "qd": self._qd.copy(),
            "measured": (self._q_meas, self._qd_meas),
            "disturbances": self.disturbances,
            "ledger": (self._dist_tau.copy(), self._dist_work),
            "was_reset": self._was_reset,
        }

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(**state["init_kwargs"])  # type: ignore[misc]
        self._np_random = state["np_random"]
        self._np_random_seed = state["np_random_seed"]
        self.spec = state["env_spec"]
        self._steps, self._s0 = state["steps"], state["s0"]
        self.arm.reset_state(state["q"], state["qd"])
        self._q, self._qd = self.arm.state()
        self._q_meas, self._qd_meas = state["measured"]
        self.disturbances = state["disturbances"]
        self._dist_tau, self._dist_work = state["ledger"]
        self._was_reset = state["was_reset"]
        if self._was_reset:
            self._apply_plant_changes()
