"""Correlative 2D scan matching (Olson 2009) with branch and bound (Hess et al. 2016).

The target (a scan or a map, ``(N, 2)`` points in its own frame) is rasterised once into a
likelihood grid — ``g = exp(−d²/2σ²)`` with ``d`` the distance from a cell to the nearest
occupied cell — and every candidate pose of a window is scored by summing ``g`` under the
transformed source points. The per-cell work (distance transform, max-pooled levels, the
search) runs in the Rust core (:mod:`scanreg-core` ``correlative``), parallel over rotations.

>>> grid = scanreg.prepare_correlative(target_points, resolution=0.05)
>>> res = scanreg.match_correlative(source_points, grid, init=T_guess,
...                                 window=(0.5, 0.5, np.deg2rad(20)))
>>> res.pose, res.covariance, res.fitness

The search lattice
    Rotations ``θ₀ + k·δθ`` for ``|k| ≤ ⌈dθ/δθ⌉`` and translations ``t₀ + (i, j)·r`` for
    ``|i| ≤ ⌈dx/r⌉``, ``|j| ≤ ⌈dy/r⌉``, around ``init = (t₀, θ₀)``; ``r`` is the grid
    resolution. ``search="branch_and_bound"`` (the default) explores the same lattice through
    max-pooled grids and returns the same candidate as ``"exhaustive"`` (same pose, same score;
    ties go to the smallest ``(k, i, j)``), usually after far fewer evaluations.

The covariance
    Olson's estimate over the scored candidates ``x = [x, y, θ]`` (the *window frame*: the
    pose vector of ``T_target_source``), with ``p = exp(S − S_max)`` and ``S = Σ g``
    (``g ≈ 1 − d²/2σ²`` near a wall, so ``S`` is the Gaussian log-likelihood of the points to
    second order): ``Σ_w = Σ p x xᵀ / Σ p − μ μᵀ`` — over the whole window for the exhaustive
    search, over a ``±covariance_radius``-step neighbourhood of the optimum for branch and
    bound. The lattice cannot resolve the pose more finely than one step, so the variance of a
    uniform quantisation error, ``diag(r², r², δθ²)/12``, is added.

    The window frame perturbs the pose vector: ``x = x̂ + δx``, ``θ = θ̂ + δθ``. scanreg's
    covariances are over the right perturbation ``T = T̂ · exp(ξ)``, ``ξ = [ρx, ρy, θ]``,
    whose translation to first order is ``t̂ + R̂ ρ``; hence ``ρ = R̂ᵀ δt``, ``ξθ = δθ`` and
    ``covariance = J Σ_w Jᵀ`` with ``J = blockdiag(R̂ᵀ, 1)``.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from . import _core
from ._validate import FloatArray, as_covariance, as_points, positive, readonly
from ._validate import frozen as _frozen
from .quality import Conditioning, conditioning
from .transform import SE2, as_pose

#: How the lattice is searched (not a cost function: the score is the same either way).
Search = Literal["branch_and_bound", "exhaustive"]
SEARCHES: tuple[str, ...] = ("branch_and_bound", "exhaustive")

#: Default grid resolution (m/cell).
DEFAULT_RESOLUTION = 0.05
#: Default search window ``(dx, dy, dθ)``: ±0.5 m, ±0.5 m, ±20°.
DEFAULT_WINDOW = (0.5, 0.5, math.radians(20.0))
#: Default number of max-pooled levels (Hess et al. use 7: nodes up to 64 × 64 cells).
DEFAULT_LEVELS = 7


@dataclass(frozen=True)
class CorrelativeTiming:
    """Wall time in seconds: building the grid (0 when a prepared grid was passed) and the
    search (including the covariance)."""

    grid_seconds: float
    search_seconds: float

    @property
    def total_seconds(self) -> float:
        return self.grid_seconds + self.search_seconds


@dataclass(frozen=True)
class CorrelativeResult:
    """The answer of :func:`match_correlative`.

    Attributes
    ----------
    pose : SE2
        ``T_target_source`` of the best lattice candidate.
    score : float
        Mean likelihood of the source points at ``pose``, in ``[0, 1]`` (1: every point in an
        occupied cell).
    covariance : (3, 3) float64
        Over the right perturbation ``[ρx, ρy, θ]`` (``T = pose @ SE2.exp(ξ)``); see the
        module docstring for how it comes from the window-frame estimate.
    window_covariance : (3, 3) float64
        Olson's estimate over the window frame ``[x, y, θ]`` (pose-vector offsets in the
        target frame), quantisation term included.
    mean : (3,) float64
        ``[x, y, θ]``: the ``p``-weighted mean of the candidates (a sub-lattice estimate).
    fitness : float
        Fraction of source points within one cell (8-neighbourhood) of an occupied cell.
    num_evaluated : int
        Full-resolution candidates scored.
    num_bounds : int
        Branch-and-bound upper bounds computed on coarser levels (0 when exhaustive).
    num_candidates : int
        Size of the lattice window.
    at_window_edge : bool
        The optimum lies on the border of the window: the true pose may be outside it.
    search : str
        ``"branch_and_bound"`` or ``"exhaustive"``.
    resolution, angular_resolution : float
        The lattice steps (m, rad).
    timing : CorrelativeTiming
    length_scale : float
        RMS range of the source points (m): the length scale of ``conditioning``.
    conditioning : Conditioning
        Eigen-analysis of ``covariance⁻¹`` (computed on first read).
    """

    pose: SE2
    score: float
    covariance: FloatArray
    window_covariance: FloatArray
    mean: FloatArray
    fitness: float
    num_evaluated: int
    num_bounds: int
    num_candidates: int
    at_window_edge: bool
    search: str
    resolution: float
    angular_resolution: float
    timing: CorrelativeTiming
    length_scale: float = field(default=1.0, repr=False)

    @functools.cached_property
    def conditioning(self) -> Conditioning:
        """Eigen-analysis of the information ``covariance⁻¹``; computed on first read (the 2D
        odometry reads only the pose, and this was a fifth of its search's time)."""
        return conditioning(_frozen(np.linalg.inv(self.covariance)), 2, self.length_scale)

    @property
    def standard_deviations(self) -> FloatArray:
        """``sqrt(diag(covariance))``: ``[ρx, ρy, θ]`` in metres, metres, radians."""
        return _frozen(np.sqrt(np.diag(self.covariance)))


@dataclass(frozen=True, eq=False)
class CorrelativeGrid:
    """A target rasterised once for :func:`match_correlative` (see
    :func:`prepare_correlative`).

    Attributes
    ----------
    resolution : float
        Cell size and translation step, metres.
    sigma : float
        Blur of the likelihood, metres.
    levels : int
        Max-pooled levels available to branch and bound.
    origin : (float, float)
        Target-frame coordinates of the lower-left corner of cell ``(0, 0)``.
    shape : (int, int)
        ``(width, height)`` in cells.
    num_points : int
        Target points rasterised.
    """

    resolution: float
    sigma: float
    levels: int
    origin: tuple[float, float]
    shape: tuple[int, int]
    num_points: int
    _native: _core.CorrelativeGrid
    build_seconds: float
    #: What :func:`prepare_correlative` was given (a copy): pickling rebuilds the grid from it
    #: (the build is deterministic) instead of shipping the rasters.
    _inputs: tuple[Any, ...] = field(default=(), repr=False)

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        if not self._inputs:
            raise TypeError("CorrelativeGrid: only a grid built by prepare_correlative pickles")
        return (_rebuild_correlative, self._inputs)

    @property
    def likelihood(self) -> np.ndarray[Any, np.dtype[np.float32]]:
        """``(height, width)`` float32 likelihood (row = y, column = x)."""
        return self._native.likelihood

    def match(self, source: Any, **options: Any) -> CorrelativeResult:
        """:func:`match_correlative` against this grid."""
        return match_correlative(source, self, **options)

    def updated(self, points: Any, *, in_place: bool = False) -> CorrelativeGrid:
        """The grid of ``points``, computed from this one (equal to prepare_correlative's).

        The grid :func:`prepare_correlative` builds from ``points`` with this grid's
        resolution, sigma and levels, cell for cell and to the bit: a cell's likelihood
        depends only on the occupied cells within the blur's reach, so only the cells near an
        occupied cell that disappeared (and those the grid's extent gained) are rasterised
        again, and the discs of the cells that appeared are lowered in. For a local map that
        gains a keyframe and drops its oldest (:class:`scanreg.pipeline.Odometry2D`).

        ``in_place``: the new grid takes this one's rasters and changes them where they
        change, instead of changing a copy (a long-range laser's local map spans a million
        cells, and copying them cost more than the update); this grid must not be used
        afterwards (it would read the new grid's rasters)."""
        ref = as_points(points, "points", dim=2)
        if not isinstance(in_place, bool):
            raise TypeError(f"in_place: expected a bool, got {type(in_place).__name__}")
        t0 = time.perf_counter()
        if in_place:
            native = self._native
            native.update(ref)
        else:
            native = self._native.updated(ref)
        return _grid(native, ref, self.resolution, self.sigma, self.levels, t0)


def prepare_correlative(
    points: Any,
    *,
    resolution: float = DEFAULT_RESOLUTION,
    sigma: float | None = None,
    levels: int = DEFAULT_LEVELS,
) -> CorrelativeGrid:
    """Rasterise the target ``points`` ``(N, 2)`` (metres) once, for many matches against it.

    Parameters
    ----------
    resolution : float
        Cell size (m); also the translation step of the search.
    sigma : float, optional
        Blur (m) of the likelihood ``exp(−d²/2σ²)``; default: ``resolution``.
    levels : int
        Max-pooled levels for branch and bound (0: exhaustive only); at most 12.
    """
    ref = as_points(points, "points", dim=2)
    res = positive(resolution, "resolution")
    sig = res if sigma is None else positive(sigma, "sigma")
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)):
        raise TypeError(f"levels: expected an int, got {type(levels).__name__}")
    if not 0 <= levels <= 12:
        raise ValueError(f"levels: must be in [0, 12], got {levels}")
    t0 = time.perf_counter()
    native = _core.CorrelativeGrid(ref, res, sig, int(levels))
    return _grid(native, ref, res, sig, int(levels), t0)


