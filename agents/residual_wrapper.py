"""Residual reinforcement learning on top of a model-based controller: :class:`ResidualWrapper`.

The wrapper turns a ptrack_gym env into one whose action is a *correction* to a base
controller's torque (its options: :class:`~agents.residual_spec.ResidualSpec`):

.. math::

    \\tau = \\tau_{base}(q, \\dot q) + \\mathrm{scale} \\odot a, \\qquad a \\in [-1, 1]^n,

with τ_base = ``controller.step(q, q̇, dt)`` on the env's measured joint state and
``scale`` (N·m, per joint) ``scale_nm``, or ``scale_fraction`` · τ_max (default 0.1). With
``scale_accel_rad_s2`` α the residual is a joint *acceleration* instead:

.. math::

    \\tau = \\tau_{base}(q, \\dot q) + M(q)\\,\\alpha a, \\qquad a \\in [-1, 1]^n,

M the env's nominal mass matrix at the measured q, so on the nominal plant the residual adds
exactly α a to q̈ (rad/s²), every joint alike, whatever the arm's inertia and coupling
(``docs/rl.md``). The inner env receives ``torque_to_action(τ, τ_max)`` — the one conversion
every adapter uses — so with a = 0 the wrapped env is *bit-identical* to the base controller
run standalone through :class:`~agents.policy.ControllerPolicy`. The controller is reset
with every env reset, at the env's measured state and reference phase s₀ + t.

Observation: the inner observation, followed — with ``include_controller_state`` — by the
base's feature block (:mod:`agents.residual_features`, ``feature_names``).

Safeguards (both off by default, so a = 0 stays bit-identical to the base):

* ``action_penalty`` w ≥ 0 — a penalty on the *learned part only*: the reward becomes
  r + w (1 − |clip(a)|²/n). The constant w keeps a bounded (``reward="kernel"``) reward
  ≥ 0, so ending an episode early still never pays; ``info["reward_residual"]`` is the
  added term.
* ``gate_rad`` d_g > 0 — a residual gated by the path error: τ_res = γ(d) scale ⊙ a with
  γ(d) = 1 − exp(−(max(d − d₀, 0)/d_g)²), d the path distance of the measured state (rad)
  and d₀ = ``gate_deadband_rad`` ≥ 0 (default 0). On the path the residual is inactive
  whatever the policy outputs; with d₀ > 0 it is *exactly* zero while d ≤ d₀, so an arm
  the base keeps within d₀ of the path runs bit-identically to the base alone (choose d₀
  above the base's undisturbed path distance). ``info["residual_gate"]`` is γ.
* ``prior_gain_per_rad`` g ≥ 0 — a hand-made feedback the learned part is added to, a
  *control prior* (Cheng et al., "Control regularization for reduced variance
  reinforcement learning", ICML 2019): stiffness toward the base's own reference point,

  .. math::

      a_{prior} = \\mathrm{clip}(g\\,(q_r(s) - q), -1, 1), \\qquad
      a_{eff} = \\mathrm{clip}(a + a_{prior}, -1, 1),

  with q_r(s) − q the base's own reference error at the measured state the policy
  observes (:data:`~agents.residual_features.PRIOR_ERROR_FEATURES`: the passivity block's
  ``path_error_j_rad``, s its path parameter; the time-indexed blocks' ``e_j_rad``, s their
  clock; bases of :data:`agents.registry.PRIOR_BASES`), and a_eff in place of a in τ_res
  (gated alike). A zero-initialised actor then starts as the prior, and a
  behaviour-cloning pull toward a = 0 becomes a pull toward it. ``info["residual_prior"]``
  is a_prior; the action penalty stays on the learned a.

* ``tank`` — an energy tank (:mod:`agents.energy_tank`, passivity bases): the residual,
  after the gate and the prior, is scaled by λ ∈ [0, 1] so the energy it injects is paid
  from a tank filled only by the law's own dissipation; the tank is settled with the work
  the residual really did, (q_{k+1} − q_k)ᵀ(τ_applied − τ_base), at the measured states,
  and filled with the energy the law really dissipated, measured at its sampled port
  (:class:`agents.energy_tank.PortDissipation`; where the sampled law created energy —
  joules where a residual holds a torque near a stall — the tank pays it); it also pays
  what the arm gained beyond the commanded torque's work as the law measures it
  (:class:`agents.energy_tank.ArmEnergyObserver`: a disturbance's work, a delayed or
  noisy sensor's energy). Storage plus tank then grows by no more than the pump's, the
  re-synchronisation's and the disturbance's work, whatever the policy outputs, behind a
  delayed sensor too. ``info["tank_level_j"]`` T after the step, ``info["tank_scale"]``
  λ, ``info["tank_withheld_j"]`` the energy held back this episode so far,
  ``info["tank_law_created_j"]`` the most the sampled law owed the tank so far,
  ``info["tank_arm_gained_j"]`` the most the arm owed it.

Info (every step): ``tau_base_nm`` τ_base, ``tau_residual_nm`` γ scale ⊙ a_eff or
M(q) γ α a_eff (a_eff = clip(a, −1, 1) without a prior; N·m, before the env's own
clipping of the sum to τ_max), ``controller`` the controller's ``diagnostics()``; reset's
info has ``controller`` too. Over a passivity base (tank or not) also ``balance_excess_j``:
storage + tank against its start, the pump's, re-synchronisation's and disturbance's work
(:class:`agents.energy_tank.BalanceLedger`; :attr:`ResidualWrapper.balance` keeps the
episode's largest).

A base may also be a *network*: ``base="network"`` with ``base_model`` the folder of a saved
pure SAC policy (:data:`~agents.residual_spec.NETWORK_BASE`,
:class:`~agents.network.NetworkController`) — RL then learns a correction to a frozen
learned policy (an imitation) and the composite stays a pure policy (no model-based
controller at run time). It offers no feature block of its own (the n entries of the last
τ_base / τ_max) and hence no control prior.

:func:`make_residual_env` is the one-call constructor: ``gym.make`` + the base of
:func:`build_base` + the wrapper.
"""

