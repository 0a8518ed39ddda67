"""Tracking metrics on recorded trajectories, for every controller alike.

A controller that tracks the path up to a time offset (the passivity controller) must be
judged by its distance to the path, not only by the time-indexed error; these functions
compute both kinds, and the quantities that tell them apart (phase offset, speed ratio).

All functions are pure: arrays in, numbers out (SI units; s in seconds of path time).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ptrack_gym.paths import ReferencePath
from ptrack_gym.projection import PathProjector
from ptrack_gym.robots.model import RobotModel

FloatArray = NDArray[np.float64]


def path_distances(projector: PathProjector, q: FloatArray) -> tuple[FloatArray, FloatArray]:
    """For each row of q (T, n): d_k = min_s |q_k − q_r(s)| (rad) and the minimising s_k."""
    return projector.nearest_many(q)


def phase_offset(s_star: FloatArray, s_ref: FloatArray, period_s: float) -> FloatArray:
    """Phase offset (s) of the nearest path point behind (−) or ahead (+) of the
    time-indexed reference, wrapped to [−S/2, S/2)."""
    d = np.asarray(s_star, dtype=np.float64) - np.asarray(s_ref, dtype=np.float64)
    return (d + 0.5 * period_s) % period_s - 0.5 * period_s


def speed_ratio(
    model: RobotModel, path: ReferencePath, q: FloatArray, qd: FloatArray, s_star: FloatArray
) -> FloatArray:
    """σ̇_k = sqrt(q̇ᵀ M(q) q̇ / M_r(s*_k)), M_r(s) = q_r'(s)ᵀ M(q_r(s)) q_r'(s): the arm's
    speed relative to the path's nominal speed at the nearest path point — the passivity
    controller's σ̇, defined for any run. 1 means moving at the reference's pace."""
    q_r, qd_r, _ = path.evaluate(np.asarray(s_star, dtype=np.float64))
    norms2 = getattr(model, "metric_norms2", None)  # a batch evaluation, where the model has one
    if norms2 is not None:
        speed2, m_r = norms2(q, qd), norms2(q_r, qd_r)
    else:
        speed2 = np.array([qk @ model.mass_matrix(pk) @ qk for pk, qk in zip(q, qd, strict=True)])
        m_r = np.array([vk @ model.mass_matrix(pk) @ vk for pk, vk in zip(q_r, qd_r, strict=True)])
    return np.sqrt(np.maximum(speed2, 0.0) / m_r)


def rms(x: FloatArray) -> float:
    """Root mean square of a series (NaN for an empty one)."""
    x = np.asarray(x, dtype=np.float64)
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def recovery_time(
    t_s: FloatArray, distance: FloatArray, t_end_s: float, threshold_rad: float
) -> float:
    """Time (s) from ``t_end_s`` (the end of a disturbance) until the path distance is back
    below ``threshold_rad`` and stays there to the end of the record; NaN if it never does.
    0 if it never left."""
    t = np.asarray(t_s, dtype=np.float64)
    d = np.asarray(distance, dtype=np.float64)
    after = t >= t_end_s
    if not np.any(after):
        return float("nan")
    above = np.flatnonzero(after & (d >= threshold_rad))
    if above.size == 0:
        return 0.0
    last = above[-1]
    if last == len(t) - 1:
        return float("nan")
    return float(t[last + 1] - t_end_s)


#: The per-step series of an :class:`EpisodeRecord` (optional ones may be None).
_PER_STEP = (
    "t_s", "q", "qd", "s_ref", "tau_nm", "path_distance", "path_s", "tracking_error",
    "tau_ff_nm",
)  # fmt: skip


@dataclass(frozen=True)
class EpisodeRecord:
    """What one episode recorded, one row per control step k (state after step k)."""

    t_s: FloatArray  # (T,) time after the step
    q: FloatArray  # (T, n) true joint positions (rad)
    qd: FloatArray  # (T, n) true joint velocities (rad/s)
    s_ref: FloatArray  # (T,) time-indexed reference phase (s)
    tau_nm: FloatArray  # (T, n) torque applied by the controller during step k (N·m)
    torque_limits_nm: FloatArray  # (n,)
    disturbance_work_j: float  # ∫ q̇ᵀ τ_d over the episode (J)
    unstable: bool
    impulse_end_s: float | None = None  # end of the first impulse/push, if any
    intended_steps: int | None = None  # the episode's full length, for unstable episodes
    path_distance: FloatArray | None = None  # (T,) info["path_distance"], if recorded (rad)
    path_s: FloatArray | None = None  # (T,) info["path_s"], the nearest s, if recorded (s)
    tracking_error: FloatArray | None = None  # (T,) info["tracking_error"], if recorded (rad)
    #: (T, n) the nominal feed-forward of step k along the controller's own reference,
    #: :func:`feedforward_torques` (N·m); None for a policy without a phase (a learned one)
    tau_ff_nm: FloatArray | None = None


def feedforward_torques(model: RobotModel, path: ReferencePath, s: FloatArray) -> FloatArray:
    """τ_ff,k = ID(q_r(s_k), q_r'(s_k), q_r''(s_k)) (N·m), (T, n): the nominal model's inverse
    dynamics M(q_r) q_r'' + C(q_r, q_r') q_r' + g(q_r) along the reference at the phases
    ``s`` (T,) (s) at the nominal phase speed ṡ = 1 — the torque that holds the nominal arm
    on the reference, which every model-based law sends when it tracks exactly. A phase
    that is not finite (a diverged controller's) gives NaN there."""
    s = np.asarray(s, dtype=np.float64)
    out = np.full((len(s), model.n), np.nan)
    ok = np.flatnonzero(np.isfinite(s))
    if ok.size:
        q_r, qd_r, qdd_r = path.evaluate(s[ok])
        for j, k in enumerate(ok):
            out[k] = model.inverse_dynamics(q_r[j], qd_r[j], qdd_r[j])
    return out


def episode_metrics(
    record: EpisodeRecord,
    model: RobotModel,
    projector: PathProjector,
    failure_distance_rad: float = 0.5,
    recovery_threshold_rad: float = 1e-2,
    settle_fraction: float = 0.5,
) -> dict[str, float]:
    """Every per-episode metric of the evaluation table.

    * ``path_dist_rms/max/final`` — d = min_s |q − q_r(s)| (rad);
    * ``time_err_rms`` — |q_r(s_ref) − q| (rad), the time-indexed error;
    * ``speed_ratio_err`` — mean |σ̇ − 1| over the last ``settle_fraction`` of the episode;
    * ``phase_offset_s`` — mean phase offset (s) over that window (see :func:`phase_offset`);
    * ``recovery_s`` — :func:`recovery_time` after ``impulse_end_s`` (NaN without one);
    * ``tau_rms_frac``, ``tau_peak_frac``, ``saturation_frac`` — effort relative to the
      limits (fraction of steps with a joint at ≥ 99.9% of its limit);
    * ``tau_dyn_rms_frac`` — the RMS over steps and joints of (τ − g(q))/τ_max, g the nominal
      gravity torque at the state: the effort beyond holding the arm up, which is most of
      ``tau_rms_frac`` and the same for every controller (the effort budgets and fronts);
    * ``tau_fb_rms_frac`` — the RMS over steps and joints of (τ − τ_ff)/τ_max, τ_ff the
      record's nominal feed-forward along the controller's own reference
      (:func:`feedforward_torques`): the *feedback* effort, ~0 for an exact model tracking
      exactly, what a gain buys (the tuner's effort budget); NaN without ``tau_ff_nm``;
    * ``controller_work_j`` — Σ τ_kᵀ (q_{k+1} − q_k), ``disturbance_work_j``;
    * ``failed`` — 1 if unstable or the path distance ever exceeded
      ``failure_distance_rad`` (failed episodes are kept and counted, never dropped).

    An unstable episode ends early and its last row is not a real pose (the env clips it);
    that row is dropped and both error series are padded with ``failure_distance_rad`` up
    to ``intended_steps``, so blowing up never scores better than staying near the path.

    The path distances, nearest s and time-indexed errors are the record's (the env's info)
    when it has them, otherwise computed by ``projector`` and the path.
    """
    if record.unstable and len(record.q) > 1:
        record = dataclasses.replace(
            record,
            **{
                name: getattr(record, name)[:-1]
                for name in _PER_STEP
                if getattr(record, name) is not None
            },
        )
    q, qd = record.q, record.qd
    if len(q) == 0:  # nothing was stepped (a controller diverged at once): failed throughout
        out = dict.fromkeys(METRIC_NAMES, float("nan"))
        out.update(
            path_dist_rms=failure_distance_rad, path_dist_max=failure_distance_rad,
            path_dist_final=failure_distance_rad, time_err_rms=failure_distance_rad,
            controller_work_j=0.0, disturbance_work_j=float(record.disturbance_work_j),
            failed=1.0,
        )  # fmt: skip
        return out
    if record.path_distance is not None and record.path_s is not None:
        dist, s_star = np.asarray(record.path_distance), np.asarray(record.path_s)
    else:
        dist, s_star = path_distances(projector, q)
    path = projector.path
    if record.tracking_error is not None:
        time_err = np.asarray(record.tracking_error, dtype=np.float64)
    else:
        time_err = np.linalg.norm(path.evaluate(record.s_ref)[0] - q, axis=1)
    if record.unstable:
        missing = max((record.intended_steps or len(q)) - len(q), 1)
        pad = np.full(missing, failure_distance_rad)
        dist, time_err = np.concatenate([dist, pad]), np.concatenate([time_err, pad])
    k0 = int(len(q) * (1.0 - settle_fraction))
    ratio = speed_ratio(model, path, q[k0:], qd[k0:], s_star[k0:])
    offset = phase_offset(s_star[k0:], record.s_ref[k0:], path.period_s)
    frac = np.abs(record.tau_nm) / record.torque_limits_nm
    many = getattr(model, "gravity_many", None)  # a batch evaluation, where the model has one
    gravity = many(q) if many is not None else np.array([model.gravity(qk) for qk in q])
    dyn_frac = (record.tau_nm - gravity) / record.torque_limits_nm
    fb_rms = (
        rms((record.tau_nm - record.tau_ff_nm) / record.torque_limits_nm)
        if record.tau_ff_nm is not None
        else float("nan")
    )
    dq = np.diff(q, axis=0)
    work = float(np.sum(record.tau_nm[1:] * dq)) if len(q) > 1 else 0.0
    # A blown-up episode never recovered (and its padded series has no time stamps).
    recovery = (
        recovery_time(record.t_s, dist, record.impulse_end_s, recovery_threshold_rad)
        if record.impulse_end_s is not None and not record.unstable
        else float("nan")
    )
    failed = record.unstable or bool(np.max(dist) > failure_distance_rad)
    return {
        "path_dist_rms": rms(dist),
        "path_dist_max": float(np.max(dist)),
        "path_dist_final": float(dist[-1]),
        "time_err_rms": rms(time_err),
        "speed_ratio_err": float(np.mean(np.abs(ratio - 1.0))) if ratio.size else float("nan"),
        "phase_offset_s": float(np.mean(offset)) if offset.size else float("nan"),
        "recovery_s": recovery,
        "tau_rms_frac": rms(frac),
        "tau_dyn_rms_frac": rms(dyn_frac),
        "tau_fb_rms_frac": fb_rms,
        "tau_peak_frac": float(np.max(frac)),
        "saturation_frac": float(np.mean(np.any(frac >= 0.999, axis=1))),
        "controller_work_j": work,
        "disturbance_work_j": float(record.disturbance_work_j),
        "failed": float(failed),
    }


METRIC_NAMES: Sequence[str] = (
    "path_dist_rms",
    "path_dist_max",
    "path_dist_final",
    "time_err_rms",
    "speed_ratio_err",
    "phase_offset_s",
    "recovery_s",
    "tau_rms_frac",
    "tau_dyn_rms_frac",
    "tau_fb_rms_frac",
    "tau_peak_frac",
    "saturation_frac",
    "controller_work_j",
    "disturbance_work_j",
    "failed",
)