def _grid(
    native: Any, ref: FloatArray, resolution: float, sigma: float, levels: int, t0: float
) -> CorrelativeGrid:
    """The :class:`CorrelativeGrid` around the core's ``native`` grid of ``ref``, built (or
    updated) since ``t0``; ``levels`` as asked (the core may pool fewer)."""
    elapsed = time.perf_counter() - t0
    return CorrelativeGrid(
        resolution=resolution,
        sigma=sigma,
        levels=native.levels,
        origin=native.origin,
        shape=native.shape,
        num_points=int(ref.shape[0]),
        _native=native,
        build_seconds=elapsed,
        _inputs=(readonly(np.array(ref)), resolution, sigma, levels),
    )


def _rebuild_correlative(
    reference: FloatArray, resolution: float, sigma: float, levels: int
) -> CorrelativeGrid:
    return prepare_correlative(reference, resolution=resolution, sigma=sigma, levels=levels)


def default_angular_resolution(source: FloatArray, resolution: float) -> float:
    """Hess et al. 2016 eq. 7: the angle that moves the farthest point by about one cell,
    ``acos(1 − r²/(2 d_max²))`` with ``d_max`` the largest source range."""
    d_max = max(float(np.sqrt((source**2).sum(axis=1)).max()), resolution)
    step = float(math.acos(1.0 - resolution**2 / (2.0 * d_max**2)))
    if not step > 0.0:
        # The search rotates the scan about its frame's origin (the sensor): a scan whose
        # points sit ~10⁷ m from it has no representable one-cell angle.
        raise ValueError(
            f"source: points up to {d_max:.3g} m from the source frame's origin leave no "
            "one-cell angular step; give the scan in its sensor frame (init carries the map "
            "pose) or an explicit angular_resolution"
        )
    return step


