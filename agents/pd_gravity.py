"""PD control with gravity compensation and reference velocity feed-forward.

.. math::

    \\tau = K_p e + K_d \\dot e + g(q), \\qquad e = q_r - q, \\quad \\dot e = q_r' - \\dot q

Takegaki & Arimoto (1981) proved this law (without q_r') globally asymptotically stable
for a *fixed* set point. On a moving reference it is not a tracking controller: the
inertial and Coriolis torques M q̈_r + C q̇_r of the reference are never supplied, so the
arm lags the reference by roughly e ≈ K_p⁻¹ (M q̈_r + C q̇_r). ``docs/baselines.md`` reports
the size of that steady error on each robot.
"""

from __future__ import annotations

from agents.base import FloatArray
from agents.gains import PDGravityGains, gain_vector
from agents.reference_clock import ReferenceClock, error_diagnostics
from ptrack_gym.paths import ReferencePath
from ptrack_gym.robots.model import RobotModel


class PDGravityController:
    """PD + gravity compensation on the time-indexed reference q_r(s), s = s₀ + t.

    The clock is set to the env's reference phase by :meth:`reset` and advanced by ``dt``
    in :meth:`step`.

    Args:
        model: the controller's nominal dynamics model (only g(q) is used).
        path: the reference path q_r(s), s in seconds.
        gains: K_p (N·m/rad) and K_d (N·m·s/rad), diagonal.

    Raises:
        InvalidConfigError: (a ``ValueError``) bad gains, or a model/path mismatch.
    """

    def __init__(self, model: RobotModel, path: ReferencePath, gains: PDGravityGains) -> None:
        if not isinstance(gains, PDGravityGains):
            raise TypeError(f"gains must be PDGravityGains, got {type(gains).__name__}")
        self.clock = ReferenceClock(model, path)
        self.model = model
        self.path = path
        self.gains = gains
        self.n = model.n
        self.kp = gain_vector(gains.kp_nm_rad, self.n, "kp_nm_rad")  # (n,) N·m/rad
        self.kd = gain_vector(gains.kd_nms_rad, self.n, "kd_nms_rad")  # (n,) N·m·s/rad
        self._diag: dict[str, float] = {}

    def reset(self, q: FloatArray, qd: FloatArray, s_ref: float) -> None:
        """Start the clock at s = ``s_ref`` (s)."""
        self.clock.reset(s_ref)
        self._diag = {"s": float(s_ref)}

    def step(self, q: FloatArray, qd: FloatArray, dt: float) -> FloatArray:
        """τ = K_p e + K_d ė + g(q) (N·m), shape (n,); then s ← s + dt."""
        err = self.clock.errors(q, qd, dt)
        tau = self.kp * err.e + self.kd * err.ed + self.model.gravity(q)
        self._diag = error_diagnostics(self.clock.advance(dt), err)
        return tau

    def diagnostics(self) -> dict[str, float]:
        """``s``: the clock after the last step (s), equal to the env's ``s_ref`` then;
        ``tracking_error`` |e| (rad) and ``velocity_error`` |ė| (rad/s) of the state
        passed to the last step (against q_r(s − dt))."""
        return dict(self._diag)
