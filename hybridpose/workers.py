"""Worker processes that end with the process that started them.

A pool of fresh interpreters (``spawn``: the renderer's GL context and threads do not survive a fork)
outlives a parent killed by a signal it cannot handle (``kill PID``, the out-of-memory killer): its
workers wait for work that never comes or finish their tasks, holding the cores, and a render job's
keep writing views into the folder a resumed run reads. (Ctrl-C reaches the whole process group and
ends them all.) Found on a benchmark whose parent was killed: five workers ran on for an hour beside
later measurements.

Neither ``multiprocessing`` nor ``concurrent.futures`` offers this; Linux's ``PR_SET_PDEATHSIG`` is
Linux's alone and fires when the parent's *thread* that started the worker ends. So each worker watches
its parent itself.
"""
from __future__ import annotations

import multiprocessing
import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor

PARENT_POLL_S = 1.0  # how often a worker checks that its parent still runs (seconds)


def exit_with_parent(parent_pid: int) -> None:
    """A pool's ``initializer``: starts a daemon thread in this worker that ends it (exit status 1, no
    clean-up: its parent, which would collect its results, is gone) once ``parent_pid`` is no longer its
    parent (a dead parent's children pass to another process)."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def pool_options() -> dict:
    """Keyword arguments that make a pool's workers end with this process: for a
    ``multiprocessing`` context's ``Pool`` and for a ``ProcessPoolExecutor`` alike
    (``initializer``, ``initargs``)."""
    return {"initializer": exit_with_parent, "initargs": (os.getpid(),)}


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity where the system tells it, else all)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # macOS and Windows have no affinity call
        return max(1, os.cpu_count() or 1)


def spawn_executor(max_workers: int) -> ProcessPoolExecutor:
    """A ``ProcessPoolExecutor`` of ``max_workers`` fresh interpreters (``spawn``) that end with this process."""
    return ProcessPoolExecutor(max_workers, mp_context=multiprocessing.get_context("spawn"), **pool_options())


def spawn_pool(processes: int):
    """A ``multiprocessing.Pool`` of ``processes`` fresh interpreters (``spawn``) that end with this process."""
    return multiprocessing.get_context("spawn").Pool(processes, **pool_options())
