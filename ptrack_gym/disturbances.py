"""Composable, seeded disturbances and model mismatch for the tracking environments.

A disturbance is a small object with optional hooks; the env calls them at documented
points and never lets them touch the simulator themselves:

* ``reset(rng, ctx)`` — at every env reset, with the episode's own stream: draws the
  episode's schedule;
* ``joint_torque(t, q, q̇)`` — before every physics sub-step (t its start time): τ_d is
  added to the plant torque, after the actuator clip, unseen by the controller;
* ``wrench(t)`` — before every physics sub-step: (link, world-frame force in N) applied
  at the link's centre of mass;
* ``plant(t)`` — before every control step: link mass changes of the plant only;
* ``actuate(τ)`` — every control step, on the commanded (clipped) torque: actuation noise;
* ``sense(q, q̇)`` — every control step, on the true state: what the observation and the
  controllers see.

Everything random is drawn from the ``rng`` given to ``reset`` (a stream the env derives
from its reset seed alone), in an order that does not depend on the actions: two
controllers run with the same seed meet exactly the same disturbances.

Build disturbances from specs with :func:`build_disturbances`: a preset name
(``"impulse"``), a ``(preset, level)`` pair, a ``(preset, {"energy_j": E})`` pair, a spec
dict (``{"type": "impulse", "fraction": 0.3}``) or a list of those. Level 0 is no
disturbance, 1 nominal, higher harder. See :data:`PRESETS`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from ptrack_gym.errors import InvalidConfigError

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class DisturbanceContext:
    """What a disturbance may know about the episode (SI units).

    Attributes:
        n: number of joints.
        torque_limits_nm: the actuators' limits, shape (n,).
        physics_dt_s / control_dt_s: the time steps.
        horizon_s: the nominal episode length, for onset times and energy budgets.
        ee_link: the end-effector link name (pushes and payloads act there by default).
        home_mass_matrix: nominal M at the home pose, (n, n), for energy budgets.
        ee_jacobian_home: translational Jacobian of the ee link's centre of mass at home, (3, n).
        mean_path_speed_rad_s: mean |q_r'| along the reference (rad/s), for energy budgets.
    """

    n: int
    torque_limits_nm: FloatArray
    physics_dt_s: float
    control_dt_s: float
    horizon_s: float
    ee_link: str
    home_mass_matrix: FloatArray
    ee_jacobian_home: FloatArray
    mean_path_speed_rad_s: float


@dataclass(frozen=True)
class MassChange:
    """A plant link's mass is ``nominal · scale + added_kg`` (inertia scaled by ``scale``)."""

    scale: float = 1.0
    added_kg: float = 0.0


def _unit(rng: np.random.Generator, n: int) -> FloatArray:
    v = rng.standard_normal(n)
    return v / np.linalg.norm(v)


def _draw(rng: np.random.Generator, value: float | tuple[float, float]) -> float:
    """A fixed value, or uniform in a (low, high) range."""
    if isinstance(value, tuple):
        return float(rng.uniform(*value))
    return float(value)


def _impulse_energy_scale(p: FloatArray, mass: FloatArray, energy_j: float) -> float:
    """Factor c such that the momentum c·p gives an arm at rest ½(cp)ᵀM⁻¹(cp) = energy_j."""
    e1 = 0.5 * float(p @ np.linalg.solve(mass, p))
    return float(np.sqrt(energy_j / e1)) if e1 > 0 else 0.0


@dataclass
class Disturbance:
    """Base of every disturbance: all hooks are no-ops. Subclasses are dataclasses whose
    fields are the spec; episode state set by ``reset`` lives in private attributes."""

    name: ClassVar[str] = "none"

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        """Draw this episode's schedule."""

    def joint_torque(self, t_s: float, q: FloatArray, qd: FloatArray) -> FloatArray | None:
        """Joint torque (N·m) to add before the physics sub-step starting at ``t_s``."""
        return None

    def wrench(self, t_s: float) -> tuple[str, FloatArray] | None:
        """(link name, world-frame force in N at the link's centre of mass), or None."""
        return None

    def plant(self, t_s: float) -> dict[str, MassChange] | None:
        """Plant link mass changes in force at ``t_s`` (None: this one changes nothing)."""
        return None

    def actuate(self, tau_nm: FloatArray) -> FloatArray:
        """The torque the actuators really produce for the command ``tau_nm``."""
        return tau_nm

    def sense(self, q: FloatArray, qd: FloatArray) -> tuple[FloatArray, FloatArray]:
        """What the sensors report for the true (q, q̇)."""
        return q, qd

    def schedule(self) -> dict[str, Any]:
        """The episode's drawn parameters (for logs and tests)."""
        return {}


