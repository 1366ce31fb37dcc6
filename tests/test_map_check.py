"""The map's self-check (scanreg.pipeline.map_check): good maps pass, broken ones are flagged
with named reasons, on a simulated loop with a deliberately broken trajectory and on the real
Intel excerpt (its odometry alone against its loop-closed map)."""

from __future__ import annotations

import dataclasses
import importlib.util
from functools import cache
from typing import Any

import numpy as np
import pytest
from conftest import data_dir
from scanreg import SE2
from scanreg.saved_map import SavedMap

pytest.importorskip("gtsam")

from scanreg.graph import Edge, Kernel
from scanreg.pipeline.map_check import (
    MapCheck,
    MapCheckSettings,
    check_map,
    describe_region,
    kernel_weight,
    loop_residual,
)
from scanreg.pipeline.mapping import MappingConfig, MappingResult
from test_mapping import _ring_run


@cache
def _intel_excerpt() -> MappingResult[SE2]:
    # The excerpt of tests/test_mapping.py: the first 300 scans of the Intel subset.
    from scanreg.io import read_scans
    from scanreg.pipeline.mapping import run_mapping

    log = read_scans(data_dir("carmen-intel") / "intel_gfs_subset_clf_timestamps.clf")
    return run_mapping(log, MappingConfig(), max_scans=300)


def _broken(poses: tuple[SE2, ...], at: int, kink: SE2) -> list[SE2]:
    """``poses`` with every pose from ``at`` on moved by ``kink`` about the pose at ``at``: a
    trajectory that jumps once and is right, relative to itself, elsewhere."""
    pivot = poses[at]
    moved = pivot @ kink @ pivot.inverse()
    return [p if k < at else moved @ p for k, p in enumerate(poses)]


def _truth(run: Any) -> list[SE2]:
    """The simulated run's exact poses in the mapper's frame (the first scan's)."""
    return [run.poses[0].inverse() @ p for p in run.poses]


