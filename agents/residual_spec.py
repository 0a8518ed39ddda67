"""The options of a residual policy around a base controller, whole: :class:`ResidualSpec`.

One frozen record says which base the residual corrects (a registry controller with its
gains, or a saved pure policy), the authority of the learned action (a torque, or an
acceleration), what the policy observes, and the safeguards (a penalty on the learned part,
a path-error gate, a control prior). :mod:`agents.residual_wrapper` states the equation
each option enters. A spec is checked when it is made; what needs the env (the joint count
of ``scale_nm``, the robot a ``base_model`` was trained on) is checked by the wrapper.

Keyword style: :meth:`ResidualSpec.from_options` makes a spec from keyword options — the
one place an unknown option is refused by name — and :func:`split_options` separates a
spec's options from an env's.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np

from agents.energy_tank import EnergyTank
from agents.registry import CONTROLLER_NAMES, PRIOR_BASES, check_gain_choice
from ptrack_gym.errors import InvalidConfigError

#: Default residual authority: scale = 0.1 · τ_max per joint.
DEFAULT_SCALE_FRACTION = 0.1
#: The base name of a *network* base: a saved pure policy (``base_model``, a model folder)
#: run as a controller (:class:`~agents.network.NetworkController`).
NETWORK_BASE = "network"
#: The bases an energy-tank residual may have: the passivity laws (their dissipation fills it).
TANK_BASES: tuple[str, ...] = ("passivity", "passivity_paper")
#: Every base a residual may have: the registry's controllers and a network.
RESIDUAL_BASES: tuple[str, ...] = (*CONTROLLER_NAMES, NETWORK_BASE)


@dataclass(frozen=True, kw_only=True)
class ResidualSpec:
    """Every option of a residual policy (module docstring); checked at construction.

    Raises:
        InvalidConfigError: (a ``ValueError``) an option out of its domain, naming it.
    """

    base: str = "passivity"
    """The base controller: a name of :data:`agents.registry.CONTROLLER_NAMES`, or
    :data:`NETWORK_BASE` for a saved pure policy."""
    base_gains: str | Mapping[str, float] = "default"
    """The base's gains: ``"default"`` (the robot's default rates at the env's control rate),
    ``"tuned"`` (the rates in ``agents/tuned``, as they are now) or the rates themselves
    (rate → value, as ``make_controller`` takes them: what a trained residual pins, since
    ``agents/tuned`` changes when a controller is retuned); ``"default"`` for a network base."""
    base_model: str | None = None
    """With ``base`` = :data:`NETWORK_BASE`, the folder of the saved pure policy that is the
    base (:mod:`agents.network`); None otherwise."""
    scale_fraction: float = DEFAULT_SCALE_FRACTION
    """Torque authority as a fraction ≥ 0 of the torque limits: scale = ``scale_fraction`` ·
    τ_max (N·m, per joint), unless ``scale_nm`` or ``scale_accel_rad_s2`` is given."""
    scale_nm: float | tuple[float, ...] | None = None
    """Torque authority (N·m): one value for every joint or one per joint, each finite and
    ≥ 0; None: from ``scale_fraction``. Not with ``scale_accel_rad_s2``."""
    scale_accel_rad_s2: float | None = None
    """Acceleration authority α ≥ 0 (rad/s²): the residual torque is M(q) α a; None: a
    torque residual."""
    include_controller_state: bool = True
    """Append the base's feature block (:mod:`agents.residual_features`) to the observation."""
    action_penalty: float = 0.0
    """w ≥ 0 of the reward term w (1 − |clip(a)|²/n) on the learned action a."""
    gate_rad: float | None = None
    """d_g > 0 (rad) of the path-error gate γ(d) = 1 − exp(−((d − d₀)⁺/d_g)²); None: no gate."""
    gate_deadband_rad: float = 0.0
    """d₀ ≥ 0 (rad) of the gate (γ = 0 while d ≤ d₀); > 0 needs ``gate_rad``."""
    prior_gain_per_rad: float = 0.0
    """g ≥ 0 (1/rad) of the control prior a_prior = clip(g (q_r(s) − q), −1, 1); 0: none;
    > 0 needs a base of :data:`agents.registry.PRIOR_BASES`."""
    tank: bool = False
    """Gate the residual by an energy tank filled by the passivity law's own dissipation
    (:mod:`agents.energy_tank`); needs a base of :data:`TANK_BASES`."""
    tank_beta: float = 0.5
    """β ∈ [0, 1]: the fraction of the law's dissipation that fills the tank."""
    tank_initial_j: float = 0.5
    """T(0) (J), in [``tank_floor_j``, ``tank_cap_j``]."""
    tank_floor_j: float = 0.01
    """T_min > 0 (J): an injecting residual is held back so the tank stays above it."""
    tank_cap_j: float = 2.0
    """T_max (J): the most the tank holds."""

    def __post_init__(self) -> None:
        if self.base not in RESIDUAL_BASES:
            raise InvalidConfigError(
                f"unknown base controller {self.base!r}; known: {RESIDUAL_BASES}"
            )
        _check_real("scale_fraction", self.scale_fraction)
        check_safeguards(
            self.action_penalty, self.gate_rad, self.gate_deadband_rad, self.scale_accel_rad_s2
        )
        check_base_gains(self.base_gains)
        check_prior(self.base, self.prior_gain_per_rad)
        _check_base_pairing(self.base, self.base_model, self.base_gains)
        if not isinstance(self.include_controller_state, bool):
            raise InvalidConfigError(
                f"include_controller_state must be True or False, got "
                f"{self.include_controller_state!r}"
            )
        if not isinstance(self.tank, bool):
            raise InvalidConfigError(f"tank must be True or False, got {self.tank!r}")
        if self.tank:
            if self.base not in TANK_BASES:
                raise InvalidConfigError(
                    f"an energy tank is filled by the passivity law's dissipation: its base "
                    f"must be one of {TANK_BASES}, got {self.base!r}"
                )
            self.energy_tank()  # checks the tank's parameters
        if self.scale_nm is not None:
            if self.scale_accel_rad_s2 is not None:
                raise InvalidConfigError("give scale_nm or scale_accel_rad_s2, not both")
            object.__setattr__(self, "scale_nm", _torque_authority(self.scale_nm))

    @classmethod
    def from_options(
        cls, options: Mapping[str, Any], start: ResidualSpec | None = None
    ) -> ResidualSpec:
        """``start`` (default: the defaults) with the fields named in ``options`` replaced.

        Raises:
            InvalidConfigError: an option that is not a field (naming every such one), or a
                value out of its domain.
        """
        unknown = sorted(set(options) - set(SPEC_FIELDS))
        if unknown:
            raise InvalidConfigError(
                f"unknown residual option(s) {unknown}; known: {list(SPEC_FIELDS)}"
            )
        return dataclasses.replace(start if start is not None else cls(), **options)

    def energy_tank(self) -> EnergyTank:
        """A new tank of this spec's parameters (whether or not ``tank`` is set)."""
        return EnergyTank(self.tank_beta, self.tank_initial_j, self.tank_floor_j, self.tank_cap_j)

    def options(self) -> dict[str, Any]:
        """Every field, name → value (plain Python values: str, float, tuple, bool, None)."""
        return {name: getattr(self, name) for name in SPEC_FIELDS}


