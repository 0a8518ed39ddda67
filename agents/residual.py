"""Residual reinforcement learning on top of a model-based controller.

:class:`ResidualWrapper` turns a ptrack_gym env into one whose action is a *correction*
to a base controller's torque:

.. math::

    \\tau = \\tau_{base}(q, \\dot q) + \\mathrm{scale} \\odot a, \\qquad a \\in [-1, 1]^n,

with τ_base = ``controller.step(q, q̇, dt)`` on the env's measured joint state and
``scale`` (N·m, per joint) a fraction of the torque limits (default 0.1). With
``scale_accel_rad_s2`` α the residual is a joint *acceleration* instead:

.. math::

    \\tau = \\tau_{base}(q, \\dot q) + M(q)\\,\\alpha a, \\qquad a \\in [-1, 1]^n,

M the env's nominal mass matrix at the measured q, so on the nominal plant the residual adds
exactly α a to q̈ (rad/s²), every joint alike — a fraction of τ_max gives the iiwa's light
wrist ~4 000 rad/s² (0.1 τ_max) and a per-joint α M_jj(q_home) still moved it 0.36 rad off
its path through the coupling (measured, docs/rl.md). The inner env
receives ``torque_to_action(τ, τ_max)`` — the one conversion every adapter uses — so with
a = 0 the wrapped env is *bit-identical* to the base controller run standalone through
:class:`~agents.policy.ControllerPolicy`. The controller is reset with every env reset,
at the env's measured state and reference phase s₀ + t.

Observation: the inner observation (6n + 2 entries, see ``TrackingEnv``), followed — with
``include_controller_state=True`` — by a fixed-size float32 vector of the base
controller's state, each entry clipped to documented finite bounds
(:class:`ControllerFeatures`, ``feature_names``). Every entry is evaluated at the measured
state the observation describes and at the controller's state after its last step — the
state its *next* step starts from. Per controller (n joints, S the path period in s,
v_max the env's speed bound in rad/s):

``passivity`` — 6 + 2n entries

=====================  ==========================================  ===============  ============
entries                quantity                                    unit             bounds
=====================  ==========================================  ===============  ============
0, 1                   sin, cos of 2π s / S (the controller's s)   —                ±1
2                      ṡ, the controller's path rate               1                ±10
3                      σ̇ = √(q̇ᵀM(q)q̇ / M_r(s)), the speed ratio   1                [0, 10]
4                      s̃ = s − σ                                   s                ±S
5                      path error |q − q_r(s)|                     rad              [0, 2π]
6 : 6 + n              q_r(s) − q per joint                        rad              ±2π
6 + n : 6 + 2n         last τ_base / τ_max (0 after reset)         —                ±2
=====================  ==========================================  ===============  ============

``computed_torque``, ``pd_gravity`` — 3n entries; ``slotine_li`` — 4n entries. These
controllers track the time-indexed reference q_r(s) with a clock s that equals the env's
s₀ + t, so their errors repeat the inner observation's (in float64 before rounding); they
are kept so every base has the same kind of block:

=====================  ==========================================  ===============  ============
entries                quantity                                    unit             bounds
=====================  ==========================================  ===============  ============
0 : n                  e = q_r(s) − q                              rad              ±2π
n : 2n                 ė = q_r'(s) − q̇                             rad/s            ±2 v_max
2n : 3n (Slotine–Li)   r = ė + Λ e                                 rad/s            ±r_max
last n                 last τ_base / τ_max (0 after reset)         —                ±2
=====================  ==========================================  ===============  ============

with r_max = 2 v_max + 2π max Λ. Each controller supplies its block through its
``residual_features`` method (:class:`~agents.base.HasResidualFeatures`); a controller
without one gets n entries, the last τ_base / τ_max.

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
  observes (:data:`PRIOR_ERROR_FEATURES`: the passivity block's ``path_error_j_rad``, s its
  path parameter; the time-indexed blocks' ``e_j_rad``, s their clock; bases of
  :data:`PRIOR_BASES`), and a_eff in place of a in τ_res (gated alike). A zero-initialised
  actor then starts as the prior, and the behaviour-cloning pull toward a = 0
  (``train.train``'s ``actor_bc_weight``) becomes a pull toward it. g = 1000 1/rad is
  ``train.authority_probe``'s probe. ``info["residual_prior"]``
  is a_prior; the action penalty stays on the learned a.

Info (every step): ``tau_base_nm`` τ_base, ``tau_residual_nm`` γ scale ⊙ a_eff or
M(q) γ α a_eff (a_eff = clip(a, −1, 1) without a prior; N·m, before the env's own
clipping of the sum to τ_max),
``controller`` the controller's ``diagnostics()``; reset's info has ``controller`` too.

:func:`make_residual_env` is the one-call constructor: ``gym.make`` + the controller of
:func:`agents.registry.make_controller` (default or tuned gains) + the wrapper.

A base may also be a *network*: ``base="network"`` with ``base_model`` the folder of a saved
pure SAC policy (:data:`NETWORK_BASE`, :class:`~agents.network.NetworkController`) — RL then
learns a correction to a frozen learned policy (an imitation, ``train.imitation``) and the
composite stays a pure policy (no model-based controller at run time). It offers no feature
block of its own (the n entries of the last τ_base / τ_max) and hence no control prior.
"""

