"""The registry of controllers: one :class:`ControllerEntry` per controller name.

Adding a controller is one file (a class with the :class:`~agents.base.Controller`
interface, a ``build(ctx, gains=None)`` function that fills in default gains, and the
module constants of :class:`RateSource`) and one entry in :data:`ENTRIES`. Every other
table here (:data:`CONTROLLERS`, :data:`CONTROLLER_NAMES`, :data:`RATE_MODULES`,
:data:`TUNABLE`, :data:`PRIOR_BASES`) is a read-only view of that one.

:func:`make_controller` is the one constructor the residual wrapper, the evaluation and
training scripts and the benchmarks use. Every controller is built from the env's
*nominal* model (``env.unwrapped.model``), never from the simulated body.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any, Protocol

import yaml

from agents import (
    adaptive_slotine_li,
    computed_torque,
    observer_computed_torque,
    passivity,
    path_following,
    pd_gravity,
    pid_gravity,
    slotine_li,
)
from agents.base import ControlContext, Controller
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots.profile import RobotProfile

#: A controller builder: (context, gains) → controller; gains None (the robot's defaults), a
#: mapping of rates, or the controller's gains dataclass.
Builder = Callable[[ControlContext, Any], Controller]


class RateSource(Protocol):
    """What states a controller's gain rates (its bandwidths and ratios, made absolute by its
    ``gains_from_rates``): the controller's module, through these constants."""

    #: The key of its rates in a robot profile's ``controller_gains``.
    NAME: str
    #: Generic default rates, rate → value (ω in rad/s, dimensionless ratios, …).
    DEFAULT_RATES: Mapping[str, Any]
    #: What the tuner (``train.studies.tune``) searches: rate → (low, high, log scale).
    TUNABLE: Mapping[str, tuple[float, float, bool]]
    #: The rates one gain scale multiplies (``train.studies.fronts``): its bandwidths.
    BANDWIDTHS: tuple[str, ...]


@dataclass(frozen=True)
class ControllerEntry:
    """One controller of the registry.

    Attributes:
        name: the name :func:`make_controller`, the configs and the residual ids use.
        build: its builder, ``build(ctx, gains=None)``.
        rates: the module stating its gain rates (:class:`RateSource`), or an object with
            its constants: the paper's passivity law shares the default one's, less the
            tuned rates its law fixes (``agents.passivity.PAPER_RATES``).
        prior_base: whether a residual on it may have a control prior: its residual
            feature block holds the reference error q_r(s) − q per joint
            (``agents.residual_features.PRIOR_ERROR_FEATURES``).
        tunable: whether the tuner searches its rates (:data:`TUNABLE`).
        gain_rules: the revision of how its builder makes gains of the same rates; raised
            when a change moves its gains at some control rate (a study's record of the
            rates it ran then differs: ``train.evaluation.rate_record``). 1 for all but the
            passivity laws, 2 since their rate cap lowers the pump with the springs
            (docs/control_rates.md, loop 6).
    """

    name: str
    build: Builder
    rates: RateSource
    prior_base: bool = True
    tunable: bool = True
    gain_rules: int = 1


def _table(*entries: ControllerEntry) -> Mapping[str, ControllerEntry]:
    """name → entry, read-only; a repeated name raises."""
    table = {entry.name: entry for entry in entries}
    if len(table) != len(entries):
        raise InvalidConfigError("two registry entries share a name")
    return MappingProxyType(table)


#: Every controller, name → entry: the one table.
ENTRIES: Mapping[str, ControllerEntry] = _table(
    ControllerEntry("passivity", passivity.build, passivity, gain_rules=2),
    ControllerEntry("passivity_paper", passivity.build_paper, passivity.PAPER_RATES, gain_rules=2),
    ControllerEntry("computed_torque", computed_torque.build, computed_torque),
    ControllerEntry("pd_gravity", pd_gravity.build, pd_gravity),
    ControllerEntry("slotine_li", slotine_li.build, slotine_li),
    ControllerEntry("pid_gravity", pid_gravity.build, pid_gravity),
    ControllerEntry(
        "computed_torque_observer", observer_computed_torque.build, observer_computed_torque
    ),
    ControllerEntry("adaptive_slotine_li", adaptive_slotine_li.build, adaptive_slotine_li),
    ControllerEntry("computed_torque_path", path_following.build, path_following),
)

