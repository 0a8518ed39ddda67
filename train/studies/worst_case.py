"""The episodes of an adversarial search (:mod:`train.studies.adversary`): the searchable
space of a disturbance family at an energy (:class:`Searchable`), one episode's cost
(:func:`evaluate`), and the replay of a found worst case (:func:`replay`; a spec replays
bit-identically)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import yaml

import ptrack_gym  # noqa: F401  (registers the envs)
from agents import passivity
from agents.policy import ControllerPolicy
from agents.registry import GAIN_CHOICES, make_controller, pinned_rates
from ptrack_gym.metrics import EpisodeRecord
from ptrack_gym.paths import ReferencePath
from ptrack_gym.robots import profile_for_env_id
from train.evaluation.episode import rollout
from train.studies.adversary_config import AdversaryConfig, saved_config

#: Raw ranges of the wrapping parameters: a phase (a fraction of the path period) in
#: [−0.5, 1.5] and a sphere angle in [−π, 3π], each mapped periodically — two periods
#: wide, so the seam of the period lies inside the box, not on its edge.
PHASE_RANGE = (-0.5, 1.5)
ANGLE_RANGE = (-math.pi, 3.0 * math.pi)


def sphere_point(angles: Sequence[float]) -> list[float]:
    """The point of the unit sphere S^{d−1} with hyperspherical angles φ₁…φ_{d−1}:
    x₁ = cos φ₁, x_k = sin φ₁ ⋯ sin φ_{k−1} cos φ_k, x_d = sin φ₁ ⋯ sin φ_{d−1}. Every
    coordinate is 2π-periodic in every angle, so the map wraps in each."""
    x, carry = [], 1.0
    for phi in angles:
        x.append(carry * math.cos(phi))
        carry *= math.sin(phi)
    return [*x, carry]


def is_wrapping(name: str) -> bool:
    """Whether a searched parameter wraps around (no bound to sit on): the phases and the
    sphere angles of the "period" space."""
    return name in ("start_phase", "onset_phase") or (name[:1] == "a" and name[1:].isdigit())


#: Two episodes of a search lie in one basin (:meth:`Searchable.same_basin`) when their
#: directions are within this angle (rad) of each other and their disturbances meet the
#: path within :data:`BASIN_PHASE` of a period (a pulse) or within a factor
#: :data:`BASIN_FREQUENCY` in frequency (a periodic torque), on the same link.
BASIN_ANGLE = math.pi / 4
BASIN_PHASE = 1.0 / 16.0
BASIN_FREQUENCY = 1.5


@dataclass(frozen=True)
class Searchable:
    """One family at one energy on one robot: its parameters, their spec, its cost window."""

    cfg: AdversaryConfig
    family: str
    energy_j: float

    @property
    def n(self) -> int:
        return profile_for_env_id(self.cfg.env_id).n

    @property
    def period_s(self) -> float:
        """The period S of the env's (default) path (s)."""
        return float(profile_for_env_id(self.cfg.env_id).path_period_s)

    @property
    def torque_limits_nm(self) -> tuple[float, ...]:
        """The robot's joint torque limits (N·m)."""
        return tuple(profile_for_env_id(self.cfg.env_id).torque_limits_nm)

    @property
    def links(self) -> list[str | None]:
        return list(self.cfg.push_links) or [None] if self.family == "push" else [None]

    @property
    def dims(self) -> int:
        """Dimension of the direction: 3 (a world direction) for a push, else n."""
        return 3 if self.family == "push" else self.n

    def space(self, trial: Any) -> dict[str, Any]:
        """Suggest this family's parameters on an Optuna trial."""
        c = self.cfg
        params: dict[str, Any] = {}
        period = c.space == "period"
        if period:
            phase = trial.suggest_float("start_phase", *PHASE_RANGE) % 1.0
            params["s0"] = phase * self.period_s
        if self.family == "periodic":
            params["frequency_hz"] = trial.suggest_float("frequency_hz", *c.frequency_hz, log=True)
        elif period:
            phase = trial.suggest_float("onset_phase", *PHASE_RANGE) % 1.0
            params["onset_s"] = c.onset_s[0] + phase * self.period_s
        else:
            params["onset_s"] = trial.suggest_float("onset_s", *c.onset_s)
        if period:
            angles = [trial.suggest_float(f"a{i}", *ANGLE_RANGE) for i in range(self.dims - 1)]
            params["direction"] = sphere_point(angles)
        else:
            params["direction"] = [
                trial.suggest_float(f"x{i}", -1.0, 1.0) for i in range(self.dims)
            ]
        if self.family == "push" and len(self.cfg.push_links) > 1:
            params["link"] = trial.suggest_categorical("link", list(self.cfg.push_links))
        elif self.family == "push" and self.cfg.push_links:
            params["link"] = self.cfg.push_links[0]
        return params

    def midpoint(self, link: str | None) -> dict[str, Any]:
        """A valid parameter set (for the checks before running)."""
        params: dict[str, Any] = {"onset_s": self.cfg.onset_s[0], "direction": [1.0] * self.dims}
        if self.family == "periodic":
            params = {"frequency_hz": self.cfg.frequency_hz[0], "direction": [1.0] * self.dims}
        if link is not None:
            params["link"] = link
        return params

    def spec(self, params: dict[str, Any]) -> dict[str, Any]:
        """The disturbance spec of a parameter set (replays bit-identically)."""
        c = self.cfg
        direction = [float(x) for x in params["direction"]]
        if not np.any(direction):
            direction[0] = 1.0  # a zero direction (measure zero) means the first axis
        if self.family == "impulse":
            return {
                "type": "impulse", "energy_j": self.energy_j, "duration_s": c.impulse_duration_s,
                "onset_s": float(params["onset_s"]), "direction": direction,
                "energy_mode": c.energy_mode,
            }  # fmt: skip
        if self.family == "push":
            spec = {
                "type": "push", "energy_j": self.energy_j, "duration_s": c.push_duration_s,
                "onset_s": float(params["onset_s"]), "direction": direction,
            }  # fmt: skip
            if c.energy_mode == "delivered":  # "home" specs stay as they were written
                spec["energy_mode"] = "delivered"
            if params.get("link") is not None:
                spec["link"] = params["link"]
            return spec
        return {
            "type": "periodic", "energy_j": self.energy_j,
            "frequency_hz": float(params["frequency_hz"]), "direction": direction,
        }  # fmt: skip

    def same_basin(
        self, a: dict[str, Any], a_s0: float | None, b: dict[str, Any], b_s0: float | None
    ) -> bool:
        """Whether two episodes (specs and start phases s0, s) push the arm the same way at
        the same point: directions within :data:`BASIN_ANGLE`, the same link, and a pulse's
        path phase at its onset, (s0 + onset) mod S, within :data:`BASIN_PHASE` of a period S
        of each other (wrapping), or periodic frequencies within a factor
        :data:`BASIN_FREQUENCY` (a periodic torque's direction up to its sign). A local
        search started in one basin stays in it, so a further local run starts in another
        (:func:`train.studies.adversary.local_start`)."""
        da, db = np.asarray(a["direction"], float), np.asarray(b["direction"], float)
        cos = float(da @ db / (np.linalg.norm(da) * np.linalg.norm(db)))
        if self.family == "periodic":  # −d is d half a period later: the same torque
            cos = abs(cos)
        if math.acos(min(1.0, max(-1.0, cos))) >= BASIN_ANGLE or a.get("link") != b.get("link"):
            return False
        if self.family == "periodic":
            ratio = a["frequency_hz"] / b["frequency_hz"]
            return 1.0 / BASIN_FREQUENCY < ratio < BASIN_FREQUENCY
        period = self.period_s
        gap = ((a_s0 or 0.0) + a["onset_s"] - (b_s0 or 0.0) - b["onset_s"]) % period / period
        return min(gap, 1.0 - gap) < BASIN_PHASE

    def window(self, spec: dict[str, Any]) -> tuple[float, float]:
        """The cost window (s) of a spec."""
        if self.family == "periodic":
            return self.cfg.periodic_s - self.cfg.post_s, self.cfg.periodic_s
        end = spec["onset_s"] + spec["duration_s"]
        return end, end + self.cfg.post_s

    def episode_s(self) -> float:
        """The episode's length (s): the latest onset, the pulse and the cost window."""
        if self.family == "periodic":
            return self.cfg.periodic_s
        duration = (
            self.cfg.impulse_duration_s if self.family == "impulse" else self.cfg.push_duration_s
        )
        last_onset = (
            self.cfg.onset_s[0] + self.period_s
            if self.cfg.space == "period"
            else self.cfg.onset_s[1]
        )
        return last_onset + duration + self.cfg.post_s


