"""The studies of a tuning fight (:mod:`train.studies.tune`): the objective a trial is
scored by (:class:`TrialObjective`; the validation episodes, :class:`EpisodeObjective`), a
seed's rounds of Optuna studies with their widenings (:class:`SeedStudies`) and the winner
over the seeds (:func:`winner`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any, NamedTuple, Protocol

import numpy as np

from agents.registry import entry
from ptrack_gym.errors import InvalidConfigError
from train.evaluation.episode import EpisodeSettings, Task, run_episode
from train.studies.tune_boxes import Box, bounds_hit, box_text, widened_bound
from train.studies.tune_config import TuneConfig
from train.studies.tune_fight import spread


class TrialScore(NamedTuple):
    """A trial's score: objective J (rad), mean effort E, failed episodes."""

    error_rad: float
    effort: float
    failures: int


class TrialObjective(Protocol):
    """What a study asks of its objective (the episodes, or a test's cheap function)."""

    def score(self, controller: str, rates: Mapping[str, float] | None) -> TrialScore:
        """The score of ``controller`` with gain ``rates`` (None: its default gains)."""
        ...

    def response(self, controller: str, rates: Mapping[str, float]) -> np.ndarray:
        """What ``controller`` does with ``rates`` (e.g. its torques at a probe state): two
        rate sets with equal responses are the same controller (a cap binds)."""
        ...


def score_rows(rows: Sequence[Mapping[str, Any]], effort_metric: str) -> TrialScore:
    """J = geometric mean of the episodes' ``path_dist_rms`` (floored at 10⁻¹² rad), E = the
    mean of their ``effort_metric`` (an episode without one — no step taken — makes E
    infinite: never feasible), and the failures."""
    error = float(np.exp(np.mean(np.log([max(r["path_dist_rms"], 1e-12) for r in rows]))))
    efforts = np.array([r[effort_metric] for r in rows], dtype=float)
    effort = float(np.mean(efforts)) if np.isfinite(efforts).all() else math.inf
    return TrialScore(error, effort, int(sum(r["failed"] for r in rows)))


def _run(args: tuple[Task, EpisodeSettings]) -> dict[str, Any]:
    return run_episode(*args)[0]


class EpisodeObjective:
    """The validation episodes of ``cfg`` run in ``pool`` (:class:`TrialObjective`)."""

    def __init__(self, cfg: TuneConfig, pool: ProcessPoolExecutor) -> None:
        self.cfg, self.pool = cfg, pool
        self._env: Any = None

    def score(self, controller: str, rates: Mapping[str, float] | None) -> TrialScore:
        gains = "default" if rates is None else tuple(sorted(rates.items()))
        rows = list(self.pool.map(_run, self.cfg.episodes(controller, gains)))
        return score_rows(rows, self.cfg.effort_metric)

    def response(self, controller: str, rates: Mapping[str, float]) -> np.ndarray:
        """τ (N·m) of three steps from q = q_r(s₀) + 0.05, q̇ = 0.9 q_r'(s₀), s₀ = S/4, at
        the config's control rate, (3, n)."""
        import gymnasium as gym

        from agents.base import ControlContext

        if self._env is None:
            self._env = gym.make(self.cfg.env_id, control_hz=self.cfg.control_hz)
        ctx = ControlContext.from_env(self._env)
        law = entry(controller).build(ctx, dict(rates))
        s0 = 0.25 * ctx.path.period_s
        q_r, qd_r, _ = ctx.path.evaluate(s0)
        q, qd = q_r + 0.05, 0.9 * qd_r
        law.reset(q, qd, s0)
        return np.array([law.step(q, qd, ctx.dt_s) for _ in range(3)])

    def close(self) -> None:
        if self._env is not None:
            self._env.close()


def study_name(controller: str, seed: int, round_: int = 0) -> str:
    """The journal's name of a study: ``<controller>.seed<k>``, ``….widen<r>`` after r ≥ 1
    widenings."""
    return f"{controller}.seed{seed}" + (f".widen{round_}" if round_ else "")


