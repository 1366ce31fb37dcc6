"""The process-wide thread budget of the Rust core.

Every parallel loop of the core without a pool of its own (``RegistrationSettings.num_threads``)
runs on one process-wide pool, sized once per process at the first parallel call: by default
one thread per CPU (or ``RAYON_NUM_THREADS``). A process that shares the machine — a batch
worker given one CPU, a server's request handler — sizes it first::

    import scanreg
    scanreg.set_num_threads(1)      # before any other scanreg call in this process

Results do not depend on the thread count: the core's parallel sums use fixed chunks added in
chunk order, so 1 and 8 threads give the same pose to the bit.
"""

from __future__ import annotations

import operator

from . import _core


def set_num_threads(num_threads: int) -> None:
    """Size the core's process-wide pool to ``num_threads`` (>= 1).

    Raises
    ------
    TypeError
        ``num_threads`` is not an integer.
    ValueError
        ``num_threads`` < 1.
    RuntimeError
        The pool already runs another number of threads (it is built once per process, at the
        first parallel call): call this before any other scanreg call, or set
        ``RAYON_NUM_THREADS`` in the process's environment.
    """
    if isinstance(num_threads, bool):
        raise TypeError("num_threads: expected an int, got bool")
    try:
        n = operator.index(num_threads)
    except TypeError:
        raise TypeError(f"num_threads: expected an int, got {type(num_threads).__name__}") from None
    if n < 1:
        raise ValueError(f"num_threads: must be >= 1, got {n}")
    try:
        _core.set_num_threads(n)
    except ValueError as exc:
        raise RuntimeError(str(exc)) from None


def get_num_threads() -> int:
    """Threads of the core's process-wide pool (sizes it by default if nothing has yet)."""
    return _core.get_num_threads()


__all__ = ["get_num_threads", "set_num_threads"]