@dataclass(frozen=True)
class Outcome:
    """What one episode gave the search."""

    cost: float  # path-distance RMS over the window (rad); failure distance if unstable
    unstable: bool
    work_j: float  # ∫ q̇ᵀτ_d over the episode (J)
    peak_speed_rad_s: float  # max |q̇| over the episode
    peak_tau_frac: float  # max |τ| / τ_max of the applied (clipped) torque
    peak_joint: int = 0  # the joint (0-based) where |q̇| peaked


def episode(
    env_id: str,
    controller: str,
    spec: dict[str, Any] | None,
    reset_seed: int,
    episode_s: float,
    control_hz: float,
    gains: str | dict[str, Any] = "default",
    s0: float | None = None,
) -> tuple[EpisodeRecord, ReferencePath]:
    """One episode of ``controller`` (with ``gains``) under ``spec`` (None: undisturbed)
    from ``reset_seed``, started on the path at phase ``s0`` (s; None: the reset seed's);
    deterministic. Returns its record and the env's reference path."""
    steps = round(episode_s * control_hz)
    env = gym.make(
        env_id,
        disturbance=spec,
        control_hz=control_hz,
        horizon_s=episode_s,
        max_episode_steps=steps,
    )
    try:
        policy = ControllerPolicy(env, make_controller(controller, env, gains))
        options = None if s0 is None else {"s0": float(s0)}
        record, _ = rollout(env, policy, reset_seed, reset_options=options)
        path = env.unwrapped.path
    finally:
        env.close()
    return record, path


