"""Rigid transforms SE(2) and SE(3).

Conventions (used everywhere in scanreg)
----------------------------------------
* A pose ``T_target_source`` maps source coordinates into the target frame:
  ``p_T = R p_S + t``. ``T_a_b @ T_b_c == T_a_c``.
* Minimal vectors: ``[tx, ty, θ]`` (SE(2)) and ``[tx, ty, tz, rx, ry, rz]`` with ``r`` the
  rotation vector (axis × angle, radians) (SE(3)). ``t`` is the translation itself.
* Tangent (Lie algebra) vectors are ordered **translation first**: ``[ρx, ρy, θ]`` and
  ``[ρx, ρy, ρz, φx, φy, φz]``; ``exp``/``log`` map between them and poses. Note that ``ρ`` is
  not ``t`` when there is rotation (``t = V(φ) ρ``).
* Perturbations are on the **right**: ``T ⊕ δ = T @ exp(δ)``, so ``δ`` lives in the source
  (body) frame. Every covariance scanreg reports is over this ``δ``. ``T.adjoint()`` moves a
  tangent vector to the left: ``T @ exp(δ) == exp(T.adjoint() @ δ) @ T``, so a covariance in
  the target frame is ``Ad Σ Adᵀ``.
"""

from __future__ import annotations

from typing import Any, TypeVar

import numpy as np

from ._validate import FloatArray, as_matrix, as_points

try:
    # The gufunc behind ``np.linalg.solve`` for one right-hand side: the same LAPACK solve, so
    # the same bits, without the wrapper's ~4 µs of checks (SE2.log runs in every 2D
    # registration's trust analysis). numpy's own wrapper where a numpy release moves it.
    from numpy.linalg._umath_linalg import solve1 as _solve1

    _GUFUNC = True
except ImportError:  # pragma: no cover - numpy layout change
    _GUFUNC = False


def _solve2(a: FloatArray, b: FloatArray) -> FloatArray:
    """``np.linalg.solve(a, b)`` for a nonsingular ``a`` and one right-hand side."""
    out: FloatArray
    if _GUFUNC:
        out = _solve1(a, b, signature="dd->d")
    else:  # pragma: no cover - numpy layout change
        out = np.linalg.solve(a, b).astype(np.float64, copy=False)
    return out


#: Largest tolerated deviation of ``RᵀR`` from identity when a rotation is given; anything
#: within it is projected onto the nearest rotation. Poses read from files carry a few
#: significant digits or float32 round-off (the 3DMatch ground truth: 7e-5), and are rigid all
#: the same; a matrix off by more than this is not a rotation (a 0.1 % scale already is).
ORTHONORMAL_TOLERANCE = 1e-3

_SMALL_ANGLE = 1e-6
# Below this angle, coefficients with cancellation use their Taylor series (error < θ⁶).
_SERIES_ANGLE = 1e-2


def _hat3(v: FloatArray) -> FloatArray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _checked_rotation(rotation: Any, dim: int, name: str, atol: float) -> FloatArray:
    """Validate a rotation matrix and project it onto SO(dim) (removes round-off drift)."""
    r = as_matrix(rotation, name, (dim, dim))
    # Entries past ~1e154 overflow RᵀR (a damaged file: found by fuzz/, kitti_calib): inf is
    # "not orthonormal" too, without numpy's overflow warning.
    with np.errstate(over="ignore", invalid="ignore"):
        err = float(np.abs(r.T @ r - np.eye(dim)).max())
    if not err <= atol:
        raise ValueError(f"{name}: not orthonormal (max |RᵀR - I| = {err:.2e} > {atol:.0e})")
    det = float(np.linalg.det(r))
    if det < 0:
        raise ValueError(f"{name}: is a reflection (det = {det:.6f}); a rotation needs det = +1")
    u, _, vt = np.linalg.svd(r)
    projected: FloatArray = u @ vt
    return projected


