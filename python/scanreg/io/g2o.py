"""g2o pose graphs: ``VERTEX_SE2`` / ``EDGE_SE2`` (2D) and ``VERTEX_SE3:QUAT`` /
``EDGE_SE3:QUAT`` (3D).

File lines (g2o's own layout)::

    VERTEX_SE2 id x y theta
    EDGE_SE2 i j x y theta  I11 I12 I13 I22 I23 I33
    VERTEX_SE3:QUAT id x y z qx qy qz qw
    EDGE_SE3:QUAT i j x y z qx qy qz qw  <21 values: 6×6 information, upper triangle by rows>
    FIX id

A vertex is ``T_world_vertex``; an edge measurement is ``T_i_j = inv(T_world_i) T_world_j``.
The information matrix is over g2o's error ordering, translation first: ``[x, y, θ]`` in 2D
and ``[x, y, z, qx, qy, qz]`` in 3D, where the rotation part is the imaginary part of the error
quaternion (≈ half the rotation vector). scanreg's covariances are over the
translation-first tangent ``[ρ, φ]`` (right perturbation, the same frame as g2o's error);
:func:`g2o_information` converts one to the other (the 3D rotation block is
scaled by 2 on each side).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._validate import FloatArray, as_matrix
from ..quality import information_from_covariance
from ..transform import SE2, SE3
from ._common import FileFormatError, PathLike
from .trajectory import quaternion_to_rotation, rotation_to_quaternion


@dataclass(frozen=True)
class PoseGraphEdge:
    """A relative-pose constraint ``T_from_to`` with its information matrix (g2o ordering)."""

    from_id: int
    to_id: int
    measurement: SE2 | SE3
    information: FloatArray

    def __post_init__(self) -> None:
        dof = 3 if isinstance(self.measurement, SE2) else 6
        if not isinstance(self.measurement, SE2 | SE3):
            raise TypeError(f"measurement: expected SE2 or SE3, got {type(self.measurement)}")
        info = as_matrix(self.information, "information", (dof, dof))
        if np.abs(info - info.T).max() > 1e-9 * max(1.0, float(np.abs(info).max())):
            raise ValueError("information: must be symmetric")
        info.setflags(write=False)
        object.__setattr__(self, "information", info)


@dataclass(frozen=True)
class PoseGraph:
    """Vertices ``T_world_vertex`` by id, edges, and the ids held fixed."""

    vertices: dict[int, SE2 | SE3]
    edges: tuple[PoseGraphEdge, ...] = ()
    fixed: frozenset[int] = field(default_factory=frozenset)

    def __post_init__(self) -> None:
        kinds = {type(v) for v in self.vertices.values()} | {
            type(e.measurement) for e in self.edges
        }
        if len(kinds) > 1:
            raise ValueError("vertices/edges: a pose graph is either all SE2 or all SE3")
        for e in self.edges:
            for vid in (e.from_id, e.to_id):
                if vid not in self.vertices:
                    raise ValueError(
                        f"edges: edge {e.from_id}->{e.to_id} uses unknown vertex {vid}"
                    )
        object.__setattr__(self, "edges", tuple(self.edges))
        object.__setattr__(self, "fixed", frozenset(self.fixed))


def g2o_information(covariance: Any) -> FloatArray:
    """g2o's information matrix for a scanreg covariance over ``[ρ, φ]`` (3×3 or 6×6).

    The inverse is :func:`scanreg.quality.information_from_covariance` (the one inversion:
    an infinite variance is a direction with no information). In 3D, g2o's rotation error is
    the quaternion's imaginary part ``≈ φ / 2``, so with ``D = diag(1, 1, 1, 2, 2, 2)`` the
    result is ``D Σ⁻¹ D`` — a rescaling for g2o's parametrisation, hence its own name; in 2D
    it is ``Σ⁻¹``.
    """
    cov = np.asarray(covariance, dtype=np.float64)
    if cov.shape not in ((3, 3), (6, 6)):
        raise ValueError(f"covariance: expected shape (3, 3) or (6, 6), got {cov.shape}")
    info = information_from_covariance(as_matrix(cov, "covariance", cov.shape))
    if cov.shape == (6, 6):
        d = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0])
        info = np.asarray(d[:, None] * info * d[None, :], dtype=np.float64)
    result: FloatArray = 0.5 * (info + info.T)
    return result


def _upper(info: FloatArray) -> list[float]:
    rows, cols = np.triu_indices(info.shape[0])
    return [float(v) for v in info[rows, cols]]


#: Upper-triangle indices by size (``np.triu_indices`` costs more than the rest of a line).
_TRIU = {dof: np.triu_indices(dof) for dof in (3, 6)}


def _from_upper(values: FloatArray, dof: int) -> FloatArray:
    info = np.zeros((dof, dof))
    rows, cols = _TRIU[dof]
    info[rows, cols] = values
    info[cols, rows] = values
    return info


def _se3_fields(pose: SE3) -> list[float]:
    return [*map(float, pose.translation), *map(float, rotation_to_quaternion(pose.rotation))]


def write_g2o(path: PathLike, graph: PoseGraph) -> None:
    """Write a pose graph in g2o's text format (``%.17g``: exact round trip)."""
    if not isinstance(graph, PoseGraph):
        raise TypeError(f"graph: expected PoseGraph, got {type(graph).__name__}")
    lines = []
    for vid, pose in sorted(graph.vertices.items()):
        if isinstance(pose, SE2):
            values = [*map(float, pose.translation), pose.angle]
            lines.append(f"VERTEX_SE2 {vid} " + " ".join(f"{v:.17g}" for v in values))
        else:
            lines.append(
                f"VERTEX_SE3:QUAT {vid} " + " ".join(f"{v:.17g}" for v in _se3_fields(pose))
            )
    for vid in sorted(graph.fixed):
        lines.append(f"FIX {vid}")
    for e in graph.edges:
        m = e.measurement
        meas = [*map(float, m.translation), m.angle] if isinstance(m, SE2) else _se3_fields(m)
        tag = "EDGE_SE2" if isinstance(m, SE2) else "EDGE_SE3:QUAT"
        numbers = " ".join(f"{v:.17g}" for v in meas + _upper(e.information))
        lines.append(f"{tag} {e.from_id} {e.to_id} {numbers}")
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


