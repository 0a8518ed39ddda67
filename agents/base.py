"""The controller interface shared by every model-based controller in ``agents``.

A controller never touches the simulator: it is built from a dynamics model and a
reference (path tables), and at each control step it is given the measured joint
state. Its whole interface is :class:`Controller`:

* ``reset(q, qd, s_ref)`` — start an episode: measured state (rad, rad/s) and the
  env's time-indexed reference phase ``s_ref`` (s), i.e. the reference is q_r(s_ref) now;
* ``step(q, qd, dt)`` — return the torque τ (N·m) for the measured state, then advance
  the controller's internal state (its clock, or (s, ṡ, σ)) by ``dt`` seconds;
* ``diagnostics()`` — a flat dict of floats describing the controller's internal state
  after the last ``step`` (for ``info`` and logs).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


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
