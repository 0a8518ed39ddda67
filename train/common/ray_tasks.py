"""Independent tasks on Ray (``backend: ray``): a local instance of ``workers`` CPUs, or the
cluster at ``address``; results come back as they finish, so a study appends and resumes
exactly as with its process pool. Needs the ``ray`` extra (checked by the configs that ask
for it)."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any

#: How long (s) tasks cancelled by an interruption get to finish (a training run saves
#: where it got to) before Ray is shut down, which kills them.
CANCEL_GRACE_S = 120.0


def ray_results(
    fn: Callable[..., Any],
    tasks: Sequence[tuple[Any, ...]],
    workers: int,
    address: str | None = None,
    grace_s: float = CANCEL_GRACE_S,
) -> Iterator[tuple[tuple[Any, ...], Any]]:
    """(task, ``fn(*task)``) for every task, each run once (no retry: a task that died is an
    error, not a rerun of a stale plan) as a one-CPU Ray task, in the order they finish.
    Ray is started here (``max(1, workers)`` CPUs) and shut down after, unless it already
    runs. Leaving the iterator early (an interrupt, a failed task) cancels the unfinished
    tasks — a KeyboardInterrupt in each — and waits up to ``grace_s`` for them to stop
    before the shutdown."""
    if not tasks:
        return
    import ray

    started = not ray.is_initialized()
    if started:
        if address:
            ray.init(address=address, include_dashboard=False, log_to_driver=False)
        else:
            ray.init(num_cpus=max(1, workers), include_dashboard=False, log_to_driver=False)
    refs: dict[Any, tuple[Any, ...]] = {}
    try:
        remote = ray.remote(num_cpus=1, max_retries=0)(fn)
        refs = {remote.remote(*task): task for task in tasks}
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1)
            for ref in done:
                task = refs.pop(ref)
                yield task, ray.get(ref)
    finally:
        pending = list(refs)
        for ref in pending:
            ray.cancel(ref)
        if pending:
            ray.wait(pending, num_returns=len(pending), timeout=grace_s)
        if started:
            ray.shutdown()
