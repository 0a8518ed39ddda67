"""The passivity controller's reference tables of a path for a dynamics model.

:class:`PassivityTables` tabulates, for a path and a :class:`~ptrack_gym.robots.RobotModel`,
every quantity of ``docs/control_law.md`` from the path and inverse dynamics — no finite
differences:

.. math::

    M_r = q_r'^T M(q_r) q_r', \\quad \\tau_r = M(q_r) q_r'' + C(q_r, q_r') q_r' + g(q_r),
    \\quad W_r = -U(q_r) - \\tfrac12 M_r,

    W_r' = -q_r'^T \\tau_r, \\quad M_r' = 2 q_r'^T (\\tau_r - g(q_r)).

The law needs M_r(s) ≥ β > 0 (a non-stationary path); the tables refuse a path that
violates it, naming the worst s. :func:`passivity_tables` caches the tables per (path,
model), so many controllers on one env share them.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Hashable
from typing import NamedTuple

import numpy as np
from scipy.interpolate import CubicSpline

from agents.base import FloatArray
from ptrack_gym.errors import InvalidPathError
from ptrack_gym.paths import ReferencePath
from ptrack_gym.projection import PathProjector
from ptrack_gym.robots.model import RobotModel


class PathPoint(NamedTuple):
    """The reference quantities at one value of s (SI units; see the module docstring)."""

    q: FloatArray  # q_r(s), (n,) rad
    qd: FloatArray  # q_r'(s), (n,) rad/s
    tau: FloatArray  # τ_r(s), (n,) N·m
    m_r: float  # M_r(s), J (kg·m²/s²)
    m_r_d: float  # M_r'(s), J/s
    w_r: float  # W_r(s), J
    w_r_d: float  # W_r'(s), J/s


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


class PassivityTables:
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
        if grid_size < 32:
            raise InvalidPathError("grid_size must be >= 32")
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
        self.mean_m_r = float(np.mean(m_r))
        self.beta_j = max(beta_abs_j, beta_rel * self.mean_m_r)
        worst = int(np.argmin(m_r))
        if m_r[worst] < self.beta_j:
            raise InvalidPathError(
                f"path is (nearly) stationary: M_r = q_r'ᵀ M q_r' = {m_r[worst]:.3e} J at "
                f"s = {self.grid_s[worst]:.4f} s, below β = {self.beta_j:.3e} J"
            )
        self.min_m_r = float(m_r[worst])
        self.columns = columns
        self.knots = np.append(self.grid_s, self.period_s)
        self._spline = CubicSpline(
            self.knots, np.vstack([columns, columns[:1]]), bc_type="periodic"
        )
        self.coefficients: FloatArray = self._spline.c
        """The spline's coefficients (4, N, 3n + 4) on ``knots`` (scipy's ``PPoly`` layout),
        for the compiled law (:mod:`agents.passivity_kernel`)."""
        self.projector = PathProjector(path, grid_size)

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

    def q_samples(self, count: int = 64) -> FloatArray:
        """q_r at ``count`` evenly spaced values of s over one period, (count, n) (rad)."""
        step = max(1, len(self.grid_s) // count)
        return self.columns[::step, : self.n].copy()

    def exact(self, s: float) -> PathPoint:
        """Reference quantities at ``s`` computed on line from the path and model."""
        return reference_quantities(self.path, self.model, s)


#: Tables kept by :func:`passivity_tables` (least recently used first).
_CACHE: OrderedDict[tuple[Hashable, Hashable], PassivityTables] = OrderedDict()
_CACHE_SIZE = 16


def passivity_tables(path: ReferencePath, model: RobotModel) -> PassivityTables:
    """The default-grid :class:`PassivityTables` of (path, model), shared (they are read-only
    after construction): many controllers on one env, or on equal envs, build them once.

    Shared by content: a path and a model with a ``cache_key`` (the package's paths and
    :class:`~ptrack_gym.robots.PinocchioModel`; equal keys mean equal values) hit the last
    16 tables built; anything else gets tables of its own.
    """
    key = (getattr(path, "cache_key", None), getattr(model, "cache_key", None))
    if None in key:
        return PassivityTables(path, model)
    tables = _CACHE.get(key)
    if tables is None:
        tables = _CACHE[key] = PassivityTables(path, model)
        if len(_CACHE) > _CACHE_SIZE:
            _CACHE.popitem(last=False)
    _CACHE.move_to_end(key)
    return tables
