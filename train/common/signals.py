"""Interruptions of a training run: SIGTERM as Ctrl-C, and saves that no signal cuts short.

A run interrupted by Ctrl-C (SIGINT) or by ``kill`` / a scheduler / ``Pool.terminate``
(SIGTERM, see :func:`sigterm_as_interrupt`) saves the state it reached. Python raises
``KeyboardInterrupt`` at whatever line runs when the signal arrives; arriving in the middle
of a save, it can leave a half-written file — or turn into another error on the way out:
``torch.save`` cut by it raises ``RuntimeError: [enforce fail at inline_container.cc]``,
which the run's ``except KeyboardInterrupt`` does not catch, so the run ended without its
final save (seen: a campaign's worker stopped during a checkpoint saved nothing, one time
in three). Every save is therefore run :func:`uninterrupted`: the signal waits until the
file is written and is then delivered as it would have been.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from typing import Any

#: The signals that interrupt a run.
INTERRUPTS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM raises ``KeyboardInterrupt`` in this process (enter it
    from the main thread), so a run terminated while it trains saves its state as an
    interrupted one does: the CLI and the campaign's worker processes (which
    ``Pool.terminate`` stops with SIGTERM). The previous handler is restored on exit — an
    idle worker terminated after its run then exits quietly."""

    def _raise(signum: int, frame: Any) -> None:
        # One-shot: a second SIGTERM (Pool.terminate's, after a signal to the whole process
        # group) is ignored, so it cannot cut the save it started short.
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise KeyboardInterrupt(f"signal {signum}")

    previous = signal.signal(signal.SIGTERM, _raise)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextlib.contextmanager
def uninterrupted() -> Iterator[None]:
    """Hold SIGINT and SIGTERM while the block runs (a save), then deliver them.

    A signal that arrives inside the block is recorded, not acted on; when the block ends
    (normally or by an exception) the handlers in force before it are restored and every
    held signal is raised again, once, in the order it came — each even when one before it
    raised — so it does what it would have done had it arrived just after the save:
    ``KeyboardInterrupt`` under Python's default SIGINT handler or
    :func:`sigterm_as_interrupt`, the end of the process under SIGTERM's default action.
    A signal ignored before the block (or whose handler Python did not install) is left
    alone. Blocks nest (an inner block hands its signals to the outer one). Outside the
    main thread, where Python runs no signal handler and cannot install one, the block runs
    as it is.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []

    def _hold(signum: int, frame: Any) -> None:
        if signum not in held:
            held.append(signum)

    restore = contextlib.ExitStack()
    try:
        for s in INTERRUPTS:
            previous = signal.getsignal(s)
            if previous is None or previous == signal.SIG_IGN:
                continue
            restore.callback(signal.signal, s, previous)  # registered before it is replaced
            signal.signal(s, _hold)
        yield
    finally:
        try:
            restore.close()  # every handler back, even if a signal interrupts one restore
        finally:
            _deliver(held)


def _deliver(signals: list[int]) -> None:
    """Raise each of ``signals`` in order; a handler's exception does not stop the rest."""
    if signals:
        try:
            signal.raise_signal(signals[0])
        finally:
            _deliver(signals[1:])
