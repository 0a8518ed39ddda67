"""Periodic reference paths q_r(s) and the tables the passivity controller needs.

The path parameter ``s`` is measured in seconds: a controller that tracks the path at
nominal speed has ṡ = 1, and the path repeats with period ``period_s``.

Paths (each implements :class:`ReferencePath`):

* :class:`MultiSinePath` — joint-space multi-sine (Lissajous) curves, analytic
  derivatives; :func:`default_path` and :func:`random_multisine` build them per robot;
* :class:`SplinePath` — a periodic cubic spline through samples, e.g.
  :func:`ee_circle_path`, an end-effector circle converted to joints by IK on a grid.

:class:`PathTables` tabulates, for a path and a :class:`~ptrack_gym.robots.model.RobotModel`,
every quantity of CONTROL_LAW.md from the path and inverse dynamics — no finite
differences:

.. math::

    M_r = q_r'^T M(q_r) q_r', \\quad \\tau_r = M(q_r) q_r'' + C(q_r, q_r') q_r' + g(q_r),
    \\quad W_r = -U(q_r) - \\tfrac12 M_r,

    W_r' = -q_r'^T \\tau_r, \\quad M_r' = 2 q_r'^T (\\tau_r - g(q_r)).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np
from scipy.interpolate import CubicSpline

from ptrack_gym.errors import InvalidPathError
from ptrack_gym.robots.model import RobotModel
from ptrack_gym.robots.spec import FloatArray, RobotSpec
from ptrack_gym.sim import BulletArm, BulletSim


@runtime_checkable
class ReferencePath(Protocol):
    """A smooth path in joint space, periodic in s with period ``period_s`` (s)."""

    n: int
    period_s: float

    def evaluate(self, s: float | FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """q_r(s) (rad), q_r'(s) (rad/s), q_r''(s) (rad/s²).

        Shapes (n,) for a scalar ``s``, (m, n) for ``s`` of shape (m,).
        """
        ...


class MultiSinePath:
    """q_r(s) = c + Σ_k a_k ⊙ sin(k ω s + φ_k),  ω = 2π / period_s,  k = 1..K.

    Args:
        center_rad: c, shape (n,).
        amplitudes_rad: a, shape (K, n); row k−1 is harmonic k.
        phases_rad: φ, shape (K, n).
        period_s: the period S (s).
    """

    def __init__(
        self,
        center_rad: FloatArray,
        amplitudes_rad: FloatArray,
        phases_rad: FloatArray,
        period_s: float,
    ) -> None:
        self.center = np.asarray(center_rad, dtype=np.float64)
        self.amplitudes = np.atleast_2d(np.asarray(amplitudes_rad, dtype=np.float64))
        self.phases = np.atleast_2d(np.asarray(phases_rad, dtype=np.float64))
        self.n = self.center.shape[0]
        if self.center.ndim != 1 or self.amplitudes.shape != self.phases.shape:
            raise InvalidPathError("center must be (n,), amplitudes and phases (K, n)")
        if self.amplitudes.shape[1] != self.n:
            raise InvalidPathError(f"amplitudes must have {self.n} columns")
        if not (np.isfinite(period_s) and period_s > 0):
            raise InvalidPathError(f"period_s must be positive, got {period_s!r}")
        self.period_s = float(period_s)
        k = np.arange(1, self.amplitudes.shape[0] + 1, dtype=np.float64)
        self._omega_k = (2.0 * np.pi / self.period_s) * k[:, None]  # (K, 1)
        self._a_w = self.amplitudes * self._omega_k  # (K, n)
        self._a_w2 = self._a_w * self._omega_k  # (K, n)
        # Scalar hot path: one sine of the stacked arguments [ω_k s + φ; ω_k s + φ + π/2]
        # gives sin and cos, and one product with the stacked coefficients all three sums.
        zeros = np.zeros_like(self.amplitudes)
        self._omega_2k = np.vstack([self._omega_k, self._omega_k])  # (2K, 1)
        self._phase_2k = np.vstack([self.phases, self.phases + 0.5 * np.pi])  # (2K, n)
        self._coef = np.stack(
            [
                np.vstack([self.amplitudes, zeros]),
                np.vstack([zeros, self._a_w]),
                np.vstack([-self._a_w2, zeros]),
            ]
        )  # (3, 2K, n)
        self._offset = np.stack([self.center, np.zeros(self.n), np.zeros(self.n)])  # (3, n)

    def evaluate(self, s: float | FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """See :meth:`ReferencePath.evaluate`."""
        if isinstance(s, float | int) or np.ndim(s) == 0:  # the hot path: one s
            sin_cos = np.sin(self._omega_2k * float(s) + self._phase_2k)  # (2K, n)
            out = (self._coef * sin_cos).sum(axis=1) + self._offset
            return out[0], out[1], out[2]
        arg = self._omega_k * np.asarray(s, dtype=np.float64)[:, None, None] + self.phases
        sin, cos = np.sin(arg), np.cos(arg)  # (m, K, n)
        return (
            self.center + np.sum(self.amplitudes * sin, axis=1),
            np.sum(self._a_w * cos, axis=1),
            -np.sum(self._a_w2 * sin, axis=1),
        )


class SplinePath:
    """A periodic cubic spline through joint samples at s_i = i·S/N, i = 0..N−1.

    q_r is C², so τ_r (which uses q_r'') is continuous. Samples must close the loop
    smoothly: the spline joins the last sample back to the first.
    """

    def __init__(self, samples_rad: FloatArray, period_s: float) -> None:
        samples = np.asarray(samples_rad, dtype=np.float64)
        if samples.ndim != 2 or samples.shape[0] < 4:
            raise InvalidPathError("samples must have shape (N >= 4, n)")
        if not (np.isfinite(period_s) and period_s > 0):
            raise InvalidPathError(f"period_s must be positive, got {period_s!r}")
        self.n = samples.shape[1]
        self.period_s = float(period_s)
        knots = np.linspace(0.0, self.period_s, samples.shape[0] + 1)
        closed = np.vstack([samples, samples[:1]])
        self._q = CubicSpline(knots, closed, bc_type="periodic", axis=0)
        self._qd = self._q.derivative(1)
        self._qdd = self._q.derivative(2)

    def evaluate(self, s: float | FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """See :meth:`ReferencePath.evaluate`."""
        sm = np.mod(s, self.period_s)
        return self._q(sm), self._qd(sm), self._qdd(sm)


# -- path families per robot -------------------------------------------------------


def default_path(spec: RobotSpec, period_s: float | None = None) -> MultiSinePath:
    """The robot's default reference: a fixed two-harmonic Lissajous curve around home.

    Joint j of n moves with amplitude a_j = ``path_amplitude_rad[j]`` and phase πj/n on
    harmonic 1, and a_j/4 with phase πj/n + π/3 on harmonic 2. The spread phases keep
    q_r' away from zero: min M_r / mean M_r is 0.17 (two-link), 0.07 (iiwa) and 0.16
    (Panda). The period defaults to 4 s for the two-link arm and 8 s for 7-joint arms.
    """
    n = spec.n
    period = period_s if period_s is not None else (4.0 if n <= 2 else 8.0)
    amp = np.array(spec.path_amplitude_rad)
    j = np.arange(n)
    amplitudes = np.vstack([amp, amp / 4.0])
    phases = np.vstack([np.pi * j / n, np.pi * j / n + np.pi / 3.0])
    return MultiSinePath(np.array(spec.home_q_rad), amplitudes, phases, period)


def random_multisine(
    spec: RobotSpec,
    rng: np.random.Generator,
    period_range_s: tuple[float, float] = (4.0, 8.0),
    harmonics: int = 2,
    amplitude_scale: tuple[float, float] = (0.5, 1.0),
) -> MultiSinePath:
    """A random Lissajous path around the home pose, drawn from ``rng`` only.

    Harmonic k's amplitude for joint j is ``path_amplitude_rad[j] · u / k`` with u uniform
    in ``amplitude_scale``; phases are uniform in [0, 2π); the period is uniform in
    ``period_range_s``. The total amplitude never exceeds the spec's bound times
    Σ 1/k, which the robot specs keep inside the joint limits; callers should still
    validate with :func:`check_joint_limits` and :class:`PathTables`.
    """
    if harmonics < 1:
        raise InvalidPathError("harmonics must be >= 1")
    k = np.arange(1, harmonics + 1)[:, None]
    amp = np.array(spec.path_amplitude_rad) * rng.uniform(
        *amplitude_scale, size=(harmonics, spec.n)
    )
    phases = rng.uniform(0.0, 2.0 * np.pi, size=(harmonics, spec.n))
    period = float(rng.uniform(*period_range_s))
    return MultiSinePath(np.array(spec.home_q_rad), amp / k, phases, period)


def ee_circle_path(
    spec: RobotSpec,
    center_m: FloatArray,
    radius_m: float,
    normal: FloatArray = (0.0, 1.0, 0.0),
    period_s: float = 6.0,
    n_samples: int = 256,
) -> SplinePath:
    """An end-effector circle converted to a smooth periodic joint path.

    The circle p(θ) = c + r (cos θ u + sin θ v), with (u, v) orthonormal and normal to
    ``normal``, is sampled at ``n_samples`` equal angles; each point is solved for the
    centre of mass of ``spec.ee_link`` by :func:`_position_ik`, warm-started from the
    previous solution. Two laps are solved and the
    second is kept, so the loop closes; a gap at the seam above 1e-3 rad, or an IK
    position error above 1 mm, raises :class:`InvalidPathError`.
    """
    center = np.asarray(center_m, dtype=np.float64)
    nrm = np.asarray(normal, dtype=np.float64)
    nrm = nrm / np.linalg.norm(nrm)
    u = np.cross(nrm, [0.0, 0.0, 1.0] if abs(nrm[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(nrm, u)
    thetas = np.linspace(0.0, 2.0 * np.pi, n_samples, endpoint=False)
    targets = center + radius_m * (np.cos(thetas)[:, None] * u + np.sin(thetas)[:, None] * v)
    home = np.array(spec.home_q_rad)
    with BulletSim() as sim:
        arm = sim.load_arm(spec.urdf_path, spec.joint_names, spec.torque_limits_nm)
        q = home.copy()
        laps: list[list[FloatArray]] = [[], []]
        errors: list[float] = []
        for lap in range(2):
            for target in targets:
                q, err = _position_ik(arm, spec.ee_link, target, q, home)
                laps[lap].append(q)
                if lap == 1:
                    errors.append(err)
    samples = np.array(laps[1])
    if max(errors) > 1e-3:
        raise InvalidPathError(
            f"IK could not reach the circle: worst position error {max(errors):.2e} m "
            f"at sample {int(np.argmax(errors))}"
        )
    # A loop closes when the second lap retraces the first (the IK map is single-valued).
    seam = float(np.max(np.abs(samples - np.array(laps[0]))))
    if seam > 1e-3:
        raise InvalidPathError(
            f"IK solutions do not close the loop (laps differ by {seam:.2e} rad)"
        )
    return SplinePath(samples, period_s)


def _position_ik(
    arm: BulletArm,
    link: str,
    target_m: FloatArray,
    q0: FloatArray,
    rest_q: FloatArray,
    iterations: int = 100,
    damping: float = 1e-6,
    null_gain: float = 0.1,
) -> tuple[FloatArray, float]:
    """Position IK by damped least squares with a null-space pull towards ``rest_q``.

    Iterates q ← q + J⁺ e + (I − J⁺J) k (q_rest − q), J⁺ = Jᵀ(JJᵀ + λ²I)⁻¹, with J the
    translational Jacobian of ``link``'s centre of mass (PyBullet's ``calculateJacobian``)
    and e the position error (m). Returns the solution and its final error (m).
    """
    import pybullet as p

    cid, idx, n = arm.sim.client_id, arm.link_index(link), arm.n
    zeros = [0.0] * n
    q = np.array(q0, dtype=np.float64)
    err = np.inf
    for _ in range(iterations):
        arm.reset_state(q, np.zeros(n))
        pos = np.array(
            p.getLinkState(arm.body_id, idx, computeForwardKinematics=1, physicsClientId=cid)[0]
        )
        e = target_m - pos
        err = float(np.linalg.norm(e))
        jac = np.array(
            p.calculateJacobian(
                arm.body_id, idx, [0.0, 0.0, 0.0], q.tolist(), zeros, zeros, physicsClientId=cid
            )[0]
        )  # (3, n)
        jjt = jac @ jac.T + damping * np.eye(3)
        pinv = jac.T @ np.linalg.solve(jjt, np.eye(3))  # (n, 3)
        null = (np.eye(n) - pinv @ jac) @ (null_gain * (rest_q - q))
        if err < 1e-12:
            break
        q = q + pinv @ e + null
    return q, err


def check_joint_limits(
    path: ReferencePath,
    lower_rad: FloatArray,
    upper_rad: FloatArray,
    margin_rad: float = 0.05,
    grid_size: int = 2048,
) -> None:
    """Raise :class:`InvalidPathError` if q_r(s) comes within ``margin_rad`` of a limit.

    Checked on ``grid_size`` equally spaced values of s over one period; the message
    names the first offending joint and s.
    """
    s = np.linspace(0.0, path.period_s, grid_size, endpoint=False)
    q = path.evaluate(s)[0]
    low = q < np.asarray(lower_rad) + margin_rad
    high = q > np.asarray(upper_rad) - margin_rad
    bad = low | high
    if np.any(bad):
        i, j = np.argwhere(bad)[0]
        side = "lower" if low[i, j] else "upper"
        raise InvalidPathError(
            f"path leaves joint limits: joint {j} reaches q = {q[i, j]:.4f} rad at "
            f"s = {s[i]:.4f} s, within {margin_rad} rad of its {side} limit"
        )


# -- tables ------------------------------------------------------------------------


class PathPoint(NamedTuple):
    """The reference quantities at one value of s (SI units; see the module docstring)."""

    q: FloatArray  # q_r(s), (n,) rad
    qd: FloatArray  # q_r'(s), (n,) rad/s
    tau: FloatArray  # τ_r(s), (n,) N·m
    m_r: float  # M_r(s), J (kg·m²/s²)
    m_r_d: float  # M_r'(s), J/s
    w_r: float  # W_r(s), J
    w_r_d: float  # W_r'(s), J/s


class NearestPoint(NamedTuple):
    """The path point closest to a joint vector."""

    s: float  # the minimising s, in [0, period_s)
    distance: float  # |q − q_r(s)| (rad)


def reference_quantities(path: ReferencePath, model: RobotModel, s: float) -> PathPoint:
    """The :class:`PathPoint` at ``s`` computed exactly from the path and the model."""
    q, qd, qdd = path.evaluate(float(s))
    mass = model.mass_matrix(q)
    tau = model.inverse_dynamics(q, qd, qdd)
    grav = model.gravity(q)
    m_r = float(qd @ mass @ qd)
    return PathPoint(
        q=q,
        qd=qd,
        tau=tau,
        m_r=m_r,
        m_r_d=float(2.0 * qd @ (tau - grav)),
        w_r=-model.potential(q) - 0.5 * m_r,
        w_r_d=float(-qd @ tau),
    )


class PathTables:
    """Reference tables of a path for a model, on a periodic grid, with interpolation.

    Every column (q_r, q_r', τ_r, M_r, M_r', W_r, W_r') is computed exactly at
    ``grid_size`` nodes by :func:`reference_quantities` and interpolated between them
    by one periodic cubic spline (scipy). :meth:`exact` evaluates on line instead.

    Args:
        path: the reference path.
        model: the controller's (nominal) dynamics model.
        grid_size: number of nodes per period.
        beta_abs_j: absolute floor β₀ (J) of M_r.
        beta_rel: relative floor: the path is rejected as stationary where
            M_r(s) < β = max(beta_abs_j, beta_rel · mean M_r).

    Raises:
        InvalidPathError: a path whose M_r dips below β anywhere on the grid (the message
            names the worst s), or a model/path dimension mismatch.
    """

    def __init__(
        self,
        path: ReferencePath,
        model: RobotModel,
        grid_size: int = 2048,
        beta_abs_j: float = 1e-6,
        beta_rel: float = 1e-2,
    ) -> None:
        if path.n != model.n:
            raise InvalidPathError(f"path has {path.n} joints, model has {model.n}")
        if grid_size < 16:
            raise InvalidPathError("grid_size must be >= 16")
        self.path = path
        self.model = model
        self.n = path.n
        self.period_s = path.period_s
        self.grid_s = np.linspace(0.0, self.period_s, grid_size, endpoint=False)
        points = [reference_quantities(path, model, s) for s in self.grid_s]
        columns = np.array(
            [
                np.concatenate([pt.q, pt.qd, pt.tau, [pt.m_r, pt.m_r_d, pt.w_r, pt.w_r_d]])
                for pt in points
            ]
        )  # (N, 3n + 4)
        m_r = columns[:, 3 * self.n]
        self.beta_j = max(beta_abs_j, beta_rel * float(np.mean(m_r)))
        worst = int(np.argmin(m_r))
        if m_r[worst] < self.beta_j:
            raise InvalidPathError(
                f"path is (nearly) stationary: M_r = q_r'ᵀ M q_r' = {m_r[worst]:.3e} J at "
                f"s = {self.grid_s[worst]:.4f} s, below β = {self.beta_j:.3e} J"
            )
        self.grid_q = columns[:, : self.n].copy()  # (N, n)
        self._init_nearest(columns[:, self.n : 2 * self.n])
        knots = np.append(self.grid_s, self.period_s)
        self._spline = CubicSpline(knots, np.vstack([columns, columns[:1]]), bc_type="periodic")
        self.min_m_r = float(m_r[worst])

    def __call__(self, s: float) -> PathPoint:
        """Interpolated reference quantities at ``s`` (any real; wrapped to the period)."""
        return self._point(self._spline(s % self.period_s))

    def pair(self, s1: float, s2: float) -> tuple[PathPoint, PathPoint]:
        """``(self(s1), self(s2))`` with one spline evaluation (the controller's hot path)."""
        v = self._spline(np.mod((s1, s2), self.period_s))
        return self._point(v[0]), self._point(v[1])

    def _point(self, v: FloatArray) -> PathPoint:
        n = self.n
        return PathPoint(
            q=v[:n],
            qd=v[n : 2 * n],
            tau=v[2 * n : 3 * n],
            m_r=float(v[3 * n]),
            m_r_d=float(v[3 * n + 1]),
            w_r=float(v[3 * n + 2]),
            w_r_d=float(v[3 * n + 3]),
        )

    def exact(self, s: float) -> PathPoint:
        """Reference quantities at ``s`` computed on line from the path and model."""
        return reference_quantities(self.path, self.model, s)

    #: Stride of the nearest-point search's coarse stage (grid nodes).
    _STRIDE = 8

    def _init_nearest(self, grid_qd: FloatArray) -> None:
        """Tables of :meth:`nearest`: a wrapped copy of the grid (so the fine window is a
        slice) and, per grid interval j, the cubic Hermite interpolant of q_r through its
        exact end values and slopes, q_r(s_j + t) ≈ q_j + a t + b t² + c t³ for
        t ∈ [0, h], as the coefficients (a, b, c) and their six pairwise dot products."""
        n_grid, stride = len(self.grid_s), self._STRIDE
        h = self.period_s / n_grid
        q0, q1 = self.grid_q, np.roll(self.grid_q, -1, axis=0)
        m0, m1 = h * grid_qd, h * np.roll(grid_qd, -1, axis=0)
        delta = q1 - q0
        a = grid_qd
        b = (3.0 * delta - 2.0 * m0 - m1) / h**2
        c = (m0 + m1 - 2.0 * delta) / h**3
        pairs = ((a, a), (a, b), (a, c), (b, b), (b, c), (c, c))
        self._h = h
        self._grid_wrapped = self.grid_q[np.arange(-stride, n_grid + stride) % n_grid]
        self._coarse_q = np.ascontiguousarray(self.grid_q[::stride])
        self._coarse_sq = np.einsum("ij,ij->i", self._coarse_q, self._coarse_q)
        self._hermite = np.ascontiguousarray(np.stack([a, b, c], axis=1))  # (N, 3, n)
        dots = np.stack([np.einsum("ij,ij->i", x, y) for x, y in pairs], axis=1)
        self._hermite_dots: list[list[float]] = dots.tolist()  # (N, 6)

    def nearest(self, q: FloatArray) -> NearestPoint:
        """The point of the path nearest ``q``: min over s of |q − q_r(s)| (rad).

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

        Cost: two small array searches, one 3×n product and scalar arithmetic. The coarse
        stage can only pick the wrong branch where two parts of the path pass within
        ~8 grid spacings of each other.
        """
        stride, h = self._STRIDE, self._h
        n_grid = len(self.grid_s)
        # |q_i − q|² − |q|² = |q_i|² − 2 q_iᵀq: one product ranks the coarse nodes.
        i = int(np.argmin(self._coarse_sq - 2.0 * (self._coarse_q @ q))) * stride
        fine = self._grid_wrapped[i : i + 2 * stride + 1] - q  # nodes i − 8 … i + 8
        d2 = np.einsum("ij,ij->i", fine, fine)
        k = int(np.argmin(d2))
        j = (i - stride + k) % n_grid
        node_d2 = float(d2[k])
        if float(fine[k] @ self._hermite[j, 0]) <= 0.0:  # (q − q_j)ᵀq_r'(s_j) ≥ 0: ahead
            interval, e0, p0, node_t = j, -fine[k], node_d2, 0.0
        else:
            interval = (j - 1) % n_grid
            e0 = q - self.grid_q[interval]
            p0, node_t = float(e0 @ e0), h
        ea, eb, ec = (self._hermite[interval] @ e0).tolist()
        aa, ab, ac, bb, bc, cc = self._hermite_dots[interval]
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


PathFactory = Callable[[RobotSpec, np.random.Generator], ReferencePath]
