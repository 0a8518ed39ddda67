"""Gains of the classical baseline controllers, their validation, and per-robot defaults.

Every gain is diagonal: a scalar (the same on every joint) or one positive number per
joint. A diagonal gain is positive definite exactly when every entry is positive, and
diagonal Λ and K_D commute, which the Slotine–Li Lyapunov argument needs (Λ K_D must be
symmetric positive definite).

The defaults (:func:`default_computed_torque_gains`, :func:`default_pd_gravity_gains`,
:func:`default_slotine_li_gains`) were chosen by ``bench/baseline_gain_study.py`` for
the env defaults (physics and control at 1 kHz, the robot's default path); the study
and its table are in ``docs/baselines.md``. All three families are parametrised by one
closed-loop bandwidth ω (rad/s) and, where the law has no inertia of its own, scaled
by the joint inertias of the home pose, m = diag M(q_home) (kg·m²):

* computed torque: K_p = ω² I (1/s²), K_d = 2ζω I (1/s) — the error obeys
  ë + K_d ė + K_p e = 0, a double pole at −ω for ζ = 1;
* PD + gravity: K_p = ω² diag(m) (N·m/rad), K_d = 2ζω diag(m) (N·m·s/rad) — the same
  poles for a decoupled arm near home;
* Slotine–Li: Λ = ω I (1/s), K_D = ω diag(m) (N·m·s/rad) — the linearised error obeys
  (s + Λ)(s + M⁻¹K_D) e = 0, a double pole near −ω.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agents.base import FloatArray
from ptrack_gym.errors import InvalidConfigError

#: A diagonal gain: one number for every joint, or one per joint.
Gain = float | tuple[float, ...]

#: diag M(q_home) (kg·m²) of the nominal PyBullet models, rounded to 4 significant
#: digits (``BulletModel(make_robot(name)).mass_matrix(home_q_rad)``; the study prints
#: the unrounded values).
HOME_INERTIA_KGM2: dict[str, tuple[float, ...]] = {
    "two_link": (0.6351, 0.08333),
    "iiwa": (1.765, 2.587, 0.4941, 0.5367, 0.01265, 0.008761, 0.001),
    "panda": (1.558, 2.351, 1.783, 1.651, 0.8305, 0.7371, 0.6),
}


def _check_gain(value: Gain, name: str) -> Gain:
    """Return ``value`` as a float or a tuple of floats, all finite and > 0, or raise."""
    arr = np.asarray(value, dtype=np.float64)
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


def gain_vector(value: Gain, n: int, name: str) -> FloatArray:
    """The diagonal of a gain for ``n`` joints, shape (n,); a scalar is broadcast.

    Raises:
        InvalidConfigError: (a ``ValueError``) a non-positive or non-finite entry, or a
            sequence whose length is not ``n``.
    """
    checked = _check_gain(value, name)
    arr = np.asarray(checked, dtype=np.float64)
    if arr.ndim == 0:
        return np.full(n, float(arr))
    if arr.shape != (n,):
        raise InvalidConfigError(
            f"{name} must be a scalar or have one entry per joint ({n}), got {arr.shape[0]}"
        )
    return arr.copy()


def _inertia(robot_name: str) -> FloatArray:
    try:
        return np.array(HOME_INERTIA_KGM2[robot_name])
    except KeyError:
        raise InvalidConfigError(
            f"no default gains for robot {robot_name!r}; known: {sorted(HOME_INERTIA_KGM2)}"
        ) from None


def _rounded(x: FloatArray) -> tuple[float, ...]:
    """Four significant digits, so the defaults read as plain numbers."""
    return tuple(float(f"{v:.4g}") for v in x)


@dataclass(frozen=True)
class ComputedTorqueGains:
    """Gains of :class:`~agents.computed_torque.ComputedTorqueController`.

    Attributes:
        kp_1_s2: K_p (1/s²), the stiffness of the error dynamics ë + K_d ė + K_p e = 0.
        kd_1_s: K_d (1/s), its damping.
    """

    kp_1_s2: Gain
    kd_1_s: Gain

    def __post_init__(self) -> None:
        object.__setattr__(self, "kp_1_s2", _check_gain(self.kp_1_s2, "kp_1_s2"))
        object.__setattr__(self, "kd_1_s", _check_gain(self.kd_1_s, "kd_1_s"))

    @classmethod
    def from_bandwidth(cls, omega_rad_s: float, zeta: float = 1.0) -> ComputedTorqueGains:
        """K_p = ω², K_d = 2ζω on every joint."""
        return cls(kp_1_s2=omega_rad_s**2, kd_1_s=2.0 * zeta * omega_rad_s)


@dataclass(frozen=True)
class PDGravityGains:
    """Gains of :class:`~agents.pd_gravity.PDGravityController`.

    Attributes:
        kp_nm_rad: K_p (N·m/rad).
        kd_nms_rad: K_d (N·m·s/rad).
    """

    kp_nm_rad: Gain
    kd_nms_rad: Gain

    def __post_init__(self) -> None:
        object.__setattr__(self, "kp_nm_rad", _check_gain(self.kp_nm_rad, "kp_nm_rad"))
        object.__setattr__(self, "kd_nms_rad", _check_gain(self.kd_nms_rad, "kd_nms_rad"))

    @classmethod
    def from_inertia(
        cls, inertia_kgm2: FloatArray, omega_rad_s: float, zeta: float = 1.0
    ) -> PDGravityGains:
        """K_p = ω² m, K_d = 2ζω m, with m the joint inertias (kg·m²), e.g. diag M(q_home)."""
        m = np.asarray(inertia_kgm2, dtype=np.float64)
        return cls(
            kp_nm_rad=_rounded(omega_rad_s**2 * m),
            kd_nms_rad=_rounded(2.0 * zeta * omega_rad_s * m),
        )


@dataclass(frozen=True)
class SlotineLiGains:
    """Gains of :class:`~agents.slotine_li.SlotineLiController`.

    Attributes:
        lambda_1_s: Λ (1/s), the sliding-surface slope: r = ė + Λ e.
        kd_nms_rad: K_D (N·m·s/rad), the damping injected on r.
    """

    lambda_1_s: Gain
    kd_nms_rad: Gain

    def __post_init__(self) -> None:
        object.__setattr__(self, "lambda_1_s", _check_gain(self.lambda_1_s, "lambda_1_s"))
        object.__setattr__(self, "kd_nms_rad", _check_gain(self.kd_nms_rad, "kd_nms_rad"))

    @classmethod
    def from_inertia(cls, inertia_kgm2: FloatArray, omega_rad_s: float) -> SlotineLiGains:
        """Λ = ω, K_D = ω m, with m the joint inertias (kg·m²): a double pole near −ω."""
        m = np.asarray(inertia_kgm2, dtype=np.float64)
        return cls(lambda_1_s=float(omega_rad_s), kd_nms_rad=_rounded(omega_rad_s * m))


#: Default closed-loop bandwidths ω (rad/s) per controller and robot, from the study: the
#: largest ω of the sweep (5, 7, 10, 14, 20, 28, 40) at which no run, from rest 0.1 rad
#: off the path at four start phases, clips a torque. The answer is the same for the three
#: controllers. The Panda's wrist (12 N·m limits against 0.6–0.83 kg·m² of URDF inertia)
#: holds it at 7 rad/s.
DEFAULT_BANDWIDTH_RAD_S: dict[str, dict[str, float]] = {
    "computed_torque": {"two_link": 20.0, "iiwa": 20.0, "panda": 7.0},
    "pd_gravity": {"two_link": 20.0, "iiwa": 20.0, "panda": 7.0},
    "slotine_li": {"two_link": 20.0, "iiwa": 20.0, "panda": 7.0},
}


def default_computed_torque_gains(robot_name: str) -> ComputedTorqueGains:
    """The study's computed-torque gains for ``robot_name`` ("two_link", "iiwa", "panda")."""
    _inertia(robot_name)  # validates the name
    omega = DEFAULT_BANDWIDTH_RAD_S["computed_torque"][robot_name]
    return ComputedTorqueGains.from_bandwidth(omega)


def default_pd_gravity_gains(robot_name: str) -> PDGravityGains:
    """The study's PD + gravity gains for ``robot_name`` ("two_link", "iiwa", "panda")."""
    m = _inertia(robot_name)
    return PDGravityGains.from_inertia(m, DEFAULT_BANDWIDTH_RAD_S["pd_gravity"][robot_name])


def default_slotine_li_gains(robot_name: str) -> SlotineLiGains:
    """The study's Slotine–Li gains for ``robot_name`` ("two_link", "iiwa", "panda")."""
    m = _inertia(robot_name)
    return SlotineLiGains.from_inertia(m, DEFAULT_BANDWIDTH_RAD_S["slotine_li"][robot_name])
