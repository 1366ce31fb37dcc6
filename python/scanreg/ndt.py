"""Normal Distributions Transform registration: 2D (Biber & Straßer 2003) and 3D (Magnusson
2009, point to distribution; the solver is :mod:`scanreg._ndt3d`). ``prepare_ndt`` and
``match_ndt`` take ``(N, 2)`` or ``(N, 3)`` clouds; what follows describes 2D, and 3D differs
only where :mod:`scanreg._ndt3d` says (one voxel grid per level, seven neighbouring voxels per
point, the pose updated on the right).

The target is summarised by a Gaussian per cell in four grids shifted by half a cell (built
once, in the Rust core); a source scan is aligned by Newton's method on the NDT cost
``f(p) = −Σ exp(−½ qᵀΣ⁻¹q)`` over the pose vector ``p = [tx, ty, θ]`` of
``T_target_source``. The per-point sums (cost, analytic gradient and Hessian) run in the
core; the iteration policy is here.

>>> target = scanreg.prepare_ndt(target_points, cell_size=1.0)
>>> res = scanreg.match_ndt(source_points, target, init=T_guess)
>>> res.pose, res.covariance, res.converged

Covariance
    Near a good fit ``exp(−½m) ≈ 1 − ½m``, so ``f`` is, up to a constant, the negative Gaussian
    log-likelihood of the points with each cell's covariance as the measurement model (Biber &
    Straßer §IV use the Hessian this way). Its Gauss–Newton part, the Fisher information
    ``Σ e·JᵀΣ⁻¹J``, is inverted (the exact Hessian adds terms that vanish at a perfect fit and
    turn it indefinite where points cross cell borders). It is mapped to scanreg's right
    perturbation ``T = T̂ · exp(ξ)`` with ``J = blockdiag(R̂ᵀ, 1)`` (``ρ = R̂ᵀ δt``, see
    :mod:`scanreg.correlative`). Cell covariances are shapes of walls, not sensor noise, so
    expect it to be over-confident.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import _core, _ndt3d
from ._newton import StopReason, damped_newton
from ._validate import FloatArray, as_points, positive, readonly
from ._validate import frozen as _frozen
from .quality import Conditioning, conditioning
from .transform import SE2, SE3, as_pose


@dataclass(frozen=True, eq=False)
class NdtTarget:
    """A target prepared for :func:`match_ndt` (see :func:`prepare_ndt`).

    ``cell_sizes`` are the levels matched coarse to fine (``cell_size · 2^k``, …,
    ``cell_size``); ``num_cells`` counts the cells of the four shifted grids of the finest.
    """

    cell_size: float
    cell_sizes: tuple[float, ...]
    #: Cells of the finest level: one count per shifted grid in 2D (four), one in 3D.
    num_cells: tuple[int, ...]
    num_points: int
    _natives: tuple[_core.NdtGrid, ...] | tuple[_core.NdtGrid3, ...]
    #: 2 or 3.
    dim: int = 2
    #: What :func:`prepare_ndt` was given (a copy): pickling rebuilds the grids from it (the
    #: build is deterministic) instead of shipping them.
    _inputs: tuple[Any, ...] = field(default=(), repr=False)

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        if not self._inputs:
            raise TypeError("NdtTarget: only a target built by prepare_ndt pickles")
        return (_rebuild_ndt, self._inputs)

    def cells(self, grid: int = 0) -> tuple[FloatArray, FloatArray]:
        """Means ``(K, D)`` and covariances ``(K, D, D)`` of the finest level (2D: of one of
        its four shifted grids)."""
        native = self._natives[-1]
        if isinstance(native, _core.NdtGrid3):
            if grid != 0:
                raise ValueError(f"grid: a 3D target has one grid per level, got {grid}")
            return native.cells()
        return native.cells(grid)


@dataclass(frozen=True)
class NdtResult:
    """The answer of :func:`match_ndt`.

    Attributes
    ----------
    pose : SE2 or SE3
        ``T_target_source``.
    covariance : (3, 3) or (6, 6)
        Over the right perturbation ``[ρx, ρy, θ]`` / ``[ρ, φ]`` (see the module docstring);
        all ``inf`` when the information is singular.
    hessian : (3, 3) or (6, 6)
        ``∇²f`` at ``pose``: over the pose vector ``[tx, ty, θ]`` in 2D, over the tangent in
        3D (may be indefinite: the cost has kinks where points cross cell borders).
    information : (3, 3) or (6, 6)
        ``covariance⁻¹``: the Fisher information ``Σ e·JᵀΣ⁻¹J`` in the tangent.
    cost : float
        ``f`` at ``pose`` (``−Σ exp(−½ qᵀΣ⁻¹q)`` over points and the four grids).
    score : float
        ``−cost / N``: mean NDT score per source point, in ``[0, 4]``.
    fitness : float
        Fraction of source points inside at least one target cell.
    iterations : int
    converged : bool
    stop_reason : "converged", "max_iterations" or "no_overlap"
        ``converged``: a step below both tolerances, or no damped step lowers the cost.
    conditioning : Conditioning
        Of the information ``covariance⁻¹``, weak directions named.
    seconds : float
        Wall time of the iterations.
    """

    pose: SE2 | SE3
    covariance: FloatArray
    hessian: FloatArray
    information: FloatArray
    cost: float
    score: float
    fitness: float
    iterations: int
    converged: bool
    stop_reason: StopReason
    conditioning: Conditioning
    seconds: float

    @property
    def standard_deviations(self) -> FloatArray:
        return _frozen(np.sqrt(np.diag(self.covariance)))


def prepare_ndt(
    points: Any,
    *,
    cell_size: float = 1.0,
    levels: int = 2,
    min_points: int | None = None,
    min_eigen_ratio: float = 1e-3,
) -> NdtTarget:
    """Build the NDT Gaussians of the target ``points`` (metres) at ``levels`` cell sizes
    ``cell_size · 2^(levels−1)``, …, ``cell_size`` (coarse to fine: the coarse levels widen the
    basin, the finest sets the detail). ``(N, 2)``: four grids shifted by half a cell per level;
    ``(N, 3)``: one voxel grid per level.

    Cells with fewer than ``min_points`` points (default 3 in 2D, 6 in 3D) are dropped;
    covariance eigenvalues below ``min_eigen_ratio`` × the largest are raised to it (Biber &
    Straßer and Magnusson use 0.001).
    """
    ref = as_points(points, "points")
    dim = int(ref.shape[1])
    size = positive(cell_size, "cell_size")
    min_pts = (3 if dim == 2 else 6) if min_points is None else min_points
    for name, value in (("levels", levels), ("min_points", min_pts)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise TypeError(f"{name}: expected an int, got {type(value).__name__}")
    if not 1 <= levels <= 8:
        raise ValueError(f"levels: must be in [1, 8], got {levels}")
    sizes = tuple(size * 2.0**k for k in range(int(levels) - 1, -1, -1))
    natives: tuple[_core.NdtGrid, ...] | tuple[_core.NdtGrid3, ...]
    if dim == 3:
        natives = _ndt3d.build_levels(ref, sizes, int(min_pts), float(min_eigen_ratio))
        num_cells: tuple[int, ...] = (natives[-1].num_cells,)
    else:
        natives = tuple(_core.NdtGrid(ref, c, int(min_pts), float(min_eigen_ratio)) for c in sizes)
        num_cells = natives[-1].num_cells
    if sum(num_cells) == 0:
        raise ValueError(f"points: no cell of {size} m holds {min_pts} points; use larger cells")
    return NdtTarget(
        cell_size=size,
        cell_sizes=sizes,
        num_cells=num_cells,
        num_points=len(ref),
        _natives=natives,
        dim=dim,
        _inputs=(readonly(np.array(ref)), size, int(levels), min_points, float(min_eigen_ratio)),
    )


def _rebuild_ndt(
    points: FloatArray,
    cell_size: float,
    levels: int,
    min_points: int | None,
    min_eigen_ratio: float,
) -> NdtTarget:
    return prepare_ndt(
        points,
        cell_size=cell_size,
        levels=levels,
        min_points=min_points,
        min_eigen_ratio=min_eigen_ratio,
    )


def _centroid(points: FloatArray) -> FloatArray:
    """``p₀ + mean(p − p₀)``: the differences keep their digits at map coordinates."""
    p0 = points[0]
    out: FloatArray = p0 + (points - p0).mean(axis=0)
    return out


def _levenberg_marquardt(
    native: _core.NdtGrid,
    src: FloatArray,
    p: FloatArray,
    max_iterations: int,
    tol_t: float,
    tol_r: float,
) -> tuple[FloatArray, StopReason, int]:
    """Minimise the NDT cost from ``p`` on one grid level.

    Newton steps damped as Levenberg–Marquardt (:func:`scanreg._newton.damped_newton`). A step
    is at most half a cell and 0.1 rad, the region where the quadratic model of a cell's
    Gaussian holds.
    """

    def evaluate(v: FloatArray) -> tuple[float, FloatArray, FloatArray, int]:
        cost, grad, hess, _, matched = native.evaluate(src, (float(v[0]), float(v[1]), float(v[2])))
        return cost, grad, hess, matched

    max_step = 0.5 * native.cell_size

    def bound(step: FloatArray) -> FloatArray:
        scale = min(1.0, max_step / max(float(np.hypot(step[0], step[1])), 1e-300))
        out: FloatArray = step * min(scale, 0.1 / max(abs(float(step[2])), 1e-300))
        return out

    def small(step: FloatArray) -> bool:
        return float(np.hypot(step[0], step[1])) < tol_t and abs(float(step[2])) < tol_r

    return damped_newton(
        evaluate,
        p,
        retract=lambda v, step: v + step,
        bound=bound,
        small=small,
        max_iterations=max_iterations,
    )


def match_ndt(
    source: Any,
    target: Any,
    *,
    init: Any = None,
    cell_size: float | None = None,
    max_iterations: int = 50,
    translation_tolerance: float = 1e-5,
    rotation_tolerance: float = 1e-5,
) -> NdtResult:
    """Align ``source`` ``(N, 2)`` or ``(N, 3)`` to ``target`` (points or an
    :class:`NdtTarget` of the same dimension) by NDT.

    Parameters
    ----------
    init : SE2 / SE3 or a homogeneous matrix, optional
        Initial ``T_target_source`` (default identity). NDT is local: the basin is about
        half a cell.
    cell_size : float, optional
        For a raw target (default 1.0 m); must agree with a prepared one.
    max_iterations, translation_tolerance, rotation_tolerance
        Newton stops when a step is below both tolerances (m, rad).
    """
    src = as_points(source, "source")
    dim = int(src.shape[1])
    pose0 = (SE2.identity() if dim == 2 else SE3.identity()) if init is None else None
    pose0 = pose0 or as_pose(init, "init", dim)
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, (int, np.integer)):
        raise TypeError("max_iterations: expected an int")
    if max_iterations < 1:
        raise ValueError(f"max_iterations: must be >= 1, got {max_iterations}")
    tol_t = positive(translation_tolerance, "translation_tolerance")
    tol_r = positive(rotation_tolerance, "rotation_tolerance")
    if isinstance(target, NdtTarget):
        ndt = target
        if cell_size is not None and positive(cell_size, "cell_size") != ndt.cell_size:
            raise ValueError(
                f"cell_size: {cell_size} differs from the prepared target's {ndt.cell_size}"
            )
    else:
        ndt = prepare_ndt(target, cell_size=1.0 if cell_size is None else cell_size)
    if not ndt._natives:
        raise ValueError("target: the NdtTarget has no grid")
    if ndt.dim != dim:
        raise ValueError(f"target: a {ndt.dim}D NDT target for {dim}D source points")
    if isinstance(pose0, SE3):
        natives3 = tuple(n for n in ndt._natives if isinstance(n, _core.NdtGrid3))
        f = _ndt3d.match(src, natives3, pose0, int(max_iterations), tol_t, tol_r)
        length = float(np.sqrt(((src - src.mean(axis=0)) ** 2).sum(axis=1).mean())) or 1.0
        return NdtResult(
            pose=f["pose"],
            covariance=_frozen(f["covariance"]),
            hessian=_frozen(f["hessian"]),
            information=_frozen(f["information"]),
            cost=f["cost"],
            score=f["score"],
            fitness=f["fitness"],
            iterations=f["iterations"],
            converged=f["stop_reason"] == "converged",
            stop_reason=f["stop_reason"],
            conditioning=conditioning(_frozen(f["information"]), 3, length),
            seconds=f["seconds"],
        )
    assert isinstance(pose0, SE2)
    natives2 = tuple(n for n in ndt._natives if isinstance(n, _core.NdtGrid))
    t0 = time.perf_counter()
    # Solved for the pose of a frame centred on the source's centroid c (points p − c, pose
    # T·Tr(c)): the rotation then turns the points about themselves, not about a source
    # origin that may be 10⁷ m away (map coordinates), so the step bounds and tolerances act on
    # how far the points move and the result does not depend on where the clouds sit.
    c = _centroid(src)
    src_c = np.ascontiguousarray(src - c)
    p = (pose0 @ SE2.from_vector([c[0], c[1], 0.0])).as_vector()
    stop: StopReason = "max_iterations"
    iterations = 0
    for native in natives2:
        p, stop, used = _levenberg_marquardt(native, src_c, p, int(max_iterations), tol_t, tol_r)
        iterations += used
    seconds = time.perf_counter() - t0
    p[2] = math.atan2(math.sin(p[2]), math.cos(p[2]))
    cost, grad_c, hess_c, fisher_c, matched = native.evaluate(
        src_c, (float(p[0]), float(p[1]), float(p[2]))
    )
    pose_c = SE2.from_vector(p)
    pose = pose_c @ SE2.from_vector([-c[0], -c[1], 0.0])
    # Back to the pose vector [tx, ty, θ] of the source frame: t_c = t + R(θ) c, so
    # ∂p_c/∂p = [[I, R'(θ) c], [0, 1]], and ∇²f gains g_c·∂²t_c/∂θ² = −g_c·R(θ)c.
    rc = pose_c.rotation @ c
    jp = np.eye(3)
    jp[:2, 2] = [-rc[1], rc[0]]
    h = jp.T @ (0.5 * (hess_c + hess_c.T)) @ jp
    h[2, 2] -= float(grad_c[:2] @ rc)
    fisher_c = 0.5 * (fisher_c + fisher_c.T)
    jac = np.eye(3)
    jac[:2, :2] = pose.rotation.T
    # Tangent about the centroid (ξ_c = J δp_c, so I_ξc = J I_p Jᵀ, J orthogonal), then about
    # the source origin: ξ_c = M ξ with M = [[I, c⊥], [0, 1]] (c⊥ = (−c_y, c_x)).
    info_c = jac @ fisher_c @ jac.T
    m = np.eye(3)
    m[:2, 2] = [-c[1], c[0]]
    info = m.T @ info_c @ m
    if np.linalg.eigvalsh(fisher_c).min() > 1e-12 * max(float(np.abs(fisher_c).max()), 1e-300):
        m_inv = np.eye(3)
        m_inv[:2, 2] = [c[1], -c[0]]
        cov = m_inv @ np.linalg.inv(info_c) @ m_inv.T
        cov = 0.5 * (cov + cov.T)
    else:
        cov = np.full((3, 3), np.inf)
    length = float(np.sqrt((src**2).sum(axis=1).mean())) or 1.0
    return NdtResult(
        pose=pose,
        covariance=_frozen(cov),
        hessian=_frozen(h),
        information=_frozen(info),
        cost=float(cost),
        score=float(-cost / len(src)),
        fitness=float(matched / len(src)),
        iterations=iterations,
        converged=stop == "converged",
        stop_reason=stop,
        conditioning=conditioning(_frozen(0.5 * (info + info.T)), 2, length),
        seconds=seconds,
    )


__all__ = ["NdtResult", "NdtTarget", "match_ndt", "prepare_ndt"]
