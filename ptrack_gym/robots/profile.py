"""Everything the package knows about one robot: a frozen :class:`RobotProfile`.

A profile is data only. The simulated arm (:class:`ptrack_gym.sim.BulletArm`) and the
controllers' dynamics model (:mod:`ptrack_gym.robots.model`) are both built from it,
separately, so that the plant can be perturbed while the model stays nominal. Quantities a
model can compute (home-pose inertias, the path's mean M_r) are never stored here: they are
computed where they are needed.

Each robot lives in one file of this package, ``ptrack_gym/robots/<name>.py``, which
defines ``PROFILE``; :data:`ptrack_gym.robots.ROBOT_MODULES` lists the files.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import tempfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ptrack_gym.errors import InvalidConfigError

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class EECircle:
    """An end-effector circle (``path="circle"``): centre (m), radius (m), the circle's
    normal (world frame) and its period (s)."""

    center_m: tuple[float, float, float]
    radius_m: float
    normal: tuple[float, float, float]
    period_s: float = 6.0


@dataclass(frozen=True)
class DisturbanceScales:
    """What level 1 of the disturbance presets means for this robot.

    Attributes:
        impulse_j: kinetic energy (J) an ``impulse`` gives the arm at rest at home.
        push_n: force (N) of a ``push`` at the end effector.
        payload_kg: mass (kg) of the ``payload`` picked up at the end effector.
        mismatch_links: links whose mass and inertia the ``mismatch`` preset scales.
    """

    impulse_j: float
    push_n: float
    payload_kg: float
    mismatch_links: tuple[str, ...]


@dataclass(frozen=True, eq=False)
class RobotProfile:
    """A fixed-base, fully actuated arm and the benchmark's settings for it.

    Attributes:
        name: short identifier (``"iiwa"``); the key of ``ptrack_gym.robots.ROBOTS``.
        env_name: the env id is ``ptrack_gym/<env_name>Track-v0``.
        urdf: a URDF file path, or a function returning URDF text (written once to a
            per-user cache folder, see :attr:`urdf_path`).
        joint_names: the controlled joints, in order (n of them); the URDF must have no
            other movable joint.
        torque_limits_nm: symmetric torque limit per joint (N·m); torques are clipped to it.
        joint_lower_rad / joint_upper_rad: joint position limits (rad).
        home_q_rad: a comfortable pose away from limits and singularities (rad).
        path_amplitude_rad: per-joint amplitude of the default and random paths (rad).
        path_period_s: period of the default path (s).
        ee_link: the end-effector link (pushes, payloads, circles, rendering).
        circle: the end-effector circle of ``path="circle"``.
        disturbance_scales: level 1 of the disturbance presets.
        default_control_hz: the control rate of training runs (Hz); physics runs at 1 kHz.
        controller_gains: default gains per controller name, as the rates its module's
            ``gains_from_rates`` reads (``agents``); a controller without an entry uses its
            module's generic defaults. Shared by every env of a process: never mutate.
        convergence_target_s: the time (s) within which the passivity controller is
            expected to converge from rest off the path (gain studies, tests).
        max_joint_speed_rad_s: speed above which a simulation counts as unstable (rad/s);
            below PyBullet's internal 100 rad/s clamp so a blow-up is seen, not clamped.
        camera_target_m / camera_distance_m: the rendering camera.
        source: where the model and its numbers come from (documentation).
    """

    name: str
    env_name: str
    urdf: str | Callable[[], str]
    joint_names: tuple[str, ...]
    torque_limits_nm: tuple[float, ...]
    joint_lower_rad: tuple[float, ...]
    joint_upper_rad: tuple[float, ...]
    home_q_rad: tuple[float, ...]
    path_amplitude_rad: tuple[float, ...]
    path_period_s: float
    ee_link: str
    circle: EECircle
    disturbance_scales: DisturbanceScales
    default_control_hz: float = 1000.0
    controller_gains: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    convergence_target_s: float = 30.0
    max_joint_speed_rad_s: float = 50.0
    camera_target_m: tuple[float, float, float] = (0.0, 0.0, 0.5)
    camera_distance_m: float = 2.0
    source: str = ""

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        for name in (
            "torque_limits_nm",
            "joint_lower_rad",
            "joint_upper_rad",
            "home_q_rad",
            "path_amplitude_rad",
        ):
            if len(getattr(self, name)) != n:
                raise InvalidConfigError(f"{self.name}: RobotProfile.{name} must have {n} entries")
        lo, hi = np.array(self.joint_lower_rad), np.array(self.joint_upper_rad)
        home = np.array(self.home_q_rad)
        if np.any(lo >= hi) or np.any(home <= lo) or np.any(home >= hi):
            raise InvalidConfigError(f"{self.name}: home pose must lie strictly within limits")
        if min(self.torque_limits_nm) <= 0:
            raise InvalidConfigError(f"{self.name}: torque limits must be positive")
        if not 0.0 < self.max_joint_speed_rad_s < 100.0:
            raise InvalidConfigError("max_joint_speed_rad_s must lie in (0, 100) rad/s")
        if not (math.isfinite(self.path_period_s) and self.path_period_s > 0):
            raise InvalidConfigError(f"{self.name}: path_period_s must be positive")

    @property
    def n(self) -> int:
        """Number of controlled joints."""
        return len(self.joint_names)

    @property
    def env_id(self) -> str:
        """The registered Gymnasium id of this robot's tracking env."""
        return f"ptrack_gym/{self.env_name}Track-v0"

    @cached_property
    def urdf_path(self) -> str:
        """Path of the URDF (a generated one is written on first use, see
        :func:`materialize_urdf`)."""
        if callable(self.urdf):
            return materialize_urdf(self.name, self.urdf())
        return self.urdf

    def limits(self) -> tuple[FloatArray, FloatArray]:
        """Joint position limits (lower, upper) as arrays (rad)."""
        return np.array(self.joint_lower_rad), np.array(self.joint_upper_rad)

    def home(self) -> FloatArray:
        """The home pose as an array (rad)."""
        return np.array(self.home_q_rad)