_WIDTH = {"VERTEX_SE2": 4, "VERTEX_SE3:QUAT": 8, "EDGE_SE2": 11, "EDGE_SE3:QUAT": 30, "FIX": 1}


def _se3_from(path: Path, number: int, values: FloatArray) -> SE3:
    norm = math.hypot(*values[3:7].tolist())  # no overflow for finite entries
    if abs(norm - 1.0) > 1e-3:
        raise FileFormatError(path, f"line {number}: quaternion norm {norm:.6g}, not 1")
    # The matrix of a normalised quaternion is a rotation to round-off: SE3's check and SVD
    # projection (most of the time of a line) have nothing to do.
    return SE3._adopt(quaternion_to_rotation(values[3:7]), values[:3].copy())


def read_g2o(path: PathLike) -> PoseGraph:
    """Read a 2D or 3D g2o pose graph (the tags listed in the module docstring)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise FileFormatError(p, "not a text file (invalid UTF-8)") from None
    vertices: dict[int, SE2 | SE3] = {}
    edges: list[PoseGraphEdge] = []
    fixed: set[int] = set()
    for number, line in enumerate(text.splitlines(), start=1):
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        tag = words[0]
        if tag not in _WIDTH:
            raise FileFormatError(p, f"line {number}: unsupported g2o tag {tag!r}")
        if len(words) - 1 != _WIDTH[tag]:
            raise FileFormatError(
                p, f"line {number}: {tag} needs {_WIDTH[tag]} values, got {len(words) - 1}"
            )
        ids_count = 1 if tag.startswith(("VERTEX", "FIX")) else 2
        try:
            ids = [int(w) for w in words[1 : 1 + ids_count]]
            values = np.array(words[1 + ids_count :], dtype=np.float64)
        except ValueError as exc:
            raise FileFormatError(p, f"line {number}: bad number: {exc}") from None
        if not np.isfinite(values).all():
            raise FileFormatError(p, f"line {number}: NaN or inf")
        try:
            if tag == "FIX":
                fixed.add(ids[0])
            elif tag.startswith("VERTEX"):
                if ids[0] in vertices:
                    raise FileFormatError(p, f"line {number}: vertex {ids[0]} defined twice")
                vertices[ids[0]] = (
                    SE2.from_vector(values) if tag == "VERTEX_SE2" else _se3_from(p, number, values)
                )
            elif tag == "EDGE_SE2":
                edges.append(
                    PoseGraphEdge(
                        ids[0], ids[1], SE2.from_vector(values[:3]), _from_upper(values[3:], 3)
                    )
                )
            else:
                meas = _se3_from(p, number, values[:7])
                edges.append(PoseGraphEdge(ids[0], ids[1], meas, _from_upper(values[7:], 6)))
        except FileFormatError:
            raise
        except ValueError as exc:
            raise FileFormatError(p, f"line {number}: {exc}") from None
    try:
        return PoseGraph(vertices, tuple(edges), frozenset(fixed))
    except ValueError as exc:
        raise FileFormatError(p, str(exc)) from None
