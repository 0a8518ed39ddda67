"""Composable, seeded disturbances and model mismatch for the tracking environments.

* :mod:`~ptrack_gym.disturbances.base` — the :class:`Disturbance` interface (its hooks),
  the :class:`DisturbanceContext` a disturbance may read, and :data:`RECOVERY_S`, the time
  an episode must leave after a disturbance's latest event (shorter episodes are refused);
* :mod:`~ptrack_gym.disturbances.torques` — the joint-torque families (impulse, step,
  periodic and noise torques), sized by M(q_home) or, with ``sizing="onset"``, by M(q)
  at the configuration where they start to act (:data:`SIZINGS`);
* :mod:`~ptrack_gym.disturbances.families` — the other families (push, payload, mismatch,
  action and observation noise, delay), and the joint torques re-exported;
* :mod:`~ptrack_gym.disturbances.presets` — presets × levels and :func:`build_disturbances`;
* :mod:`~ptrack_gym.disturbances.runner` — the sub-step loop and the work ledger.

Everything random is drawn from the stream given to ``reset`` (which the env derives from
its reset seed alone), in an order that does not depend on the actions: two controllers
run with the same seed meet exactly the same disturbances.
"""

from ptrack_gym.disturbances.base import (
    DISTURBANCES,
    RECOVERY_S,
    SIZINGS,
    Disturbance,
    DisturbanceContext,
    MassChange,
    min_horizon_s,
)
from ptrack_gym.disturbances.families import (
    ActionNoise,
    Mismatch,
    ObservationDelay,
    ObservationNoise,
    Payload,
    Push,
)
from ptrack_gym.disturbances.presets import (
    ENERGY_PRESETS,
    PRESETS,
    DisturbanceSpec,
    build_disturbances,
    from_spec,
    preset_does_work,
    preset_specs,
)
from ptrack_gym.disturbances.runner import DisturbanceRunner
from ptrack_gym.disturbances.torques import (
    ImpulseTorque,
    NoiseTorque,
    PeriodicTorque,
    StepTorque,
)

__all__ = [
    "DISTURBANCES",
    "ENERGY_PRESETS",
    "PRESETS",
    "RECOVERY_S",
    "SIZINGS",
    "ActionNoise",
    "Disturbance",
    "DisturbanceContext",
    "DisturbanceRunner",
    "DisturbanceSpec",
    "ImpulseTorque",
    "MassChange",
    "Mismatch",
    "NoiseTorque",
    "ObservationDelay",
    "ObservationNoise",
    "Payload",
    "PeriodicTorque",
    "Push",
    "StepTorque",
    "build_disturbances",
    "from_spec",
    "min_horizon_s",
    "preset_does_work",
    "preset_specs",
]
