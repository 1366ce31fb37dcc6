"""NDT in 3D (Magnusson 2009, point to distribution): the solver behind :func:`scanreg.match_ndt`
for ``(N, 3)`` clouds. The per-point sums run in the core (``_core.NdtGrid3``); the iteration
policy is here, as in 2D.

The pose is updated on the right, ``T ← T·exp(δ)``, about the source's centroid ``c`` (points
``p − c``, pose ``T·Tr(c)``): a rotation step then turns the points about themselves, so the
step bounds and tolerances act on how far the points move, wherever the clouds sit. The
information ``Σ e·JᵀΣ⁻¹J`` (the Gauss–Newton part of the Hessian, the Fisher information of the
voxel Gaussians) is moved back to the source origin's tangent with the adjoint of ``Tr(c)``.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from . import _core
from ._newton import StopReason, damped_newton
from ._validate import FloatArray
from .transform import SE3


def build_levels(
    points: FloatArray,
    sizes: tuple[float, ...],
    min_points: int,
    min_eigen_ratio: float,
) -> tuple[_core.NdtGrid3, ...]:
    return tuple(_core.NdtGrid3(points, c, int(min_points), float(min_eigen_ratio)) for c in sizes)


def _centroid(points: FloatArray) -> FloatArray:
    p0 = points[0]
    out: FloatArray = p0 + (points - p0).mean(axis=0)
    return out


def _hat(v: FloatArray) -> FloatArray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _newton(
    native: _core.NdtGrid3,
    src: FloatArray,
    pose: SE3,
    max_iterations: int,
    tol_t: float,
    tol_r: float,
    radius: float,
) -> tuple[SE3, StopReason, int]:
    """Damped Newton on one level (:func:`scanreg._newton.damped_newton`). A step moves no
    point by more than half a voxel (translation and rotation bounded separately)."""

    def evaluate(t: SE3) -> tuple[float, FloatArray, FloatArray, int]:
        cost, grad, hess, _, matched = native.evaluate(src, t.as_matrix())
        return cost, grad, hess, matched

    max_t = 0.5 * native.cell_size
    max_r = min(0.1, max_t / max(radius, 1e-9))

    def bound(step: FloatArray) -> FloatArray:
        t_norm = float(np.linalg.norm(step[:3]))
        r_norm = float(np.linalg.norm(step[3:]))
        scale = min(1.0, max_t / max(t_norm, 1e-300), max_r / max(r_norm, 1e-300))
        out: FloatArray = step * scale
        return out

    def small(step: FloatArray) -> bool:
        return float(np.linalg.norm(step[:3])) < tol_t and float(np.linalg.norm(step[3:])) < tol_r

    return damped_newton(
        evaluate,
        pose,
        retract=lambda t, step: t @ SE3.exp(step),
        bound=bound,
        small=small,
        max_iterations=max_iterations,
    )


def match(
    src: FloatArray,
    natives: tuple[_core.NdtGrid3, ...],
    init: SE3,
    max_iterations: int,
    tol_t: float,
    tol_r: float,
) -> dict[str, Any]:
    """Coarse to fine over ``natives``; returns the fields of an ``NdtResult``."""
    t0 = time.perf_counter()
    c = _centroid(src)
    src_c = np.ascontiguousarray(src - c)
    radius = float(np.sqrt((src_c**2).sum(axis=1).mean())) or 1.0
    shift = SE3(np.eye(3), c)
    pose_c = init @ shift
    stop: StopReason = "max_iterations"
    iterations = 0
    for native in natives:
        pose_c, stop, used = _newton(
            native, src_c, pose_c, int(max_iterations), tol_t, tol_r, radius
        )
        iterations += used
    seconds = time.perf_counter() - t0
    native = natives[-1]
    cost, _, hess_c, fisher_c, matched = native.evaluate(src_c, pose_c.as_matrix())
    pose = pose_c @ SE3(np.eye(3), -c)
    # ξ (tangent at pose) = A ξ_c (tangent at pose_c) with A = Ad(Tr(c)) = [[I, [c]×], [0, I]].
    a = np.eye(6)
    a[:3, 3:] = _hat(c)
    a_inv = np.eye(6)
    a_inv[:3, 3:] = -_hat(c)
    fisher_c = 0.5 * (fisher_c + fisher_c.T)
    info = a_inv.T @ fisher_c @ a_inv
    hess = a_inv.T @ (0.5 * (hess_c + hess_c.T)) @ a_inv
    top = max(float(np.abs(fisher_c).max()), 1e-300)
    if matched > 0 and np.linalg.eigvalsh(fisher_c).min() > 1e-12 * top:
        cov = a @ np.linalg.inv(fisher_c) @ a.T
        cov = 0.5 * (cov + cov.T)
    else:
        cov = np.full((6, 6), np.inf)
    return {
        "pose": pose,
        "covariance": cov,
        "hessian": hess,
        "information": 0.5 * (info + info.T),
        "cost": float(cost),
        "score": float(-cost / len(src)),
        "fitness": float(matched / len(src)),
        "iterations": iterations,
        "stop_reason": stop,
        "seconds": seconds,
    }
