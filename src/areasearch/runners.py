"""Where work runs: one small interface with three implementations, chosen once at the edge.

The training rollouts, the sharded PPO update and the evaluation harness all hand out tasks
(``fn(*args)``, ``fn`` a module-level function) and read the results back in order. A
:class:`Runner` does that:

* :class:`InProcess`: here, one task after the other (``--workers 0``, or one worker).
* :class:`ProcessPool`: in spawned worker processes that exit as soon as their parent is gone, so a
  killed ``areasearch eval`` or ``areasearch train`` (SIGKILL, an out-of-memory kill, a cluster's
  pre-emption) leaves no stray process waiting on a pipe nobody writes to.
* :class:`RayRunner`: as Ray tasks of one CPU each, on a local Ray instance or on a cluster.

:func:`make_runner` picks one from the command line's ``--backend`` / ``--workers`` / ``--address``;
nothing below the edge branches on a backend's name. Results come back in task order whatever the
runner, so an outcome never depends on where it was computed.

Large read-only arrays that many tasks need (the iteration's graphs in a sharded update) travel once
through :meth:`Runner.share`; a task resolves the handle it receives with :func:`shared`.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import shutil
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures import as_completed as completed_futures
from pathlib import Path
from typing import Any, Protocol, cast

import numpy as np

from .errors import AreaSearchError, ConfigError

BACKENDS = ("local", "ray")
"""The values of ``--backend``: ``local`` (this process or a process pool, by ``--workers``) and ``ray``."""


class Runner(Protocol):
    """Runs tasks ``fn(*args)``; every result comes back in the order of its task."""

    workers: int
    """How many tasks run at once (1 in this process)."""

    def imap(self, fn: Callable[..., Any], tasks: Iterable[tuple[Any, ...]]) -> Iterator[Any]:
        """``fn(*args)`` for each of ``tasks``, yielded in order, each as soon as it and those before it
        are done. Closing the iterator early cancels the tasks not yet started."""
        ...

    def as_completed(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> Iterator[tuple[int, Any]]:
        """``(i, fn(*tasks[i]))`` for each task, yielded as each is done (in this process: in order), so
        that the caller can use a result while the others still run. Closing the iterator early cancels
        the tasks not yet started."""
        ...

    def call(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> list[Any]:
        """``fn(*args)`` for each of ``tasks``; the results in order."""
        ...

    def put(self, value: Any) -> Any:
        """``value`` as an argument for many tasks: sent once (Ray's object store) or as it is."""
        ...

    def share(self, arrays: dict[str, np.ndarray]) -> contextlib.AbstractContextManager[Any]:
        """A handle to ``arrays`` that tasks resolve with :func:`shared`, valid inside the ``with``
        block: sent once instead of once per task."""
        ...

    def close(self) -> None:
        """Stop the workers (a runner that started Ray shuts it down)."""
        ...


class InProcess:
    """A :class:`Runner` in this process, one task after the other."""

    workers = 1

    def imap(self, fn: Callable[..., Any], tasks: Iterable[tuple[Any, ...]]) -> Iterator[Any]:
        for args in tasks:
            yield fn(*args)

    def as_completed(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> Iterator[tuple[int, Any]]:
        for i, args in enumerate(tasks):
            yield i, fn(*args)

    def call(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> list[Any]:
        return [fn(*args) for args in tasks]

    def put(self, value: Any) -> Any:
        return value

    @contextlib.contextmanager
    def share(self, arrays: dict[str, np.ndarray]) -> Iterator[Any]:
        yield arrays

    def close(self) -> None:
        pass


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


class ProcessPool:
    """A :class:`Runner` on ``workers`` spawned processes (:func:`worker_pool`), started on first use."""

    def __init__(self, workers: int) -> None:
        if workers < 1:
            raise ConfigError(f"a process pool needs at least one worker, got {workers}")
        self.workers = workers
        self._pool: ProcessPoolExecutor | None = None

    def _executor(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._pool = worker_pool(self.workers)
        return self._pool

    def imap(self, fn: Callable[..., Any], tasks: Iterable[tuple[Any, ...]]) -> Iterator[Any]:
        pool = self._executor()
        futures: list[Future[Any]] = []
        try:
            futures = [pool.submit(fn, *args) for args in tasks]
            for future in futures:
                yield future.result()
        finally:
            for future in futures:
                future.cancel()

    def as_completed(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> Iterator[tuple[int, Any]]:
        pool = self._executor()
        futures: dict[Future[Any], int] = {}
        try:
            futures = {pool.submit(fn, *args): i for i, args in enumerate(tasks)}
            for future in completed_futures(futures):
                yield futures[future], future.result()
        finally:
            for future in futures:
                future.cancel()

    def call(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> list[Any]:
        return list(self.imap(fn, tasks))

    def put(self, value: Any) -> Any:
        return value

    @contextlib.contextmanager
    def share(self, arrays: dict[str, np.ndarray]) -> Iterator[Any]:
        """``.npy`` files in a temporary folder (in ``/dev/shm`` where it has room) that each worker maps
        once, removed at the end of the block. (Pipes would carry the same megabytes once per task.)"""
        nbytes = sum(a.nbytes for a in arrays.values())
        folder = Path(tempfile.mkdtemp(prefix="areasearch-share-", dir=_shared_memory_dir(nbytes)))
        try:
            for name, array in arrays.items():
                np.save(folder / f"{name}.npy", array, allow_pickle=False)
            yield str(folder)
        finally:
            shutil.rmtree(folder, ignore_errors=True)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


class RayRunner:
    """A :class:`Runner` of Ray tasks (one CPU each): on a local Ray instance of ``workers`` CPUs, or on
    the cluster at ``address``. A Ray instance already running in this process is used as it is; a
    Ray started here is shut down by :meth:`close`."""

    def __init__(self, workers: int, address: str | None = None) -> None:
        try:
            import ray
        except ImportError:
            raise ConfigError("--backend ray needs Ray: pip install 'areasearch[ray]'") from None
        self.workers = max(1, workers)
        self._ray = ray
        self._remote: dict[Callable[..., Any], Any] = {}
        self._started = not ray.is_initialized()
        if self._started:
            try:
                if address:
                    ray.init(address=address, log_to_driver=False, logging_level=logging.ERROR)
                else:
                    ray.init(
                        num_cpus=self.workers, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR
                    )
            except (ConnectionError, RuntimeError, ValueError, TimeoutError) as exc:
                where = f"the Ray cluster at {address}" if address else "a local Ray instance"
                raise AreaSearchError(f"cannot start or reach {where}: {' '.join(str(exc).split())}") from None

    def _remote_of(self, fn: Callable[..., Any]) -> Any:
        remote = self._remote.get(fn)
        if remote is None:
            remote = self._remote[fn] = self._ray.remote(num_cpus=1)(fn)
        return remote

    def imap(self, fn: Callable[..., Any], tasks: Iterable[tuple[Any, ...]]) -> Iterator[Any]:
        remote = self._remote_of(fn)
        refs: list[Any] = []
        fetched = 0
        try:
            refs = [remote.remote(*args) for args in tasks]
            for ref in refs:
                yield self._ray.get(ref)
                fetched += 1
        finally:
            for ref in refs[fetched:]:
                self._ray.cancel(ref)

    def as_completed(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> Iterator[tuple[int, Any]]:
        remote = self._remote_of(fn)
        pending: dict[Any, int] = {}
        try:
            pending = {remote.remote(*args): i for i, args in enumerate(tasks)}
            while pending:
                (ref,), _ = self._ray.wait(list(pending), num_returns=1)
                yield pending.pop(ref), self._ray.get(ref)
        finally:
            for ref in pending:
                self._ray.cancel(ref)

    def call(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> list[Any]:
        remote = self._remote_of(fn)
        return list(self._ray.get([remote.remote(*args) for args in tasks]))

    def put(self, value: Any) -> Any:
        return self._ray.put(value)

    @contextlib.contextmanager
    def share(self, arrays: dict[str, np.ndarray]) -> Iterator[Any]:
        yield self._ray.put(arrays)

    def close(self) -> None:
        if self._started and self._ray.is_initialized():
            self._ray.shutdown()


def make_runner(backend: str, workers: int, address: str | None = None) -> Runner:
    """The runner of ``--backend`` and ``--workers``: ``ray`` (with ``address``, a cluster), or for
    ``local`` a process pool of ``workers`` processes when ``workers`` > 1 and this process
    otherwise."""
    if backend == "ray":
        return RayRunner(workers, address)
    if backend != "local":
        raise ConfigError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    return ProcessPool(workers) if workers > 1 else InProcess()


_SHARED: dict[str, Any] = {}


def shared(handle: Any) -> Mapping[str, np.ndarray]:
    """The arrays behind a handle of :meth:`Runner.share` (in a worker process: a folder of ``.npy``
    files, mapped copy-on-write and kept for the next task with the same handle; in Ray or this
    process: the arrays themselves)."""
    if not isinstance(handle, str):
        return cast(Mapping[str, np.ndarray], handle)
    cached = _SHARED.get("arrays")
    if cached is None or cached[0] != handle:
        arrays = {p.stem: np.load(p, mmap_mode="c", allow_pickle=False) for p in sorted(Path(handle).glob("*.npy"))}
        cached = _SHARED["arrays"] = (handle, arrays)
    return cast(Mapping[str, np.ndarray], cached[1])


def _shared_memory_dir(nbytes: int) -> str | None:
    """Where :meth:`ProcessPool.share` writes ``nbytes``: the RAM-backed ``/dev/shm`` where there is one
    with room to spare (a container's is often 64 MB), else the temporary folder (its pages stay in
    the page cache all the same)."""
    shm = Path("/dev/shm")
    try:
        room = shm.is_dir() and os.access(shm, os.W_OK) and shutil.disk_usage(shm).free > 2 * nbytes + (64 << 20)
    except OSError:
        room = False
    return str(shm) if room else None
