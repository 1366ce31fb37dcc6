"""Results do not depend on where the clouds sit: the same pair at the origin and moved to map
coordinates (10³, 10⁵, 10⁷ m) gives the same relative pose, for every method in 2D and 3D.

Two ways of being far from the origin:
* ``both``: source and target moved together (a scan already placed in map coordinates; the
  source frame's origin is 10⁷ m from its points) — the relative pose is compared after moving
  the answer back (``S⁻¹ T S``);
* ``target``: a scan in its sensor frame against a map in map coordinates (localization), init
  ``S·T`` — compared as ``S⁻¹ T``; the covariance (over the right perturbation in the source
  frame) must not change either.

The clouds are first snapped to a 2⁻²⁰ m (~1 µm) grid so that moving them is exact: a cloud
moved to 10⁷ m in float64 is otherwise rounded to ~2e-9 m, which can flip an exact tie between
two equidistant k-NN neighbours (scan points at equal ranges) and so change a normal or a
covariance — a change of the data, not of the solver. The solver's own frame dependence is
what these tests bound: 1e-6 m and 1e-8 rad.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scanreg
from conftest import data_dir
from scanreg import SE2, SE3
from scanreg import preprocess as pp

OFFSETS = (1e3, 1e5, 1e7)
TOL_M, TOL_RAD = 1e-6, 1e-8
METHODS_2D = ("point_to_point", "point_to_line", "gicp")
METHODS_3D = ("point_to_point", "point_to_plane", "gicp")


def snap(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.round(a * 2.0**20) / 2.0**20)


def shift(offset: float, dim: int) -> SE2 | SE3:
    if dim == 2:
        return SE2.from_vector([offset, -0.7 * offset, 0.0])
    return SE3.from_vector([offset, -0.7 * offset, 0.01 * offset, 0.0, 0.0, 0.0])


def moved(points: np.ndarray, s: SE2 | SE3) -> np.ndarray:
    return np.ascontiguousarray(points + s.translation)


def gap(a: SE2 | SE3, b: SE2 | SE3) -> tuple[float, float]:
    d = (a.inverse() @ b).log()  # type: ignore[operator]
    k = 2 if isinstance(a, SE2) else 3
    return float(np.linalg.norm(d[:k])), float(np.linalg.norm(d[k:]))


def intel_pairs() -> list[tuple[np.ndarray, np.ndarray, SE2]]:
    from scanreg.io import read_carmen

    log = read_carmen(data_dir("carmen-intel", "intel.gfs.log"))
    scans = [s.to_points(0.1, 40.0) for s in log.scans[:24]]
    return [(snap(scans[k]), snap(scans[k - 1]), log.motion_prior(k - 1, k)) for k in (5, 11, 23)]


def kitti_pair() -> tuple[np.ndarray, np.ndarray, SE3]:
    def frame(i: int) -> np.ndarray:
        path = data_dir("kitti-odometry-00-frames-000-015", "velodyne", f"{i:06d}.bin")
        raw = np.fromfile(path, dtype=np.float32).reshape(-1, 4)[:, :3].astype(np.float64)
        return snap(pp.voxel_downsample(raw, 0.5).points)

    return frame(1), frame(0), SE3.from_vector([0.8, 0.0, 0.0, 0.0, 0.0, 0.0])


def simulated_pair() -> tuple[np.ndarray, np.ndarray, SE3]:
    from scanreg import simulate as sim

    street = sim.street(seed=0)
    lidar = sim.LidarModel.preset("hdl32")
    a = SE3.from_vector([0.0, 1.75, 1.73, 0, 0, 0])
    b = SE3.from_vector([1.0, 1.9, 1.73, 0, 0, math.radians(2.0)])
    sa = pp.voxel_downsample(sim.simulate_sweep(street, lidar, a, seed=1).points, 0.5).points
    sb = pp.voxel_downsample(sim.simulate_sweep(street, lidar, b, seed=2).points, 0.5).points
    return snap(sb), snap(sa), a.inverse() @ b


def check_offsets(
    source: np.ndarray, target: np.ndarray, start: SE2 | SE3, method: str, **kw: object
) -> None:
    dim = source.shape[1]
    base = scanreg.register(source, target, method=method, init=start, **kw)  # type: ignore[arg-type]
    for offset in OFFSETS:
        s = shift(offset, dim)
        both = scanreg.register(
            moved(source, s),
            moved(target, s),
            method=method,  # type: ignore[arg-type]
            init=s @ start @ s.inverse(),  # type: ignore[operator]
            **kw,
        )
        dt, dr = gap(base.pose, s.inverse() @ both.pose @ s)  # type: ignore[operator]
        assert dt < TOL_M and dr < TOL_RAD, (method, offset, "both", dt, dr)
        assert both.stop_reason == base.stop_reason, (method, offset, both.stop_reason)
        far = scanreg.register(
            source,
            moved(target, s),
            method=method,  # type: ignore[arg-type]
            init=s @ start,  # type: ignore[operator]
            **kw,
        )
        dt, dr = gap(base.pose, s.inverse() @ far.pose)  # type: ignore[operator]
        assert dt < TOL_M and dr < TOL_RAD, (method, offset, "target", dt, dr)
        assert far.stop_reason == base.stop_reason, (method, offset, far.stop_reason)


@pytest.mark.parametrize("method", METHODS_2D)
def test_intel_pairs_give_the_same_pose_at_map_coordinates(method: str) -> None:
    for source, target, odometry in intel_pairs():
        answer = scanreg.register(source, target, method=method, init=odometry).pose
        kick = SE2.from_vector([0.05, -0.04, math.radians(2.0)])
        # From the answer, and from a start within the basin (odometry, and a kicked answer).
        for start in (answer, odometry, answer @ kick):
            check_offsets(source, target, start, method, max_correspondence_distance=0.3)


@pytest.mark.parametrize("method", METHODS_3D)
def test_kitti_and_simulated_pairs_give_the_same_pose_at_map_coordinates(method: str) -> None:
    for source, target, guess in (kitti_pair(), simulated_pair()):
        answer = scanreg.register(source, target, method=method, init=guess).pose
        kick = SE3.from_vector([0.2, -0.1, 0.05, 0.005, -0.005, math.radians(1.5)])
        for start in (answer, answer @ kick):
            check_offsets(source, target, start, method)


def test_covariance_is_the_same_for_a_map_in_map_coordinates() -> None:
    """A scan in its sensor frame against a map 10⁷ m away: the covariance over the
    right perturbation (source frame) is the same as at the origin."""
    source, target, odometry = intel_pairs()[0]
    base = scanreg.register(source, target, method="point_to_line", init=odometry)
    for offset in OFFSETS:
        s = shift(offset, 2)
        far = scanreg.register(source, moved(target, s), method="point_to_line", init=s @ odometry)  # type: ignore[operator]
        np.testing.assert_allclose(far.covariance, base.covariance, rtol=1e-6)
        assert far.verdict is not None and base.verdict is not None
        assert far.verdict.accepted == base.verdict.accepted


def test_ndt_gives_the_same_pose_at_map_coordinates() -> None:
    """NDT's cost is a sum of exponentials of ``q = x' − μ`` with both terms in map coordinates:
    at 10⁷ m their ~1e-9 m rounding moves the flat optimum by up to ~2e-6 m / 7e-7 rad (measured),
    hence a looser bound there."""
    for source, target, odometry in intel_pairs():
        kw = {"translation_tolerance": 1e-10, "rotation_tolerance": 1e-10}
        base = scanreg.match_ndt(source, target, init=odometry, **kw)  # type: ignore[arg-type]
        for offset in OFFSETS:
            s = shift(offset, 2)
            both = scanreg.match_ndt(
                moved(source, s),
                moved(target, s),
                init=s @ odometry @ s.inverse(),  # type: ignore[operator]
                **kw,  # type: ignore[arg-type]
            )
            dt, dr = gap(base.pose, s.inverse() @ both.pose @ s)  # type: ignore[operator]
            tol_m, tol_rad = (TOL_M, 1e-7) if offset < 1e6 else (1e-5, 3e-6)
            assert dt < tol_m and dr < tol_rad, (offset, "both", dt, dr)
            far = scanreg.match_ndt(source, moved(target, s), init=s @ odometry, **kw)  # type: ignore[operator, arg-type]
            dt, dr = gap(base.pose, s.inverse() @ far.pose)  # type: ignore[operator]
            assert dt < tol_m and dr < tol_rad, (offset, "target", dt, dr)


def test_correlative_gives_the_same_pose_for_a_map_in_map_coordinates() -> None:
    """The correlative window is over the source frame's pose (it rotates the scan about the
    sensor), so the invariant case is a scan in its sensor frame against a far reference."""
    for source, target, odometry in intel_pairs():
        kw = {"window": (0.3, 0.3, math.radians(10)), "resolution": 0.05}
        base = scanreg.match_correlative(source, target, init=odometry, **kw)  # type: ignore[arg-type]
        for offset in OFFSETS:
            s = shift(offset, 2)
            far = scanreg.match_correlative(source, moved(target, s), init=s @ odometry, **kw)  # type: ignore[operator, arg-type]
            dt, dr = gap(base.pose, s.inverse() @ far.pose)  # type: ignore[operator]
            assert dt < TOL_M and dr < TOL_RAD, (offset, dt, dr)
            assert far.score == pytest.approx(base.score, rel=1e-9)


def test_correlative_names_a_scan_far_from_its_own_origin() -> None:
    source, target, _ = intel_pairs()[0]
    s = shift(1e7, 2)
    with pytest.raises(ValueError, match=r"source: points up to .* m from the source frame"):
        scanreg.match_correlative(moved(source, s), moved(target, s), init=s)


def test_odometry_started_at_utm_coordinates_follows_the_same_path() -> None:
    """``Odometry(initial_pose=...)`` 4.2e6 m from the origin: the voxel map keys its voxels
    relative to its first point (it refused coordinates past 2^20 voxels), and the poses are
    the origin run's moved by the initial pose. The offset is a whole number of voxels and the
    rotation the identity, so both runs bin the points into the same voxels."""
    s = SE3.from_vector([5e5, 4.2e6, 30.0, 0.0, 0.0, 0.0])
    at_origin, at_utm = scanreg.pipeline.Odometry(), scanreg.pipeline.Odometry(initial_pose=s)
    for i in range(4):
        path = data_dir("kitti-odometry-00-frames-000-015", "velodyne", f"{i:06d}.bin")
        sweep = np.fromfile(path, dtype=np.float32).reshape(-1, 4)[:, :3].astype(np.float64)
        a, b = at_origin.step(sweep), at_utm.step(sweep)
        dt, dr = gap(s @ a.pose, b.pose)  # type: ignore[operator]
        assert dt < TOL_M and dr < TOL_RAD, (i, dt, dr)