def _check_fraction(value: float | tuple[float, float], name: str) -> None:
    values = value if isinstance(value, tuple) else (value,)
    if not all(np.isfinite(v) and v >= 0 for v in values):
        raise InvalidConfigError(f"{name} must be >= 0 (or a (low, high) range), got {value!r}")


@dataclass
class ImpulseTorque(Disturbance):
    """A joint-torque impulse held for ``duration_s`` from an onset uniform in ``onset_s``.

    Size, by precedence: ``energy_j`` — the impulse changes the velocity of an arm at rest
    at home by c·v (v a random unit vector of joint velocities) with the kinetic energy
    ½c²vᵀMv = energy_j, i.e. τ_d = c·M(q_home)v / duration; ``accel_rad_s2`` —
    τ_d = M(q_home)(α u); otherwise τ_d = a·τ_max ⊙ u (``fraction``), u a random unit vector.
    The torque acts on the physics sub-steps that start inside [onset, onset + duration):
    choose ``duration_s`` as a multiple of the physics step, or the delivered momentum is
    rounded to whole sub-steps.
    """

    name: ClassVar[str] = "impulse"
    fraction: float = 0.5
    duration_s: float = 0.05
    onset_s: float | tuple[float, float] = (1.0, 4.0)
    accel_rad_s2: float | None = None
    energy_j: float | None = None

    def __post_init__(self) -> None:
        _check_fraction(self.fraction, "fraction")
        if not self.duration_s > 0:
            raise InvalidConfigError(f"duration_s must be > 0, got {self.duration_s!r}")
        if self.energy_j is not None:
            _check_fraction(self.energy_j, "energy_j")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._onset = _draw(rng, self.onset_s)
        u = _unit(rng, ctx.n)
        if self.energy_j is not None:
            mass = ctx.home_mass_matrix
            c = np.sqrt(2.0 * self.energy_j / float(u @ mass @ u))
            self._tau = c * (mass @ u) / self.duration_s
        else:
            self._tau = _torque_vector(self.fraction, self.accel_rad_s2, u, ctx)

    def joint_torque(self, t_s: float, q: FloatArray, qd: FloatArray) -> FloatArray | None:
        if self._onset <= t_s < self._onset + self.duration_s:
            return self._tau
        return None

    def schedule(self) -> dict[str, Any]:
        return {"onset_s": self._onset, "tau_nm": self._tau.copy(), "duration_s": self.duration_s}


def _torque_vector(
    fraction: float, accel: float | None, direction: FloatArray, ctx: DisturbanceContext
) -> FloatArray:
    """a·τ_max ⊙ u (``fraction``), or M(q_home)·(α u) with α = ``accel`` (rad/s²): the
    inertia-scaled form gives every joint a comparable acceleration, light wrists included."""
    if accel is not None:
        return ctx.home_mass_matrix @ (accel * direction)
    return fraction * ctx.torque_limits_nm * direction


def _unit_like(v: FloatArray) -> FloatArray:
    norm = np.linalg.norm(v)
    return v / norm if norm > 0 else v


def _sustained_amplitude(ctx: DisturbanceContext, energy_j: float) -> float:
    """Torque norm A (N·m) such that A · mean|q_r'| · horizon = energy_j: the most work a
    torque of norm A can do on an arm moving along the reference for the whole horizon."""
    return energy_j / max(ctx.mean_path_speed_rad_s * ctx.horizon_s, 1e-12)