def outcome(
    record: EpisodeRecord, window: tuple[float, float], failure_distance_rad: float
) -> Outcome:
    """What an episode gives the search: its cost over ``window`` (s) and the rest."""
    t, dist = record.t_s, record.path_distance
    inside = (t > window[0]) & (t <= window[1] + 1e-9)
    if record.unstable:
        cost = failure_distance_rad
    else:
        cost = float(np.sqrt(np.mean(dist[inside] ** 2))) if np.any(inside) else float("nan")
    return Outcome(
        cost=cost,
        unstable=record.unstable,
        work_j=record.disturbance_work_j,
        peak_speed_rad_s=float(np.max(np.abs(record.qd))),
        peak_tau_frac=float(np.max(np.abs(record.tau_nm) / record.torque_limits_nm)),
        peak_joint=int(np.argmax(np.max(np.abs(record.qd), axis=0))),
    )


def evaluate(
    env_id: str,
    controller: str,
    spec: dict[str, Any],
    reset_seed: int,
    episode_s: float,
    window: tuple[float, float],
    control_hz: float,
    failure_distance_rad: float,
    gains: str | dict[str, Any] = "default",
    s0: float | None = None,
) -> Outcome:
    """One episode of ``controller`` (with ``gains``) under ``spec`` from ``reset_seed``,
    started on the path at phase ``s0`` (s; None: the reset seed's); deterministic."""
    record, _ = episode(env_id, controller, spec, reset_seed, episode_s, control_hz, gains, s0)
    return outcome(record, window, failure_distance_rad)


def evaluate_task(args: tuple[Any, ...]) -> Outcome:
    return evaluate(*args)


def controller_gains(cfg: AdversaryConfig, controller: str) -> str | dict[str, Any]:
    """The gains argument of ``controller``'s episodes: the rates of the config's gains
    themselves (:func:`agents.registry.pinned_rates`: the tuned file's, or every numeric rate
    of the default), recorded in ``worst.yml`` so that a replay does not depend on a later
    tuning or a new default, with the config's ``rates`` for it over them."""
    given = cfg.rates.get(controller)
    if cfg.gains in GAIN_CHOICES:
        return pinned_rates(profile_for_env_id(cfg.env_id), controller, cfg.gains, given)
    return {**given} if given else cfg.gains


