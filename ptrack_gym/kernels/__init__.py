"""Compiled hot paths (numba), each the twin of a readable numpy reference.

Every kernel here computes exactly what a numpy method elsewhere in the package states
(the reference named in its docstring); ``tests/test_kernels.py`` checks each pair to
≤ 1e-12 (relative), and only the kernel runs on the hot path. Kernels are compiled on first
use and cached on disk (``cache=True``), so a new process loads them in milliseconds.

* :mod:`.path` — evaluation of the package's paths (multi-sine, periodic piecewise cubic);
* :mod:`.projection` — the nearest point of a path (:meth:`PathProjector.nearest`);
* :mod:`.task` — observation and reward of a step (:meth:`TrackingTask.observe`);
* :mod:`.linalg` — small dense helpers (the symmetric mass matrix from CRBA's triangle).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import numba
import numpy as np
from numpy.typing import NDArray

F = TypeVar("F", bound=Callable[..., Any])

#: What calling a kernel raises for arguments it has no compiled version for and cannot
#: compile one: numba types no float16 (``NotImplementedError``), longdouble or non-native
#: byte order, and a kernel may need one float width throughout (``TypingError``, a
#: ``NumbaError``). A caller taking user arrays on its hot path catches these (a ``try``
#: costs nothing when nothing is raised) and retries on native float64 copies.
DISPATCH_ERRORS: tuple[type[Exception], ...] = (numba.core.errors.NumbaError, NotImplementedError)


def kernel(fn: F) -> F:
    """``numba.njit`` with the package's settings: cached on disk, no fast-math (IEEE
    semantics, so a kernel can equal its numpy twin), errors checked like numpy's."""
    return numba.njit(cache=True, fastmath=False, error_model="numpy")(fn)  # type: ignore[return-value]


def pack(arrays: Sequence[NDArray[np.float64]]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Many float arrays (≤ 3-d) as one flat array and a layout (offset, d0, d1, d2) per
    array: a kernel then takes two arguments instead of many (numba unboxes each array
    argument on every call, ~50-100 ns apiece) and reads them back with :func:`view1` …
    :func:`view3`."""
    flat_parts, rows, offset = [], [], 0
    for a in arrays:
        arr = np.ascontiguousarray(a, dtype=np.float64)
        shape = (*arr.shape, 1, 1, 1)[:3]
        rows.append((offset, *shape))
        flat_parts.append(arr.ravel())
        offset += arr.size
    return np.concatenate(flat_parts), np.array(rows, dtype=np.int64)


@kernel
def view1(flat: NDArray[np.float64], layout: NDArray[np.int64], k: int) -> NDArray[np.float64]:
    """Array k of a :func:`pack`, 1-d."""
    o, d0 = layout[k, 0], layout[k, 1]
    return flat[o : o + d0]


@kernel
def view2(flat: NDArray[np.float64], layout: NDArray[np.int64], k: int) -> NDArray[np.float64]:
    """Array k of a :func:`pack`, 2-d."""
    o, d0, d1 = layout[k, 0], layout[k, 1], layout[k, 2]
    return flat[o : o + d0 * d1].reshape((d0, d1))


@kernel
def view3(flat: NDArray[np.float64], layout: NDArray[np.int64], k: int) -> NDArray[np.float64]:
    """Array k of a :func:`pack`, 3-d."""
    o, d0, d1, d2 = layout[k, 0], layout[k, 1], layout[k, 2], layout[k, 3]
    return flat[o : o + d0 * d1 * d2].reshape((d0, d1, d2))


__all__ = ["DISPATCH_ERRORS", "kernel", "pack", "view1", "view2", "view3"]
