"""Scalar argument checks for the simulator (errors name the argument)."""

from __future__ import annotations

import math
from typing import Any


def finite(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"{name}: expected a real number, got {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name}: must be finite, got {value}")
    return v


def positive(value: Any, name: str) -> float:
    v = finite(value, name)
    if v <= 0:
        raise ValueError(f"{name}: must be > 0, got {value}")
    return v


def non_negative(value: Any, name: str) -> float:
    v = finite(value, name)
    if v < 0:
        raise ValueError(f"{name}: must be >= 0, got {value}")
    return v


def probability(value: Any, name: str) -> float:
    v = finite(value, name)
    if not 0.0 <= v <= 1.0:
        raise ValueError(f"{name}: must be in [0, 1], got {value}")
    return v


def count(value: Any, name: str, minimum: int = 1) -> int:
    # numpy integers are accepted; bools and floats are not (a float count is a bug).
    if isinstance(value, bool) or not hasattr(value, "__index__"):
        raise TypeError(f"{name}: expected an integer, got {type(value).__name__}")
    v = int(value)
    if v < minimum:
        raise ValueError(f"{name}: must be >= {minimum}, got {v}")
    return v


def seed(value: Any, name: str = "seed") -> int:
    return count(value, name, minimum=0)