class SeedStudies:
    """The studies of one tuning run: a seed's rounds, each an Optuna study."""

    def __init__(
        self,
        optuna: Any,
        storage: Any,
        objective: TrialObjective,
        cfg: TuneConfig,
        budget: float,
        progress: bool,
    ) -> None:
        self.optuna, self.storage, self.objective = optuna, storage, objective
        self.cfg, self.budget, self.progress = cfg, budget, progress

    def seed_result(self, controller: str, seed: int) -> dict[str, Any] | None:
        """The best feasible trial of ``controller``'s study seed ``seed`` over its rounds
        (each widening one), with the rates on a bound of the last box and why they stay
        there. A seed none of whose trials meets the budget gives its least-over-budget
        trial (lowest effort, then lowest J — the order Optuna's constrained samplers rank
        infeasible trials by), marked ``over_budget``, and is not widened: widening follows
        an optimum of J within the budget, which such a seed has not found; None if no
        trial completed."""
        cfg, box = self.cfg, self._start_box(controller, seed)
        last = cfg.max_widenings if cfg.widen_on_bound else 0
        if self.progress:
            print(f"{study_name(controller, seed)}: {cfg.study_trials(controller)} trials a "
                  f"study (max({cfg.trials}, {cfg.trials_per_rate} x {len(box)} rates))",
                  flush=True)  # fmt: skip
        stuck: dict[str, str] = {}  # rate → why its bound was not widened
        study, best, round_ = None, None, 0
        for round_ in range(last + 1):
            study = self._round(controller, seed, round_, box, study)
            best = self._best(_complete(self.optuna, study))
            if best is None or not self._feasible(best) or round_ == last:
                break
            widen = self._widen(controller, best.params, box, stuck)
            if not widen:
                break
            box = {**box, **widen}
        new = _new_trials(self.optuna, self.storage, controller, seed, round_)
        if best is None:
            return None
        hits = bounds_hit(best.params, box)
        over = not self._feasible(best)
        why = {name: f"{side}, " + ("not widened: no trial within the effort budget" if over
                                   else self._why(controller, best.params, box, name, side,
                                                  stuck, round_))
               for name, side in sorted(hits.items())}  # fmt: skip
        return {
            "error_rad": float(best.value),
            "effort": float(best.user_attrs["effort"]),
            "failures": int(best.user_attrs["failures"]),
            "over_budget": over,
            "rates": {k: float(v) for k, v in best.params.items()},
            "trial": best.user_attrs.get("copied_from", f"{study.study_name}#{best.number}"),
            "trials": len(new),
            "feasible_trials": sum(self._feasible(t) for t in new),
            "widenings": round_,
            "box": box_text(box),
            "on_bound": sorted(hits),
            "on_bound_why": why,
            "wall_s": round(
                sum((t.datetime_complete - t.datetime_start).total_seconds() for t in new), 1
            ),
        }

    def _stored_box(self, name: str) -> Box | None:
        """The box the journal's study ``name`` searched (None: no such study)."""
        if name not in self.optuna.study.get_all_study_names(self.storage):
            return None
        stored = self.optuna.load_study(study_name=name, storage=self.storage).user_attrs
        box = stored.get("box")
        return None if box is None else {k: (float(lo), float(hi), bool(log))
                                         for k, (lo, hi, log) in box.items()}  # fmt: skip

    def _start_box(self, controller: str, seed: int) -> Box:
        """The box round 0 of ``seed`` searches: with ``carry_boxes``, the box the previous
        study seed ended in (the last of its rounds 0 … ``max_widenings`` this config
        runs: its widenings kept, so a bound found too tight is not found again by every
        seed), or, resumed, the box it started in — which must hold the config's box (a
        carried box only ever grows; a later ``max_widenings`` may have widened the seed
        before it since); else, and for the first seed, the config's box, which a resumed
        study must have searched (:meth:`_round`).

        Raises:
            InvalidConfigError: a resumed carried study whose box does not hold the config's.
        """
        cfg = self.cfg
        first = cfg.box(controller)
        seeds = list(cfg.study_seeds)
        if not cfg.carry_boxes:
            return first
        stored = self._stored_box(study_name(controller, seed, 0))
        if stored is not None and seeds.index(seed) == 0:
            if stored != first:  # the first seed searches the config's box, or nothing
                raise InvalidConfigError(
                    f"study {study_name(controller, seed, 0)} searched {box_text(stored)}, "
                    f"this run's first seed searches {box_text(first)} (its box changed, or "
                    "the seeds before it were dropped): tune into another --out"
                )
            return stored
        if stored is not None:
            if set(stored) != set(first) or any(
                stored[k][0] > lo or stored[k][1] < hi or stored[k][2] != log
                for k, (lo, hi, log) in first.items()
            ):
                raise InvalidConfigError(
                    f"study {study_name(controller, seed, 0)} searched {box_text(stored)}, "
                    f"which does not hold this run's box {box_text(first)}: tune into "
                    "another --out"
                )
            return stored
        if seeds.index(seed) == 0:
            return first
        previous, box = seeds[seeds.index(seed) - 1], None
        for r in range((cfg.max_widenings if cfg.widen_on_bound else 0) + 1):
            found = self._stored_box(study_name(controller, previous, r))
            if found is None:
                break
            box = found
        return box or first

    def spent_trials(self, controller: str, seed: int) -> int:
        """The new trials ``seed`` ran over every round it has in the journal (feasible or
        not)."""
        rounds = 0
        while self._stored_box(study_name(controller, seed, rounds + 1)) is not None:
            rounds += 1
        if self._stored_box(study_name(controller, seed, 0)) is None:
            return 0
        return len(_new_trials(self.optuna, self.storage, controller, seed, rounds))

    def _feasible(self, trial: Any) -> bool:
        return bool(trial.user_attrs["effort"] <= self.budget)

    def _best(self, trials: Sequence[Any]) -> Any:
        """The first of ``trials`` in :func:`budget_order`; None for no trials."""
        return min(
            trials,
            key=lambda t: budget_order(self._feasible(t), t.value, t.user_attrs["effort"]),
            default=None,
        )

    def _widen(
        self, controller: str, rates: Mapping[str, float], box: Box, stuck: dict[str, str]
    ) -> Box:
        """The rates of ``box`` to widen for a winner at ``rates``: each on a bound, unless
        moving it to the widened bound changes nothing (``stuck``: "capped") or it sits at
        its floor ("at the floor")."""
        widen: Box = {}
        for name, side in bounds_hit(rates, box).items():
            if name in stuck:
                continue
            lo, hi, log = box[name]
            new = widened_bound(name, lo, hi, log, side)
            if new is None:
                stuck[name] = "at the floor"
                continue
            moved = {**rates, name: new}
            if np.array_equal(
                self.objective.response(controller, rates),
                self.objective.response(controller, moved),
            ):
                stuck[name] = "capped"
                continue
            widen[name] = (new, hi, log) if side == "low" else (lo, new, log)
        return widen

    def _why(
        self,
        controller: str,
        rates: Mapping[str, float],
        box: Box,
        name: str,
        side: str,
        stuck: dict[str, str],
        rounds: int,
    ) -> str:
        """Why the winning rate ``name`` stays on its ``side`` bound."""
        cfg = self.cfg
        if name not in stuck:
            lo, hi, log = box[name]
            new = widened_bound(name, lo, hi, log, side)
            if new is None:
                stuck[name] = "at the floor"
            elif np.array_equal(
                self.objective.response(controller, rates),
                self.objective.response(controller, {**rates, name: new}),
            ):
                stuck[name] = "capped"
        if stuck.get(name) == "capped":
            return (f"capped: gains_from_rates' per-sample cap at {cfg.control_hz:g} Hz, "
                    "a value past it changes nothing")  # fmt: skip
        if stuck.get(name) == "at the floor":
            return "at the floor: cannot be widened"
        if not cfg.widen_on_bound:
            return "not widened (widen_on_bound off)"
        return f"still after {rounds} widening(s) (max_widenings {cfg.max_widenings})"

    def _round(self, controller: str, seed: int, round_: int, box: Box, previous: Any) -> Any:
        """Run (or continue) round ``round_`` of a seed's study in ``box``: N_c new trials,
        after the trials of ``previous`` (the last round) copied in as history."""
        optuna, cfg = self.optuna, self.cfg
        name = study_name(controller, seed, round_)
        study = optuna.create_study(
            study_name=name, storage=self.storage, direction="minimize", load_if_exists=True,
            sampler=optuna.samplers.TPESampler(seed=seed, n_startup_trials=cfg.startup_trials),
        )  # fmt: skip
        stored = study.user_attrs.get("box")
        if stored is None:
            study.set_user_attr("box", box_text(box))
        elif stored != box_text(box):
            raise InvalidConfigError(
                f"study {name} searched {stored}, this run would search {box_text(box)} (its "
                "earlier rounds changed): tune into another --out"
            )
        running = study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.RUNNING,))
        for stale in running:  # an interrupted trial
            study.tell(stale.number, state=optuna.trial.TrialState.FAIL)
        distributions = {
            k: optuna.distributions.FloatDistribution(lo, hi, log=log)
            for k, (lo, hi, log) in box.items()
        }
        if previous is not None:
            have = {t.user_attrs.get("copied_from") for t in study.get_trials(deepcopy=False)}
            for t in _complete(optuna, previous):
                source = t.user_attrs.get("copied_from", f"{previous.study_name}#{t.number}")
                if source not in have:
                    study.add_trial(optuna.trial.create_trial(
                        params=t.params, distributions=distributions, value=t.value,
                        user_attrs={**t.user_attrs, "copied_from": source},
                        constraints=dict(t.constraints),
                    ))  # fmt: skip
        n = cfg.study_trials(controller)
        done = sum("copied_from" not in t.user_attrs for t in _complete(optuna, study))
        while done < n:
            # TPE rebuilds its model from the history at every ask: a sampler seeded by
            # (seed, round, trial index) makes a resumed study ask exactly what an
            # uninterrupted one does (one seeded once would repeat its first random draws)
            study.sampler = optuna.samplers.TPESampler(
                seed=int(np.random.SeedSequence([seed, round_, done]).generate_state(1)[0]),
                n_startup_trials=cfg.startup_trials,
            )
            trial = study.ask()
            rates = {k: trial.suggest_float(k, lo, hi, log=log) for k, (lo, hi, log) in box.items()}
            score = self.objective.score(controller, rates)
            trial.set_user_attr("effort", score.effort)
            trial.set_user_attr("failures", score.failures)
            trial.set_constraint("effort", score.effort - self.budget)  # feasible when <= 0
            study.tell(trial, score.error_rad)
            done += 1
            if self.progress:
                feasible = "feasible" if score.effort <= self.budget else "over budget"
                print(
                    f"{name} trial {done}/{n}: error {score.error_rad:.3e} rad, effort "
                    f"{score.effort:.4f} ({feasible}), failures {score.failures}, "
                    + ", ".join(f"{k}={v:.3g}" for k, v in rates.items()),
                    flush=True,
                )
        return study