from __future__ import annotations

import math
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.envs.registration import EnvSpec

from agents.base import Controller, FeatureBlock, FloatArray, HasResidualFeatures
from agents.policy import torque_to_action
from agents.registry import CONTROLLER_NAMES, GAIN_CHOICES, make_controller
from ptrack_gym.errors import InvalidActionError, InvalidConfigError

#: Default residual authority: scale = 0.1 · τ_max per joint.
DEFAULT_SCALE_FRACTION = 0.1
#: Bound of the "last τ_base / τ_max" features: beyond ±2 only "saturated" matters.
_BASE_RATIO_BOUND = 2.0
#: The feature names, per joint j, of the error to the base's own reference point that a
#: control prior (``prior_gain_per_rad``) feeds back, in order of preference: the passivity
#: block's q_r(s) − q (s the controller's path parameter) and the time-indexed blocks'
#: e = q_r(s) − q (s the controller's clock).
PRIOR_ERROR_FEATURES = ("path_error_{j}_rad", "e_{j}_rad")
#: The bases whose feature block has one of :data:`PRIOR_ERROR_FEATURES` for every joint; a
#: test keeps this equal to the controllers' blocks.
PRIOR_BASES = ("passivity", "passivity_paper", "computed_torque", "pd_gravity", "slotine_li")
#: The base name of a *network* base: a saved pure policy (``base_model``, a model folder)
#: run as a controller (:class:`~agents.network.NetworkController`).
NETWORK_BASE = "network"
#: Every base a residual may have: the registry's controllers and a network.
RESIDUAL_BASES: tuple[str, ...] = (*CONTROLLER_NAMES, NETWORK_BASE)


def prior_error_names(names: tuple[str, ...], n: int) -> list[str] | None:
    """The names, in ``names``, of the n-joint reference error a control prior feeds back
    (the first of :data:`PRIOR_ERROR_FEATURES` present for every joint), or None."""
    for pattern in PRIOR_ERROR_FEATURES:
        wanted = [pattern.format(j=j) for j in range(n)]
        if set(wanted) <= set(names):
            return wanted
    return None


