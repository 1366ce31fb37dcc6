"""Figures that show whether a registration or a trajectory worked (matplotlib, optional).

Every function draws one figure and writes it to ``path``; the format follows the extension
(``.png`` or ``.svg``; ``.pdf`` also works). matplotlib (``pip install 'scanreg[plot]'``) is
imported only when a function is called, and only its object-oriented API is used (a
``Figure`` with the Agg canvas): no pyplot, no global state, nothing shown on screen, safe in
threads and on machines without a display.

* :func:`plot_scan_alignment` — 2D source and target before and after applying the pose,
  and the pose's uncertainty: the position ellipse and the heading ± σ wedge.
* :func:`plot_trajectories` — estimate against reference, top view.
* :func:`plot_error_over_distance` — position (and heading) error along the reference path.
* :func:`plot_weak_directions` — the points with the poorly constrained directions as arrows.
* :func:`plot_residual_histogram` — residuals, with an optional threshold line.
* :func:`plot_frame_uncertainty` — an odometry run's per-frame standard deviations, with the
  rejected frames and the frames held to the motion prior marked.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ._validate import FloatArray, as_matrix, as_points
from .degeneracy import Degeneracy
from .io import Trajectory
from .io._common import PathLike
from .quality import Conditioning
from .transform import SE2

#: Extensions a figure can be written as.
FORMATS = (".png", ".svg", ".pdf")
#: χ² quantile for a 95 % region in 2 dof: the ellipse is drawn at sqrt(5.991)σ.
_CHI2_2DOF_95 = 5.991464547107979

_COLORS = {"source": "#d62728", "target": "#1f77b4", "estimate": "#d62728", "reference": "#444444"}


def _figure(width: float, height: float) -> Any:
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise ImportError(
            "plots need matplotlib: pip install 'scanreg[plot]' (or pip install matplotlib)"
        ) from None
    return Figure(figsize=(width, height), dpi=110, layout="constrained")


def _check_path(path: PathLike) -> Path:
    if not isinstance(path, (str, Path)) and not hasattr(path, "__fspath__"):
        raise TypeError(f"path: expected a str or os.PathLike, got {type(path).__name__}")
    p = Path(path)
    if p.suffix.lower() not in FORMATS:
        raise ValueError(f"path: {p} must end in one of {', '.join(FORMATS)}")
    if not p.parent.is_dir():
        raise FileNotFoundError(f"path: folder {p.parent} does not exist")
    return p


def _save(fig: Any, path: Path) -> Path:
    fig.savefig(path, format=path.suffix.lower()[1:])
    return path


def _trajectory(value: Any, name: str) -> Trajectory:
    if not isinstance(value, Trajectory):
        raise TypeError(f"{name}: expected a scanreg.io.Trajectory, got {type(value).__name__}")
    if len(value) < 2:
        raise ValueError(f"{name}: needs at least 2 poses, got {len(value)}")
    return value


def _covariance(value: Any, name: str, dim: int) -> FloatArray:
    cov = as_matrix(value, name, (dim, dim))
    if np.abs(cov - cov.T).max() > 1e-9 * max(float(np.abs(cov).max()), 1e-300):
        raise ValueError(f"{name}: is not symmetric")
    if np.linalg.eigvalsh(cov).min() < -1e-12 * max(float(np.abs(cov).max()), 1e-300):
        raise ValueError(f"{name}: is not positive semi-definite")
    return cov


def _ellipse(center: FloatArray, cov2: FloatArray, scale: float) -> FloatArray:
    """Points ``(101, 2)`` of the ellipse ``{x: (x-c)ᵀ Σ⁻¹ (x-c) = scale²}``."""
    vals, vecs = np.linalg.eigh(0.5 * (cov2 + cov2.T))
    t = np.linspace(0, 2 * np.pi, 101)
    circle = np.stack([np.cos(t), np.sin(t)], axis=1)
    out: FloatArray = center + scale * (circle * np.sqrt(np.maximum(vals, 0))) @ vecs.T
    return out


def _unit(metres: float) -> tuple[float, str]:
    """A display factor and unit for a length: mm, cm or m."""
    if metres < 0.01:
        return 1000.0, "mm"
    if metres < 1.0:
        return 100.0, "cm"
    return 1.0, "m"


# --------------------------------------------------------------------------- scans


def plot_scan_alignment(
    path: PathLike,
    source: FloatArray,
    target: FloatArray,
    pose: SE2,
    covariance: Any = None,
    *,
    title: str | None = None,
) -> Path:
    """2D scans before and after alignment, and the pose's uncertainty.

    Parameters
    ----------
    path : str or Path
        Where to write the figure (``.png`` / ``.svg``).
    source, target : (N, 2), (M, 2) float64
        Points in their own frames (metres).
    pose : SE2
        ``T_target_source`` (e.g. a registration result's ``pose``).
    covariance : (3, 3), optional
        Over scanreg's tangent ``[ρx, ρy, θ]`` (body frame). The third panel then shows the
        95 % ellipse of the source origin's position in the target frame (``R Σ_ρρ Rᵀ``,
        zoomed, in cm or mm) and the heading ± 2σ_θ.

    Returns
    -------
    Path
        ``path``.
    """
    out = _check_path(path)
    src = as_points(source, "source", dim=2)
    tgt = as_points(target, "target", dim=2)
    if not isinstance(pose, SE2):
        raise TypeError(f"pose: expected a scanreg.SE2, got {type(pose).__name__}")
    cov = None if covariance is None else _covariance(covariance, "covariance", 3)
    panels = 3 if cov is not None else 2
    fig = _figure(4.6 * panels, 4.6)
    axes = fig.subplots(1, panels)
    moved = pose.apply(src)
    for ax, pts, label in ((axes[0], src, "before"), (axes[1], moved, "after")):
        ax.scatter(
            tgt[:, 0], tgt[:, 1], s=14, c=_COLORS["target"], label="target", lw=0, alpha=0.45
        )
        ax.scatter(pts[:, 0], pts[:, 1], s=3, c=_COLORS["source"], label="source", lw=0)
        ax.set_title(f"{label} alignment")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x [m] (target frame)")
    axes[0].set_ylabel("y [m]")
    origin = pose.translation
    heading = np.array([np.cos(pose.angle), np.sin(pose.angle)])
    axes[1].plot(*origin, marker="+", color="k", ms=10, ls="none", label="source origin")
    for ax in axes[:2]:
        ax.legend(loc="upper right", markerscale=2, fontsize=8)
    if cov is not None:
        ax = axes[2]
        rot = pose.rotation
        cov_xy = rot @ cov[:2, :2] @ rot.T
        sigma_t = float(np.sqrt(max(np.linalg.eigvalsh(cov_xy)[-1], 0.0)))
        sigma_theta = float(np.sqrt(max(cov[2, 2], 0.0)))
        factor, unit = _unit(3 * sigma_t)
        ell = (_ellipse(origin, cov_xy, float(np.sqrt(_CHI2_2DOF_95))) - origin) * factor
        ax.fill(ell[:, 0], ell[:, 1], color=_COLORS["source"], alpha=0.25, lw=0)
        ax.plot(ell[:, 0], ell[:, 1], color=_COLORS["source"], label="95 % position region")
        radius = max(float(np.abs(ell).max()), 1e-12)
        ax.plot([0, heading[0] * radius], [0, heading[1] * radius], color="k", lw=1.5)
        # ±2σ_θ is often far below a degree: widen the wedge to be seen, and say by how much
        half = 2 * sigma_theta
        widen = max(1.0, np.radians(4.0) / max(half, 1e-300))
        for sign in (-1, 1):
            a = pose.angle + sign * half * widen
            ax.plot([0, np.cos(a) * radius], [0, np.sin(a) * radius], color="k", ls="--", lw=1)
        wedge = "heading ± 2σ_θ" + (f" (drawn ×{widen:.3g} wider)" if widen > 1 else "")
        ax.plot([], [], color="k", ls="--", lw=1, label=wedge)
        ax.plot(0, 0, marker="+", color="k", ms=10)
        lim = 1.25 * radius
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_aspect("equal")
        ax.set_xlabel(f"Δx [{unit}] about the estimate")
        ax.set_ylabel(f"Δy [{unit}]")
        sigma_deg = np.degrees(sigma_theta)
        ax.set_title(f"uncertainty: σ_xy ≤ {sigma_t * factor:.3g} {unit}, σ_θ = {sigma_deg:.3g}°")
        ax.legend(loc="upper right", fontsize=8)
        ax.grid(alpha=0.3)
    vec = pose.as_vector()
    fig.suptitle(
        title
        or f"T_target_source: t = ({vec[0]:.3f}, {vec[1]:.3f}) m, θ = {np.degrees(vec[2]):.2f}°"
    )
    return _save(fig, out)


# --------------------------------------------------------------------------- trajectories


def _aligned_pairs(
    estimate: Trajectory, reference: Trajectory, alignment: str
) -> tuple[Trajectory, Trajectory]:
    from .eval.align import align, associate

    if alignment not in ("none", "se3", "sim3"):
        raise ValueError(f"alignment: expected 'none', 'se3' or 'sim3', got {alignment!r}")
    ref, est = associate(reference, estimate, max_difference=0.01)
    aligned, _ = align(ref, est, alignment)
    return ref, aligned


PLANES = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}


def _plane_axes(plane: str, positions: FloatArray) -> tuple[int, int]:
    if plane == "auto":
        spread = np.ptp(positions, axis=0)
        i, j = sorted(int(k) for k in np.argsort(spread)[-2:])
        return i, j
    if plane not in PLANES:
        raise ValueError(f"plane: expected 'auto', 'xy', 'xz' or 'yz', got {plane!r}")
    return PLANES[plane]


def _break_at_gaps(positions: FloatArray, stamps: FloatArray | None) -> FloatArray:
    """Positions with a NaN row wherever the time step exceeds 5× the median step, so that
    a gap (lost tracking, unmatched poses) is not drawn as a straight segment."""
    if stamps is None or len(stamps) < 3:
        return positions
    dt = np.diff(stamps)
    gaps = np.flatnonzero(dt > 5 * max(float(np.median(dt)), 1e-12)) + 1
    out: FloatArray = np.insert(positions, gaps, np.nan, axis=0)
    return out


def plot_trajectories(
    path: PathLike,
    estimate: Trajectory,
    reference: Trajectory | None = None,
    *,
    alignment: str = "none",
    plane: str = "auto",
    labels: tuple[str, str] = ("estimate", "reference"),
    title: str | None = None,
) -> Path:
    """Top view of an estimated trajectory, optionally against a reference.

    ``alignment`` (``"none"``, ``"se3"``, ``"sim3"``) aligns the estimate to the reference
    first, as for the ATE; poses are paired as :func:`scanreg.eval.absolute_trajectory_error`
    pairs them. ``plane`` is ``"xy"``, ``"xz"``, ``"yz"`` or ``"auto"``: the two axes along
    which the positions spread most (``"xz"`` for KITTI's camera frame, y pointing down).
    Start (○) and end (□) are marked; time gaps (more than 5× the median step, e.g. lost
    tracking) are left open rather than drawn as straight segments.
    """
    out = _check_path(path)
    est = _trajectory(estimate, "estimate")
    if reference is not None:
        ref = _trajectory(reference, "reference")
        ref, est = _aligned_pairs(est, ref, alignment)
    elif alignment != "none":
        raise ValueError("alignment: needs a reference")
    series = [(est, labels[0], _COLORS["estimate"], "-")]
    if reference is not None:
        series.insert(0, (ref, labels[1], _COLORS["reference"], "--"))
    i, j = _plane_axes(plane, np.concatenate([t.positions for t, *_ in series]))
    fig = _figure(6.4, 6.0)
    ax = fig.subplots()
    for traj, label, color, style in series:
        p = traj.positions
        line = _break_at_gaps(p, traj.timestamps)
        ax.plot(line[:, i], line[:, j], style, color=color, label=label, lw=1.5)
        ax.plot(p[0, i], p[0, j], "o", color=color, mfc="none", ms=8)
        ax.plot(p[-1, i], p[-1, j], "s", color=color, mfc="none", ms=8)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(f"{'xyz'[i]} [m]")
    ax.set_ylabel(f"{'xyz'[j]} [m]")
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    suffix = "" if reference is None or alignment == "none" else f" ({alignment}-aligned)"
    ax.set_title(title or f"trajectory, top view{suffix}")
    return _save(fig, out)


def plot_error_over_distance(
    path: PathLike,
    estimate: Trajectory,
    reference: Trajectory,
    *,
    alignment: str = "none",
    title: str | None = None,
) -> Path:
    """Position and rotation error of each pose against the distance travelled.

    The distance is the reference's path length from its first paired pose; the errors are
    ``|t_ref − t_est|`` and the angle of ``R_refᵀ R_est`` after ``alignment`` (see
    :func:`plot_trajectories`).
    """
    out = _check_path(path)
    ref, est = _aligned_pairs(
        _trajectory(estimate, "estimate"), _trajectory(reference, "reference"), alignment
    )
    from .eval import _poses

    distance = _poses.path_lengths(ref.positions)
    position_error = np.linalg.norm(ref.positions - est.positions, axis=1)
    rotation_error = np.degrees(_poses.rotation_angle(_poses.relative(ref.poses, est.poses)))
    fig = _figure(7.5, 5.0)
    ax_t, ax_r = fig.subplots(2, 1, sharex=True)
    ax_t.plot(distance, position_error, color=_COLORS["estimate"], lw=1.5)
    ax_t.set_ylabel("position error [m]")
    ax_t.grid(alpha=0.3)
    ax_r.plot(distance, rotation_error, color="#2ca02c", lw=1.5)
    ax_r.set_ylabel("rotation error [°]")
    ax_r.set_xlabel("distance travelled along the reference [m]")
    ax_r.grid(alpha=0.3)
    ax_t.set_ylim(bottom=0)
    ax_r.set_ylim(bottom=0)
    final = 100 * position_error[-1] / max(float(distance[-1]), 1e-12)
    ax_t.set_title(
        title
        or f"error over distance ({alignment} alignment): {position_error[-1]:.3g} m "
        f"after {distance[-1]:.4g} m ({final:.3g} %)"
    )
    return _save(fig, out)


# --------------------------------------------------------------------------- quality


def plot_weak_directions(
    path: PathLike,
    points: FloatArray,
    conditioning: Conditioning,
    *,
    degeneracy: Degeneracy | None = None,
    all_directions: bool = False,
    max_arrows: int = 60,
    title: str | None = None,
) -> Path:
    """Points (top view) with each poorly constrained direction drawn as arrows.

    A tangent direction ``v = [ρ, φ]`` moves a point ``p`` of the source (body) frame by
    ``ρ + φ × p`` (right perturbation), so a rotation turns points about the source origin,
    not about their centroid. Each direction gets a panel with that motion drawn as arrows
    at up to ``max_arrows`` points (top view: the x, y components in 3D), labelled with its
    description and scaled ratio (1 = as well constrained as the best direction).

    Parameters
    ----------
    points : (N, 2) or (N, 3) float64
        The source points in the source frame (where ``δ`` acts), matching the conditioning.
    conditioning : Conditioning
        From a registration result (``result.conditioning``).
    degeneracy : Degeneracy, optional
        The result's verdict on weakness (``result.degeneracy``): its weak directions are
        drawn, and the title says whether the result is degenerate. Without it, the weakest
        direction of ``conditioning``.
    all_directions : bool
        Draw every eigen-direction, not only the weak ones (or, when there are none, the
        weakest).
    """
    out = _check_path(path)
    pts = as_points(points, "points")
    if not isinstance(conditioning, Conditioning):
        raise TypeError(
            f"conditioning: expected a scanreg.quality.Conditioning, "
            f"got {type(conditioning).__name__}"
        )
    dof = conditioning.eigenvalues.shape[0]
    dim = {3: 2, 6: 3}.get(dof)
    if dim is None or pts.shape[1] != dim:
        raise ValueError(
            f"points: the conditioning is over {dof} dof, expected shape (N, {dim or '?'}), "
            f"got {pts.shape}"
        )
    if isinstance(max_arrows, bool) or not isinstance(max_arrows, int) or max_arrows < 1:
        raise ValueError(f"max_arrows: expected a positive integer, got {max_arrows!r}")
    from .quality import describe_direction

    length = conditioning.length_scale
    if all_directions:
        shown = [
            (v, r, describe_direction(v, dim, length))
            for v, r in _scaled_directions(conditioning, dim)
        ]
    else:
        weak = () if degeneracy is None else degeneracy.weak_directions
        chosen = weak or (conditioning.weakest,)
        shown = [(w.vector, w.ratio, w.description) for w in chosen]
    cols = min(len(shown), 3)
    rows = -(-len(shown) // cols)
    fig = _figure(max(5.2 * cols, 6.4), 5.2 * rows + 0.6)
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).reshape(-1)
    extent = float(np.ptp(pts[:, :2], axis=0).max()) or 1.0
    # one arrow per grid cell, so dense clusters near the sensor do not bury the rest
    cells = np.floor((pts[:, :2] - pts[:, :2].min(axis=0)) / (extent / np.sqrt(max_arrows)))
    _, first = np.unique(cells, axis=0, return_index=True)
    first = np.sort(first)
    at = pts[first[:: max(1, first.size // max_arrows)]]
    palette = ["#d62728", "#ff7f0e", "#9467bd", "#2ca02c", "#1f77b4", "#8c564b"]
    for k, (vec, ratio, text) in enumerate(shown):
        ax = axes[k]
        v = np.asarray(vec, dtype=np.float64)
        if dim == 2:
            motion = v[:2] + v[2] * np.stack([-at[:, 1], at[:, 0]], axis=1)
        else:
            motion = (v[:3] + np.cross(v[3:], at))[:, :2]
            full = v[:3] + np.cross(v[3:], at)
        in_plane = float(np.linalg.norm(motion, axis=1).max())
        scale = 0.12 * extent / max(in_plane, 1e-300)
        ax.scatter(pts[:, 0], pts[:, 1], s=3, c="#888888", lw=0)
        ax.quiver(
            at[:, 0],
            at[:, 1],
            motion[:, 0] * scale,
            motion[:, 1] * scale,
            color=palette[k % len(palette)],
            angles="xy",
            scale_units="xy",
            scale=1.0,
            width=0.006,
        )
        ax.plot(0, 0, marker="+", color="k", ms=12, mew=2)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x [m] (source frame; + = origin)")
        ax.set_ylabel("y [m]")
        ax.grid(alpha=0.3)
        note = ""
        if dim == 3:
            share = in_plane / max(float(np.linalg.norm(full, axis=1).max()), 1e-300)
            if share < 0.5:
                note = "\n(mostly out of the xy plane: arrows short in this view)"
        ax.set_title(f"{text}\nscaled ratio {ratio:.3g}{note}", fontsize=9)
    for ax in axes[len(shown) :]:
        ax.set_visible(False)
    if degeneracy is None:
        state = "weakest direction"
    else:
        state = "degenerate" if degeneracy.degenerate else "well conditioned"
    fig.suptitle(
        title
        or f"{state} (scaled condition number {conditioning.scaled_condition_number:.3g})\n"
        "arrows: how the points move along each direction"
    )
    return _save(fig, out)


def _scaled_directions(conditioning: Conditioning, dim: int) -> list[tuple[FloatArray, float]]:
    """Every eigen-direction of the scaled information matrix, in metres / radians."""
    dof = conditioning.eigenvalues.shape[0]
    vals, vecs = conditioning.eigenvalues, conditioning.eigenvectors
    hessian = vecs @ np.diag(vals) @ vecs.T
    s_inv = np.ones(dof)
    s_inv[dim:] = 1.0 / conditioning.length_scale
    svals, svecs = np.linalg.eigh(hessian * np.outer(s_inv, s_inv))
    out = []
    for i in range(dof):
        v = svecs[:, i] * s_inv
        out.append((v / np.linalg.norm(v), float(svals[i] / svals[-1])))
    return out


def plot_residual_histogram(
    path: PathLike,
    residuals: Any,
    *,
    bins: int = 50,
    threshold: float | None = None,
    unit: str = "m",
    log: bool = False,
    title: str | None = None,
) -> Path:
    """Histogram of residuals (distances or signed distances), with RMSE and median marked.

    ``threshold`` (e.g. the maximum correspondence distance or a kernel's scale) is drawn
    as a vertical line, with the share of residuals beyond it. ``log=True`` puts the counts
    on a log scale, so that a thin tail of outliers shows.
    """
    out = _check_path(path)
    if not isinstance(residuals, np.ndarray):
        raise TypeError(f"residuals: expected a numpy.ndarray, got {type(residuals).__name__}")
    if residuals.dtype.kind not in "fiu":
        raise TypeError(f"residuals: expected a real numeric array, got dtype {residuals.dtype}")
    r = np.asarray(residuals, dtype=np.float64).reshape(-1)
    if r.size == 0:
        raise ValueError("residuals: is empty")
    if not np.isfinite(r).all():
        raise ValueError("residuals: contains NaN or inf")
    if isinstance(bins, bool) or not isinstance(bins, (int, np.integer)) or bins < 1:
        raise ValueError(f"bins: expected a positive integer, got {bins!r}")
    if threshold is not None and not (np.isfinite(threshold) and threshold > 0):
        raise ValueError(f"threshold: must be finite and > 0, got {threshold}")
    fig = _figure(6.4, 4.2)
    ax = fig.subplots()
    ax.hist(r, bins=int(bins), color="#1f77b4", alpha=0.8, log=bool(log))
    rmse = float(np.sqrt(np.mean(r**2)))
    median = float(np.median(np.abs(r)))
    ax.axvline(median, color="k", ls=":", label=f"median |r| = {median:.3g} {unit}")
    ax.axvline(rmse, color="k", ls="--", label=f"RMSE = {rmse:.3g} {unit}")
    if r.min() < 0:
        ax.axvline(-median, color="k", ls=":")
        ax.axvline(-rmse, color="k", ls="--")
    if threshold is not None:
        beyond = float(np.mean(np.abs(r) > threshold))
        ax.axvline(threshold, color="#d62728", label=f"threshold {threshold:.3g} {unit}")
        ax.plot([], [], " ", label=f"{100 * beyond:.1f} % beyond")
        if r.min() < 0:
            ax.axvline(-threshold, color="#d62728")
    ax.set_xlabel(f"residual [{unit}]")
    ax.set_ylabel("count")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(title or f"{r.size} residuals")
    return _save(fig, out)


__all__ = [
    "FORMATS",
    "plot_error_over_distance",
    "plot_residual_histogram",
    "plot_scan_alignment",
    "plot_trajectories",
    "plot_weak_directions",
]


def plot_frame_uncertainty(
    path: PathLike,
    covariances: Any,
    *,
    accepted: Any = None,
    held: Any = None,
    title: str | None = None,
) -> Path:
    """Per-frame standard deviations of an odometry run: translation (x, y, z in cm) above,
    rotation (roll, pitch, yaw in degrees) below, on a log scale. ``covariances`` is
    ``(K, 6, 6)`` (translation first; ``inf`` rows, e.g. the first frame, are left out);
    ``accepted`` and ``held`` are optional ``(K,)`` flags: rejected frames get a red tick at
    the bottom, frames held to the motion prior an orange one."""
    out = _check_path(path)
    cov = np.asarray(covariances, dtype=np.float64)
    if cov.ndim != 3 or cov.shape[1:] != (6, 6) or len(cov) == 0:
        raise ValueError(f"covariances: expected shape (K, 6, 6) with K >= 1, got {cov.shape}")
    k = np.arange(len(cov))
    with np.errstate(invalid="ignore"):
        sd = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0, None))
    sd[~np.isfinite(sd)] = np.nan
    fig = _figure(7.0, 5.0)
    top, bottom = fig.subplots(2, 1, sharex=True)
    for axis, (lo, scale, unit, names) in zip(
        (top, bottom),
        ((0, 100.0, "cm", "xyz"), (3, np.degrees(1.0), "deg", ("roll", "pitch", "yaw"))),
        strict=True,
    ):
        for c in range(3):
            axis.plot(k, sd[:, lo + c] * scale, lw=1.2, label=f"σ {names[c]}")
        axis.set_yscale("log")
        axis.set_ylabel(f"σ [{unit}]")
        axis.grid(alpha=0.3, which="both")
        axis.legend(loc="upper right", ncols=3, fontsize="small")
    for flags, color, label in ((accepted, "#d62728", "rejected"), (held, "#ff7f0e", "held")):
        if flags is None:
            continue
        f = np.asarray(flags, dtype=bool)
        marks = k[~f] if label == "rejected" else k[f]
        if marks.size:
            bottom.plot(
                marks,
                np.full(marks.size, np.nanmin(sd[:, 3:] * np.degrees(1.0))),
                "|",
                color=color,
                ms=12,
                label=label,
            )
    bottom.set_xlabel("frame")
    top.set_title(title or "per-frame standard deviation (given the local map)")
    return _save(fig, out)
