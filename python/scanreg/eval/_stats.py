"""Summary statistics of a set of per-pose (or per-pair) errors."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import FloatArray


@dataclass(frozen=True)
class ErrorStatistics:
    """Statistics of non-negative errors (unit of the metric: m, rad or deg).

    ``std`` is the population standard deviation (``ddof = 0``), ``sse`` the sum of squares.
    """

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float
    errors: FloatArray

    @classmethod
    def from_errors(cls, errors: FloatArray) -> ErrorStatistics:
        e = np.array(errors, dtype=np.float64).reshape(-1)
        if e.size == 0:
            raise ValueError("errors: no error values to summarise (nothing was evaluated)")
        e.setflags(write=False)
        return cls(
            rmse=float(np.sqrt(np.mean(e**2))),
            mean=float(np.mean(e)),
            median=float(np.median(e)),
            std=float(np.std(e)),
            min=float(np.min(e)),
            max=float(np.max(e)),
            sse=float(np.sum(e**2)),
            errors=e,
        )

    def __len__(self) -> int:
        return int(self.errors.size)