def check_safeguards(
    action_penalty: float,
    gate_rad: float | None,
    gate_deadband_rad: float = 0.0,
    scale_accel_rad_s2: float | None = None,
) -> None:
    """Raise :class:`InvalidConfigError` unless ``action_penalty`` is a finite real ≥ 0,
    ``gate_rad`` is None or a finite real > 0 (rad), ``gate_deadband_rad`` is a finite
    real ≥ 0 (rad) that is 0 unless a gate is set, and ``scale_accel_rad_s2`` is None or a
    finite real ≥ 0 (rad/s²)."""
    _check_scale_accel(scale_accel_rad_s2)
    if (
        isinstance(action_penalty, bool)
        or not (isinstance(action_penalty, (int, float)) and math.isfinite(action_penalty))
        or action_penalty < 0
    ):
        raise InvalidConfigError(f"action_penalty must be finite and >= 0, got {action_penalty!r}")
    if gate_rad is not None and (
        isinstance(gate_rad, bool)
        or not isinstance(gate_rad, (int, float))
        or not (math.isfinite(gate_rad) and gate_rad > 0)
    ):
        raise InvalidConfigError(f"gate_rad must be None or finite and > 0, got {gate_rad!r}")
    if (
        isinstance(gate_deadband_rad, bool)
        or not isinstance(gate_deadband_rad, (int, float))
        or not (math.isfinite(gate_deadband_rad) and gate_deadband_rad >= 0)
    ):
        raise InvalidConfigError(
            f"gate_deadband_rad must be finite and >= 0, got {gate_deadband_rad!r}"
        )
    if gate_deadband_rad > 0 and gate_rad is None:
        raise InvalidConfigError("gate_deadband_rad needs gate_rad (the gate it widens)")


def check_prior(base: str | None, prior_gain_per_rad: float) -> None:
    """Raise :class:`InvalidConfigError` unless ``prior_gain_per_rad`` is a finite real ≥ 0
    (1/rad) that is 0 unless ``base`` is one of :data:`PRIOR_BASES` (None: a controller
    object, whose feature block decides)."""
    if (
        isinstance(prior_gain_per_rad, bool)
        or not isinstance(prior_gain_per_rad, (int, float))
        or not (math.isfinite(prior_gain_per_rad) and prior_gain_per_rad >= 0)
    ):
        raise InvalidConfigError(
            f"prior_gain_per_rad must be finite and >= 0, got {prior_gain_per_rad!r}"
        )
    if prior_gain_per_rad > 0 and base is not None and base not in PRIOR_BASES:
        raise InvalidConfigError(
            f"a control prior (prior_gain_per_rad) needs a base of {PRIOR_BASES}, got {base!r}"
        )


def check_base_model(
    base: str | None, base_model: str | None, robot: str | None = None, base_gains: str = "default"
) -> None:
    """Raise :class:`InvalidConfigError` unless ``base_model`` (a model folder) is given
    exactly when ``base`` is :data:`NETWORK_BASE` (None: a controller object) and then
    holds a pure policy of ``robot`` (when given; :func:`agents.network.check_network_folder`)
    and ``base_gains`` stays "default" (a network has no gains)."""
    if base == NETWORK_BASE:
        if base_gains != "default":
            raise InvalidConfigError("a network base has no gains: keep base_gains 'default'")
        if not isinstance(base_model, str) or not base_model:
            raise InvalidConfigError("a network base needs base_model, a pure policy's folder")
        from agents.network import check_network_folder

        check_network_folder(base_model, robot)
    elif base_model is not None:
        raise InvalidConfigError(f"base_model is for a {NETWORK_BASE!r} base, not {base!r}")


def build_base(env: Any, base: str, base_gains: str, base_model: str | None) -> Controller:
    """The base controller ``base`` for ``env``: a registry controller with ``base_gains``,
    or, for :data:`NETWORK_BASE`, the pure policy saved in ``base_model``."""
    if base == NETWORK_BASE:
        from agents.network import load_network_controller

        return load_network_controller(str(base_model), env)
    return make_controller(base, env, base_gains)


