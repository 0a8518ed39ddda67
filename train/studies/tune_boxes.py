"""The tuner's search boxes: which box a rate is searched in, whether an optimum sits on its
edge, and how a box is widened (``ptrack tune``, :mod:`train.studies.tune`).

A box is rate → (low, high, log): the controller's ``TUNABLE`` (:data:`agents.registry.TUNABLE`)
with a config's ``boxes`` overrides. A rate's position in its box is

.. math::

    u = \\frac{\\log x - \\log lo}{\\log hi - \\log lo} \\;\\text{(log scale)}, \\qquad
    u = \\frac{x - lo}{hi - lo} \\;\\text{(linear)},

and it lies *on a bound* when u < :data:`BOUND_MARGIN` (the low one) or u > 1 −
:data:`BOUND_MARGIN` (the high one): the search may have been stopped by the box, not by
the objective. Widening moves that bound by a factor :data:`WIDEN_FACTOR` (log scale: lo/3,
3·hi) or by the box's width (linear: lo − (hi − lo), hi + (hi − lo)), never to or below the
rate's floor (:data:`RATE_FLOORS`: every gain rate here is positive; a damping ratio ζ = 0
is no damping) — a low bound that would reach it goes halfway there instead.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from agents.registry import TUNABLE
from ptrack_gym.errors import InvalidConfigError

#: rate → (low, high, log scale).
Box = dict[str, tuple[float, float, bool]]

#: A rate within this fraction of its box (in log space for log-scaled rates) of a bound
#: lies on that bound.
BOUND_MARGIN = 0.05
#: Positions this close to the margin count as on it (logarithms round in the last bits).
POSITION_ROUNDING = 1e-12
#: A log-scaled bound is widened by this factor (÷ for the low one, × for the high one).
WIDEN_FACTOR = 3.0
#: The value each rate must stay strictly above (0: a bandwidth, a ratio, a gain is > 0);
#: rates not named have the floor 0 too.
RATE_FLOORS: Mapping[str, float] = {"zeta": 0.0, "kd_ratio": 0.0, "damping_ratio": 0.0}
#: A low bound this close (relative) to its floor cannot be widened any further.
FLOOR_TOLERANCE = 1e-6


def resolve_box(controller: str, overrides: Mapping[str, Sequence[Any]] | None = None) -> Box:
    """The box ``controller`` is searched in: its ``TUNABLE`` box, each rate that
    ``overrides`` names replaced by its [low, high, log] (checked by :func:`check_boxes`)."""
    box = {
        name: (float(lo), float(hi), bool(log))
        for name, (lo, hi, log) in TUNABLE[controller].items()
    }
    for name, spec in (overrides or {}).items():
        lo, hi, log = spec
        box[name] = (float(lo), float(hi), bool(log))
    return box


def check_boxes(boxes: Mapping[str, Any]) -> None:
    """Raise :class:`InvalidConfigError` unless ``boxes`` (a config's ``boxes``) maps
    tunable controllers to {tunable rate: [low, high, log]} with finite low < high, a bool
    log, and 0 < low for a log scale (and, any scale, low above the rate's floor)."""
    if not isinstance(boxes, Mapping):
        raise InvalidConfigError(
            f"boxes must map controllers to {{rate: [lo, hi, log]}}, got {boxes!r}"
        )
    for controller, rates in boxes.items():
        if controller not in TUNABLE:
            raise InvalidConfigError(
                f"boxes: {controller!r} is not a tunable controller; known: {sorted(TUNABLE)}"
            )
        if not isinstance(rates, Mapping):
            raise InvalidConfigError(f"boxes[{controller}] must map rates to [lo, hi, log]")
        for name, spec in rates.items():
            where = f"boxes[{controller}][{name}]"
            if name not in TUNABLE[controller]:
                raise InvalidConfigError(
                    f"{where}: {controller} tunes no rate {name!r}; it tunes "
                    f"{sorted(TUNABLE[controller])}"
                )
            ok = (
                isinstance(spec, Sequence)
                and not isinstance(spec, str)
                and len(spec) == 3
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in spec[:2])
                and isinstance(spec[2], bool)
            )
            if not ok:
                raise InvalidConfigError(
                    f"{where} must be [lo, hi, log] (two numbers, a bool), got {spec!r}"
                )
            lo, hi, log = float(spec[0]), float(spec[1]), spec[2]
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise InvalidConfigError(f"{where}: need finite lo < hi, got [{lo}, {hi}]")
            floor = RATE_FLOORS.get(name, 0.0)
            if lo <= floor:
                scale = "a log scale needs lo > 0" if log else f"{name} must stay > {floor}"
                raise InvalidConfigError(f"{where}: lo {lo} is not above the floor ({scale})")


def bound_position(value: float, low: float, high: float, log: bool) -> float:
    """u ∈ [0, 1]: where ``value`` lies in [low, high], in log space for a log scale
    (module docstring)."""
    if log:
        return (math.log(value) - math.log(low)) / (math.log(high) - math.log(low))
    return (value - low) / (high - low)


def bounds_hit(
    rates: Mapping[str, float],
    box: Mapping[str, tuple[float, float, bool]],
    margin: float = BOUND_MARGIN,
) -> dict[str, str]:
    """rate → "low" or "high" for every rate of ``rates`` in ``box`` that lies within
    ``margin`` of a bound (u < margin, u > 1 − margin; exactly at the margin, up to the
    rounding of the logarithms (:data:`POSITION_ROUNDING`), is inside)."""
    out = {}
    for name, value in rates.items():
        if name not in box:
            continue
        u = bound_position(value, *box[name])
        if u < margin - POSITION_ROUNDING:
            out[name] = "low"
        elif u > 1.0 - margin + POSITION_ROUNDING:
            out[name] = "high"
    return out


def widened_bound(name: str, low: float, high: float, log: bool, side: str) -> float | None:
    """The new ``side`` ("low" or "high") bound of rate ``name``'s box [low, high]: low/3
    or 3·high on a log scale, low − w or high + w (w = high − low) on a linear one; a low
    bound that would reach the rate's floor goes halfway to it; None where the low bound
    already sits at the floor (within :data:`FLOOR_TOLERANCE`)."""
    if side == "high":
        return high * WIDEN_FACTOR if log else high + (high - low)
    floor = RATE_FLOORS.get(name, 0.0)
    if low - floor <= FLOOR_TOLERANCE * max(abs(low), 1.0):
        return None
    new = low / WIDEN_FACTOR if log else low - (high - low)
    return new if new > floor else floor + 0.5 * (low - floor)


def box_text(box: Mapping[str, tuple[float, float, bool]]) -> dict[str, list[Any]]:
    """``box`` as YAML-friendly lists: rate → [low, high, log]."""
    return {name: [float(lo), float(hi), bool(log)] for name, (lo, hi, log) in box.items()}
