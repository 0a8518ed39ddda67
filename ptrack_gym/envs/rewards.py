"""A bounded tracking reward for learning: exponential kernels of the errors.

The env's default reward (``reward="quadratic"``, see ``TrackingEnv``) is unbounded: a
flailing arm earns −10² per step while the differences that matter near the path are
~1e-4, and the effort term on the *total* torque charges holding the arm against gravity.
:class:`KernelReward` (``reward="kernel"``) is what a learner is given instead:

.. math::

    r = \\frac{w_d K(d) + w_e K(|e|) + w_u k_u}{w_d + w_e + w_u} \\in [0, 1], \\quad
    K(x) = \\frac{1}{m} \\sum_{i=1}^{m} \\exp\\big(-(x / \\sigma_i)^2\\big), \\quad
    k_u = \\exp\\Big(-\\frac{|u|^2}{n\\,\\sigma_u^2}\\Big),\\ u = \\frac{\\tau - g(q)}{\\tau_{max}},

with d the path distance (rad), e = q_r(s₀ + t) − q the time-indexed error (rad), τ the
commanded torque and g(q) the nominal gravity torque (N·m) — holding the arm up is free,
only the dynamic part of the torque is charged. Several scales σ_i (default 0.1, 0.01 and
0.001 rad) keep a gradient from the first swing down to sub-milliradian tracking: one
kernel alone is flat far from its scale.

Every reward is ≥ 0, so an episode that ends early (off the path, or unstable: reward 0
at that step, nothing after) never earns more than one that goes on.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ptrack_gym.robots.profile import FloatArray

#: The reward modes of ``TrackingEnv(reward=...)``.
REWARD_MODES: tuple[str, ...] = ("quadratic", "kernel")
#: Default kernel weights (path distance, time-indexed error, dynamic effort).
DEFAULT_KERNEL_WEIGHTS: tuple[float, float, float] = (0.5, 0.4, 0.1)
#: Default error scales σ_i (rad) of the multi-scale kernel K.
DEFAULT_KERNEL_SCALES_RAD: tuple[float, ...] = (0.1, 0.01, 0.001)
#: Default scale σ_u of the effort kernel (fraction of the torque limit, RMS over joints).
DEFAULT_EFFORT_SCALE = 0.5


def multiscale_kernel(x: float, scales: Sequence[float]) -> float:
    """K(x) = mean_i exp(−(x/σ_i)²) ∈ (0, 1]; 1 at x = 0 (x and σ_i in the same unit)."""
    return sum(math.exp(-((x / s) ** 2)) for s in scales) / len(scales)


class KernelReward:
    """The bounded reward of the module docstring.

    Args:
        weights: (w_d, w_e, w_u) ≥ 0, not all 0.
        scales_rad: the error scales σ_i (rad), each > 0.
        effort_scale: σ_u (> 0), in units of τ_max.
        torque_limits_nm: τ_max per joint (N·m).
    """

    def __init__(
        self,
        weights: Sequence[float],
        scales_rad: Sequence[float],
        effort_scale: float,
        torque_limits_nm: FloatArray,
    ) -> None:
        w = tuple(float(x) for x in weights)
        total = sum(w)
        self.weights = tuple(x / total for x in w)
        self.scales_rad = tuple(float(s) for s in scales_rad)
        self.effort_scale = float(effort_scale)
        self.torque_limits_nm = np.asarray(torque_limits_nm, dtype=np.float64)
        self.n = len(self.torque_limits_nm)

    def terms(
        self,
        path_distance: float,
        tracking_error: float,
        tau_nm: FloatArray,
        gravity_nm: FloatArray,
    ) -> tuple[float, float, float]:
        """The three weighted terms (path, time, effort), each ≥ 0, summing to r ≤ 1."""
        w_d, w_e, w_u = self.weights
        u = (np.asarray(tau_nm) - gravity_nm) / self.torque_limits_nm
        effort = math.exp(-float(u @ u) / (self.n * self.effort_scale**2))
        return (
            w_d * multiscale_kernel(path_distance, self.scales_rad),
            w_e * multiscale_kernel(tracking_error, self.scales_rad),
            w_u * effort,
        )
