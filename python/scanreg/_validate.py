"""One validator for every array that crosses the public API.

Errors name the argument and the problem ("source: expected shape (N, 3), got (10, 4)").
Inputs are never mutated and never silently converted: float64, C-contiguous, finite.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def _as_float64_array(value: Any, name: str) -> FloatArray:
    if not isinstance(value, np.ndarray):
        kind = type(value).__name__
        raise TypeError(f"{name}: expected a numpy.ndarray of float64, got {kind}")
    if value.dtype != np.float64:
        raise TypeError(
            f"{name}: expected dtype float64, got {value.dtype}; "
            f"convert with {name}.astype(np.float64)"
        )
    if not value.flags.c_contiguous:
        raise ValueError(f"{name}: array is not C-contiguous; pass numpy.ascontiguousarray({name})")
    return value


def as_points(
    value: Any,
    name: str,
    *,
    dim: int | None = None,
    min_points: int = 1,
) -> FloatArray:
    """Check a point array of shape ``(N, 2)`` or ``(N, 3)`` (or ``(N, dim)``)."""
    arr = _as_float64_array(value, name)
    dims = (2, 3) if dim is None else (dim,)
    if arr.ndim != 2 or arr.shape[1] not in dims:
        want = " or ".join(f"(N, {d})" for d in dims)
        raise ValueError(f"{name}: expected shape {want}, got {arr.shape}")
    if arr.shape[0] == 0 and min_points > 0:
        raise ValueError(f"{name}: is empty (0 points)")
    if arr.shape[0] < min_points:
        raise ValueError(f"{name}: need at least {min_points} points, got {arr.shape[0]}")
    if not np.isfinite(arr).all():
        bad = int(np.flatnonzero(~np.isfinite(arr).all(axis=1))[0])
        raise ValueError(f"{name}: point {bad} has a non-finite coordinate (NaN or inf)")
    return arr


def as_weights(value: Any, name: str, n: int) -> FloatArray:
    """Check per-point weights: shape ``(n,)``, finite, ``>= 0``, not all zero."""
    arr = _as_float64_array(value, name)
    if arr.shape != (n,):
        raise ValueError(f"{name}: expected shape ({n},) (one weight per point), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name}: contains NaN or inf")
    if (arr < 0).any():
        raise ValueError(f"{name}: weights must be >= 0, got a minimum of {arr.min()}")
    if not (arr > 0).any():
        raise ValueError(f"{name}: all weights are zero")
    return arr


def as_matrix(value: Any, name: str, shape: tuple[int, ...]) -> FloatArray:
    """Check a small dense matrix or vector of an exact shape (float64, finite).

    Contiguity is not required here: small matrices are copied, never passed by reference.
    """
    if not isinstance(value, np.ndarray):
        try:
            value = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise TypeError(f"{name}: expected an array of numbers: {exc}") from None
    if value.dtype.kind not in "fiu" or value.dtype == np.float16:
        raise TypeError(f"{name}: expected a real numeric array, got dtype {value.dtype}")
    arr = np.array(value, dtype=np.float64)  # copy: callers may keep it
    if arr.shape != shape:
        raise ValueError(f"{name}: expected shape {shape}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name}: contains NaN or inf")
    return arr


def positive(value: float, name: str) -> float:
    """A finite, strictly positive number."""
    v = float(value)
    if not np.isfinite(v) or v <= 0:
        raise ValueError(f"{name}: must be finite and > 0, got {value}")
    return v


def check_flag(value: Any, name: str) -> bool:
    """``value`` as a bool; anything else (``1``, ``"yes"``) is a TypeError naming ``name``."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name}: expected a bool, got {type(value).__name__}")
    return bool(value)


def frozen(value: Any) -> FloatArray:
    """A read-only float64 copy of ``value``: what result dataclasses hold, so that a frozen
    result is immutable all the way down."""
    out: FloatArray = np.array(value, dtype=np.float64)
    out.setflags(write=False)
    return out


def readonly(arr: Any) -> Any:
    """Mark a freshly made array read-only in place (no copy) and return it."""
    arr.setflags(write=False)
    return arr
