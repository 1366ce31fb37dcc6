"""The 2D mapper's odometry in a process of its own.

:func:`~scanreg.pipeline.run_mapping` runs the odometry of the next scans
(:meth:`Mapper.track`) beside the graph (:meth:`Mapper.integrate`). On two threads they share
one interpreter lock: their Python and gtsam's calls (which hold it) take turns, and on a
quiet 2-core machine the two threads overlapped for ~6 s of a 47–53 s Intel run. In a child
process each has an interpreter: the child tracks every scan of the log in order and streams
each :class:`~scanreg.pipeline.mapping.Tracked` back with what tracking recorded on its
:class:`Mapper` (:meth:`Mapper.odometry_since`), which the parent's mapper adopts before it
integrates the scan — the same poses, to the bit, as the threads give.

The child is a fresh interpreter (``python -c``, not ``fork``: a fork would inherit the
core's thread pool without its threads), started from the same ``scanreg`` package as the
parent, fed the scans, the configuration and the core's thread budget through its stdin,
answering on its stdout. It ignores Ctrl-C (the parent stops it and keeps what was mapped)
and exits when its input closes; an error in it is raised in the parent.
"""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
from collections import deque
from multiprocessing.connection import Connection
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..threads import get_num_threads

if TYPE_CHECKING:
    from ..io.scan_log import ScanLog
    from .mapping import Mapper, MappingConfig, Tracked

#: The child's bootstrap: the parent's ``scanreg`` first on its path, then serve.
_BOOT = (
    "import sys; sys.path.insert(0, sys.argv[1]); "
    "from scanreg.pipeline.odometry_process import serve; serve()"
)
#: Scans the child sends at once: each message wakes the parent, which on a busy machine
#: waits for a time slice each time.
_BATCH = 8
#: A pipe holds this many bytes before the child waits for the parent to read (Linux; the
#: default 64 kB is ~10 scans: the child would stall whenever a loop search runs long).
_PIPE_BYTES = 1 << 20


class OdometryProcessError(RuntimeError):
    """The odometry's process stopped without an answer (it died, or its error could not
    be carried back)."""


def available() -> bool:
    """Whether this platform runs the odometry in a child process (POSIX pipes, an
    interpreter to start)."""
    return os.name == "posix" and bool(sys.executable)


class OdometryProcess:
    """The odometry of ``scans`` (every scan, in order) under ``config``, in a child process;
    :meth:`next` hands its scans to a parent :class:`Mapper` one by one."""

    def __init__(self, scans: ScanLog, config: MappingConfig) -> None:
        from ..io.scan_log import ScanLog
        from .mapping import MappingConfig

        # Refused here, by name: in the child a wrong argument would fail only at its first scan.
        if not isinstance(scans, ScanLog):
            raise TypeError(f"scans: expected a ScanLog, got {type(scans).__name__}")
        if not isinstance(config, MappingConfig):
            raise TypeError(f"config: expected a MappingConfig, got {type(config).__name__}")
        package = Path(__file__).resolve().parents[2]
        self._proc = subprocess.Popen(
            [sys.executable, "-c", _BOOT, str(package)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
        )
        assert self._proc.stdin is not None and self._proc.stdout is not None
        for stream in (self._proc.stdin, self._proc.stdout):
            _widen(stream.fileno())
        self._to = Connection(os.dup(self._proc.stdin.fileno()), readable=False)
        self._from = Connection(os.dup(self._proc.stdout.fileno()), writable=False)
        self._proc.stdin.close()
        self._proc.stdout.close()
        self._scans: deque[tuple[Tracked, Any]] = deque()
        # Pickled while the child starts; sent once it says it runs (an interpreter that
        # cannot import scanreg never does: OdometryProcessError, and the caller uses a
        # thread). The child's core pool as large as ours (a batch worker may have sized ours
        # to one).
        threads = get_num_threads()
        data = pickle.dumps((scans, config, threads), protocol=pickle.HIGHEST_PROTOCOL)
        try:
            if self._receive() != ["ready"]:
                raise OdometryProcessError("odometry process: no handshake")
            self._to.send_bytes(data)
        except BaseException:
            self.close()
            raise

    def next(self, mapper: Mapper) -> Tracked:
        """The next scan's :class:`Tracked`, its odometry's record adopted by ``mapper``."""
        if not self._scans:
            kind, *payload = self._receive()
            if kind != "scans":
                raise OdometryProcessError(f"odometry process: expected scans, got {kind!r}")
            self._scans.extend(payload[0])
        tracked, record = self._scans.popleft()
        mapper.adopt_odometry(record)
        return tracked

    def finish(self, mapper: Mapper) -> None:
        """After the last scan: ``mapper`` adopts the child's wheels as calibrated; the child
        exits."""
        kind, *payload = self._receive()
        if kind != "end":
            raise OdometryProcessError(f"odometry process: expected its end, got {kind!r}")
        mapper.adopt_odometry_end(payload[0])
        self.close()

    def close(self) -> None:
        """Stop the child (if still running) and release the pipes."""
        for conn in (self._to, self._from):
            conn.close()
        if self._proc.poll() is None:
            self._proc.kill()
        self._proc.wait()

    def _receive(self) -> list[Any]:
        try:
            message: list[Any] = self._from.recv()
        except (EOFError, OSError) as exc:
            raise self._died() from exc
        if message[0] == "error":
            raise message[1]
        return message

    def _died(self) -> OdometryProcessError:
        code = self._proc.wait()
        return OdometryProcessError(f"odometry process: stopped without an answer (exit {code})")


def _widen(fd: int) -> None:
    """Let a pipe hold :data:`_PIPE_BYTES` (Linux; elsewhere its default)."""
    try:
        import fcntl

        fcntl.fcntl(fd, getattr(fcntl, "F_SETPIPE_SZ", 1031), _PIPE_BYTES)
    except (ImportError, OSError):
        pass


def serve() -> None:
    """The child: say it runs, read ``(scans, config, threads)`` from stdin, track every scan
    and answer on stdout (eight scans a message, then the end; an error after what was
    tracked)."""
    from ..threads import set_num_threads
    from .mapping import Mapper, track_scan

    # Ctrl-C reaches the whole process group: the parent decides what to keep, then stops us.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    inbox = Connection(os.dup(sys.stdin.fileno()), writable=False)
    outbox = Connection(os.dup(sys.stdout.fileno()), readable=False)
    # Whatever else writes to stdout here (a print, a warning printed by a library) goes to
    # stderr: on stdout it would corrupt the answers.
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    sys.stdout = sys.stderr
    batch: list[tuple[Any, ...]] = []
    try:
        outbox.send(["ready"])
        scans, config, threads = pickle.loads(inbox.recv_bytes())
        set_num_threads(threads)
        mapper = Mapper(config)
        for k in range(len(scans)):
            mark = mapper.odometry_mark()
            tracked = track_scan(mapper, scans, config, k)
            batch.append((tracked, mapper.odometry_since(mark)))
            if len(batch) == _BATCH or k + 1 == len(scans):
                outbox.send(["scans", batch])
                batch = []
        outbox.send(["end", mapper.odometry_end()])
    except (BrokenPipeError, EOFError):
        return  # the parent stopped listening
    except Exception as exc:  # carried back and raised in the parent, after what was tracked
        if batch:
            outbox.send(["scans", batch])
        try:
            outbox.send(["error", exc])
        except Exception:
            outbox.send(["error", OdometryProcessError(f"odometry process: {exc!r}")])


__all__ = ["OdometryProcess", "OdometryProcessError", "available", "serve"]
