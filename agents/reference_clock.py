"""The time-indexed reference shared by the classical baselines.

Computed torque, PD + gravity and Slotine–Li all track q_r(s) with s = s₀ + t: a clock
set to the env's reference phase at ``reset`` and advanced by ``dt`` after each step.
:class:`ReferenceClock` is that clock and the errors against it,

.. math::

    e = q_r(s) - q, \\qquad \\dot e = q_r'(s) - \\dot q,

held by their shared body (:class:`agents.time_indexed.TimeIndexedController`) so the
bookkeeping (and its checks) exists once.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from agents.base import FeatureBlock, FloatArray
from ptrack_gym.errors import InvalidConfigError, ResetNeededError
from ptrack_gym.kernels.path import path_tables, reference_errors
from ptrack_gym.paths import ReferencePath
from ptrack_gym.robots.model import RobotModel


class ReferenceErrors(NamedTuple):
    """The reference at the clock's s and the errors of a measured state against it."""

    q_r: FloatArray  # (n,) rad
    qd_r: FloatArray  # (n,) rad/s
    qdd_r: FloatArray  # (n,) rad/s²
    e: FloatArray  # q_r − q, (n,) rad
    ed: FloatArray  # q_r' − q̇, (n,) rad/s


class ReferenceClock:
    """Clock s (s) of a time-indexed reference path.

    Raises:
        InvalidConfigError: (a ``ValueError``) a path whose joint count is not the model's.
    """

    def __init__(self, model: RobotModel, path: ReferencePath) -> None:
        if path.n != model.n:
            raise InvalidConfigError(f"path has {path.n} joints, model has {model.n}")
        self.path = path
        self.n = path.n
        self.s: float | None = None
        kernel_data = getattr(path, "kernel_data", None)  # the package's paths have one
        self._tables = path_tables(kernel_data()) if kernel_data is not None else None

    def reset(self, s_ref: float) -> None:
        """Start the clock at s = ``s_ref`` (s)."""
        self.s = float(s_ref)

    def errors(self, q: FloatArray, qd: FloatArray, dt: float) -> ReferenceErrors:
        """The reference at the current s and the errors of (q, q̇); checks that ``reset``
        came first and that ``dt`` (s), the step about to be taken, is positive."""
        if self.s is None:
            raise ResetNeededError("call reset() before step()")
        if not (math.isfinite(dt) and dt > 0.0):
            raise InvalidConfigError(f"dt must be a positive number of seconds, got {dt!r}")
        if self._tables is None:
            return self.errors_numpy(q, qd)
        out = np.empty((5, self.n))  # the compiled twin of errors_numpy: one call, one array
        reference_errors(*self._tables, self.s, q, qd, out)
        return ReferenceErrors(*out)

    def errors_numpy(self, q: FloatArray, qd: FloatArray) -> ReferenceErrors:
        """The readable reference of :meth:`errors` (any path): (q_r, q_r', q_r'') =
        ``path.evaluate(s)``, e = q_r − q, ė = q_r' − q̇."""
        assert self.s is not None
        q_r, qd_r, qdd_r = self.path.evaluate(self.s)
        return ReferenceErrors(q_r, qd_r, qdd_r, q_r - q, qd_r - qd)

    def advance(self, dt: float) -> float:
        """s ← s + dt; returns the new s (s)."""
        assert self.s is not None
        self.s += float(dt)
        return self.s


def error_diagnostics(s: float, err: ReferenceErrors) -> dict[str, float]:
    """The diagnostics every baseline reports: clock s, |e| (rad) and |ė| (rad/s)."""
    return {
        "s": s,
        "tracking_error": float(np.linalg.norm(err.e)),
        "velocity_error": float(np.linalg.norm(err.ed)),
    }


def time_indexed_features(
    clock: ReferenceClock, n: int, max_speed_rad_s: float, lam: FloatArray | None = None
) -> FeatureBlock:
    """The residual features of a time-indexed controller: e = q_r(s) − q (rad, ±2π),
    ė = q_r'(s) − q̇ (rad/s, ±2 v_max) against the controller's clock s, and with
    ``lam`` (Slotine–Li's Λ) r = ė + Λ e (rad/s, ±(2 v_max + 2π max Λ))."""
    two_pi = 2.0 * np.pi
    names = [*[f"e_{j}_rad" for j in range(n)], *[f"ed_{j}_rad_s" for j in range(n)]]
    blocks = [np.full(n, two_pi), np.full(n, 2.0 * max_speed_rad_s)]
    if lam is not None:
        names += [f"r_{j}_rad_s" for j in range(n)]
        blocks.append(np.full(n, 2.0 * max_speed_rad_s + two_pi * float(np.max(lam))))
    high = np.concatenate(blocks)

    def values(q: FloatArray, qd: FloatArray) -> FloatArray:
        s = 0.0 if clock.s is None else clock.s
        q_r, qd_r, _ = clock.path.evaluate(s)
        e, ed = q_r - q, qd_r - qd  # (n,) rad, rad/s
        return np.concatenate([e, ed] if lam is None else [e, ed, ed + lam * e])

    return FeatureBlock(tuple(names), -high, high, values)
