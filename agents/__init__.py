"""Controllers, residual wrappers and policy adapters for ptrack_gym environments.

``from agents import make_controller, ControllerPolicy`` is all a user needs to run a
controller on an env; :data:`agents.registry.CONTROLLERS` lists the controllers.
"""

from agents.policy import ControllerPolicy
from agents.registry import CONTROLLER_NAMES, CONTROLLERS, make_controller

__all__ = ["CONTROLLERS", "CONTROLLER_NAMES", "ControllerPolicy", "make_controller"]