@dataclass
class StepTorque(Disturbance):
    """A constant joint torque from a random onset to the episode's end: a·τ_max ⊙ u, or
    M(q_home)(α u) with ``accel_rad_s2``; with ``energy_j``, |τ_d| = energy_j /
    (mean|q_r'| · horizon), the most work it can do along the reference."""

    name: ClassVar[str] = "step"
    fraction: float = 0.1
    onset_s: float | tuple[float, float] = (1.0, 4.0)
    accel_rad_s2: float | None = None
    energy_j: float | None = None

    def __post_init__(self) -> None:
        _check_fraction(self.fraction, "fraction")
        if self.energy_j is not None:
            _check_fraction(self.energy_j, "energy_j")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._onset = _draw(rng, self.onset_s)
        self._tau = _torque_vector(self.fraction, self.accel_rad_s2, _unit(rng, ctx.n), ctx)
        if self.energy_j is not None:
            self._tau = _unit_like(self._tau) * _sustained_amplitude(ctx, self.energy_j)

    def joint_torque(self, t_s: float, q: FloatArray, qd: FloatArray) -> FloatArray | None:
        return self._tau if t_s >= self._onset else None

    def schedule(self) -> dict[str, Any]:
        return {"onset_s": self._onset, "tau_nm": self._tau.copy()}


@dataclass
class PeriodicTorque(Disturbance):
    """τ_d,j(t) = A_j sin(2π f t + φ_j), A = a·τ_max ⊙ |u| (or |M(q_home) α|u|| with
    ``accel_rad_s2``), f drawn once per episode in ``frequency_hz``, phases φ_j uniform in
    [0, 2π) once per episode (never redrawn). With ``energy_j``: |A| = energy_j /
    (mean|q_r'| · horizon)."""

    name: ClassVar[str] = "periodic"
    fraction: float = 0.1
    frequency_hz: float | tuple[float, float] = (0.5, 2.0)
    accel_rad_s2: float | None = None
    energy_j: float | None = None

    def __post_init__(self) -> None:
        _check_fraction(self.fraction, "fraction")
        _check_fraction(self.frequency_hz, "frequency_hz")
        if self.energy_j is not None:
            _check_fraction(self.energy_j, "energy_j")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._freq = _draw(rng, self.frequency_hz)
        self._amp = np.abs(
            _torque_vector(self.fraction, self.accel_rad_s2, np.abs(_unit(rng, ctx.n)), ctx)
        )
        self._phase = rng.uniform(0.0, 2.0 * np.pi, ctx.n)
        if self.energy_j is not None:
            self._amp = _unit_like(self._amp) * _sustained_amplitude(ctx, self.energy_j)

    def joint_torque(self, t_s: float, q: FloatArray, qd: FloatArray) -> FloatArray | None:
        return self._amp * np.sin(2.0 * np.pi * self._freq * t_s + self._phase)

    def schedule(self) -> dict[str, Any]:
        return {
            "frequency_hz": self._freq,
            "amplitude_nm": self._amp.copy(),
            "phase_rad": self._phase.copy(),
        }


@dataclass
class NoiseTorque(Disturbance):
    """Random joint torque, std a·τ_max per joint (or α·M_jj(q_home) with
    ``accel_rad_s2``), drawn every physics sub-step.

    ``bandwidth_hz=None``: white (independent draws). Otherwise band-limited: a first-order
    low-pass (Ornstein–Uhlenbeck) process x ← ρx + √(1−ρ²)·σw, ρ = exp(−2π f_c dt), whose
    stationary std is σ and whose spectrum falls off above f_c."""

    name: ClassVar[str] = "noise_torque"
    fraction: float = 0.05
    bandwidth_hz: float | None = 5.0
    accel_rad_s2: float | None = None

    def __post_init__(self) -> None:
        _check_fraction(self.fraction, "fraction")
        if self.bandwidth_hz is not None and not self.bandwidth_hz > 0:
            raise InvalidConfigError(f"bandwidth_hz must be > 0 or None, got {self.bandwidth_hz!r}")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._rng = rng
        self._sigma = (
            self.fraction * ctx.torque_limits_nm
            if self.accel_rad_s2 is None
            else self.accel_rad_s2 * np.diag(ctx.home_mass_matrix)
        )
        self._rho = (
            0.0
            if self.bandwidth_hz is None
            else float(np.exp(-2.0 * np.pi * self.bandwidth_hz * ctx.physics_dt_s))
        )
        self._x = self._sigma * rng.standard_normal(ctx.n)

    def joint_torque(self, t_s: float, q: FloatArray, qd: FloatArray) -> FloatArray | None:
        w = self._rng.standard_normal(self._x.shape[0])
        self._x = self._rho * self._x + np.sqrt(1.0 - self._rho**2) * self._sigma * w
        return self._x


