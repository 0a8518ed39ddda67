"""A pure policy that starts as a model-based controller: DAgger, then RL fine-tuning.

Pure SAC from scratch never held the 7-joint iiwa on its path (docs/rl.md): a 0.005 τ_max
white torque noise alone — far less than SAC's default exploration — carries the arm
0.1 rad off the path under PD + gravity at its default gains. This module gives the pure
policy (observation → normalized torque, no controller at run time) a starting point
that tracks, from a model-based *expert* queried as a teacher:

* **DAgger** (Ross, Gordon & Bagnell, AISTATS 2011): round 0 runs the expert (with a
  small Gaussian perturbation of the executed action, DART, Laskey et al. 2017, so the data
  covers the states just off the path) and labels each visited state with the expert's
  action; every further round runs the *current network* and labels the states *it*
  visits with the expert's action, then refits on everything collected so far. The
  network learns the expert's corrections in exactly the states its own errors lead to —
  behaviour cloning alone (round 0) compounds its errors (``tests/test_imitation.py``: on
  the two-link two rounds reach the expert's path distance, cloning alone is > 10× worse;
  on the iiwa, docs/rl.md: 3.3e-3 to 3.5e-2 rad undisturbed after 4 rounds, 5 seeds).
* The fit: Adam on the mean squared difference between the SAC actor's deterministic
  action tanh(μ(s)) and the expert's action a_E(s) ∈ [−1, 1]ⁿ, over the observations as the
  training env's ``VecNormalize`` sees them (its statistics are started from round 0's data).
* During RL fine-tuning, optionally a pull toward the expert's labels,
  λ·E_(s, a_E)∈D[|tanh(μ(s)) − a_E|²/n] added to the actor's loss (:func:`add_demo_bc`,
  TD3+BC's term with the demonstrations as its dataset).

The expert is any controller of ``agents.registry``; its action depends on the env's state
and clock only for PD + gravity, computed torque and Slotine–Li (the passivity controller
also carries its path parameter, which the observation does not show, so a network cannot
represent it exactly). Every random draw comes from a ``np.random.Generator`` and a
``torch.Generator`` seeded by the run's seed: the same seed gives the same data and weights.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.vec_env import VecNormalize

from agents.policy import ControllerPolicy
from agents.registry import make_controller

#: The demonstrations' file in a run folder (``--resume`` reloads it for the BC pull).
DEMO_FILE = "demonstrations.npz"
#: Per-round statistics of the imitation, in a run folder.
DEMO_STATS_FILE = "imitation.json"
#: Expert actions are clipped to ±this before the fit: tanh reaches ±1 only at infinity.
LABEL_BOUND = 0.995


@dataclass(frozen=True)
class DaggerSpec:
    """What one imitation does (each field is a ``TrainConfig`` field ``imitate_*``).

    Attributes:
        controller: the expert, a name of ``agents.registry.CONTROLLER_NAMES``.
        gains: its gains, "default" or "tuned".
        rounds: DAgger rounds after round 0 (0: behaviour cloning only).
        first_steps: env steps of round 0 (the expert drives).
        round_steps: env steps of each further round (the network drives).
        noise: std of the Gaussian added to the executed action (normalized units, a/τ_max),
            every round.
        epochs_first: passes over the data after round 0.
        epochs_round: passes over the whole aggregated data after each further round.
        batch_size: minibatch size of the fit.
        learning_rate: Adam's step size of the fit.
    """

    controller: str
    gains: str = "default"
    rounds: int = 4
    first_steps: int = 100_000
    round_steps: int = 50_000
    noise: float = 0.002
    epochs_first: int = 10
    epochs_round: int = 5
    batch_size: int = 256
    learning_rate: float = 1e-3


class RoundStats(NamedTuple):
    """One DAgger round: who drove, env steps, episodes ended early (off the path or
    unstable), the fit's mean squared action error over its last pass."""

    round: int
    driver: str  # "expert" or "network"
    steps: int
    terminated: int
    fit_mse: float


class Demonstrations(NamedTuple):
    """Everything DAgger collected: raw observations (float32, (N, obs_dim)) and the
    expert's actions at them ((N, n), in [−1, 1]), and the rounds' statistics."""

    observations: np.ndarray
    actions: np.ndarray
    rounds: list[RoundStats]

    @property
    def env_steps(self) -> int:
        """Env steps the imitation took (its sample cost, beside RL's)."""
        return int(sum(r.steps for r in self.rounds))


