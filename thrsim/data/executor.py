"""One executor interface for a laptop and a cluster: a local process pool or a Dask scheduler.

Both run the same task function (:func:`thrsim.data.generate.run_one_case`) and hand back
futures with ``.result()``; :meth:`Executor.as_completed` yields them as they finish. Local
(:class:`LocalExecutor`): spawned worker processes that die with their parent, whose pool the
caller restarts when a worker is killed mid-case. Dask (``--scheduler tcp://HOST:PORT``,
:class:`DaskExecutor`): every worker needs the same thrsim and sees the output folder at the
same path; the client fails fast when the scheduler is unreachable, and Dask reschedules a task
whose worker died. Read :data:`DASK_SECURITY` (appended below) before starting a scheduler
anywhere but loopback.
"""

from __future__ import annotations

import concurrent.futures as cf
import ctypes
import multiprocessing
import os
import signal
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any, Protocol

from thrsim.errors import ThrsimInputError

#: how to keep a Dask scheduler private; part of this module's and ``thrsim dataset``'s help
DASK_SECURITY = """
Security: a Dask scheduler has no authentication of its own, and its tasks are pickled
functions, so anyone who reaches its port can run code on every worker. Never listen on
``0.0.0.0`` on a network you do not control. On one machine keep it on loopback
(``--host 127.0.0.1``); across machines bind it to a private interface that only the cluster
reaches, or keep it on loopback and reach it through an SSH tunnel
(``ssh -N -L 8786:127.0.0.1:8786 HEAD``, then ``--scheduler tcp://127.0.0.1:8786``); on a
shared network use Dask's TLS: ``dask scheduler --protocol tls --tls-ca-file ca.pem --tls-cert
scheduler.pem --tls-key scheduler.key``, workers with ``tls://HEAD:8786`` and their own
``--tls-*`` files, and thrsim with ``--scheduler tls://HEAD:8786`` and the client's certificate
in Dask's configuration (``DASK_DISTRIBUTED__COMM__TLS__CA_FILE``,
``DASK_DISTRIBUTED__COMM__TLS__CLIENT__CERT``, ``DASK_DISTRIBUTED__COMM__TLS__CLIENT__KEY``,
``DASK_DISTRIBUTED__COMM__REQUIRE_ENCRYPTION=True``).
"""
__doc__ = f"{__doc__}\n{DASK_SECURITY}"

_THREAD_VARS = ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


class Executor(Protocol):
    workers: int
    description: str

    def submit(self, fn: Callable, *args: Any, key: str | None = None) -> Any: ...

    def as_completed(self, futures: Iterable[Any]) -> Iterator[Any]: ...

    def close(self, cancel: bool = False) -> None: ...

    def stop(self) -> None: ...

    def restart(self) -> None: ...


def is_worker_lost(error: BaseException) -> bool:
    """True when the error means the process running the task died (not that the task failed)."""
    if isinstance(error, cf.process.BrokenProcessPool):
        return True
    name = type(error).__name__
    return name in ("KilledWorker", "CommClosedError")


def cap_numerical_threads(threads: int) -> None:
    """Use at most ``threads`` numerical threads in this process (numba's are per Python thread,
    so this also works inside a Dask worker). Once Numba's threading layer has started
    (:func:`thrsim.cache.use_numba_cache` starts it on import), its pool is capped at run time
    only: a changed ``NUMBA_NUM_THREADS`` would make Numba's next compilation fail ("Cannot set
    NUMBA_NUM_THREADS ... once the threads have been launched")."""
    for var in _THREAD_VARS:
        if var != "NUMBA_NUM_THREADS" or "numba" not in sys.modules:
            os.environ[var] = str(threads)
    if "numba" in sys.modules:
        import numba

        numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))


def _worker_init(threads: int) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole process group: the parent decides
    cap_numerical_threads(threads)
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL("libc.so.6", use_errno=True)
            libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG: die with the parent
            if os.getppid() == 1:  # the parent already died before prctl took effect
                os._exit(1)
        except OSError:
            pass


#: the longest a closing local pool waits for its manager thread to end (s; it ends once its workers have)
MANAGER_JOIN_S = 10.0