def _window(window: Any) -> tuple[float, float, float]:
    try:
        values = [float(v) for v in window]
    except (TypeError, ValueError):
        raise TypeError(f"window: expected (dx, dy, dθ) numbers, got {window!r}") from None
    if len(values) != 3:
        raise ValueError(f"window: expected (dx, dy, dθ), got {len(values)} values")
    if not all(math.isfinite(v) and v >= 0 for v in values):
        raise ValueError(f"window: half-widths must be finite and >= 0, got {tuple(values)}")
    if values[2] > math.pi:
        raise ValueError(f"window: dθ must be <= π, got {values[2]}")
    return values[0], values[1], values[2]


def _steps(half_width: float, step: float) -> int:
    # The window covers at least ±half_width (tolerating rounding in half_width / step).
    return math.ceil(half_width / step - 1e-9)


def match_correlative(
    source: Any,
    target: Any,
    *,
    init: Any = None,
    window: Any = DEFAULT_WINDOW,
    resolution: float | None = None,
    angular_resolution: float | None = None,
    search: Search = "branch_and_bound",
    sigma: float | None = None,
    levels: int = DEFAULT_LEVELS,
    covariance_radius: int = 4,
    init_covariance: Any = None,
) -> CorrelativeResult:
    """Find ``T_target_source`` by correlative search over a window around ``init``.

    Parameters
    ----------
    source : (N, 2) float64
        Source scan points in the source frame (metres).
    target : (M, 2) float64 or CorrelativeGrid
        Target points (in the target frame), or a grid from
        :func:`prepare_correlative` (then ``resolution``/``sigma``/``levels`` must be left
        unset or agree).
    init : SE2 or (3, 3) matrix, optional
        Window centre (default: identity).
    window : (dx, dy, dθ)
        Half-widths in metres, metres, radians.
    resolution : float, optional
        Grid cell and translation step (m); default 0.05.
    angular_resolution : float, optional
        Rotation step (rad); default :func:`default_angular_resolution`.
    search : "branch_and_bound" (default) or "exhaustive"
        How the window is searched: both return the same candidate (same pose and score);
        branch and bound scores far fewer of them.
    covariance_radius : int
        Branch and bound: half-width in steps of the dense neighbourhood used for the
        covariance.
    init_covariance : (3, 3) float64, optional
        How uncertain ``init`` is (over its right-perturbation tangent ``[ρx, ρy, θ]``,
        positive definite): a motion cost. Each candidate is then ranked by
        ``S − ½ δᵀ Σ⁻¹ δ``, ``δ`` its offset from ``init`` — ``S`` is, to second order, the
        points' log-likelihood, so this is the candidate's log-posterior under a Gaussian
        prior at ``init`` (the real-time correlative matcher's motion cost, Olson 2009): where
        the scan says little (a corridor's axis) or two basins fit about equally, the one the
        prediction supports wins, while a basin the scan clearly prefers still does. Both
        searches return the same candidate with it. ``score``, ``fitness`` and the covariance
        stay the scan's own (the cost enters only the ranking).

    Raises
    ------
    ValueError, TypeError
        Naming the argument: bad shapes, non-finite points, unknown search, a window or step
        that is not positive, an ``init`` that is not a rigid transform.
    """
    found = _search(
        source,
        target,
        init=init,
        window=window,
        resolution=resolution,
        angular_resolution=angular_resolution,
        search=search,
        sigma=sigma,
        levels=levels,
        covariance_radius=covariance_radius,
        init_covariance=init_covariance,
        min_score=None,
    )
    assert found is not None  # without a floor there is always a best candidate
    return found


