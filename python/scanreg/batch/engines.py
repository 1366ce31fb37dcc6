"""The engine protocol: what runs a batch's calls on workers, and the factory by name.

An engine runs ``fn(*args)`` for each call on its workers (``fn`` is
:func:`scanreg.batch.jobs.execute`, which never raises for a job's own error) and yields an
:class:`Outcome` per call as it finishes, in any order. A call whose worker died (killed,
out of memory, ``os._exit``) is retried up to ``retries`` times, then reported lost. Engines:

* ``"local"`` (:class:`~scanreg.batch.local.LocalEngine`): worker processes on this machine;
  no extra dependency.
* ``"ray"`` (:class:`~scanreg.batch.ray_engine.RayEngine`): tasks on a Ray cluster (a running
  one by address, or a local one it starts); ``pip install 'scanreg[ray]'``.

Each engine knows how many jobs run at once (``slots``) and how many threads each may use
(``threads_per_job``, passed to the job, which sizes the core's pool to it before any work).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

ENGINES: tuple[str, ...] = ("local", "ray")


@dataclass(frozen=True)
class Outcome:
    """One call's end."""

    #: Position of the call in the sequence given to :meth:`Engine.run`.
    index: int
    #: What the call returned, or None when every attempt lost its worker.
    record: dict[str, Any] | None
    #: Attempts made (1 + retries used).
    attempts: int
    #: Why each lost attempt was lost (``"worker died (exit code 1)"``).
    lost: tuple[str, ...] = field(default=())


class Engine(Protocol):
    """What :func:`scanreg.batch.run_batch` needs of an engine."""

    name: str

    @property
    def slots(self) -> int:
        """Jobs that run at once."""

    @property
    def threads_per_job(self) -> int:
        """Threads each job may use."""

    def run(
        self,
        fn: Callable[..., dict[str, Any]],
        calls: Sequence[tuple[Any, ...]],
        *,
        retries: int,
        on_start: Callable[[int], None] = ...,
    ) -> Iterator[Outcome]:
        """``fn(*calls[i])`` for every ``i`` on the workers; an :class:`Outcome` per call as
        it ends. ``on_start(i)`` when call ``i`` is handed to a worker."""

    def close(self) -> None:
        """Stop the workers (and a cluster the engine started)."""


def available_cpus() -> int:
    """CPUs this process may run on (its affinity mask, else the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not Linux
        return os.cpu_count() or 1


def check_count(value: int | None, name: str) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{name}: expected an int, got {type(value).__name__}")
    if value < 1:
        raise ValueError(f"{name}: must be >= 1, got {value}")
    return value


def make_engine(
    engine: str = "local",
    *,
    workers: int | None = None,
    threads_per_job: int | None = None,
    address: str | None = None,
) -> Engine:
    """The engine named ``engine`` (``"local"`` or ``"ray"``).

    ``workers``: local worker processes (default: one per CPU) or, for a Ray cluster this
    engine starts, its CPUs; ``threads_per_job``: threads each job may use (default: the CPUs
    divided among the workers, at least 1; on Ray, 1 — one CPU per task); ``address``: a
    running Ray cluster (``host:port`` or ``auto``), Ray only.
    """
    workers = check_count(workers, "workers")
    threads_per_job = check_count(threads_per_job, "threads_per_job")
    if engine == "local":
        if address is not None:
            raise ValueError("address: only the ray engine connects to a cluster")
        from .local import LocalEngine

        return LocalEngine(workers=workers, threads_per_job=threads_per_job)
    if engine == "ray":
        from .ray_engine import RayEngine

        return RayEngine(address=address, workers=workers, threads_per_job=threads_per_job)
    raise ValueError(f"engine: unknown {engine!r} (known: {', '.join(ENGINES)})")


__all__ = ["ENGINES", "Engine", "Outcome", "available_cpus", "make_engine"]
