"""The passivity-based trajectory-tracking controller of Mahony (CDC 2019).

Equations as restated in ``docs/control_law.md`` (which fixes the paper's double
count of W_r in H_r). The controller tracks the path q_r(s) *up to a time offset*: it
carries its own path parameter s with rate ṡ, and σ, the path parameter of the true
system, whose rate σ̇ = sqrt(q̇ᵀM q̇ / M_r(s)) is the arm's speed ratio to the path.

Notation (SI units; s, σ in seconds of path time): with measured (q, q̇),

.. math::

    \\tau_{\\dot q} = M(q)\\dot q, \\quad v^2 = \\dot q^T M \\dot q, \\quad
    \\dot\\sigma = \\sqrt{v^2 / M_r(s)}, \\quad \\tilde s = s - \\sigma, \\quad
    \\dot{\\tilde s} = \\dot s - \\dot\\sigma

    \\phi = \\tfrac12 (q - q_r(s))^T K (q - q_r(s)), \\quad \\psi = \\tfrac12\\kappa\\tilde s^2

    \\tau_r^0 = \\frac{v^2}{M_r}\\tau_r - \\frac{\\dot q^T\\tau_r}{M_r}\\tau_{\\dot q}, \\quad
    \\mu = \\frac{W_r'(\\sigma) - \\kappa\\tilde s - R\\dot{\\tilde s}}{\\sqrt{M_r(s)}}

    \\tau_{sync} = -\\mu\\,\\tau_{\\dot q}/v + \\tau_r^0 - \\partial\\phi/\\partial q
        - D\\dot e, \\quad
    e_c = -\\kappa\\tilde s - R\\dot{\\tilde s} + (\\partial\\phi/\\partial q + D\\dot e)^T q_r'(s),
    \\quad \\dot e = \\dot q - q_r'(s)\\dot s

    H_r = \\tfrac12 M_r(s)(\\dot s^2 - 1), \\quad
    f = -k(H + W_r(\\sigma))\\,\\tau_{\\dot q} \\text{ (metric) or } \\dot q \\text{ (paper)},
    \\quad f_r = -k H_r \\dot s

    \\tau = \\tau_{sync} + f, \\quad
    M_r(s)\\ddot s = -\\tfrac12 M_r'(s)(\\dot s^2 - 1) + e_c + f_r

Storage function E = H + W_r(σ) + H_r + φ + ψ, with Ė = −R s̃̇² − ėᵀDė (k = 0, no
disturbance). D, a damper beside φ's spring, is not in the paper (D = 0 is its law; the
defaults set D = c K dt, see below).

Opt-in, not in the paper: ``PassivityGains.sync_rate`` > 0 adds a phase
re-synchronisation of σ (see :meth:`PassivityController.law`); it acts only while the
speed ratio v/√M_r(s) is below ``sync_ratio`` (below 1: at low speed only; above 1: also at
nominal speed; each robot's profile sets it) and leaves the law above it unchanged; on the
reference its term is exactly 0 whatever ``sync_ratio``. With ``sync_rate`` = 0 (the
dataclass default) the law is exactly the paper's.

Default gains and the rates they are made of: :mod:`agents.passivity_gains`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from agents.base import ControlContext, FeatureBlock, FloatArray, state_arrays
from agents.gains import (
    max_mode_frequency,
)
from agents.passivity_gains import (  # the gains' names, re-exported: the law's module
    BANDWIDTHS,
    DEFAULT_RATES,
    NAME,
    PAPER_LAW,
    PAPER_RATES,
    PAPER_TUNABLE,
    RATE_MARGIN,
    TUNABLE,
    PassivityGains,
    cap_for_rate,
    default_gains,
    gains_from_rates,
)
from agents.passivity_kernel import OUT, law_step, law_tables
from agents.passivity_sampling import (
    PHASE_DAMPING_LIMIT,
    PUMP_LIMIT,
    max_period_s,
    phase_rate,
)
from agents.passivity_tables import PassivityTables, passivity_tables
from ptrack_gym.errors import ControlRateError, InvalidConfigError
from ptrack_gym.robots.model import RobotModel

__all__ = [
    "BANDWIDTHS",
    "DEFAULT_RATES",
    "DIAGNOSTICS",
    "HOLDS",
    "HOLD_FILTER_S",
    "INTEGRATORS",
    "NAME",
    "PAPER_LAW",
    "PAPER_RATES",
    "PAPER_TUNABLE",
    "RATE_MARGIN",
    "TUNABLE",
    "LawOutput",
    "PassivityController",
    "PassivityGains",
    "PassivityState",
    "build",
    "build_paper",
    "cap_for_rate",
    "default_gains",
    "fit_scale",
    "gains_from_rates",
]

#: How ``step`` integrates (s, ṡ, σ) (see :class:`PassivityController`).
INTEGRATORS = ("implicit", "symplectic")
#: Which torque ``step`` holds over the control period (see :class:`PassivityController`).
HOLDS = ("midpoint", "sample")
#: T_b (s): the time constant of the midpoint hold's estimate of the model's acceleration
#: error (:class:`PassivityController`): slow beside the law's fast loops (≥ 25 ms
#: periods), fast beside a payload's or a model error's change.
HOLD_FILTER_S = 0.1
#: The direction guard's c (class docstring): the phase channel's direction is damped where
#: the velocity changed by more than 1/c of itself over the last period.
DIRECTION_GUARD = 4.0
_STARTS = ("nearest", "reference")
#: The law's scalars :meth:`PassivityController.diagnostics` reports after s, ṡ, σ
#: (fields of :class:`LawOutput`).
DIAGNOSTICS = ("s_tilde", "s_tilde_dot", "sigma_dot", "energy", "h_plus_w", "h_r", "phi", "psi",
               "pump_power", "dissipation", "sync_power", "path_error", "r0_scale")  # fmt: skip


class LawOutput(NamedTuple):
    """Everything the control law computes at one state (SI units)."""

    tau: FloatArray  # torque to send, τ = τ_sync + f (N·m)
    s_dd: float  # s̈ (1/s)
    sigma_dot: float  # σ̇, the speed ratio (1)
    energy: float  # E = H + W_r(σ) + H_r + φ + ψ (J)
    h_plus_w: float  # H(q, q̇) + W_r(σ) (J)
    h_r: float  # H_r(s, ṡ) = ½ M_r (ṡ² − 1) (J)
    phi: float  # φ (J)
    psi: float  # ψ (J)
    pump_power: float  # q̇ᵀf + ṡ f_r, power the pump injects (W)
    dissipation: float  # R s̃̇² + ėᵀDė, the passive dissipation rate (W)
    sync_power: float  # (W_r'(σ) − κ s̃ − R s̃̇)·u: what the re-synchronisation u adds to Ė (W)
    s_tilde: float  # s̃ = s − σ (s)
    s_tilde_dot: float  # s̃̇ = ṡ − σ̇ (1)
    tau_sync: FloatArray  # (n,) N·m
    tau_r0: FloatArray  # α τ_r⁰, the work-free part of the reference torque as sent, (n,) N·m
    pump_torque: FloatArray  # f, (n,) N·m
    path_error: float  # |q − q_r(s)| (rad)
    r0_scale: float = 1.0  # α, the saturation-aware scale of τ_r⁰ (1: the paper's law)
    hold_correction: FloatArray | None = None  # δ, τ − τ(sample) of the midpoint hold, (n,) N·m


@dataclass
class PassivityState:
    """The controller's internal state: path parameter s (s), rate ṡ (1), σ (s)."""

    s: float = 0.0
    sd: float = 0.0
    sigma: float = 0.0


