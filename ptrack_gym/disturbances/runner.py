"""The runner of an episode's disturbances: the physics sub-step loop and the work ledger.

:class:`DisturbanceRunner` composes the env's disturbances. Every control step the env
hands it the commanded torque; the runner applies the plant changes, the actuation error,
joint torques and pushes over the physics sub-steps, and keeps the ledger of the work the
disturbance torque does. When no disturbance acts during a control step, the sub-steps run
without any of that bookkeeping (the result is the same: τ_d = 0).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from ptrack_gym.disturbances.base import Disturbance, DisturbanceContext, FloatArray, MassChange

if TYPE_CHECKING:
    from ptrack_gym.sim import BulletArm


def _overrides(d: Disturbance, hook: str) -> bool:
    return getattr(type(d), hook) is not getattr(Disturbance, hook)


class DisturbanceRunner:
    """All of an env's disturbances, composed, with the episode's work ledger.

    Attributes:
        items: the disturbances, in the order their hooks are applied.
        work_j: ∫ q̇ᵀτ_d since the last reset (J): per sub-step τ_dᵀ(q_{k+1} − q_k), the
            exact work of a torque held over a semi-implicit Euler step.
        last_torque_nm: τ_d of the last physics sub-step (pushes as JᵀF), shape (n,); a
            new array every control step (Gymnasium: an info never shares an object with
            the last), never written in place, so it can be handed out without a copy.
    """

    def __init__(self, items: list[Disturbance], n: int) -> None:
        self.items = list(items)
        self.n = n
        self._actors = [
            d for d in self.items if _overrides(d, "joint_torque") or _overrides(d, "wrench")
        ]
        self._torquers = [d for d in self._actors if _overrides(d, "joint_torque")]
        self._pushers = [d for d in self._actors if _overrides(d, "wrench")]
        self._actuators = [d for d in self.items if _overrides(d, "actuate")]
        self._sensors = [d for d in self.items if _overrides(d, "sense")]
        self._editors = [d for d in self.items if _overrides(d, "plant")]
        self.work_j = 0.0
        self.last_torque_nm = np.zeros(n)
        self._was_reset = False
        self._plant_window = (np.inf, -np.inf)  # [from, until) the applied plant holds

    def validate(self, ctx: DisturbanceContext) -> None:
        """Check every disturbance against the env (links, directions, onsets that fit in
        ``ctx.horizon_s``); raises :class:`~ptrack_gym.errors.InvalidConfigError`."""
        for d in self.items:
            d.check_horizon(ctx.horizon_s)
            d.validate(ctx)

    def set_context(self, ctx: DisturbanceContext) -> None:
        """Re-attach the context after unpickling (see ``Disturbance.set_context``)."""
        for d in self.items:
            d.set_context(ctx)

    def reset(self, rng: np.random.Generator, ctx: DisturbanceContext) -> None:
        """Reset every disturbance with its own child stream of ``rng`` (in list order) and
        zero the ledger."""
        children = rng.spawn(len(self.items)) if self.items else []
        for d, child in zip(self.items, children, strict=True):
            d.reset(child, ctx)
        self.work_j = 0.0
        self.last_torque_nm = np.zeros(self.n)
        self._was_reset = True
        self._plant_window = (np.inf, -np.inf)  # the new schedule is applied at once

    @property
    def senses(self) -> bool:
        """Whether a disturbance changes what the sensors report."""
        return bool(self._sensors)

    @property
    def was_reset(self) -> bool:
        """Whether the disturbances have an episode schedule (``reset`` was called)."""
        return self._was_reset

    def schedules(self) -> list[dict[str, Any]]:
        """This episode's drawn parameters, one dict per disturbance."""
        return [{"type": d.name, **d.schedule()} for d in self.items]

    def sense(self, q: FloatArray, qd: FloatArray) -> tuple[FloatArray, FloatArray]:
        """What the sensors report for the true (q, q̇)."""
        if not self._sensors:
            return q, qd
        for d in self._sensors:
            q, qd = d.sense(q, qd)
        return q, qd

    def plant(self, t_s: float) -> dict[str, MassChange]:
        """Combined plant mass changes at ``t_s``: scales multiply, added masses add."""
        out: dict[str, MassChange] = {}
        for d in self._editors:
            for link, ch in (d.plant(t_s) or {}).items():
                old = out.get(link, MassChange())
                out[link] = MassChange(old.scale * ch.scale, old.added_kg + ch.added_kg)
        return out

    def apply_plant(self, arm: BulletArm, t_s: float, force: bool = False) -> None:
        """Set the plant's link masses to those in force at ``t_s`` (no-op without a
        plant-changing disturbance). Between the editors' change times the plant is
        constant, so nothing is recomputed there unless ``force`` (a new arm body: one
        rebuilt after unpickling, or reset to nominal)."""
        if not self._editors:
            return
        if not force and self._plant_window[0] <= t_s < self._plant_window[1]:
            return
        arm.set_mass_changes({k: (v.scale, v.added_kg) for k, v in self.plant(t_s).items()})
        self._plant_window = self._plant_interval(t_s)

    def _acting(self, t0_s: float, t1_s: float) -> bool:
        """Whether a joint torque or a push may act in [t0, t1) (s)."""
        for d in self._actors:
            if d.acts_during(t0_s, t1_s):
                return True
        return False

    def _plant_interval(self, t_s: float) -> tuple[float, float]:
        """[from, until) around ``t_s`` in which no editor changes the plant; empty when
        one may change it at any time."""
        lo, hi = -np.inf, np.inf
        for d in self._editors:
            times = d.plant_change_times()
            if times is None:
                return (np.inf, -np.inf)
            for c in times:
                if c <= t_s:
                    lo = max(lo, c)
                else:
                    hi = min(hi, c)
        return (lo, hi)

    def step(
        self,
        arm: BulletArm,
        tau_cmd: FloatArray,
        q: FloatArray,
        qd: FloatArray,
        first_substep: int,
        substeps: int,
        physics_dt_s: float,
    ) -> tuple[FloatArray, FloatArray]:
        """One control step of ``substeps`` physics sub-steps from the true (q, q̇);
        returns the new true (q, q̇).

        Per sub-step k starting at t_k = (first_substep + k)·dt: τ_d = (actuated −
        commanded torque) + Σ joint torques + Σ Jᵀ(q_k) F for pushes; the plant gets
        τ_cmd + τ_d; the ledger adds τ_dᵀ(q_{k+1} − q_k).
        """
        if not self.items:  # the common, undisturbed case first
            self.last_torque_nm = np.zeros(self.n)
            return arm.run_torque(tau_cmd.tolist(), substeps)
        t0 = first_substep * physics_dt_s
        if self._editors:
            self.apply_plant(arm, t0)
        t1 = (first_substep + substeps) * physics_dt_s
        if not self._actuators and not self._acting(t0, t1):
            self.last_torque_nm = np.zeros(self.n)
            return arm.run_torque(tau_cmd.tolist(), substeps)
        tau_act = tau_cmd
        for d in self._actuators:
            tau_act = d.actuate(tau_act)
        actuation_error = tau_act - tau_cmd
        torquers, pushers = self._torquers, self._pushers
        for k in range(substeps):
            t_k = (first_substep + k) * physics_dt_s
            tau_d = actuation_error.copy()
            for d in torquers:
                tau = d.joint_torque(t_k, q, qd)
                if tau is not None:
                    tau_d += tau
            if pushers:
                arm.apply_torque_list((tau_cmd + tau_d).tolist())
                for d in pushers:
                    w = d.wrench(t_k, q, qd)
                    if w is not None:
                        link, force = w
                        arm.apply_link_force(link, force)
                        tau_d = tau_d + arm.com_jacobian(link, q).T @ force
                arm.sim.step()
                q_next, qd = arm.state()
            else:  # the same PyBullet calls: torque, one step, joint states
                q_next, qd = arm.run_torque((tau_cmd + tau_d).tolist(), 1)
            w = float(tau_d @ (q_next - q))
            # Only a finite state counts; a finite w implies one (a non-finite q_next makes
            # a term inf or NaN), so the full check runs only when w is not finite.
            if math.isfinite(w) or np.isfinite(q_next).all():
                self.work_j += w
            q = q_next
            self.last_torque_nm = tau_d
        return q, qd
