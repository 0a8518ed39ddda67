"""The tracking task: from the arm's state to the observation, the reward and the info.

:class:`TrackingTask` knows the reference path (and its projector), the observation
layout, the reward weights and the info keys; it never touches the simulator. The env
calls :meth:`TrackingTask.observe` once per reset and per step. Paths of the package run
through the compiled twin (:func:`ptrack_gym.kernels.task.observe`) of the readable
:meth:`TrackingTask.observe_numpy`; any other :class:`~ptrack_gym.paths.ReferencePath`
runs through ``observe_numpy`` itself.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from gymnasium import spaces

from ptrack_gym.envs.rewards import KernelReward
from ptrack_gym.errors import InvalidActionError, InvalidConfigError
from ptrack_gym.kernels import DISPATCH_ERRORS
from ptrack_gym.kernels import task as task_kernels
from ptrack_gym.paths import ReferencePath
from ptrack_gym.projection import PathProjector
from ptrack_gym.robots.model import RobotModel
from ptrack_gym.robots.profile import FloatArray


class TrackingTask:
    """Observation, reward and info of the tracking task (see ``TrackingEnv``'s docstring
    for the tables).

    Args:
        path: the reference q_r(s).
        projector: the nearest-point search on ``path``.
        model: the nominal model (for ``info["energy_j"]`` when ``info_energy``).
        max_speed_rad_s: the joint-speed bound v_max of the observation (rad/s).
        reward_weights: (w_path, w_time, w_effort).
        unstable_penalty: the reward of an unstable step is −unstable_penalty.
        info_energy: add ``energy_j`` = H(q, q̇) to the info (one M(q) and U(q) per step).
        kernel: the bounded reward (``reward="kernel"``) that replaces the quadratic one;
            None keeps the quadratic reward.
    """

    def __init__(
        self,
        path: ReferencePath,
        projector: PathProjector,
        model: RobotModel,
        max_speed_rad_s: float,
        reward_weights: tuple[float, float, float],
        unstable_penalty: float,
        info_energy: bool,
        kernel: KernelReward | None = None,
    ) -> None:
        self.path = path
        self.projector = projector
        self.model = model
        self.n = n = path.n
        self.max_speed_rad_s = float(max_speed_rad_s)
        self.reward_weights = reward_weights
        self.unstable_penalty = unstable_penalty
        self.info_energy = info_energy
        self.kernel = kernel
        ang, vel = np.full(n, 4 * np.pi), np.full(n, max_speed_rad_s)
        high = np.concatenate([ang, vel, ang, vel, 2 * ang, 2 * vel, [1.0, 1.0]])
        self._high32 = high.astype(np.float32)
        self._high = self._high32.astype(np.float64)
        self._buf = np.zeros(6 * n + 2)
        self.observation_space = spaces.Box(-self._high32, self._high32, dtype=np.float32)
        kernel_data = getattr(path, "kernel_data", None)
        self._tables = (
            task_kernels.task_tables(
                kernel_data(), projector.kernel_args, reward_weights, self._high, max_speed_rad_s
            )
            if kernel_data is not None
            else None
        )
        self._scalars = task_kernels.scalars_buffer(n)

    @property
    def compiled(self) -> bool:
        """Whether :meth:`observe` runs the compiled kernel (the path offers kernel data)."""
        return self._tables is not None

    def observe(
        self,
        q: FloatArray,
        qd: FloatArray,
        q_meas: FloatArray,
        qd_meas: FloatArray,
        s_ref: float,
        t_s: float,
        action: FloatArray,
        tau_nm: FloatArray,
        disturbance_torque_nm: FloatArray,
        disturbance_work_j: float,
        unstable: bool = False,
    ) -> tuple[np.ndarray, float, dict[str, Any]]:
        """Observation, reward and info after a step (or a reset, with a zero action); the
        compiled twin of :meth:`observe_numpy` (same arguments, same results to 1e-12).

        The true (q, q̇) is first made usable in place (:meth:`sanitize_numpy`); if it was
        not, or ``unstable`` says the caller found it unusable already (it sanitises before
        sensing when sensors must see a finite state), ``info["unstable"]`` is True and the
        reward is −``unstable_penalty``. Measured arrays that are the true ones (no sensing
        disturbance) are sanitised with them. The arrays may be of any real dtype or byte
        order (those the kernel cannot take are cast to float64, the sanitised state copied
        back); shapes other than (n,) raise :class:`InvalidConfigError` there
        (:class:`InvalidActionError` for the action).
        """
        if self._tables is None:
            return self.observe_numpy(
                q, qd, q_meas, qd_meas, s_ref, t_s, action, tau_nm, disturbance_torque_nm,
                disturbance_work_j, unstable,
            )  # fmt: skip
        obs = np.empty(6 * self.n + 2, dtype=np.float32)
        flat, layout = self._tables
        try:
            stable = task_kernels.observe(
                q, qd, q_meas, qd_meas, s_ref, action, flat, layout, obs, self._scalars
            )
        except DISPATCH_ERRORS:  # a dtype or byte order the kernel cannot take
            stable = self._observe_float64(q, qd, q_meas, qd_meas, s_ref, action, obs)
        unstable = unstable or not stable
        dist, s_star, err, r_path, r_time, r_effort = self._scalars[:6].tolist()
        info: dict[str, Any] = {
            "t_s": t_s,
            "s_ref": s_ref,
            "path_distance": dist,
            "path_s": s_star,
            "tracking_error": err,
            "tau_nm": tau_nm,
            "reward_path": r_path,
            "reward_time": r_time,
            "reward_effort": r_effort,
            "disturbance_torque_nm": disturbance_torque_nm,
            "disturbance_work_j": disturbance_work_j,
            "unstable": unstable,
        }
        if self.info_energy:
            info["energy_j"] = self.model.kinetic_energy(q, qd) + self.model.potential(q)
        if self.kernel is not None:
            return obs, self._kernel_reward(info, q, tau_nm), info
        reward = -self.unstable_penalty if unstable else r_path + r_time + r_effort
        return obs, reward, info

    def _observe_float64(
        self,
        q: FloatArray,
        qd: FloatArray,
        q_meas: FloatArray,
        qd_meas: FloatArray,
        s_ref: float,
        action: FloatArray,
        obs: np.ndarray,
    ) -> bool:
        """The kernel of :meth:`observe` on native float64 copies of its arrays (a measured
        array that is the true one stays the same copy); the sanitised (q, q̇) is copied
        back, so the in-place contract holds for any dtype."""
        q64, qd64 = self._float64(q, "q"), self._float64(qd, "qd")
        qm64 = q64 if q_meas is q else self._float64(q_meas, "q_meas")
        qdm64 = qd64 if qd_meas is qd else self._float64(qd_meas, "qd_meas")
        a64 = self._float64(action, "action", InvalidActionError)
        flat, layout = self._tables  # type: ignore[misc]
        stable = task_kernels.observe(
            q64, qd64, qm64, qdm64, s_ref, a64, flat, layout, obs, self._scalars
        )
        if not stable:
            q[...], qd[...] = q64, qd64
        return stable

    def _float64(
        self, x: FloatArray, name: str, error: type[ValueError] = InvalidConfigError
    ) -> FloatArray:
        """``x`` as a writable, native, contiguous float64 array of shape (n,), or
        ``error`` naming it."""
        arr = np.asarray(x)
        if arr.shape != (self.n,) or arr.dtype.kind not in "fiu":
            raise error(
                f"{name} must be real numbers of shape ({self.n},), got shape {arr.shape} "
                f"and dtype {arr.dtype}"
            )
        with np.errstate(over="ignore"):  # a longdouble beyond float64 is ±inf (unusable)
            out = np.ascontiguousarray(arr, dtype=np.float64)
        return out if out.flags.writeable else out.copy()

    def _kernel_reward(self, info: dict[str, Any], q: FloatArray, tau_nm: FloatArray) -> float:
        """The kernel reward (0 when unstable); replaces the info's reward terms."""
        assert self.kernel is not None
        terms = self.kernel.terms(
            info["path_distance"], info["tracking_error"], tau_nm, self.model.gravity(q)
        )
        info["reward_path"], info["reward_time"], info["reward_effort"] = terms
        return 0.0 if info["unstable"] else float(sum(terms))

    def sanitize(self, q: FloatArray, qd: FloatArray) -> bool:
        """Whether (q, q̇) is usable (finite q, |q̇| ≤ v_max); if not, made finite in place
        (compiled twin of :meth:`sanitize_numpy`). Any real dtype or byte order (cast to
        float64 where the kernel cannot take it, the result copied back)."""
        try:
            return task_kernels.sanitize(q, qd, self.max_speed_rad_s)
        except DISPATCH_ERRORS:  # a dtype or byte order the kernel cannot take
            q64, qd64 = self._float64(q, "q"), self._float64(qd, "qd")
            stable = task_kernels.sanitize(q64, qd64, self.max_speed_rad_s)
            if not stable:
                q[...], qd[...] = q64, qd64
            return stable

    def sanitize_numpy(self, q: FloatArray, qd: FloatArray) -> bool:
        """The readable reference of :meth:`sanitize`: usable iff max|q̇| ≤ v_max (a NaN
        fails) and every q is finite; otherwise q ← nan_to_num(q, 0), q̇ ← clip(nan_to_num(q̇,
        0), ±v_max), in place."""
        v_max = self.max_speed_rad_s
        if float(np.max(np.abs(qd))) <= v_max and bool(np.all(np.isfinite(q))):
            return True
        q[:] = np.nan_to_num(q, nan=0.0, posinf=0.0, neginf=0.0)
        qd[:] = np.clip(np.nan_to_num(qd, nan=0.0), -v_max, v_max)
        return False

    def observation_numpy(
        self,
        q_meas: FloatArray,
        qd_meas: FloatArray,
        q_ref: FloatArray,
        qd_ref: FloatArray,
        s_ref: float,
    ) -> np.ndarray:
        """The observation (6n + 2, float32): measured q, q̇, q_r(s_ref), q_r'(s_ref), the
        errors q_r − q and q_r' − q̇ (measured), and (sin, cos) of 2π s_ref / S, clipped to
        the observation space."""
        n, buf = self.n, self._buf
        buf[:n], buf[n : 2 * n] = q_meas, qd_meas
        buf[2 * n : 3 * n], buf[3 * n : 4 * n] = q_ref, qd_ref
        np.subtract(q_ref, q_meas, out=buf[4 * n : 5 * n])
        np.subtract(qd_ref, qd_meas, out=buf[5 * n : 6 * n])
        omega = 2.0 * math.pi * s_ref / self.path.period_s
        buf[6 * n], buf[6 * n + 1] = math.sin(omega), math.cos(omega)
        return np.minimum(np.maximum(buf, -self._high), self._high).astype(np.float32)

    def observe_numpy(
        self,
        q: FloatArray,
        qd: FloatArray,
        q_meas: FloatArray,
        qd_meas: FloatArray,
        s_ref: float,
        t_s: float,
        action: FloatArray,
        tau_nm: FloatArray,
        disturbance_torque_nm: FloatArray,
        disturbance_work_j: float,
        unstable: bool = False,
    ) -> tuple[np.ndarray, float, dict[str, Any]]:
        """The readable reference of :meth:`observe`.

        Reward: r = −(w_path d² + w_time |q_r(s_ref) − q|² + w_effort |a|²/n), d the path
        distance of the true q; −``unstable_penalty`` when (q, q̇) was not usable.
        """
        unstable = not self.sanitize_numpy(q, qd) or unstable
        q_ref, qd_ref, _ = self.path.evaluate(s_ref)
        obs = self.observation_numpy(q_meas, qd_meas, q_ref, qd_ref, s_ref)
        near = self.projector.nearest_numpy(q)
        e = q_ref - q
        e2 = float(e @ e)
        w_path, w_time, w_effort = self.reward_weights
        info: dict[str, Any] = {
            "t_s": t_s,
            "s_ref": s_ref,
            "path_distance": near.distance,
            "path_s": near.s,
            "tracking_error": math.sqrt(e2),
            "tau_nm": tau_nm,
            "reward_path": -w_path * near.distance**2,
            "reward_time": -w_time * e2,
            "reward_effort": -w_effort * float(action @ action) / self.n,
            "disturbance_torque_nm": disturbance_torque_nm,
            "disturbance_work_j": disturbance_work_j,
            "unstable": unstable,
        }
        if self.info_energy:
            info["energy_j"] = self.model.kinetic_energy(q, qd) + self.model.potential(q)
        if self.kernel is not None:
            return obs, self._kernel_reward(info, q, tau_nm), info
        if unstable:
            reward = -self.unstable_penalty
        else:
            reward = info["reward_path"] + info["reward_time"] + info["reward_effort"]
        return obs, float(reward), info