def fit_scale(rest: FloatArray, r0: FloatArray, box: FloatArray) -> float:
    """α = the largest a ∈ [0, 1] with |rest_j + a r0_j| ≤ max(box_j, |rest_j|) for every j
    (the saturation-aware scale of :meth:`PassivityController.law`)."""
    bound = np.maximum(box, np.abs(rest))
    if np.all(np.abs(rest + r0) <= bound):  # the paper's torque fits
        return 1.0
    mag = np.abs(r0)
    moving = mag > 0.0
    # Per joint, |rest + a r0| ≤ bound holds for a ∈ [0, (bound − sign(r0) rest) / |r0|].
    hi = (bound[moving] - np.sign(r0[moving]) * rest[moving]) / mag[moving]
    return float(min(1.0, max(0.0, float(hi.min())))) if hi.size else 1.0


class PassivityController:
    """Mahony's passivity-based tracking controller (see the module docstring).

    Args:
        model: the nominal dynamics model (never the simulated body).
        tables: the reference tables of the path for that model
            (:func:`agents.passivity_tables.passivity_tables`).
        gains: the controller gains.
        start: how ``reset`` chooses s₀ — "nearest": the path point nearest q₀
            (default; the controller does not care about time); "reference": s₀ = the
            env's time-indexed phase s_ref.
        sd0: ṡ₀ at reset; None (default) sets ṡ₀ = σ̇(q₀, q̇₀, s₀), so s̃̇₀ = 0: 0 from
            rest, 1 on the path at nominal speed. σ₀ = s₀ always.
        integrator: how ``step`` integrates (s, ṡ, σ): :data:`INTEGRATORS` (below).
        hold: which torque ``step`` holds over the period: :data:`HOLDS` (below).
        direction_guard: the direction guard's c ≥ 0 (below; None: :data:`DIRECTION_GUARD`,
            0: off).
        dt_s: the control period (s) to check now (:meth:`check_rate`); ``step`` checks
            every new period it is given.

    Raises:
        ControlRateError: ``dt_s`` exceeds :meth:`max_period_s`.

    Integration (``step``, ``integrator``): the virtual system (s, ṡ, σ) over one control
    period dt, given the measured (q, q̇) at its start.

    * ``"implicit"`` (default): semi-implicit Euler, implicit in the virtual system's stiff
      linear part. With a = (κ + q_r'ᵀK q_r')/M_r(s) (the springs ψ and φ acting on s),
      c = (R + q_r'ᵀD q_r')/M_r(s) (the dampers acting on ṡ) and b = (q_r'ᵀK q̇ + κ σ̇)/M_r(s)
      (how fast those springs' other ends, q and σ, move),

      .. math::

          \\Delta\\dot s = \\frac{dt\\,(\\ddot s + dt\\,(b - a \\dot s))}{1 + c\\,dt + a\\,dt^2},
          \\quad \\dot s \\leftarrow \\dot s + \\Delta\\dot s,\\quad s \\leftarrow s + dt\\,\\dot s,
          \\quad \\sigma \\leftarrow \\sigma + dt\\,\\dot\\sigma

      — backward Euler of s̈ linearised in (s, ṡ) at the step's start, with q and σ moving
      at q̇ and σ̇ over the step. First order; stable for every dt where that part is stiff,
      where an explicit step needs a dt² + 2c dt < 4, which fails on a path's slow
      stretches (small M_r(s)) at ordinary control rates (``docs/control_rates.md``). On the
      reference Δṡ = 0 exactly (s̈ = 0 and b = a). The pump's term of s̈,
      f_r/M_r = −k ½(ṡ² − 1)ṡ, is cubic in ṡ: explicit, it overshoots once dt J > 2,
      J = k(3ṡ² − 1)/2 = −∂(f_r/M_r)/∂ṡ, and a ṡ thrown far from 1 (a push, a residual
      policy's torque) then runs to ±inf in a few steps. Where dt J > 1 the step is
      implicit in it too — dt J − 1 is added to the denominator, so Δṡ never exceeds
      the Newton step −(f_r/M_r)/J — and where dt J ≤ 1 (ṡ near 1 inside the rate
      limit k dt ≤ 1) the step is the one above, bit for bit.
    * ``"symplectic"``: symplectic Euler — ṡ ← ṡ + dt·s̈, s ← s + dt·ṡ(new),
      σ ← σ + dt·σ̇ (the explicit scheme the implicit one is compared with).

    The torque held over the period (``hold``):

    * ``"midpoint"`` (default): the law's torque at the sample plus δ
      (:meth:`hold_correction`), the change of its velocity feedback B = ∂τ/∂q̇ (of the
      reference torque τ_r⁰, the phase damping R and the pump) between the sample and the
      period's midpoint, the velocity there predicted with the model and the held torque
      itself (linearly implicit). A zero-order hold turns the law's velocity feedback into
      an explicit Euler step: the work-free τ_r⁰ = G(q̇) q̇ (G skew) is a gyroscopic torque
      that turns the arm's velocity fast on a path's slow stretches, and an explicit step
      grows such a rotation at rate ω by √(1 + (ω dt)²) per step; the midpoint keeps it
      (``docs/control_rates.md``). δ = O(dt), and 0 at rest (q̇ = 0). The prediction
      subtracts b̂, the model's recent acceleration error — what it predicted for the last
      period less what the arm did, (q̇_k − q̇_{k−1})/dt, low-passed with time constant
      ``hold_filter_s`` (0.1 s; 0: none) — so a payload or a model error the nominal model
      does not know does not bias δ.
    * ``"sample"``: the law's torque at the sample, held (a plain zero-order hold).

    The direction guard (``direction_guard`` c ≥ 0; None: :data:`DIRECTION_GUARD`; 0: off):
    the phase channel's torque −μ τ_q̇/v points along the arm's velocity, and CONTROL_LAW.md
    takes τ_q̇/v := 0 "when speed ≈ 0". Sampled, "≈ 0" is a matter of the period: where the
    velocity turns by about itself within one (the arm held near a stall by a persistent
    torque — a payload, a residual policy), the held direction flips from sample to sample,
    the braking channel (μ > 0) becomes a relay, and the loop settles into a period-2 cycle
    in which the sampled law creates energy — 9.9 J in 5 s on the two-link at 250 Hz under
    a constant 0.1 τ_max ⊙ (1, −1) (tuned gains, random path 1), its port's balance
    (:class:`agents.energy_tank.PortDissipation`) broken by joules. With the guard, while
    μ > 0, the direction's speed is v_g = max(v, c |Δq̇|_M), Δq̇ = dt (a − b̂) the velocity
    change the midpoint hold's memory expected over the last period (the model's
    acceleration under the torque held, less its error estimate b̂: a prediction, so sensor
    noise barely moves it; the guard waits for that memory and is off with the sample
    hold), and

    .. math::

        \\tau_\\mu = -\\frac{\\mu}{v_g} M(q)\\dot q, \\qquad
        \\dot\\sigma_0 = \\frac{v^2}{v_g \\sqrt{M_r(s)}}

    (σ̇ = σ̇₀ + the re-synchronisation), so the channel's power −μ v²/v_g is still
    −μ √M_r σ̇₀ and the storage balance of Theorem 4.1 holds exactly in continuous time
    for any v_g ≥ v (``tests/test_passivity.py``, "guarded"). A driving channel (μ ≤ 0) is
    left alone: its flips dissipate, and weakening it would hold a slow arm in a stall.
    Where the velocity changes by less than v/c over a period — on the path — v_g = v and
    the law is unchanged, bit for bit (``bench/direction_guard.py``). In the cycle above it
    is a damper of rate ≤ 1/(c dt) instead: the energy the sampled law creates falls from
    9.9 J to 0.03 J (c = 4).
    """

    def __init__(
        self,
        model: RobotModel,
        tables: PassivityTables,
        gains: PassivityGains | None = None,
        start: str = "nearest",
        sd0: float | None = None,
        integrator: str = "implicit",
        hold: str = "midpoint",
        dt_s: float | None = None,
        hold_filter_s: float = HOLD_FILTER_S,
        direction_guard: float | None = None,
    ) -> None:
        if tables.n != model.n:
            raise InvalidConfigError(f"tables have {tables.n} joints, model has {model.n}")
        if start not in _STARTS:
            raise InvalidConfigError(f"start must be one of {_STARTS}, got {start!r}")
        if integrator not in INTEGRATORS:
            raise InvalidConfigError(f"integrator must be one of {INTEGRATORS}, got {integrator!r}")
        if hold not in HOLDS:
            raise InvalidConfigError(f"hold must be one of {HOLDS}, got {hold!r}")
        if not (math.isfinite(hold_filter_s) and hold_filter_s >= 0.0):
            raise InvalidConfigError(f"hold_filter_s must be >= 0, got {hold_filter_s!r}")
        if direction_guard is None:
            direction_guard = DIRECTION_GUARD
        if not (math.isfinite(direction_guard) and direction_guard >= 0.0):
            raise InvalidConfigError(f"direction_guard must be >= 0, got {direction_guard!r}")
        self.integrator, self.hold, self.hold_filter_s = integrator, hold, float(hold_filter_s)
        self.direction_guard = float(direction_guard)
        # The midpoint hold's memory: (has a previous step, its dt, its q̇ (n), the model's
        # acceleration under its torque (n), the acceleration error estimate b̂ (n)).
        self._hold_state = np.zeros(2 + 3 * model.n)
        self.model = model
        self.tables = tables
        self.gains = gains or PassivityGains()
        self.n = model.n
        self.k_diag = self.gains.stiffness(self.n)
        self.d_diag = self.gains.damping(self.n)
        self.start = start
        self.sd0 = sd0
        self._state = np.zeros(3)  # (s, ṡ, σ), integrated in place by the compiled law
        g = self.gains
        if g.torque_limits_nm is not None and len(g.torque_limits_nm) != self.n:
            raise InvalidConfigError(
                f"torque_limits_nm has {len(g.torque_limits_nm)} entries, the robot has {self.n}"
            )
        box = g.torque_limits_nm or (0.0,) * self.n
        gains_vector = np.array(
            [g.kappa, g.R, g.k_pump, 1.0 if g.pump == "metric" else 0.0, g.speed_eps,
             g.sync_rate, g.sync_ratio, 0.0 if g.torque_limits_nm is None else 1.0,
             1.0 if integrator == "implicit" else 0.0, 1.0 if hold == "midpoint" else 0.0,
             float(hold_filter_s), self.direction_guard, *self.k_diag, *self.d_diag, *box]
        )  # fmt: skip
        self._tables = law_tables(gains_vector, tables.knots, tables.coefficients, tables.period_s)
        self._out = np.zeros(len(OUT) + 4 * self.n)
        self._zeros = np.zeros(self.n)
        self.mode_frequency_rad_s = max_mode_frequency(model, tables.q_samples(), self.k_diag)
        """ω_max, the fastest mode of φ's springs on the path (:func:`max_mode_frequency`)."""
        self.phase_rate_1_s = phase_rate(tables, self.gains)
        """max_s (R + q_r'ᵀD q_r')/M_r(s), the phase loop's damping rate
        (:func:`~agents.passivity_sampling.phase_rate`)."""
        self._checked_dt: float | None = None
        if dt_s is not None:
            self.check_rate(dt_s)
        self._last_tau: FloatArray | None = None

    def max_period_s(self) -> float:
        """The longest control period (s) this controller serves on its path with its gains
        (:func:`~agents.passivity_sampling.max_period_s`), the shortest of three:

        * springs: ω_max dt ≤ θ(c) (:func:`~agents.passivity_sampling.spring_angle_limit`:
          1 at the default c = 1, 1/√2 without a damper), ω_max the fastest mode of φ's
          springs on the path (:attr:`mode_frequency_rad_s`), c = min_j D_j / (K_j dt) the
          damper's share. A spring mode held over dt with the damper D = cK dt grows per
          step by :func:`~agents.passivity_sampling.spring_growth`, < 1 iff c > ½ and
          c (ω dt)² < 2 (ω dt < √2 at c = 1); without a damper (the paper's law) an isolated
          mode grows at every period. The limit keeps a factor √2 inside either
          (``docs/control_rates.md``).
        * virtual pump: k dt ≤ 1 (:data:`~agents.passivity_sampling.PUMP_LIMIT`), k the
          pump gain: f_r's −k(ṡ − 1) in s̈ is stepped explicitly and grows once k dt > 2
          (:func:`~agents.passivity_sampling.pump_growth`).
        * phase loop: c_phase dt ≤ 2 (:data:`~agents.passivity_sampling.PHASE_DAMPING_LIMIT`),
          c_phase = max_s (R + q_r'ᵀD q_r')/M_r(s) (:attr:`phase_rate_1_s`): the virtual
          system and the arm's motion along the path, damped against each other, keep ρ ≤ 1
          beyond c dt = 2 (:func:`~agents.passivity_sampling.phase_growth`).

        The phase spring κ needs no limit (σ integrates the arm's speed), nor does the
        velocity turning of τ_r⁰ (held at the midpoint). Why each, with figures:
        ``docs/control_rates.md``."""
        d = float(np.min(self.d_diag / self.k_diag))  # D_j / K_j (s); c = d / dt
        return max_period_s(self.mode_frequency_rad_s, d, self.phase_rate_1_s, self.gains.k_pump)

    def check_rate(self, dt_s: float) -> None:
        """Raise :class:`~ptrack_gym.errors.ControlRateError` if ``dt_s`` exceeds
        :meth:`max_period_s`, naming the loop that sets the limit."""
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise InvalidConfigError(f"the control period must be positive, got {dt_s!r}")
        limit = self.max_period_s()
        if dt_s > limit * (1.0 + 1e-12):
            phase_limit = PHASE_DAMPING_LIMIT / self.phase_rate_1_s
            k = self.gains.k_pump
            if k > 0.0 and PUMP_LIMIT / k <= limit * (1.0 + 1e-12):
                why = (
                    f"its virtual pump k = {k:.4g} 1/s steps ṡ explicitly, {k * dt_s:.3g} per "
                    f"period (at most {PUMP_LIMIT:g}); lower the pump (the gain rate 'lam')"
                )
            elif phase_limit <= limit * (1.0 + 1e-12):
                why = (
                    f"its phase damping (R + q_r'ᵀD q_r')/M_r(s) reaches "
                    f"{self.phase_rate_1_s:.4g} 1/s on the path's slowest stretch, "
                    f"{self.phase_rate_1_s * dt_s:.3g} per period (at most "
                    f"{PHASE_DAMPING_LIMIT:g}); lower R (the gain rate 'rho') or the joint "
                    f"dampers D (the gain rate 'damping_ratio')"
                )
            else:
                why = (
                    f"the fastest mode of its springs K on the path turns at "
                    f"{self.mode_frequency_rad_s:.4g} rad/s, "
                    f"{self.mode_frequency_rad_s * dt_s:.3g} rad per period; lower K (the "
                    f"gain rate 'omega')"
                )
            raise ControlRateError(
                f"the passivity controller cannot serve a control period of "
                f"{dt_s * 1e3:.4g} ms ({1.0 / dt_s:.4g} Hz) on this path with these gains: its "
                f"limit is {limit * 1e3:.4g} ms ({1.0 / limit:.4g} Hz): {why}, or raise the "
                f"control rate (docs/control_rates.md)"
            )
        self._checked_dt = dt_s

    @property
    def state(self) -> PassivityState:
        """The controller's state (s, ṡ, σ) after its last step."""
        s, sd, sigma = self._state.tolist()
        return PassivityState(s=s, sd=sd, sigma=sigma)

    @property
    def last(self) -> LawOutput | None:
        """Everything the law computed at the last step (None before the first)."""
        if self._last_tau is None:
            return None
        n, out = self.n, self._out
        k = len(OUT)
        scalars = dict(zip(OUT, out[:k].tolist(), strict=True))
        return LawOutput(
            tau=self._last_tau.copy(),
            tau_sync=out[k : k + n].copy(),
            tau_r0=out[k + n : k + 2 * n].copy(),
            pump_torque=out[k + 2 * n : k + 3 * n].copy(),
            hold_correction=out[k + 3 * n : k + 4 * n].copy(),
            **scalars,
        )

    # -- the law (pure) --------------------------------------------------------------
    def law(
        self,
        q: FloatArray,
        qd: FloatArray,
        s: float,
        sd: float,
        sigma: float,
        dt: float = 0.0,
        accel_bias: FloatArray | None = None,
        turn: FloatArray | None = None,
    ) -> LawOutput:
        """Evaluate the control law at (q, q̇, s, ṡ, σ); changes no state.

        Phase re-synchronisation (``gains.sync_rate`` γ > 0; not in the paper):
        the paper's σ integrates the speed ratio v/√M_r(s), which counts *any* motion, so
        the initial snap onto the path from an off-path rest start can leave σ ahead of the
        arm's actual place on the path. At low speed that phase defect makes the μ channel
        brake the arm (κ s̃ and W_r'(σ) at the wrong phase), the spring φ passes the brake
        on to s, and the pair can stall at ṡ ≪ 1 (the trap of
        ``docs/passivity_gain_study.md``). With γ > 0,

            σ̇ = v/√M_r(s) + w γ Δ,   Δ = (q − q_r(σ))ᵀ M(q) q_r'(σ) / (q_r'(σ)ᵀ M(q) q_r'(σ)),

        Δ the Gauss–Newton step from σ toward the point of the path nearest q in the
        metric M(q), and w = 1 − 3x² + 2x³, x = min(v/(r̄ √M_r(s)), 1), r̄ =
        ``gains.sync_ratio``: w = 1 at rest, w = 0 at and above the speed ratio r̄. So σ
        relaxes toward the arm's phase at rate γ while the arm is slow, and the law is
        the paper's exactly whenever v/√M_r(s) ≥ r̄. On the reference Δ = 0 (q = q_r(σ)),
        so the term vanishes there for any r̄ and Lemma 5.1 holds. r̄ > 1 lets it act at
        nominal speed too: there the paper's σ can hold a steady phase defect s̃ that the
        phase spring maps into a slowly decaying transverse path error
        (``docs/passivity_gain_study.md``). With u = w γ Δ the storage function's balance
        becomes
        Ė = −R s̃̇² + pump power + q̇ᵀτ_d + (W_r'(σ) − κ s̃ − R s̃̇) u, the last term
        ``sync_power`` (derivation: σ̇ = σ̇₀ + u enters Ẇ_r(σ) and ψ̇, while the μ channel
        delivers −μ√M_r σ̇₀; tested on the exact closed loop): Theorem 4.1's
        Ė = −R s̃̇² holds only where v/√M_r(s) ≥ r̄. ``sigma_dot`` in the output is the
        full σ̇ (what σ integrates); s̃̇ = ṡ − σ̇ uses it too.

        Saturation-aware reference torque (``gains.torque_limits_nm`` = τ_max given; not in
        the paper): the paper's torque is τ = τ_rest + τ_r⁰ with τ_rest = −μ τ_q̇/v − ∂φ/∂q
        + f. τ_r⁰ = (v²/M_r) τ_r − (q̇ᵀτ_r/M_r) τ_q̇ grows like σ̇², and once it exceeds
        τ_max the actuators' per-joint clip turns this work-free torque into one that does
        work, q̇ᵀclip(τ) ≠ q̇ᵀτ. After a fast push that work raises σ̇, hence τ_r⁰, hence
        the work: a blow-up (``docs/worst_case.md``). With τ_max given the law sends

            τ = τ_rest + α τ_r⁰,  α = max{a ∈ [0, 1] : |τ_rest,j + a τ_r⁰,j| ≤ B_j ∀ j},
            B_j = max(τ_max,j, |τ_rest,j|)

        (a = 0 is always feasible; where τ_rest alone exceeds a limit, τ_r⁰ may not push
        that joint further out). α = 1 — the paper's law exactly — whenever the paper's
        torque fits in the box, in particular on the reference (Lemma 5.1). Since
        q̇ᵀτ_r⁰ = 0 for every α and s̈ does not involve τ_r⁰, the power the law sends and
        the storage balance are the paper's: Ė = −R s̃̇² + pump power + q̇ᵀτ_d, now with
        the torque the actuators really deliver whenever τ_rest fits (without the remedy
        the clip adds q̇ᵀ(clip(τ) − τ) to Ė, of either sign and unbounded in σ̇).
        """
        g = self.gains
        ref, ref_sigma = self.tables.pair(s, sigma)
        mass = self.model.mass_matrix(q)  # (n, n)
        tau_qd = mass @ qd  # (n,) the dual of q̇
        speed2 = max(float(qd @ tau_qd), 0.0)
        speed = np.sqrt(speed2)
        m_r = ref.m_r
        sigma_dot = np.sqrt(speed2 / m_r)
        sync = 0.0  # u, the re-synchronisation's part of σ̇
        if g.sync_rate > 0.0:
            x = min(sigma_dot / g.sync_ratio, 1.0)
            w = 1.0 - x * x * (3.0 - 2.0 * x)
            if w > 0.0:
                t_sigma = mass @ ref_sigma.qd  # M(q) q_r'(σ)
                delta = float((q - ref_sigma.q) @ t_sigma) / float(ref_sigma.qd @ t_sigma)
                sync = w * g.sync_rate * delta
                sigma_dot = sigma_dot + sync
        s_t, s_td = s - sigma, sd - sigma_dot
        mu_j = ref_sigma.w_r_d - g.kappa * s_t - g.R * s_td  # μ √M_r(s) (J)
        v_g = speed  # the direction's speed (``direction_guard``: max(v, c |Δq̇|_M))
        guard = self.direction_guard
        if guard > 0.0 and dt > 0.0 and speed > g.speed_eps and turn is not None and mu_j > 0.0:
            dv = np.asarray(turn, dtype=np.float64)
            v_g = max(speed, guard * np.sqrt(max(float(dv @ mass @ dv), 0.0)))
            if v_g > speed:  # σ̇₀ = v²/(v_g √M_r): the channel's power stays −μ √M_r σ̇₀
                sigma_dot = sigma_dot - (1.0 - speed / v_g) * np.sqrt(speed2 / m_r)
                s_td = sd - sigma_dot
                mu_j = ref_sigma.w_r_d - g.kappa * s_t - g.R * s_td
        err = q - ref.q  # (n,)
        dphi_dq = self.k_diag * err  # ∂φ/∂q; ∂φ/∂q_r = −∂φ/∂q
        damp = self.d_diag * (qd - ref.qd * sd)  # D ė, ė = q̇ − q_r'(s) ṡ (N·m)
        spring = dphi_dq + damp  # the spring-damper's pull on the arm, negated
        phi = 0.5 * float(err @ dphi_dq)
        psi = 0.5 * g.kappa * s_t**2
        tau_r0 = (speed2 / m_r) * ref.tau - (float(qd @ ref.tau) / m_r) * tau_qd
        mu = mu_j / np.sqrt(m_r)
        e_c = -g.kappa * s_t - g.R * s_td + float(spring @ ref.qd)
        h_plus_w = 0.5 * speed2 + self.model.potential(q) + ref_sigma.w_r
        h_r = 0.5 * m_r * (sd * sd - 1.0)
        direction = tau_qd if g.pump == "metric" else qd
        f = -g.k_pump * h_plus_w * direction
        rest = f - spring  # τ − τ_r⁰: everything that does work
        if speed > g.speed_eps:
            rest = rest - (mu / v_g) * tau_qd
        alpha = 1.0
        if g.torque_limits_nm is not None:  # saturation-aware: α τ_r⁰ into the box
            alpha = fit_scale(rest, tau_r0, np.asarray(g.torque_limits_nm))
            tau_r0 = alpha * tau_r0
        tau_sync = tau_r0 - spring
        if speed > g.speed_eps:
            tau_sync = tau_sync - (mu / v_g) * tau_qd
        f_r = -g.k_pump * h_r * sd
        s_dd = (-0.5 * ref.m_r_d * (sd * sd - 1.0) + e_c + f_r) / m_r
        tau = tau_sync + f
        hold = np.zeros(self.n)
        if dt > 0.0 and self.hold == "midpoint":
            b_hat = self._zeros if accel_bias is None else np.asarray(accel_bias, dtype=np.float64)
            hold = self.hold_correction(q, qd, mass, tau, ref.tau, ref.m_r, alpha, dt, b_hat)
            tau = tau + hold
        return LawOutput(
            tau=tau,
            s_dd=float(s_dd),
            sigma_dot=float(sigma_dot),
            energy=float(h_plus_w + h_r + phi + psi),
            h_plus_w=float(h_plus_w),
            h_r=float(h_r),
            phi=phi,
            psi=float(psi),
            pump_power=float(qd @ f + sd * f_r),
            dissipation=float(g.R * s_td**2 + damp @ (qd - ref.qd * sd)),
            sync_power=float(mu_j * sync),
            s_tilde=float(s_t),
            s_tilde_dot=float(s_td),
            tau_sync=tau_sync,
            tau_r0=tau_r0,
            pump_torque=f,
            path_error=float(np.linalg.norm(err)),
            r0_scale=float(alpha),
            hold_correction=hold,
        )

    def hold_correction(
        self,
        q: FloatArray,
        qd: FloatArray,
        mass: FloatArray,
        tau: FloatArray,
        tau_r: FloatArray,
        m_r: float,
        alpha: float,
        dt: float,
        accel_bias: FloatArray,
    ) -> FloatArray:
        """δ (N·m, (n,)): what the midpoint hold adds to the law's torque τ at the sample
        (see the class docstring), with B the law's velocity feedback through the reference
        torque, the phase damping and the pump,

        .. math::

            B = \\frac{\\alpha (2\\tau_r p^T - p\\,\\tau_r^T)}{M_r}
                - \\frac{\\alpha P + R}{M_r v^2}\\, p p^T - k\\, d\\, p^T,
            \\quad p = M(q)\\dot q,\\ v^2 = \\dot q^T p,\\ P = \\dot q^T \\tau_r,
            \\ d = p \\text{ (metric) or } \\dot q \\text{ (paper)},

            y = (M - \\tfrac{dt}{2} B)^{-1} (\\tau - h(q, \\dot q) - M \\hat b),
            \\quad \\delta = \\tfrac{dt}{2} B y,

        h = C(q, q̇)q̇ + g(q) from the model; y is the arm's acceleration over the period
        predicted by the model less its recent error b̂ (``accel_bias``, rad/s²). B is ∂τ/∂q̇
        of τ_r⁰ and of the μ channel's −μ τ_q̇/v less their parts proportional to M (a common
        rate of every velocity direction, which the two cancel on the path) and with the μ
        channel's turning of its direction written as on the path (μ/v = −αP/M_r there), so B
        stays bounded as v → 0; the p pᵀ term is dropped where v ≤ ``speed_eps``. With the
        saturation-aware box, δ is scaled (by :func:`fit_scale`) so that it never pushes a
        joint past max(τ_max, |τ|); where M − (dt/2)B is singular, δ = 0."""
        g = self.gains
        p = mass @ qd  # (n,)
        speed2 = float(qd @ p)
        direction = p if g.pump == "metric" else qd
        b = alpha * (2.0 * np.outer(tau_r, p) - np.outer(p, tau_r)) / m_r
        if np.sqrt(max(speed2, 0.0)) > g.speed_eps:
            b = b - (alpha * float(qd @ tau_r) + g.R) / (m_r * speed2) * np.outer(p, p)
        b = b - g.k_pump * np.outer(direction, p)
        bias = self.model.inverse_dynamics(q, qd, np.zeros(self.n))
        try:
            y = np.linalg.solve(mass - 0.5 * dt * b, tau - bias - mass @ accel_bias)
        except np.linalg.LinAlgError:
            return np.zeros(self.n)
        delta = 0.5 * dt * (b @ y)
        if not np.all(np.isfinite(delta)):
            return np.zeros(self.n)
        if g.torque_limits_nm is not None:
            delta = fit_scale(tau, delta, np.asarray(g.torque_limits_nm)) * delta
        return delta

    # -- the Controller protocol -------------------------------------------------------
    def reset(
        self,
        q: FloatArray,
        qd: FloatArray,
        s_ref: float = 0.0,
        *,
        s0: float | None = None,
        sd0: float | None = None,
        sigma0: float | None = None,
    ) -> None:
        """Set (s, ṡ, σ) for a new episode (see the class docstring for the defaults).

        Keyword arguments ``s0``, ``sd0``, ``sigma0`` override the choice.
        """
        q, qd = state_arrays(q, qd)
        if s0 is None:
            s0 = self.tables.projector.nearest(q).s if self.start == "nearest" else float(s_ref)
        if sigma0 is None:
            sigma0 = s0
        if sd0 is None:
            sd0 = self.sd0
        if sd0 is None:
            m = self.model.mass_matrix(q)
            sd0 = float(np.sqrt(max(float(qd @ m @ qd), 0.0) / self.tables(s0).m_r))
        self._state[:] = (float(s0), float(sd0), float(sigma0))
        self._hold_state[:] = 0.0
        self._last_tau = None

    def step(self, q: FloatArray, qd: FloatArray, dt: float) -> FloatArray:
        """τ (N·m) for the measured (q, q̇); then integrate (s, ṡ, σ) over ``dt`` (s).

        The compiled twin of :meth:`step_numpy` (:func:`agents.passivity_kernel.law_step`)."""
        if dt != self._checked_dt and dt > 0.0:
            self.check_rate(dt)
        q, qd = state_arrays(q, qd)
        tau = np.empty(self.n)
        bias = self._zeros  # C(q, q̇)q̇ + g(q), read by the midpoint hold only
        if self.hold == "midpoint" and dt > 0.0:
            bias = self.model.inverse_dynamics(q, qd, self._zeros)
        law_step(
            q, qd, self.model.mass_matrix(q), self.model.potential(q), bias, dt,
            self._state, self._hold_state, *self._tables, tau, self._out,
        )  # fmt: skip
        self._last_tau = tau
        return tau

    def step_numpy(self, q: FloatArray, qd: FloatArray, dt: float) -> FloatArray:
        """The readable reference of :meth:`step`: :meth:`law` at the current state, then
        one step of the class docstring's ``integrator``."""
        if dt != self._checked_dt and dt > 0.0:
            self.check_rate(dt)
        st = self.state
        q, qd = state_arrays(q, qd)
        n, hs = self.n, self._hold_state
        midpoint = self.hold == "midpoint" and dt > 0.0
        # the direction guard's Δq̇ = dt (a − b̂): the velocity change the hold's memory
        # expected over the last period (its model's acceleration less its error estimate)
        turn = dt * (hs[2 + n : 2 + 2 * n] - hs[2 + 2 * n :]) if midpoint and hs[0] > 0.5 else None
        if midpoint and hs[0] > 0.5 and self.hold_filter_s > 0.0:  # b̂ ← b̂ + λ (error − b̂)
            error = hs[2 + n : 2 + 2 * n] - (qd - hs[2 : 2 + n]) / hs[1]
            lam = 1.0 - math.exp(-dt / self.hold_filter_s)
            hs[2 + 2 * n :] += lam * (error - hs[2 + 2 * n :])
        out = self.law(q, qd, st.s, st.sd, st.sigma, dt, hs[2 + 2 * n :], turn)
        if midpoint:  # what the model predicts the arm does under the torque sent
            h = self.model.inverse_dynamics(q, qd, np.zeros(n))
            hs[2 + n : 2 + 2 * n] = np.linalg.solve(self.model.mass_matrix(q), out.tau - h)
            hs[2 : 2 + n], hs[0], hs[1] = qd, 1.0, dt
        sd_dot = dt * out.s_dd
        if self.integrator == "implicit" and dt > 0.0:
            g, ref = self.gains, self.tables(st.s)
            a = (g.kappa + float(ref.qd @ (self.k_diag * ref.qd))) / ref.m_r
            c = (g.R + float(ref.qd @ (self.d_diag * ref.qd))) / ref.m_r
            b = (float(ref.qd @ (self.k_diag * qd)) + g.kappa * out.sigma_dot) / ref.m_r
            limit = max(dt * g.k_pump * (1.5 * st.sd**2 - 0.5) - 1.0, 0.0)  # the pump's J
            sd_dot = dt * (out.s_dd + dt * (b - a * st.sd)) / (1.0 + c * dt + a * dt * dt + limit)
        sd_new = st.sd + sd_dot
        self._state[:] = (st.s + dt * sd_new, sd_new, st.sigma + dt * out.sigma_dot)
        return out.tau

    def diagnostics(self) -> dict[str, float]:
        """s, ṡ, σ after the last step, and the law's scalars at that step."""
        st = self.state
        d = {"s": st.s, "sd": st.sd, "sigma": st.sigma}
        out = self.last
        if out is not None:
            d.update({name: getattr(out, name) for name in DIAGNOSTICS})
        return d

    def residual_features(self, max_speed_rad_s: float) -> FeatureBlock:
        """Phase of s (sin, cos), ṡ, σ̇, s̃ = s − σ, path error |q_r(s) − q| and its vector
        (6 + n entries; bounds ±1, ±10, [0, 10], ±S, [0, 2π], ±2π)."""
        n, period = self.n, self.tables.period_s
        two_pi = 2.0 * math.pi
        names = (
            "sin_phase_s", "cos_phase_s", "sd", "sigma_dot", "s_tilde_s", "path_error_rad",
            *[f"path_error_{j}_rad" for j in range(n)],
        )  # fmt: skip
        high = np.concatenate([[1.0, 1.0, 10.0, 10.0, period, two_pi], np.full(n, two_pi)])
        low = -high
        low[3] = 0.0  # σ̇ ≥ 0
        low[5] = 0.0  # a distance

        def values(q: FloatArray, qd: FloatArray) -> FloatArray:
            st = self.state
            if not (math.isfinite(st.s) and math.isfinite(st.sd)):  # a diverged law: NaN
                return np.full(len(names), math.nan)
            ref = self.tables(st.s)
            speed2 = max(float(qd @ self.model.mass_matrix(q) @ qd), 0.0)  # q̇ᵀMq̇ (J)
            err = ref.q - q  # (n,) rad
            omega = two_pi * st.s / period
            head = [
                math.sin(omega),
                math.cos(omega),
                st.sd,
                math.sqrt(speed2 / ref.m_r),
                st.s - st.sigma,
                float(np.linalg.norm(err)),
            ]
            return np.concatenate([head, err])

        return FeatureBlock(names, low, high, values)


