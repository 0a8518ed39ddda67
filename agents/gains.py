"""Gain helpers shared by the controllers: diagonal gains, and the control-rate cap.

Every classical gain here is diagonal: a scalar (the same on every joint) or one positive
number per joint. A diagonal gain is positive definite exactly when every entry is
positive, and diagonal Λ and K_D commute, which the Slotine–Li Lyapunov argument needs.

Default gains are stated as rates (a closed-loop bandwidth ω in rad/s, …) in each robot's
profile (``ptrack_gym/robots/<name>.py``, ``controller_gains``) and made absolute by each
controller's ``default_gains`` with the robot's home-pose joint inertias. Default and tuned
gains are *rate-aware*, in two steps: no joint's natural frequency √(K_j / M_jj(home)) may
exceed :data:`MAX_FREQUENCY_PER_SAMPLE` · f_control (:func:`cap_stiffness`); and, where a
gain acts through the coupled arm (a stiffness or damping scaled by the home inertias and
applied without M(q)), its fastest coupled mode on the path may turn at most
:data:`MAX_MODE_ANGLE_PER_SAMPLE` rad and damp at most :data:`MAX_DAMPING_PER_SAMPLE` per
control sample (:func:`max_mode_frequency`, :func:`cap_coupled_bandwidth`): the coupled
modes of a folded arm or a light wrist run faster than the per-joint estimate, and a
zero-order hold loses its continuous-time margin there.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from agents.base import ControlContext, FloatArray
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.paths import ReferencePath
from ptrack_gym.robots.model import RobotModel, home_inertia_kgm2

#: A diagonal gain: one number for every joint, or one per joint.
Gain = float | tuple[float, ...]

#: α: the largest natural frequency of a joint's closed loop a default gain may give,
#: in rad per control sample (ω_j · dt ≤ α).
MAX_FREQUENCY_PER_SAMPLE = 0.2
#: The largest frequency of a stiffness's *coupled* modes, √λ_max(M(q)⁻¹K) on the path, a
#: default gain may give, in rad per control sample: the per-joint cap above reads the
#: diagonal of M at home, and the coupled modes of a light wrist or of a folded arm run
#: faster (:func:`max_mode_frequency`).
MAX_MODE_ANGLE_PER_SAMPLE = 0.8
#: The largest damping per control sample δ = λ_max(M(q)⁻¹ D) dt of a velocity feedback D
#: a default or tuned gain may give on the path: held over dt, the feedback scales the
#: velocity by 1 − δ per step — flipping its sign, still decaying, beyond δ = 1, growing
#: beyond δ = 2 — and the cap keeps 80% of that bound.
MAX_DAMPING_PER_SAMPLE = 1.6


def check_gain(value: Gain, name: str) -> Gain:
    """Return ``value`` as a float or a tuple of floats, all finite and > 0, or raise
    :class:`InvalidConfigError` naming ``name``."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidConfigError(f"{name} must be numbers, got {value!r}") from None
    if arr.ndim > 1 or arr.size == 0:
        raise InvalidConfigError(
            f"{name} must be a positive number or a sequence of positive numbers (one per "
            f"joint), got shape {arr.shape}"
        )
    if not (np.all(np.isfinite(arr)) and np.all(arr > 0.0)):
        raise InvalidConfigError(
            f"{name} must be positive definite: every diagonal entry finite and > 0, "
            f"got {arr.tolist()}"
        )
    return float(arr) if arr.ndim == 0 else tuple(float(x) for x in arr)


@dataclass(frozen=True)
class DiagonalGains:
    """The base of the classical baselines' gains dataclasses: every field is a diagonal
    :data:`Gain`, checked by :func:`check_gain` at construction and stored as a float or a
    tuple of floats."""

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            object.__setattr__(self, field.name, check_gain(getattr(self, field.name), field.name))


