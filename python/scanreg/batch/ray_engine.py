"""The ``ray`` engine: each job a Ray task on a cluster (``pip install 'scanreg[ray]'``).

Connects to a running cluster by ``address`` (``host:port`` of its head, or ``"auto"``), or
starts a local one with ``workers`` CPUs (stopped by :meth:`RayEngine.close`). Each task asks
for ``threads_per_job`` CPUs and the job sizes the core's thread pool to exactly that, so a
node runs as many jobs as it has CPUs to give, none oversubscribing it.

Ray's own task retries are off (``max_retries=0``): a task whose worker died is resubmitted
here, so every engine counts attempts the same way. A job's own exception is caught inside the
task (:func:`scanreg.batch.jobs.execute`) and recorded, not retried: the code and the input are
deterministic, a second attempt would fail the same way.

Every node needs scanreg (the same version) in the Python environment its Ray workers use.
"""

from __future__ import annotations

import socket
import sys
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from .engines import Outcome, available_cpus

_CONNECT_TIMEOUT = 5.0
_LOOPBACK = "127.0.0.2"


def import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ImportError(
            "engine 'ray' needs Ray: pip install 'scanreg[ray]' (or use --engine local)"
        ) from None
    return ray


def check_address(address: str) -> None:
    """Fail fast, naming ``address``, when no Ray head answers there (Ray itself would retry
    for a minute before giving up)."""
    if address in ("auto", "local") or address.startswith("ray://"):
        return
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ValueError(f"address: expected HOST:PORT of a Ray head (or 'auto'), got {address!r}")
    try:
        with socket.create_connection((host, int(port)), timeout=_CONNECT_TIMEOUT):
            pass
    except OSError as exc:
        raise ConnectionError(
            f"address {address}: no Ray cluster answers there ({exc.strerror or exc}); start one "
            f"with `ray start --head --port {port}` or check the address"
        ) from None


def _call(fn: Callable[..., dict[str, Any]], args: tuple[Any, ...]) -> dict[str, Any]:
    return fn(*args)


class RayEngine:
    """Jobs as Ray tasks (see the module docstring)."""

    name = "ray"

    def __init__(
        self,
        *,
        address: str | None = None,
        workers: int | None = None,
        threads_per_job: int | None = None,
    ) -> None:
        ray = import_ray()
        if address is not None:
            if workers is not None:
                raise ValueError("workers: sets the CPUs of a local Ray cluster, not of --address")
            check_address(address)
        self._ray = ray
        self._threads = 1 if threads_per_job is None else threads_per_job
        self._started = False
        if not ray.is_initialized():
            if address is None:
                # A private cluster, reachable from this machine only. Ray replaces 127.0.0.1
                # by the machine's network address; another loopback address (all of 127/8
                # on Linux) stays on loopback.
                loopback = {"_node_ip_address": _LOOPBACK} if sys.platform == "linux" else {}
                ray.init(
                    num_cpus=workers if workers is not None else available_cpus(),
                    include_dashboard=False,
                    log_to_driver=False,
                    **loopback,
                )
            else:
                options: dict[str, Any] = {}
                host = address.rpartition(":")[0]
                if host.startswith("127."):  # a cluster on loopback: this driver is on its node
                    options["_node_ip_address"] = host
                ray.init(address=address, log_to_driver=False, **options)
            self._started = True
        cpus = int(ray.cluster_resources().get("CPU", 1))
        if self._threads > cpus:
            raise ValueError(
                f"threads_per_job: {self._threads} is more than the cluster's {cpus} CPUs"
            )
        self._slots = max(1, cpus // self._threads)
        self._remote = ray.remote(_call).options(num_cpus=self._threads, max_retries=0)

    @property
    def slots(self) -> int:
        return self._slots

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
        ray = self._ray
        pending = deque(range(len(calls)))
        attempts = [0] * len(calls)
        lost: list[list[str]] = [[] for _ in calls]
        running: dict[Any, int] = {}
        try:
            while pending or running:
                # at most one task per free slot in flight: retries go first, and "running"
                # means running
                while pending and len(running) < self._slots:
                    i = pending.popleft()
                    attempts[i] += 1
                    running[self._remote.remote(fn, calls[i])] = i
                    on_start(i)
                done, _ = ray.wait(list(running), num_returns=1)
                for ref in done:
                    i = running.pop(ref)
                    try:
                        record = ray.get(ref)
                    except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError) as exc:
                        lost[i].append(f"worker died ({type(exc).__name__})")
                        if attempts[i] <= retries:
                            pending.appendleft(i)
                        else:
                            yield Outcome(i, None, attempts[i], tuple(lost[i]))
                        continue
                    except ray.exceptions.RayError as exc:  # not the job's error: Ray's
                        record = {
                            "status": "failed",
                            "error": f"{type(exc).__name__}: {str(exc).splitlines()[0]}",
                            "traceback": str(exc),
                        }
                    yield Outcome(i, record, attempts[i], tuple(lost[i]))
        finally:
            for ref in running:
                ray.cancel(ref, force=True)

    def close(self) -> None:
        if self._started and self._ray.is_initialized():
            self._ray.shutdown()
        self._started = False


__all__ = ["RayEngine", "check_address", "import_ray"]