def deterministic_action(model: SAC, obs_normalized: torch.Tensor) -> torch.Tensor:
    """SAC's deterministic action tanh(μ(s)) ∈ (−1, 1)ⁿ for a batch of normalized
    observations, differentiable in the actor's parameters."""
    mean_actions, _, _ = model.actor.get_action_dist_params(obs_normalized)
    return torch.tanh(mean_actions)


def collect(
    env: gym.Env,
    expert: ControllerPolicy,
    steps: int,
    noise: float,
    rng: np.random.Generator,
    driver: Callable[[np.ndarray], np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Run ``steps`` env steps, label every observation with the expert's action.

    The executed action is clip(driver(obs) + noise·ξ, −1, 1), ξ ~ N(0, I) from ``rng``;
    ``driver=None``: the expert drives. Episodes are reset with seeds drawn from ``rng``.

    Returns:
        (observations (steps, obs_dim) float32, expert actions (steps, n) float32, the
        number of episodes that terminated — ended off the path or unstable — not truncated).
    """
    obs_dim = int(np.prod(env.observation_space.shape))
    n = int(np.prod(env.action_space.shape))
    observations = np.empty((steps, obs_dim), dtype=np.float32)
    actions = np.empty((steps, n), dtype=np.float32)
    terminated = 0
    obs, _ = env.reset(seed=int(rng.integers(2**31 - 1)))
    for k in range(steps):
        label = expert.action(obs)
        observations[k], actions[k] = obs, label
        executed = label if driver is None else driver(obs)
        if noise > 0.0:
            executed = executed + noise * rng.standard_normal(n)
        obs, _, term, trunc, _ = env.step(np.clip(executed, -1.0, 1.0).astype(np.float32))
        if term or trunc:
            terminated += int(term)
            obs, _ = env.reset(seed=int(rng.integers(2**31 - 1)))
    return observations, actions, terminated


def fit_actor(
    model: SAC,
    obs_normalized: np.ndarray,
    actions: np.ndarray,
    epochs: int,
    batch_size: int,
    learning_rate: float,
    generator: torch.Generator,
) -> float:
    """Minimise mean |tanh(μ(s)) − clip(a_E, ±LABEL_BOUND)|²/n over the actor's parameters
    (Adam, shuffled minibatches from ``generator``); returns the last pass's mean loss."""
    x = torch.as_tensor(obs_normalized, dtype=torch.float32, device=model.device)
    y = torch.as_tensor(
        np.clip(actions, -LABEL_BOUND, LABEL_BOUND), dtype=torch.float32, device=model.device
    )
    optimizer = torch.optim.Adam(model.actor.parameters(), lr=learning_rate)
    last = float("nan")
    for _ in range(epochs):
        order = torch.randperm(len(x), generator=generator).to(model.device)
        total, count = 0.0, 0
        for start in range(0, len(x), batch_size):
            idx = order[start : start + batch_size]
            loss = ((deterministic_action(model, x[idx]) - y[idx]) ** 2).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            total += float(loss.detach()) * len(idx)
            count += len(idx)
        last = total / count
    return last


def _normalizer(vec_normalize: VecNormalize | None) -> Callable[[np.ndarray], np.ndarray]:
    if vec_normalize is None:
        return lambda obs: np.asarray(obs, dtype=np.float32)
    return lambda obs: np.asarray(vec_normalize.normalize_obs(obs), dtype=np.float32)


def dagger(
    model: SAC,
    env: gym.Env,
    spec: DaggerSpec,
    seed: int,
    vec_normalize: VecNormalize | None = None,
) -> Demonstrations:
    """Train ``model``'s actor to imitate ``spec.controller`` on ``env`` by DAgger.

    ``env`` is a single (unvectorized) env built like the training env. With
    ``vec_normalize`` (the training env's), its observation statistics are first updated
    with round 0's observations — the network then sees the expert's state distribution
    with mean 0 and unit variance — and every fit uses its normalization.

    Returns:
        The aggregated demonstrations (raw observations) and the rounds' statistics.
    """
    rng = np.random.default_rng(seed)
    generator = torch.Generator().manual_seed(seed)
    expert = ControllerPolicy(env, make_controller(spec.controller, env, spec.gains))
    obs, act, term = collect(env, expert, spec.first_steps, spec.noise, rng)
    if vec_normalize is not None:
        vec_normalize.obs_rms.update(obs.astype(np.float64))
    normalize = _normalizer(vec_normalize)
    observations, actions = [obs], [act]
    mse = fit_actor(
        model, normalize(obs), act, spec.epochs_first, spec.batch_size, spec.learning_rate,
        generator,
    )  # fmt: skip
    rounds = [RoundStats(0, "expert", spec.first_steps, term, mse)]

    def network(o: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            x = torch.as_tensor(normalize(o[None]), device=model.device)
            return deterministic_action(model, x)[0].cpu().numpy().astype(np.float64)

    for k in range(1, spec.rounds + 1):
        obs, act, term = collect(env, expert, spec.round_steps, spec.noise, rng, network)
        observations.append(obs)
        actions.append(act)
        all_obs, all_act = np.concatenate(observations), np.concatenate(actions)
        mse = fit_actor(
            model, normalize(all_obs), all_act, spec.epochs_round, spec.batch_size,
            spec.learning_rate, generator,
        )  # fmt: skip
        rounds.append(RoundStats(k, "network", spec.round_steps, term, mse))
    return Demonstrations(np.concatenate(observations), np.concatenate(actions), rounds)


def save_demonstrations(demos: Demonstrations, run_dir: Path, spec: DaggerSpec) -> None:
    """``demonstrations.npz`` (observations, actions) and ``imitation.json`` (the spec,
    the rounds, the env steps in all) in ``run_dir``."""
    run_dir.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(run_dir / DEMO_FILE, observations=demos.observations, actions=demos.actions)
    stats: dict[str, Any] = {
        "spec": spec.__dict__,
        "env_steps": demos.env_steps,
        "rounds": [r._asdict() for r in demos.rounds],
    }
    (run_dir / DEMO_STATS_FILE).write_text(json.dumps(stats, indent=2) + "\n")


def load_demonstrations(run_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """(observations, actions) of a run's ``demonstrations.npz``.

    Raises:
        FileNotFoundError: the run has none.
    """
    with np.load(run_dir / DEMO_FILE) as data:
        return data["observations"], data["actions"]


def demo_bc_loss(
    model: SAC, obs_normalized: torch.Tensor, actions: torch.Tensor, weight: float
) -> torch.Tensor:
    """λ·mean over the batch and the n action dimensions of (tanh(μ(s)) − a_E)², a_E
    clipped to ±LABEL_BOUND as in the fit."""
    target = actions.clamp(-LABEL_BOUND, LABEL_BOUND)
    return weight * ((deterministic_action(model, obs_normalized) - target) ** 2).mean()


def add_demo_bc(
    model: SAC,
    observations: np.ndarray,
    actions: np.ndarray,
    weight: float,
    seed: int | Sequence[int],
) -> None:
    """Before every step of the actor's optimizer, add the gradient of :func:`demo_bc_loss`
    on a minibatch of the demonstrations (SB3's batch size, drawn from
    ``np.random.default_rng(seed)``; observations normalized by the model's current
    VecNormalize statistics, as SB3's ``train`` normalizes replay data) to the actor's
    gradient SB3 has just
    computed. Skipped while the actor is frozen (critic warm-up). Hooks are not saved with
    a model: apply again after loading one (``train.rl.run.run`` does, on ``--resume``)."""
    algo: Any = model
    params = list(algo.actor.parameters())
    rng = np.random.default_rng(seed)
    labels = torch.as_tensor(actions, dtype=torch.float32, device=algo.device)

    def before(opt: torch.optim.Optimizer, args: Any, kwargs: Any) -> None:
        if not any(p.requires_grad for p in params):
            return
        idx = rng.integers(len(observations), size=algo.batch_size)
        obs = observations[idx]
        if algo._vec_normalize_env is not None:
            obs = algo._vec_normalize_env.normalize_obs(obs)
        x = torch.as_tensor(np.asarray(obs, dtype=np.float32), device=algo.device)
        demo_bc_loss(algo, x, labels[torch.as_tensor(idx)], weight).backward()

    algo.actor.optimizer.register_step_pre_hook(before)
