"""A weak 2D result moved along its weak direction to where the scan fits it clearly better
(:mod:`scanreg.shift`, ``RegistrationSettings.shift_weak``)."""

from __future__ import annotations

import numpy as np
import pytest
import scanreg
from scanreg import SE2
from scanreg.shift import maybe_weak_2d, weak_shift


def _doorways() -> np.ndarray:
    """Two walls 2 m apart along x (5 cm spacing), each with a 0.3 m doorway every 2 m (the
    two walls' staggered by 1 m): every normal faces across the corridor, so the analysis
    finds the axis weak, but moved along it the walls' points fall into the doorways."""
    x = np.arange(-10.0, 10.0, 0.05)
    upper = x[np.mod(x, 2.0) > 0.3]
    lower = x[np.mod(x + 1.0, 2.0) > 0.3]
    return np.ascontiguousarray(
        np.vstack([np.c_[upper, np.full_like(upper, 1.0)], np.c_[lower, np.full_like(lower, -1.0)]])
    )


def _reveals(bare: bool = False) -> np.ndarray:
    """Two walls 2 m apart along x (5 cm spacing), and unless ``bare`` two door reveals 0.5 m
    long at 45° to the corridor leaving them at x = ±3 m: too few points for the scan to pin
    the pose along the axis."""
    x = np.arange(-10.0, 10.0, 0.05)
    pts = [np.c_[x, np.full_like(x, 1.0)], np.c_[x, np.full_like(x, -1.0)]]
    if not bare:
        s = np.arange(0.04, 0.5, 0.04)[:, None]
        d = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4)])
        pts.append(np.array([-3.0, 1.0]) + s * d)
        pts.append(np.array([3.0, -1.0]) - s * d)
    return np.ascontiguousarray(np.vstack(pts))


def _pair(points: np.ndarray, seed: int) -> tuple[np.ndarray, scanreg.PreparedTarget]:
    rng = np.random.default_rng(seed)
    target = scanreg.prepare(
        points + rng.normal(0.0, 0.01, points.shape), normals=True, covariances=True
    )
    return points + rng.normal(0.0, 0.01, points.shape), target


@pytest.mark.parametrize("method", ["point_to_point", "gicp"])
@pytest.mark.parametrize(("seed", "offset"), [(0, 0.3), (0, -0.3), (1, 0.3), (1, -0.3)])
def test_result_left_off_along_the_corridor_ends_where_the_doorways_fit(
    method: str, seed: int, offset: float
) -> None:
    # From 0.3 m off along the axis both methods stop near their start (0.29 m off: the
    # doorways' pull is too weak) and are rejected as degenerate; the surface count along the
    # weak direction peaks at the truth, where the scan pins the pose.
    source, target = _pair(_doorways(), seed)
    start = SE2.from_vector([offset, 0.0, 0.0])
    kept = scanreg.register(source, target, method=method, init=start, shift_weak=False)  # type: ignore[arg-type]
    assert abs(float(kept.pose.translation[0])) > 0.25
    assert kept.verdict is not None and not kept.verdict.accepted
    res = scanreg.register(source, target, method=method, init=start)  # type: ignore[arg-type]
    assert res.degeneracy is not None and res.degeneracy.degenerate  # still weak, pinned
    assert abs(float(res.pose.translation[0])) < 0.025
    assert abs(float(res.pose.translation[1])) < 0.005
    assert res.converged and res.iterations == kept.iterations
    assert res.verdict is not None
    assert res.verdict.accepted, res.verdict.reasons
    # The covariance keeps the prior along the axis (the analysis's, at the moved pose).
    assert res.covariance[0, 0] > 0.3**2


@pytest.mark.parametrize("bare", [False, True])
def test_corridor_the_scan_does_not_pin_is_not_moved(bare: bool) -> None:
    # The reveals fit the scan at one place along the corridor, but moved 0.15 m from it the
    # scan loses under the analysis's 3 %: no shift (it would stay degenerate), nor in a
    # bare corridor, for every method.
    source, target = _pair(_reveals(bare), 0)
    start = SE2.from_vector([0.3, 0.0, 0.0])
    for method in ("point_to_point", "point_to_line", "gicp"):
        on = scanreg.register(source, target, method=method, init=start)
        off = scanreg.register(source, target, method=method, init=start, shift_weak=False)
        assert on.degeneracy is not None and on.degeneracy.degenerate
        np.testing.assert_array_equal(on.pose.as_matrix(), off.pose.as_matrix())


def test_weak_shift_and_its_screen() -> None:
    rng = np.random.default_rng(0)
    points = _doorways()
    target = scanreg.prepare(points, normals=True)
    source = points + rng.normal(0.0, 0.005, points.shape)
    res = scanreg.register(source, target, method="point_to_line", shift_weak=False)
    deg = res.degeneracy
    assert deg is not None and deg.degenerate
    off = res.pose.as_matrix() @ SE2.from_vector([0.3, 0.0, 0.0]).as_matrix()
    moved = weak_shift(target, source, off, deg, 1.0)
    assert moved is not None and abs(moved[0, 2]) < 0.02
    # At the fitted pose, pinned there: not moved.
    assert weak_shift(target, source, res.pose.as_matrix(), deg, 1.0) is None
    # The screen: a corridor's normals face across it only; a room's face both ways.
    assert target.normals is not None
    assert maybe_weak_2d(np.arange(len(points)), target.normals)
    side = np.arange(-2.0, 2.0, 0.05)
    room = scanreg.prepare(
        np.vstack(
            [
                np.c_[side, np.full_like(side, 2.0)],
                np.c_[side, np.full_like(side, -2.0)],
                np.c_[np.full_like(side, 2.0), side],
                np.c_[np.full_like(side, -2.0), side],
            ]
        ),
        normals=True,
    )
    assert room.normals is not None
    assert not maybe_weak_2d(np.arange(len(room.points)), room.normals)
    assert not maybe_weak_2d(np.full(5, -1), target.normals)


def test_shift_weak_must_be_a_bool() -> None:
    with pytest.raises(TypeError, match="shift_weak: expected a bool, got int"):
        scanreg.RegistrationSettings(shift_weak=1)  # type: ignore[arg-type]
