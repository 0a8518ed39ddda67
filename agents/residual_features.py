"""The base controller's block of a residual policy's observation: :class:`ControllerFeatures`.

With ``include_controller_state`` the residual observation is the inner observation (6n + 2
entries, see ``TrackingEnv``) followed by a fixed-size float32 vector of the base
controller's state, each entry clipped to documented finite bounds. Every entry is
evaluated at the measured state the observation describes and at the controller's state
after its last step — the state its *next* step starts from. Per controller (n joints, S
the path period in s, v_max the env's speed bound in rad/s):

``passivity`` — 6 + 2n entries

=====================  ==========================================  ===============  ============
entries                quantity                                    unit             bounds
=====================  ==========================================  ===============  ============
0, 1                   sin, cos of 2π s / S (the controller's s)   —                ±1
2                      ṡ, the controller's path rate               1                ±10
3                      σ̇ = √(q̇ᵀM(q)q̇ / M_r(s)), the speed ratio   1                [0, 10]
4                      s̃ = s − σ                                   s                ±S
5                      path error |q − q_r(s)|                     rad              [0, 2π]
6 : 6 + n              q_r(s) − q per joint                        rad              ±2π
6 + n : 6 + 2n         last τ_base / τ_max (0 after reset)         —                ±2
=====================  ==========================================  ===============  ============

``computed_torque``, ``pd_gravity`` — 3n entries; ``slotine_li`` — 4n entries. These
controllers track the time-indexed reference q_r(s) with a clock s that equals the env's
s₀ + t, so their errors repeat the inner observation's (in float64 before rounding); they
are kept so every base has the same kind of block:

=====================  ==========================================  ===============  ============
entries                quantity                                    unit             bounds
=====================  ==========================================  ===============  ============
0 : n                  e = q_r(s) − q                              rad              ±2π
n : 2n                 ė = q_r'(s) − q̇                             rad/s            ±2 v_max
2n : 3n (Slotine–Li)   r = ė + Λ e                                 rad/s            ±r_max
last n                 last τ_base / τ_max (0 after reset)         —                ±2
=====================  ==========================================  ===============  ============

with r_max = 2 v_max + 2π max Λ. Each controller supplies its block through its
``residual_features`` method (:class:`~agents.base.HasResidualFeatures`); a controller
without one (a network base, :mod:`agents.network`) gets n entries, the last τ_base / τ_max.

A control prior reads the base's reference error q_r(s) − q from this block
(:data:`PRIOR_ERROR_FEATURES`, :func:`prior_error_names`).
"""

from __future__ import annotations

import numpy as np

from agents.base import Controller, FeatureBlock, FloatArray, HasResidualFeatures

#: Bound of the "last τ_base / τ_max" features: beyond ±2 only "saturated" matters.
BASE_RATIO_BOUND = 2.0
#: The feature names, per joint j, of the error to the base's own reference point that a
#: control prior (``prior_gain_per_rad``) feeds back, in order of preference: the passivity
#: block's q_r(s) − q (s the controller's path parameter) and the time-indexed blocks'
#: e = q_r(s) − q (s the controller's clock).
PRIOR_ERROR_FEATURES = ("path_error_{j}_rad", "e_{j}_rad")


def prior_error_names(names: tuple[str, ...], n: int) -> list[str] | None:
    """The names, in ``names``, of the n-joint reference error a control prior feeds back
    (the first of :data:`PRIOR_ERROR_FEATURES` present for every joint), or None."""
    for pattern in PRIOR_ERROR_FEATURES:
        wanted = [pattern.format(j=j) for j in range(n)]
        if set(wanted) <= set(names):
            return wanted
    return None


class ControllerFeatures:
    """The residual observation's controller block: the controller's own
    :class:`~agents.base.FeatureBlock` (when it offers one, :class:`HasResidualFeatures`)
    followed by the last τ_base / τ_max (n entries, ±2); float64, clipped to its bounds.

    Args:
        controller: the base controller.
        max_speed_rad_s: v_max, the env's joint-speed bound (rad/s), for the bounds.

    Attributes:
        names: one name per entry.
        low, high: finite bounds per entry.
    """

    def __init__(self, controller: Controller, max_speed_rad_s: float) -> None:
        n = controller.n
        ratio_names = tuple(f"tau_base_ratio_{j}" for j in range(n))
        ratio_high = np.full(n, BASE_RATIO_BOUND)
        self.block: FeatureBlock | None = (
            controller.residual_features(max_speed_rad_s)
            if isinstance(controller, HasResidualFeatures)
            else None
        )
        if self.block is None:
            self.names, self.low, self.high = ratio_names, -ratio_high, ratio_high
        else:
            self.names = (*self.block.names, *ratio_names)
            self.low = np.concatenate([self.block.low, -ratio_high])
            self.high = np.concatenate([self.block.high, ratio_high])

    def __call__(self, q: FloatArray, qd: FloatArray, base_ratio: FloatArray) -> FloatArray:
        """Features at measured (q, q̇) (rad, rad/s), clipped to [low, high];
        ``base_ratio`` is the last τ_base / τ_max, shape (n,). All NaN where the block is
        NaN (a base whose own state diverged: the residual wrapper ends the episode)."""
        if self.block is None:
            x = base_ratio
        else:
            values = self.block.values(q, qd)
            if np.isnan(values).any():
                return np.full(len(self.names), np.nan)
            x = np.concatenate([values, base_ratio])
        return np.minimum(np.maximum(np.nan_to_num(x), self.low), self.high)