def test_simulated_loop_passes_and_a_broken_trajectory_is_flagged() -> None:
    # The scans of the simulated ring at their exact poses, then with a deliberate break. (The
    # exact poses rather than the mapper's: the check is under test here, not the mapper.)
    run, res = _ring_run()
    truth = _truth(run)
    good = check_map(res, truth)
    # Measured: 0 of ~2400 judged returns contradicted.
    assert not any(r.startswith("contradictions:") for r in good.reasons), good.reasons
    assert good.contradiction_fraction < 0.01 and good.returns > 1000
    # The second half of the lap turned by 3° and moved 0.3 m at its start: the return over
    # the start puts walls where the first pass saw through.
    broken = _broken(tuple(truth), res.num_scans // 2, SE2.from_vector([0.3, 0.0, np.radians(3)]))
    bad = check_map(res, broken)
    # Measured: 75 % of the judged returns contradicted.
    assert not bad.consistent
    assert bad.contradiction_fraction > 0.3
    assert any(r.startswith("contradictions:") for r in bad.reasons), bad.reasons
    # The worst region is where the second half overlaps the first: the first 8 m leg
    # (y = 2 m, x from 2 to 10 m) that the lap drives again at its end.
    worst = bad.regions[0]
    assert 0.0 < worst.x < 12.0 and -1.0 < worst.y < 5.0, worst


def test_a_local_break_is_flagged_where_the_whole_map_would_pass() -> None:
    # The last tenth of the lap moved 0.3 m: only the stretch over the start disagrees, too
    # little of the whole map for the map-wide limit; its square gives it away. (Loops are
    # not judged here: against the exact poses every loop edge of the broken lap is off.)
    run, res = _ring_run()
    truth = _truth(run)
    settings = MapCheckSettings(max_loops_over_bound=1.0)
    assert check_map(res, truth, settings).consistent
    broken = _broken(tuple(truth), int(0.9 * res.num_scans), SE2.from_vector([0.3, 0.0, 0.0]))
    bad = check_map(res, broken, settings)
    # Measured: 6.6 % of 2362 judged returns over the map; 38 of 45 in the worst 4 m square.
    assert bad.contradiction_fraction < settings.max_contradiction_fraction
    assert not bad.consistent
    assert [r.split(":")[0] for r in bad.reasons] == ["contradictions gather"], bad.reasons
    worst = bad.regions[0]
    assert worst.contradictions > 0.5 * worst.returns
    # And whose returns they are: the moved tail's (scans from 0.9 of the run on). Measured:
    # all 38 from scans 306-324 of 334.
    moved = int(0.9 * res.num_scans)
    ((first, last, count),) = worst.passes
    assert moved <= first <= last < res.num_scans and count == worst.contradictions
    assert describe_region(bad.as_dict()["regions"][0]).endswith(
        f"from scans {first}-{last} ({count})"
    )
    # Without the square's limit (a share no square can reach), the same map passes.
    lenient = dataclasses.replace(settings, min_region_share=1.0)
    assert check_map(res, broken, lenient).consistent


def test_intel_excerpt_odometry_is_flagged_and_the_closed_map_passes() -> None:
    res = _intel_excerpt()
    closed = check_map(res)
    odometry = check_map(res, res.odometry_poses)
    # Measured: closed 1.5 % of 13215 judged returns contradicted, 0 of 278 loops over their
    # bound; the odometry alone 35 % of 11909, 258 of 278.
    assert closed.consistent, closed.reasons
    assert closed.contradiction_fraction < 0.05 and closed.loops_over_bound <= 5
    assert not odometry.consistent, odometry.as_dict()
    assert odometry.contradiction_fraction > 0.2
    assert any(r.startswith("contradictions:") for r in odometry.reasons)
    assert odometry.loops_over_bound > 0.5 * len(odometry.loops)


def test_summary_is_json_ready_and_states_its_thresholds() -> None:
    import json

    run, res = _ring_run()
    check = check_map(res, _truth(run), settings=MapCheckSettings(max_loops_over_bound=1.0))
    record = json.loads(json.dumps(check.as_dict()))
    assert record["consistent"] is True and record["reasons"] == []
    assert record["contradictions"] <= record["returns"] == check.returns > 1000
    assert check.returns < sum(len(p) for p in res.node_points)  # only what revisits saw
    assert record["loops"] == sum(e.kind == "loop" for e in res.graph.edges)
    assert record["thresholds"]["max_contradiction_fraction"] == 0.10
    assert len(check.contradiction_points) == check.contradictions
    # Each region of a broken map names the passes whose returns it holds contradicted,
    # summing to its count.
    broken = check_map(res, _broken(tuple(_truth(run)), 100, SE2.from_vector([0.3, 0.0, 0.05])))
    regions = json.loads(json.dumps(broken.as_dict()))["regions"]
    assert len(regions) >= 3  # (measured: 4)
    for region in regions:
        assert sum(n for _, _, n in region["passes"]) == region["contradictions"] > 0
        assert all(0 <= a <= b < res.num_scans for a, b, _ in region["passes"])


def test_write_outputs_writes_the_check(tmp_path: Any) -> None:
    import json

    from scanreg.pipeline import write_outputs

    run, res = _ring_run()
    truth = _truth(run)
    broken = check_map(res, _broken(tuple(truth), 100, SE2.from_vector([0.3, 0.0, 0.05])))
    paths = write_outputs(tmp_path, res, plot=False, check=broken)
    record = json.loads(paths["summary"].read_text())
    assert record["self_check"] == json.loads(json.dumps(broken.as_dict()))
    assert record["num_scans"] == res.num_scans
    xy = np.loadtxt(paths["contradictions"], delimiter=",", skiprows=1, ndmin=2)
    np.testing.assert_allclose(xy, broken.contradiction_points, atol=5e-4)
    # Without a check given, the run's own is made.
    paths = write_outputs(tmp_path / "own", res, plot=False)
    own = json.loads(paths["summary"].read_text())["self_check"]
    assert own == json.loads(json.dumps(check_map(res).as_dict()))
    exact = check_map(res, truth, settings=MapCheckSettings(max_loops_over_bound=1.0))
    write_outputs(tmp_path / "exact", res, plot=False, check=exact)
    if importlib.util.find_spec("plotly") is not None:  # the report shows the verdict
        from scanreg.report import write_report

        assert "<b>INCONSISTENT</b>" in write_report(tmp_path).read_text(encoding="utf-8")
        assert "<b>consistent</b>" in write_report(tmp_path / "exact").read_text(encoding="utf-8")
    with pytest.raises(TypeError, match="check: expected a MapCheck"):
        write_outputs(tmp_path / "bad", res, check={"consistent": True})  # type: ignore[arg-type]


def test_loop_residual_against_a_hand_computed_chi2() -> None:
    info = np.diag([100.0, 400.0, 0.0])  # nothing along θ: two degrees of freedom
    edge = Edge("loop", 0, 1, SE2.from_vector([1.0, 0.0, 0.0]), info, Kernel("cauchy", 2.0))
    r = loop_residual(edge, SE2.identity(), SE2.from_vector([1.1, 0.05, 0.3]))
    e = (SE2.from_vector([1.0, 0.0, 0.0]).inverse() @ SE2.from_vector([1.1, 0.05, 0.3])).log()
    assert r.dof == 2 and r.bound == pytest.approx(13.816)
    assert r.chi2 == pytest.approx(100 * e[0] ** 2 + 400 * e[1] ** 2)
    assert r.weight == pytest.approx(1 / (1 + r.chi2 / 4))
    assert kernel_weight(Kernel("huber", 1.0), 4.0) == pytest.approx(0.5)
    assert kernel_weight(None, 1e6) == 1.0


def test_bad_input_names_the_argument() -> None:
    _, res = _ring_run()
    with pytest.raises(TypeError, match="result: expected a MappingResult or a SavedMap"):
        check_map("run")  # type: ignore[arg-type]
    # A saved map: 2D, of format 2 (its node scans kept) only.
    saved = SavedMap.from_result(res, session="ring")
    assert check_map(saved).returns == check_map(res).returns
    with pytest.raises(ValueError, match=r"result: the map keeps no node scans \(format 1\)"):
        check_map(dataclasses.replace(saved, node_points=None, format_version=1))
    with pytest.raises(ValueError, match="result: check_map needs a 2D map, got a 3D one"):
        check_map(dataclasses.replace(saved, dim=3))
    with pytest.raises(ValueError, match="poses: expected one per scan"):
        check_map(res, res.poses[:-1])
    with pytest.raises(TypeError, match="settings: expected MapCheckSettings"):
        check_map(res, settings={"resolution": 0.1})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="max_range: must be finite and > 0"):
        MapCheckSettings(max_range=0.0)
    with pytest.raises(ValueError, match="min_views: must be an int >= 1"):
        MapCheckSettings(min_views=0)
    with pytest.raises(ValueError, match="bins: must be an int >= 3"):
        MapCheckSettings(bins=2)
    with pytest.raises(ValueError, match="max_contradiction_fraction: must be in"):
        MapCheckSettings(max_contradiction_fraction=2.0)
    assert isinstance(check_map(res, settings=dataclasses.replace(MapCheckSettings())), MapCheck)


