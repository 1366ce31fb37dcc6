"""One validator for every array that crosses the public API.

Errors name the argument and the problem ("source: expected shape (N, 3), got (10, 4)").
Inputs are taken as users have them — float32 scans (KITTI ``.bin``), strided views
(``scan[::2]``), Fortran order, lists, any array-like of real numbers — and converted once, here,
to C-contiguous float64 (no copy when they already are). The caller's array is never mutated.
Points must be finite.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
_F64 = np.dtype(np.float64)
T = TypeVar("T")


def _as_float64_array(value: Any, name: str) -> FloatArray:
    """``value`` as a C-contiguous float64 array: itself when it already is one (the common case
    costs two checks), else one converted copy."""
    if isinstance(value, np.ndarray):
        dtype = value.dtype
        if (dtype is _F64 or dtype == _F64) and value.flags.c_contiguous:  # identity first
            return value
        if dtype.kind not in "fiu" or dtype == np.float16:
            raise TypeError(f"{name}: expected real numbers (float or int), got dtype {dtype}")
        return np.ascontiguousarray(value, dtype=np.float64)
    if isinstance(value, (str, bytes)) or value is None:
        raise TypeError(f"{name}: expected an array of numbers, got {type(value).__name__}")
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name}: expected an array of numbers: {exc}") from None
    if arr.dtype.kind not in "fiu" or arr.dtype == np.float16:
        kind = type(value).__name__
        raise TypeError(f"{name}: expected an array of real numbers, got {kind} of {arr.dtype}")
    return np.ascontiguousarray(arr, dtype=np.float64)


def as_points(
    value: Any,
    name: str,
    *,
    dim: int | None = None,
    min_points: int = 1,
    finite: bool = True,
) -> FloatArray:
    """Check a point array of shape ``(N, 2)`` or ``(N, 3)`` (or ``(N, dim)``).

    ``finite=False`` leaves the NaN/inf scan to the caller: for arrays handed straight to a
    core call that scans them itself (same message), on a 2D scan the numpy scan costs a
    tenth of a registration."""
    arr = _as_float64_array(value, name)
    dims = (2, 3) if dim is None else (dim,)
    if arr.ndim != 2 or arr.shape[1] not in dims:
        want = " or ".join(f"(N, {d})" for d in dims)
        raise ValueError(f"{name}: expected shape {want}, got {arr.shape}")
    if arr.shape[0] == 0 and min_points > 0:
        raise ValueError(f"{name}: is empty (0 points)")
    if arr.shape[0] < min_points:
        raise ValueError(f"{name}: need at least {min_points} points, got {arr.shape[0]}")
    if finite:
        check_finite_points(arr, name)
    return arr


def check_finite_points(arr: FloatArray, name: str) -> None:
    """Raise naming the first point with a NaN or inf coordinate."""
    if not np.isfinite(arr).all():
        bad = int(np.flatnonzero(~np.isfinite(arr).all(axis=1))[0])
        raise ValueError(f"{name}: point {bad} has a non-finite coordinate (NaN or inf)")


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


def as_covariance(value: Any, name: str, dof: int, *, definite: bool = False) -> FloatArray:
    """Check a covariance, as a copy: ``(dof, dof)``, finite, symmetric (to round-off) and
    positive semi-definite (``definite``: positive definite)."""
    try:
        cov = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(
            f"{name}: expected a ({dof}, {dof}) array, got {type(value).__name__}"
        ) from None
    if cov.shape != (dof, dof):
        raise ValueError(f"{name}: expected shape ({dof}, {dof}), got {cov.shape}")
    # np.allclose's test (|a − b| <= atol + rtol·|b|) written out: for finite values the same
    # answer at a fraction of its cost (every odometry step and graph edge checks one).
    if (
        not np.isfinite(cov).all()
        or not (np.abs(cov - cov.T) <= 1e-12 + 1e-9 * np.abs(cov.T)).all()
    ):
        raise ValueError(f"{name}: must be finite and symmetric")
    low = float(np.linalg.eigvalsh(cov)[0])
    if definite and low <= 0.0:
        raise ValueError(f"{name}: must be positive definite")
    # Round-off may leave a zero eigenvalue slightly negative.
    if low < -1e-12 * max(float(np.abs(cov).max()), 1e-300):
        raise ValueError(f"{name}: must be positive semi-definite")
    return cov


def positive(value: float, name: str) -> float:
    """A finite, strictly positive number."""
    v = float(value)
    if not math.isfinite(v) or v <= 0:
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


class LazyFields:
    """Mixin of a frozen dataclass whose instances :func:`build_lazy` may leave some fields out
    of: each is computed on first read by its thunk, then kept like any field (equality, repr,
    copies and pickles see every field). For results whose parts most callers never read: a
    2D registration's degeneracy directions cost as much as a tenth of its own solve."""

    __slots__ = ()

    if not TYPE_CHECKING:  # mypy keeps checking the declared fields

        def __getattr__(self, name: str) -> Any:
            # Called only for a name not found otherwise: a lazy field not computed yet.
            try:
                thunk = self.__dict__["_lazy"][name]
            except KeyError:
                raise AttributeError(
                    f"{type(self).__name__!r} object has no attribute {name!r}"
                ) from None
            # Two threads may both compute it: the same value either way.
            return self.__dict__.setdefault(name, thunk())

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        lazy = state.pop("_lazy", None)
        if lazy:
            for f in dataclasses.fields(self):  # type: ignore[arg-type]
                if f.name not in state:
                    state[f.name] = getattr(self, f.name)
        return state


def build_lazy(cls: type[T], fields: dict[str, Any], lazy: dict[str, Callable[[], Any]]) -> T:
    """:func:`build` with the fields in ``lazy`` computed on first read (``cls`` is a
    :class:`LazyFields`); ``fields`` and ``lazy`` together are every field."""
    obj = object.__new__(cls)
    obj.__dict__.update(fields)
    obj.__dict__["_lazy"] = lazy
    return obj


def build(cls: type[T], fields: dict[str, Any]) -> T:
    """An instance of the frozen dataclass ``cls`` from every one of its ``fields``, already
    checked, without the generated ``__init__``: it sets each field through
    ``object.__setattr__``, which on a 2D scan made the result objects of one registration cost
    a tenth as much as the registration. No ``__post_init__`` runs; ``tests/test_register.py``
    checks that the callers pass exactly the dataclass's fields."""
    obj = object.__new__(cls)
    obj.__dict__.update(fields)
    return obj


def replaced(obj: T, **changes: Any) -> T:
    """``dataclasses.replace(obj, **changes)`` for an object :func:`build` or
    :func:`build_lazy` made, without ``__init__``: the other fields as they are (checked when
    it was built; lazy ones still lazy, computed from the same inputs when read). ``replace``
    reads every field, computing the lazy ones, and sets each through ``object.__setattr__``."""
    new = object.__new__(type(obj))
    new.__dict__.update(obj.__dict__)
    new.__dict__.update(changes)
    return new
