"""Disturbance presets × levels, and :func:`build_disturbances`, which turns a user's spec
into disturbance objects.

A spec is a preset name (``"impulse"``), a ``(preset, level)`` pair, a
``(preset, {"energy_j": E})`` pair, a spec dict (``{"type": "impulse", "fraction": 0.3}``),
a :class:`~ptrack_gym.disturbances.base.Disturbance` or a list of those. Level 0 is no
disturbance, 1 nominal, higher harder; what level 1 means per robot is its profile's
:class:`~ptrack_gym.robots.profile.DisturbanceScales`. A preset's options may also be a
mapping: ``(preset, {"level": L, "sizing": "onset"})`` or ``(preset, {"energy_j": E,
"sizing": "onset"})`` (``level`` defaults to 1; ``level`` and ``energy_j`` exclude each
other).

``sizing`` (:data:`~ptrack_gym.disturbances.base.SIZINGS`, see
:mod:`~ptrack_gym.disturbances.torques`) selects, for a whole preset, whether its joint
torques are sized by M(q_home) or by M(q) where they start to act: the impulse, periodic
and noise torques (and a step) take it; the payload, push, mismatch (its damping and
friction are joint properties), action and observation noise have no such option and
are built the same either way.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

from ptrack_gym.disturbances.base import DISTURBANCES, Disturbance, check_sizing
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots.profile import DisturbanceScales, RobotProfile

PRESETS: tuple[str, ...] = (
    "none",
    "impulse",
    "push",
    "periodic",
    "noise",
    "payload",
    "mismatch",
    "mixed",
    "delay",
    "friction",
)
#: Presets that accept an energy budget, ``(preset, {"energy_j": E})``.
ENERGY_PRESETS: tuple[str, ...] = ("impulse", "push", "periodic")

DisturbanceSpec = str | tuple[str, Any] | Mapping[str, Any] | Disturbance


def preset_specs(name: str, level: float, profile: RobotProfile) -> list[dict[str, Any]]:
    """The specs of preset ``name`` at ``level`` (0 none, 1 nominal) for a robot.

    Torque magnitudes are inertia-scaled (``accel_rad_s2``) or energy-based, so a level
    means a comparable push on every joint of every robot: at level 1, an impulse gives the
    arm at rest at home the robot's ``impulse_j`` of kinetic energy in 50 ms; a periodic
    torque accelerates each joint by up to 2 rad/s²; the noise preset adds sensor noise
    (1 mrad, 10 mrad/s), actuation noise (1 rad/s² per joint inertia) and a 5 Hz
    band-limited torque (1 rad/s²); a payload of ``payload_kg`` is picked up between 1 and
    4 s; the mismatch preset scales link masses by ±20%, with damping 0.5/s and friction
    0.5 rad/s²; the friction preset is that damping and friction alone at twice the size
    (1/s and 1 rad/s² per unit of joint inertia, nominal masses); the delay preset reports
    the state sampled 2 ms × level earlier (at least ⌈delay / Δt⌉ control steps). The
    onsets (1-4 s) are the same at every level, so are the shortest episodes these accept
    (:func:`~ptrack_gym.disturbances.base.min_horizon_s`: the latest onset + duration +
    0.5 s of recovery): impulse and mixed 4.55 s, push 4.6 s, payload 4.5 s; the others
    any length.
    """
    return _specs(name, level, profile.disturbance_scales)


def _specs(name: str, level: float, sc: DisturbanceScales) -> list[dict[str, Any]]:
    """:func:`preset_specs` from the robot's level-1 scales."""
    specs: dict[str, list[dict[str, Any]]] = {
        "none": [],
        "impulse": [{"type": "impulse", "energy_j": sc.impulse_j * level, "duration_s": 0.05}],
        "push": [{"type": "push", "force_n": sc.push_n * level, "duration_s": 0.1}],
        "periodic": [{"type": "periodic", "accel_rad_s2": 2.0 * level}],
        "noise": [
            {"type": "observation_noise", "q_std_rad": 1e-3 * level, "qd_std_rad_s": 1e-2 * level},
            {"type": "action_noise", "accel_rad_s2": 1.0 * level},
            {"type": "noise_torque", "accel_rad_s2": 1.0 * level, "bandwidth_hz": 5.0},
        ],
        "payload": [{"type": "payload", "mass_kg": sc.payload_kg * level, "pick_s": (1.0, 4.0)}],
        "delay": [{"type": "observation_delay", "delay_s": 2e-3 * level}],
        "mismatch": [
            {
                "type": "mismatch",
                "mass_scale": (1.0 - 0.2 * level, 1.0 + 0.2 * level),
                "damping_per_s": 0.5 * level,
                "friction_rad_s2": 0.5 * level,
                "links": sc.mismatch_links,
            }
        ],
        # the joints' damping and friction alone, nominal masses: the dynamics a policy
        # trained under randomised masses has never met (issue 39's held-out dynamics)
        "friction": [
            {
                "type": "mismatch",
                "mass_scale": 1.0,
                "damping_per_s": 1.0 * level,
                "friction_rad_s2": 1.0 * level,
                "links": (),
            }
        ],
    }
    if name == "mixed":
        return [
            *_specs("impulse", 0.5 * level, sc),
            *_specs("periodic", 0.5 * level, sc),
            *_specs("noise", 0.5 * level, sc),
            *_specs("payload", 0.5 * level, sc),
        ]
    if name not in specs:
        raise InvalidConfigError(f"unknown disturbance preset {name!r}; known: {sorted(PRESETS)}")
    return specs[name] if level > 0 else []


