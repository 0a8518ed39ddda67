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