def check_base_gains(base_gains: str) -> None:
    """Raise :class:`InvalidConfigError` unless ``base_gains`` is one of
    ``agents.registry.GAIN_CHOICES`` ("default", "tuned")."""
    if base_gains not in GAIN_CHOICES:
        raise InvalidConfigError(f"base_gains must be one of {GAIN_CHOICES}, got {base_gains!r}")


class ControllerFeatures:
    """The residual observation's controller block: the controller's own
    :class:`~agents.base.FeatureBlock` (when it offers one, :class:`HasResidualFeatures`)
    followed by the last τ_base / τ_max (n entries, ±2); float64, clipped to its bounds.

    Attributes:
        names: one name per entry.
        low, high: finite bounds per entry.
    """

    def __init__(self, controller: Controller, max_speed_rad_s: float) -> None:
        n = controller.n
        ratio_names = tuple(f"tau_base_ratio_{j}" for j in range(n))
        ratio_high = np.full(n, _BASE_RATIO_BOUND)
        self.block: FeatureBlock | None = (
            controller.residual_features(max_speed_rad_s)
            if isinstance(controller, HasResidualFeatures)
            else None
        )
        if self.block is None:
            self.names, self.low, self.high = ratio_names, -ratio_high, ratio_high
        else:
            self.names = (*self.block.names, *ratio_names)
            self.low = np.concatenate([self.block.low, -ratio_high])
            self.high = np.concatenate([self.block.high, ratio_high])

    def __call__(self, q: FloatArray, qd: FloatArray, base_ratio: FloatArray) -> FloatArray:
        """Features at measured (q, q̇) (rad, rad/s), clipped to [low, high];
        ``base_ratio`` is the last τ_base / τ_max, shape (n,)."""
        x = (
            base_ratio
            if self.block is None
            else np.concatenate([self.block.values(q, qd), base_ratio])
        )
        return np.minimum(np.maximum(np.nan_to_num(x), self.low), self.high)