def gain_vector(value: Gain, n: int, name: str) -> FloatArray:
    """The diagonal of a gain for ``n`` joints, shape (n,); a scalar is broadcast.

    Raises:
        InvalidConfigError: (a ``ValueError``) a non-positive or non-finite entry, or a
            sequence whose length is not ``n``.
    """
    arr = np.asarray(check_gain(value, name), dtype=np.float64)
    if arr.ndim == 0:
        return np.full(n, float(arr))
    if arr.shape != (n,):
        raise InvalidConfigError(
            f"{name} must be a scalar or have one entry per joint ({n}), got {arr.shape[0]}"
        )
    return arr.copy()


def cap_stiffness(stiffness: FloatArray, inertia_kgm2: FloatArray, dt_s: float) -> FloatArray:
    """K_j limited to (α / dt)² · M_jj: the joint's natural frequency √(K_j / M_jj) stays
    ≤ α / dt (rad/s), α = :data:`MAX_FREQUENCY_PER_SAMPLE`, dt the control period (s).

    ``stiffness`` (N·m/rad, or 1/s² per unit inertia with ``inertia_kgm2`` = 1)."""
    if not (np.isfinite(dt_s) and dt_s > 0):
        raise InvalidConfigError(f"the control period must be positive, got {dt_s!r}")
    limit = (MAX_FREQUENCY_PER_SAMPLE / dt_s) ** 2 * np.asarray(inertia_kgm2, dtype=np.float64)
    return np.minimum(np.asarray(stiffness, dtype=np.float64), limit)


def max_mode_frequency(model: RobotModel, q_samples: FloatArray, stiffness: FloatArray) -> float:
    """ω_max = max over the configurations q_k (rows of ``q_samples``, rad) of
    √λ_max(M(q_k)⁻¹ K), K = diag(``stiffness``) (N·m/rad): the frequency (rad/s) of the
    fastest mode of the arm held by the springs K alone. It exceeds max_j √(K_j / M_jj) by
    the inertial coupling (λ_max of K^½ M⁻¹ K^½, a symmetric matrix)."""
    root = np.sqrt(np.asarray(stiffness, dtype=np.float64))
    mats = np.array([np.linalg.inv(model.mass_matrix(q)) for q in np.atleast_2d(q_samples)])
    scaled = root[None, :, None] * mats * root[None, None, :]
    return float(np.sqrt(max(np.linalg.eigvalsh(scaled)[:, -1].max(), 0.0)))