def find_correlative(
    source: Any,
    target: Any,
    *,
    min_score: float,
    init: Any = None,
    window: Any = DEFAULT_WINDOW,
    resolution: float | None = None,
    angular_resolution: float | None = None,
    sigma: float | None = None,
    levels: int = DEFAULT_LEVELS,
    covariance_radius: int = 4,
) -> CorrelativeResult | None:
    """:func:`match_correlative`'s branch-and-bound answer if its ``score`` is at least
    ``min_score`` (in ``[0, 1]``), else ``None``.

    Every branch whose bound is below ``min_score`` is pruned from the start, so a window
    that does not hold the place costs a fraction of a full search: what a loop-closure
    search over many candidates, most of them not the place, needs (Cartographer's
    constraint search prunes the same way). When there is an answer it is
    :func:`match_correlative`'s, to the bit. Arguments as there.
    """
    score = float(min_score)
    if not 0.0 <= score <= 1.0:
        raise ValueError(f"min_score: must be in [0, 1], got {min_score!r}")
    return _search(
        source,
        target,
        init=init,
        window=window,
        resolution=resolution,
        angular_resolution=angular_resolution,
        search="branch_and_bound",
        sigma=sigma,
        levels=levels,
        covariance_radius=covariance_radius,
        init_covariance=None,
        min_score=score,
    )