def _complete(optuna: Any, study: Any) -> list[Any]:
    return study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))


def _new_trials(optuna: Any, storage: Any, controller: str, seed: int, rounds: int) -> list[Any]:
    """The trials a seed ran itself (no copies) over its rounds 0..``rounds``."""
    out = []
    for r in range(rounds + 1):
        study = optuna.load_study(study_name=study_name(controller, seed, r), storage=storage)
        out += [t for t in _complete(optuna, study) if "copied_from" not in t.user_attrs]
    return out


def budget_order(feasible: bool, error_rad: float, effort: float) -> tuple[float, ...]:
    """The sort key of the tuner's one rule for a trial or a seed's result: every one within
    the effort budget first, by J (rad); then the rest, least effort first, then J — the
    order Optuna's constrained samplers give infeasible trials."""
    return (0.0, error_rad) if feasible else (1.0, effort, error_rad)


def winner(
    cfg: TuneConfig,
    controller: str,
    seeds: Mapping[int, dict[str, Any] | None],
    budget: float,
    spent: int | None = None,
) -> dict[str, Any]:
    """The result of ``controller``: the best of its seeds' winners (lowest J among those
    within the budget; if none is, the least over it, ``over_budget``), the seeds' spread,
    every seed's best, and the totals — ``spent``, the new trials of every seed (those
    without a feasible one too; None: the found seeds' counts), makes ``trials`` and
    ``env_steps`` what the fight spent."""
    found = {s: r for s, r in seeds.items() if r is not None}
    if not found:
        raise InvalidConfigError(f"{controller}: no trial completed in any study seed")
    seed = min(found, key=lambda s: (*budget_order(
        not found[s].get("over_budget", False), found[s]["error_rad"], found[s]["effort"]
    ), s))  # fmt: skip
    trials = spent if spent is not None else sum(r["trials"] for r in found.values())
    w = found[seed]
    return {
        "controller": controller,
        "rates": dict(w["rates"]),
        "error_rad": w["error_rad"],
        "effort": w["effort"],
        "failures": w["failures"],
        "over_budget": bool(w.get("over_budget", False)),
        "seed": int(seed),
        "trial": w["trial"],
        "trials_per_study": cfg.study_trials(controller),
        "trials": trials,
        # what the fight spent on this controller, in the units of an RL budget: every new
        # trial of every seed ran the validation episodes (the copies into a widening ran
        # nothing new)
        "env_steps": trials * cfg.trial_env_steps(controller),
        "feasible_trials": sum(r["feasible_trials"] for r in found.values()),
        "effort_metric": cfg.effort_metric,
        "effort_budget": float(budget),
        "spread": spread([r["error_rad"] for r in found.values()]),
        "on_bound": list(w["on_bound"]),
        "on_bound_why": dict(w["on_bound_why"]),
        "box": dict(w["box"]),
        "seeds": {
            int(s): (dict(r, rates=dict(r["rates"])) if r else None) for s, r in seeds.items()
        },
        # the trials' own durations: right across interruptions and resumes
        "wall_s": round(sum(r["wall_s"] for r in found.values()), 1),
    }
