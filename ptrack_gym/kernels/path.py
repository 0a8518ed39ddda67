"""Path evaluation kernels: q_r(s), q_r'(s), q_r''(s) of the package's two path kinds.

A path that can be evaluated here offers ``kernel_data()`` → :class:`PathKernelData`; one
signature serves both kinds (the arrays of the other kind are empty), so one compiled
specialisation runs every path.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ptrack_gym.kernels import kernel, pack, view1, view2, view3

FloatArray = NDArray[np.float64]

MULTISINE = 0
PIECEWISE_CUBIC = 1


class PathKernelData(NamedTuple):
    """A path in the kernels' terms.

    ``kind`` :data:`MULTISINE`: q_r(s) = center + Σ_k amp_k ⊙ sin(omega_k s + phase_k)
    (amp, phase (K, n); omega (K,) rad/s). ``kind`` :data:`PIECEWISE_CUBIC`: on knot
    interval i (``knots`` (N + 1,), uniform, spanning one period), q_r(s) =
    Σ_m coeffs[m, i] (s − knots[i])^(3−m) (``coeffs`` (4, N, n), scipy's ``PPoly`` layout),
    with s wrapped to [0, period).
    """

    kind: int
    period_s: float
    center: FloatArray
    amp: FloatArray
    phase: FloatArray
    omega: FloatArray
    knots: FloatArray
    coeffs: FloatArray


def multisine_data(
    center: FloatArray, amp: FloatArray, phase: FloatArray, omega: FloatArray, period_s: float
) -> PathKernelData:
    """:class:`PathKernelData` of a multi-sine path."""
    n = center.shape[0]
    return PathKernelData(
        MULTISINE,
        float(period_s),
        np.ascontiguousarray(center, dtype=np.float64),
        np.ascontiguousarray(amp, dtype=np.float64),
        np.ascontiguousarray(phase, dtype=np.float64),
        np.ascontiguousarray(omega, dtype=np.float64),
        np.zeros(2),
        np.zeros((4, 1, n)),
    )


def piecewise_cubic_data(knots: FloatArray, coeffs: FloatArray, period_s: float) -> PathKernelData:
    """:class:`PathKernelData` of a periodic piecewise cubic (a periodic spline)."""
    n = coeffs.shape[2]
    return PathKernelData(
        PIECEWISE_CUBIC,
        float(period_s),
        np.zeros(n),
        np.zeros((1, n)),
        np.zeros((1, n)),
        np.zeros(1),
        np.ascontiguousarray(knots, dtype=np.float64),
        np.ascontiguousarray(coeffs, dtype=np.float64),
    )


@kernel
def cubic_interval(knots: FloatArray, period: float, s: float) -> tuple[int, float]:
    """(i, s − knots[i]) of the knot interval holding s wrapped to [0, period)."""
    sm = s % period
    n_int = knots.shape[0] - 1
    i = min(int(sm / (period / n_int)), n_int - 1)
    if sm < knots[i]:
        i -= 1
    elif i + 1 < n_int and sm >= knots[i + 1]:
        i += 1
    return i, sm - knots[i]


@kernel
def eval_path(
    kind: int,
    period: float,
    center: FloatArray,
    amp: FloatArray,
    phase: FloatArray,
    omega: FloatArray,
    knots: FloatArray,
    coeffs: FloatArray,
    s: float,
    q: FloatArray,
    qd: FloatArray,
    qdd: FloatArray,
) -> None:
    """q_r(s), q_r'(s), q_r''(s) into ``q``, ``qd``, ``qdd`` (shape (n,); see
    :class:`PathKernelData`). Twins: ``MultiSinePath.evaluate``, ``SplinePath.evaluate``."""
    n = q.shape[0]
    if kind == MULTISINE:
        for j in range(n):
            q[j] = center[j]
            qd[j] = 0.0
            qdd[j] = 0.0
        for k in range(amp.shape[0]):
            w = omega[k]
            for j in range(n):
                arg = w * s + phase[k, j]
                sn, cs = math.sin(arg), math.cos(arg)
                q[j] += amp[k, j] * sn
                qd[j] += amp[k, j] * w * cs
                qdd[j] -= amp[k, j] * w * w * sn
    else:
        i, x = cubic_interval(knots, period, s)
        for j in range(n):
            c0, c1, c2, c3 = coeffs[0, i, j], coeffs[1, i, j], coeffs[2, i, j], coeffs[3, i, j]
            q[j] = ((c0 * x + c1) * x + c2) * x + c3
            qd[j] = (3.0 * c0 * x + 2.0 * c1) * x + c2
            qdd[j] = 6.0 * c0 * x + 2.0 * c1


def path_tables(data: PathKernelData) -> tuple[FloatArray, NDArray[np.int64]]:
    """A path's kernel data packed (:func:`ptrack_gym.kernels.pack`) for
    :func:`reference_errors`: (kind, period), then its six arrays in field order."""
    return pack(
        [
            np.array([float(data.kind), data.period_s]),
            data.center,
            data.amp,
            data.phase,
            data.omega,
            data.knots,
            data.coeffs,
        ]
    )


@kernel
def reference_errors(
    flat: FloatArray,
    layout: NDArray[np.int64],
    s: float,
    q: FloatArray,
    qd: FloatArray,
    out: FloatArray,
) -> None:
    """Rows of ``out`` (5, n): q_r(s), q_r'(s), q_r''(s) and the errors e = q_r(s) − q,
    ė = q_r'(s) − q̇ (rad, rad/s, rad/s²), the path from :func:`path_tables`. Twin:
    ``ReferenceClock.errors_numpy`` (``path.evaluate(s)`` and two subtractions)."""
    params = view1(flat, layout, 0)
    eval_path(
        int(params[0]), params[1], view1(flat, layout, 1), view2(flat, layout, 2),
        view2(flat, layout, 3), view1(flat, layout, 4), view1(flat, layout, 5),
        view3(flat, layout, 6), s, out[0], out[1], out[2],
    )  # fmt: skip
    for j in range(q.shape[0]):
        out[3, j] = out[0, j] - q[j]
        out[4, j] = out[1, j] - qd[j]
