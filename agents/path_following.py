"""Path-following computed torque: a time-indexed law whose clock is re-synchronised to the arm.

The time-indexed baselines track q_r(s) with s = s₀ + t, so an arm held back by a
disturbance is pulled toward where the reference *is now*, cutting across the path to
catch up. :class:`PathFollowingController` wraps such a law (computed torque by default,
by composition: it holds the inner controller and resets its clock) and, before each step,
moves the clock's phase to the arm's place on the path:

.. math::

    \\hat s_k = s_{k-1} + dt \\quad (\\hat s_0 = s_{ref}), \\qquad
    s^*_k = \\arg\\min_{|s - \\hat s_k| \\le W} |q_k - q_r(s)|, \\qquad W = w\\,S,

    s_k = \\hat s_k + \\beta\\,(s^*_k - \\hat s_k), \\qquad
    \\beta = 1 - e^{-\\gamma\\,dt} \\;(\\gamma = \\infty: \\beta = 1),

then the inner law runs at s_k at nominal speed ṡ = 1 (q_r(s_k), q_r'(s_k), q_r''(s_k);
for computed torque τ = M(q)(q_r'' + K_d(q_r' − q̇) + K_p(q_r − q)) + C(q, q̇)q̇ + g(q),
N·m) and the clock advances, s ← s_k + dt (s in seconds of path time, S the period).

* **Window** (``window_fraction`` w, default 0.1): the phase moves by at most W per
  step besides its nominal dt, so it never jumps to another part of a path that nears
  itself farther than W away in phase (on every robot's default path, points ≥ S/10 apart
  in phase are ≥ 0.18 rad apart). The search uses the package's projector
  (:class:`~ptrack_gym.projection.PathProjector`): its global nearest point when that lies in
  the window (then it is the window's nearest too); otherwise the nearest of its grid
  nodes in the window, refined by Newton steps on ½|q − q_r(s)|² inside the window.
* **Blending** (``sync_rate_1_s`` γ, default ∞: full re-synchronisation): with β = 1 the
  error e = q_r(s*) − q is normal to the path (q_r'(s*)ᵀe = 0 at an interior minimum), so
  only the transverse error has a spring; along the path the law has velocity feedback
  K_d only and the arm resumes nominal speed where it is instead of racing to q_r(t).
  s* is a smooth function of q while the path distance stays below the path's radius of
  curvature (∂s*/∂q = q_r'ᵀ / (|q_r'|² − eᵀq_r'')), so no rate limit is needed there; a
  finite γ low-passes the correction (a first-order phase observer ṡ = 1 + γ(s* − s)) for
  noisy measurements, at the price of a tangential spring on the lag s* − s.
* **Limits**: with no tangential spring a sustained push along the path moves the arm
  along it freely, and the feed-forward at ṡ = 1 then misses its real speed (transverse
  error grows while the push lasts). What the variant removes is the catch-up after a
  delay; under the env's 50-ms impulses its path distance is computed torque's ± 15%.

Gains are computed torque's (:class:`~agents.computed_torque.ComputedTorqueGains`) under
their own :data:`NAME`, so tuned gains are kept apart (each robot profile states its
``controller_gains["computed_torque_path"]``, equal to its computed-torque rates).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from agents import computed_torque
from agents.base import ControlContext, FeatureBlock, FloatArray, state_arrays
from agents.computed_torque import ComputedTorqueController, ComputedTorqueGains
from agents.gains import cap_bandwidth, rates
from agents.time_indexed import TimeIndexedController
from ptrack_gym.errors import InvalidConfigError, ResetNeededError
from ptrack_gym.projection import PathProjector

#: The gain rates (:class:`agents.registry.RateSource`): computed torque's, under this name.
NAME = "computed_torque_path"
DEFAULT_RATES = dict(computed_torque.DEFAULT_RATES)
BANDWIDTHS = computed_torque.BANDWIDTHS
TUNABLE = dict(computed_torque.TUNABLE)

#: Default half-width of the phase search window, as a fraction of the period.
WINDOW_FRACTION = 0.1
#: Newton steps refining a window search that falls back to the projector's grid.
NEWTON_STEPS = 4


def gains_from_rates(ctx: ControlContext, given: Mapping[str, float] | None) -> ComputedTorqueGains:
    """Absolute gains from rates — ``DEFAULT_RATES``, updated by the profile's
    ``controller_gains[NAME]``, updated by ``given``: K_p = ω² (1/s²), K_d = 2ζω (1/s), ω
    capped at α / dt (rad/s)."""
    r = rates(DEFAULT_RATES, given, NAME, ctx.profile.controller_gains.get(NAME))
    return ComputedTorqueGains.from_bandwidth(cap_bandwidth(r["omega"], ctx.dt_s), r["zeta"])


def default_gains(ctx: ControlContext) -> ComputedTorqueGains:
    """The robot's default gains at the context's control rate (:func:`gains_from_rates`)."""
    return gains_from_rates(ctx, None)


def _wrap(x: float, period: float) -> float:
    """x wrapped to [−period/2, period/2)."""
    return (x + 0.5 * period) % period - 0.5 * period


class PathFollowingController:
    """A time-indexed law whose phase is re-synchronised to the arm (module docstring).

    Args:
        inner: the time-indexed controller (its clock is set before each of its steps).
        window_fraction: w ∈ (0, 0.5): the search window is s ± w·S.
        sync_rate_1_s: γ > 0 (1/s), the blending rate; ``math.inf`` re-syncs fully.

    Raises:
        InvalidConfigError: (a ``ValueError``) w or γ out of range.
    """

    def __init__(
        self,
        inner: TimeIndexedController,
        window_fraction: float = WINDOW_FRACTION,
        sync_rate_1_s: float = math.inf,
    ) -> None:
        if not (isinstance(window_fraction, (int, float)) and 0.0 < window_fraction < 0.5):
            raise InvalidConfigError(
                f"window_fraction must be in (0, 0.5), got {window_fraction!r}"
            )
        if not (isinstance(sync_rate_1_s, (int, float)) and sync_rate_1_s > 0.0):
            raise InvalidConfigError(f"sync_rate_1_s must be > 0, got {sync_rate_1_s!r}")
        self.inner = inner
        self.path = inner.path
        self.n = inner.n
        self.projector = PathProjector(inner.path)
        self.window_s = float(window_fraction) * self.path.period_s  # W (s)
        self.sync_rate_1_s = float(sync_rate_1_s)
        self._correction_s = 0.0  # s_k − ŝ_k of the last step (s)
        self._distance_rad = math.nan  # |q − q_r(s*)| of the last step (rad)

    def reset(self, q: FloatArray, qd: FloatArray, s_ref: float) -> None:
        """Start at ŝ₀ = ``s_ref`` (s): the first step searches the window around it."""
        self.inner.reset(q, qd, s_ref)
        self._correction_s, self._distance_rad = 0.0, math.nan

    def nearest_in_window(self, q: FloatArray, s_hat: float) -> tuple[float, float]:
        """(s*, d): s* = argmin over |s − ŝ| ≤ W of |q − q_r(s)| (s, unwrapped near ŝ) and
        d = |q − q_r(s*)| (rad) (module docstring, *Window*)."""
        p, half = self.projector, self.window_s
        near = p.nearest(q)
        offset = _wrap(near.s - s_hat, p.period_s)
        if abs(offset) <= half:
            return s_hat + offset, near.distance
        nodes = np.arange(math.ceil((s_hat - half) / p.h), math.floor((s_hat + half) / p.h) + 1)
        diff = p.grid_q[nodes % len(p.grid_s)] - q  # (m, n) rad
        s = float(nodes[int(np.argmin(np.einsum("ij,ij->i", diff, diff)))] * p.h)
        low, high = max(s - p.h, s_hat - half), min(s + p.h, s_hat + half)
        for _ in range(NEWTON_STEPS):  # f = ½|q − q_r|², f' = −eᵀq_r', f'' = |q_r'|² − eᵀq_r''
            q_r, qd_r, qdd_r = self.path.evaluate(s)
            e = q - q_r
            curve = float(qd_r @ qd_r - e @ qdd_r)
            if curve <= 0.0:
                break
            s = min(max(s + float(e @ qd_r) / curve, low), high)
        # Where f is concave (q beyond the centre of curvature) its minimum is an end point.
        ends = (s, low, high)
        dist, s = min((float(np.linalg.norm(q - self.path.evaluate(x)[0])), x) for x in ends)
        return s, dist

    def step(self, q: FloatArray, qd: FloatArray, dt: float) -> FloatArray:
        """τ (N·m), shape (n,): the inner law at the re-synchronised phase s_k; then
        s ← s_k + dt (module docstring)."""
        s_hat = self.inner.clock.s
        if s_hat is None:
            raise ResetNeededError("call reset() before step()")
        if not (math.isfinite(dt) and dt > 0.0):
            raise InvalidConfigError(f"dt must be a positive number of seconds, got {dt!r}")
        q, qd = state_arrays(q, qd)
        if q.shape != (self.n,) or qd.shape != (self.n,) or not np.isfinite(q).all():
            raise InvalidConfigError(
                f"q, qd must be finite with shape ({self.n},), got {q.shape}, {qd.shape}"
            )
        s_star, self._distance_rad = self.nearest_in_window(q, s_hat)
        beta = 1.0 if math.isinf(self.sync_rate_1_s) else -math.expm1(-self.sync_rate_1_s * dt)
        self._correction_s = beta * (s_star - s_hat)
        self.inner.clock.reset(s_hat + self._correction_s)
        return self.inner.step(q, qd, dt)

    def diagnostics(self) -> dict[str, float]:
        """The inner controller's (``s`` after the step, ``tracking_error`` |q_r(s_k) − q|
        (rad), ``velocity_error`` (rad/s)), with ``phase_correction_s`` s_k − ŝ_k (s) and
        ``window_distance_rad`` |q − q_r(s*_k)| (rad) of the last step (after one)."""
        if math.isnan(self._distance_rad):
            return self.inner.diagnostics()
        return {
            **self.inner.diagnostics(),
            "phase_correction_s": self._correction_s,
            "window_distance_rad": self._distance_rad,
        }

    def residual_features(self, max_speed_rad_s: float) -> FeatureBlock:
        """The inner law's block against the re-synchronised clock: e = q_r(s) − q (rad),
        ė = q_r'(s) − q̇ (rad/s) (:func:`agents.reference_clock.time_indexed_features`)."""
        return self.inner.residual_features(max_speed_rad_s)


def build(ctx: ControlContext, gains: Any = None) -> PathFollowingController:
    """Path-following computed torque for a context: ``gains`` None (the robot's defaults),
    a mapping of rates (:func:`gains_from_rates`) or :class:`ComputedTorqueGains`."""
    if gains is None or isinstance(gains, Mapping):
        gains = gains_from_rates(ctx, gains)
    return PathFollowingController(ComputedTorqueController(ctx.model, ctx.path, gains))
