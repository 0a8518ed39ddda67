"""The passivity controller's gains (:class:`PassivityGains`) and how they are made from
rates (:mod:`agents.passivity`, the law).

Default gains (:func:`default_gains`) are set by rates and an inertia floor, the same on
every robot, made absolute with the robot's home-pose joint inertias, the mean M_r of the
path in use (M̄_r, the "mass" of the path-parameter dynamics M_r(s) s̈ = …) and the control
period dt:

* K_j = min(ω² · max(M_jj(q_home), m_floor), (α/dt)² M_jj)   spring of φ (N·m/rad)
* D_j = c K_j dt (+ 2 ζ √(K_j M_jj(q_home)) with ζ > 0)      damper beside φ (N·m·s/rad)
* κ = ω_s² M̄_r,  R = ρ M̄_r,  k_pump = λ / M̄_r ("metric" pump)

then capped for the rate from the path's extremes (:func:`cap_for_rate`): K, D and
k_pump scaled together where the fastest coupled mode of M(q)⁻¹K on the path would turn
more than 0.8 rad per sample or where the joint dampers' q_r'ᵀDq_r'/M_r(s) dt alone would
exceed 0.9 × 1.6, R lowered where (R + q_r'ᵀDq_r')/M_r(s) dt would exceed 1.6
on the slowest stretch, k_pump lowered where k_pump dt would exceed 0.8. The rates are
:data:`DEFAULT_RATES` updated by the robot profile's
``controller_gains["passivity"]`` (ω, ω_s in rad/s; ρ, λ in 1/s; m_floor in kg·m²; c; ζ
``damping_ratio``, dimensionless; γ in 1/s and r̄ for the re-synchronisation);
α = :data:`agents.gains.MAX_FREQUENCY_PER_SAMPLE` rad per sample
(:func:`agents.gains.cap_stiffness`).
The study that chose them is ``docs/passivity_gain_study.md``; the discretization, its
rate limit (:meth:`PassivityController.max_period_s`) and the caps: ``docs/control_rates.md``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from agents.base import ControlContext, FloatArray
from agents.gains import cap_stiffness, max_mode_frequency, rates
from agents.passivity_sampling import PHASE_DAMPING_LIMIT, PUMP_LIMIT, spring_angle_limit
from agents.passivity_tables import PassivityTables, passivity_tables
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots.model import RobotModel, home_inertia_kgm2

NAME = "passivity"
#: Generic default rates (see the module docstring).
DEFAULT_RATES: dict[str, Any] = {
    "omega": 20.0,
    "omega_s": 20.0,
    "rho": 10.0,
    "lam": 2.0,
    "pump": "metric",
    "m_floor": 0.1,
    "sync_rate": 0.0,
    "sync_ratio": 0.5,
    "saturation_aware": True,
    "zoh_damping": 1.0,
    "damping_ratio": 0.7,
}
#: The rates one gain scale multiplies (``train.studies.fronts``): the joint and the
#: phase spring bandwidths (the damping rates ρ, λ stay).
BANDWIDTHS = ("omega", "omega_s")
#: What the tuner (``train.studies.tune``) searches: rate → (low, high, log scale); the rest (the
#: inertia floor, the re-synchronisation, the remedy) stays the robot's.
#: The joint damping ratio ζ is searched on a log scale from 0.02 (about the damping the
#: hold's damper alone leaves, ``docs/worst_case.md#spring-modes``) to 2 (overdamped).
TUNABLE = {
    "omega": (3.0, 100.0, True),
    "omega_s": (3.0, 100.0, True),
    "rho": (2.0, 40.0, True),
    "lam": (0.5, 10.0, True),
    "damping_ratio": (0.02, 2.0, True),
}
#: The paper's law exactly (the ``passivity_paper`` controller): no re-synchronisation of σ,
#: no saturation-aware reference torque — whatever a robot's defaults or tuned rates say.
PAPER_LAW = {"sync_rate": 0.0, "saturation_aware": False, "zoh_damping": 0.0, "damping_ratio": 0.0}
#: What the tuner searches for the paper's law: :data:`TUNABLE` less the rates
#: :data:`PAPER_LAW` fixes.
PAPER_TUNABLE = {k: v for k, v in TUNABLE.items() if k not in PAPER_LAW}


class PAPER_RATES:  # a namespace of constants, as a controller's module is
    """The rate source of the paper's law (``agents.registry.RateSource``): the passivity
    controller's profile key, default rates and bandwidths, :data:`PAPER_TUNABLE` — the
    tuner must not search a rate :data:`PAPER_LAW` fixes (it could not act) — and those
    fixed rates (``FIXED``: ``agents.registry.effective_rates`` applies them last)."""

    NAME = NAME
    DEFAULT_RATES = DEFAULT_RATES
    TUNABLE = PAPER_TUNABLE
    BANDWIDTHS = BANDWIDTHS
    FIXED = PAPER_LAW


_PUMPS = ("metric", "paper")
#: The default and tuned gains run at most this fraction of their stated period limit
#: (:func:`cap_for_rate`, :meth:`PassivityController.max_period_s`).
RATE_MARGIN = 0.8
#: The largest share of the phase loop's rate budget (:data:`RATE_MARGIN` ·
#: ``PHASE_DAMPING_LIMIT`` M_r(s)/dt) the joint dampers' q_r'ᵀD q_r' may take anywhere on the
#: path (:func:`cap_for_rate`): R keeps at least a tenth of the slowest stretch's budget.
#: Above every share the default and tuned gains reach where they were served before the
#: rule (four robots, 1 kHz to 100 Hz, the default path and 70 random ones: largest 0.78,
#: the iiwa's tuned gains at 500 Hz on random path 307), so it changes none of them
#: (``docs/control_rates.md``, loop 7).
DAMPER_SHARE_MAX = 0.9


@dataclass(frozen=True)
class PassivityGains:
    """Gains of the passivity controller.

    Attributes:
        K: spring stiffness of φ (N·m/rad): a scalar (K·I) or one value per joint (diagonal).
        D: damping (N·m·s/rad) of a damper in parallel with φ's spring, acting on the rate
            of its stretch ė = q̇ − q_r'(s) ṡ: a scalar or one value per joint (diagonal),
            each ≥ 0. NOT in the paper; 0 (the dataclass default) is the paper's law. The
            default gains set D = c K dt (``zoh_damping`` c): twice the energy a zero-order
            hold of period dt feeds into the spring (see :meth:`PassivityController.law`).
        kappa: κ > 0, stiffness of the phase spring ψ = ½κ s̃² (J/s²).
        R: R > 0, damping of the phase-rate error s̃̇ (J·s/s² = J/s).
        k_pump: k ≥ 0, energy-pump gain (1/(J·s) for "metric", N·m·s/(rad·J) for "paper").
        pump: "metric" — f = −k(H + W_r(σ)) M q̇ (coordinate-free, default) — or "paper" —
            f = −k(H + W_r(σ)) q̇ (the paper's written form).
        speed_eps: below this √(q̇ᵀMq̇) (√J) the direction τ_q̇/speed is taken as 0, as the
            paper prescribes for speed ≈ 0; keeps the law finite at rest.
        sync_rate: γ ≥ 0 (1/s), phase re-synchronisation of σ — NOT in the paper;
            0 (the default) is the paper's law exactly. With γ > 0, while the speed ratio
            v/√M_r(s) is below ``sync_ratio``, σ is also pulled toward the arm's own phase
            on the path (see :meth:`PassivityController.law`), which frees the stall trap
            of the paper's law. Above ``sync_ratio`` the law is the paper's.
        sync_ratio: r̄ > 0, the speed ratio v/√M_r(s) below which ``sync_rate`` acts
            (with a smooth step: full strength at rest, none from r̄ on).
        torque_limits_nm: the actuators' limits τ_max (N·m, one per joint), or None (the
            dataclass default: the paper's law). NOT in the paper: when given, the law is
            saturation-aware — the work-free reference torque τ_r⁰ is scaled into the box
            |τ_j| ≤ τ_max,j (see :meth:`PassivityController.law`), so the actuators deliver
            the law's torque instead of a clipped one that does work the law never
            commanded; the law is the paper's whenever its torque fits in the box.
    """

    K: float | tuple[float, ...] = 100.0
    D: float | tuple[float, ...] = 0.0
    kappa: float = 10.0
    R: float = 0.2
    k_pump: float = 20.0
    pump: str = "metric"
    speed_eps: float = 1e-6
    sync_rate: float = 0.0
    sync_ratio: float = 0.5
    torque_limits_nm: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        k = np.atleast_1d(np.asarray(self.K, dtype=np.float64))
        if k.ndim != 1 or not np.all(np.isfinite(k)) or np.any(k <= 0):
            raise InvalidConfigError(
                f"K must be a positive scalar or positive per-joint values, got {self.K!r}"
            )
        d = np.atleast_1d(np.asarray(self.D, dtype=np.float64))
        if d.ndim != 1 or not np.all(np.isfinite(d)) or np.any(d < 0):
            raise InvalidConfigError(
                f"D must be a scalar or per-joint values, each finite and >= 0, got {self.D!r}"
            )
        for name in ("kappa", "R"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InvalidConfigError(f"{name} must be a positive number, got {v!r}")
        if not (np.isfinite(self.k_pump) and self.k_pump >= 0):
            raise InvalidConfigError(f"k_pump must be >= 0, got {self.k_pump!r}")
        if self.pump not in _PUMPS:
            raise InvalidConfigError(f"pump must be one of {_PUMPS}, got {self.pump!r}")
        if not (np.isfinite(self.speed_eps) and self.speed_eps > 0):
            raise InvalidConfigError(f"speed_eps must be positive, got {self.speed_eps!r}")
        if not (np.isfinite(self.sync_rate) and self.sync_rate >= 0):
            raise InvalidConfigError(f"sync_rate must be >= 0, got {self.sync_rate!r}")
        if not (np.isfinite(self.sync_ratio) and self.sync_ratio > 0):
            raise InvalidConfigError(f"sync_ratio must be positive, got {self.sync_ratio!r}")
        if self.torque_limits_nm is not None:
            lim = np.asarray(self.torque_limits_nm, dtype=np.float64)
            if lim.ndim != 1 or lim.size == 0 or not np.all(np.isfinite(lim)) or np.any(lim <= 0):
                raise InvalidConfigError(
                    f"torque_limits_nm must be None or positive per-joint values, "
                    f"got {self.torque_limits_nm!r}"
                )
            object.__setattr__(self, "torque_limits_nm", tuple(float(x) for x in lim))

    @classmethod
    def from_rates(
        cls,
        inertia_kgm2: FloatArray,
        mean_m_r_j: float,
        omega: float,
        omega_s: float,
        rho: float,
        lam: float,
        pump: str = "metric",
        m_floor: float = 0.0,
        sync_rate: float = 0.0,
        sync_ratio: float = 0.5,
        dt_s: float | None = None,
        torque_limits_nm: tuple[float, ...] | None = None,
        zoh_damping: float = 0.0,
    ) -> PassivityGains:
        """Absolute gains from rates (the module docstring's formulas): K_j = ω² ·
        max(M_jj, m_floor), capped by :func:`agents.gains.cap_stiffness` when the control
        period ``dt_s`` (s) is given; D_j = c K_j dt with c = ``zoh_damping`` (0 without
        ``dt_s``); κ = ω_s² M̄_r, R = ρ M̄_r, k_pump = λ / M̄_r; ``torque_limits_nm`` makes
        the law saturation-aware.

        Args:
            inertia_kgm2: the joint inertias that scale K, e.g. diag M(q_home) (kg·m²).
            mean_m_r_j: M̄_r, the mean of M_r(s) over the path (J).
        """
        m = np.asarray(inertia_kgm2, dtype=np.float64)
        if not (np.isfinite(mean_m_r_j) and mean_m_r_j > 0):
            raise InvalidConfigError(f"mean_m_r_j must be positive, got {mean_m_r_j!r}")
        if not (np.isfinite(zoh_damping) and zoh_damping >= 0):
            raise InvalidConfigError(f"zoh_damping must be >= 0, got {zoh_damping!r}")
        stiffness = omega**2 * np.maximum(m, m_floor)
        damping = np.zeros_like(stiffness)
        if dt_s is not None:
            stiffness = cap_stiffness(stiffness, m, dt_s)
            damping = zoh_damping * stiffness * dt_s
        return cls(
            K=tuple(float(k) for k in stiffness),
            D=tuple(float(d) for d in damping),
            kappa=float(omega_s**2 * mean_m_r_j),
            R=float(rho * mean_m_r_j),
            k_pump=float(lam / mean_m_r_j),
            pump=pump,
            sync_rate=float(sync_rate),
            sync_ratio=float(sync_ratio),
            torque_limits_nm=torque_limits_nm,
        )

    def stiffness(self, n: int) -> FloatArray:
        """The diagonal of K as an (n,) array (N·m/rad)."""
        return _diagonal(self.K, n, "K")

    def damping(self, n: int) -> FloatArray:
        """The diagonal of D as an (n,) array (N·m·s/rad)."""
        return _diagonal(self.D, n, "D")


def _diagonal(value: float | tuple[float, ...], n: int, name: str) -> FloatArray:
    """A scalar or per-joint gain as its (n,) diagonal."""
    k = np.atleast_1d(np.asarray(value, dtype=np.float64))
    if k.shape == (1,):
        return np.full(n, k[0])
    if k.shape != (n,):
        raise InvalidConfigError(f"{name} has {k.shape[0]} entries, the robot has {n} joints")
    return k.copy()


def gains_from_rates(
    ctx: ControlContext, given: Mapping[str, Any] | None, tables: PassivityTables | None = None
) -> PassivityGains:
    """Absolute gains from rates — ``DEFAULT_RATES``, updated by the robot's profile rates,
    updated by ``given`` — for the context's path and control rate: inertias from the
    model, M̄_r from the tables, the actuator box from the profile when
    ``saturation_aware``."""
    r = rates(DEFAULT_RATES, given, NAME, ctx.profile.controller_gains.get(NAME))
    aware = bool(r.pop("saturation_aware"))
    zeta = r.pop("damping_ratio")
    tables = tables or passivity_tables(ctx.path, ctx.model)
    inertia = home_inertia_kgm2(ctx.model, ctx.profile)
    gains = PassivityGains.from_rates(
        inertia, tables.mean_m_r, dt_s=ctx.dt_s,
        torque_limits_nm=ctx.profile.torque_limits_nm if aware else None, **r,
    )  # fmt: skip
    if zeta == 0.0:
        return cap_for_rate(gains, ctx.model, tables, ctx.dt_s)
    # twice: the joint damper is sized on the capped springs, and changes their cap; the
    # pump's own limit only at the end, so it sees the two spring factors' product
    gains = cap_for_rate(gains, ctx.model, tables, ctx.dt_s, limit_pump=False)
    damped = add_joint_damping(gains, inertia, zeta)  # a negative or NaN ζ is refused there
    return cap_for_rate(damped, ctx.model, tables, ctx.dt_s)


def add_joint_damping(
    gains: PassivityGains, inertia_kgm2: FloatArray, zeta: float
) -> PassivityGains:
    """``gains`` with 2 ζ √(K_j m_j) added to each D_j: the damping ratio ζ (dimensionless)
    on each joint's spring-damper taken alone, m_j = ``inertia_kgm2`` (kg·m², e.g.
    diag M(q_home), not floored). NOT in the paper, and not the zero-order-hold damper
    c K dt beside it: that one only returns the energy the hold feeds into the spring, so
    φ's springs are left with a damping ratio of about ω dt / 2 (0.004–0.10 on the four
    robots at 1 kHz) — transverse to the path the law has almost no dissipation (Ė = −R s̃̇²
    − ėᵀDė), and a periodic torque at one of those modes resonates
    (``docs/worst_case.md``). D stays diagonal and ≥ 0, so Ė ≤ −ėᵀDė still holds. The
    rate caps rerun afterwards (:func:`gains_from_rates`): a larger D/K lowers the spring
    angle a period admits, so a large ζ softens the springs (at 1 kHz none on the four
    robots up to ζ = 1.5, the xArm6's K × 0.93 at ζ = 2 and × 0.1 at ζ = 20; at 250 Hz the
    iiwa's × 0.62 at ζ = 0.7).

    Raises:
        InvalidConfigError: ζ negative or not finite.
    """
    if isinstance(zeta, bool) or not isinstance(zeta, (int, float)) or not zeta >= 0.0:
        raise InvalidConfigError(f"damping_ratio must be a number >= 0, got {zeta!r}")
    if not math.isfinite(zeta):
        raise InvalidConfigError(f"damping_ratio must be finite, got {zeta!r}")
    n = len(inertia_kgm2)
    m = np.asarray(inertia_kgm2, dtype=np.float64)
    added = 2.0 * zeta * np.sqrt(gains.stiffness(n) * m)
    return dataclasses.replace(gains, D=tuple(float(d) for d in gains.damping(n) + added))


def cap_for_rate(
    gains: PassivityGains,
    model: RobotModel,
    tables: PassivityTables,
    dt_s: float,
    limit_pump: bool = True,
) -> PassivityGains:
    """``gains`` such that the control period ``dt_s`` is at most 80% (:data:`RATE_MARGIN`)
    of each limit of :meth:`PassivityController.max_period_s`:

    * K, D and the pump k scaled by one factor where needed so that the fastest mode of
      φ's springs on the path (:func:`~agents.gains.max_mode_frequency`) turns at most
      0.8 θ(0.8 c) rad per period, θ the spring limit
      (:func:`~agents.passivity_sampling.spring_angle_limit`) and c = min_j D_j/(K_j dt) —
      what it would be at the period dt/0.8 (scaling K and D together keeps c); the
      per-joint cap reads M's diagonal at home only. The pump goes with them: its arm half
      f = −k (H + W_r) M q̇ is a velocity feedback whose sign follows H + W_r, and off the
      path (H + W_r < 0) it pushes the arm along its own velocity, against the springs and
      dampers that pull it back; softening those alone undoes the balance the gains were
      chosen with (docs/control_rates.md, loop 6: with k left alone, the tuned two-link at
      250 Hz was thrown past 0.1 rad by 5 of 100 impulses, 2 past 0.5; with k scaled, none —
      ``python bench/impulse_throws.py --hz 250 --seeds 10``);
    * K, D and k scaled by one factor more where the joint dampers' share of the phase
      loop, q_r'ᵀD q_r'/M_r(s) dt, would exceed 0.9 (:data:`DAMPER_SHARE_MAX`) of its
      limit 0.8 · 2 anywhere on the path: D sized on the home pose's inertias can exceed
      it alone on a stretch where the path moves the joints whose inertia is far below
      home's (the iiwa's default gains at 250 Hz on random path 307: 1.09 of it, refused
      before — R could not go below 0; ``bench/damper_share.py`` surveys the shares);
    * R lowered where needed so that (R + q_r'ᵀD q_r')/M_r(s) dt ≤ 0.8 · 2 everywhere on
      the path (its extremes, not the mean M̄_r that R = ρ M̄_r scales by);
    * the pump k lowered where needed so that k dt ≤ 0.8 (:data:`PUMP_LIMIT`: the virtual
      system's pump term is stepped explicitly) — unless ``limit_pump`` is false (a pass
      whose result is capped again: the limit is taken once, at the end).
    """
    n = model.n
    stiffness = gains.stiffness(n)
    c = float(np.min(gains.damping(n) / stiffness)) / dt_s
    angle = RATE_MARGIN * spring_angle_limit(RATE_MARGIN * c)
    omega = max_mode_frequency(model, tables.q_samples(), stiffness)
    if omega * dt_s > angle:
        scale = (angle / (omega * dt_s)) ** 2
        gains = dataclasses.replace(
            gains,
            K=tuple(float(k) for k in scale * stiffness),
            D=tuple(float(d) for d in scale * gains.damping(n)),
            k_pump=float(scale * gains.k_pump),
        )
    damper, budget = phase_loads(tables, gains.damping(n), dt_s)
    share = float(np.max(damper / budget))
    if share > DAMPER_SHARE_MAX:  # the joint dampers alone would leave R no room
        scale = DAMPER_SHARE_MAX / share
        gains = dataclasses.replace(
            gains,
            K=tuple(float(k) for k in scale * gains.stiffness(n)),
            D=tuple(float(d) for d in scale * gains.damping(n)),
            k_pump=float(scale * gains.k_pump),
        )
        damper, _ = phase_loads(tables, gains.damping(n), dt_s)
    r_max = float(np.min(budget - damper))  # > 0 while the dampers take ≤ 0.9 of it
    if gains.R > r_max > 0.0:  # (≤ 0 only with the rule off: check_rate refuses it then)
        gains = dataclasses.replace(gains, R=r_max)
    k_max = RATE_MARGIN * PUMP_LIMIT / dt_s
    if limit_pump and gains.k_pump > k_max:
        gains = dataclasses.replace(gains, k_pump=k_max)
    return gains


def phase_loads(
    tables: PassivityTables, damping: FloatArray, dt_s: float
) -> tuple[FloatArray, FloatArray]:
    """Per row of ``tables`` (the path's samples): the joint dampers' load on the phase loop
    q_r'ᵀD q_r' (J·s, D = diag(``damping``)) and the loop's budget for R + q_r'ᵀD q_r' at the
    period ``dt_s``, :data:`RATE_MARGIN` · ``PHASE_DAMPING_LIMIT`` · M_r(s)/dt (J·s)."""
    n = tables.n
    qd, m_r = tables.columns[:, n : 2 * n], tables.columns[:, 3 * n]
    damper = np.einsum("ij,j,ij->i", qd, np.asarray(damping, dtype=np.float64), qd)
    return damper, RATE_MARGIN * PHASE_DAMPING_LIMIT * m_r / dt_s


def damper_share(tables: PassivityTables, damping: FloatArray, dt_s: float) -> float:
    """The joint dampers' largest share of the phase loop's budget on the path,
    max_s q_r'ᵀD q_r' / (0.8 · 2 M_r(s)/dt) (:func:`phase_loads`; :func:`cap_for_rate`
    keeps it ≤ :data:`DAMPER_SHARE_MAX`)."""
    damper, budget = phase_loads(tables, damping, dt_s)
    return float(np.max(damper / budget))


def default_gains(ctx: ControlContext, tables: PassivityTables | None = None) -> PassivityGains:
    """The robot's default gains for the context's path and control rate (module
    docstring): the profile's rates."""
    return gains_from_rates(ctx, None, tables)
