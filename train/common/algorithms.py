"""The algorithm names ``ptrack train --algo`` accepts, without importing a learner (torch
and SB3 load only where a model is built: :mod:`train.evaluation.policies`)."""

from __future__ import annotations

#: Stable-Baselines3's own algorithms.
SB3_ALGOS: tuple[str, ...] = ("sac", "td3", "ppo")
#: The recurrent ones, from sb3-contrib (the optional ``recurrent`` extra), by rl-zoo3's
#: names → class: ``ppo_lstm`` is RecurrentPPO with an LSTM policy (``MlpLstmPolicy``),
#: whose hidden state lets a policy infer what one observation cannot (a payload from a push).
RECURRENT_ALGOS: dict[str, str] = {"ppo_lstm": "RecurrentPPO"}
#: Every algorithm name ``--algo`` accepts.
ALGO_NAMES: tuple[str, ...] = (*SB3_ALGOS, *RECURRENT_ALGOS)
#: The on-policy algorithms (rollouts of ``n_steps`` per env, no replay buffer).
ON_POLICY: tuple[str, ...] = ("ppo", "ppo_lstm")