def preset_does_work(name: str) -> bool:
    """Whether preset ``name`` (at a level > 0) acts through a joint torque, a force or an
    actuation error — what the work ledger ``info["disturbance_work_j"]`` counts — so that
    an episode it acted in has done work on the arm (≠ 0 J); False for a preset that only
    changes the plant's masses or the sensors (``payload``: its ledger reads 0 J even when it
    acts). An unknown name counts as doing work. The families of a preset are the same for
    every robot."""
    if name not in PRESETS:
        return True
    hooks = ("joint_torque", "wrench", "actuate")
    return any(
        getattr(DISTURBANCES[spec["type"]], hook) is not getattr(Disturbance, hook)
        for spec in _specs(name, 1.0, DisturbanceScales(1.0, 1.0, 1.0, ()))
        for hook in hooks
    )


def from_spec(spec: Mapping[str, Any]) -> Disturbance:
    """A disturbance from a spec dict ``{"type": family, field: value, ...}``; unknown
    families or fields raise :class:`InvalidConfigError` naming the known ones."""
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


def _level(name: str, arg: Any) -> float:
    if isinstance(arg, bool) or not isinstance(arg, (int, float)):
        raise InvalidConfigError(f"preset {name!r}: level must be a number >= 0, got {arg!r}")
    level = float(arg)
    if not (math.isfinite(level) and level >= 0):
        raise InvalidConfigError(f"preset {name!r}: level must be >= 0, got {arg!r}")
    return level


def _sized(spec: Mapping[str, Any], sizing: str) -> dict[str, Any]:
    """``spec`` with ``sizing`` added if its family has that field and it sets none."""
    kind = spec.get("type")
    cls = DISTURBANCES.get(kind) if isinstance(kind, str) else None
    has_sizing = cls is not None and any(f.name == "sizing" for f in dataclasses.fields(cls))
    return {**spec, "sizing": sizing} if has_sizing and "sizing" not in spec else dict(spec)


def _preset_with_options(
    name: str, options: Mapping[str, Any], sizing: str, profile: RobotProfile
) -> list[dict[str, Any]]:
    """The specs of ``(preset, {"level": L | "energy_j": E, "sizing": S})``."""
    keys = set(options)
    if not keys <= {"level", "energy_j", "sizing"} or {"level", "energy_j"} <= keys:
        raise InvalidConfigError(
            f"preset {name!r}: the options are 'level' or 'energy_j' (not both) and "
            f"'sizing', got {sorted(options)}"
        )
    sizing = check_sizing(options.get("sizing", sizing), f"preset {name!r}: sizing")
    if "energy_j" not in options:
        level = _level(name, options.get("level", 1.0))
        return [_sized(s, sizing) for s in preset_specs(name, level, profile)]
    if name not in ENERGY_PRESETS:
        raise InvalidConfigError(
            f"preset {name!r} takes no energy budget; those that do: {ENERGY_PRESETS}"
        )
    return [
        _sized(
            {
                **{k: v for k, v in s.items() if k not in ("fraction", "accel_rad_s2")},
                "energy_j": options["energy_j"],
            },
            sizing,
        )
        for s in preset_specs(name, 1.0, profile)
    ]


def build_disturbances(
    spec: DisturbanceSpec | Sequence[DisturbanceSpec] | None,
    profile: RobotProfile,
    sizing: str = "home",
) -> list[Disturbance]:
    """Turn a user spec into disturbance objects (see the module docstring for the forms).

    ``sizing`` (``"home"`` or ``"onset"``) is given to every family built here that has a
    ``sizing`` field and whose spec sets none (a preset's option or a spec dict's own
    ``sizing`` wins); a :class:`Disturbance` object is used as it is. An unknown value
    raises :class:`InvalidConfigError` listing the choices.
    """
    check_sizing(sizing)
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
            continue
        specs: list[dict[str, Any]]
        if isinstance(item, str):
            specs = [_sized(s, sizing) for s in preset_specs(item, 1.0, profile)]
        elif isinstance(item, tuple) and len(item) == 2 and isinstance(item[0], str):
            name, arg = item
            if isinstance(arg, Mapping):
                specs = _preset_with_options(name, arg, sizing, profile)
            else:
                specs = [_sized(s, sizing) for s in preset_specs(name, _level(name, arg), profile)]
        elif isinstance(item, Mapping):
            specs = [_sized(item, sizing)]
        else:
            raise InvalidConfigError(f"cannot build a disturbance from {item!r}")
        out.extend(from_spec(s) for s in specs)
    return out