def test_core_refuses_bad_arrays() -> None:
    from scanreg import _core

    poses = np.zeros((1, 3))
    points = np.array([[1.0, 0.0]])
    opts: dict[str, Any] = {"bins": 360, "margin": 0.3, "max_range": 10.0, "min_gap": 0}
    with pytest.raises(ValueError, match="offsets: must rise from 0"):
        _core.see_through(poses, points, np.array([0, 2]), **opts)
    with pytest.raises(ValueError, match="points: contains NaN"):
        _core.see_through(poses, np.array([[np.nan, 0.0]]), np.array([0, 1]), **opts)
    with pytest.raises(ValueError, match="poses: expected shape"):
        _core.see_through(np.zeros((1, 2)), points, np.array([0, 1]), **opts)
    with pytest.raises(ValueError, match="stride: must be >= 1"):
        _core.see_through(poses, points, np.array([0, 1]), **opts, stride=0)
    with pytest.raises(ValueError, match=r"sessions: expected one per scan \(1\), got 2"):
        _core.see_through(poses, points, np.array([0, 1]), **opts, sessions=np.zeros(2, np.uint32))
    # The 3D judge: rows of [R row-major, t] and (N, 3) points, refused alike by name.
    pose3 = np.r_[np.eye(3).ravel(), np.zeros(3)][None, :]
    point3 = np.array([[1.0, 0.0, 0.0]])
    opts3 = {**opts, "elevation_bins": 60}
    world, judged, seen, through = _core.see_through_3d(pose3, point3, np.array([0, 1]), **opts3)
    assert world.shape == (1, 3) and list(judged) == [0] and seen[0] == through[0] == 0
    with pytest.raises(ValueError, match=r"poses: expected shape \(N, 12\)"):
        _core.see_through_3d(poses, point3, np.array([0, 1]), **opts3)
    with pytest.raises(ValueError, match=r"points: expected shape \(N, 3\)"):
        _core.see_through_3d(pose3, points, np.array([0, 1]), **opts3)
    with pytest.raises(ValueError, match="elevation_bins: must be at least 3"):
        _core.see_through_3d(pose3, point3, np.array([0, 1]), **{**opts3, "elevation_bins": 2})
    with pytest.raises(ValueError, match="poses: contains NaN"):
        _core.see_through_3d(np.full((1, 12), np.nan), point3, np.array([0, 1]), **opts3)
