"""A virtual energy tank that pays for a residual's injected energy: :class:`EnergyTank`.

The passivity controller's storage E = H + W_r(σ) + H_r + φ + ψ obeys (CONTROL_LAW.md)

.. math::

    \\dot E = -D + P_{pump} + P_{sync} + \\dot q^\\top \\tau_d + \\dot q^\\top \\tau_{res},

D ≥ 0 its passive dissipation (R s̃̇² + ėᵀDė), P_pump and P_sync the pump's and the
re-synchronisation's power, τ_d the disturbance and τ_res a residual added to the law's
torque. A learned τ_res with q̇ᵀτ_res > 0 injects energy nothing accounts for. The tank
(Ferraguti et al., ICRA 2013 and T-RO 2015; ``../shared/TANK.md``) is a store T with

.. math::

    \\dot T = \\beta D - \\dot q^\\top \\tau_{res}, \\qquad 0 \\le \\beta \\le 1,

filled only by energy the law has already dissipated and paying for every joule the
residual injects, capped at T_max (a quiet stretch banks no more). Then

.. math::

    \\frac{d}{dt}(E + T) = -(1 - \\beta) D + P_{pump} + P_{sync} + \\dot q^\\top \\tau_d
    \\le P_{pump} + P_{sync} + \\dot q^\\top \\tau_d

whatever the network outputs, and E ≤ E(0) + T(0) + ∫(P_pump + P_sync + q̇ᵀτ_d) as long as
T ≥ 0. In discrete time (one control step of length Δt) the tank is kept at the law's
*sampled port*, where energy really changes hands (Franken et al. 2011's passivity layer):

* **gate** (:meth:`EnergyTank.gate`, before the step): the residual is scaled by
  λ ∈ [0, 1], the largest with W(λ) ≤ T − T_min, W the work λτ_res is predicted to do over
  the step on the nominal model — semi-implicit Euler, q̇⁺ = q̇ + Δt M⁻¹(τ_base + λτ_res − h):
  W(λ) = λ a₁ + λ² a₂, a₁ = Δt (q̇ + Δt M⁻¹(τ_base − h))ᵀτ_res, a₂ = Δt² τ_resᵀM⁻¹τ_res ≥ 0.
  A correction within the budget (W(1) ≤ T − T_min) passes whole; with the tank at or
  below its floor it is held back entirely (λ = 0: the base alone), a dissipative one
  too (TANK.md's "scaled to zero": a torque opposing the arm can hold it near a stall,
  where the sampled law creates energy — fill);
* **settle** (:meth:`EnergyTank.settle`, after it): T ← min(T_max, T − W), W the work the
  residual really did, (q_{k+1} − q_k)ᵀ(τ_applied − τ_base) — the env's ledger for τ_d.
  The floor T_min > 0 absorbs the prediction's error (a plant other than the model, the
  torque limits); T below 0 is reported (``overdrawn_j``), never hidden;
* **fill** (:meth:`EnergyTank.fill`, once the law has read the next state): with the energy
  the law really dissipated over the step, measured at its port (:class:`PortDissipation`),

  .. math::

      \\Delta_k = -(L_{k+1} - L_k) - \\tau_k^\\top (q_{k+1} - q_k)
                  + (P_{pump,k} + P_{sync,k}) \\Delta t,

  L = E − H the law's virtual storage and τ_k its torque held over the step. Where the
  sampled law *created* energy (Δ_k < 0) the tank pays it, T ← T + Δ_k, and the law owes
  it (its debt P ← P − Δ_k); a later Δ_k > 0 first repays the debt in full, r = min(Δ_k, P),
  and fills with β of the rest: T ← min(T_max, T + r + β(Δ_k − r)). In continuous time
  Δ = D dt; sampled, Δ_k = D_k Δt − ρ_k with a residue ρ_k that a torque held while the
  arm turns near a stall makes positive by joules (a residual holding 0.1 τ_max on the
  two-link at 250 Hz: 5.5 J over 5 s, which broke the balance when the tank was filled
  with β D Δt), and that sensor noise makes alternate in sign from step to step (hence the
  debt: paid and repaid, noise costs the tank nothing);
* **pay** (:meth:`EnergyTank.pay_arm`, with the fill): with what the arm gained over the
  step beyond the commanded torque's work, as the law measures it (:class:`ArmEnergyObserver`,
  u_k = ΔH − τ_kᵀΔq on the model at the measured states): u_k > 0 is paid, T ← T − u_k, and
  owed by the arm; a later u_k < 0 repays that debt, never more (a loss — friction, a
  disturbance braking the arm — fills nothing). With an exact sensor on the exact plant
  u_k is the disturbance's work, so the tank pays a push's energy too (the law's
  dissipation of it refills β of it); behind a delayed sensor u_k is energy the sampled
  loop gained that neither the law's port nor the residual's settlement sees (a chattering
  residual behind the 2-ms delay at 250 Hz: 12 J in 5 s).

Then, on what the law measures (E at its measured states, on its model), with u_j the
arm's observed gains and A_k ≥ 0 what the arm still owes the tank:

.. math::

    (E + T)_k - (E + T)_0 - \\sum (P_{pump} + P_{sync}) \\Delta t - W_d
    = \\sum_{j<k} (u_j - w_{d,j}) - A_k - (1 - \\beta) \\sum_{j<k} (\\Delta_j - r_j)^+
      - \\text{(cap)}

(w_{d,j} the disturbance's work over step j), "cap" ≥ 0 what T_max turned away, T_k read
after step k − 1's fill and pay. Since A_k = Σ u_j + (the losses that repaid nothing)
≥ max(0, Σ u_j), the right side is ≤ min(Σ (u_j − w_{d,j}), −W_d): on the exact plant with an
exact sensor u_j − w_{d,j} is the simulator's residue, so the excess is at most that
residue; behind any sensor, delayed or noisy, or on a plant other than the model, it is
at most −W_d — ≤ 0 where the disturbance did no net negative work (a delay alone), and at
most the energy a disturbance took out (damping, friction, braking torques) where a
wrong sensor or model booked some of that loss as a repayment (millijoules under the
noise preset).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from agents.base import FloatArray
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots.model import RobotModel


@dataclass
class EnergyTank:
    """The tank's parameters (J) and its level (module docstring).

    Args:
        beta: β ∈ [0, 1], the fraction of the law's dissipation that fills the tank.
        initial_j: T(0) ≥ ``floor_j``.
        floor_j: T_min > 0: an injecting residual is held back so T stays above it.
        cap_j: T_max ≥ ``initial_j``.

    Raises:
        InvalidConfigError: a value out of its domain.
    """

    beta: float = 0.5
    initial_j: float = 0.5
    floor_j: float = 0.01
    cap_j: float = 2.0
    level_j: float = field(init=False)
    withheld_j: float = field(init=False, default=0.0)
    """Energy the gate held back this episode: Σ W(1) − W(λ) over the steps (J; a
    dissipative correction held back at the floor counts negative)."""
    overdrawn_j: float = field(init=False, default=0.0)
    """The deepest the level went below 0 this episode (J, ≥ 0; 0 when it never did)."""
    created_j: float = field(init=False, default=0.0)
    """The most the sampled law owed the tank at any step this episode: the net energy it
    had created, paid from the tank and not yet dissipated again (J, ≥ 0)."""
    arm_gained_j: float = field(init=False, default=0.0)
    """The most the arm owed the tank at any step this episode: the net energy it had
    gained beyond the commanded torque's work (:class:`ArmEnergyObserver`), paid from the
    tank and not yet given back (J, ≥ 0)."""

    def __post_init__(self) -> None:
        values = (self.beta, self.initial_j, self.floor_j, self.cap_j)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
            raise InvalidConfigError(f"tank parameters must be finite numbers, got {values}")
        if not 0.0 <= self.beta <= 1.0:
            raise InvalidConfigError(f"tank_beta must be in [0, 1], got {self.beta}")
        if not 0.0 < self.floor_j <= self.initial_j <= self.cap_j:
            raise InvalidConfigError(
                "the tank needs 0 < tank_floor_j <= tank_initial_j <= tank_cap_j, got "
                f"{self.floor_j}, {self.initial_j}, {self.cap_j}"
            )
        self.reset()

    def reset(self) -> None:
        """A new episode: the level at T(0), nothing held back."""
        self.level_j = float(self.initial_j)
        self.withheld_j = 0.0
        self.overdrawn_j = 0.0
        self.created_j = 0.0
        self.arm_gained_j = 0.0
        self._debt_j = 0.0
        self._arm_debt_j = 0.0

    def gate(
        self,
        model: RobotModel,
        q: FloatArray,
        qd: FloatArray,
        tau_base: FloatArray,
        tau_res: FloatArray,
        dt_s: float,
    ) -> float:
        """λ ∈ [0, 1] for ``tau_res`` (N·m) at the measured (q, q̇) with the base's
        ``tau_base`` over a step of ``dt_s`` (module docstring); adds W(1) − W(λ) to
        :attr:`withheld_j`."""
        if not np.any(tau_res):
            return 1.0
        mass = np.asarray(model.mass_matrix(q))
        h = np.asarray(model.inverse_dynamics(q, qd, np.zeros_like(q)))  # C q̇ + g
        v_free = qd + dt_s * np.linalg.solve(mass, tau_base - h)
        a1 = dt_s * float(v_free @ tau_res)
        a2 = dt_s * dt_s * float(tau_res @ np.linalg.solve(mass, tau_res))
        budget = self.level_j - self.floor_j
        whole = a1 + a2
        if whole <= budget:
            return 1.0
        # at or below the floor the residual is held back entirely, its dissipative part
        # too: a torque that opposes the arm can hold it near a stall, where the sampled law
        # creates energy the tank must then pay (fill)
        lam = 0.0
        if budget > 0.0:  # W(λ) = a₁λ + a₂λ² rises through the budget once on (0, 1)
            lam = (
                budget / a1
                if a2 <= 0.0
                else (-a1 + math.sqrt(a1 * a1 + 4.0 * a2 * budget)) / (2.0 * a2)
            )
            lam = min(max(lam, 0.0), 1.0)
        self.withheld_j += whole - (a1 * lam + a2 * lam * lam)
        return lam

    def settle(self, work_j: float) -> None:
        """T ← min(T_max, T − W) after a step in which the residual did ``work_j`` (J)."""
        self.level_j = min(self.cap_j, self.level_j - float(work_j))
        self.overdrawn_j = max(self.overdrawn_j, -self.level_j)

    def fill(self, dissipated_j: float) -> None:
        """The tank after a step in which the law dissipated Δ = ``dissipated_j`` (J,
        :class:`PortDissipation`; module docstring): Δ < 0, created energy, is paid
        (T ← T + Δ) and owed; Δ > 0 repays what is owed, then fills with β of the rest, up
        to T_max. A non-finite Δ: nothing."""
        d = float(dissipated_j)
        if not math.isfinite(d):
            return
        if d < 0.0:
            self.level_j += d
            self._debt_j -= d
            self.created_j = max(self.created_j, self._debt_j)
            self.overdrawn_j = max(self.overdrawn_j, -self.level_j)
            return
        repaid = min(d, self._debt_j)
        self._debt_j -= repaid
        self.level_j = min(self.cap_j, self.level_j + repaid + self.beta * (d - repaid))

    def pay_arm(self, gained_j: float) -> None:
        """The tank after a step in which the arm gained u = ``gained_j`` (J) beyond the
        commanded torque's work (:class:`ArmEnergyObserver`; module docstring): u > 0 is
        paid (T ← T − u) and owed by the arm; u < 0 repays what is owed, never more — a
        loss (friction, a disturbance braking the arm) fills nothing. A non-finite u:
        nothing."""
        u = float(gained_j)
        if not math.isfinite(u):
            return
        if u > 0.0:
            self.level_j -= u
            self._arm_debt_j += u
            self.arm_gained_j = max(self.arm_gained_j, self._arm_debt_j)
            self.overdrawn_j = max(self.overdrawn_j, -self.level_j)
            return
        repaid = min(-u, self._arm_debt_j)
        self._arm_debt_j -= repaid
        self.level_j = min(self.cap_j, self.level_j + repaid)


@dataclass
class PortDissipation:
    """The energy the passivity law dissipated over each step, measured at its sampled port
    (J; module docstring):

    .. math::

        \\Delta_k = -(L_{k+1} - L_k) - \\tau_k^\\top (q_{k+1} - q_k)
                    + (P_{pump,k} + P_{sync,k}) \\Delta t,

    L = E − H = W_r(σ) + H_r + φ + ψ the law's virtual storage (its storage less the arm's
    energy H = ½ q̇ᵀM q̇ + U on its model), τ_k the torque it held over step k. In
    continuous time L̇ + q̇ᵀτ = P_pump + P_sync − D (CONTROL_LAW.md), so Δ = D dt; with a
    zero-order hold τ_kᵀ(q_{k+1} − q_k) is exactly the work the law's torque did on the
    arm, so Δ_k < 0 is energy the sampled law created, whatever the plant and the
    disturbance. Δ_k is known once the law has acted at k + 1.
    """

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """A new episode: no step recorded."""
        self._last: tuple[float, FloatArray, FloatArray, float] | None = None

    def record(
        self, diagnostics: dict[str, float], arm_energy_j: float, q: FloatArray,
        tau: FloatArray, dt_s: float,
    ) -> float:  # fmt: skip
        """Δ of the step before this one (0 at an episode's first step; NaN where a
        quantity is not finite), from this step's ``diagnostics`` (the law's, having acted
        at ``q`` (rad) with ``tau`` (N·m)) and the arm's energy H at the state it read (J),
        this step lasting ``dt_s`` (s)."""
        virtual = float(diagnostics["energy"]) - float(arm_energy_j)
        flows_j = supplied_power_w(diagnostics) * dt_s
        dissipated = 0.0
        if self._last is not None:
            last_virtual, last_q, last_tau, last_flows_j = self._last
            dissipated = -(virtual - last_virtual) - float(last_tau @ (q - last_q)) + last_flows_j
        self._last = (virtual, np.array(q, dtype=float), np.array(tau, dtype=float), flows_j)
        return dissipated if math.isfinite(dissipated) else math.nan


@dataclass
class ArmEnergyObserver:
    """The energy the arm gained over each step beyond the work the commanded torque did on
    it, as the law's sensors and model see it (J) — a passivity observer (Hannaford and
    Ryu, T-RO 2002) at the arm's port:

    .. math::

        u_k = H(q_{k+1}, \\dot q_{k+1}) - H(q_k, \\dot q_k) - \\tau_k^\\top (q_{k+1} - q_k),

    H = ½ q̇ᵀM q̇ + U on the nominal model at the measured states, τ_k the torque
    commanded over step k (base + residual, within the limits). With an exact sensor on the
    exact plant u_k is the disturbance's work over the step (+ the simulator's residue).
    A sensor other than the truth makes it differ by energy no force accounts for: with a
    state reported one step late, u_k = (τ_{k−1} − τ_k)ᵀ(q_k − q_{k−1}) in true states —
    positive, step after step, where a torque alternates while the arm moves (a residual
    chattering behind a delayed sensor: 12 J in 5 s on the two-link, which the law's port
    never sees). The tank pays u > 0 (:meth:`EnergyTank.pay_arm`), so its balance holds on
    what the law measures whatever the sensor; the price is that it pays the disturbance's
    injected work too. u_k is known once the next state is read.
    """

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """A new episode: no step recorded."""
        self._last: tuple[float, FloatArray] | None = None
        self._tau: FloatArray | None = None

    def record(self, arm_energy_j: float, q: FloatArray) -> float:
        """u of the step that ends at the measured ``q`` (rad), the arm's energy H there
        ``arm_energy_j`` (J): 0 at an episode's first step or before a torque was
        :meth:`commanded`; NaN where a quantity is not finite."""
        gained = 0.0
        if self._last is not None and self._tau is not None:
            last_energy, last_q = self._last
            gained = float(arm_energy_j) - last_energy - float(self._tau @ (q - last_q))
        self._last = (float(arm_energy_j), np.array(q, dtype=float))
        self._tau = None
        return gained if math.isfinite(gained) else math.nan

    def commanded(self, tau_nm: FloatArray) -> None:
        """The torque τ_k (N·m) held over the step that starts at the last :meth:`record`."""
        self._tau = np.array(tau_nm, dtype=float)


#: The storage flows a :class:`BalanceLedger` reads off a passivity base's diagnostics.
BALANCE_KEYS = ("energy", "pump_power", "sync_power")


def has_storage(diagnostics: dict[str, float]) -> bool:
    """Whether a controller's ``diagnostics`` carry a storage a :class:`BalanceLedger` can
    keep (every one of :data:`BALANCE_KEYS`: the passivity laws')."""
    return all(key in diagnostics for key in BALANCE_KEYS)


def supplied_power_w(diagnostics: dict[str, float]) -> float:
    """P_pump + P_sync (W): the power a passivity law's ``diagnostics`` say its pump and
    re-synchronisation supply to its storage (the flows both ledgers credit)."""
    return float(diagnostics["pump_power"]) + float(diagnostics["sync_power"])


@dataclass
class BalanceLedger:
    """The tank's balance along one episode (module docstring; ``../shared/TANK.md``):

    .. math::

        x_k = (E_k + T_k) - (E_0 + T_0) - \\sum_{j<k} (P_{pump,j} + P_{sync,j}) \\Delta t - W_d(t_k)

    (J), E_k the law's storage at the state it acted on at step k (its model, its measured
    state), T_k the tank's level then (0 without a tank), W_d the disturbance's work since
    reset (the env's ledger). On the exact closed loop x_k ≤ the discrete residue with a
    tank, whatever the residual does; a residual without one, or a plant or sensor other
    than the law's, can make it grow. :attr:`excess_max_j` is the episode's largest x_k
    (≥ 0: x_0 = 0 is among them; +inf once the law's storage or state is not finite).
    """

    excess_j: float = field(init=False, default=math.nan)
    """x_k at the last step recorded (J; NaN before the first)."""
    excess_max_j: float = field(init=False, default=math.nan)
    """max_k x_k over the episode (J; NaN before the first step, +inf once E is not finite)."""

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """A new episode: nothing recorded."""
        self._start: float | None = None
        self._flows_j = 0.0
        self._work_d_j = 0.0
        self.excess_j = math.nan
        self.excess_max_j = math.nan

    def diverged(self, storage: bool = False) -> None:
        """The law's state ran to a non-finite value this step: x = +inf where the ledger
        recorded a step or ``storage`` says the law has one (it diverged at its first);
        nothing for a base without a storage."""
        if self._start is not None or storage:
            self.excess_j = self.excess_max_j = math.inf

    def record(
        self, diagnostics: dict[str, float], tank_level_j: float, work_d_after_j: float,
        dt_s: float,
    ) -> float:  # fmt: skip
        """x_k of the step just taken: ``diagnostics`` the law's at that step (E_k,
        P_pump, P_sync), ``tank_level_j`` T_k (before the step's settling),
        ``work_d_after_j`` W_d at the step's end (J; the next x's)."""
        stored = float(diagnostics["energy"]) + float(tank_level_j)
        if self._start is None:
            self._start = stored
        excess = stored - self._start - self._flows_j - self._work_d_j
        if not math.isfinite(excess):
            excess = math.inf
        self._flows_j += supplied_power_w(diagnostics) * dt_s
        self._work_d_j = float(work_d_after_j)
        self.excess_j = excess
        self.excess_max_j = (
            excess if math.isnan(self.excess_max_j) else max(self.excess_max_j, excess)
        )
        return excess
