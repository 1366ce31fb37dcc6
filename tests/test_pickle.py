"""Everything public travels: results, configs, poses and targets survive pickle and cloudpickle
(what a process pool or Ray does to a task's arguments and results), with the numbers that
matter equal to the bit and prepared targets answering as the originals do."""

from __future__ import annotations

import os
import pickle
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import scanreg
from scanreg import _core
from scanreg.io import open_sequence
from scanreg.pipeline import Odometry2D, OdometryConfig2D

try:
    import cloudpickle
except ImportError:  # pragma: no cover - dev installs it
    if os.environ.get("CI", "").lower() == "true":
        raise
    cloudpickle = None

DUMPERS: list[Any] = [pytest.param(pickle.dumps, id="pickle")]
DUMPERS.append(
    pytest.param(
        None if cloudpickle is None else cloudpickle.dumps,
        id="cloudpickle",
        marks=pytest.mark.skipif(cloudpickle is None, reason="cloudpickle not installed (dev)"),
    )
)

RNG = np.random.default_rng(11)
CLOUD3 = np.ascontiguousarray(RNG.uniform(-5, 5, (400, 3)) * [1, 1, 0.2])
CLOUD2 = np.ascontiguousarray(RNG.uniform(-5, 5, (300, 2)))
QUERY3 = np.ascontiguousarray(RNG.uniform(-5, 5, (50, 3)))
QUERY2 = np.ascontiguousarray(RNG.uniform(-4, 4, (50, 2)))


def roundtrip(obj: Any, dumps: Callable[[Any], bytes]) -> Any:
    return pickle.loads(dumps(obj))


def same(a: Any, b: Any) -> None:
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize("dumps", DUMPERS)
def test_poses_and_configs(dumps: Callable[[Any], bytes]) -> None:
    for pose in (
        scanreg.SE2.from_vector([1, 2, 0.3]),
        scanreg.SE3.from_vector([1, 2, 3, 0.1, 0, 0.2]),
    ):
        back = roundtrip(pose, dumps)
        assert type(back) is type(pose)
        same(back.as_matrix(), pose.as_matrix())
    for config in (
        scanreg.OdometryConfig(method="point_to_plane", voxel_size=0.7),
        scanreg.RegistrationSettings(max_iterations=7, kernel="huber"),
        scanreg.VerdictThresholds(min_overlap=0.4),
        OdometryConfig2D(front_end="correlative"),
    ):
        assert roundtrip(config, dumps) == config


@pytest.mark.parametrize("dumps", DUMPERS)
def test_targets_answer_as_the_originals(dumps: Callable[[Any], bytes]) -> None:
    tree = _core.KdTree(CLOUD3)
    back = roundtrip(tree, dumps)
    for a, b in zip(tree.knn(QUERY3, 5), back.knn(QUERY3, 5), strict=True):
        same(a, b)

    target = scanreg.prepare(CLOUD3, normals=True, covariances=True)
    back_t = roundtrip(target, dumps)
    for name in ("points", "normals", "covariances", "valid"):
        same(getattr(back_t, name), getattr(target, name))
    same(back_t.nearest(QUERY3, 1.0).indices, target.nearest(QUERY3, 1.0).indices)

    grid = scanreg.prepare_correlative(CLOUD2, resolution=0.1)
    back_g = roundtrip(grid, dumps)
    same(back_g.likelihood, grid.likelihood)
    assert (back_g.origin, back_g.shape, back_g.levels) == (grid.origin, grid.shape, grid.levels)

    ndt = scanreg.prepare_ndt(CLOUD2, cell_size=1.0)
    back_n = roundtrip(ndt, dumps)
    assert back_n.cell_sizes == ndt.cell_sizes and back_n.num_cells == ndt.num_cells
    for a, b in zip(ndt.cells(2), back_n.cells(2), strict=True):
        same(a, b)
    ndt3 = scanreg.prepare_ndt(CLOUD3, cell_size=2.0)
    back_n3 = roundtrip(ndt3, dumps)
    assert (back_n3.dim, back_n3.num_cells) == (3, ndt3.num_cells)
    for a, b in zip(ndt3.cells(), back_n3.cells(), strict=True):
        same(a, b)


