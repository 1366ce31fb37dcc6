"""Robust M-estimator kernels: names, tuning constants and scale estimation.

The kernels themselves (loss ``ρ`` and IRLS weight ``ρ'(r)/r``) live in the Rust core;
this module picks their scale. With ``kernel_scale=None`` the scale is
``tuning constant × σ̂``, with ``σ̂`` a robust (median-based) estimate of the residual noise,
so that on clean Gaussian data each kernel keeps about 95 % of least-squares efficiency.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from ._validate import FloatArray

KernelName = Literal["none", "huber", "cauchy", "tukey", "geman_mcclure", "welsch"]

#: Tuning constants in units of σ for 95 % asymptotic efficiency under Gaussian noise
#: (Holland & Welsch 1977; Zhang 1997 table 1). Geman–McClure has no standard value; 2.0
#: gives a similar down-weighting profile to Cauchy at 2.385.
TUNING: dict[str, float] = {
    "huber": 1.345,
    "cauchy": 2.385,
    "tukey": 4.685,
    "geman_mcclure": 2.0,
    "welsch": 2.985,
}

KERNELS: tuple[str, ...] = ("none", *TUNING)

# Median of a χ distribution with k degrees of freedom (the norm of a k-D standard normal):
# sqrt of the χ² median. Converts a median residual norm to σ per coordinate.
_CHI_MEDIAN = {1: 0.6744897501960817, 2: 1.1774100225154747, 3: 1.5381722544550522}


def check_kernel(name: str) -> str:
    if name not in KERNELS:
        raise ValueError(f"kernel: unknown {name!r}; expected one of {', '.join(KERNELS)}")
    return name


def robust_sigma(residuals: FloatArray, components: int) -> float:
    """σ per coordinate from the median residual magnitude.

    ``residuals`` are norms of ``components``-D residual vectors (or signed scalars when
    ``components == 1``); the median is robust to up to 50 % outliers.
    """
    med = float(np.median(np.abs(residuals)))
    return med / _CHI_MEDIAN[components]


def default_scale(kernel: str, residuals: FloatArray, components: int) -> float:
    """Kernel scale ``c = tuning × σ̂`` (never zero: floored at 1e-9 of the data's units)."""
    if kernel == "none":
        return 1.0
    scale = TUNING[kernel] * float(np.sqrt(components)) * robust_sigma(residuals, components)
    return max(scale, 1e-9)
