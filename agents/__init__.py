"""Controllers, residual wrappers and policy adapters for ptrack_gym environments.

``from agents import make_controller, ControllerPolicy`` is all a user needs to run a
controller on an env; :data:`agents.registry.ENTRIES` lists the controllers, one entry
each. ``import agents`` also registers the residual ids
``ptrack_gym/<Robot>Track-Residual-<Base>-v0`` (:data:`RESIDUAL_ENV_IDS`), e.g.
``gym.make("ptrack_gym/TwoLinkTrack-Residual-Passivity-v0")``.
"""

import ptrack_gym  # noqa: F401  (registers the plain ids the residual ids build on)
from agents.policy import ControllerPolicy
from agents.registry import CONTROLLER_NAMES, CONTROLLERS, ENTRIES, make_controller
from agents.residual_ids import register_residual_envs
from agents.residual_spec import ResidualSpec

RESIDUAL_ENV_IDS: list[str] = register_residual_envs()

__all__ = [
    "CONTROLLERS",
    "CONTROLLER_NAMES",
    "ENTRIES",
    "RESIDUAL_ENV_IDS",
    "ControllerPolicy",
    "ResidualSpec",
    "make_controller",
]
