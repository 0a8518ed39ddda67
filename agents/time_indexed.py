"""The shared body of the controllers that track the time-indexed reference q_r(s), s = s₀ + t.

Computed torque, PD + gravity and Slotine–Li differ only in their torque law
τ = law(q, q̇, r), r the reference and its errors at the clock's s
(:class:`~agents.reference_clock.ReferenceErrors`: q_r, q_r', q_r'', e = q_r − q,
ė = q_r' − q̇). :class:`TimeIndexedController` holds the rest once: the gains' type check,
the :class:`~agents.reference_clock.ReferenceClock` (set to the env's reference phase s_ref
by ``reset``, advanced by dt after each ``step``, so s = s₀ + t), the diagnostics and the
residual feature block. A subclass states its gains type, its rates → gains map and
:meth:`TimeIndexedController.torque`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, ClassVar, TypeVar

from agents.base import ControlContext, FeatureBlock, FloatArray, state_arrays
from agents.reference_clock import (
    ReferenceClock,
    ReferenceErrors,
    error_diagnostics,
    time_indexed_features,
)
from ptrack_gym.errors import InvalidArgumentError
from ptrack_gym.paths import ReferencePath
from ptrack_gym.robots.model import RobotModel

_C = TypeVar("_C", bound="TimeIndexedController")


class TimeIndexedController:
    """A torque law on the time-indexed reference q_r(s), s = s₀ + t (module docstring).

    Args:
        model: the controller's nominal dynamics model (never the simulator).
        path: the reference path q_r(s), s in seconds.
        gains: the subclass's gains (an instance of :attr:`gains_type`).

    Raises:
        TypeError: gains of another type.
        InvalidConfigError: (a ``ValueError``) a model/path joint-count mismatch.
    """

    #: The gains dataclass the subclass takes.
    gains_type: ClassVar[type]
    #: (ctx, rates or None) → gains: the subclass module's ``gains_from_rates``.
    rates_to_gains: ClassVar[Callable[[ControlContext, Mapping[str, float] | None], Any]]

    def __init__(self, model: RobotModel, path: ReferencePath, gains: Any) -> None:
        if not isinstance(gains, self.gains_type):
            raise InvalidArgumentError(
                f"gains must be {self.gains_type.__name__}, got {type(gains).__name__}"
            )
        self.clock = ReferenceClock(model, path)
        self.model = model
        self.path = path
        self.gains = gains
        self.n = model.n
        self._last: tuple[float, ReferenceErrors] | None = None  # (s after the step, errors)
        self._s0 = 0.0

    @classmethod
    def build(cls: type[_C], ctx: ControlContext, gains: Any = None) -> _C:
        """The controller for a context with ``gains``: None — the robot's default gains
        at the context's control rate; a mapping of rates (e.g. tuned ones), made absolute
        by :attr:`rates_to_gains`; or a :attr:`gains_type` instance, as given."""
        if gains is None or isinstance(gains, Mapping):
            gains = cls.rates_to_gains(ctx, gains)
        return cls(ctx.model, ctx.path, gains)

    def reset(self, q: FloatArray, qd: FloatArray, s_ref: float) -> None:
        """Start the clock at s = ``s_ref`` (s); (q, q̇) are not used."""
        self.clock.reset(s_ref)
        self._last, self._s0 = None, float(s_ref)

    def step(self, q: FloatArray, qd: FloatArray, dt: float) -> FloatArray:
        """τ = :meth:`torque` (N·m), shape (n,), at measured (q, q̇) (rad, rad/s) against
        q_r(s); then s ← s + dt (s)."""
        q, qd = state_arrays(q, qd)
        err = self.clock.errors(q, qd, dt)
        tau = self.torque(q, qd, err)
        self._last = (self.clock.advance(dt), err)
        return tau

    def torque(self, q: FloatArray, qd: FloatArray, err: ReferenceErrors) -> FloatArray:
        """The subclass's law: τ (N·m), shape (n,), at (q, q̇) with the reference ``err``."""
        raise NotImplementedError

    def diagnostics(self) -> dict[str, float]:
        """``s``: the clock after the last step (s), equal to the env's ``s_ref`` then;
        ``tracking_error`` |e| (rad) and ``velocity_error`` |ė| (rad/s) of the state
        passed to the last step (against q_r(s − dt))."""
        return {"s": self._s0} if self._last is None else error_diagnostics(*self._last)

    def residual_features(self, max_speed_rad_s: float) -> FeatureBlock:
        """e, ė against the clock (:func:`agents.reference_clock.time_indexed_features`);
        ``max_speed_rad_s`` v_max bounds ė to ±2 v_max."""
        return time_indexed_features(self.clock, self.n, max_speed_rad_s)
