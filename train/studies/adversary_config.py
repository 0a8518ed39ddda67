"""The configuration of an adversarial disturbance search (``ptrack adversary``):
:class:`AdversaryConfig` and its validation."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import ptrack_gym  # noqa: F401  (registers the envs)
from agents.registry import CONTROLLER_NAMES, GAIN_CHOICES, tuned_rates
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots import profile_for_env_id
from train.common import arguments

#: The smallest budget: the warm-started CMA-ES starts from the best tenth of the random
#: draws (cmaes' ``get_warm_start_mgd``, γ = 0.1), which must hold one draw.
MIN_BUDGET = 10

#: The families the search can drive, with what it searches.
FAMILIES: tuple[str, ...] = ("impulse", "push", "periodic")


@dataclass
class AdversaryConfig:
    """An adversarial search (the fields of ``--config`` / ``--set``)."""

    env_id: str = "ptrack_gym/IiwaTrack-v0"
    """Registered env id."""
    controllers: list[str] = field(
        default_factory=lambda: ["passivity", "computed_torque", "pd_gravity", "slotine_li"]
    )
    """Controller names of ``agents.registry``."""
    gains: str = "default"
    """The controllers' gains: "default" or "tuned" (``agents/tuned``, ``train.studies.tune``)."""
    families: list[str] = field(default_factory=lambda: ["impulse"])
    """Disturbance families searched (:data:`FAMILIES`)."""
    energies_j: list[float] = field(default_factory=lambda: [2.0])
    """Energy budgets (J) of the family's ``energy_j``."""
    energy_mode: str = "home"
    """Impulse sizing: "home" (the preset's) or "delivered" (``ImpulseTorque``)."""
    budget: int = 200
    """Searched episodes per controller × family × energy; as many random ones besides."""
    popsize: int = 8
    """CMA-ES population (episodes evaluated in parallel per generation)."""
    reset_seed: int = 0
    """Env reset seed of every episode (the start on the path)."""
    seed: int = 0
    """Seed of the samplers."""
    onset_s: tuple[float, float] = (0.5, 2.0)
    """Range of the searched onset (s)."""
    post_s: float = 1.5
    """Length of the cost window after the disturbance (s)."""
    impulse_duration_s: float = 0.05
    """Duration of an impulse (s)."""
    push_duration_s: float = 0.1
    """Duration of a push (s)."""
    push_links: list[str] = field(default_factory=list)
    """Links a push may act on (empty: the end effector)."""
    frequency_hz: tuple[float, float] = (0.2, 5.0)
    """Range of the searched frequency of a periodic torque (Hz, log-uniform)."""
    periodic_s: float = 4.0
    """Length of a periodic-torque episode (s)."""
    control_hz: float = 1000.0
    """Control rate (Hz)."""
    failure_distance_rad: float = 0.5
    """Cost of an unstable episode (rad)."""
    workers: int = 0
    """Worker processes (0: the usable cores)."""
    out: str = "results/adversary"
    """Output folder."""

    def validate(self) -> None:
        """Raise :class:`InvalidConfigError` naming the first bad field, before any episode."""
        unknown = [c for c in self.controllers if c not in CONTROLLER_NAMES]
        if not self.controllers or unknown:
            raise InvalidConfigError(
                f"controllers must be names of {list(CONTROLLER_NAMES)}, got {self.controllers}"
            )
        if self.gains not in GAIN_CHOICES:
            raise InvalidConfigError(f"gains must be one of {GAIN_CHOICES}, got {self.gains!r}")
        if self.gains == "tuned":
            robot = profile_for_env_id(self.env_id).name
            for c in self.controllers:
                tuned_rates(robot, c)  # raises naming the missing file
        bad = [f for f in self.families if f not in FAMILIES]
        if not self.families or bad:
            raise InvalidConfigError(
                f"families must be some of {list(FAMILIES)}, got {self.families}"
            )
        if not self.energies_j or not all(
            isinstance(e, (int, float)) and math.isfinite(e) and e > 0 for e in self.energies_j
        ):
            raise InvalidConfigError(f"energies_j must be positive numbers, got {self.energies_j}")
        for name in ("controllers", "families", "energies_j"):
            values = getattr(self, name)
            if len(set(values)) != len(values):
                raise InvalidConfigError(f"{name} has duplicates: {values}")
        if self.budget < MIN_BUDGET or self.popsize < 2:
            raise InvalidConfigError(
                f"budget must be >= {MIN_BUDGET} (the search starts from the best tenth of as "
                f"many random draws: at least one) and popsize >= 2, got budget {self.budget}, "
                f"popsize {self.popsize}"
            )
        lo, hi = self.onset_s
        if not (0 <= lo <= hi) or not (0 < self.frequency_hz[0] <= self.frequency_hz[1]):
            raise InvalidConfigError("onset_s and frequency_hz must be (low, high) ranges")
        for name in ("post_s", "impulse_duration_s", "push_duration_s", "periodic_s"):
            if not getattr(self, name) > 0:
                raise InvalidConfigError(f"{name} must be positive")
        if self.energy_mode not in ("home", "delivered"):
            raise InvalidConfigError(
                f"energy_mode must be 'home' or 'delivered', got {self.energy_mode!r}"
            )
        profile_for_env_id(self.env_id)  # a known robot (its links: worst_case.check_targets)


def load_config(path: Path | None, overrides: Sequence[str]) -> AdversaryConfig:
    """The config of a YAML file, with ``field=value`` overrides; unknown keys raise."""
    return arguments.load_config(AdversaryConfig, path, overrides, validate=False)