def so3_exp(rotvec: FloatArray) -> FloatArray:
    """Rotation matrix of a rotation vector (Rodrigues), exact near zero."""
    theta = float(np.linalg.norm(rotvec))
    k = _hat3(rotvec)
    if theta < _SMALL_ANGLE:
        a, b = 1.0 - theta**2 / 6.0, 0.5 - theta**2 / 24.0
    else:
        a, b = np.sin(theta) / theta, 2.0 * np.sin(0.5 * theta) ** 2 / theta**2
    return np.eye(3) + a * k + b * (k @ k)


def so3_log(rotation: FloatArray) -> FloatArray:
    """Rotation vector of a rotation matrix, stable at 0 and at π (via a unit quaternion)."""
    r = rotation
    trace = float(np.trace(r))
    # Shepperd's method: pick the largest of w², x², y², z² to divide by.
    diag = np.array([trace, r[0, 0], r[1, 1], r[2, 2]])
    i = int(np.argmax(diag))
    if i == 0:
        w = 0.5 * np.sqrt(1.0 + trace)
        xyz = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / (4.0 * w)
    else:
        a = i - 1
        b, c = (a + 1) % 3, (a + 2) % 3
        q = np.zeros(3)
        q[a] = 0.5 * np.sqrt(max(1.0 + r[a, a] - r[b, b] - r[c, c], 0.0))
        q[b] = (r[b, a] + r[a, b]) / (4.0 * q[a])
        q[c] = (r[c, a] + r[a, c]) / (4.0 * q[a])
        w = (r[c, b] - r[b, c]) / (4.0 * q[a])
        xyz = q
    if w < 0:  # the same rotation; keep the angle in [0, π]
        w, xyz = -w, -xyz
    s = float(np.linalg.norm(xyz))
    if s < 1e-12:
        small: FloatArray = 2.0 * xyz / max(w, 1e-300)  # first order: θ·axis ≈ 2·xyz
        return small
    angle = 2.0 * np.arctan2(s, w)
    result: FloatArray = xyz * (angle / s)
    return result


def _so3_left_jacobian(phi: FloatArray) -> FloatArray:
    """``V(φ)`` in ``t = V(φ) ρ`` of the SE(3) exponential."""
    theta = float(np.linalg.norm(phi))
    k = _hat3(phi)
    # 1 - cos θ = 2 sin²(θ/2) avoids cancellation; θ - sin θ needs its series below 1e-2.
    b = 0.5 if theta == 0.0 else 2.0 * np.sin(0.5 * theta) ** 2 / theta**2
    if theta < _SERIES_ANGLE:
        c = 1.0 / 6.0 - theta**2 / 120.0 + theta**4 / 5040.0
    else:
        c = (theta - np.sin(theta)) / theta**3
    return np.eye(3) + b * k + c * (k @ k)


def _so3_left_jacobian_inverse(phi: FloatArray) -> FloatArray:
    theta = float(np.linalg.norm(phi))
    k = _hat3(phi)
    if theta < _SERIES_ANGLE:  # the closed form cancels catastrophically near 0
        d = 1.0 / 12.0 + theta**2 / 720.0 + theta**4 / 30240.0
    else:
        d = (1.0 - theta * np.sin(theta) / (2.0 * (1.0 - np.cos(theta)))) / theta**2
    return np.eye(3) - 0.5 * k + d * (k @ k)


def _so2_v(theta: float) -> FloatArray:
    """``V(θ)`` in ``t = V(θ) ρ`` of the SE(2) exponential."""
    if abs(theta) < _SMALL_ANGLE:
        a, b = 1.0 - theta**2 / 6.0, theta / 2.0 - theta**3 / 24.0
    else:
        a, b = np.sin(theta) / theta, 2.0 * np.sin(0.5 * theta) ** 2 / theta
    return np.array([[a, -b], [b, a]])


def _rot2(theta: float) -> FloatArray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


P = TypeVar("P", bound="_Pose")


