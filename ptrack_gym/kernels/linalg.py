"""Small dense helpers."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ptrack_gym.kernels import kernel

FloatArray = NDArray[np.float64]


@kernel
def symmetrize_upper(upper: FloatArray, out: FloatArray) -> None:
    """out = the symmetric matrix whose upper triangle is ``upper``'s (CRBA fills only the
    upper triangle of M). Twin: ``np.triu(upper) + np.triu(upper, 1).T``."""
    n = upper.shape[0]
    for i in range(n):
        out[i, i] = upper[i, i]
        for j in range(i + 1, n):
            out[i, j] = upper[i, j]
            out[j, i] = upper[i, j]


@kernel
def quadratic_form_upper(upper: FloatArray, v: FloatArray) -> float:
    """vᵀ M v for the symmetric M whose upper triangle is ``upper``. Twin: ``v @ M @ v``."""
    n = v.shape[0]
    acc = 0.0
    for i in range(n):
        acc += upper[i, i] * v[i] * v[i]
        for j in range(i + 1, n):
            acc += 2.0 * upper[i, j] * v[i] * v[j]
    return acc


@kernel
def quadratic_forms_upper(uppers: FloatArray, v: FloatArray) -> FloatArray:
    """v_kᵀ M_k v_k for every k: :func:`quadratic_form_upper` of ``uppers[k]`` (T, n, n) and
    ``v[k]`` (T, n), in one call."""
    out = np.empty(v.shape[0])
    for k in range(v.shape[0]):
        out[k] = quadratic_form_upper(uppers[k], v[k])
    return out


@kernel
def solve_small(a: FloatArray, b: FloatArray, out: FloatArray) -> bool:
    """x with a x = b into ``out`` by Gaussian elimination with partial pivoting, for a small
    dense a (n, n) (neither argument is changed); False, and ``out`` undefined, where a pivot
    is not above 1e-14 times the largest |a_ij| (singular to working precision). Twin:
    ``np.linalg.solve`` (LAPACK's LU with partial pivoting)."""
    n = b.shape[0]
    m = a.copy()
    x = b.copy()
    scale = 0.0
    for i in range(n):
        for j in range(n):
            scale = max(scale, abs(m[i, j]))
    if not scale > 0.0:
        return False
    for k in range(n):
        p = k
        for i in range(k + 1, n):
            if abs(m[i, k]) > abs(m[p, k]):
                p = i
        if not abs(m[p, k]) > 1e-14 * scale:
            return False
        if p != k:
            for j in range(n):
                m[k, j], m[p, j] = m[p, j], m[k, j]
            x[k], x[p] = x[p], x[k]
        for i in range(k + 1, n):
            f = m[i, k] / m[k, k]
            for j in range(k, n):
                m[i, j] -= f * m[k, j]
            x[i] -= f * x[k]
    for k in range(n - 1, -1, -1):
        acc = x[k]
        for j in range(k + 1, n):
            acc -= m[k, j] * out[j]
        out[k] = acc / m[k, k]
    return True