def materialize_urdf(name: str, text: str) -> str:
    """Write a generated URDF to a per-user cache folder and return its path.

    The file name carries a hash of the text, so a changed model never reuses a stale
    file, and the write is atomic (write then rename), so parallel workers are safe.
    """
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    folder = Path(tempfile.gettempdir()) / f"ptrack_gym-{os.getuid()}"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}-{digest}.urdf"
    if not path.exists():
        fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp")
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    return str(path)


@dataclass(frozen=True)
class Inertial:
    """A link's inertial block: mass (kg), centre of mass in the link frame (m) and inertia
    tensor about it (kg·m²: ixx, ixy, ixz, iyy, iyz, izz)."""

    mass_kg: float
    com_m: tuple[float, float, float]
    inertia_kgm2: tuple[float, float, float, float, float, float]

    def principal_axes(self) -> tuple[tuple[float, float, float], FloatArray]:
        """(rpy, moments): the inertia tensor as R diag(moments) Rᵀ, R = Rz(y) Ry(p) Rx(r)
        (URDF's convention), a proper rotation from its eigenvectors."""
        ixx, ixy, ixz, iyy, iyz, izz = self.inertia_kgm2
        if ixy == ixz == iyz == 0.0:  # already principal: no rotation
            return (0.0, 0.0, 0.0), np.array([ixx, iyy, izz], dtype=np.float64)
        tensor = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]], dtype=np.float64)
        moments, rot = np.linalg.eigh(tensor)
        if np.linalg.det(rot) < 0:
            rot[:, 2] = -rot[:, 2]
        pitch = math.asin(max(-1.0, min(1.0, -rot[2, 0])))
        roll = math.atan2(rot[2, 1], rot[2, 2])
        yaw = math.atan2(rot[1, 0], rot[0, 0])
        return (roll, pitch, yaw), moments

    def xml(self) -> str:
        """The URDF ``<inertial>`` element, in principal axes: a diagonal tensor in a rotated
        inertial frame. PyBullet would otherwise diagonalise the tensor itself (and zero an
        unphysical one), and its rounding would differ from Pinocchio's at 1e-12."""
        (roll, pitch, yaw), (i1, i2, i3) = self.principal_axes()
        x, y, z = (repr(float(v)) for v in self.com_m)
        return (
            f'<inertial><origin rpy="{roll!r} {pitch!r} {yaw!r}" xyz="{x} {y} {z}"/>'
            f'<mass value="{float(self.mass_kg)!r}"/>'
            f'<inertia ixx="{float(i1)!r}" ixy="0" ixz="0" iyy="{float(i2)!r}" iyz="0" '
            f'izz="{float(i3)!r}"/></inertial>'
        )


def replace_inertials(urdf_text: str, inertials: Mapping[str, Inertial]) -> str:
    """The URDF with the ``<inertial>`` block of each named link replaced (added where a
    link has none). Raises ``ValueError`` for a link the URDF does not have."""
    for link, inertial in inertials.items():
        pattern = re.compile(rf'(<link name="{re.escape(link)}"\s*>)(.*?)(</link>)', re.S)
        match = pattern.search(urdf_text)
        if match is None:
            raise ValueError(f"the URDF has no link {link!r}")
        body = re.sub(r"<inertial>.*?</inertial>", "", match.group(2), flags=re.S)
        new = match.group(1) + inertial.xml() + body + match.group(3)
        urdf_text = urdf_text[: match.start()] + new + urdf_text[match.end() :]
    return urdf_text


def absolute_mesh_paths(urdf_text: str, folder: str) -> str:
    """The URDF with ``package://`` mesh paths made absolute under ``folder``, so a rewritten
    copy loads from anywhere."""
    return urdf_text.replace('filename="package://', f'filename="{folder}/')
