"""The run folder every job writes into, and the worker processes it runs episodes in.

One harness for the evaluation sweep, the control-rate study, gain tuning, the fronts and
the adversarial search:

* :func:`open_run` — refuse a folder that holds any file unless ``--resume`` (continue it)
  or ``--force`` (start over in place); on resume, refuse a config that differs in a field
  that changes results (the folder would mix two experiments); then write the provenance:
  ``config.yml`` (the settings) and ``command.txt`` (the command line as it was typed);
* :func:`worker_pool` — ``n`` worker processes of one BLAS thread each, forked where a fork
  is safe (:func:`start_method`), spawned elsewhere;
* :func:`worker_count` — ``workers`` of a config, 0 meaning every core this process may use.

Figures use matplotlib's headless Agg backend (:mod:`train.plots`).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import shlex
import sys
import threading
import time
from collections.abc import Callable, Collection, Mapping
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from ptrack_gym.errors import InvalidConfigError
from train.common.threads import one_thread_defaults

#: Modules whose state does not survive a fork (thread pools, device handles): while one
#: is imported, ``start_method("auto")`` spawns.
FORK_UNSAFE_MODULES = ("torch", "jax", "tensorflow", "ray")

CONFIG_FILE = "config.yml"
COMMAND_FILE = "command.txt"


@dataclass(frozen=True)
class RunFolder:
    """An opened run folder.

    Attributes:
        out: the folder.
        results: the file whose content marks results there (``episodes.csv``,
            ``points.csv``, ``optuna.journal``).
        resumed: whether the folder already held results that this run continues.
    """

    out: Path
    results: Path
    resumed: bool


def has_results(path: Path) -> bool:
    """Whether ``path`` exists and is not empty."""
    return path.exists() and path.stat().st_size > 0


def open_run(
    out: str | Path,
    results: str,
    settings: Mapping[str, Any],
    *,
    resume: bool,
    force: bool = False,
    free: Collection[str] = (),
    saved_required: bool = True,
    defaults: Mapping[str, Any] | None = None,
) -> RunFolder:
    """Open the run folder ``out`` for a job whose results go to ``out/results``.

    Args:
        out: the run folder (created if missing).
        results: the results file's name inside ``out``.
        settings: what ``config.yml`` records; on resume it is compared with the saved one.
        resume: continue the results already there.
        force: start over in a folder that holds files: its results file is deleted, every
            other file is rewritten (what publishing to ``docs/results/...`` takes).
        free: settings a resume may change (they change no result: workers, the output
            folder, a larger budget).
        saved_required: on resume over existing results, a missing ``config.yml`` is an
            error (it cannot be checked); ``False`` skips the check instead.
        defaults: the value a setting had before the saved ``config.yml`` recorded it (a
            run written before the setting existed ran with it); a setting neither records
            nor defaults is not compared.

    Raises:
        InvalidConfigError: the folder holds any file and neither ``resume`` nor ``force``
            is given (nothing shipped or computed is overwritten by default); or on resume
            the saved settings differ in a field not in ``free`` (each named, old → new), or
            ``config.yml`` is missing while ``saved_required``.
    """
    out = Path(out)
    path = out / results
    if resume and force:
        raise InvalidConfigError("--resume continues a run, --force starts it over: not both")
    held = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
    if held and not (resume or force):
        shown = ", ".join(held[:4]) + (", …" if len(held) > 4 else "")
        raise InvalidConfigError(
            f"{out} already holds {len(held)} file(s) ({shown}): --resume continues that "
            "run, --force starts it over in place, or choose another --out"
        )
    if force:
        path.unlink(missing_ok=True)
    existing = has_results(path)
    saved = out / CONFIG_FILE
    if existing:
        check_saved_settings(out, results, settings, free, defaults, saved_required)
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(saved, yaml.safe_dump(dict(settings), sort_keys=False))
    write_atomic(out / COMMAND_FILE, shlex.join(getattr(sys, "orig_argv", sys.argv)) + "\n")
    return RunFolder(out, path, existing)


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` so that a reader sees the old file or the new, never a part.

    Several processes may resume one run folder at once (``ptrack tune --resume`` split by
    controller): each rewrites ``config.yml`` while another reads it. A plain
    ``write_text`` truncates first, and a reader in that window saw an empty config.
    """
    saved_whole(path, lambda tmp: tmp.write_text(text))