def build(
    ctx: ControlContext, gains: PassivityGains | Mapping[str, Any] | None = None
) -> PassivityController:
    """The controller for a context: its default gains, the given gains, or gains from the
    given rates (a mapping, e.g. tuned ones).

    Raises:
        InvalidPathError: the path is stationary for the law (M_r below β somewhere).
        ControlRateError: the context's control period exceeds what the gains serve on the
            path (:meth:`PassivityController.max_period_s`); default and rate-given gains
            are capped (:func:`cap_for_rate`) and never are.
    """
    tables = passivity_tables(ctx.path, ctx.model)
    if gains is None:
        gains = default_gains(ctx, tables)
    elif isinstance(gains, Mapping):
        gains = gains_from_rates(ctx, gains, tables)
    return PassivityController(ctx.model, tables, gains, dt_s=ctx.dt_s)


def build_paper(
    ctx: ControlContext, gains: PassivityGains | Mapping[str, Any] | None = None
) -> PassivityController:
    """The paper's law exactly (:data:`PAPER_LAW`) with the robot's (or the given) rates;
    given rates that :data:`PAPER_LAW` fixes otherwise are refused (they could not act)."""
    if isinstance(gains, Mapping):
        clash = sorted(k for k, v in PAPER_LAW.items() if k in gains and gains[k] != v)
        if clash:
            raise InvalidConfigError(
                f"the paper's law fixes {', '.join(f'{k}={PAPER_LAW[k]!r}' for k in clash)}; "
                f"use the 'passivity' controller for other values"
            )
    if isinstance(gains, PassivityGains):
        if gains.sync_rate or gains.torque_limits_nm is not None or np.any(np.asarray(gains.D)):
            raise InvalidConfigError(
                "the paper's law has no sync_rate, no torque_limits_nm and no damper D"
            )
        return build(ctx, gains)
    return build(ctx, {**dict(gains or {}), **PAPER_LAW})
