"""The configuration of an adversarial disturbance search (``ptrack adversary``):
:class:`AdversaryConfig` and its validation."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import ptrack_gym  # noqa: F401  (registers the envs)
from agents.registry import CONTROLLER_NAMES, GAIN_CHOICES, check_rates, tuned_rates
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
    rates: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Gain rates by controller, replacing those of ``gains`` (e.g. ``{passivity:
    {damping_ratio: 0.3}}``): a search of the same controller with other gains."""
    families: list[str] = field(default_factory=lambda: ["impulse"])
    """Disturbance families searched (:data:`FAMILIES`)."""
    energies_j: list[float] = field(default_factory=lambda: [2.0])
    """Energy budgets (J) of the family's ``energy_j``."""
    energy_mode: str = "delivered"
    """Impulse sizing: "delivered" (the impulse changes the moving arm's kinetic energy by
    ``energy_j`` at its onset: equal work for every controller, ``ImpulseTorque``) or
    "home" (the preset's: the energy it would give the arm at rest at home)."""
    budget: int = 200
    """Searched episodes per controller × family × energy × search seed; as many random
    ones besides."""
    popsize: int = 8
    """CMA-ES population of the first run (episodes evaluated in parallel per generation);
    each restart doubles it."""
    restarts: int = 1
    """CMA-ES restarts (IPOP's schedule, on a fixed budget): the searched budget is split
    over ``restarts`` + 1 runs, the r-th with population popsize·2^r, each warm-started from
    every episode of the seed so far."""
    polish_budget: int = 50
    """Episodes of a last, local CMA-ES run per search seed (0: none), beside ``budget``: it
    starts at the seed's worst episode so far with a small step (``polish_sigma``), where the
    global runs (large steps, doubling populations) jump past narrow peaks — a push's phase
    and direction, a periodic torque's resonance (BIPOP's small-population regime, once)."""
    polish_starts: int = 1
    """Local runs per search seed, each of ``polish_budget`` episodes: the first from the
    seed's worst episode so far, each further one from the worst random draw in a basin no
    earlier local run started in or reached
    (:meth:`train.studies.worst_case.Searchable.same_basin`: another direction, path phase or
    frequency) — a multistart local search: the global runs, warm-started from the seed's
    best episodes, all settle in the basin the random draws found first (seen: one Panda
    push seed of three, 22 % below the others)."""
    polish_sigma: float = 0.02
    """The local run's initial step, as a fraction of each searched range (CMA-ES works in
    the box scaled to [0, 1]; phases and angles are searched over two periods, so 0.02 is
    4 % of a period)."""
    scan_points: int = 0
    """A periodic torque's frequency scan (0: none; ``space`` "period" only): per search
    seed, before the CMA-ES runs, one episode per joint at each of ``scan_points``
    log-spaced frequencies, from one start phase, and ``scan_top`` episodes at the
    frequencies and directions they predict worst (:mod:`train.studies.periodic_scan`):
    scan_points·n + scan_top episodes beside ``budget``. Impulses and pushes have none."""
    scan_top: int = 3
    """Frequencies the scan verifies with a real episode at its predicted worst direction."""
    scan_phases: int = 0
    """A second stage of the scan: at the frequency the first predicts worst, the axis
    episodes from this many more start phases (evenly spaced around the path's period), and
    the worst of them verified — a resonance's strength depends on where on the path the
    cost window falls: scan_phases·n + 1 episodes more."""
    scan_refine: int = 0
    """Golden-section steps in log-frequency around each of the ``scan_top`` frequencies,
    between its grid neighbours, on the predicted cost, before it is verified (0: none): a
    lightly damped resonance is narrower than the grid's cells (the passivity law's spring
    modes, ``docs/worst_case.md#spring-modes``): scan_refine·n·scan_top episodes more."""
    scan_phase_refine: int = 0
    """Golden-section steps in log-frequency after each second stage, at its worst start
    phase, within two grid cells either side of its frequency (0: none): where on the path
    the cost window falls moves a resonance's peak (the Panda's: 7 Hz from one start phase,
    9.4 Hz from others): scan_phase_refine·n·scan_phase_top episodes more."""
    scan_phase_top: int = 1
    """How many of the scan's frequencies (the worst predicted first) get the second stage
    (``scan_phases``): seeds that rank two resonances differently then still search both."""
    reset_seed: int = 0
    """Env reset seed of every episode (the start on the path, where ``space`` is "box")."""
    search_seeds: list[int] = field(default_factory=lambda: [0, 1, 2])
    """Seeds of the samplers: one random and one searched study per seed; the spread of
    the worst case over them is reported."""
    space: str = "period"
    """The searched space. "period": the start phase s₀ and the onset's phase both span one
    whole period of the path and wrap around (the onset lies in [onset_s[0], onset_s[0] + S)),
    and a direction is a point of the unit sphere by angles that wrap; "box": the searches
    before issue 38 — the onset in the box ``onset_s``, the start phase of ``reset_seed``,
    directions in the cube [−1, 1]^d, CMA-ES seeded by the search seed and started without
    the random worst (with ``restarts`` 0 and ``energy_mode`` "home" it repeats those
    searches exactly)."""
    onset_s: tuple[float, float] = (0.5, 2.0)
    """"period": its low end is the earliest onset (s; the arm settles on the path before);
    "box": the range of the searched onset (s)."""
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
        if not isinstance(self.rates, dict) or any(c not in self.controllers for c in self.rates):
            raise InvalidConfigError(
                f"rates must map searched controllers {self.controllers} to gain rates "
                f"(name: value), got {self.rates!r}"
            )
        for c, r in self.rates.items():
            check_rates(profile_for_env_id(self.env_id), c, r, f"rates of {c}")
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
        if (
            isinstance(self.polish_budget, bool)
            or not isinstance(self.polish_budget, int)
            or not (self.polish_budget == 0 or self.polish_budget >= self.popsize)
        ):
            raise InvalidConfigError(
                f"polish_budget must be 0 or an integer >= popsize ({self.popsize}), got "
                f"{self.polish_budget!r}"
            )
        if (
            isinstance(self.polish_starts, bool)
            or not isinstance(self.polish_starts, int)
            or not 1 <= self.polish_starts <= self.budget
        ):
            raise InvalidConfigError(
                f"polish_starts must be an integer from 1 to budget ({self.budget}: each "
                f"further local run starts at a random draw of its own), got "
                f"{self.polish_starts!r}"
            )
        if not (isinstance(self.polish_sigma, (int, float)) and 0 < self.polish_sigma <= 0.5):
            raise InvalidConfigError(
                f"polish_sigma must lie in (0, 0.5], got {self.polish_sigma!r}"
            )
        for name in ("scan_points", "scan_top", "scan_phases", "scan_refine", "scan_phase_top",
                     "scan_phase_refine"):  # fmt: skip
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise InvalidConfigError(f"{name} must be an integer >= 0, got {value!r}")
        if self.scan_points and not (3 <= self.scan_points and 1 <= self.scan_top):
            raise InvalidConfigError(
                f"a frequency scan needs scan_points >= 3 and scan_top >= 1, got "
                f"{self.scan_points} and {self.scan_top}"
            )
        if self.scan_points and self.scan_top > self.scan_points:
            raise InvalidConfigError(
                f"scan_top ({self.scan_top}) must not exceed scan_points ({self.scan_points})"
            )
        if self.scan_points and not 1 <= self.scan_phase_top <= self.scan_top:
            raise InvalidConfigError(
                f"scan_phase_top must lie in [1, scan_top = {self.scan_top}], "
                f"got {self.scan_phase_top}"
            )
        if self.scan_points and self.space != "period":
            raise InvalidConfigError("a frequency scan (scan_points > 0) needs space 'period'")
        lo, hi = self.onset_s
        if not (0 <= lo <= hi) or not (0 < self.frequency_hz[0] <= self.frequency_hz[1]):
            raise InvalidConfigError("onset_s and frequency_hz must be (low, high) ranges")
        if self.space not in ("period", "box"):
            raise InvalidConfigError(f"space must be 'period' or 'box', got {self.space!r}")
        searched = []  # the ranges searched: an empty one leaves nothing to search
        if self.space == "box" and any(f != "periodic" for f in self.families):
            searched.append(("onset_s", self.onset_s))
        if "periodic" in self.families:
            searched.append(("frequency_hz", self.frequency_hz))
        for name, (low, high) in searched:
            if not high > low:
                raise InvalidConfigError(
                    f"{name} [{low:g}, {high:g}] is an empty search range: give low < high"
                )
        if (
            not self.search_seeds
            or len(set(self.search_seeds)) != len(self.search_seeds)
            or any(isinstance(k, bool) or not isinstance(k, int) for k in self.search_seeds)
        ):
            raise InvalidConfigError(
                f"search_seeds must be distinct integers, not empty, got {self.search_seeds}"
            )
        if (
            isinstance(self.restarts, bool)
            or not isinstance(self.restarts, int)
            or not (0 <= self.restarts and self.budget // (self.restarts + 1) >= self.popsize)
        ):
            raise InvalidConfigError(
                f"restarts must be an integer >= 0 leaving each CMA-ES run >= popsize "
                f"episodes (budget {self.budget} / (restarts + 1) >= {self.popsize}), got "
                f"{self.restarts!r}"
            )
        for name in ("post_s", "impulse_duration_s", "push_duration_s", "periodic_s"):
            if not getattr(self, name) > 0:
                raise InvalidConfigError(f"{name} must be positive")
        if self.energy_mode not in ("home", "delivered"):
            raise InvalidConfigError(
                f"energy_mode must be 'home' or 'delivered', got {self.energy_mode!r}"
            )
        profile_for_env_id(self.env_id)  # a known robot (its links: worst_case.check_targets)


def saved_config(saved: dict[str, Any]) -> AdversaryConfig:
    """The config of a search's ``config.yml``, that of a search before issue 38 included:
    it had one sampler ``seed`` and searched the box (``space`` "box"); one without
    ``polish_budget`` ran no local run."""
    # ``ran_at``: the rates each controller's episodes ran (a record, not a setting)
    saved = {k: v for k, v in saved.items() if k != arguments.RAN_AT_KEY}
    if "seed" in saved:
        saved["search_seeds"] = [int(saved.pop("seed"))]
    saved.setdefault("space", "box")
    saved.setdefault("restarts", 0)
    saved.setdefault("polish_budget", 0)  # a search before the local run
    saved.setdefault("scan_points", 0)  # a search before the frequency scan
    saved.setdefault("scan_phases", 0)  # a scan before its second stage
    return AdversaryConfig(**saved)


def load_config(path: Path | None, overrides: Sequence[str]) -> AdversaryConfig:
    """The config of a YAML file, with ``field=value`` overrides; unknown keys raise."""
    return arguments.load_config(AdversaryConfig, path, overrides, validate=False)
