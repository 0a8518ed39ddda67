"""The point of a reference path nearest a joint vector: d(q) = min_s |q − q_r(s)| (rad).

The *path distance* of the reward and the metrics. :class:`PathProjector` needs the path
only (q_r and q_r' on a grid), no dynamics model; its search runs compiled
(:func:`ptrack_gym.kernels.projection.nearest`), with :meth:`PathProjector.nearest_numpy`
as the readable reference.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Protocol

import numpy as np

from ptrack_gym.errors import InvalidConfigError, InvalidPathError
from ptrack_gym.kernels.projection import nearest as nearest_kernel
from ptrack_gym.robots.profile import FloatArray


class SampledCurve(Protocol):
    """What the projector reads of a path: any :class:`ptrack_gym.paths.ReferencePath`
    (kept structural here so that ``ptrack_gym.paths`` can re-export the projector)."""

    period_s: float

    def evaluate(self, s: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """q_r(s) (rad), q_r'(s) (rad/s), q_r''(s) (rad/s²) on the nodes ``s`` (m,): (m, n)."""
        ...


class NearestPoint(NamedTuple):
    """The path point closest to a joint vector."""

    s: float  # the minimising s, in [0, period_s)
    distance: float  # |q − q_r(s)| (rad)


class PathProjector:
    """The point of a path nearest a joint vector: d(q) = min_s |q − q_r(s)| (rad).

    Model-free: built from q_r and q_r' on ``grid_size`` nodes per period. See
    :meth:`nearest` for the method and its accuracy.
    """

    #: Stride of the coarse stage of the search (grid nodes).
    STRIDE = 8

    def __init__(self, path: SampledCurve, grid_size: int = 2048) -> None:
        if grid_size < 4 * self.STRIDE:
            raise InvalidPathError(f"grid_size must be >= {4 * self.STRIDE}")
        self.path = path
        self.period_s = path.period_s
        self.grid_s = np.linspace(0.0, self.period_s, grid_size, endpoint=False)
        grid_q, grid_qd, _ = path.evaluate(self.grid_s)
        # Native float64 whatever the path returns (a user's path may answer in float16,
        # longdouble or big-endian arrays, which the compiled search cannot take).
        self.grid_q = np.ascontiguousarray(grid_q, dtype=np.float64)  # (N, n)
        grid_qd = np.asarray(grid_qd, dtype=np.float64)
        self.n = self.grid_q.shape[1]
        n_grid, stride = grid_size, self.STRIDE
        h = self.period_s / n_grid
        # Per grid interval j, the cubic Hermite interpolant of q_r through its exact end
        # values and slopes: q_r(s_j + t) ≈ q_j + a t + b t² + c t³ for t ∈ [0, h].
        q0, q1 = self.grid_q, np.roll(self.grid_q, -1, axis=0)
        m0, m1 = h * grid_qd, h * np.roll(grid_qd, -1, axis=0)
        delta = q1 - q0
        a = grid_qd
        b = (3.0 * delta - 2.0 * m0 - m1) / h**2
        c = (m0 + m1 - 2.0 * delta) / h**3
        self.h = h
        self.grid_wrapped = np.ascontiguousarray(
            self.grid_q[np.arange(-stride, n_grid + stride) % n_grid]
        )
        self.coarse_q = np.ascontiguousarray(self.grid_q[::stride])
        self.coarse_q_t = np.ascontiguousarray(self.coarse_q.T)  # (n, C), for the kernel
        self.coarse_sq = np.einsum("ij,ij->i", self.coarse_q, self.coarse_q)
        self.hermite = np.ascontiguousarray(np.stack([a, b, c], axis=1))  # (N, 3, n)
        pairs = ((a, a), (a, b), (a, c), (b, b), (b, c), (c, c))
        self.hermite_dots = np.ascontiguousarray(
            np.stack([np.einsum("ij,ij->i", x, y) for x, y in pairs], axis=1)
        )  # (N, 6)

    def nearest(self, q: FloatArray) -> NearestPoint:
        """The point of the path nearest ``q`` (rad, n real numbers of any dtype or byte
        order): the compiled twin (:func:`ptrack_gym.kernels.projection.nearest`) of
        :meth:`nearest_numpy`.

        Raises:
            InvalidConfigError: ``q`` is not n real numbers (the kernel reads n entries).
        """
        s, d = nearest_kernel(self._joint_vectors(q, 1), *self.kernel_args)
        return NearestPoint(s=s, distance=d)

    def _joint_vectors(self, q: FloatArray, ndim: int) -> FloatArray:
        """``q`` as native, contiguous float64 of shape (n,) (``ndim`` 1) or (T, n)
        (``ndim`` 2), or :class:`InvalidConfigError`."""
        arr = np.asarray(q)
        if arr.ndim != ndim or arr.shape[-1] != self.n or arr.dtype.kind not in "fiu":
            want = f"({self.n},)" if ndim == 1 else f"(T, {self.n})"
            raise InvalidConfigError(
                f"q must be real numbers of shape {want}, got shape {arr.shape} and dtype "
                f"{arr.dtype}"
            )
        return np.ascontiguousarray(arr, dtype=np.float64)

    @property
    def kernel_args(self) -> tuple[object, ...]:
        """The projector's tables in the order :func:`~ptrack_gym.kernels.projection.nearest`
        takes them after q."""
        return (
            self.grid_s, self.grid_q, self.grid_wrapped, self.coarse_q_t, self.coarse_sq,
            self.hermite, self.hermite_dots, self.h, self.STRIDE, self.period_s,
        )  # fmt: skip

    def nearest_numpy(self, q: FloatArray) -> NearestPoint:
        """The point of the path nearest ``q``: min over s of |q − q_r(s)| (rad) — the
        readable reference of :meth:`nearest`.

        1. A global search over every 8th grid node, then over the 17 nodes around the
           best one, gives the nearest node j.
        2. The sign of d|q − q_r(s)|²/ds = −2 (q − q_j)ᵀ q_r'(s_j) at the node tells on
           which side the minimum lies: the grid interval [s_j, s_j + h] or [s_j − h, s_j].
        3. On that interval q_r is replaced by its cubic Hermite interpolant through the
           exact end values and slopes (error ≤ h⁴/384 · max |d⁴q_r/ds⁴|: ~1e-11 rad on
           the default paths with h = S/2048), so |q − q_r(s_i + t)|² is a polynomial
           g(t) = P₀ + P₁ t + … + P₆ t⁶ whose q-independent coefficients are tabulated.
           Three Newton steps on g'(t) = 0 from the quadratic model's root, kept inside
           [0, h], give t*; the result is the smaller of g(t*) and the node's distance².

        The coarse stage can only pick the wrong branch where two parts of the path pass
        within ~8 grid spacings of each other.
        """
        q = np.asarray(q, dtype=np.float64)
        stride, h = self.STRIDE, self.h
        n_grid = len(self.grid_s)
        # |q_i − q|² − |q|² = |q_i|² − 2 q_iᵀq: one product ranks the coarse nodes.
        i = int(np.argmin(self.coarse_sq - 2.0 * (self.coarse_q @ q))) * stride
        fine = self.grid_wrapped[i : i + 2 * stride + 1] - q  # nodes i − 8 … i + 8
        d2 = np.einsum("ij,ij->i", fine, fine)
        k = int(np.argmin(d2))
        j = (i - stride + k) % n_grid
        node_d2 = float(d2[k])
        if float(fine[k] @ self.hermite[j, 0]) <= 0.0:  # (q − q_j)ᵀq_r'(s_j) ≥ 0: ahead
            interval, e0, p0, node_t = j, -fine[k], node_d2, 0.0
        else:
            interval = (j - 1) % n_grid
            e0 = q - self.grid_q[interval]
            p0, node_t = float(e0 @ e0), h
        ea, eb, ec = (self.hermite[interval] @ e0).tolist()
        aa, ab, ac, bb, bc, cc = self.hermite_dots[interval].tolist()
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
        s = float(self.grid_s[interval]) + best_t
        return NearestPoint(s=s % self.period_s, distance=math.sqrt(max(best_d2, 0.0)))

    def nearest_many(self, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        """For each row of q (T, n): (d_k, s_k) of :meth:`nearest`."""
        args = self.kernel_args
        out = [nearest_kernel(qk, *args) for qk in self._joint_vectors(q, 2)]
        return np.array([d for _, d in out]), np.array([s for s, _ in out])