class _Pose:
    """Shared behaviour of SE2 and SE3: a rotation ``R`` and translation ``t``, immutable."""

    DIM: int
    DOF: int
    __slots__ = ("_rotation", "_translation")

    _rotation: FloatArray
    _translation: FloatArray

    def __init__(
        self,
        rotation: Any = None,
        translation: Any = None,
        *,
        atol: float = ORTHONORMAL_TOLERANCE,
    ) -> None:
        d = self.DIM
        rot = np.eye(d) if rotation is None else _checked_rotation(rotation, d, "rotation", atol)
        trans = np.zeros(d) if translation is None else as_matrix(translation, "translation", (d,))
        rot.setflags(write=False)
        trans.setflags(write=False)
        object.__setattr__(self, "_rotation", rot)
        object.__setattr__(self, "_translation", trans)

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError(f"{type(self).__name__} is immutable")

    def __reduce__(self) -> tuple[Any, tuple[FloatArray, FloatArray]]:
        # Pickle (multiprocessing, caches) through the constructor path that skips the setattr
        # guard; the arrays are stored exactly, so a round trip is bit-identical.
        return (type(self)._unchecked, (self._rotation, self._translation))

    @classmethod
    def _unchecked(cls: type[P], rotation: FloatArray, translation: FloatArray) -> P:
        return cls._adopt(
            np.array(rotation, dtype=np.float64), np.array(translation, dtype=np.float64)
        )

    @classmethod
    def _adopt(cls: type[P], rotation: FloatArray, translation: FloatArray) -> P:
        """Wrap float64 arrays that nothing else references (fresh results of numpy
        operations) without copying them: they are made read-only in place."""
        rotation.setflags(write=False)
        translation.setflags(write=False)
        return cls._wrap(rotation, translation)

    @classmethod
    def _wrap(cls: type[P], rotation: FloatArray, translation: FloatArray) -> P:
        """Wrap read-only float64 arrays as they are (the core's fresh results: shared with
        the core's outcome, never written)."""
        obj = cls.__new__(cls)
        object.__setattr__(obj, "_rotation", rotation)
        object.__setattr__(obj, "_translation", translation)
        return obj

    # --- construction -------------------------------------------------------------------
    @classmethod
    def identity(cls: type[P]) -> P:
        return cls._unchecked(np.eye(cls.DIM), np.zeros(cls.DIM))

    @classmethod
    def from_rt(cls: type[P], rotation: Any, translation: Any) -> P:
        """From a rotation matrix and a translation vector (validated)."""
        return cls(rotation, translation)

    @classmethod
    def from_matrix(cls: type[P], matrix: Any, *, atol: float = ORTHONORMAL_TOLERANCE) -> P:
        """From a homogeneous ``(D+1, D+1)`` matrix; the last row must be ``[0, ..., 0, 1]``."""
        d = cls.DIM
        m = as_matrix(matrix, "matrix", (d + 1, d + 1))
        bottom = np.zeros(d + 1)
        bottom[d] = 1.0
        if np.abs(m[d] - bottom).max() > atol:
            raise ValueError(f"matrix: last row must be {bottom.tolist()}, got {m[d].tolist()}")
        return cls(m[:d, :d], m[:d, d], atol=atol)

    # --- access -------------------------------------------------------------------------
    @property
    def rotation(self) -> FloatArray:
        """``R`` (read-only view)."""
        return self._rotation

    @property
    def translation(self) -> FloatArray:
        """``t`` (read-only view)."""
        return self._translation

    def as_matrix(self) -> FloatArray:
        """Homogeneous ``(D+1, D+1)`` matrix (a new, writable array)."""
        d = self.DIM
        m = np.zeros((d + 1, d + 1))  # (np.eye costs twice as much; poses go out per call)
        m[:d, :d] = self._rotation
        m[:d, d] = self._translation
        m[d, d] = 1.0
        return m

    # --- group operations ---------------------------------------------------------------
    def __matmul__(self: P, other: P) -> P:
        if type(other) is not type(self):
            return NotImplemented
        return self._adopt(
            self._rotation @ other._rotation,
            self._rotation @ other._translation + self._translation,
        )

    def inverse(self: P) -> P:
        rt = self._rotation.T
        return self._unchecked(rt, -rt @ self._translation)  # rt is a view: copied

    def orthonormalized(self: P) -> P:
        """The same pose with round-off removed from its rotation.

        Each composition adds a little to ``|RᵀR − I|`` and a chain that feeds its own output
        back (``pose @ velocity`` with ``velocity = previous⁻¹ @ pose``) grows it geometrically.
        Returns ``self`` when the rotation is orthonormal to 1e-12, else its projection onto
        SO(D), so that poses which are already clean stay bit-identical.
        """
        r = self._rotation
        if self.DIM == 2:
            # Plain floats: every 2D registration checks its guess, and numpy's per-call cost
            # was a fifth of what the Python side of a scan's registration spends.
            (a, b), (c, d) = r.tolist()
            tol = 1e-12
            if (
                abs(a * a + c * c - 1.0) <= tol
                and abs(a * b + c * d) <= tol
                and abs(b * b + d * d - 1.0) <= tol
            ):
                return self
        elif float(np.abs(r.T @ r - np.eye(self.DIM)).max()) <= 1e-12:
            return self
        u, _, vt = np.linalg.svd(r)
        return self._adopt(u @ vt, self._translation.copy())

    def apply(self, points: Any) -> FloatArray:
        """Map ``(N, D)`` points from the source frame into the target frame."""
        pts = as_points(points, "points", dim=self.DIM, min_points=0)
        out: FloatArray = pts @ self._rotation.T + self._translation
        return out

    def interpolate(self: P, other: P, alpha: float) -> P:
        """Geodesic interpolation: ``self`` at ``alpha = 0``, ``other`` at ``alpha = 1``."""
        if type(other) is not type(self):
            raise TypeError(f"other: expected {type(self).__name__}, got {type(other).__name__}")
        a = float(alpha)
        if not np.isfinite(a):
            raise ValueError(f"alpha: must be finite, got {alpha}")
        return self @ type(self).exp(a * (self.inverse() @ other).log())

    def is_close(self: P, other: P, *, atol: float = 1e-9) -> bool:
        """Whether the two poses differ by less than ``atol`` in every matrix entry."""
        return bool(np.abs(self.as_matrix() - other.as_matrix()).max() <= atol)

    # --- subclasses provide these ---------------------------------------------------------
    @classmethod
    def exp(cls: type[P], xi: Any) -> P:
        raise NotImplementedError

    def log(self) -> FloatArray:
        raise NotImplementedError

    def __repr__(self) -> str:
        vec = np.array2string(self.as_vector(), precision=6, separator=", ", suppress_small=True)
        return f"{type(self).__name__}.from_vector({vec})"

    def as_vector(self) -> FloatArray:
        raise NotImplementedError

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        assert isinstance(other, _Pose)
        return bool(
            np.array_equal(self._rotation, other._rotation)
            and np.array_equal(self._translation, other._translation)
        )

    def __hash__(self) -> int:
        return hash((self._rotation.tobytes(), self._translation.tobytes()))


