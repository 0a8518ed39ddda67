"""The trajectory-tracking environment: a torque-controlled arm follows a periodic path.

This module is glue. It composes the robot's :class:`~ptrack_gym.robots.RobotProfile`, a
:class:`~ptrack_gym.sim.BulletSim` that owns the plant, the nominal
:class:`~ptrack_gym.robots.PinocchioModel`, the reference path and its projector, a
:class:`~ptrack_gym.disturbances.DisturbanceRunner` (physics sub-steps and work ledger)
and a :class:`~ptrack_gym.envs.task.TrackingTask` (observation, reward, info). Its
arguments are validated by :class:`~ptrack_gym.envs.config.EnvConfig`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded

from ptrack_gym.disturbances import DisturbanceContext, DisturbanceRunner, DisturbanceSpec
from ptrack_gym.envs.config import EnvConfig
from ptrack_gym.envs.rewards import (
    DEFAULT_EFFORT_SCALE,
    DEFAULT_KERNEL_SCALES_RAD,
    DEFAULT_KERNEL_WEIGHTS,
    KernelReward,
)
from ptrack_gym.envs.task import TrackingTask
from ptrack_gym.errors import InvalidActionError, InvalidConfigError, InvalidPathError
from ptrack_gym.kernels.task import clip_action
from ptrack_gym.paths import ReferencePath, check_joint_limits, make_path
from ptrack_gym.projection import PathProjector
from ptrack_gym.robots import PinocchioModel
from ptrack_gym.robots.profile import FloatArray
from ptrack_gym.sim import BulletSim


class TrackingEnv(gym.Env[np.ndarray, np.ndarray]):
    """A torque-controlled arm must follow a periodic reference path.

    ## Description
    The arm (one of ``ptrack_gym.robots.ROBOTS``: a planar two-link arm, the KUKA iiwa, the
    Franka Panda, the UFactory xArm6) is simulated by PyBullet at ``physics_hz``; the agent
    commands joint torques at ``control_hz`` (an integer divisor of ``physics_hz``), held
    constant over the physics sub-steps. The reference is a periodic joint path q_r(s)
    with s in seconds; at episode time t the time-indexed reference is q_r(s₀ + t), s₀ the
    episode's start phase.

    ## Action space
    ``Box(-1, 1, (n,), float32)``: joint torque normalized by the robot's torque limits,
    τ_j = clip(a_j, −1, 1) · τ_max,j (N·m). An out-of-range action acts exactly as the
    clipped one. A wrong shape, a NaN/inf entry or a non-real dtype (complex, string,
    bool, object) raises ``ValueError`` and leaves the state untouched.

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

    v_max = the profile's ``max_joint_speed_rad_s`` (50 rad/s).

    ## Reward
    ``reward="quadratic"`` (default): r = −(w_path · d² + w_time · |q_r − q|² + w_effort ·
    |a|²/n), with d the path distance min_s |q − q_r(s)| (rad). Defaults w = (10, 1, 0.01).
    ``reward="kernel"``: the bounded r ∈ [0, 1] of :mod:`ptrack_gym.envs.rewards` —
    multi-scale exponential kernels of d and |q_r − q| (``kernel_scales_rad``, default 0.1,
    0.01, 0.001 rad) and of the dynamic effort (τ − g(q))/τ_max (``kernel_effort_scale``),
    weighted by ``kernel_weights`` (default 0.5, 0.4, 0.1); an unstable step earns 0, so
    ending early never pays. Either way the three terms are ``info["reward_path"]``,
    ``info["reward_time"]`` and ``info["reward_effort"]``.

    ## Starting state
    s₀ is uniform in [0, S) (seeded by ``reset``). ``start="on_path"``: q = q_r(s₀),
    q̇ = q_r'(s₀), plus Gaussian noise of std ``start_noise_rad`` on q.
    ``start="rest_near_path"``: q = q_r(s₀) + u, u uniform in ±``start_offset_rad``,
    q̇ = 0. ``reset(options={"s0": …, "q": …, "qd": …})`` overrides any of them.

    ## Episode end
    ``terminated=True`` when the simulation is unstable: a non-finite state, or a joint
    speed above v_max (below PyBullet's internal 100 rad/s clamp). Then
    ``info["unstable"]`` is True, the observation is finite (clipped) and the reward is
    ``-unstable_penalty`` (0 with ``reward="kernel"``). With ``max_path_distance_rad``
    set, ``terminated=True`` also when the true path distance exceeds it
    (``info["off_path"]``, always present, says so); the step's reward is the usual one.
    Time limits come from ``TimeLimit`` (``max_episode_steps``
    at registration); the env itself never truncates. Stepping before the first
    ``reset`` raises ``gymnasium.error.ResetNeeded``.

    ## Info
    ``t_s`` (s), ``s_ref`` (s), ``path_distance`` (rad), ``path_s`` (s, the nearest
    path parameter), ``tracking_error`` (rad, |q_r(s₀+t) − q|), ``tau_nm`` (commanded
    torque after clipping), the reward terms, ``off_path`` (after a step),
    ``disturbance_torque_nm`` (joint-space disturbance torque of the last physics
    sub-step, pushes as JᵀF),
    ``disturbance_work_j`` (∫ q̇ᵀτ_d since reset, J), ``unstable``; with
    ``info_energy=True`` also ``energy_j`` (H(q, q̇) by the nominal model, J). Path
    distance, errors and energy use the true state; the observation holds the *measured*
    state (sensing disturbances), as does ``measured_joint_state()``.

    ## Arguments
    ``robot`` (a name of ``ptrack_gym.robots.ROBOTS``); ``path`` ("default", "circle",
    "random", or a :class:`~ptrack_gym.paths.ReferencePath`); ``path_seed`` (for
    "random"); ``path_seeds`` (a pool of random paths, ``path="random"``: every reset draws
    one of them from the reset seed's own stream — ``info["path_seed"]`` says which — so a
    policy trains on a distribution of paths; every path is built, and checked, when the
    env is); ``physics_hz`` (1000), ``control_hz`` (1000); ``start``,
    ``start_noise_rad``, ``start_offset_rad``; ``reward_weights``; ``unstable_penalty``;
    ``reward``, ``kernel_weights``, ``kernel_scales_rad``, ``kernel_effort_scale``;
    ``max_path_distance_rad`` (None: no off-path termination);
    ``disturbance`` (see :mod:`ptrack_gym.disturbances`: a preset name,
    ``(preset, level)``, specs or a list); ``disturbance_sizing`` ("home": joint-torque
    disturbances sized by M(q_home); "onset": by M(q) where they start to act, see
    :mod:`ptrack_gym.disturbances.torques`); ``disturbance_choices`` (instead of
    ``disturbance``: a list of such specs, one drawn per reset from the reset seed's own
    stream, ``info["disturbance_choice"]`` its index — a distribution of disturbance
    families to train on; an episode under choice k is the episode of the env built with
    ``disturbance`` = choice k); ``horizon_s`` (the nominal episode length the
    disturbances draw onsets and energy budgets for, 10 s; a disturbance whose latest
    onset + duration + 0.5 s of recovery does not fit in it is refused); ``info_energy`` (False);
    ``render_mode`` ("rgb_array" works headless); ``gui``. Unknown arguments raise
    ``TypeError``; bad values ``ValueError`` (:class:`~ptrack_gym.envs.config.EnvConfig`).

    ## Version history
    v0: first release; the nominal model is Pinocchio's, ``energy_j`` is opt-in.
    v1 (``ptrack_gym.envs.preview``): v0 with a preview of the reference ahead appended to
    the observation.
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
        reward: str = "quadratic",
        kernel_weights: tuple[float, float, float] = DEFAULT_KERNEL_WEIGHTS,
        kernel_scales_rad: tuple[float, ...] = DEFAULT_KERNEL_SCALES_RAD,
        kernel_effort_scale: float = DEFAULT_EFFORT_SCALE,
        max_path_distance_rad: float | None = None,
        disturbance: DisturbanceSpec | Sequence[DisturbanceSpec] | None = None,
        disturbance_sizing: str = "home",
        horizon_s: float = 10.0,
        info_energy: bool = False,
        render_mode: str | None = None,
        gui: bool = False,
        path_seeds: Sequence[int] | None = None,
        disturbance_choices: Sequence[DisturbanceSpec] | None = None,
    ) -> None:
        self.config = config = EnvConfig(
            robot=robot, path=path, path_seed=path_seed, physics_hz=physics_hz,
            control_hz=control_hz, start=start, start_noise_rad=start_noise_rad,
            start_offset_rad=start_offset_rad, reward_weights=reward_weights,
            unstable_penalty=unstable_penalty, reward=reward, kernel_weights=kernel_weights,
            kernel_scales_rad=kernel_scales_rad, kernel_effort_scale=kernel_effort_scale,
            max_path_distance_rad=max_path_distance_rad, disturbance=disturbance,
            disturbance_sizing=disturbance_sizing, horizon_s=horizon_s, info_energy=info_energy,
            render_mode=render_mode, gui=gui,
            path_seeds=None if path_seeds is None else tuple(path_seeds),
            disturbance_choices=(
                None if disturbance_choices is None else tuple(disturbance_choices)
            ),
        )  # fmt: skip
        self.robot_profile = profile = config.profile
        self.render_mode = config.render_mode
        self.n = profile.n
        self.substeps = config.substeps
        self.physics_dt = 1.0 / config.physics_hz
        self.dt = self.substeps * self.physics_dt
        self.torque_limits_nm = np.array(profile.torque_limits_nm)
        self.max_speed = profile.max_joint_speed_rad_s
        self.model = PinocchioModel(profile)
        first = config.path_seed if config.path_seeds is None else config.path_seeds[0]
        self._paths: dict[int | None, tuple[ReferencePath, PathProjector, TrackingTask]] = {}
        self.path_seed = first
        """The seed of the episode's random path (None: a path without one)."""
        for seed in config.path_seeds or ():  # every path of the pool, before any episode
            try:
                self._path_parts(seed)
            except InvalidPathError as exc:
                raise InvalidPathError(f"path_seeds: seed {seed}: {exc}") from exc
        self.path, self.projector, self.task = self._path_parts(first)
        # one runner per choice (each classifies its own hooks), else the one
        self._runners = [
            DisturbanceRunner(items, self.n) for items in config.choices or [config.disturbances]
        ]
        self._choice = 0
        self.runner = self._runners[0]
        self.sim = BulletSim(timestep_s=self.physics_dt, gui=config.gui)
        try:
            self.arm = self.sim.load_arm(
                profile.urdf_path, profile.joint_names, profile.torque_limits_nm
            )
            home = profile.home()
            self.disturbance_context = DisturbanceContext(
                n=self.n,
                torque_limits_nm=self.torque_limits_nm.copy(),
                physics_dt_s=self.physics_dt,
                control_dt_s=self.dt,
                horizon_s=config.horizon_s,
                ee_link=profile.ee_link,
                home_mass_matrix=np.array(self.model.mass_matrix(home)),
                ee_jacobian_home=self.arm.com_jacobian(profile.ee_link, home),
                mean_path_speed_rad_s=self._mean_path_speed(),
                link_jacobians_home={
                    link: self.arm.com_jacobian(link, home) for link in self.arm.link_names
                },
                mass_matrix=self.model.mass_matrix,
                com_jacobian=self.arm.com_jacobian,
            )
            self._contexts = {self.path_seed: self.disturbance_context}
            for runner in self._runners:
                runner.validate(self.disturbance_context)
        except BaseException:
            self.close()  # no PyBullet client outlives a failed construction
            raise
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.n,), dtype=np.float32)
        self.observation_space = self.task.observation_space
        self.episode = 0  # resets so far: lets a controller adapter see a new episode
        self._steps = 0  # control steps this episode; time is steps · dt (no drift)
        self._s0 = 0.0
        self._q, self._qd = profile.home(), np.zeros(self.n)
        self._q_meas, self._qd_meas = self._q, self._qd

    def _path_parts(self, seed: int | None) -> tuple[ReferencePath, PathProjector, TrackingTask]:
        """The path of ``seed`` (the config's path when the env has no pool), its projector
        and its task; built once per seed."""
        if seed in self._paths:
            return self._paths[seed]
        config, profile = self.config, self.robot_profile
        path = make_path(config.path, profile, seed, self.model.mass_matrix)
        check_joint_limits(path, *profile.limits())
        projector = PathProjector(path)
        task = TrackingTask(
            path,
            projector,
            self.model,
            self.max_speed,
            config.reward_weights,
            config.unstable_penalty,
            config.info_energy,
            kernel=(
                KernelReward(
                    config.kernel_weights,
                    config.kernel_scales_rad,
                    config.kernel_effort_scale,
                    self.torque_limits_nm,
                )
                if config.reward == "kernel"
                else None
            ),
        )
        self._paths[seed] = (path, projector, task)
        return path, projector, task

    def pool_paths(self) -> dict[int, ReferencePath]:
        """The pool's paths by seed (``path_seeds``); empty for a single path."""
        return {seed: self._path_parts(seed)[0] for seed in self.config.path_seeds or ()}

    def _use_path(self, seed: int) -> None:
        """Make the pool's path ``seed`` the env's (and the disturbances' mean path speed)."""
        if seed == self.path_seed:
            return
        self.path_seed = seed
        self.path, self.projector, self.task = self._path_parts(seed)
        if seed not in self._contexts:  # one context per path, as its parts
            self._contexts[seed] = dataclasses.replace(
                self.disturbance_context, mean_path_speed_rad_s=self._mean_path_speed()
            )
        self.disturbance_context = self._contexts[seed]

    def _mean_path_speed(self) -> float:
        """Mean |q_r'| over the path's projector grid (rad/s)."""
        return float(np.mean(np.linalg.norm(self.path.evaluate(self.projector.grid_s)[1], axis=1)))

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
        # schedule never depend on each other, nor on the actions. A path pool draws its
        # path from a third (the first two are then those of a single path's env).
        cfg = self.config
        if cfg.path_seeds is None:
            rng, dist_rng = self.np_random.spawn(2)
        else:
            rng, dist_rng, path_rng = self.np_random.spawn(3)
            self._use_path(cfg.path_seeds[int(path_rng.integers(len(cfg.path_seeds)))])
        if cfg.disturbance_choices is not None:  # the next child stream: the episode's choice
            choice = int(self.np_random.spawn(1)[0].integers(len(self._runners)))
            if choice != self._choice:
                self.arm.set_mass_changes({})  # the last choice's plant edits undone
                self._choice, self.runner = choice, self._runners[choice]
        s0 = float(options.get("s0", rng.uniform(0.0, self.path.period_s)))
        q_ref, qd_ref, _ = self.path.evaluate(s0)
        if cfg.start == "on_path":
            q, qd = q_ref + cfg.start_noise_rad * rng.standard_normal(self.n), qd_ref.copy()
        else:
            q = q_ref + rng.uniform(-cfg.start_offset_rad, cfg.start_offset_rad, size=self.n)
            qd = np.zeros(self.n)
        self.arm.reset_state(options.get("q", q), options.get("qd", qd))  # validates them
        self._s0, self._steps = s0, 0
        self.episode += 1
        self._q, self._qd = self.arm.state()
        self.runner.reset(dist_rng, self.disturbance_context)
        self.runner.apply_plant(self.arm, 0.0)
        self._q_meas, self._qd_meas = self.runner.sense(self._q, self._qd)
        obs, _, info = self.task.observe(
            self._q, self._qd, self._q_meas, self._qd_meas, s0, 0.0, np.zeros(self.n),
            np.zeros(self.n), self.runner.last_torque_nm, self.runner.work_j,
        )  # fmt: skip
        if cfg.path_seeds is not None:
            info["path_seed"] = self.path_seed
        if cfg.disturbance_choices is not None:
            info["disturbance_choice"] = self._choice
        return obs, info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self.runner.was_reset:
            raise ResetNeeded("call reset() before step()")
        a, tau = self._validate_action(action)  # tau = clip(a) ⊙ τ_max, within the limits
        q, qd = self.runner.step(
            self.arm, tau, self._q, self._qd, self._steps * self.substeps, self.substeps,
            self.physics_dt,
        )  # fmt: skip
        self._steps += 1
        # Sensors see the state made finite, should it have blown up (without sensors the
        # task sanitises the true and the measured state, the same arrays, at once).
        blown_up = self.runner.senses and not self.task.sanitize(q, qd)
        self._q, self._qd = q, qd
        self._q_meas, self._qd_meas = q_meas, qd_meas = self.runner.sense(q, qd)
        t = self._steps * self.dt
        obs, reward, info = self.task.observe(
            q, qd, q_meas, qd_meas, self._s0 + t, t, a, tau, self.runner.last_torque_nm,
            self.runner.work_j, blown_up,
        )  # fmt: skip
        unstable = info["unstable"]  # a non-finite state or a joint faster than v_max
        max_d = self.config.max_path_distance_rad
        off_path = max_d is not None and info["path_distance"] > max_d
        info["off_path"] = off_path
        return obs, reward, unstable or off_path, False, info

    def _validate_action(self, action: np.ndarray) -> tuple[FloatArray, FloatArray]:
        """(clip(a, −1, 1), the torque it commands (N·m)), or InvalidActionError."""
        a = np.asarray(action)
        if a.dtype.kind not in "fiu":
            raise InvalidActionError(f"action must be real numbers, got dtype {a.dtype}")
        if a.shape != (self.n,):
            raise InvalidActionError(f"action must have shape ({self.n},), got {a.shape}")
        if a.dtype != np.float32 and a.dtype != np.float64:  # float16, longdouble, ints, or
            with np.errstate(over="ignore"):  # another byte order: the kernel takes native
                a = a.astype(np.float64)  # floats; a longdouble beyond them is ±inf, refused
        clipped, tau = np.empty(self.n), np.empty(self.n)  # both end up in the info/reward
        if clip_action(a, self.torque_limits_nm, clipped, tau) >= 0:
            a = a.astype(np.float64)
            idx = np.flatnonzero(~np.isfinite(a))
            raise InvalidActionError(
                f"action has non-finite entries at indices {idx.tolist()}: {a[idx].tolist()}"
            )
        return clipped, tau

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
        if not self.runner.was_reset:
            raise ResetNeeded("no disturbance schedule before the first reset()")
        return self.runner.schedules()

    # -- rendering and lifetime ------------------------------------------------------
    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        profile = self.robot_profile
        return self.sim.render_rgb(profile.camera_target_m, profile.camera_distance_m)

    def close(self) -> None:
        """Disconnect the plant's PyBullet client (idempotent)."""
        if hasattr(self, "sim"):
            self.sim.close()

    # -- pickling: rebuild the client, restore the state -----------------------------
    def __getstate__(self) -> dict[str, Any]:
        return {
            "config": self.config.kwargs(),
            "np_random": self._np_random,
            "np_random_seed": self._np_random_seed,
            "env_spec": self.spec,
            "episode": (self.episode, self._steps, self._s0),
            "state": (self._q.copy(), self._qd.copy(), self._q_meas, self._qd_meas),
            "runner": self.runner,
            "path_seed": self.path_seed,
            "choice": self._choice,
        }

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(**state["config"])  # type: ignore[misc]
        if self.config.path_seeds is not None:
            self._use_path(state["path_seed"])
        self._np_random, self._np_random_seed = state["np_random"], state["np_random_seed"]
        self.spec = state["env_spec"]
        self.episode, self._steps, self._s0 = state["episode"]
        q, qd, self._q_meas, self._qd_meas = state["state"]
        self.arm.reset_state(q, qd)
        self._q, self._qd = self.arm.state()
        self._choice = state.get("choice", 0)
        self.runner = self._runners[self._choice] = state["runner"]
        self.runner.set_context(self.disturbance_context)
        if self.runner.was_reset:
            self.runner.apply_plant(self.arm, self.t, force=True)  # a new, nominal body