class ResidualWrapper(
    gym.Wrapper[np.ndarray, np.ndarray, np.ndarray, np.ndarray], gym.utils.RecordConstructorArgs
):
    """Learn a bounded torque correction on top of a base controller (module docstring).

    Args:
        env: a ptrack_gym env (any wrapper of a ``TrackingEnv``).
        controller: the base controller, built for ``env``'s robot (same n), or the name
            of a controller (``agents.registry.CONTROLLER_NAMES``, ``base_gains``). Given by
            name, the wrapper is re-creatable from ``env.spec`` (``spec.make()``, as
            Gymnasium's checker and ``gym.make(spec)`` do); given as an object, ``spec``
            is None (a controller object cannot be rebuilt from a spec).
        scale_nm: residual authority (N·m): a scalar or one value per joint, each finite
            and ≥ 0; None (default) → ``DEFAULT_SCALE_FRACTION`` · τ_max.
        include_controller_state: append the controller's feature vector to the
            observation (default True).
        action_penalty: w ≥ 0 of the penalty on the learned part (module docstring).
        gate_rad: d_g (rad) of the path-error gate; None (default): no gate.
        gate_deadband_rad: d₀ (rad) of the gate: γ = 0 while d ≤ d₀ (default 0).
        base_gains: with ``controller`` given by name, its gains: ``"default"`` (the
            robot's default rates at the env's control rate) or ``"tuned"`` (the rates
            of ``agents/tuned``, as the main job runs it); must stay ``"default"`` for a
            controller object, whose gains are its own.
        prior_gain_per_rad: g ≥ 0 (1/rad) of the control prior (module docstring); 0
            (default): none.
        base_model: with ``controller="network"`` (:data:`NETWORK_BASE`), the folder of the
            saved pure policy that is the base (:mod:`agents.network`); None otherwise.

    Raises:
        InvalidConfigError: (a ``ValueError``) a joint-count mismatch or a bad scale.
    """

    def __init__(
        self,
        env: gym.Env[np.ndarray, np.ndarray],
        controller: Controller | str,
        scale_nm: float | FloatArray | None = None,
        include_controller_state: bool = True,
        action_penalty: float = 0.0,
        gate_rad: float | None = None,
        gate_deadband_rad: float = 0.0,
        scale_accel_rad_s2: float | None = None,
        base_gains: str = "default",
        prior_gain_per_rad: float = 0.0,
        base_model: str | None = None,
    ) -> None:
        check_base_gains(base_gains)
        if not isinstance(controller, str) and base_gains != "default":
            raise InvalidConfigError("base_gains is for a base given by name, not an object")
        check_base_model(
            controller if isinstance(controller, str) else None,
            base_model,
            env.unwrapped.robot_profile.name,
            base_gains,
        )
        self._controller_name = controller if isinstance(controller, str) else None
        self._registered = False  # set by residual_env: the spec is the registered one
        if self._controller_name is not None:
            gym.utils.RecordConstructorArgs.__init__(
                self,
                controller=controller,
                scale_nm=scale_nm,
                include_controller_state=include_controller_state,
                action_penalty=action_penalty,
                gate_rad=gate_rad,
                gate_deadband_rad=gate_deadband_rad,
                scale_accel_rad_s2=scale_accel_rad_s2,
                base_gains=base_gains,
                prior_gain_per_rad=prior_gain_per_rad,
                base_model=base_model,
            )
        super().__init__(env)
        u = env.unwrapped
        self.tracking_env = u
        self.n = int(u.n)
        if isinstance(controller, str):
            controller = build_base(env, controller, base_gains, base_model)
        self.base_gains = base_gains
        self.base_model = base_model
        if controller.n != self.n:
            raise InvalidConfigError(f"controller has {controller.n} joints, env has {self.n}")
        self.controller = controller
        self.torque_limits_nm = np.asarray(u.torque_limits_nm, dtype=np.float64)
        check_safeguards(action_penalty, gate_rad, gate_deadband_rad, scale_accel_rad_s2)
        if scale_accel_rad_s2 is not None and scale_nm is not None:
            raise InvalidConfigError("give scale_nm or scale_accel_rad_s2, not both")
        self.scale_accel_rad_s2 = None if scale_accel_rad_s2 is None else float(scale_accel_rad_s2)
        if scale_nm is None:
            scale = DEFAULT_SCALE_FRACTION * self.torque_limits_nm
        else:
            raw = np.asarray(scale_nm, dtype=np.float64)
            if raw.ndim > 1 or (raw.ndim == 1 and raw.shape != (self.n,)):
                raise InvalidConfigError(
                    f"scale_nm must be a scalar or have {self.n} entries, got shape {raw.shape}"
                )
            scale = np.broadcast_to(raw, (self.n,)).copy()
        if not (np.all(np.isfinite(scale)) and np.all(scale >= 0.0)):
            raise InvalidConfigError(f"scale_nm must be finite and >= 0, got {scale.tolist()}")
        self.scale_nm: FloatArray | None = None if self.scale_accel_rad_s2 is not None else scale
        """Torque authority per joint (N·m); None when the residual is an acceleration."""
        self.action_penalty = float(action_penalty)
        self.gate_rad = None if gate_rad is None else float(gate_rad)
        self.gate_deadband_rad = float(gate_deadband_rad)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.n,), dtype=np.float32)

        inner = env.observation_space
        assert isinstance(inner, spaces.Box)
        self.features: ControllerFeatures | None = None
        if include_controller_state:
            self.features = ControllerFeatures(controller, float(u.max_speed))
            low = np.concatenate([inner.low, self.features.low.astype(np.float32)])
            high = np.concatenate([inner.high, self.features.high.astype(np.float32)])
            self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self._base_ratio = np.zeros(self.n)
        check_prior(self._controller_name, prior_gain_per_rad)
        self.prior_gain_per_rad = float(prior_gain_per_rad)
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

    @property
    def spec(self) -> EnvSpec | None:
        """The env's spec with this wrapper appended, when the controller was given by
        name; None when it was given as an object (it cannot be rebuilt). Built by a
        registered residual id (:func:`residual_env`), the registered spec itself."""
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
        q, qd = u.measured_joint_state()
        self.controller.reset(q, qd, u.s0 + u.t)
        self._base_ratio = np.zeros(self.n)
        info["controller"] = self.controller.diagnostics()
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
        inner_action = torque_to_action(tau_base + tau_res, self.torque_limits_nm)
        obs, reward, terminated, truncated, info = self.env.step(inner_action)
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
        info["controller"] = self.controller.diagnostics()
        self._last_obs = self._augment(obs)
        return self._last_obs, reward, terminated, truncated, info


