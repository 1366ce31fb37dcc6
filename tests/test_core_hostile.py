"""The native module under hostile input: every call returns or raises a named
ValueError/TypeError/OverflowError — never a Rust panic (pyo3's PanicException is a
BaseException, so it would fail these tests), never a hang."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scanreg import _core

ALLOWED = (ValueError, TypeError, OverflowError)

# Coordinates that break naive code: NaN/inf, huge, subnormal, signed zero.
nasty_float = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e308, -1e308, 5e-324, 1e-300, 1e18, -1e18]),
)
points = st.integers(0, 6).flatmap(
    lambda n: st.sampled_from([1, 2, 3, 4]).flatmap(
        lambda d: arrays(np.float64, (n, d), elements=nasty_float)
    )
)
finite_points = st.integers(1, 40).flatmap(
    lambda n: st.sampled_from([2, 3]).flatmap(
        lambda d: arrays(
            np.float64, (n, d), elements=st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)
        )
    )
)
scalar = st.one_of(nasty_float, st.integers(-5, 5).map(float))


def call(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
    try:
        fn(*args, **kwargs)
    except ALLOWED as exc:
        assert str(exc), "errors must say what is wrong"


FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FAST
@given(points, points, scalar)
def test_paired(a: np.ndarray, b: np.ndarray, s: float) -> None:
    call(_core.paired_moments, a, b)
    dim = a.shape[1] if a.shape[1] in (2, 3) else 3
    pose = np.eye(dim + 1)
    pose[0, dim] = s
    for objective in ("point_to_point", "point_to_plane"):
        call(
            _core.linearize_paired,
            a,
            b,
            pose,
            objective=objective,
            kernel="huber",
            kernel_scale=s,
            target_normals=b,
        )


@FAST
@given(points, points, scalar, st.integers(-2, 50))
def test_kdtree(a: np.ndarray, q: np.ndarray, s: float, k: int) -> None:
    try:
        tree = _core.KdTree(a)
    except ALLOWED:
        return
    call(tree.nearest, q, s)
    call(tree.knn, q, k)
    call(tree.radius, q, s)
    call(tree.statistical_outliers, k, s)
    call(tree.radius_outliers, s, k)
    call(tree.local_geometry, k, np.zeros(tree.dim), regularization="plane", epsilon=s)


@FAST
@given(points, points, scalar, scalar)
def test_voxels_and_crops(a: np.ndarray, q: np.ndarray, size: float, s: float) -> None:
    for method in ("centroid", "first"):
        call(_core.voxel_downsample, a, size, method)
    call(_core.crop_range, a, s, size)
    call(_core.crop_box, a, np.full(max(a.shape[1], 1), s), np.full(max(a.shape[1], 1), size))


@FAST
@given(finite_points, st.floats(1e-300, 1e-3))
def test_tiny_voxels_on_large_coordinates(a: np.ndarray, size: float) -> None:
    # 1e6 m / 1e-300 m overflows any integer voxel key: must be refused, not wrap or panic.
    call(_core.voxel_downsample, np.ascontiguousarray(a * 1e6), size, "centroid")


@FAST
@given(points, arrays(np.float64, st.integers(0, 7), elements=nasty_float), scalar)
def test_deskew(a: np.ndarray, v: np.ndarray, t: float) -> None:
    call(_core.deskew, a, np.zeros(a.shape[0]), v, t)


@FAST
@given(st.binary(max_size=200), st.integers(-10, 1 << 20))
def test_lzf(data: bytes, size: int) -> None:
    call(_core.lzf_decompress, data, size)
    call(_core.lzf_compress, data)


def test_wrong_types_are_type_errors() -> None:
    with pytest.raises(TypeError):
        _core.KdTree(np.zeros((3, 3), dtype=np.int64))  # type: ignore[arg-type]
    with pytest.raises(TypeError):
        _core.deskew([[0.0, 0.0]], np.zeros(1), np.zeros(3), 0.0)  # type: ignore[arg-type]
