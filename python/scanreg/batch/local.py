"""The ``local`` engine: worker processes on this machine, each running one job at a time.

Not :class:`concurrent.futures.ProcessPoolExecutor`: when one of its workers dies it fails
every pending call (``BrokenProcessPool``) without saying whose worker died. Here each worker
has its own pipe, so a death is charged to the one job it was running, which is retried on a
fresh worker while the others go on.

Workers are started with ``spawn``: a forked child would inherit the parent's thread pool in a
broken state (its threads do not survive ``fork``), and each worker must size its own pool.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import traceback
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from multiprocessing.connection import Connection, wait
from typing import Any

from .engines import Outcome, available_cpus


def _serve(conn: Connection) -> None:
    """A worker's loop: receive ``(index, fn, args)``, send ``(index, fn(*args))``."""
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        index, fn, args = msg
        try:
            out = fn(*args)
        except Exception as exc:  # fn records job errors itself: this is the engine's own
            out = {
                "status": "failed",
                "error": f"{type(exc).__name__}: {exc}",
                "traceback": traceback.format_exc(),
            }
        conn.send((index, out))


#: Thread counts a worker's libraries read when they load: numpy's BLAS starts one thread
#: per core by default (before the job runs), the core's pool reads RAYON_NUM_THREADS.
_THREAD_VARIABLES = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "RAYON_NUM_THREADS",
)


class _Worker:
    def __init__(self, ctx: Any, threads: int) -> None:
        self.conn, child = ctx.Pipe(duplex=True)
        self.process = ctx.Process(target=_serve, args=(child,), daemon=True)
        # the child copies this process's environment when it starts
        saved = {k: os.environ.get(k) for k in _THREAD_VARIABLES}
        os.environ.update({k: str(threads) for k in _THREAD_VARIABLES})
        try:
            self.process.start()
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        child.close()
        self.index: int | None = None  # the call it runs

    def stop(self) -> None:
        with contextlib.suppress(OSError, ValueError):  # already gone
            self.conn.send(None)
        self.process.join(timeout=5)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()
        self.conn.close()


class LocalEngine:
    """Worker processes on this machine (see the module docstring)."""

    name = "local"

    def __init__(self, *, workers: int | None = None, threads_per_job: int | None = None) -> None:
        cpus = available_cpus()
        self._workers = workers if workers is not None else cpus
        self._threads = (
            threads_per_job if threads_per_job is not None else max(1, cpus // self._workers)
        )
        self._ctx = mp.get_context("spawn")
        self._pool: list[_Worker] = []

    @property
    def slots(self) -> int:
        return self._workers

    @property
    def threads_per_job(self) -> int:
        return self._threads

    def run(
        self,
        fn: Callable[..., dict[str, Any]],
        calls: Sequence[tuple[Any, ...]],
        *,
        retries: int,
        on_start: Callable[[int], None] = lambda i: None,
    ) -> Iterator[Outcome]:
        pending = deque(range(len(calls)))
        attempts = [0] * len(calls)
        lost: list[list[str]] = [[] for _ in calls]
        # workers an earlier run started wait for work (one that died meanwhile is dropped)
        for worker in [w for w in self._pool if not w.process.is_alive()]:
            self._pool.remove(worker)
            worker.conn.close()
        idle: list[_Worker] = list(self._pool)
        busy: list[_Worker] = []
        try:
            while pending or busy:
                while pending and (idle or len(self._pool) < self._workers):
                    if idle:
                        worker = idle.pop()
                    else:
                        worker = _Worker(self._ctx, self._threads)
                        self._pool.append(worker)
                    i = pending.popleft()
                    attempts[i] += 1
                    worker.index = i
                    worker.conn.send((i, fn, calls[i]))
                    busy.append(worker)
                    on_start(i)
                ready = set(wait([w.conn for w in busy] + [w.process.sentinel for w in busy]))
                for worker in list(busy):
                    assert worker.index is not None
                    i = worker.index
                    message = None
                    if worker.conn in ready or worker.process.sentinel in ready:
                        try:
                            if worker.conn.poll():
                                message = worker.conn.recv()
                        except (EOFError, OSError):
                            message = None
                    if message is not None:
                        busy.remove(worker)
                        worker.index = None
                        idle.append(worker)
                        yield Outcome(i, message[1], attempts[i], tuple(lost[i]))
                    elif worker.process.sentinel in ready:  # died with the call unanswered
                        busy.remove(worker)
                        self._pool.remove(worker)
                        worker.process.join()
                        worker.conn.close()
                        lost[i].append(f"worker died (exit code {worker.process.exitcode})")
                        if attempts[i] <= retries:
                            pending.appendleft(i)
                        else:
                            yield Outcome(i, None, attempts[i], tuple(lost[i]))
        finally:
            if pending or busy:  # interrupted: nothing keeps running behind the caller
                self.close()

    def close(self) -> None:
        pool, self._pool = self._pool, []
        for worker in pool:
            worker.stop()


__all__ = ["LocalEngine"]