def make_residual_env(
    env_id: str,
    base: str = "passivity",
    scale_fraction: float = DEFAULT_SCALE_FRACTION,
    include_controller_state: bool = True,
    action_penalty: float = 0.0,
    gate_rad: float | None = None,
    gate_deadband_rad: float = 0.0,
    scale_accel_rad_s2: float | None = None,
    base_gains: str = "default",
    prior_gain_per_rad: float = 0.0,
    base_model: str | None = None,
    **env_kwargs: Any,
) -> ResidualWrapper:
    """``gym.make(env_id, **env_kwargs)`` wrapped in a :class:`ResidualWrapper` around
    the controller ``base`` (one of ``agents.registry.CONTROLLER_NAMES``) with
    ``base_gains`` ("default" or "tuned") — or the pure policy in ``base_model`` for
    ``base="network"`` — with scale = ``scale_fraction`` · τ_max (N·m)
    — or, with ``scale_accel_rad_s2`` α, the residual M(q) α a (an acceleration, module
    docstring) — and the wrapper's ``action_penalty``, ``gate_rad``,
    ``gate_deadband_rad`` and ``prior_gain_per_rad``.

    ``env_kwargs`` go to ``gym.make`` (env arguments such as ``control_hz``,
    ``disturbance``, and ``max_episode_steps``), which rejects unknown names.

    Raises:
        InvalidConfigError: (a ``ValueError``) an unknown base or a bad scale fraction.
    """
    _check_base(base, scale_fraction, scale_accel_rad_s2)
    check_base_gains(base_gains)
    check_prior(base, prior_gain_per_rad)
    check_base_model(base, base_model, base_gains=base_gains)
    env = gym.make(env_id, **env_kwargs)
    return _wrap(
        env, base, scale_fraction, include_controller_state,
        action_penalty, gate_rad, gate_deadband_rad, scale_accel_rad_s2, base_gains,
        prior_gain_per_rad, base_model,
    )  # fmt: skip


def _check_base(base: str, scale_fraction: float, scale_accel_rad_s2: float | None) -> None:
    if base not in RESIDUAL_BASES:
        raise InvalidConfigError(f"unknown base controller {base!r}; known: {RESIDUAL_BASES}")
    if not (math.isfinite(scale_fraction) and scale_fraction >= 0.0):
        raise InvalidConfigError(f"scale_fraction must be finite and >= 0, got {scale_fraction}")
    _check_scale_accel(scale_accel_rad_s2)


def _check_scale_accel(scale_accel_rad_s2: float | None) -> None:
    if scale_accel_rad_s2 is not None and (
        isinstance(scale_accel_rad_s2, bool)
        or not isinstance(scale_accel_rad_s2, (int, float))
        or not (math.isfinite(scale_accel_rad_s2) and scale_accel_rad_s2 >= 0)
    ):
        raise InvalidConfigError(
            f"scale_accel_rad_s2 must be None or finite and >= 0, got {scale_accel_rad_s2!r}"
        )