#: The names of :class:`ResidualSpec`'s fields, in order.
SPEC_FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(ResidualSpec))


def split_options(options: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """(the options that are :class:`ResidualSpec` fields, the rest — an env's)."""
    spec = {k: v for k, v in options.items() if k in SPEC_FIELDS}
    return spec, {k: v for k, v in options.items() if k not in SPEC_FIELDS}


def _check_real(name: str, value: object, *, optional: bool = False, strict: bool = False) -> None:
    """Raise :class:`InvalidConfigError` unless ``value`` is a finite real ≥ 0 (> 0 when
    ``strict``), or None when ``optional``."""
    if optional and value is None:
        return
    if (
        isinstance(value, bool)
        or not isinstance(value, numbers.Real)
        or not math.isfinite(value)
        or value < 0
        or (strict and value == 0)
    ):
        domain = f"{'None or ' if optional else ''}finite and {'>' if strict else '>='} 0"
        raise InvalidConfigError(f"{name} must be {domain}, got {value!r}")


def _torque_authority(value: object) -> float | tuple[float, ...]:
    """``scale_nm`` as a float or a tuple of floats (N·m), each finite and ≥ 0."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidConfigError(f"scale_nm must be numbers, got {value!r}") from None
    if arr.ndim > 1:
        raise InvalidConfigError(f"scale_nm must be a scalar or one value per joint: {arr.shape}")
    if not (np.all(np.isfinite(arr)) and np.all(arr >= 0.0)):
        raise InvalidConfigError(f"scale_nm must be finite and >= 0, got {arr.tolist()}")
    return float(arr) if arr.ndim == 0 else tuple(float(x) for x in arr)


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
    _check_real("scale_accel_rad_s2", scale_accel_rad_s2, optional=True)
    _check_real("action_penalty", action_penalty)
    _check_real("gate_rad", gate_rad, optional=True, strict=True)
    _check_real("gate_deadband_rad", gate_deadband_rad)
    if gate_deadband_rad > 0 and gate_rad is None:
        raise InvalidConfigError("gate_deadband_rad needs gate_rad (the gate it widens)")


def check_prior(base: str | None, prior_gain_per_rad: float) -> None:
    """Raise :class:`InvalidConfigError` unless ``prior_gain_per_rad`` is a finite real ≥ 0
    (1/rad) that is 0 unless ``base`` is one of :data:`agents.registry.PRIOR_BASES` (None: a
    controller object, whose feature block decides)."""
    _check_real("prior_gain_per_rad", prior_gain_per_rad)
    if prior_gain_per_rad > 0 and base is not None and base not in PRIOR_BASES:
        raise InvalidConfigError(
            f"a control prior (prior_gain_per_rad) needs a base of {PRIOR_BASES}, got {base!r}"
        )


def check_base_gains(base_gains: object) -> None:
    """Raise :class:`InvalidConfigError` unless ``base_gains`` is one of
    :data:`agents.registry.GAIN_CHOICES` ("default", "tuned") or a non-empty mapping of rate
    names to finite real numbers (which rates the base knows is checked when it is built)."""
    if isinstance(base_gains, Mapping):
        bad = {
            k: v
            for k, v in base_gains.items()
            if not isinstance(k, str)
            or isinstance(v, bool)
            or not isinstance(v, (int, float))
            or not math.isfinite(v)
        }
        if not base_gains or bad:
            raise InvalidConfigError(
                f"base_gains as rates must map rate names to finite numbers, got "
                f"{dict(base_gains)!r}"
            )
        return
    check_gain_choice(base_gains, "base_gains")


def _check_base_pairing(base: str | None, base_model: str | None, base_gains: object) -> None:
    """A ``base_model`` exactly for a network base, which keeps the default gains."""
    if base == NETWORK_BASE:
        if base_gains != "default":
            raise InvalidConfigError("a network base has no gains: keep base_gains 'default'")
        if not isinstance(base_model, str) or not base_model:
            raise InvalidConfigError("a network base needs base_model, a pure policy's folder")
    elif base_model is not None:
        raise InvalidConfigError(f"base_model is for a {NETWORK_BASE!r} base, not {base!r}")


def check_base_model(
    base: str | None,
    base_model: str | None,
    robot: str | None = None,
    base_gains: object = "default",
) -> None:
    """Raise :class:`InvalidConfigError` unless ``base_model`` (a model folder) is given
    exactly when ``base`` is :data:`NETWORK_BASE` (None: a controller object) and then
    holds a pure policy of ``robot`` (when given; :func:`agents.network.check_network_folder`)
    and ``base_gains`` stays "default" (a network has no gains)."""
    _check_base_pairing(base, base_model, base_gains)
    if base == NETWORK_BASE:
        from agents.network import check_network_folder

        check_network_folder(str(base_model), robot)


def resolve_spec(
    spec: ResidualSpec | str, options: Mapping[str, Any]
) -> tuple[ResidualSpec, dict[str, Any]]:
    """(the residual spec, the env's options) of a builder's arguments: ``spec`` — a
    :class:`ResidualSpec`, or the base's name for the defaults — with the fields named in
    ``options`` replaced (:meth:`ResidualSpec.from_options`); the other options are the
    env's.

    Raises:
        InvalidConfigError: the base given twice (by name and as ``base``), or a value out
            of its domain.
    """
    own, env_options = split_options(options)
    if isinstance(spec, ResidualSpec):
        return ResidualSpec.from_options(own, spec), env_options
    if "base" in own:
        raise InvalidConfigError(f"the base is given twice: {spec!r} and base={own['base']!r}")
    return ResidualSpec.from_options({"base": spec, **own}), env_options


#: The options a run configuration sets beside its base and authority (``train``'s configs
#: name the base ``residual`` and keep ``scale_fraction`` apart), in its order.
RUN_OPTIONS: tuple[str, ...] = (
    "action_penalty",
    "gate_rad",
    "gate_deadband_rad",
    "scale_accel_rad_s2",
    "base_gains",
    "prior_gain_per_rad",
    "base_model",
    "tank",
    "tank_beta",
)
#: :data:`RUN_OPTIONS` with the spec's defaults: a compatibility view for ``train``.
WRAPPER_DEFAULTS: Mapping[str, Any] = MappingProxyType(
    {name: getattr(ResidualSpec(), name) for name in RUN_OPTIONS}
)
