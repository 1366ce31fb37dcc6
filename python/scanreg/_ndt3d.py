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
from typing import Any, Literal

import numpy as np

from . import _core
from ._validate import FloatArray
from .transform import SE3

StopReason = Literal["converged", "max_iterations", "no_overlap"]


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
    """Damped Newton on one level: ``(∇²f + λI) δ = −∇f``, λ raised until the system is
    positive definite and the step lowers the cost, lowered after each accepted step. A step
    moves no point by more than half a voxel (translation and rotation bounded separately)."""

    def evaluate(t: SE3) -> tuple[float, FloatArray, FloatArray, int]:
        cost, grad, hess, _, matched = native.evaluate(src, t.as_matrix())
        return cost, grad, hess, matched

    cost, grad, hess, matched = evaluate(pose)
    max_t = 0.5 * native.cell_size
    max_r = min(0.1, max_t / max(radius, 1e-9))
    lam = 0.0
    for iteration in range(1, max_iterations + 1):
        if matched == 0:
            return pose, "no_overlap", iteration - 1
        sym = 0.5 * (hess + hess.T)
        vals = np.linalg.eigvalsh(sym)
        top = max(float(np.abs(vals).max()), 1e-12)
        lam = max(lam, -float(vals[0]) + 1e-6 * top, 0.0)
        while True:
            step = -np.linalg.solve(sym + lam * np.eye(6), grad)
            t_norm = float(np.linalg.norm(step[:3]))
            r_norm = float(np.linalg.norm(step[3:]))
            scale = min(1.0, max_t / max(t_norm, 1e-300), max_r / max(r_norm, 1e-300))
            step = step * scale
            trial = pose @ SE3.exp(step)
            c_new, g_new, h_new, m_new = evaluate(trial)
            if c_new < cost:
                break
            lam = max(4.0 * lam, 1e-3 * top)
            if lam > 1e9 * top:  # no step lowers the cost: a minimum
                return pose, "converged", iteration
        pose, cost, grad, hess, matched = trial, c_new, g_new, h_new, m_new
        lam /= 3.0
        if float(np.linalg.norm(step[:3])) < tol_t and float(np.linalg.norm(step[3:])) < tol_r:
            return pose, "converged", iteration
    return pose, "max_iterations", max_iterations


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