from __future__ import annotations

import math
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.envs.registration import EnvSpec

from agents.base import Controller, FloatArray, ObservesAppliedTorque
from agents.energy_tank import (
    ArmEnergyObserver,
    BalanceLedger,
    PortDissipation,
    has_storage,
)
from agents.policy import torque_to_action
from agents.registry import make_controller
from agents.residual_features import PRIOR_ERROR_FEATURES, ControllerFeatures, prior_error_names
from agents.residual_spec import NETWORK_BASE, ResidualSpec, check_base_model, resolve_spec
from ptrack_gym.errors import InvalidActionError, InvalidConfigError

Env = gym.Env[np.ndarray, np.ndarray]


def build_base(
    env: Any, base: str, base_gains: Any, base_model: str | None, path: Any = None
) -> Controller:
    """The base controller ``base`` for ``env``: a registry controller with ``base_gains``
    (on ``path``, one of a pool's, instead of the env's own), or, for
    :data:`~agents.residual_spec.NETWORK_BASE`, the pure policy saved in ``base_model``."""
    if base == NETWORK_BASE:
        from agents.network import load_network_controller

        return load_network_controller(str(base_model), env)
    return make_controller(base, env, base_gains, path=path)


class ResidualWrapper(
    gym.Wrapper[np.ndarray, np.ndarray, np.ndarray, np.ndarray], gym.utils.RecordConstructorArgs
):
    """Learn a bounded torque correction on top of a base controller (module docstring).

    Args:
        env: a ptrack_gym env (any wrapper of a ``TrackingEnv``).
        controller: the base controller, built for ``env``'s robot (same n); or None (or
            the base's name, as the spec's ``base``) to build ``spec.base`` with
            ``spec.base_gains`` (:func:`build_base`). Built by name, the wrapper is
            re-creatable from ``env.spec`` (``spec.make()``, as Gymnasium's checker and
            ``gym.make(spec)`` do); given as an object, ``spec`` is None (a controller
            object cannot be rebuilt from a spec), ``base_gains`` must stay "default" and
            ``spec.base`` is not used.
        spec: the residual's options (default: :class:`ResidualSpec`'s defaults).
        options: fields of :class:`ResidualSpec` replacing the spec's (keyword style:
            ``ResidualWrapper(env, "pd_gravity", gate_rad=0.01)``).

    Raises:
        InvalidConfigError: (a ``ValueError``) an unknown option, a bad value, a
            joint-count mismatch, or gains or a model folder given with a controller object.
    """

    def __init__(
        self,
        env: Env,
        controller: Controller | str | None = None,
        spec: ResidualSpec | None = None,
        **options: Any,
    ) -> None:
        by_name = controller is None or isinstance(controller, str)
        if isinstance(controller, str):
            if "base" in options:
                raise InvalidConfigError(
                    f"the base is given twice: {controller!r} and base={options['base']!r}"
                )
            options = {"base": controller, **options}
        spec = ResidualSpec.from_options(options, spec)
        if not by_name and spec.base_gains != "default":
            raise InvalidConfigError("base_gains is for a base given by name, not an object")
        if not by_name and spec.base_model is not None:
            raise InvalidConfigError("base_model is for a base given by name, not an object")
        u = env.unwrapped
        pool = u.pool_paths() if hasattr(u, "pool_paths") else {}
        if pool and (not by_name or spec.base == NETWORK_BASE):
            raise InvalidConfigError(
                "a residual over a pool of paths (path_seeds) needs a registry base given by "
                "name: the wrapper builds one base per path"
            )
        if by_name:
            check_base_model(spec.base, spec.base_model, u.robot_profile.name, spec.base_gains)
            recorded = {k: v for k, v in spec.options().items() if k != "base"}
            gym.utils.RecordConstructorArgs.__init__(self, controller=spec.base, **recorded)
        super().__init__(env)
        self.residual_spec = spec
        """The residual's options, whole."""
        self._controller_name = spec.base if by_name else None
        self._registered = False  # set by use_registered_spec: the spec is the registered one
        self.tracking_env = u
        self.n = int(u.n)
        # one base per path of a pool (the one of the episode's path acts), else one
        self._bases: dict[Any, Controller] = {
            seed: build_base(env, spec.base, spec.base_gains, spec.base_model, path=path)
            for seed, path in pool.items()
        }
        if self._bases:
            controller = self._bases[u.path_seed]
        elif controller is None or isinstance(controller, str):
            controller = build_base(env, spec.base, spec.base_gains, spec.base_model)
        if controller.n != self.n:
            raise InvalidConfigError(f"controller has {controller.n} joints, env has {self.n}")
        self.controller = controller
        self.base_gains, self.base_model = spec.base_gains, spec.base_model
        self.torque_limits_nm = np.asarray(u.torque_limits_nm, dtype=np.float64)
        accel = spec.scale_accel_rad_s2
        self.scale_accel_rad_s2 = None if accel is None else float(accel)
        self.scale_nm: FloatArray | None = None if accel is not None else self._scale_nm(spec)
        """Torque authority per joint (N·m); None when the residual is an acceleration."""
        self.action_penalty = float(spec.action_penalty)
        self.gate_rad = None if spec.gate_rad is None else float(spec.gate_rad)
        self.gate_deadband_rad = float(spec.gate_deadband_rad)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.n,), dtype=np.float32)

        inner = env.observation_space
        assert isinstance(inner, spaces.Box)
        self.features: ControllerFeatures | None = None
        self._features_by: dict[Any, ControllerFeatures] = {
            seed: ControllerFeatures(c, float(u.max_speed)) for seed, c in self._bases.items()
        }
        if spec.include_controller_state:
            self.features = self._features_by.get(u.path_seed) or ControllerFeatures(
                controller, float(u.max_speed)
            )
            blocks = list(self._features_by.values()) or [self.features]
            f_low = np.min([b.low for b in blocks], axis=0)  # the union of the paths' bounds
            f_high = np.max([b.high for b in blocks], axis=0)
            low = np.concatenate([inner.low, f_low.astype(np.float32)])
            high = np.concatenate([inner.high, f_high.astype(np.float32)])
            self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self._base_ratio = np.zeros(self.n)
        self.prior_gain_per_rad = float(spec.prior_gain_per_rad)
        self._prior = np.zeros(self.n)  # a_prior at the measured state last observed
        self._prior_features: ControllerFeatures | None = None  # None: no prior
        if self.prior_gain_per_rad > 0:
            feats = self.features or ControllerFeatures(controller, float(u.max_speed))
            names = prior_error_names(feats.names, self.n)
            if names is None:
                raise InvalidConfigError(
                    "a control prior needs the base's reference-error features "
                    f"({' or '.join(PRIOR_ERROR_FEATURES)}); {type(controller).__name__} has none"
                )
            self._prior_features = feats
            self._prior_cols = np.array([feats.names.index(name) for name in names])
            self._prior_by = self._features_by  # a pool's: the same names on every path
        self.tank = spec.energy_tank() if spec.tank else None
        """The energy tank (None without ``tank``)."""
        self._port = PortDissipation()  # what the law dissipated: the tank's only fill
        self._arm = ArmEnergyObserver()  # what the arm gained unexplained: the tank pays it
        self.balance = BalanceLedger()
        """Storage + tank along the episode (:class:`agents.energy_tank.BalanceLedger`), kept
        for a base whose diagnostics give its storage and flows (the passivity laws); NaN
        for others."""

    def _scale_nm(self, spec: ResidualSpec) -> FloatArray:
        """The torque authority (N·m, (n,)): ``spec.scale_nm`` broadcast to the n joints,
        or ``spec.scale_fraction`` · τ_max."""
        if spec.scale_nm is None:
            return spec.scale_fraction * self.torque_limits_nm
        raw = np.asarray(spec.scale_nm, dtype=np.float64)
        if raw.ndim == 1 and raw.shape != (self.n,):
            raise InvalidConfigError(
                f"scale_nm must be a scalar or have {self.n} entries, got shape {raw.shape}"
            )
        return np.broadcast_to(raw, (self.n,)).copy()

    def use_registered_spec(self) -> None:
        """Report the inner env's spec as this env's: for the registered residual ids, whose
        entry point (:func:`agents.residual_ids.residual_env`) builds this wrapper."""
        self._registered = True

    @property
    def spec(self) -> EnvSpec | None:
        """The env's spec with this wrapper appended, when the controller was given by
        name; None when it was given as an object (it cannot be rebuilt). Built by a
        registered residual id, the registered spec itself."""
        if self._registered:
            return self.env.spec
        if self._controller_name is None:
            return None
        return super().spec

    @property
    def feature_names(self) -> tuple[str, ...]:
        """Names of the appended observation entries (empty without controller state)."""
        return self.features.names if self.features is not None else ()

    @property
    def prior_action(self) -> FloatArray:
        """a_prior at the measured state last observed — what the next step adds to the
        policy's action (zeros without a prior); a copy."""
        return self._prior.copy()

    def _augment(self, obs: np.ndarray) -> np.ndarray:
        """The observation with the controller block; also sets a_prior at this state."""
        if self.features is None and self._prior_features is None:
            return obs
        q, qd = self.tracking_env.measured_joint_state()
        feats = (self.features or self._prior_features)(q, qd, self._base_ratio)  # type: ignore[misc]
        if self._prior_features is not None:
            error = feats[self._prior_cols]  # q_r(s) − q (rad), float64, clipped to ±2π
            self._prior = np.minimum(np.maximum(self.prior_gain_per_rad * error, -1.0), 1.0)
        if self.features is None:
            return obs
        return np.concatenate([obs, feats.astype(np.float32)])

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset the env, then the controller at the measured state and phase s₀ + t."""
        obs, info = self.env.reset(seed=seed, options=options)
        u = self.tracking_env
        if self._bases:  # the base (and its features) of the episode's path
            self.controller = self._bases[u.path_seed]
            if self.features is not None:
                self.features = self._features_by[u.path_seed]
            if self._prior_features is not None:
                self._prior_features = self._prior_by[u.path_seed]
        q, qd = u.measured_joint_state()
        self.controller.reset(q, qd, u.s0 + u.t)
        self._base_ratio = np.zeros(self.n)
        info["controller"] = self.controller.diagnostics()
        if self.tank is not None:
            self.tank.reset()
            info["tank_level_j"] = self.tank.level_j
        self._port.reset()
        self._arm.reset()
        self.balance.reset()
        self._last_obs = self._augment(obs)
        return self._last_obs, info

    def step(
        self, action: np.ndarray
    ) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        """τ = τ_base + γ scale ⊙ a_eff — or τ_base + M(q) γ α a_eff with
        ``scale_accel_rad_s2`` — (N·m), applied as ``torque_to_action(τ)``; a_eff =
        clip(a, −1, 1), or clip(a + a_prior, −1, 1) with a control prior.

        Raises:
            InvalidActionError: (a ``ValueError``) ``action`` is not of shape (n,) or has
                a non-finite entry; nothing is stepped.
        """
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (self.n,):
            raise InvalidActionError(f"action must have shape ({self.n},), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise InvalidActionError(f"action has non-finite entries: {a.tolist()}")
        u = self.tracking_env
        q, qd = u.measured_joint_state()
        tau_base = self.controller.step(q, qd, u.dt)  # (n,) N·m
        if not np.all(np.isfinite(tau_base)):  # the base diverged: the episode ends as unstable
            self.balance.diverged(has_storage(self.controller.diagnostics()))
            info = {"unstable": True, "controller_diverged": True, "t_s": u.t}
            penalty = -float(u.config.unstable_penalty)
            return self._last_obs, penalty, True, False, info
        a = np.minimum(np.maximum(a, -1.0), 1.0)
        a_eff = a
        if self._prior_features is not None:
            prior = self._prior
            a_eff = np.minimum(np.maximum(a + prior, -1.0), 1.0)
        gate = 1.0
        if self.gate_rad is not None:
            d = max(u.projector.nearest(q).distance - self.gate_deadband_rad, 0.0)
            gate = -math.expm1(-((d / self.gate_rad) ** 2))  # γ = 1 − exp(−((d − d₀)⁺/d_g)²)
        if self.scale_nm is not None:
            tau_res = (gate * self.scale_nm) * a_eff  # (n,) N·m; γ = 1 exactly without a gate
        else:  # M(q) γ α a: the acceleration α a (rad/s²) on the nominal model (cached M)
            tau_res = u.model.mass_matrix(q) @ ((gate * self.scale_accel_rad_s2) * a_eff)
        tank_scale = 1.0
        if self.tank is not None:  # the step before: what the law dissipated, the arm gained
            model = u.model
            arm_j = model.kinetic_energy(q, qd) + float(model.potential(q))  # H (J)
            self.tank.fill(
                self._port.record(self.controller.diagnostics(), arm_j, q, tau_base, u.dt)
            )
            self.tank.pay_arm(self._arm.record(arm_j, q))
            tank_scale = self.tank.gate(u.model, q, qd, tau_base, tau_res, u.dt)
            tau_res = tank_scale * tau_res
            # the torque applied, the limits' clipping included (the action's float32
            # rounding, ~1e-7 of τ, is left to the law's own residue)
            limits = self.torque_limits_nm
            applied = np.minimum(np.maximum(tau_base + tau_res, -limits), limits)
            self._arm.commanded(applied)
        if isinstance(self.controller, ObservesAppliedTorque):  # e.g. a momentum observer
            self.controller.applied_torque(tau_base + tau_res, u.dt)
        inner_action = torque_to_action(tau_base + tau_res, self.torque_limits_nm)
        obs, reward, terminated, truncated, info = self.env.step(inner_action)
        diagnostics = self.controller.diagnostics()
        if has_storage(diagnostics):
            level = self.tank.level_j if self.tank is not None else 0.0  # T_k, before settling
            info["balance_excess_j"] = self.balance.record(
                diagnostics, level, float(info.get("disturbance_work_j", 0.0)), u.dt
            )
        if self.tank is not None:
            q_next, _ = u.measured_joint_state()
            work = float((q_next - q) @ (applied - tau_base))  # beyond the base's torque
            if math.isfinite(work):
                self.tank.settle(work)
            info["tank_level_j"] = self.tank.level_j
            info["tank_scale"] = tank_scale
            info["tank_withheld_j"] = self.tank.withheld_j
            info["tank_law_created_j"] = self.tank.created_j
            info["tank_arm_gained_j"] = self.tank.arm_gained_j
        if self.action_penalty > 0.0:
            bonus = self.action_penalty * (1.0 - float(a @ a) / self.n)
            reward = float(reward) + bonus
            info["reward_residual"] = bonus
        if self.gate_rad is not None:
            info["residual_gate"] = gate
        if self._prior_features is not None:
            info["residual_prior"] = prior
        self._base_ratio = tau_base / self.torque_limits_nm
        info["tau_base_nm"] = tau_base
        info["tau_residual_nm"] = tau_res
        info["controller"] = diagnostics
        augmented = self._augment(obs)
        if not np.all(np.isfinite(augmented)):  # the base's own state diverged: as above
            self.balance.diverged(has_storage(self.controller.diagnostics()))
            info.update(unstable=True, controller_diverged=True)
            return self._last_obs, -float(u.config.unstable_penalty), True, False, info
        self._last_obs = augmented
        return self._last_obs, reward, terminated, truncated, info


def wrap(env: Env, spec: ResidualSpec) -> ResidualWrapper:
    """``env`` in a :class:`ResidualWrapper` built by ``spec`` (its base by name); ``env``
    is closed if that fails."""
    try:
        return ResidualWrapper(env, spec=spec)
    except BaseException:
        env.close()
        raise


def make_residual_env(
    env_id: str,
    spec: ResidualSpec | str = "passivity",
    scale_fraction: float | None = None,
    **options: Any,
) -> ResidualWrapper:
    """``gym.make(env_id, **env_options)`` in a :class:`ResidualWrapper` built by ``spec``.

    Args:
        env_id: a plain ptrack_gym id (``ptrack_gym/<Robot>Track-v0``), or its preview id
            (``…TrackPreview-v0``, the reference ahead, which the residual's observation
            keeps).
        spec: the residual's options whole; or, keyword style, the base's name (a name of
            :data:`~agents.residual_spec.RESIDUAL_BASES`) with the spec's other fields
            among ``options``.
        scale_fraction: the spec's ``scale_fraction`` (keyword style); None: the spec's.
        options: fields of :class:`ResidualSpec` (replacing the spec's), then the env's
            arguments for ``gym.make`` (``control_hz``, ``disturbance``,
            ``max_episode_steps``, …), which rejects unknown names.

    Raises:
        InvalidConfigError: (a ``ValueError``) an unknown base, a bad value, or a
            ``base_model`` folder without a pure policy.
    """
    if scale_fraction is not None:
        options = {**options, "scale_fraction": scale_fraction}
    spec, env_options = resolve_spec(spec, options)
    check_base_model(spec.base, spec.base_model, base_gains=spec.base_gains)
    return wrap(gym.make(env_id, **env_options), spec)
