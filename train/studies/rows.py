"""Run a study's episodes and append their rows as they finish: :func:`run_rows`, shared by
the studies whose episodes are independent (:mod:`train.studies.rates`,
:mod:`train.studies.verdict_study`)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import as_completed
from pathlib import Path
from typing import Any

from tqdm import tqdm

from train.common.runs import worker_count, worker_pool
from train.evaluation.results import EpisodeWriter


def run_rows(
    run_one: Callable[..., dict[str, Any]],
    tasks: Sequence[tuple[Any, ...]],
    workers: int,
    path: Path,
    columns: Sequence[str],
    progress: bool = True,
    backend: str = "process",
    ray_address: str | None = None,
) -> None:
    """``run_one(*task)`` for every task — in ``workers`` processes (0: the cores; 1: here),
    or with ``backend="ray"`` as Ray tasks (:func:`train.common.ray_tasks.ray_results`; a
    cluster at ``ray_address``) — each row appended to ``path`` (``columns``) as it
    finishes, fsynced. An interrupt or a failed episode cancels what has not started; every
    row written stays (``--resume``)."""
    writer = EpisodeWriter(path, columns)
    try:
        bar = tqdm(total=len(tasks), disable=not progress, desc="episodes")
        if backend == "ray":
            from train.common.ray_tasks import ray_results

            for _, row in ray_results(run_one, tasks, worker_count(workers), ray_address):
                writer.write(row)
                bar.update()
        elif worker_count(workers) == 1:
            for task in tasks:
                writer.write(run_one(*task))
                bar.update()
        else:
            with worker_pool(worker_count(workers)) as pool:
                futures = [pool.submit(run_one, *task) for task in tasks]
                try:
                    for fut in as_completed(futures):
                        writer.write(fut.result())
                        bar.update()
                finally:
                    for fut in futures:
                        fut.cancel()
        bar.close()
    finally:
        writer.close()
