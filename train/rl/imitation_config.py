"""The imitation fields of a training run (``imitate``, ``demo_bc_weight``,
``decision_every``): their checks and the DAgger they ask for (:mod:`train.rl.imitation`
runs it)."""

from __future__ import annotations

from typing import Any

from agents.hold import check_decision_every
from agents.registry import CONTROLLER_NAMES, GAIN_CHOICES
from ptrack_gym.errors import InvalidConfigError
from train.rl.hyperparameters import TrainConfigError
from train.rl.imitation import DaggerSpec

#: The demonstration pull's random stream, apart from DAgger's (seeded by the run's seed
#: alone): np.random.default_rng([seed, DEMO_BC_STREAM, steps at its start]).
DEMO_BC_STREAM = 7919


def check_imitation(cfg: Any) -> None:
    """Raise :class:`TrainConfigError` unless the imitation fields of ``cfg`` (a
    :class:`~train.rl.config.TrainConfig`) agree (an
    expert that exists, pure SAC, per-step labels, an initial log-std)."""
    try:
        check_decision_every(cfg.decision_every)
    except InvalidConfigError as exc:
        raise TrainConfigError(str(exc)) from None
    if cfg.imitate is not None and cfg.decision_every != 1:
        raise TrainConfigError("imitate labels every control step: keep decision_every 1")
    if cfg.imitate is None:
        if cfg.demo_bc_weight:
            raise TrainConfigError("demo_bc_weight needs imitate (the expert's demonstrations)")
        return
    if cfg.imitate not in CONTROLLER_NAMES:
        raise TrainConfigError(
            f"unknown expert {cfg.imitate!r} for imitate; known: {list(CONTROLLER_NAMES)}"
        )
    if cfg.residual != "none" or cfg.algo != "sac":
        raise TrainConfigError("imitate is for pure SAC (residual none, algo sac)")
    if cfg.imitate_gains not in GAIN_CHOICES:
        raise TrainConfigError(
            f"imitate_gains must be one of {GAIN_CHOICES}, got {cfg.imitate_gains!r}"
        )
    if cfg.init_log_std is None:
        raise TrainConfigError(
            "imitate needs init_log_std: the fit trains the actor's mean only, so its "
            "exploration std would be whatever the shared layers make of the log-std head"
        )


def dagger_spec(cfg: Any) -> DaggerSpec:
    """The imitation a config asks for (``cfg.imitate`` set)."""
    assert cfg.imitate is not None
    return DaggerSpec(
        controller=cfg.imitate,
        gains=cfg.imitate_gains,
        rounds=cfg.imitate_rounds,
        first_steps=cfg.imitate_steps,
        round_steps=cfg.imitate_round_steps,
        noise=cfg.imitate_noise,
    )
