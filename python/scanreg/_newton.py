"""The damped Newton loop shared by NDT in 2D (:mod:`scanreg.ndt`) and 3D (:mod:`scanreg._ndt3d`).

``(∇²f + λI) δ = −∇f``, with λ raised until ``∇²f + λI`` is positive definite and the step
lowers the cost (Biber & Straßer: "add λI until positive definite"), and lowered after each
accepted step. The caller says how a step is bounded (``bound``), applied (``retract``) and
judged small enough to stop (``small``); the cost, gradient and Hessian come from ``evaluate``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal, TypeVar

import numpy as np

from ._validate import FloatArray

X = TypeVar("X")
StopReason = Literal["converged", "max_iterations", "no_overlap"]
#: ``evaluate(x) -> (cost, gradient, Hessian, number of matched points)``.
Evaluate = Callable[[X], tuple[float, FloatArray, FloatArray, int]]


def damped_newton(
    evaluate: Evaluate[X],
    x: X,
    *,
    retract: Callable[[X, FloatArray], X],
    bound: Callable[[FloatArray], FloatArray],
    small: Callable[[FloatArray], bool],
    max_iterations: int,
) -> tuple[X, StopReason, int]:
    """Minimise from ``x``; returns the estimate, why it stopped and the iterations used."""
    cost, grad, hess, matched = evaluate(x)
    dof = len(grad)
    lam = 0.0
    for iteration in range(1, max_iterations + 1):
        if matched == 0:
            return x, "no_overlap", iteration - 1
        sym = 0.5 * (hess + hess.T)
        vals = np.linalg.eigvalsh(sym)
        top = max(float(np.abs(vals).max()), 1e-12)
        lam = max(lam, -float(vals[0]) + 1e-6 * top, 0.0)
        while True:
            raw = np.asarray(-np.linalg.solve(sym + lam * np.eye(dof), grad), dtype=np.float64)
            step = bound(raw)
            trial = retract(x, step)
            c_new, g_new, h_new, m_new = evaluate(trial)
            if c_new < cost:
                break
            lam = max(4.0 * lam, 1e-3 * top)
            if lam > 1e9 * top:  # no step lowers the cost: a minimum
                return x, "converged", iteration
        x, cost, grad, hess, matched = trial, c_new, g_new, h_new, m_new
        lam /= 3.0
        if small(step):
            return x, "converged", iteration
    return x, "max_iterations", max_iterations