def _wrap(
    env: gym.Env[np.ndarray, np.ndarray],
    base: str,
    scale_fraction: float,
    include_controller_state: bool,
    action_penalty: float,
    gate_rad: float | None,
    gate_deadband_rad: float,
    scale_accel_rad_s2: float | None,
    base_gains: str = "default",
    prior_gain_per_rad: float = 0.0,
    base_model: str | None = None,
) -> ResidualWrapper:
    """``env`` in a :class:`ResidualWrapper` around ``base`` (its ``base_gains``, or the
    policy in ``base_model``) with
    scale = ``scale_fraction`` · τ_max (N·m), or the acceleration authority
    ``scale_accel_rad_s2`` when given; ``env`` is closed if that fails."""
    try:
        limits = np.asarray(env.unwrapped.torque_limits_nm, dtype=np.float64)
        scale_nm = (
            tuple(float(x) for x in scale_fraction * limits) if scale_accel_rad_s2 is None else None
        )
        return ResidualWrapper(
            env, base, scale_nm, include_controller_state,
            action_penalty, gate_rad, gate_deadband_rad, scale_accel_rad_s2, base_gains,
            prior_gain_per_rad, base_model,
        )  # fmt: skip
    except BaseException:
        env.close()
        raise


def _camel(name: str) -> str:
    return "".join(part.capitalize() for part in name.split("_"))


def residual_env_id(env_id: str, base: str) -> str:
    """``ptrack_gym/<Robot>Track-v0`` + ``computed_torque`` →
    ``ptrack_gym/<Robot>Track-Residual-ComputedTorque-v0``."""
    stem = env_id.removesuffix("-v0")
    return f"{stem}-Residual-{_camel(base)}-v0"


def residual_env(
    robot: str,
    base: str,
    scale_fraction: float = DEFAULT_SCALE_FRACTION,
    include_controller_state: bool = True,
    action_penalty: float = 0.0,
    gate_rad: float | None = None,
    gate_deadband_rad: float = 0.0,
    scale_accel_rad_s2: float | None = None,
    base_gains: str = "default",
    prior_gain_per_rad: float = 0.0,
    **env_kwargs: Any,
) -> ResidualWrapper:
    """The entry point of the registered residual ids (:func:`register_residual_envs`):
    a ``TrackingEnv(robot=robot, **env_kwargs)`` in a :class:`ResidualWrapper` around the
    controller ``base`` with ``base_gains``; ``gym.make`` adds the time limit and its
    checkers.

    Raises:
        InvalidConfigError: an unknown base or a bad scale fraction (unknown env
            arguments raise ``TypeError``, bad values ``ValueError``, as ``TrackingEnv``).
    """
    from ptrack_gym.envs.tracking import TrackingEnv

    _check_base(base, scale_fraction, scale_accel_rad_s2)
    check_base_gains(base_gains)
    check_prior(base, prior_gain_per_rad)
    env = TrackingEnv(robot=robot, **env_kwargs)
    wrapper = _wrap(
        env, base, scale_fraction, include_controller_state,
        action_penalty, gate_rad, gate_deadband_rad, scale_accel_rad_s2, base_gains,
        prior_gain_per_rad,
    )  # fmt: skip
    wrapper._registered = True
    return wrapper


def register_residual_envs() -> list[str]:
    """Register ``ptrack_gym/<Robot>Track-Residual-<Base>-v0`` for every robot and base
    controller (string entry point :func:`residual_env`, the plain id's time limit) and
    return the ids. ``import agents`` calls it; ``ptrack_gym`` never imports ``agents``."""
    from ptrack_gym.robots import ROBOTS

    ids = []
    for profile in ROBOTS.values():
        plain = gym.spec(profile.env_id)
        for base in CONTROLLER_NAMES:
            env_id = residual_env_id(profile.env_id, base)
            if env_id not in gym.registry:
                gym.register(
                    id=env_id,
                    entry_point="agents.residual:residual_env",
                    kwargs={"robot": profile.name, "base": base},
                    max_episode_steps=plain.max_episode_steps,
                )
            ids.append(env_id)
    return ids
