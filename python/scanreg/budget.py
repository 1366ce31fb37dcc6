"""A memory budget: large requests are refused with a clear error before they allocate.

A 10 M-point cloud is a normal map; what it costs depends on what is built from it. With a budget
set (``set_memory_budget("4G")`` or the environment variable ``SCANREG_MEMORY_BUDGET=4G``), the
calls that allocate per point — :func:`scanreg.prepare`, :func:`scanreg.register`,
:meth:`scanreg.LocalMap.insert`, :func:`scanreg.preprocess.voxel_downsample` — estimate their
peak from the point count and raise :class:`MemoryBudgetExceeded` (a ``MemoryError``) naming the
request, the estimate and the budget, instead of letting the process be killed mid-way. No
budget (the default) costs one attribute read per call.

The estimates are peak bytes per point measured on 1 M-point clouds (``benchmarks/scale.py``,
peak RSS in a fresh process), rounded up: see :data:`BYTES_PER_POINT`.
"""

from __future__ import annotations

import os
import re

#: Peak bytes per input point, measured by ``benchmarks/scale.py`` and rounded up.
BYTES_PER_POINT: dict[str, int] = {
    "index": 120,  # the k-d tree, its reordered copy and the read-only points (3D)
    "normals": 40,  # unit normals and validity, on top of the index
    "covariances": 160,  # GICP covariances (3×3 per point), on top of the index
    "source": 70,  # register(): source copy, correspondences, certificates (point methods)
    "source_covariances": 200,  # register(method="gicp"): the source's own covariances
    "local_map": 600,  # LocalMap.insert(): voxel hash map storage per point inserted
    "voxel_downsample": 45,  # keys, slots and sums
}

_ENV = "SCANREG_MEMORY_BUDGET"
_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


class MemoryBudgetExceeded(MemoryError):
    """A request's estimated peak memory exceeds the budget (:func:`set_memory_budget`)."""


def _parse(value: int | str | None, name: str) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool):
        raise TypeError(f"{name}: expected bytes as an int or a string like '4G', got bool")
    if isinstance(value, int):
        if value <= 0:
            raise ValueError(f"{name}: must be > 0 bytes, got {value}")
        return value
    if isinstance(value, str):
        m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([KMGT]?)I?B?\s*", value.upper())
        if m is None:
            raise ValueError(f"{name}: expected bytes like 4096, '512M' or '4G', got {value!r}")
        size = int(float(m.group(1)) * _UNITS[m.group(2)])
        if size <= 0:
            raise ValueError(f"{name}: must be > 0 bytes, got {value!r}")
        return size
    raise TypeError(f"{name}: expected bytes as an int or a string like '4G', got {value!r}")


LIMIT: int | None = _parse(os.environ.get(_ENV) or None, _ENV)


def set_memory_budget(max_bytes: int | str | None) -> None:
    """Set the budget (``None``: no budget). Bytes as an int, or ``"512M"``, ``"4G"``, …"""
    global LIMIT
    LIMIT = _parse(max_bytes, "max_bytes")


def memory_budget() -> int | None:
    """The budget in bytes, or ``None``."""
    return LIMIT


def _human(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024:
            return f"{n:.0f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"


def check(what: str, num_points: int, parts: tuple[str, ...]) -> None:
    """Raise :class:`MemoryBudgetExceeded` when ``num_points`` × the bytes per point of
    ``parts`` exceeds the budget. Callers test ``budget.LIMIT is not None`` first."""
    limit = LIMIT
    if limit is None:
        return
    need = num_points * sum(BYTES_PER_POINT[p] for p in parts)
    if need > limit:
        raise MemoryBudgetExceeded(
            f"{what}: {num_points} points would need about {_human(need)} "
            f"({' + '.join(parts)}), over the memory budget of {_human(limit)}; "
            "downsample first (scanreg.preprocess.voxel_downsample) or raise the budget "
            f"(scanreg.set_memory_budget or {_ENV})"
        )


__all__ = [
    "BYTES_PER_POINT",
    "MemoryBudgetExceeded",
    "check",
    "memory_budget",
    "set_memory_budget",
]
