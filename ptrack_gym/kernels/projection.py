"""The nearest point of a path: the kernel twin of
:meth:`ptrack_gym.projection.PathProjector.nearest` (whose docstring states the method)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ptrack_gym.kernels import kernel

FloatArray = NDArray[np.float64]


@kernel
def nearest(
    q: FloatArray,
    grid_s: FloatArray,
    grid_q: FloatArray,
    grid_wrapped: FloatArray,
    coarse_q: FloatArray,
    coarse_sq: FloatArray,
    hermite: FloatArray,
    hermite_dots: FloatArray,
    h: float,
    stride: int,
    period: float,
) -> tuple[float, float]:
    """(s*, d): the minimiser s* ∈ [0, period) of |q − q_r(s)| and the distance d (rad).
    See :func:`nearest_into`, which this calls with a scratch vector of its own."""
    return nearest_into(
        q, grid_s, grid_q, grid_wrapped, coarse_q, coarse_sq, hermite, hermite_dots, h, stride,
        period, np.empty(q.shape[0]),
    )  # fmt: skip


@kernel
def coarse_argmin(q: FloatArray, coarse_q: FloatArray, coarse_sq: FloatArray) -> int:
    """Coarse stage of :func:`nearest_into`: the first c minimising v_c = |q_c|² − 2 q_cᵀq
    over the coarse nodes (``coarse_q`` stored transposed, (n, C); ``coarse_sq`` = |q_c|²),
    0 if no v_c is below +inf.

    Four interleaved lanes (nodes c ≡ 0, 1, 2, 3 mod 4), each keeping its first strict
    minimum, then the smallest of them, ties to the lowest index: the same node as one
    scan ``if v_c < best`` in order, and each v_c by the same operations in the same order
    (so the same bits) — only faster, the lanes' dot products and comparisons being
    independent of each other."""
    n, n_coarse = q.shape[0], coarse_sq.shape[0]
    m0 = m1 = m2 = m3 = math.inf
    i0 = i1 = i2 = i3 = -1
    c = 0
    while c + 4 <= n_coarse:
        d0 = d1 = d2 = d3 = 0.0
        for j in range(n):
            qj = q[j]
            d0 += coarse_q[j, c] * qj
            d1 += coarse_q[j, c + 1] * qj
            d2 += coarse_q[j, c + 2] * qj
            d3 += coarse_q[j, c + 3] * qj
        v0, v1 = coarse_sq[c] - 2.0 * d0, coarse_sq[c + 1] - 2.0 * d1
        v2, v3 = coarse_sq[c + 2] - 2.0 * d2, coarse_sq[c + 3] - 2.0 * d3
        if v0 < m0:
            m0, i0 = v0, c
        if v1 < m1:
            m1, i1 = v1, c + 1
        if v2 < m2:
            m2, i2 = v2, c + 2
        if v3 < m3:
            m3, i3 = v3, c + 3
        c += 4
    while c < n_coarse:  # the last C mod 4 nodes, in lane 0 (their indices are the largest)
        d0 = 0.0
        for j in range(n):
            d0 += coarse_q[j, c] * q[j]
        v0 = coarse_sq[c] - 2.0 * d0
        if v0 < m0:
            m0, i0 = v0, c
        c += 1
    best, i_best = math.inf, -1
    for m, i in ((m0, i0), (m1, i1), (m2, i2), (m3, i3)):
        if i >= 0 and (m < best or (m == best and i < i_best)):
            best, i_best = m, i
    return max(i_best, 0)


@kernel
def nearest_into(
    q: FloatArray,
    grid_s: FloatArray,
    grid_q: FloatArray,
    grid_wrapped: FloatArray,
    coarse_q: FloatArray,
    coarse_sq: FloatArray,
    hermite: FloatArray,
    hermite_dots: FloatArray,
    h: float,
    stride: int,
    period: float,
    e0: FloatArray,
) -> tuple[float, float]:
    """(s*, d): the minimiser s* ∈ [0, period) of |q − q_r(s)| and the distance d (rad).

    Arrays as built by ``PathProjector``: the N grid nodes ``grid_q`` (N, n) at ``grid_s``,
    the grid wrapped by ``stride`` nodes each side, every ``stride``-th node (transposed,
    (n, C)) and its squared norm, and per interval the Hermite coefficients (N, 3, n) and
    their six dot products;
    ``e0`` (n,) is scratch.
    """
    n_grid, n = grid_q.shape
    i = coarse_argmin(q, coarse_q, coarse_sq) * stride
    # Fine stage: the 2·stride + 1 nodes around it (the wrapped grid starts stride early).
    node_d2, k_best = math.inf, 0
    for k in range(2 * stride + 1):
        d2 = 0.0
        for j in range(n):
            e = grid_wrapped[i + k, j] - q[j]
            d2 += e * e
        if d2 < node_d2:
            node_d2, k_best = d2, k
    jn = (i - stride + k_best) % n_grid
    # Which side of node jn: sign of (q_j − q)ᵀ q_r'(s_j) (fine row minus q).
    side = 0.0
    for j in range(n):
        side += (grid_wrapped[i + k_best, j] - q[j]) * hermite[jn, 0, j]
    if side <= 0.0:  # the minimum is ahead of node jn
        interval, node_t, p0 = jn, 0.0, node_d2
        for j in range(n):
            e0[j] = q[j] - grid_wrapped[i + k_best, j]
    else:
        interval = (jn - 1) % n_grid
        node_t = h
        p0 = 0.0
        for j in range(n):
            e0[j] = q[j] - grid_q[interval, j]
            p0 += e0[j] * e0[j]
    ea, eb, ec = 0.0, 0.0, 0.0
    for j in range(n):
        ea += hermite[interval, 0, j] * e0[j]
        eb += hermite[interval, 1, j] * e0[j]
        ec += hermite[interval, 2, j] * e0[j]
    aa, ab, ac = hermite_dots[interval, 0], hermite_dots[interval, 1], hermite_dots[interval, 2]
    bb, bc, cc = hermite_dots[interval, 3], hermite_dots[interval, 4], hermite_dots[interval, 5]
    # g(t) = |e0 − a t − b t² − c t³|², expanded.
    p1, p2, p3 = -2.0 * ea, aa - 2.0 * eb, 2.0 * (ab - ec)
    p4, p5, p6 = bb + 2.0 * ac, 2.0 * bc, cc
    t = min(max(-p1 / (2.0 * p2), 0.0), h) if p2 > 0.0 else node_t
    for _ in range(3):
        slope = p1 + t * (2 * p2 + t * (3 * p3 + t * (4 * p4 + t * (5 * p5 + t * 6 * p6))))
        curve = 2 * p2 + t * (6 * p3 + t * (12 * p4 + t * (20 * p5 + t * 30 * p6)))
        if curve <= 0.0:
            break
        t = min(max(t - slope / curve, 0.0), h)
    g_t = p0 + t * (p1 + t * (p2 + t * (p3 + t * (p4 + t * (p5 + t * p6)))))
    best_t, best_d2 = node_t, node_d2
    if g_t < best_d2:
        best_t, best_d2 = t, g_t
    s = (grid_s[interval] + best_t) % period
    return s, math.sqrt(max(best_d2, 0.0))
