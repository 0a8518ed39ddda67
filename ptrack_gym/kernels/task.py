"""Observation and reward of a tracking step: the kernel twin of
:meth:`ptrack_gym.envs.task.TrackingTask.observe` (reference evaluation, observation,
nearest point, reward terms; the info dict is assembled in Python from its outputs)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ptrack_gym.kernels import kernel, pack, view1, view2, view3
from ptrack_gym.kernels.path import PathKernelData, eval_path
from ptrack_gym.kernels.projection import nearest_into

FloatArray = NDArray[np.float64]

#: Entries of ``scalars`` written by :func:`observe` (its first six; the rest is scratch).
SCALARS = ("path_distance", "path_s", "tracking_error", "reward_path", "reward_time",
           "reward_effort")  # fmt: skip


def scalars_buffer(n: int) -> FloatArray:
    """The ``scalars`` argument of :func:`observe` for n joints: the six outputs and 4n of
    scratch (no allocation inside the kernel)."""
    return np.zeros(len(SCALARS) + 4 * n)


def task_tables(
    path_data: PathKernelData,
    projector_args: tuple[object, ...],
    weights: tuple[float, float, float],
    high: FloatArray,
    max_speed: float,
) -> tuple[FloatArray, NDArray[np.int64]]:
    """Everything :func:`observe` reads that does not change during an episode, packed
    (:func:`ptrack_gym.kernels.pack`): the reward weights, the observation bound, the joint
    speed bound, the path (:class:`PathKernelData`) and the projector's tables
    (``PathProjector.kernel_args``)."""
    grid_s, grid_q, grid_wrapped, coarse_q, coarse_sq, hermite, dots, h, stride, _ = projector_args
    params = np.array([path_data.period_s, h, float(path_data.kind), float(stride), max_speed])
    return pack(
        [
            params,
            np.asarray(weights, dtype=np.float64),
            high,
            path_data.center,
            path_data.amp,
            path_data.phase,
            path_data.omega,
            path_data.knots,
            path_data.coeffs,
            grid_s,
            grid_q,
            grid_wrapped,
            coarse_q,
            coarse_sq,
            hermite,
            dots,
        ]
    )


@kernel
def observe(
    q: FloatArray,
    qd: FloatArray,
    q_meas: FloatArray,
    qd_meas: FloatArray,
    s_ref: float,
    action: FloatArray,
    flat: FloatArray,
    layout: NDArray[np.int64],
    obs: NDArray[np.float32],
    scalars: FloatArray,
) -> bool:
    """Fill ``obs`` (6n + 2, float32) and ``scalars`` (:data:`SCALARS`); ``flat``, ``layout``
    from :func:`task_tables`. First :func:`sanitize` the true (q, q̇) in place (the
    measured state may be the same arrays); returns whether it was usable.

    obs = clip([q_m, q̇_m, q_r(s_ref), q_r'(s_ref), q_r − q_m, q_r' − q̇_m, sin 2πs_ref/S,
    cos 2πs_ref/S], ±high) cast to float32; scalars: path distance d of the true q and its
    nearest s, |q_r(s_ref) − q|, and the reward terms −w_path d², −w_time |q_r − q|²,
    −w_effort |a|²/n.
    """
    params = view1(flat, layout, 0)
    period, h, kind, stride = params[0], params[1], int(params[2]), int(params[3])
    weights, high = view1(flat, layout, 1), view1(flat, layout, 2)
    stable = sanitize(q, qd, params[4])
    n = q.shape[0]
    m = len(SCALARS)
    q_ref, qd_ref, qdd_ref = (
        scalars[m : m + n],
        scalars[m + n : m + 2 * n],
        scalars[m + 2 * n : m + 3 * n],
    )
    eval_path(
        kind, period, view1(flat, layout, 3), view2(flat, layout, 4), view2(flat, layout, 5),
        view1(flat, layout, 6), view1(flat, layout, 7), view3(flat, layout, 8), s_ref, q_ref,
        qd_ref, qdd_ref,
    )  # fmt: skip
    for j in range(n):
        vals = (
            q_meas[j], qd_meas[j], q_ref[j], qd_ref[j], q_ref[j] - q_meas[j],
            qd_ref[j] - qd_meas[j],
        )  # fmt: skip
        for b in range(6):
            idx = b * n + j
            hi = high[idx]
            obs[idx] = np.float32(min(max(vals[b], -hi), hi))
    w = 2.0 * math.pi * s_ref / period
    obs[6 * n] = np.float32(min(max(math.sin(w), -high[6 * n]), high[6 * n]))
    obs[6 * n + 1] = np.float32(min(max(math.cos(w), -high[6 * n + 1]), high[6 * n + 1]))
    s_star, dist = nearest_into(
        q, view1(flat, layout, 9), view2(flat, layout, 10), view2(flat, layout, 11),
        view2(flat, layout, 12), view1(flat, layout, 13), view3(flat, layout, 14),
        view2(flat, layout, 15), h, stride, period, scalars[m + 3 * n : m + 4 * n],
    )  # fmt: skip
    e2 = 0.0
    for j in range(n):
        e = q_ref[j] - q[j]
        e2 += e * e
    a2 = 0.0
    for j in range(action.shape[0]):
        a2 += action[j] * action[j]
    scalars[0] = dist
    scalars[1] = s_star
    scalars[2] = math.sqrt(e2)
    scalars[3] = -weights[0] * dist**2
    scalars[4] = -weights[1] * e2
    scalars[5] = -weights[2] * a2 / n
    return stable


@kernel
def sanitize(q: FloatArray, qd: FloatArray, max_speed: float) -> bool:
    """Whether the state is usable — every q finite, every |q̇| ≤ ``max_speed`` (a NaN speed
    fails the comparison) — and, when it is not, make it finite in place: non-finite q → 0,
    NaN q̇ → 0, q̇ clipped to ±max_speed. Twin: ``TrackingTask.sanitize_numpy``."""
    stable = True
    for j in range(q.shape[0]):
        if not (abs(qd[j]) <= max_speed and math.isfinite(q[j])):
            stable = False
    if not stable:
        for j in range(q.shape[0]):
            if not math.isfinite(q[j]):
                q[j] = 0.0
            if math.isnan(qd[j]):
                qd[j] = 0.0
            qd[j] = min(max(qd[j], -max_speed), max_speed)
    return stable


@kernel
def clip_action(a: FloatArray, limits: FloatArray, clipped: FloatArray, tau: FloatArray) -> int:
    """clipped = clip(a, −1, 1) and tau = clipped ⊙ limits (float64, any real dtype of a);
    returns the index of the first non-finite entry of a, or −1.

    Twin: ``np.minimum(np.maximum(a, -1), 1)`` and its product with the torque limits."""
    for j in range(a.shape[0]):
        x = float(a[j])
        if not math.isfinite(x):
            return j
        x = min(max(x, -1.0), 1.0)
        clipped[j] = x
        tau[j] = x * limits[j]
    return -1