class SE2(_Pose):
    """A 2D rigid transform ``T_target_source``: ``p_T = R(θ) p_S + t``.

    Minimal vector ``[tx, ty, θ]``; tangent ``[ρx, ρy, θ]``; right perturbation
    ``T @ SE2.exp(δ)`` (see the module docstring).
    """

    DIM = 2
    DOF = 3
    __slots__ = ()

    @classmethod
    def from_vector(cls, vector: Any) -> SE2:
        """From ``[tx, ty, θ]`` (θ in radians)."""
        v = as_matrix(vector, "vector", (3,))
        return cls._unchecked(_rot2(v[2]), v[:2])

    def as_vector(self) -> FloatArray:
        """``[tx, ty, θ]`` with θ in ``(-π, π]``."""
        return np.array([self._translation[0], self._translation[1], self.angle])

    @property
    def angle(self) -> float:
        """θ in radians, in ``(-π, π]``."""
        return float(np.arctan2(self._rotation[1, 0], self._rotation[0, 0]))

    @classmethod
    def exp(cls, xi: Any) -> SE2:
        """Exponential map of a tangent vector ``[ρx, ρy, θ]``."""
        v = as_matrix(xi, "xi", (3,))
        return cls._unchecked(_rot2(v[2]), _so2_v(v[2]) @ v[:2])

    def log(self) -> FloatArray:
        """Tangent vector ``[ρx, ρy, θ]`` with θ in ``(-π, π]`` (inverse of ``exp``)."""
        theta = self.angle
        # V(θ) is never singular (det = a² + b² > 0 for |θ| ≤ π): no LinAlgError to raise.
        rho = _solve2(_so2_v(theta), self._translation)
        return np.array([rho[0], rho[1], theta])

    def adjoint(self) -> FloatArray:
        """``Ad_T`` (3×3) with ``T @ exp(δ) == exp(Ad_T δ) @ T``."""
        ad = np.eye(3)
        ad[:2, :2] = self._rotation
        ad[0, 2] = self._translation[1]
        ad[1, 2] = -self._translation[0]
        return ad


