"""The controller interface shared by every controller in ``agents``.

A controller never touches the simulator: it is built from a :class:`ControlContext` (the
robot's profile, a dynamics model, the reference path and the control period), and at each
control step it is given the measured joint state. Its whole interface is
:class:`Controller`:

* ``reset(q, qd, s_ref)`` — start an episode: measured state (rad, rad/s) and the
  env's time-indexed reference phase ``s_ref`` (s), i.e. the reference is q_r(s_ref) now;
* ``step(q, qd, dt)`` — return the torque τ (N·m) for the measured state, then advance
  the controller's internal state (its clock, or (s, ṡ, σ)) by ``dt`` seconds;
* ``diagnostics()`` — a flat dict of floats describing the controller's internal state
  after the last ``step`` (for ``info`` and logs).

Optionally (:class:`HasResidualFeatures`) ``residual_features(max_speed)`` returns the
:class:`FeatureBlock` a residual policy observes next to the env's observation; the
residual wrapper asks for it instead of inspecting the controller.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from ptrack_gym.paths import ReferencePath
from ptrack_gym.robots import RobotModel, RobotProfile

FloatArray = NDArray[np.float64]


def state_arrays(q: Any, qd: Any) -> tuple[FloatArray, FloatArray]:
    """(q, q̇) as native float64 arrays (rad, rad/s): any real dtype or byte order a user
    passes (float16, float32, longdouble, big-endian, ints) is cast once here, so the
    compiled kernels and the model see the one dtype and layout they are built for (a
    strided view is copied: the kernels are compiled for contiguous arrays)."""
    return (
        np.ascontiguousarray(q, dtype=np.float64),
        np.ascontiguousarray(qd, dtype=np.float64),
    )


@runtime_checkable
class Controller(Protocol):
    """A state-feedback torque controller for an n-joint arm (SI units)."""

    n: int

    def reset(self, q: FloatArray, qd: FloatArray, s_ref: float) -> None:
        """Start an episode at measured (q, q̇) with the reference at phase ``s_ref`` (s)."""
        ...

    def step(self, q: FloatArray, qd: FloatArray, dt: float) -> FloatArray:
        """Torque τ (N·m), shape (n,), for (q, q̇); then advance internal state by ``dt`` (s)."""
        ...

    def diagnostics(self) -> dict[str, float]:
        """Internal state after the last step, as named floats."""
        ...


@dataclass(frozen=True)
class ControlContext:
    """What a controller is built from (never the simulator).

    Attributes:
        profile: the robot (default gain rates, limits, home pose).
        model: the nominal dynamics model.
        path: the reference path q_r(s).
        dt_s: the control period (s), for rate-aware default gains.
    """

    profile: RobotProfile
    model: RobotModel
    path: ReferencePath
    dt_s: float

    @classmethod
    def from_env(cls, env: Any) -> ControlContext:
        """The context of a ptrack_gym env (any wrapper of a ``TrackingEnv``)."""
        u = env.unwrapped
        return cls(profile=u.robot_profile, model=u.model, path=u.path, dt_s=float(u.dt))


@dataclass(frozen=True)
class FeatureBlock:
    """A fixed-size, bounded vector of a controller's state for a residual policy.

    Attributes:
        names: one name per entry.
        low, high: finite bounds per entry (the wrapper clips to them).
        values: (q, q̇) → the unclipped entries at the measured state and the controller's
            state after its last step.
    """

    names: tuple[str, ...]
    low: FloatArray
    high: FloatArray
    values: Callable[[FloatArray, FloatArray], FloatArray]


@runtime_checkable
class HasResidualFeatures(Protocol):
    """A controller that offers residual policies a view of its state."""

    def residual_features(self, max_speed_rad_s: float) -> FeatureBlock:
        """The controller's feature block (v_max bounds the velocity entries)."""
        ...


@runtime_checkable
class ObservesAppliedTorque(Protocol):
    """A controller whose state depends on the torque actually applied (a disturbance
    observer): a wrapper that adds to its torque (the residual wrapper) reports the sum, so
    the addition is not mistaken for an external torque."""

    def applied_torque(self, tau_nm: FloatArray, dt: float) -> None:
        """The torque τ (N·m), shape (n,), applied for the ``dt`` seconds after the last
        ``step`` (replacing the torque that step returned)."""
        ...
