"""The field checks the study configs share (:mod:`train.studies.rates`,
:mod:`train.studies.verdict_study`): each raises :class:`InvalidConfigError` naming the
field, before any episode runs."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from agents.registry import CONTROLLER_NAMES
from ptrack_gym.disturbances import PRESETS
from ptrack_gym.errors import InvalidConfigError
from ptrack_gym.robots import ROBOTS


def check_lists(cfg: Any, names: Sequence[str]) -> None:
    """Each field of ``names`` is a non-empty list without duplicates."""
    for name in names:
        values = getattr(cfg, name)
        if not isinstance(values, list) or not values:
            raise InvalidConfigError(f"{name} must be a non-empty list, got {values!r}")
        if len(set(values)) != len(values):
            raise InvalidConfigError(f"{name} has duplicates: {values}")


def check_known(robots: Sequence[str], controllers: Sequence[str], presets: Sequence[str]) -> None:
    """Every robot, controller and disturbance preset named exists."""
    for robot in robots:
        if robot not in ROBOTS:
            raise InvalidConfigError(f"robots: unknown {robot!r}; known {sorted(ROBOTS)}")
    for c in controllers:
        if c not in CONTROLLER_NAMES:
            raise InvalidConfigError(f"controllers: unknown {c!r}; known {list(CONTROLLER_NAMES)}")
    for d in presets:
        if d not in PRESETS:
            raise InvalidConfigError(f"disturbances: unknown {d!r}; known {list(PRESETS)}")


def check_counts(cfg: Any, names: Sequence[str]) -> None:
    """Each field of ``names`` is an integer ≥ 1 (``workers``: ≥ 0, 0 meaning the cores)."""
    for name in names:
        value = getattr(cfg, name)
        low = 0 if name == "workers" else 1
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise InvalidConfigError(f"{name} must be an integer >= {low}, got {value!r}")


def check_path_seeds(env_id: str, seeds: Sequence[int], label: str) -> None:
    """Every seed of ``seeds`` gives ``env_id``'s robot an admissible random path — the one
    its env would build (:func:`ptrack_gym.paths.make_path` with the nominal model's metric),
    without a simulator; else :class:`InvalidConfigError` "``label`` <seed>: why"."""
    from ptrack_gym.errors import InvalidPathError
    from ptrack_gym.paths import make_path
    from ptrack_gym.robots import PinocchioModel, profile_for_env_id

    if not seeds:
        return
    profile = profile_for_env_id(env_id)
    metric = PinocchioModel(profile).mass_matrix
    for seed in seeds:
        try:
            make_path("random", profile, seed, metric)
        except InvalidPathError as exc:
            raise InvalidConfigError(f"{label.format(seed=seed)}: {exc}") from exc
