"""Worker processes that never outlive their parent.

A ``ProcessPoolExecutor`` worker whose parent is killed with SIGKILL (an out-of-memory kill, a
``kill -9``, a cluster's pre-emption) is re-parented to init and waits forever on a pipe nobody
writes to. :func:`worker_pool` starts workers that watch their parent and exit as soon as it is gone,
so a killed ``areasearch eval`` or ``areasearch train`` leaves no stray process behind.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor


def _watch_parent(parent: int, period_s: float) -> None:
    while True:
        time.sleep(period_s)
        if os.getppid() != parent:
            os._exit(1)


def _start_watch(parent: int, period_s: float = 0.5) -> None:
    """Initializer of a worker: a daemon thread that ends the process when ``parent`` is gone."""
    threading.Thread(target=_watch_parent, args=(parent, period_s), daemon=True, name="watch-parent").start()


def worker_pool(workers: int) -> ProcessPoolExecutor:
    """``workers`` spawned processes that exit when this process dies."""
    return ProcessPoolExecutor(
        max_workers=workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_start_watch,
        initargs=(os.getpid(),),
    )
