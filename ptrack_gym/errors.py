"""Package exceptions.

Every error the package raises on purpose derives from :class:`PtrackError`, and
also from the built-in exception a caller would naturally catch (``ValueError`` for
bad values, ``TypeError`` for bad arguments), so both ``except PtrackError`` and
``except ValueError`` work.
"""

from __future__ import annotations


class PtrackError(Exception):
    """Base class of every error raised on purpose by ptrack_gym."""


class InvalidPathError(PtrackError, ValueError):
    """A reference path violates a requirement (stationary point, joint limit, shape)."""


class InvalidActionError(PtrackError, ValueError):
    """An action has the wrong shape or non-finite entries."""


class InvalidConfigError(PtrackError, ValueError):
    """A configuration value (rate, option, spec) is out of its documented domain."""


class ControlRateError(InvalidConfigError):
    """A controller cannot serve the control period it was asked for (its stated limit for
    the path and gains is shorter)."""


class SimulationClosedError(PtrackError, RuntimeError):
    """A closed simulation was used."""


class ControllerDivergedError(PtrackError, FloatingPointError):
    """A controller returned a non-finite torque: it has diverged (the evaluation ends the
    episode as unstable; the residual env terminates it with the unstable penalty)."""


class InvalidArgumentError(PtrackError, TypeError):
    """An argument of the wrong type (a controller's gains of another controller's class)."""


class ResetNeededError(PtrackError, RuntimeError):
    """A stateful object (a controller, an env) was stepped before its first ``reset``."""
