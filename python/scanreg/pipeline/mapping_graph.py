"""The pose-graph bookkeeping :class:`~scanreg.pipeline.Mapper` (2D) and
:class:`~scanreg.pipeline.Mapper3D` share: the validation of the configuration fields both
have, when a scan becomes a node, and the covariance of the odometry edge between two nodes.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._validate import FloatArray
from ..graph import Kernel
from .odometry2d import _count, _positive

#: Non-negative fields of both mapping configurations (0 turns the feature off).
_NON_NEGATIVE = (
    "node_distance",
    "node_angle",
    "node_voxel_size",
    "drift_translation",
    "drift_rotation",
    "loop_min_travel",
    "loop_max_range",
)
#: The loosest an odometry edge may be along any direction (σ, metres or radians).
MAX_EDGE_SIGMA = 1.0

#: Positive fields of both.
_POSITIVE = ("drift_floor_translation", "drift_floor_rotation", "loop_gate_sigmas")


def validate_graph_fields(config: Any) -> None:
    """Check the node, drift, loop-candidate and kernel fields a ``MappingConfig`` and a
    ``MappingConfig3D`` share (errors name the field)."""
    for name in _NON_NEGATIVE:
        _positive(getattr(config, name), name, allow_zero=True)
    for name in _POSITIVE:
        _positive(getattr(config, name), name)
    _count(config.submap_half_size, "submap_half_size", 0)
    _count(config.max_candidates, "max_candidates", 0)
    _count(config.loop_every, "loop_every", 1)
    if not isinstance(config.loop_kernel, Kernel):
        raise TypeError(f"loop_kernel: expected Kernel, got {type(config.loop_kernel).__name__}")


def is_new_node(distance: float, angle: float, config: Any) -> bool:
    """Whether a scan ``distance`` (m) and ``angle`` (rad, its magnitude) from the last node
    becomes a node: it moved more than ``node_distance`` or turned more than ``node_angle``."""
    return bool(distance > config.node_distance or abs(angle) > config.node_angle)


def odometry_edge_covariance(distance: float, covariance: Any, config: Any, dim: int) -> FloatArray:
    """Covariance of the odometry edge between two nodes ``distance`` apart: the drift term
    (σ = floor + rate · distance, per translation and per rotation axis) plus the scan's own
    covariance against the local map (symmetrised), when it is finite and of the pose's
    size."""
    st = config.drift_floor_translation + config.drift_translation * distance
    sr = config.drift_floor_rotation + config.drift_rotation * distance
    rot = 1 if dim == 2 else 3
    cov: FloatArray = np.diag([st**2] * dim + [sr**2] * rot)
    measured = np.asarray(covariance, dtype=np.float64)
    dof = dim + rot
    if measured.shape == (dof, dof) and np.isfinite(measured).all():
        cov = cov + 0.5 * (measured + measured.T)
    # Conditioned: no direction looser than σ = MAX_EDGE_SIGMA (m or rad). A scan that says
    # nothing along a corridor's axis reports a variance of 10⁶ or more there; a chain of
    # such edges leaves the graph's linear system indeterminate for the solver (gtsam's
    # IndeterminateLinearSystemException on the Freiburg hospital log), and an edge between
    # nodes half a metre apart is not off by more than a metre anyway.
    # The eigenvalues of a matrix holding 10⁶ carry rounding errors of 10⁻¹⁰ · 10⁶: floored
    # at the drift floor's variance, which the sum above cannot go below.
    vals, vecs = np.linalg.eigh(cov)
    floor = min(config.drift_floor_translation, config.drift_floor_rotation) ** 2
    capped: FloatArray = (vecs * np.clip(vals, floor, MAX_EDGE_SIGMA**2)) @ vecs.T
    return 0.5 * (capped + capped.T)