def spring_modes(
    model: RobotModel, q_samples: FloatArray, stiffness: FloatArray, damping: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The modes of the arm held by diagonal springs K = diag(``stiffness``) (N·m/rad) and
    dampers D = diag(``damping``) (N·m·s/rad) alone, M(q_k) ë + D ė + K e = 0, frozen at
    each configuration q_k (rows of ``q_samples``, rad): for each eigenvalue λ of
    [[0, I], [−M⁻¹K, −M⁻¹D]], its natural frequency |λ| (rad/s) and damping ratio
    −Re λ / |λ| (1 for a real, overdamped λ). Returns two (count, 2n) arrays (frequency,
    damping ratio), a mode's two conjugate eigenvalues both listed."""
    k = np.diag(np.asarray(stiffness, dtype=np.float64))
    d = np.diag(np.asarray(damping, dtype=np.float64))
    n = k.shape[0]
    freq, ratio = [], []
    for q in np.atleast_2d(q_samples):
        m = model.mass_matrix(q)
        a = np.block(
            [[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(m, k), -np.linalg.solve(m, d)]]
        )
        lam = np.linalg.eigvals(a)
        mag = np.abs(lam)
        freq.append(mag)
        ratio.append(
            np.where(
                np.abs(lam.imag) > 1e-12 * np.maximum(mag, 1.0),
                -lam.real / np.maximum(mag, 1e-300),
                1.0,
            )
        )
    return np.array(freq), np.array(ratio)


def path_samples(path: ReferencePath, count: int = 64) -> FloatArray:
    """q_r at ``count`` evenly spaced s over one period of ``path``, (count, n) (rad)."""
    return path.evaluate(np.linspace(0.0, path.period_s, count, endpoint=False))[0]


def coupling_ratio(model: RobotModel, path: ReferencePath, inertia_kgm2: FloatArray) -> float:
    """max over the path of λ_max(M(q_r(s))⁻¹ diag(``inertia_kgm2``)): how much faster a
    gain scaled by those inertias (e.g. the home pose's) and applied without M(q) acts on
    the coupled arm than on each joint alone (the square of :func:`max_mode_frequency`'s
    factor)."""
    return max_mode_frequency(model, path_samples(path), inertia_kgm2) ** 2


def cap_coupled_bandwidth(
    omega_rad_s: float, dt_s: float, stiffness_gain: float, damping_gain: float
) -> float:
    """ω limited so that the fastest coupled mode of a gain family on the path stays inside
    the per-sample limits: θ = ω dt √``stiffness_gain`` ≤ :data:`MAX_MODE_ANGLE_PER_SAMPLE`
    and δ = ω dt ``damping_gain`` ≤ :data:`MAX_DAMPING_PER_SAMPLE`, where the family's
    position feedback is ω² times a matrix whose largest λ(M⁻¹·) on the path is
    ``stiffness_gain`` and its velocity feedback ω times one with ``damping_gain``
    (:func:`max_mode_frequency`)."""
    limit = min(
        MAX_MODE_ANGLE_PER_SAMPLE / (dt_s * np.sqrt(stiffness_gain)),
        MAX_DAMPING_PER_SAMPLE / (dt_s * damping_gain),
    )
    return float(min(omega_rad_s, limit))


def home_inertia_bandwidth(
    ctx: ControlContext,
    omega_rad_s: float,
    stiffness_per_ratio: float,
    damping_per_ratio: float,
    damping_offset: float = 0.0,
) -> tuple[FloatArray, float]:
    """(m, ω'): the home-pose joint inertias m = diag M(q_home) (kg·m², (n,)) of the
    context's model and ω (rad/s) capped for the context's control period dt: first at α / dt
    (:func:`cap_bandwidth`), then (:func:`cap_coupled_bandwidth`) for a gain family scaled
    by m and applied without M(q), whose stiffness gain is a ρ and damping gain b₀ + b ρ
    (a = ``stiffness_per_ratio``, b = ``damping_per_ratio``, b₀ = ``damping_offset``), with
    ρ = :func:`coupling_ratio` of m on the context's path."""
    inertia = home_inertia_kgm2(ctx.model, ctx.profile)
    ratio = coupling_ratio(ctx.model, ctx.path, inertia)
    omega = cap_coupled_bandwidth(
        cap_bandwidth(omega_rad_s, ctx.dt_s),
        ctx.dt_s,
        stiffness_per_ratio * ratio,
        damping_offset + damping_per_ratio * ratio,
    )
    return inertia, omega


def cap_bandwidth(omega_rad_s: float, dt_s: float) -> float:
    """ω limited to α / dt (rad/s) (see :func:`cap_stiffness`)."""
    if not (np.isfinite(dt_s) and dt_s > 0):
        raise InvalidConfigError(f"the control period must be positive, got {dt_s!r}")
    return float(min(omega_rad_s, MAX_FREQUENCY_PER_SAMPLE / dt_s))


def rounded(x: FloatArray) -> tuple[float, ...]:
    """Four significant digits, so the defaults read as plain numbers."""
    return tuple(float(f"{v:.4g}") for v in x)


def rates(
    defaults: dict[str, Any],
    given: object,
    controller: str,
    robot: object = None,
) -> dict[str, Any]:
    """A controller's rates: its generic ``defaults``, updated by the ``robot``'s profile
    entry, updated by ``given`` (e.g. tuned rates, which override only what they name);
    an unknown rate name raises :class:`InvalidConfigError`."""
    layers = [dict(robot or {}), dict(given or {})]  # type: ignore[call-overload]
    for layer in layers:
        unknown = sorted(set(layer) - set(defaults))
        if unknown:
            raise InvalidConfigError(
                f"unknown {controller} gain rate(s) {unknown}; known: {sorted(defaults)}"
            )
    return {**defaults, **layers[0], **layers[1]}