@dataclass
class Push(Disturbance):
    """A force on a link (default: the end effector) for ``duration_s`` from a random onset,
    in a random world direction, applied at the link's centre of mass each physics
    sub-step (PyBullet clears external forces after every step). With ``energy_j``, the
    force is scaled so its momentum Jᵀ(F·T) gives an arm at rest at home that energy."""

    name: ClassVar[str] = "push"
    force_n: float = 20.0
    duration_s: float = 0.1
    onset_s: float | tuple[float, float] = (1.0, 4.0)
    link: str | None = None
    energy_j: float | None = None

    def __post_init__(self) -> None:
        _check_fraction(self.force_n, "force_n")
        if not self.duration_s > 0:
            raise InvalidConfigError(f"duration_s must be > 0, got {self.duration_s!r}")
        if self.energy_j is not None:
            _check_fraction(self.energy_j, "energy_j")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._onset = _draw(rng, self.onset_s)
        self._link = self.link or ctx.ee_link
        direction = _unit(rng, 3)
        self._force = self.force_n * direction
        if self.energy_j is not None:
            p = ctx.ee_jacobian_home.T @ direction * self.duration_s
            self._force = direction * _impulse_energy_scale(p, ctx.home_mass_matrix, self.energy_j)

    def wrench(self, t_s: float) -> tuple[str, FloatArray] | None:
        if self._onset <= t_s < self._onset + self.duration_s:
            return self._link, self._force
        return None

    def schedule(self) -> dict[str, Any]:
        return {
            "onset_s": self._onset,
            "duration_s": self.duration_s,
            "force_n": self._force.copy(),
            "link": self._link,
        }


@dataclass
class Payload(Disturbance):
    """A point mass at the end effector (its link's centre of mass) of the plant only.

    Held from ``pick_s`` (0: from the start; a (low, high) range: drawn) until ``drop_s``
    (None: never dropped). The nominal model never sees it."""

    name: ClassVar[str] = "payload"
    mass_kg: float = 1.0
    pick_s: float | tuple[float, float] = 0.0
    drop_s: float | tuple[float, float] | None = None
    link: str | None = None

    def __post_init__(self) -> None:
        _check_fraction(self.mass_kg, "mass_kg")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._link = self.link or ctx.ee_link
        self._pick = _draw(rng, self.pick_s)
        self._drop = np.inf if self.drop_s is None else _draw(rng, self.drop_s)

    def plant(self, t_s: float) -> dict[str, MassChange] | None:
        held = self._pick <= t_s < self._drop
        return {self._link: MassChange(added_kg=self.mass_kg if held else 0.0)}

    def schedule(self) -> dict[str, Any]:
        return {
            "link": self._link,
            "pick_s": self._pick,
            "drop_s": self._drop,
            "mass_kg": self.mass_kg,
        }


