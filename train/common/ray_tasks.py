"""Independent tasks on Ray (``backend: ray``): a local instance of ``workers`` CPUs, or the
cluster at ``address``; results come back as they finish, so a study appends and resumes
exactly as with its process pool. Needs the ``ray`` extra (checked by the configs that ask
for it)."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any


def ray_results(
    fn: Callable[..., Any],
    tasks: Sequence[tuple[Any, ...]],
    workers: int,
    address: str | None = None,
) -> Iterator[tuple[tuple[Any, ...], Any]]:
    """(task, ``fn(*task)``) for every task, each run as a one-CPU Ray task, in the order
    they finish. Ray is started here (and shut down after) unless it already runs; leaving
    the iterator early cancels what has not finished."""
    import ray

    started = not ray.is_initialized()
    if started:
        if address:
            ray.init(address=address, include_dashboard=False, log_to_driver=False)
        else:
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
    remote = ray.remote(num_cpus=1)(fn)
    refs = {remote.remote(*task): task for task in tasks}
    try:
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1)
            for ref in done:
                yield refs.pop(ref), ray.get(ref)
    finally:
        for ref in refs:
            ray.cancel(ref)
        if started:
            ray.shutdown()
