"""Degeneracy: which pose directions the scene does not constrain, named in pose coordinates.

The analysis works on the *plane information* ``G = Σ J Jᵀ`` of the point-to-plane/line factor
over the final correspondences (for every method: point-to-point's own ``JᵀJ`` has ``N·I`` as
its translation block and cannot see a corridor). It is made unit-independent and
size-independent before its eigenvalues are compared:

* rotation about tangent axis ``a`` is expressed in metres at that axis' lever ``L_a``, the RMS
  distance of the source points from the axis through the source origin (about which the right
  perturbation rotates), so ``S = diag(1.., L_a..)``;
* ``Ĝ = S⁻¹ G S⁻¹ / n`` over the ``n`` correspondences. An eigenvalue of ``Ĝ`` along a unit
  direction ``v`` is then the mean squared constraint per correspondence, e.g. the mean of
  ``(n_i·v)²`` for a translation: 1 when every surface faces ``v``, 0 in a corridor along ``v``.

Noisy normals fake information: a normal off by ``δn`` gives its correspondence a share
``(δn·v)²`` along a direction ``v`` no surface faces (a tunnel's axis gains ``ε²`` per
correspondence for a normal error of ``ε²`` per tangent axis; sparse LiDAR rings make a few
normals badly wrong). Where both scans' normals are known at the correspondences, ``G`` is
judged *less what that noise adds in expectation*, ``ε² Σ Aᵀ(I − m mᵀ)A`` (``m`` the normal
in the source frame, ``A`` the point Jacobian), with ``ε²`` half the mean squared sine
between the two normals of a correspondence per tangent axis (``removed_normal_noise``).

Sparse LiDAR rings fake more than noise: a ring's neighbourhood is nearly a line, and the
normal fitted to it can point anywhere about that line (along a tunnel's axis, for a ring
around it). A prepared target flags those linear neighbourhoods
(:attr:`scanreg.PreparedTarget.linear`); their correspondences are then left out of ``G`` and
of ``n`` (they still count for the point noise). Along the simulated VLP-16 tunnel's axis they
had supplied 0.019-0.023 per correspondence of the 0.023 measured; the rest holds 0.003.

A direction is **weak** when its eigenvalue is below ``threshold = max(floor, noise_factor ·
ε̃²)``: ``ε̃²`` is the typical squared error of the target normals, measured on the data (half
the median squared sine between each normal and its nearest neighbour's), i.e. the information
along any direction that noisy normals alone produce; ``noise_factor = 6``. The ``floor`` is
what neither clutter nor a few stray correspondences can supply:

* linear neighbourhoods known and left out (a target from :func:`scanreg.prepare` in 3D):
  ``max(0.01, 20 / n)`` — the equivalent of 1 % of the correspondences facing the direction,
  twice what the 2D corridor's and five times what the tunnel's axis keep (0.004-0.005,
  0.003), and never fewer than 20 of them. Simulated VLP-16 / HDL-32 street pairs keep
  0.017-0.027 along their weakest direction (a rotation about a horizontal axis, held by the
  ground near the sensor) and pass;
* otherwise (2D, a map's or a covariance's normals, which carry no such flags): ``0.03``,
  fewer than the equivalent of 3 % of the correspondences facing it, set above what the
  rings' guesses fake.

On the simulated scenes the floor decides (sensor noise of 2–3 cm makes ``6 ε̃² < 0.001``); the
noise term raises the threshold for noisy sensors. The measurements that support both are in
``docs/calibration.md``.

The analysis itself runs in the core (``scanreg_core::trust::degeneracy``, one call per result
with the rest of the trust arithmetic, :mod:`scanreg.trust`); :class:`Degeneracy` holds it.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from . import _core
from ._validate import FloatArray, LazyFields, as_matrix, as_points
from .quality import WeakDirection


@dataclass(frozen=True)
class Degeneracy(LazyFields):
    """Eigen-analysis of the normalised, scaled plane information (see module docstring)."""

    #: ``Ĝ = S⁻¹ G S⁻¹ / n`` (dof × dof), unitless.
    information: FloatArray
    #: Rotation levers ``L_a`` (units of the points), one per rotation axis.
    levers: FloatArray
    #: Eigenvalues of ``Ĝ``, ascending (mean squared constraint per correspondence).
    eigenvalues: FloatArray
    #: Every eigen-direction, weakest first, in tangent coordinates (unit length in metres).
    directions: tuple[WeakDirection, ...]
    #: Those below ``threshold``.
    weak_directions: tuple[WeakDirection, ...]
    threshold: float
    #: ``ε̂²``: mean squared normal error measured on the target, creases included (``nan`` if
    #: not measured); its root is the resolution of a weak direction's components.
    normal_noise: float
    #: ``ε̃²``: the median counterpart (clutter and creases left out); sets the threshold.
    typical_normal_noise: float
    #: ``"plane_information"`` (target normals available) or ``"hessian"`` (the method's own
    #: ``JᵀWJ``, when the target has no normals).
    basis: str
    #: Correspondences ``n`` behind ``information`` (sets how well its eigenvectors are known;
    #: those at a linear target neighbourhood left out, see the module docstring).
    num_correspondences: int = 0
    #: ``ε²`` whose expected information was removed from ``information`` (see the module
    #: docstring); ``nan``: not measured (no source normals), nothing removed.
    removed_normal_noise: float = math.nan

    @property
    def degenerate(self) -> bool:
        return bool(self.weak_directions)

    def scaling(self) -> FloatArray:
        """``diag(S⁻¹)``: tangent = ``S⁻¹`` × scaled coordinates (``1`` for translation,
        ``1/L_a`` for rotation)."""
        dim = self.information.shape[0] - self.levers.size
        out: FloatArray = np.concatenate([np.ones(dim), 1.0 / self.levers])
        return out

    @functools.cached_property
    def _eigen(self) -> tuple[FloatArray, FloatArray]:
        # Once per analysis: the weak and strong bases and the tilts all read it.
        vals, vecs = np.linalg.eigh(self.information)
        return vals, vecs

    def weak_basis(self) -> FloatArray:
        """``(dof, w)`` orthonormal basis of the weak subspace in *scaled* coordinates: the
        eigenvectors of ``information`` below the threshold, as measured. Components below the
        normal noise are not zeroed: that would be right only for a corridor along a sensor
        axis (at any other heading it snaps the axis off the true one); the eigenvector's own
        uncertainty is carried by :meth:`tilt_variances` instead."""
        return self._eigen[1][:, : len(self.weak_directions)]

    def strong_basis(self) -> FloatArray:
        """``(dof, dof − w)`` the other eigenvectors of ``information`` (scaled coordinates),
        orthonormal and orthogonal to :meth:`weak_basis`."""
        return self._eigen[1][:, len(self.weak_directions) :]

    def tilt_variances(self, normal_noise: float) -> FloatArray:
        """``(w, dof − w)`` variance of each weak eigenvector's tilt towards each strong one
        (scaled coordinates), from normal noise ``ε²`` (rad² per tangent axis).

        First-order perturbation of ``Ĝ = (1/n) Σ J Jᵀ``: a normal error ``δn`` changes
        ``u_jᵀ Ĝ w`` by ``(1/n) Σ (u_jᵀ J)(δJᵀ w)`` (the other term vanishes, ``Jᵀ w ≈ 0``
        along a weak ``w``), of variance ``ε² λ_j / n``; the tilt is that over
        ``λ_j − λ_w``. Along a corridor known to ``±σ`` the estimate can be off across it by
        ``σ · tilt``: without this the well-determined directions claim what a slightly
        mis-estimated axis contradicts (the tunnel, ``docs/calibration.md``). ``NaN`` (not
        measured) gives zeros.
        """
        if isinstance(normal_noise, bool) or not isinstance(
            normal_noise, (int, float, np.integer, np.floating)
        ):
            raise TypeError(f"normal_noise: expected a number, got {type(normal_noise).__name__}")
        eps2 = float(normal_noise)
        if math.isnan(eps2):
            eps2 = 0.0
        elif not (math.isfinite(eps2) and eps2 >= 0.0):
            raise ValueError(
                f"normal_noise: must be finite and >= 0 (NaN: not measured), got {eps2}"
            )
        vals, _ = self._eigen
        nw = len(self.weak_directions)
        n = max(self.num_correspondences, 1)
        gap = vals[None, nw:] - vals[:nw, None]
        out: FloatArray = eps2 * vals[None, nw:] / (n * np.maximum(gap, 1e-12) ** 2)
        return out

    def weak_projector(self) -> FloatArray:
        """``(dof, dof)`` projector onto the weak subspace along the strong one, in tangent
        coordinates (``S⁻¹ W Wᵀ S`` with ``W`` = :meth:`weak_basis`)."""
        s_inv = self.scaling()
        w = self.weak_basis()
        out: FloatArray = (w @ w.T) * np.outer(s_inv, 1.0 / s_inv)
        return out


#: The threshold's floor in 2D (the core's ``degeneracy::MIN_CONSTRAINT``; module docstring).
MIN_CONSTRAINT_2D = 0.03


class HeldSteps(NamedTuple):
    """What :func:`held_steps_2d` found weak, as step projectors ``I − P_w``."""

    #: Over the registration's tangent (about the source origin).
    projector: FloatArray
    #: The source points' centroid (source frame) ...
    centroid: FloatArray
    #: ... and the projector over the tangent about it (the source moved to its centroid).
    centred: FloatArray


def held_steps_2d(
    hessian: FloatArray, source: FloatArray, count: int, floor: float = MIN_CONSTRAINT_2D
) -> HeldSteps | None:
    """The step projector ``I − P_w`` that keeps a 2D point-to-line solve at its start along
    the directions its own ``hessian`` (over ``count`` correspondences) leaves weak, or None
    when none is.

    The analysis's scaled information (module docstring) with the rotation taken about the
    ``source`` points' centroid and its lever their RMS distance from it, directions below
    ``floor``: unlike the analysis's (about the source origin, whose lever grows with the
    distance of the points from it: 1 km away the Intel pairs of tests/test_frames.py all
    read degenerate) it is the same in every frame the points are given in — with a
    ``hessian`` evaluated on the source about its centroid (one far from its origin, moved
    here, has lost its digits). Noisy normals' share is not taken off; on the first 400
    Freiburg relation pairs of each log from the odometry (1 200 results) every result it
    finds weak the analysis finds degenerate (Intel 75 of 76, ACES 104 of 104, hospital 17
    of 23). :class:`HeldSteps` has it over the registration's tangent and about the
    centroid."""
    _check_count(count)
    if count == 0:
        return None
    hessian = as_matrix(hessian, "hessian", (3, 3))
    source = as_points(source, "source", dim=2, min_points=0, finite=False)
    pts, (cx, cy), spread = _centroid_and_spread_2d(source)
    if len(pts) == 0:
        return None
    lever = max(spread, 1e-9)
    # δ about the origin -> about the centroid: the translation u = v + ω c⊥, c⊥ = (−c_y, c_x).
    to_centroid = np.array([[1.0, 0.0, -cy], [0.0, 1.0, cx], [0.0, 0.0, 1.0]])
    from_centroid = np.array([[1.0, 0.0, cy], [0.0, 1.0, -cx], [0.0, 0.0, 1.0]])
    s_inv = np.array([1.0, 1.0, 1.0 / lever])
    g = from_centroid.T @ np.asarray(hessian, dtype=np.float64) @ from_centroid
    g *= np.outer(s_inv, s_inv) / count
    if _smallest_eigenvalue_3(g) >= floor:
        return None
    vals, vecs = np.linalg.eigh(g)
    w = vecs[:, vals < floor]
    if w.shape[1] == 0:
        return None
    weak_centroid = (w @ w.T) * np.outer(s_inv, 1.0 / s_inv)
    return HeldSteps(
        projector=np.ascontiguousarray(np.eye(3) - from_centroid @ weak_centroid @ to_centroid),
        centroid=np.array([cx, cy]),
        centred=np.ascontiguousarray(np.eye(3) - weak_centroid),
    )


def _centroid_and_spread_2d(
    source: FloatArray,
) -> tuple[FloatArray, tuple[float, float], float]:
    """The finite rows of a 2D ``source``, their centroid and their RMS distance from it (the
    lever :func:`held_steps_2d` and the registration's screen take the rotation with);
    ``(0, 0)`` and 0 when no row is finite."""
    pts = source if np.isfinite(source).all() else source[np.isfinite(source).all(axis=1)]
    if len(pts) == 0:
        return pts, (0.0, 0.0), 0.0
    cx, cy = (float(v) for v in pts.mean(axis=0))
    q = pts - np.array([cx, cy])
    return pts, (cx, cy), math.sqrt(float(np.einsum("ij,ij->", q, q)) / len(q))


def _check_count(count: Any) -> None:
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 0:
        raise ValueError(f"count: expected an int >= 0, got {count!r}")


def weakest_about_centroid_2d(
    hessian: FloatArray, centroid: tuple[float, float], spread: float, count: int
) -> float:
    """:func:`_weakest_about_centroid_2d` with its arguments checked (naming the bad one)."""
    h = as_matrix(hessian, "hessian", (3, 3))
    c = as_matrix(centroid, "centroid", (2,))
    if not (math.isfinite(spread) and spread >= 0):
        raise ValueError(f"spread: must be finite and >= 0, got {spread!r}")
    _check_count(count)
    if count == 0:
        raise ValueError("count: must be > 0 (no correspondences: no information)")
    return _weakest_about_centroid_2d(h, (float(c[0]), float(c[1])), float(spread), int(count))


def _weakest_about_centroid_2d(
    hessian: FloatArray, centroid: tuple[float, float], spread: float, count: int
) -> float:
    """The smallest eigenvalue :func:`held_steps_2d` compares with its floor, from a 2D
    ``hessian`` over ``count`` correspondences about the source origin, the points' ``centroid``
    and ``spread`` (RMS distance from it), in plain float arithmetic: the screen every default
    2D call runs (a few µs). Exact while the centroid is within ~100 spreads of the origin
    (the moved Hessian loses digits as the square of that ratio)."""
    h: list[list[float]] = np.asarray(hessian, dtype=np.float64).tolist()
    cx, cy = centroid
    s = 1.0 / max(spread, 1e-9)
    # Fᵀ H F with F's last column (c_y, −c_x, 1): the rotation about the centroid.
    e0 = h[0][0] * cy - h[0][1] * cx + h[0][2]
    e1 = h[1][0] * cy - h[1][1] * cx + h[1][2]
    e2 = (
        cy * cy * h[0][0]
        + cx * cx * h[1][1]
        + h[2][2]
        - 2.0 * cx * cy * h[0][1]
        + 2.0 * cy * h[0][2]
        - 2.0 * cx * h[1][2]
    )
    g = [
        [h[0][0] / count, h[0][1] / count, e0 * s / count],
        [h[0][1] / count, h[1][1] / count, e1 * s / count],
        [e0 * s / count, e1 * s / count, e2 * s * s / count],
    ]
    return _smallest_eigenvalue_3(g)


def _smallest_eigenvalue_3(g: FloatArray | list[list[float]]) -> float:
    """The smallest eigenvalue of a symmetric 3×3 ``g``, in closed form (Smith 1961; a few
    µs in Python: it runs on every default 2D call). NaN if ``g`` has one."""
    h: list[list[float]] = g if isinstance(g, list) else g.tolist()
    a, b, c = h[0][0], h[1][1], h[2][2]
    d, e, f = h[0][1], h[0][2], h[1][2]
    mean = (a + b + c) / 3.0
    off = d * d + e * e + f * f
    p2 = ((a - mean) ** 2 + (b - mean) ** 2 + (c - mean) ** 2 + 2.0 * off) / 6.0
    if p2 <= 1e-30 * max(mean * mean, 1e-300):
        return mean
    p = math.sqrt(p2)
    a0, b0, c0 = (a - mean) / p, (b - mean) / p, (c - mean) / p
    det = (
        a0 * (b0 * c0 - f * f / p2)
        - d / p * (d / p * c0 - f * e / p2)
        + e / p * (d * f / p2 - b0 * e / p)
    )
    phi = math.acos(min(1.0, max(-1.0, det / 2.0))) / 3.0
    return mean + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)


def normal_noise(
    target_points: FloatArray, normals: FloatArray, index: _core.KdTree
) -> tuple[float, float]:
    """``(ε̂², ε̃²)``: half the mean and half the median squared sine between a normal and its
    nearest neighbour's (``index``: the k-d tree over ``target_points``).

    Two independent normal errors of variance ``ε²`` per tangent axis make a squared sine of
    about ``2ε²``; real creases and clutter add to the mean, not to the median. Up to 2000
    target points are sampled (deterministically). ``nan`` without valid normals.
    """
    if len(index) != len(target_points) or index.dim != target_points.shape[1]:
        raise ValueError("index: must be the k-d tree of target_points")
    return _core.target_normal_noise(index, normals)


def sampled_normals(
    points: FloatArray, num_neighbors: int, max_points: int = 1500
) -> tuple[Any, FloatArray]:
    """Unit normals (PCA of the ``num_neighbors`` nearest neighbours) of at most ``max_points``
    evenly spaced points of ``points``: ``(indices, normals)``. Enough to *measure* normal noise
    at a fraction of the cost of normals for every point."""
    return _core.sampled_normals(points, num_neighbors, max_points)


def correspondence_normal_noise(
    source_normals: FloatArray,
    target_normals: FloatArray,
    rotation: FloatArray,
    correspondences: Any,
) -> float:
    """Variance of a normal's direction per tangent axis (rad²), measured between two scans.

    The source normal (rotated into the target frame) and the target normal of each
    correspondence (``correspondences[i]``: target row of source normal ``i``, -1 for none)
    come from different samplings of the same surface, so their disagreement measures the
    error of normals *including* sampling effects a single scan cannot see (the ring
    structure of a spinning LiDAR tilts all neighbouring normals alike). Each normal errs by
    ``ε²`` per tangent axis, their difference by ``2ε²``: ``ε̂² = mean sin² / (2 (D - 1))``
    over the best 90 % (creases and wrong matches dropped). ``nan`` without enough valid pairs.
    """
    corr = np.ascontiguousarray(correspondences, dtype=np.int64)
    return _core.correspondence_normal_noise(
        np.arange(corr.size, dtype=np.int64),
        source_normals,
        target_normals,
        np.ascontiguousarray(rotation),
        corr,
    )