#: The controller names :func:`make_controller` accepts, in the table's order.
CONTROLLER_NAMES: tuple[str, ...] = tuple(ENTRIES)
#: name → builder (a view of :data:`ENTRIES`).
CONTROLLERS: Mapping[str, Builder] = MappingProxyType({e.name: e.build for e in ENTRIES.values()})
#: name → the module stating its rates (a view of :data:`ENTRIES`).
RATE_MODULES: Mapping[str, RateSource] = MappingProxyType(
    {e.name: e.rates for e in ENTRIES.values()}
)
#: name → the rates the tuner searches, rate → (low, high, log scale), of the tunable entries.
TUNABLE: Mapping[str, Mapping[str, tuple[float, float, bool]]] = MappingProxyType(
    {e.name: e.rates.TUNABLE for e in ENTRIES.values() if e.tunable}
)
#: The controllers a residual with a control prior may have as its base.
PRIOR_BASES: tuple[str, ...] = tuple(e.name for e in ENTRIES.values() if e.prior_base)

#: Where tuned gains live: ``<robot>-<controller>.yml`` (written by the tuner).
TUNED_DIR = Path(__file__).resolve().parent / "tuned"

#: The named gain choices of every entry point.
GAIN_CHOICES: tuple[str, ...] = ("default", "tuned")


def entry(name: str) -> ControllerEntry:
    """The registry entry of controller ``name``.

    Raises:
        InvalidConfigError: (a ``ValueError``) an unknown name, listing the known ones.
    """
    try:
        return ENTRIES[name]
    except KeyError:
        raise InvalidConfigError(
            f"unknown controller {name!r}; known: {list(CONTROLLER_NAMES)}"
        ) from None


def check_gain_choice(gains: object, what: str = "gains") -> str:
    """``gains`` if it is one of :data:`GAIN_CHOICES`, else :class:`InvalidConfigError`
    naming ``what``."""
    if not isinstance(gains, str) or gains not in GAIN_CHOICES:
        raise InvalidConfigError(f"{what} must be one of {GAIN_CHOICES}, got {gains!r}")
    return gains


def tuned_rates(robot: str, controller: str) -> dict[str, Any]:
    """The tuned rates of ``controller`` on ``robot`` (``agents/tuned/<robot>-<controller>.yml``
    in :data:`TUNED_DIR`), rate → value.

    Raises:
        InvalidConfigError: no tuned gains for that pair (the message lists those there are).
    """
    path = TUNED_DIR / f"{robot}-{controller}.yml"
    if not path.exists():
        have = sorted(p.stem for p in TUNED_DIR.glob("*.yml"))
        raise InvalidConfigError(f"no tuned gains for {controller} on {robot}; tuned: {have}")
    return dict(yaml.safe_load(path.read_text())["rates"])


def pinned_rates(
    profile: RobotProfile, name: str, gains: str, over: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """The rates a residual run or a search pins for ``name`` on the robot of ``profile``
    with ``gains`` ("default" or "tuned"): every numeric rate of :func:`effective_rates`
    (the gains, not choices such as ``pump``) — a tuned file's rates *and* the defaults of
    the rates it does not name — so neither a retune nor a new default can move them; with
    a run's own rates ``over`` them (a search's ``rates``, a sweep's ``controller_rates``).

    Raises:
        InvalidConfigError: an unknown controller or gain choice, or no tuned gains.
    """
    pinned = {
        key: value
        for key, value in effective_rates(profile, name, check_gain_choice(gains)).items()
        if isinstance(value, (int, float)) and not isinstance(value, bool)
    }
    return {**pinned, **dict(over or {})}


def still_pinned(
    profile: RobotProfile,
    name: str,
    gains: str,
    rates: Mapping[str, Any],
    over: Mapping[str, Any] | None = None,
) -> bool:
    """Whether ``rates`` — pinned by :func:`pinned_rates` with ``gains`` when a run trained —
    are still what ``name`` runs today with those gains and a run's own rates ``over`` them
    (``False`` where the pair has no tuned gains any more, or where a pin written before
    pins were complete — a tuned file's rates alone — leaves a rate to a default)."""
    try:
        return dict(rates) == pinned_rates(profile, name, gains, over)
    except InvalidConfigError:
        return False


def check_rates(
    profile: RobotProfile, name: str, rates: object, what: str = "rates"
) -> dict[str, Any]:
    """``rates`` as a dict if it is a non-empty mapping of rates ``name`` knows on the robot
    of ``profile`` (the keys of :func:`effective_rates`), each of its default's kind — a
    number finite and ≥ 0 (every rate is a bandwidth, ratio, floor or gain), a flag a bool,
    a choice a string — and none contradicting a rate its law fixes (``FIXED``: the paper's
    passivity law), which would be recorded but never run.

    Raises:
        InvalidConfigError: naming ``what`` and every offending rate.
    """
    if not isinstance(rates, Mapping) or not rates:
        raise InvalidConfigError(f"{what}: a non-empty mapping of rates, got {rates!r}")
    known = effective_rates(profile, name)
    unknown = sorted(str(k) for k in rates if k not in known)
    if unknown:
        raise InvalidConfigError(f"{what}: unknown rate(s) {unknown}; known: {sorted(known)}")
    bad = {k: v for k, v in rates.items() if not _of_kind(v, known[k])}
    if bad:
        raise InvalidConfigError(
            f"{what}: {bad} not of their rates' kind (numbers finite and >= 0, flags bool, "
            "choices strings)"
        )
    fixed = getattr(entry(name).rates, "FIXED", {})
    clash = {k: v for k, v in rates.items() if k in fixed and v != fixed[k]}
    if clash:
        raise InvalidConfigError(
            f"{what}: {name} fixes { ({k: fixed[k] for k in clash}) }, got {clash}"
        )
    return dict(rates)


def _of_kind(value: object, default: object) -> bool:
    if isinstance(default, bool) or isinstance(value, bool):
        return isinstance(value, bool) and isinstance(default, bool)
    if isinstance(default, str):
        return isinstance(value, str)
    if not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value) and value >= 0
    except OverflowError:  # an int beyond any float
        return False