class LocalExecutor:
    """A process pool on this machine: ``concurrent.futures.ProcessPoolExecutor`` with the ``spawn``
    start method. Each worker limits its numerical threads to ``threads`` (default cores ÷ workers) and, on Linux, asks
    the kernel to kill it when the parent dies (``PR_SET_PDEATHSIG``), so a ``kill -9`` of the
    parent leaves no orphan solver running. A worker killed mid-case breaks the pool; the caller
    restarts it (:meth:`restart`) and resubmits the cases in flight. Workers ignore Ctrl-C (the
    terminal sends it to them too): the caller decides, and :meth:`stop` ends them at once."""

    def __init__(self, workers: int = 1, threads: int | None = None):
        if workers < 1:
            raise ThrsimInputError(f"must be at least 1, got {workers}", "workers")
        self.workers = workers
        cores = os.cpu_count() or 1
        self.threads_per_worker = threads or max(1, cores // workers)
        self.description = f"local process pool, {workers} worker(s) × {self.threads_per_worker} thread(s)"
        self._pool = self._new_pool()

    def _new_pool(self) -> cf.ProcessPoolExecutor:
        return cf.ProcessPoolExecutor(
            max_workers=self.workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_worker_init,
            initargs=(self.threads_per_worker,),
        )

    def submit(self, fn: Callable, *args: Any, key: str | None = None) -> cf.Future:
        return self._pool.submit(fn, *args)

    def as_completed(self, futures: Iterable[cf.Future]) -> Iterator[cf.Future]:
        return cf.as_completed(list(futures))

    def restart(self) -> None:
        """Replace a broken pool (a worker died) by a fresh one."""
        self._pool.shutdown(wait=False, cancel_futures=True)
        self._pool = self._new_pool()

    def close(self, cancel: bool = False) -> None:
        manager = self._manager_thread()
        self._pool.shutdown(wait=not cancel, cancel_futures=cancel)
        if manager is not None:
            manager.join(MANAGER_JOIN_S)

    def _manager_thread(self) -> Any:
        """The pool's manager thread, which a shutdown without waiting leaves running: joined before
        the interpreter exits, where Python 3.11's exit hook can write to its wake-up pipe while it
        closes it ("Bad file descriptor" printed after a clean error)."""
        return getattr(self._pool, "_executor_manager_thread", None)

    def stop(self, grace_s: float = 1.0) -> None:
        """Cancel the queued tasks and end the running ones now: their workers are terminated.

        A pool's shutdown waits for the running tasks (a solver case: minutes); the pool has no
        public way to end them, so its worker processes are terminated (killed after ``grace_s``).
        The pool is broken afterwards: :meth:`restart` makes a new one.
        """
        manager = self._manager_thread()
        processes = list((getattr(self._pool, "_processes", None) or {}).values())
        self._pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.terminate()
        deadline = time.monotonic() + grace_s
        for process in processes:
            process.join(max(0.0, deadline - time.monotonic()))
            if process.is_alive():
                process.kill()
                process.join(1.0)
        if manager is not None:
            manager.join(MANAGER_JOIN_S)


class DaskExecutor:
    """Tasks on a Dask distributed scheduler (one task per case). Start a scheduler and workers, e.g.::

        dask scheduler --host 10.0.0.1 --port 8786             # the head node's private interface
        dask worker tcp://10.0.0.1:8786 --nworkers 4 --nthreads 1   # on every compute node

    Workers write the case files and the client the manifest, so the output folder must be on a
    file system every worker sees at the same path."""

    def __init__(self, address: str, *, connect_timeout_s: float = 5.0, worker_wait_s: float = 60.0):
        if "://" not in address:
            address = f"tcp://{address}"
        scheme, _, rest = address.partition("://")
        if scheme not in ("tcp", "tls", "inproc", "ucx", "ws", "wss") or ":" not in rest:
            raise ThrsimInputError(f"must look like tcp://HOST:PORT, got {address!r}", "scheduler")
        try:
            from distributed import Client
        except ImportError:  # pragma: no cover - dask[distributed] is a dependency
            raise ThrsimInputError("needs dask[distributed] installed", "scheduler") from None
        import dask

        try:
            with dask.config.set({"distributed.comm.timeouts.connect": f"{connect_timeout_s}s"}):
                self._client = Client(address, timeout=f"{connect_timeout_s}s", set_as_default=False)
        except (OSError, TimeoutError) as error:
            reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
            raise ThrsimInputError(
                f"cannot reach the Dask scheduler at {address} within {connect_timeout_s:g} s ({reason[:160]})"
            ) from None
        try:
            self._client.wait_for_workers(1, timeout=worker_wait_s)
        except (TimeoutError, OSError):
            self._client.close()
            raise ThrsimInputError(f"the Dask scheduler at {address} has no workers (waited {worker_wait_s:g} s)") from None
        self.address = address
        self._futures: list[Any] = []
        self.workers = max(1, len(self._client.scheduler_info().get("workers", {})))
        self.description = f"Dask scheduler {address}, {self.workers} worker(s)"

    def submit(self, fn: Callable, *args: Any, key: str | None = None) -> Any:
        kwargs: dict[str, Any] = {"pure": False}
        if key is not None:
            import uuid

            kwargs["key"] = f"{key}-{uuid.uuid4().hex[:8]}"
        future = self._client.submit(fn, *args, **kwargs)
        self._futures.append(future)
        return future

    def as_completed(self, futures: Iterable[Any]) -> Iterator[Any]:
        from distributed import as_completed

        with self._client.as_current():
            completed = as_completed(list(futures))
        while True:
            with self._client.as_current():
                try:
                    future = next(completed)
                except StopIteration:
                    return
            yield future

    def restart(self) -> None:  # Dask reschedules lost tasks itself
        pass

    def stop(self) -> None:
        """Cancel every task of this client, running ones included."""
        try:
            self._client.cancel([f for f in self._futures if not f.done()], force=True)
        except Exception:  # noqa: BLE001 - a scheduler that went away runs nothing of ours
            pass

    def close(self, cancel: bool = False) -> None:
        try:
            self._client.close(timeout=5)
        except Exception:  # noqa: BLE001 - closing a client whose scheduler went away
            pass


def make_executor(workers: int = 1, scheduler: str | None = None, connect_timeout_s: float = 5.0, threads: int | None = None) -> Executor:
    """A Dask executor on ``scheduler``, else a local pool of ``workers`` with ``threads`` each (default cores ÷ workers)."""
    if scheduler:
        return DaskExecutor(scheduler, connect_timeout_s=connect_timeout_s)
    return LocalExecutor(workers, threads)