def replay(
    worst_yml: Path,
    controller: str,
    family: str,
    energy_j: float,
    under: str | None = None,
    rates: Mapping[str, Any] | None = None,
) -> Outcome:
    """Re-run a worst case of ``worst.yml`` (bit-identical to the searched episode); with
    ``under``, the same disturbance spec, start phase and reset seed under another controller
    (at the search's gains setting: its default, or its own tuned gains). A ``delivered``
    budget is sized at the onset from that controller's own state, so its work may differ.
    ``rates`` (gain rates by name) replace those of the replayed controller's gains: the
    same case with other gains (e.g. ``{"damping_ratio": 0.5}`` for the passivity law).
    A passivity law replays with the direction guard the case records (a case found before
    the guard existed: without it, as it ran)."""
    data = yaml.safe_load(worst_yml.read_text())
    entry = data["worst"][controller][family][f"{energy_j:g}"]
    cfg = saved_config(yaml.safe_load((worst_yml.parent / "config.yml").read_text()))
    target = Searchable(cfg, family, energy_j)
    spec = entry["spec"]
    gains = entry.get("gains", cfg.gains)
    if under is not None and under != controller:
        gains = controller_gains(cfg, under)
        controller = under
    if rates:
        gains = {**(gains if isinstance(gains, Mapping) else {}), **rates}
    # the passivity law's direction guard as the case ran (0: found before the guard)
    default_guard = passivity.DIRECTION_GUARD
    passivity.DIRECTION_GUARD = float(entry.get("direction_guard", 0.0))
    try:
        return evaluate(
            cfg.env_id, controller, spec, cfg.reset_seed, target.episode_s(),
            target.window(spec), cfg.control_hz, cfg.failure_distance_rad, gains,
            entry.get("s0"),
        )  # fmt: skip
    finally:
        passivity.DIRECTION_GUARD = default_guard


def _line(outcome: Outcome) -> str:
    return (
        f"cost {outcome.cost:.6g} rad, unstable={outcome.unstable}, work {outcome.work_j:.3g} J, "
        f"peak |q̇| {outcome.peak_speed_rad_s:.3g} rad/s (joint {outcome.peak_joint + 1}), "
        f"peak |τ|/τ_max {outcome.peak_tau_frac:.2f}"
    )


def replay_all(
    worst_yml: Path, under: Sequence[str] = (), rates: Mapping[str, Any] | None = None
) -> list[str]:
    """Re-run every worst case of a search's ``worst.yml``: one line each, the replayed
    cost beside the searched one (a spec replays bit-identically: the two are equal), then,
    for each controller of ``under``, the same case under that controller (is the worst
    case the searched controller's, or the disturbance's?). With ``rates``, the searched
    controller's gains take them (:func:`replay`) and the lines say so."""
    data = yaml.safe_load(worst_yml.read_text())
    lines = []
    tag = "".join(f", {k}={v}" for k, v in (rates or {}).items())
    for controller, families in data["worst"].items():
        for family, energies in families.items():
            for energy, entry in energies.items():
                outcome = replay(worst_yml, controller, family, float(energy), rates=rates)
                lines.append(
                    f"{controller}{tag} {family} {energy} J: {_line(outcome)} "
                    f"(searched cost {entry['cost_rad']:.6g})"
                )
                for other in under:
                    outcome = replay(worst_yml, controller, family, float(energy), other)
                    lines.append(f"  the same case under {other}: {_line(outcome)}")
    return lines


def check_targets(cfg: AdversaryConfig) -> None:
    """Every family and link of ``cfg`` exists on its robot: one env per family and link
    checks the spec at the middle of the searched space (before any episode).

    Raises:
        InvalidConfigError: a family or push link the robot's env refuses, or gain
            ``rates`` its controller does not know.
    """
    env = gym.make(cfg.env_id, control_hz=cfg.control_hz)
    for controller in cfg.rates:  # unknown rate names and bad values, before any episode
        make_controller(controller, env, controller_gains(cfg, controller))
    env.close()
    for family in cfg.families:
        probe = Searchable(cfg, family, cfg.energies_j[0])
        for link in probe.links:
            spec = probe.spec(probe.midpoint(link))
            gym.make(cfg.env_id, disturbance=spec, control_hz=cfg.control_hz).close()