@dataclass
class Mismatch(Disturbance):
    """Plant ≠ model: every listed link's mass and inertia scaled by a factor drawn per
    episode in ``mass_scale``; joint viscous damping and Coulomb friction as explicit plant
    torques τ_d,j = −β M_jj q̇_j − a_f M_jj tanh(q̇_j / 0.1 rad/s), M_jj = M_jj(q_home): per
    unit of joint inertia (β in 1/s, a_f in rad/s²), so light wrists are not over-damped
    and the explicit scheme stays stable (a_f < 0.1 rad/s / dt)."""

    name: ClassVar[str] = "mismatch"
    mass_scale: float | tuple[float, float] = (0.8, 1.2)
    damping_per_s: float = 0.0
    friction_rad_s2: float = 0.0
    links: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        _check_fraction(self.mass_scale, "mass_scale")
        _check_fraction(self.damping_per_s, "damping_per_s")
        _check_fraction(self.friction_rad_s2, "friction_rad_s2")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._scales = {link: _draw(rng, self.mass_scale) for link in self.links}
        inertia = np.diag(ctx.home_mass_matrix)
        self._damping = self.damping_per_s * inertia
        self._friction = self.friction_rad_s2 * inertia

    def plant(self, t_s: float) -> dict[str, MassChange] | None:
        return {link: MassChange(scale=s) for link, s in self._scales.items()}

    def joint_torque(self, t_s: float, q: FloatArray, qd: FloatArray) -> FloatArray | None:
        if self.damping_per_s == 0.0 and self.friction_rad_s2 == 0.0:
            return None
        return -self._damping * qd - self._friction * np.tanh(qd / 0.1)

    def schedule(self) -> dict[str, Any]:
        return {"mass_scales": dict(self._scales)}


@dataclass
class ActionNoise(Disturbance):
    """Actuation noise: the actuators produce τ + σ ⊙ w, σ = a·τ_max (or α·M_jj(q_home)
    with ``accel_rad_s2``), w standard normal per control step (held over the sub-steps)."""

    name: ClassVar[str] = "action_noise"
    fraction: float = 0.02
    accel_rad_s2: float | None = None

    def __post_init__(self) -> None:
        _check_fraction(self.fraction, "fraction")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._rng = rng
        self._sigma = (
            self.fraction * ctx.torque_limits_nm
            if self.accel_rad_s2 is None
            else self.accel_rad_s2 * np.diag(ctx.home_mass_matrix)
        )

    def actuate(self, tau_nm: FloatArray) -> FloatArray:
        return tau_nm + self._sigma * self._rng.standard_normal(tau_nm.shape[0])


@dataclass
class ObservationNoise(Disturbance):
    """Sensor noise: q + σ_q w₁ (rad), q̇ + σ_q̇ w₂ (rad/s), w standard normal per control step."""

    name: ClassVar[str] = "observation_noise"
    q_std_rad: float = 1e-3
    qd_std_rad_s: float = 1e-2

    def __post_init__(self) -> None:
        _check_fraction(self.q_std_rad, "q_std_rad")
        _check_fraction(self.qd_std_rad_s, "qd_std_rad_s")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._rng = rng

    def sense(self, q: FloatArray, qd: FloatArray) -> tuple[FloatArray, FloatArray]:
        n = q.shape[0]
        return (
            q + self.q_std_rad * self._rng.standard_normal(n),
            qd + self.qd_std_rad_s * self._rng.standard_normal(n),
        )


@dataclass
class ObservationDelay(Disturbance):
    """Sensor delay: the reported state is the one ``steps`` control steps ago (the
    episode's first state until enough steps have passed)."""

    name: ClassVar[str] = "observation_delay"
    steps: int = 2

    def __post_init__(self) -> None:
        if not (isinstance(self.steps, (int, np.integer)) and self.steps >= 0):
            raise InvalidConfigError(f"steps must be an integer >= 0, got {self.steps!r}")

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        self._buffer: list[tuple[FloatArray, FloatArray]] = []

    def sense(self, q: FloatArray, qd: FloatArray) -> tuple[FloatArray, FloatArray]:
        self._buffer.append((q, qd))
        if len(self._buffer) > self.steps + 1:
            self._buffer.pop(0)
        return self._buffer[0]


DISTURBANCES: dict[str, type[Disturbance]] = {
    cls.name: cls
    for cls in (
        ImpulseTorque,
        StepTorque,
        PeriodicTorque,
        NoiseTorque,
        Push,
        Payload,
        Mismatch,
        ActionNoise,
        ObservationNoise,
        ObservationDelay,
    )
}


# -- presets -----------------------------------------------------------------------