class SE3(_Pose):
    """A 3D rigid transform ``T_target_source``: ``p_T = R p_S + t``.

    Minimal vector ``[tx, ty, tz, rx, ry, rz]`` (``r``: rotation vector); tangent
    ``[ρ, φ]``; right perturbation ``T @ SE3.exp(δ)`` (see the module docstring).
    """

    DIM = 3
    DOF = 6
    __slots__ = ()

    @classmethod
    def from_vector(cls, vector: Any) -> SE3:
        """From ``[tx, ty, tz, rx, ry, rz]`` (rotation vector in radians)."""
        v = as_matrix(vector, "vector", (6,))
        return cls._unchecked(so3_exp(v[3:]), v[:3])

    def as_vector(self) -> FloatArray:
        """``[tx, ty, tz, rx, ry, rz]`` with ``|r| <= π``."""
        return np.concatenate([self._translation, so3_log(self._rotation)])

    @property
    def rotation_vector(self) -> FloatArray:
        return so3_log(self._rotation)

    @property
    def angle(self) -> float:
        """Rotation angle in radians, in ``[0, π]``."""
        return float(np.linalg.norm(so3_log(self._rotation)))

    @classmethod
    def exp(cls, xi: Any) -> SE3:
        """Exponential map of a tangent vector ``[ρx, ρy, ρz, φx, φy, φz]``."""
        v = as_matrix(xi, "xi", (6,))
        phi = v[3:]
        return cls._unchecked(so3_exp(phi), _so3_left_jacobian(phi) @ v[:3])

    def log(self) -> FloatArray:
        """Tangent vector ``[ρ, φ]`` with ``|φ| <= π`` (inverse of ``exp``)."""
        phi = so3_log(self._rotation)
        return np.concatenate([_so3_left_jacobian_inverse(phi) @ self._translation, phi])

    def adjoint(self) -> FloatArray:
        """``Ad_T`` (6×6) with ``T @ exp(δ) == exp(Ad_T δ) @ T``."""
        ad = np.zeros((6, 6))
        ad[:3, :3] = self._rotation
        ad[:3, 3:] = _hat3(self._translation) @ self._rotation
        ad[3:, 3:] = self._rotation
        return ad


Pose = SE2 | SE3


def pose_class(dim: int) -> type[SE2] | type[SE3]:
    """``SE2`` for 2D points, ``SE3`` for 3D points."""
    if dim == 2:
        return SE2
    if dim == 3:
        return SE3
    raise ValueError(f"dim: must be 2 or 3, got {dim}")


def as_pose(value: Any, name: str, dim: int) -> SE2 | SE3:
    """Accept an ``SE2``/``SE3`` or a homogeneous matrix for a ``dim``-D pose."""
    cls = pose_class(dim)
    if isinstance(value, cls):
        return value
    if isinstance(value, _Pose):
        raise TypeError(
            f"{name}: expected {cls.__name__} for {dim}D points, got {type(value).__name__}"
        )
    try:
        return cls.from_matrix(value)
    except (ValueError, TypeError) as exc:
        raise type(exc)(f"{name}: {exc}") from None
