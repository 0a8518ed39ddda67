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
T ≥ 0. In discrete time (one control step of length Δt):

* **gate** (:meth:`EnergyTank.gate`, before the step): the residual is scaled by
  λ ∈ [0, 1], the largest with W(λ) ≤ T − T_min, W the work λτ_res is predicted to do over
  the step on the nominal model — semi-implicit Euler, q̇⁺ = q̇ + Δt M⁻¹(τ_base + λτ_res − h):
  W(λ) = λ a₁ + λ² a₂, a₁ = Δt (q̇ + Δt M⁻¹(τ_base − h))ᵀτ_res, a₂ = Δt² τ_resᵀM⁻¹τ_res ≥ 0.
  A dissipative correction (W(1) ≤ T − T_min) passes whole; with the tank at its floor an
  injecting one is held back entirely (λ = 0: the base alone);
* **settle** (:meth:`EnergyTank.settle`, after it): T ← min(T_max, T + βDΔt − W), W the
  work the residual really did, (q_{k+1} − q_k)ᵀ(τ_applied − τ_base) — the env's ledger for
  τ_d. The floor T_min > 0 absorbs the prediction's error (a plant other than the model,
  the torque limits); T below 0 is reported (``overdrawn_j``), never hidden.

The discrete balance holds up to the law's own discrete residue (E_{k+1} − E_k against its
flows), which the tank does not pay. It is not always small: a residual holding a
persistent torque can keep the arm near a stall where it grows by joules (0.1 τ_max
constant on the two-link at 250 Hz: 5.5 J in 5 s with the tank never overdrawn; an open
defect, ``docs/rl.md``; ``tests/test_energy_tank.py``'s strict xfail states it).
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
    """Energy the gate held back this episode: Σ W(1) − W(λ) over the steps (J)."""
    overdrawn_j: float = field(init=False, default=0.0)
    """The deepest the level went below 0 this episode (J, ≥ 0; 0 when it never did)."""

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

    def settle(self, work_j: float, dissipation_w: float, dt_s: float) -> None:
        """T ← min(T_max, T + β D Δt − W) after a step in which the residual did
        ``work_j`` (J) and the law dissipated at ``dissipation_w`` (W, ≥ 0)."""
        fill = self.beta * max(float(dissipation_w), 0.0) * dt_s
        self.level_j = min(self.cap_j, self.level_j + fill - float(work_j))
        self.overdrawn_j = max(self.overdrawn_j, -self.level_j)


#: The storage flows a :class:`BalanceLedger` reads off a passivity base's diagnostics.
BALANCE_KEYS = ("energy", "pump_power", "sync_power")


def has_storage(diagnostics: dict[str, float]) -> bool:
    """Whether a controller's ``diagnostics`` carry a storage a :class:`BalanceLedger` can
    keep (every one of :data:`BALANCE_KEYS`: the passivity laws')."""
    return all(key in diagnostics for key in BALANCE_KEYS)


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
        self._flows_j += (
            float(diagnostics["pump_power"]) + float(diagnostics["sync_power"])
        ) * dt_s
        self._work_d_j = float(work_d_after_j)
        self.excess_j = excess
        self.excess_max_j = (
            excess if math.isnan(self.excess_max_j) else max(self.excess_max_j, excess)
        )
        return excess
