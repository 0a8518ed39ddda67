"""What the package needs to know about a robot: a frozen :class:`RobotSpec`.

A spec is data only. The simulated arm (:class:`ptrack_gym.sim.BulletArm`) and the
controllers' dynamics model (:mod:`ptrack_gym.robots.model`) are both built from it,
separately, so that the plant can be perturbed while the model stays nominal.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ptrack_gym.errors import InvalidConfigError

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class RobotSpec:
    """A fixed-base, fully actuated arm.

    Attributes:
        name: short identifier (``"two_link"``, ``"iiwa"``, ``"panda"``).
        urdf_path: path of a URDF whose movable joints are exactly ``joint_names``.
        joint_names: the controlled joints, in order (n of them).
        torque_limits_nm: symmetric torque limit per joint (N·m); torques are clipped to it.
        joint_lower_rad / joint_upper_rad: joint position limits (rad).
        home_q_rad: a comfortable pose away from limits and singularities (rad).
        path_amplitude_rad: per-joint amplitude bound used by random reference paths (rad).
        max_joint_speed_rad_s: speed above which a simulation counts as unstable (rad/s);
            below PyBullet's internal 100 rad/s clamp so a blow-up is seen, not clamped.
        ee_link: name of the end-effector link (used by task-space paths and rendering).
        camera_target_m: where the rendering camera looks (m).
        camera_distance_m: rendering camera distance (m).
    """

    name: str
    urdf_path: str
    joint_names: tuple[str, ...]
    torque_limits_nm: tuple[float, ...]
    joint_lower_rad: tuple[float, ...]
    joint_upper_rad: tuple[float, ...]
    home_q_rad: tuple[float, ...]
    path_amplitude_rad: tuple[float, ...]
    ee_link: str
    max_joint_speed_rad_s: float = 50.0
    camera_target_m: tuple[float, float, float] = (0.0, 0.0, 0.5)
    camera_distance_m: float = 2.0

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        for field in (
            "torque_limits_nm",
            "joint_lower_rad",
            "joint_upper_rad",
            "home_q_rad",
            "path_amplitude_rad",
        ):
            if len(getattr(self, field)) != n:
                raise InvalidConfigError(f"RobotSpec.{field} must have {n} entries")
        lo, hi = np.array(self.joint_lower_rad), np.array(self.joint_upper_rad)
        home = np.array(self.home_q_rad)
        if np.any(lo >= hi) or np.any(home <= lo) or np.any(home >= hi):
            raise InvalidConfigError(f"{self.name}: home pose must lie strictly within limits")
        if not 0.0 < self.max_joint_speed_rad_s < 100.0:
            raise InvalidConfigError("max_joint_speed_rad_s must lie in (0, 100) rad/s")

    @property
    def n(self) -> int:
        """Number of controlled joints."""
        return len(self.joint_names)

    def limits(self) -> tuple[FloatArray, FloatArray]:
        """Joint position limits (lower, upper) as arrays (rad)."""
        return np.array(self.joint_lower_rad), np.array(self.joint_upper_rad)


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