#: Per-robot scales of the presets: impulse energy (J), push force (N), payload mass (kg),
#: links scaled by the mismatch preset.
ROBOT_SCALES: dict[str, dict[str, Any]] = {
    "two_link": {
        "impulse_j": 0.3,
        "push_n": 10.0,
        "payload_kg": 0.5,
        "links": ("link1", "link2"),
    },
    "iiwa": {
        "impulse_j": 1.0,
        "push_n": 40.0,
        "payload_kg": 2.0,
        "links": tuple(f"lbr_iiwa_link_{i}" for i in range(1, 8)),
    },
    "panda": {
        "impulse_j": 1.0,
        "push_n": 20.0,
        "payload_kg": 1.0,
        "links": tuple(f"panda_link{i}" for i in range(1, 8)),
    },
}


def _preset_specs(name: str, level: float, robot: str) -> list[dict[str, Any]]:
    """The specs of preset ``name`` at ``level`` (0 none, 1 nominal) for ``robot``.

    Torque magnitudes are inertia-scaled (``accel_rad_s2``) or energy-based, so a level
    means a comparable push on every joint of every robot: at level 1, an impulse gives the
    arm at rest the robot's ``impulse_j`` of kinetic energy in 50 ms; a periodic torque
    accelerates each joint by up to 2 rad/s²; the noise preset adds sensor noise (1 mrad,
    10 mrad/s), actuation noise (1 rad/s² per joint inertia) and a 5 Hz band-limited
    torque (1 rad/s²); a payload of ``payload_kg`` is picked up between 1 and 4 s; the
    mismatch preset scales link masses by ±20%, with damping 0.5/s and friction 0.5 rad/s².
    """
    sc = ROBOT_SCALES[robot]
    specs: dict[str, list[dict[str, Any]]] = {
        "none": [],
        "impulse": [{"type": "impulse", "energy_j": sc["impulse_j"] * level, "duration_s": 0.05}],
        "push": [{"type": "push", "force_n": sc["push_n"] * level, "duration_s": 0.1}],
        "periodic": [{"type": "periodic", "accel_rad_s2": 2.0 * level}],
        "noise": [
            {"type": "observation_noise", "q_std_rad": 1e-3 * level, "qd_std_rad_s": 1e-2 * level},
            {"type": "action_noise", "accel_rad_s2": 1.0 * level},
            {"type": "noise_torque", "accel_rad_s2": 1.0 * level, "bandwidth_hz": 5.0},
        ],
        "payload": [{"type": "payload", "mass_kg": sc["payload_kg"] * level, "pick_s": (1.0, 4.0)}],
        "mismatch": [
            {
                "type": "mismatch",
                "mass_scale": (1.0 - 0.2 * level, 1.0 + 0.2 * level),
                "damping_per_s": 0.5 * level,
                "friction_rad_s2": 0.5 * level,
                "links": sc["links"],
            }
        ],
    }
    if name == "mixed":
        return [
            *_preset_specs("impulse", 0.5 * level, robot),
            *_preset_specs("periodic", 0.5 * level, robot),
            *_preset_specs("noise", 0.5 * level, robot),
            *_preset_specs("payload", 0.5 * level, robot),
        ]
    if name not in specs:
        raise InvalidConfigError(f"unknown disturbance preset {name!r}; known: {sorted(PRESETS)}")
    return specs[name] if level > 0 else []


PRESETS: tuple[str, ...] = (
    "none",
    "impulse",
    "push",
    "periodic",
    "noise",
    "payload",
    "mismatch",
    "mixed",
)
_ENERGY_PRESETS = ("impulse", "push", "periodic")


def _from_spec(spec: Mapping[str, Any]) -> Disturbance:
    spec = dict(spec)
    kind = spec.pop("type", None)
    if kind not in DISTURBANCES:
        raise InvalidConfigError(
            f"disturbance spec needs 'type' in {sorted(DISTURBANCES)}, got {kind!r}"
        )
    cls = DISTURBANCES[kind]
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(spec) - known)
    if unknown:
        raise InvalidConfigError(
            f"unknown field(s) {unknown} for disturbance {kind!r}; known: {sorted(known)}"
        )
    for key, value in spec.items():  # YAML/JSON give lists where ranges are tuples
        if isinstance(value, list):
            spec[key] = tuple(value)
    return cls(**spec)