@pytest.mark.parametrize("dumps", DUMPERS)
@pytest.mark.parametrize("attributes", ["none", "normals", "covariances", "voxel_covariances"])
def test_local_map_keeps_its_contents(dumps: Callable[[Any], bytes], attributes: str) -> None:
    m = scanreg.LocalMap(3, voxel_size=1.0, max_points_per_voxel=5, attributes=attributes)  # type: ignore[arg-type]
    extra: dict[str, Any] = {}
    if attributes == "normals":
        extra["normals"] = np.tile([0.0, 0.0, 1.0], (len(CLOUD3), 1))
    if attributes == "covariances":
        extra["covariances"] = np.tile(np.eye(3) * 0.01, (len(CLOUD3), 1, 1))
    m.insert(CLOUD3, **extra)
    m.remove_far(np.zeros(3), 4.0)
    back = roundtrip(m, dumps)
    assert (len(back), back.num_voxels, back.attributes) == (len(m), m.num_voxels, attributes)
    same(back.points(), m.points())
    if attributes != "none":
        for name in ("normals", "covariances"):
            if getattr(m, name)() is not None:
                same(getattr(back, name)(), getattr(m, name)())
    a, b = m.nearest(QUERY3, 1.0), back.nearest(QUERY3, 1.0)
    same(a.points, b.points)
    same(a.squared_distances, b.squared_distances)


@pytest.mark.parametrize("dumps", DUMPERS)
def test_results_keep_pose_covariance_and_verdict(dumps: Callable[[Any], bytes]) -> None:
    truth = scanreg.SE3.from_vector([0.2, -0.1, 0.05, 0.0, 0.0, 0.03])
    source = np.ascontiguousarray(truth.inverse().apply(CLOUD3))
    target = scanreg.prepare(CLOUD3, normals=True)
    # pickled before its lazy trust analysis ran, and after
    for touched in (False, True):
        res = scanreg.register(source, target, method="point_to_plane")
        if touched:
            _ = res.covariance
        back = roundtrip(res, dumps)
        fresh = scanreg.register(source, target, method="point_to_plane")
        same(back.pose.as_matrix(), fresh.pose.as_matrix())
        same(back.covariance, fresh.covariance)
        same(back.hessian, fresh.hessian)
        assert back.verdict == fresh.verdict and back.stop_reason == fresh.stop_reason
        assert back.conditioning.weakest.description == fresh.conditioning.weakest.description

    paired = scanreg.align_paired(CLOUD3, truth.apply(CLOUD3))
    back_p = roundtrip(paired, dumps)
    same(back_p.pose.as_matrix(), paired.pose.as_matrix())
    same(back_p.covariance, paired.covariance)

    grid = scanreg.prepare_correlative(CLOUD2, resolution=0.1)
    shift = scanreg.SE2.from_vector([0.1, 0.05, 0.02])
    corr = scanreg.match_correlative(shift.inverse().apply(CLOUD2), grid, window=(0.3, 0.3, 0.1))
    back_c = roundtrip(corr, dumps)
    same(back_c.pose.as_matrix(), corr.pose.as_matrix())
    same(back_c.covariance, corr.covariance)

    ndt_res = scanreg.match_ndt(shift.inverse().apply(CLOUD2), scanreg.prepare_ndt(CLOUD2))
    back_n = roundtrip(ndt_res, dumps)
    same(back_n.pose.as_matrix(), ndt_res.pose.as_matrix())
    same(back_n.covariance, ndt_res.covariance)


@pytest.mark.parametrize("dumps", DUMPERS)
def test_odometry_frames_and_state_travel(dumps: Callable[[Any], bytes]) -> None:
    frames = list(open_sequence("sim:street,frames=3"))
    odo = scanreg.Odometry(scanreg.OdometryConfig())
    for f in frames[:2]:
        first = odo.step(f.points, f.timestamps, stamp=f.stamp)
    back_f = roundtrip(first, dumps)
    same(back_f.pose.as_matrix(), first.pose.as_matrix())
    same(back_f.covariance, first.covariance)
    assert back_f.verdict == first.verdict and back_f.held_directions == first.held_directions
    # an odometry resumed elsewhere continues exactly as the original
    moved = roundtrip(odo, dumps)
    a = odo.step(frames[2].points, frames[2].timestamps, stamp=frames[2].stamp)
    b = moved.step(frames[2].points, frames[2].timestamps, stamp=frames[2].stamp)
    same(a.pose.as_matrix(), b.pose.as_matrix())
    same(a.covariance, b.covariance)

    odo2 = Odometry2D(OdometryConfig2D())
    frame2 = odo2.step(CLOUD2)
    frame2 = odo2.step(scanreg.SE2.from_vector([0.05, 0, 0.01]).apply(CLOUD2))
    back2 = roundtrip(frame2, dumps)
    same(back2.pose.as_matrix(), frame2.pose.as_matrix())
    same(back2.covariance, frame2.covariance)