def _search(
    source: Any,
    target: Any,
    *,
    init: Any,
    window: Any,
    resolution: float | None,
    angular_resolution: float | None,
    search: Search,
    sigma: float | None,
    levels: int,
    covariance_radius: int,
    init_covariance: Any,
    min_score: float | None,
) -> CorrelativeResult | None:
    src = as_points(source, "source", dim=2)
    if search not in SEARCHES:
        raise ValueError(f"search: unknown {search!r}; expected one of {', '.join(SEARCHES)}")
    pose0 = SE2.identity() if init is None else as_pose(init, "init", 2)
    assert isinstance(pose0, SE2)
    dx, dy, dtheta = _window(window)
    if isinstance(covariance_radius, bool) or not isinstance(covariance_radius, (int, np.integer)):
        raise TypeError("covariance_radius: expected an int")
    if covariance_radius < 0:
        raise ValueError(f"covariance_radius: must be >= 0, got {covariance_radius}")
    if isinstance(target, CorrelativeGrid):
        grid = target
        if resolution is not None and positive(resolution, "resolution") != grid.resolution:
            raise ValueError(
                f"resolution: {resolution} differs from the prepared grid's {grid.resolution}"
            )
        if sigma is not None and positive(sigma, "sigma") != grid.sigma:
            raise ValueError(f"sigma: {sigma} differs from the prepared grid's {grid.sigma}")
        grid_seconds = 0.0
    else:
        res = DEFAULT_RESOLUTION if resolution is None else resolution
        grid = prepare_correlative(target, resolution=res, sigma=sigma, levels=levels)
        grid_seconds = grid.build_seconds
    r = grid.resolution
    dth = (
        default_angular_resolution(src, r)
        if angular_resolution is None
        else positive(angular_resolution, "angular_resolution")
    )
    nx, ny, nt = _steps(dx, r), _steps(dy, r), _steps(dtheta, dth)
    t0 = time.perf_counter()
    m = _native_search(
        src, grid, pose0, (nx, ny, nt), dth, search, covariance_radius, init_covariance, min_score
    )
    search_seconds = time.perf_counter() - t0
    if m is None:
        return None
    pose = SE2.from_vector(m.pose)
    k, i, j = m.index
    window_cov = np.array(m.covariance) + np.diag([r * r, r * r, dth * dth]) / 12.0
    jac = np.eye(3)
    jac[:2, :2] = pose.rotation.T
    cov = jac @ window_cov @ jac.T
    cov = 0.5 * (cov + cov.T)
    length = float(np.sqrt((src**2).sum(axis=1).mean())) or 1.0
    return CorrelativeResult(
        pose=pose,
        score=float(m.score),
        covariance=_frozen(cov),
        window_covariance=_frozen(window_cov),
        mean=_frozen(m.mean),
        fitness=float(m.fitness),
        num_evaluated=int(m.evaluated),
        num_bounds=int(m.bounds),
        num_candidates=(2 * nx + 1) * (2 * ny + 1) * (2 * nt + 1),
        at_window_edge=bool(
            (nx > 0 and abs(i) == nx) or (ny > 0 and abs(j) == ny) or (nt > 0 and abs(k) == nt)
        ),
        search=search,
        resolution=r,
        angular_resolution=dth,
        timing=CorrelativeTiming(grid_seconds=grid_seconds, search_seconds=search_seconds),
        length_scale=length,
    )


def _native_search(
    src: FloatArray,
    grid: CorrelativeGrid,
    init: SE2,
    steps: tuple[int, int, int],
    angular_step: float,
    search: str,
    covariance_radius: int,
    init_covariance: Any,
    min_score: float | None,
) -> Any:
    """The core's search of the lattice ``steps`` (half-widths in steps) around ``init``."""
    center = init.as_vector()
    penalty = None if init_covariance is None else _window_information(init_covariance, init)
    nx, ny, nt = steps
    return grid._native.search(
        src,
        (center[0], center[1], center[2]),
        nx,
        ny,
        nt,
        angular_step,
        search,
        int(covariance_radius),
        penalty,
        min_score,
    )


def best_correlative_pose(
    source: FloatArray,
    grid: CorrelativeGrid,
    init: SE2,
    window: tuple[float, float, float],
    init_covariance: FloatArray | None = None,
) -> SE2:
    """``match_correlative(source, grid, init=init, window=window,
    init_covariance=init_covariance).pose`` (branch and bound, the default angular step) and
    nothing else: no covariance, statistics or result to assemble, for a caller that reads
    only the pose (:class:`scanreg.pipeline.Odometry2D`'s search before its refinement, once
    a scan). Arguments as validated there."""
    source = as_points(source, "source", dim=2, min_points=1)
    dx, dy, dtheta = _window(window)
    r = grid.resolution
    dth = default_angular_resolution(source, r)
    steps = (_steps(dx, r), _steps(dy, r), _steps(dtheta, dth))
    m = _native_search(source, grid, init, steps, dth, "branch_and_bound", 0, init_covariance, None)
    return SE2.from_vector(m.pose)


def _window_information(covariance: Any, init: SE2) -> tuple[float, ...]:
    """``init_covariance`` (right tangent of ``init``) as the information matrix over the
    window frame's pose-vector offsets ``[x, y, θ]`` (``δt = R ρ``), row-major."""
    cov = as_covariance(covariance, "init_covariance", 3, definite=True)
    cov = 0.5 * (cov + cov.T)
    jac = np.eye(3)
    jac[:2, :2] = init.rotation
    info = np.linalg.inv(jac @ cov @ jac.T)
    info = 0.5 * (info + info.T)
    return tuple(float(v) for v in info.ravel())


__all__ = [
    "SEARCHES",
    "CorrelativeGrid",
    "CorrelativeResult",
    "CorrelativeTiming",
    "best_correlative_pose",
    "default_angular_resolution",
    "find_correlative",
    "match_correlative",
    "prepare_correlative",
]