def effective_rates(
    profile: RobotProfile, name: str, gains: str | Mapping[str, Any] | None = "default"
) -> dict[str, Any]:
    """Every rate ``name`` uses on the robot of ``profile`` with ``gains`` ("default",
    "tuned" or a mapping of rates): its generic defaults, updated by the profile's, updated
    by the tuned or given ones, then by the rates its law fixes (a rate source's optional
    ``FIXED``: the paper's passivity law) — what :func:`make_controller` makes absolute.

    Raises:
        InvalidConfigError: an unknown controller or gain choice, or no tuned gains.
    """
    source = entry(name).rates
    rates = {**source.DEFAULT_RATES, **profile.controller_gains.get(source.NAME, {})}
    if isinstance(gains, str):
        if check_gain_choice(gains) == "tuned":
            rates.update(tuned_rates(profile.name, name))
    elif isinstance(gains, Mapping):
        rates.update(gains)
    rates.update(getattr(source, "FIXED", {}))
    return rates


def scaled_rates(
    profile: RobotProfile, name: str, gains: str | Mapping[str, Any], scale: float
) -> dict[str, Any]:
    """:func:`effective_rates` with the controller's bandwidths (``BANDWIDTHS``, rad/s) ×
    ``scale``: one knob from soft to stiff, the other rates (damping ratios, …) kept.

    Raises:
        InvalidConfigError: a scale that is not a finite number > 0, or as
            :func:`effective_rates`.
    """
    if not (isinstance(scale, (int, float)) and scale > 0 and scale < float("inf")):
        raise InvalidConfigError(f"a gain scale must be a positive number, got {scale!r}")
    rates = effective_rates(profile, name, gains)
    return {**rates, **{k: rates[k] * scale for k in entry(name).rates.BANDWIDTHS}}


def make_controller(name: str, env: Any, gains: Any = None, path: Any = None) -> Controller:
    """The controller ``name`` (one of :data:`CONTROLLER_NAMES`) for ``env`` (any wrapper
    of a ``TrackingEnv``) with ``gains``: None or ``"default"`` — the robot's default gains
    at the env's control rate; ``"tuned"`` — the rates found by the tuner
    (:func:`tuned_rates`); a mapping of rates; or the controller's gains dataclass. ``path``
    (a ``ReferencePath``) replaces the env's own path: one of a pool's (``path_seeds``).

    Raises:
        InvalidConfigError: (a ``ValueError``) an unknown name or gain choice.
    """
    build = entry(name).build
    if isinstance(gains, str):
        robot = env.unwrapped.robot_profile.name
        gains = None if check_gain_choice(gains) == "default" else tuned_rates(robot, name)
    ctx = ControlContext.from_env(env)
    if path is not None:
        ctx = dataclasses.replace(ctx, path=path)
    return build(ctx, gains)
