"""The local process pool ends its manager thread when stopped or closed, so the interpreter's exit
hook cannot write to a wake-up pipe the thread is closing (a traceback after a clean error)."""

from __future__ import annotations

import time

from thrsim.data.executor import LocalExecutor


def _running(future) -> None:
    deadline = time.monotonic() + 60.0
    while not future.running() and not future.done() and time.monotonic() < deadline:
        time.sleep(0.05)


def test_a_stopped_pool_has_ended_its_workers_and_its_manager_thread():
    executor = LocalExecutor(workers=1, threads=1)
    future = executor.submit(time.sleep, 120.0)
    _running(future)
    manager = executor._manager_thread()
    assert manager is not None and manager.is_alive()
    started = time.monotonic()
    executor.stop()
    assert not manager.is_alive() and time.monotonic() - started < 30.0  # not the task's two minutes


def test_a_closed_pool_has_ended_its_manager_thread():
    executor = LocalExecutor(workers=1, threads=1)
    assert executor.submit(abs, -3).result(timeout=60.0) == 3
    manager = executor._manager_thread()
    executor.close(cancel=True)
    assert manager is not None and not manager.is_alive()
