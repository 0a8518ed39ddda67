"""Periodic reference paths q_r(s), their families and limit checks.

The path parameter ``s`` is measured in seconds: a controller that tracks the path at
nominal speed has ṡ = 1, and the path repeats with period ``period_s``.

Paths (each implements :class:`ReferencePath`):

* :class:`MultiSinePath` — joint-space multi-sine (Lissajous) curves, analytic
  derivatives; :func:`default_path` and :func:`random_multisine` build them per robot;
* :class:`SplinePath` — a periodic cubic spline through samples, e.g.
  :func:`ee_circle_path`, an end-effector circle converted to joints by IK on a grid.

:class:`~ptrack_gym.projection.PathProjector` (in :mod:`ptrack_gym.projection`, re-exported
here) finds the point of a path nearest a joint vector (the *path distance* of the reward
and the metrics); it needs the path only, no dynamics model.
Everything a particular controller needs from a path (the passivity controller's tables
of M_r, W_r, τ_r) is built by that controller, in ``agents``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np
from scipy.interpolate import CubicSpline

from ptrack_gym.errors import InvalidPathError
from ptrack_gym.kernels import path as path_kernels
from ptrack_gym.robots.profile import EECircle, FloatArray, RobotProfile


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
        for name, arr in (("center", self.center), ("amplitudes", self.amplitudes)):
            if not np.all(np.isfinite(arr)):
                raise InvalidPathError(f"{name} must be finite")
        if not np.all(np.isfinite(self.phases)):
            raise InvalidPathError("phases must be finite")
        if not (np.isfinite(period_s) and period_s > 0):
            raise InvalidPathError(f"period_s must be positive, got {period_s!r}")
        self.period_s = float(period_s)
        k = np.arange(1, self.amplitudes.shape[0] + 1, dtype=np.float64)
        self.omega_k = (2.0 * np.pi / self.period_s) * k  # (K,) rad/s
        self._omega_k = self.omega_k[:, None]  # (K, 1)
        self._a_w = self.amplitudes * self._omega_k  # (K, n)
        self._a_w2 = self._a_w * self._omega_k  # (K, n)
        self._kernel = self.kernel_data()

    @property
    def cache_key(self) -> tuple[object, ...]:
        """Equal keys, equal paths (for caches of path-derived tables)."""
        return (
            "multisine", self.center.tobytes(), self.amplitudes.tobytes(),
            self.phases.tobytes(), self.amplitudes.shape, self.period_s,
        )  # fmt: skip

    def kernel_data(self) -> path_kernels.PathKernelData:
        """This path in the compiled kernels' terms (:mod:`ptrack_gym.kernels.path`)."""
        return path_kernels.multisine_data(
            self.center, self.amplitudes, self.phases, self.omega_k, self.period_s
        )

    def evaluate(self, s: float | FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """See :meth:`ReferencePath.evaluate`. A scalar s runs the compiled kernel
        (:func:`ptrack_gym.kernels.path.eval_path`); an array of s the numpy formula of the
        class docstring, its readable twin."""
        if type(s) is float or np.ndim(s) == 0:  # the type test first: the hot path
            return _eval_scalar(self._kernel, float(s), self.n)
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
        if not np.all(np.isfinite(samples)):
            raise InvalidPathError("samples must be finite")
        if not (np.isfinite(period_s) and period_s > 0):
            raise InvalidPathError(f"period_s must be positive, got {period_s!r}")
        self.n = samples.shape[1]
        self.period_s = float(period_s)
        self.knots = np.linspace(0.0, self.period_s, samples.shape[0] + 1)
        closed = np.vstack([samples, samples[:1]])
        self.cache_key = ("spline", samples.tobytes(), samples.shape, self.period_s)
        """Equal keys, equal paths (for caches of path-derived tables)."""
        self._q = CubicSpline(self.knots, closed, bc_type="periodic", axis=0)
        self._qd = self._q.derivative(1)
        self._qdd = self._q.derivative(2)
        self._kernel = self.kernel_data()

    @property
    def coefficients(self) -> FloatArray:
        """Polynomial coefficients (4, N, n) of q_r on each knot interval: highest power
        first, in the local variable s − knots[i] (scipy's ``PPoly`` layout)."""
        return self._q.c

    def kernel_data(self) -> path_kernels.PathKernelData:
        """This path in the compiled kernels' terms (:mod:`ptrack_gym.kernels.path`)."""
        return path_kernels.piecewise_cubic_data(self.knots, self._q.c, self.period_s)

    def evaluate(self, s: float | FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """See :meth:`ReferencePath.evaluate`. A scalar s runs the compiled kernel
        (:func:`ptrack_gym.kernels.path.eval_path`); an array of s scipy's spline, its
        readable twin."""
        if type(s) is float or np.ndim(s) == 0:  # the type test first: the hot path
            return _eval_scalar(self._kernel, float(s), self.n)
        sm = np.mod(s, self.period_s)
        return self._q(sm), self._qd(sm), self._qdd(sm)


def _eval_scalar(
    data: path_kernels.PathKernelData, s: float, n: int
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """q_r(s), q_r'(s), q_r''(s) of a path's kernel data at one s (fresh arrays)."""
    q, qd, qdd = np.empty(n), np.empty(n), np.empty(n)
    path_kernels.eval_path(*data, s, q, qd, qdd)
    return q, qd, qdd


# -- path families per robot -------------------------------------------------------


def default_path(profile: RobotProfile, period_s: float | None = None) -> MultiSinePath:
    """The robot's default reference: a fixed two-harmonic Lissajous curve around home.

    Joint j of n moves with amplitude a_j = ``path_amplitude_rad[j]`` and phase πj/n on
    harmonic 1, and a_j/4 with phase πj/n + π/3 on harmonic 2. The spread phases keep
    q_r' away from zero. The period defaults to the profile's ``path_period_s``.
    """
    n = profile.n
    period = period_s if period_s is not None else profile.path_period_s
    amp = np.array(profile.path_amplitude_rad)
    j = np.arange(n)
    amplitudes = np.vstack([amp, amp / 4.0])
    phases = np.vstack([np.pi * j / n, np.pi * j / n + np.pi / 3.0])
    return MultiSinePath(profile.home(), amplitudes, phases, period)


#: A random path is kept only if its speed never falls below this fraction of its mean.
MIN_SPEED_FRACTION = 0.05


def min_speed_fraction(
    path: ReferencePath,
    metric: Callable[[FloatArray], FloatArray] | None = None,
    grid_size: int = 1024,
) -> float:
    """min_s v(s)² / mean_s v(s)² over one period, v² = q_r'ᵀ W(q_r) q_r' with the metric
    W (e.g. a model's mass matrix, which makes v² the path's M_r(s)) or the identity."""
    s = np.linspace(0.0, path.period_s, grid_size, endpoint=False)
    q, qd, _ = path.evaluate(s)
    if metric is None:
        speed2 = np.einsum("ij,ij->i", qd, qd)
    else:
        speed2 = np.array([v @ metric(qk) @ v for qk, v in zip(q, qd, strict=True)])
    mean = float(np.mean(speed2))
    return float(np.min(speed2)) / mean if mean > 0 else 0.0


def random_multisine(
    profile: RobotProfile,
    rng: np.random.Generator,
    period_range_s: tuple[float, float] = (4.0, 8.0),
    harmonics: int = 2,
    amplitude_scale: tuple[float, float] = (0.5, 1.0),
    metric: Callable[[FloatArray], FloatArray] | None = None,
    max_draws: int = 1000,
) -> MultiSinePath:
    """A random *admissible* Lissajous path around the home pose, drawn from ``rng`` only.

    One draw: harmonic k's amplitude for joint j is ``path_amplitude_rad[j] · u / k`` with u
    uniform in ``amplitude_scale``; phases are uniform in [0, 2π); the period is uniform in
    ``period_range_s``. Draws are repeated (from the same stream, so a seed always gives the
    same path) until one is admissible: it keeps :func:`check_joint_limits`' margin and its
    speed never falls below :data:`MIN_SPEED_FRACTION` of its mean (:func:`min_speed_fraction`
    in ``metric``, e.g. the robot's mass matrix, so that M_r(s) is bounded away from 0).

    Raises:
        InvalidPathError: no admissible path in ``max_draws`` draws.
    """
    if harmonics < 1:
        raise InvalidPathError("harmonics must be >= 1")
    k = np.arange(1, harmonics + 1)[:, None]
    lower, upper = profile.limits()
    for _ in range(max_draws):
        amp = np.array(profile.path_amplitude_rad) * rng.uniform(
            *amplitude_scale, size=(harmonics, profile.n)
        )
        phases = rng.uniform(0.0, 2.0 * np.pi, size=(harmonics, profile.n))
        period = float(rng.uniform(*period_range_s))
        path = MultiSinePath(profile.home(), amp / k, phases, period)
        if within_joint_limits(path, lower, upper) and (
            min_speed_fraction(path, metric) >= MIN_SPEED_FRACTION
        ):
            return path
    raise InvalidPathError(f"no admissible random path for {profile.name} in {max_draws} draws")


def ee_circle_path(
    profile: RobotProfile, circle: EECircle | None = None, n_samples: int = 256
) -> SplinePath:
    """An end-effector circle converted to a smooth periodic joint path.

    The circle p(θ) = c + r (cos θ u + sin θ v), with (u, v) orthonormal and normal to the
    circle's normal (default: the profile's ``circle``), is sampled at ``n_samples`` equal
    angles; each point is solved for the centre of mass of ``profile.ee_link`` by
    :meth:`~ptrack_gym.sim.BulletArm.position_ik`, warm-started from the previous
    solution. Two laps are solved and the second is kept, so the loop closes; a gap at
    the seam above 1e-3 rad, or an IK position error above 1 mm, raises
    :class:`InvalidPathError`.
    """
    from ptrack_gym.sim import BulletSim  # PyBullet's IK, only for this family

    c = circle or profile.circle
    center = np.asarray(c.center_m, dtype=np.float64)
    nrm = np.asarray(c.normal, dtype=np.float64)
    nrm = nrm / np.linalg.norm(nrm)
    u = np.cross(nrm, [0.0, 0.0, 1.0] if abs(nrm[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(nrm, u)
    thetas = np.linspace(0.0, 2.0 * np.pi, n_samples, endpoint=False)
    targets = center + c.radius_m * (np.cos(thetas)[:, None] * u + np.sin(thetas)[:, None] * v)
    home = profile.home()
    with BulletSim() as sim:
        arm = sim.load_arm(profile.urdf_path, profile.joint_names, profile.torque_limits_nm)
        q = home.copy()
        laps: list[list[FloatArray]] = [[], []]
        errors: list[float] = []
        for lap in range(2):
            for target in targets:
                q, err = arm.position_ik(profile.ee_link, target, q, home)
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
    return SplinePath(samples, c.period_s)


#: The path families an env can be asked for by name.
PATH_FAMILIES: tuple[str, ...] = ("default", "circle", "random")


def make_path(
    path: str | ReferencePath,
    profile: RobotProfile,
    path_seed: int | None = None,
    metric: Callable[[FloatArray], FloatArray] | None = None,
) -> ReferencePath:
    """The path ``path`` names for a robot (a :data:`PATH_FAMILIES` name, or a
    :class:`ReferencePath`, returned as is); ``path_seed`` seeds ``"random"``, ``metric``
    is its speed metric (:func:`random_multisine`)."""
    if not isinstance(path, str):
        return path
    if path == "default":
        return default_path(profile)
    if path == "random":
        return random_multisine(profile, np.random.default_rng(path_seed), metric=metric)
    if path == "circle":
        return ee_circle_path(profile)
    raise InvalidPathError(f"path must be one of {PATH_FAMILIES} or a ReferencePath, got {path!r}")


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


def within_joint_limits(path: ReferencePath, lower_rad: FloatArray, upper_rad: FloatArray) -> bool:
    """Whether :func:`check_joint_limits` accepts ``path``."""
    try:
        check_joint_limits(path, lower_rad, upper_rad)
    except InvalidPathError:
        return False
    return True


# The projector lives in its own module; re-exported for ``from ptrack_gym.paths import
# PathProjector`` (placed last: ptrack_gym.projection imports this module's names lazily).
from ptrack_gym.projection import NearestPoint, PathProjector  # noqa: E402, F401
