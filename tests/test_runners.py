"""Where work runs (:mod:`areasearch.runners`): every runner gives its results in task order (or, with
``as_completed``, as each is done, with its index), shares
arrays once (and removes what it wrote), and :func:`~areasearch.runners.make_runner` picks the runner
of ``--backend`` / ``--workers`` and refuses a backend it does not know."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import time
from collections import namedtuple
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from areasearch.errors import ConfigError
from areasearch.runners import BACKENDS, InProcess, ProcessPool, Runner, make_runner, shared

NO_RAY = "Ray is not installed: pip install 'areasearch[ray]'"
ARRAYS = {"a": np.arange(6, dtype=np.float32).reshape(2, 3), "b": np.array([True, False])}


def _square_after(x: int, delay_s: float) -> tuple[int, int]:
    """(x, x * x), after ``delay_s``: later tasks that finish first must still come back in order."""
    time.sleep(delay_s)
    return x, x * x


def _materialise(handle: Any) -> dict[str, np.ndarray]:
    return {k: np.array(v) for k, v in shared(handle).items()}


def _tasks() -> list[tuple[int, float]]:
    return [(x, 0.2 if x == 0 else 0.0) for x in range(5)]


def _check_order(runner: Runner) -> None:
    expected = [(x, x * x) for x in range(5)]
    assert list(runner.imap(_square_after, _tasks())) == expected
    assert runner.call(_square_after, _tasks()) == expected
    done = list(runner.as_completed(_square_after, _tasks()))  # each task once, with its index
    assert sorted(done) == [(x, (x, x * x)) for x in range(5)]
    if runner.workers > 1:  # task 0 sleeps: the others come back before it
        assert done[-1][0] == 0
    else:
        assert [i for i, _ in done] == list(range(5))


def test_in_process_gives_results_in_order_and_shares_the_arrays_themselves() -> None:
    runner = InProcess()
    _check_order(runner)
    assert runner.workers == 1 and runner.put(ARRAYS) is ARRAYS
    with runner.share(ARRAYS) as handle:
        assert shared(handle) is ARRAYS
        (got,) = runner.call(_materialise, [(handle,)])
    assert all(np.array_equal(got[k], ARRAYS[k]) for k in ARRAYS)
    runner.close()


def test_a_process_pool_gives_results_in_order_and_removes_its_shared_folder() -> None:
    pool = ProcessPool(2)
    try:
        _check_order(pool)
        assert pool.put(ARRAYS) is ARRAYS
        with pool.share(ARRAYS) as handle:
            folder = Path(handle)
            assert sorted(p.name for p in folder.iterdir()) == ["a.npy", "b.npy"]
            got = pool.call(_materialise, [(handle,), (handle,)])
        assert not folder.exists()
    finally:
        pool.close()
    for arrays in got:
        assert arrays.keys() == ARRAYS.keys() and all(np.array_equal(arrays[k], ARRAYS[k]) for k in ARRAYS)


def test_a_process_pool_needs_a_worker() -> None:
    with pytest.raises(ConfigError, match="at least one worker, got 0"):
        ProcessPool(0)


def test_shared_arrays_leave_a_small_dev_shm_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    """A container's /dev/shm is often 64 MB: the arrays go to the temporary folder when it lacks room."""
    usage = namedtuple("usage", "total used free")
    pool = ProcessPool(2)  # share() starts no process
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(64 << 20, 60 << 20, 4 << 20))
    with pool.share(ARRAYS) as handle:
        assert not handle.startswith("/dev/shm/")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(8 << 30, 0, 8 << 30))
    with pool.share(ARRAYS) as handle:
        room = Path("/dev/shm").is_dir() and os.access("/dev/shm", os.W_OK)
        assert handle.startswith("/dev/shm/") == room


def test_make_runner_picks_by_backend_and_workers() -> None:
    assert BACKENDS == ("local", "ray")
    assert isinstance(make_runner("local", 0), InProcess)
    assert isinstance(make_runner("local", 1), InProcess)
    pool = make_runner("local", 3)
    assert isinstance(pool, ProcessPool) and pool.workers == 3
    pool.close()  # never started


@pytest.mark.parametrize("backend", ["thread", "", "Local"])
def test_make_runner_refuses_an_unknown_backend(backend: str) -> None:
    with pytest.raises(ConfigError, match=f"backend must be one of local, ray, got {backend!r}"):
        make_runner(backend, 2)


@pytest.mark.slow
@pytest.mark.skipif(
    importlib.util.find_spec("ray") is None, reason="Ray is not installed (pip install 'areasearch[ray]')"
)
def test_ray_gives_results_in_order_and_shares_through_its_store() -> None:
    """Ray's workers import a task's function by its module, so the tasks here are Python functions of
    installed modules (this test file is not one)."""
    from areasearch.runners import RayRunner

    runner = make_runner("ray", 2)
    try:
        assert isinstance(runner, RayRunner)
        tasks = [([x] * x,) for x in range(5)]
        expected = [json.dumps([x] * x) for x in range(5)]
        assert list(runner.imap(json.dumps, tasks)) == runner.call(json.dumps, tasks) == expected
        assert sorted(runner.as_completed(json.dumps, tasks)) == list(enumerate(expected))
        with runner.share(ARRAYS) as handle:
            (got,) = runner.call(shared, [(handle,)])
        assert got.keys() == ARRAYS.keys() and all(np.array_equal(got[k], ARRAYS[k]) for k in ARRAYS)
    finally:
        runner.close()