DisturbanceSpec = str | tuple[str, Any] | Mapping[str, Any] | Disturbance


def build_disturbances(
    spec: DisturbanceSpec | Sequence[DisturbanceSpec] | None, robot: str
) -> list[Disturbance]:
    """Turn a user spec into disturbance objects (see the module docstring for the forms)."""
    if spec is None:
        return []
    if isinstance(spec, (str, Mapping, Disturbance)) or (
        isinstance(spec, tuple) and len(spec) == 2 and isinstance(spec[0], str)
    ):
        items: Sequence[Any] = [spec]
    elif isinstance(spec, Sequence):
        items = spec
    else:
        raise InvalidConfigError(f"cannot build disturbances from {spec!r}")
    out: list[Disturbance] = []
    for item in items:
        if isinstance(item, Disturbance):
            out.append(item)
        elif isinstance(item, str):
            out.extend(_from_spec(s) for s in _preset_specs(item, 1.0, robot))
        elif isinstance(item, tuple) and len(item) == 2 and isinstance(item[0], str):
            name, arg = item
            if isinstance(arg, Mapping):
                if set(arg) != {"energy_j"}:
                    raise InvalidConfigError(
                        f"preset {name!r}: the only option is 'energy_j', got {sorted(arg)}"
                    )
                if name not in _ENERGY_PRESETS:
                    raise InvalidConfigError(
                        f"preset {name!r} takes no energy budget; those that do: {_ENERGY_PRESETS}"
                    )
                for s in _preset_specs(name, 1.0, robot):
                    s = {k: v for k, v in s.items() if k not in ("fraction", "accel_rad_s2")}
                    out.append(_from_spec({**s, "energy_j": float(arg["energy_j"])}))
            else:
                level = float(arg)
                if not (np.isfinite(level) and level >= 0):
                    raise InvalidConfigError(f"preset {name!r}: level must be >= 0, got {arg!r}")
                out.extend(_from_spec(s) for s in _preset_specs(name, level, robot))
        elif isinstance(item, Mapping):
            out.append(_from_spec(item))
        else:
            raise InvalidConfigError(f"cannot build a disturbance from {item!r}")
    return out


@dataclass
class DisturbanceSet:
    """All of an env's disturbances, composed. Holds the episode's ledger."""

    items: list[Disturbance] = field(default_factory=list)

    @property
    def needs_substep_state(self) -> bool:
        """Whether any joint torque or wrench is active, so the env must account work."""
        return any(
            type(d).joint_torque is not Disturbance.joint_torque
            or type(d).wrench is not Disturbance.wrench
            for d in self.items
        )

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        """Reset every disturbance with its own child stream of ``rng`` (in list order)."""
        children = rng.spawn(len(self.items)) if self.items else []
        for d, child in zip(self.items, children, strict=True):
            d.reset(child, ctx)

    def joint_torque(self, t_s: float, q: FloatArray, qd: FloatArray) -> FloatArray | None:
        total = None
        for d in self.items:
            tau = d.joint_torque(t_s, q, qd)
            if tau is not None:
                total = tau.copy() if total is None else total + tau
        return total

    def wrenches(self, t_s: float) -> list[tuple[str, FloatArray]]:
        return [w for d in self.items if (w := d.wrench(t_s)) is not None]

    def plant(self, t_s: float) -> dict[str, MassChange]:
        """Combined mass changes: scales multiply, added masses add."""
        out: dict[str, MassChange] = {}
        for d in self.items:
            for link, ch in (d.plant(t_s) or {}).items():
                old = out.get(link, MassChange())
                out[link] = MassChange(old.scale * ch.scale, old.added_kg + ch.added_kg)
        return out

    def actuate(self, tau_nm: FloatArray) -> FloatArray:
        for d in self.items:
            tau_nm = d.actuate(tau_nm)
        return tau_nm

    def sense(self, q: FloatArray, qd: FloatArray) -> tuple[FloatArray, FloatArray]:
        for d in self.items:
            q, qd = d.sense(q, qd)
        return q, qd

    def schedules(self) -> list[dict[str, Any]]:
        return [{"type": d.name, **d.schedule()} for d in self.items]