def saved_whole(path: Path, save: Callable[[Path], object]) -> None:
    """``save`` a file to a temporary name beside ``path`` (``.<name>.<pid>.<thread>.tmp``),
    then rename it to ``path`` (atomic on one file system): the file under ``path`` is
    always a whole one — the old or the new — whether a reader looks in between or the
    process is killed mid-save; a failed save's temporary is removed."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    try:
        save(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def check_saved_settings(
    out: Path,
    results: str,
    settings: Mapping[str, Any],
    free: Collection[str] = (),
    defaults: Mapping[str, Any] | None = None,
    saved_required: bool = True,
) -> None:
    """What :func:`open_run` checks before a resume, without writing anything: where
    ``out/results`` holds results, the saved ``config.yml`` must equal ``settings`` but for
    ``free`` (``defaults``: values a setting had before the file recorded it).

    Raises:
        InvalidConfigError: as :func:`open_run` on resume.
    """
    if not has_results(Path(out) / results):
        return
    saved = Path(out) / CONFIG_FILE
    if saved.exists():
        old = {**(defaults or {}), **(yaml.safe_load(saved.read_text()) or {})}
        _check_same(old, settings, free)
    elif saved_required:
        raise InvalidConfigError(
            f"{saved} is missing: cannot check that --resume continues the same run"
        )


def _check_same(old: Mapping[str, Any], new: Mapping[str, Any], free: Collection[str]) -> None:
    changed = sorted(k for k in new if k not in free and k in old and old[k] != new[k])
    if changed:
        diffs = ", ".join(f"{k} {old[k]!r} -> {new[k]!r}" for k in changed)
        raise InvalidConfigError(f"--resume with different settings: {diffs}; use another --out")


def worker_count(workers: int) -> int:
    """``workers``, or every core this process may run on when it is 0."""
    return workers or len(os.sched_getaffinity(0))


def _thread_count() -> int:
    """Threads of this process, native ones included (BLAS pools, tqdm's monitor, the
    executors'): the entries of ``/proc/self/task`` on Linux, else the Python threads."""
    try:
        return len(os.listdir("/proc/self/task"))
    except OSError:
        return threading.active_count()


def start_method(requested: str = "auto") -> str:
    """The multiprocessing start method of the worker processes.

    ``"auto"`` is ``"fork"`` where a fork is safe — Linux (macOS's system libraries are not
    fork-safe, Windows has no fork), Python ≥ 3.11 (whose fork pools start every worker on
    the first task), this process running a single thread (native threads counted, as
    Python ≥ 3.12's own fork warning counts them: the ``ptrack`` entry points set one BLAS
    thread before numpy loads), and none of :data:`FORK_UNSAFE_MODULES` imported — and
    ``"spawn"`` elsewhere. A forked worker inherits this process's imported modules instead
    of importing them again (``bench/eval_scaling.py`` times both). The start method never
    changes an episode's numbers. Any other value is returned as it is."""
    if requested != "auto":
        return requested
    safe = (
        sys.platform.startswith("linux")
        and sys.version_info >= (3, 11)
        and _thread_count() == 1
        and not any(name in sys.modules for name in FORK_UNSAFE_MODULES)
    )
    return "fork" if safe else "spawn"


#: How often a pool's worker checks that the process that started it is alive (s).
PARENT_CHECK_S = 1.0


def exit_with_parent(parent: int) -> None:
    """A pool worker's initializer: a daemon thread ends the worker once ``parent`` (the
    process that made the pool) is gone. A study stopped by ``SIGTERM`` or ``SIGKILL`` never
    shuts its pool down, and its idle workers would otherwise wait for work forever (their
    own copy of the call queue's write end keeps it open)."""

    def watch() -> None:
        while True:
            time.sleep(PARENT_CHECK_S)
            if os.getppid() != parent:
                os._exit(0)

    threading.Thread(target=watch, name="ptrack-parent-watch", daemon=True).start()


def worker_pool(processes: int, method: str = "auto") -> ProcessPoolExecutor:
    """``processes`` worker processes of one thread each (the thread-count variables are
    set to 1 unless the user set them; a forked worker keeps this process's), started by
    ``start_method(method)``. Forked workers are started at once, while this process may
    still be single-threaded; spawned ones start on the first task."""
    one_thread_defaults()  # BLAS and torch read them when they load in a spawned worker
    method = start_method(method)
    pool = ProcessPoolExecutor(
        processes,
        mp_context=mp.get_context(method),
        initializer=exit_with_parent,
        initargs=(os.getpid(),),
    )
    if method == "fork":  # the first submit forks every worker, before any other thread
        pool.submit(int).result()
    return pool
