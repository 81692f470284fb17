"""Where a sweep's tasks run: local processes, or a Dask distributed cluster.

Both offer the same four calls to the engine: ``slots`` (how many tasks to keep in flight),
``submit(task)``, ``wait(handles, timeout)`` -> finished ``(handle, result)`` pairs, and
``stop(handles)`` for Ctrl-C. A worker that dies, or a task that raises, gives a *failed* result for
that task; the executor stays usable for the others.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor
from concurrent.futures import wait as wait_futures
from concurrent.futures.process import BrokenProcessPool

from ..errors import GuadalError
from .worker import run_combination, stop_on_terminate

#: environment of local workers: one BLAS/OpenMP thread each, set before numpy is imported
_ONE_THREAD = {name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}


def _init_local_worker(sweep_pid: int) -> None:
    # Ctrl-C reaches the whole process group; only the sweep decides how its workers stop
    # (with SIGTERM, which a running mission turns into an 'interrupted' run directory).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    stop_on_terminate()
    os.environ.update(_ONE_THREAD)
    # the sweep's pid, passed in: read here, it may already be init's when the sweep died during start-up
    threading.Thread(target=_stop_when_orphaned, args=(sweep_pid,), daemon=True).start()
    from .. import mission, runner  # noqa: F401  (paid at start-up, while the sweep is being planned)


def _ready() -> None:
    """A no-op task: submitting one per worker starts them all at once."""


def _stop_when_orphaned(parent: int) -> None:
    """A sweep killed outright leaves no worker behind: its mission stops as on Ctrl-C, then it exits."""
    while os.getppid() == parent:
        time.sleep(1.0)
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(5.0)
    os._exit(1)


def _died(exc: BaseException) -> dict:
    return {"status": "failed", "error": f"the worker running it died ({type(exc).__name__}: {exc})"}


class LocalExecutor:
    """Worker processes on this machine (started fresh, not forked: safe beside threads)."""

    def __init__(self, workers: int):
        self.workers = workers
        # one task waiting in line per worker: a worker that finishes a mission takes the next at
        # once, instead of waiting for the sweep to hear of it, record it and send another
        self.slots = 2 * workers
        self._pool = self._new_pool()
        for _ in range(workers):  # processes start on demand: ask for all of them now
            self._pool.submit(_ready)

    def _new_pool(self) -> ProcessPoolExecutor:
        import multiprocessing

        return ProcessPoolExecutor(
            self.workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_init_local_worker,
            initargs=(os.getpid(),),
        )

    def submit(self, task: dict):
        try:
            return self._pool.submit(run_combination, task)
        except BrokenProcessPool:  # a worker died earlier: the others finished; start afresh
            self._pool.shutdown(wait=False)
            self._pool = self._new_pool()
            return self._pool.submit(run_combination, task)

    def wait(self, handles: list, timeout: float) -> list[tuple]:
        done, _ = wait_futures(handles, timeout=timeout, return_when=FIRST_COMPLETED)
        out = []
        for future in done:
            try:
                out.append((future, future.result()))
            except BrokenProcessPool as exc:
                out.append((future, _died(exc)))
        return out

    def stop(self, handles: list) -> None:
        # SIGTERM: a running mission writes its run directory as 'interrupted' and the worker ends.
        # Bounded waits: a worker stopped mid-read of the task queue must not hold the sweep up.
        # Closing the pool right away lets each worker exit as soon as its mission has returned.
        processes = list(getattr(self._pool, "_processes", {}).values())
        for process in processes:
            if process.is_alive():
                process.terminate()
        self._pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.join(timeout=30)
            if process.is_alive():
                process.kill()
        self._stopped = True

    def close(self) -> None:
        if not getattr(self, "_stopped", False):
            self._pool.shutdown(wait=True)


class DaskExecutor:
    """Tasks on an existing Dask distributed cluster (``guadal[dask]``); one mission per task."""

    def __init__(self, address: str, connect_timeout: float = 10.0):
        try:
            from distributed import Client
        except ImportError as exc:
            raise GuadalError(
                "running a sweep on a Dask cluster needs the dask extra: pip install 'guadal[dask]'."
            ) from exc
        try:
            self.client = Client(address, timeout=connect_timeout, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            raise GuadalError(f"cannot reach the Dask scheduler at '{address}' ({exc}).") from exc
        self.address = address

    @property
    def slots(self) -> int:
        """Threads the cluster has now (workers may join or leave during a sweep), at least 1."""
        return max(1, sum(self.client.nthreads().values()))

    def submit(self, task: dict):
        key = f"guadal-sweep-{task['id']}-attempt{task['attempt']}-{os.getpid()}"
        return self.client.submit(run_combination, task, key=key, pure=False)

    def wait(self, handles: list, timeout: float) -> list[tuple]:
        # polled: distributed's wait() wants a default client, and a sweep sets none (it may be a library call)
        deadline = time.monotonic() + timeout
        while not (done := [f for f in handles if f.done()]) and time.monotonic() < deadline:
            time.sleep(0.02)
        out = []
        for future in done:
            try:
                out.append((future, future.result()))
            except Exception as exc:  # KilledWorker, lost connection, a task that could not even start
                out.append((future, _died(exc)))
        return out

    def stop(self, handles: list) -> None:
        # running tasks finish on their workers (Dask cannot interrupt them); queued ones are dropped
        self.client.cancel(handles)
        self.close()

    def close(self) -> None:
        self.client.close()
