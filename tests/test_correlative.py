"""Correlative scan matching: exact recovery on simulated scans, branch and bound equal to the
exhaustive search, Olson's covariance against a brute-force score surface, the corridor, the
MbICP self-matching protocol on real scans, hostile input."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from typing import Any

import numpy as np
import pytest
import scanreg
from conftest import data_dir, office_map
from scanreg import SE2
from scanreg import simulate as sim
from scanreg.correlative import SEARCHES
from scanreg.io import read_carmen

SICK = sim.LaserModel.preset("sick_lms200")


def _c(a: Any) -> np.ndarray[Any, np.dtype[np.float64]]:
    return np.ascontiguousarray(a, dtype=np.float64)


_office_map = office_map


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


@pytest.mark.parametrize("search", ["exhaustive", "branch_and_bound"])
def test_recovers_known_offsets_on_simulated_scans(search: str) -> None:
    scene, reference = _office_map()
    grid = scanreg.prepare_correlative(reference, resolution=0.05)
    rng = np.random.default_rng(1)
    checked = 0
    for n in range(40):
        truth = SE2.from_vector([rng.uniform(2.5, 3.5), rng.uniform(3.3, 4.1), rng.uniform(-3, 3)])
        scan = sim.simulate_scan(scene, SICK, truth, seed=n)
        offset = np.array(
            [rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(-0.25, 0.25)]
        )
        if np.median(np.linalg.norm(scan.points, axis=1)) < 1.0:
            continue  # the simulated sensor stands against (or in) furniture
        init = SE2.from_vector(truth.as_vector() + offset)
        res = grid.match(
            _c(scan.points),
            init=init,
            window=(0.4, 0.4, 0.3),
            angular_resolution=0.02,
            search=search,
        )
        err = res.pose.as_vector() - truth.as_vector()
        assert abs(err[0]) <= 0.05 and abs(err[1]) <= 0.05, (n, err)
        assert abs(_wrap(err[2])) <= 0.02, (n, err)
        assert res.fitness > 0.8 and res.score > 0.7 and not res.at_window_edge
        checked += 1
    assert checked >= 20


def test_branch_and_bound_equals_exhaustive_on_random_cases() -> None:
    scene = sim.floor_plan(seed=3, num_people=0)
    rng = np.random.default_rng(5)
    fewer = 0
    for case in range(30):
        a = SE2.from_vector([rng.uniform(1, 20), rng.uniform(-0.8, 0.8), rng.uniform(-3, 3)])
        step = SE2.from_vector(
            [rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(-0.5, 0.5)]
        )
        ref = sim.simulate_scan(scene, SICK, a, seed=case).points
        src = sim.simulate_scan(scene, SICK, a @ step, seed=case, scan_index=1).points
        res = float(rng.choice([0.03, 0.05, 0.1]))
        grid = scanreg.prepare_correlative(_c(ref), resolution=res, levels=int(rng.integers(1, 8)))
        # Windows of every shape, some too small to hold the truth (ties and edges included).
        window = (rng.uniform(0, 0.7), rng.uniform(0, 0.7), rng.uniform(0, 0.6))
        kw = dict(window=window, angular_resolution=float(rng.uniform(0.005, 0.03)))
        init = SE2.from_vector(rng.normal(0, 0.1, 3))
        ex = grid.match(_c(src), init=init, search="exhaustive", **kw)
        bb = grid.match(_c(src), init=init, search="branch_and_bound", **kw)
        assert bb.pose == ex.pose, (case, bb.pose, ex.pose)
        assert bb.score == ex.score and bb.fitness == ex.fitness
        assert ex.num_evaluated == ex.num_candidates and ex.num_bounds == 0
        assert bb.num_evaluated <= ex.num_evaluated
        fewer += bb.num_evaluated + bb.num_bounds < ex.num_evaluated
    assert fewer >= 20  # it also has to prune


def test_covariance_is_olsons_estimate_over_the_window() -> None:
    """Recompute the score surface in numpy from the grid and compare Σ and its mapping."""
    scene = sim.floor_plan(seed=1, num_people=0)
    a = SE2.from_vector([3.0, 3.7, 0.4])
    ref = _c(sim.simulate_scan(scene, SICK, a, seed=0).points)
    src = _c(sim.simulate_scan(scene, SICK, a @ SE2.from_vector([0.1, -0.05, 0.04]), seed=1).points)
    grid = scanreg.prepare_correlative(ref, resolution=0.1, sigma=0.25)
    init = SE2.from_vector([0.05, 0.0, 0.3])
    dth = 0.02
    res = grid.match(
        src, init=init, window=(0.3, 0.3, 0.1), angular_resolution=dth, search="exhaustive"
    )
    like = grid.likelihood.astype(np.float64)
    origin = np.array(grid.origin)
    c0 = init.as_vector()
    rows, sums = [], []
    for k in range(-5, 6):
        th = c0[2] + k * dth
        rot = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
        cells = np.floor((src @ rot.T + c0[:2] - origin) / 0.1).astype(int)
        for i in range(-3, 4):
            for j in range(-3, 4):
                cx, cy = cells[:, 0] + i, cells[:, 1] + j
                inside = (cx >= 0) & (cy >= 0) & (cx < like.shape[1]) & (cy < like.shape[0])
                sums.append(like[cy[inside], cx[inside]].sum())
                rows.append([c0[0] + 0.1 * i, c0[1] + 0.1 * j, th])
    x, s = np.array(rows), np.array(sums)
    assert res.num_evaluated == len(s)
    best = int(np.argmax(s))
    np.testing.assert_allclose(res.pose.as_vector(), x[best], atol=1e-12)
    assert res.score == pytest.approx(s[best] / len(src), rel=1e-9)
    p = np.exp(s - s.max())
    mu = p @ x / p.sum()
    olson = (x * p[:, None]).T @ x / p.sum() - np.outer(mu, mu)
    quant = np.diag([0.01, 0.01, dth**2]) / 12
    np.testing.assert_allclose(res.window_covariance, olson + quant, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(res.mean, mu, atol=1e-9)
    # Window frame → right perturbation: ρ = Rᵀ δt.
    jac = np.eye(3)
    jac[:2, :2] = res.pose.rotation.T
    np.testing.assert_allclose(res.covariance, jac @ res.window_covariance @ jac.T, atol=1e-15)
    assert olson[0, 0] > 0 and olson[2, 2] > 0  # the blur spreads p over several candidates


def test_corridor_is_weak_along_its_axis() -> None:
    scene = sim.corridor(length=200.0, width=2.0, closed_ends=False)
    a = SE2.from_vector([100.0, 0.1, 0.05])
    ref = _c(sim.simulate_scan(scene, SICK, a, seed=0).points)
    src = _c(sim.simulate_scan(scene, SICK, a @ SE2.from_vector([0.2, 0.05, 0.03]), seed=1).points)
    res = scanreg.match_correlative(src, ref, window=(0.5, 0.3, 0.2), resolution=0.05, sigma=0.1)
    sd = res.standard_deviations
    assert sd[0] > 4 * sd[1]
    weakest = res.conditioning.weakest.vector
    assert abs(weakest[0]) > 0.95
    assert "translation along (1.00" in res.conditioning.weakest.description
    # Across the corridor and in heading it is pinned down.
    assert abs(res.pose.as_vector()[1] - 0.05) <= 0.05 and abs(res.pose.angle - 0.03) <= 0.02


def test_mbicp_laserazos_self_matching_protocol() -> None:
    """Minguez et al. 2006 / Censi's CSM harness: each real scan against a noisy (σ = 1 cm)
    copy of itself displaced by a known offset, at three perturbation sizes."""
    log = read_carmen(data_dir("carmen-mbicp-laserazos", "laserazosSM3.log"))
    rng = np.random.default_rng(0)
    subset = rng.choice(len(log), 25, replace=False)
    res_m, dth = 0.03, 0.01
    for max_t, max_th in [
        (0.05, math.radians(5)),
        (0.1, math.radians(15)),
        (0.2, math.radians(45)),
    ]:
        errors = []
        for i in subset:
            scan = log.scans[int(i)]
            mask = scan.valid(min_range=0.05)
            noisy = scan.ranges[mask] + rng.normal(0.0, 0.01, int(mask.sum()))
            ang = scan.angles[mask]
            copy = np.c_[noisy * np.cos(ang), noisy * np.sin(ang)]
            truth = SE2.from_vector(rng.uniform([-max_t, -max_t, -max_th], [max_t, max_t, max_th]))
            res = scanreg.match_correlative(
                _c(truth.inverse().apply(copy)),
                scan.to_points(min_range=0.05),
                window=(0.2, 0.2, math.radians(45)),
                resolution=res_m,
                angular_resolution=dth,
                search="branch_and_bound",
            )
            e = (truth.inverse() @ res.pose).as_vector()
            errors.append([math.hypot(e[0], e[1]), abs(e[2])])
        err = np.array(errors)
        success = np.mean((err[:, 0] <= 2 * res_m) & (err[:, 1] <= 2 * dth))
        assert success >= 0.95, (max_t, success, err.max(axis=0))
        assert np.median(err[:, 0]) <= res_m and np.median(err[:, 1]) <= dth


def test_prepared_grid_gives_the_same_answer() -> None:
    scene = sim.floor_plan(seed=1, num_people=0)
    a = SE2.from_vector([3.0, 3.7, 0.4])
    ref = _c(sim.simulate_scan(scene, SICK, a, seed=0).points)
    src = _c(sim.simulate_scan(scene, SICK, a @ SE2.from_vector([0.1, 0.0, 0.05]), seed=1).points)
    grid = scanreg.prepare_correlative(ref, resolution=0.05)
    r1 = scanreg.match_correlative(src, grid)
    r2 = scanreg.match_correlative(src, ref, resolution=0.05)
    assert r1.pose == r2.pose and r1.score == r2.score
    assert r1.timing.grid_seconds == 0.0 and r2.timing.grid_seconds > 0.0
    assert grid.likelihood.shape == grid.shape[::-1]
    assert float(grid.likelihood.max()) == 1.0


def test_hostile_input_names_the_problem() -> None:
    ref = _c(np.random.default_rng(0).uniform(-3, 3, (50, 2)))
    src = ref.copy()
    grid = scanreg.prepare_correlative(ref, resolution=0.1)
    cases: list[tuple[type[Exception], str, dict[str, Any]]] = [
        (ValueError, r"source: expected shape \(N, 2\)", {"source": _c(np.zeros((5, 3)))}),
        (ValueError, "source: point 1 has a non-finite", {"source": _c([[0, 0], [np.nan, 1.0]])}),
        (ValueError, "source: is empty", {"source": _c(np.zeros((0, 2)))}),
        (TypeError, "source: expected real numbers", {"source": src.astype(complex)}),
        (ValueError, "search: unknown 'icp'", {"search": "icp"}),
        (ValueError, "window: half-widths", {"window": (0.1, -0.1, 0.1)}),
        (ValueError, "window: expected", {"window": (0.1, 0.1)}),
        (ValueError, "window: dθ must be", {"window": (0.1, 0.1, 4.0)}),
        (ValueError, "angular_resolution: must be finite and > 0", {"angular_resolution": 0.0}),
        (ValueError, "resolution: 0.2 differs", {"resolution": 0.2}),
        (ValueError, "init: ", {"init": np.array([[1.0, 0, 0], [0, 2.0, 0], [0, 0, 1.0]])}),
        (TypeError, "init: expected SE2", {"init": scanreg.SE3.identity()}),
        (ValueError, "covariance_radius", {"covariance_radius": -1}),
    ]
    for exc, match, kw in cases:
        args = {"source": src, **kw}
        source = args.pop("source")
        with pytest.raises(exc, match=match):
            scanreg.match_correlative(source, grid, **args)
    with pytest.raises(ValueError, match="resolution: must be finite and > 0"):
        scanreg.prepare_correlative(ref, resolution=-1.0)
    with pytest.raises(ValueError, match="levels: must be in"):
        scanreg.prepare_correlative(ref, levels=13)
    with pytest.raises(ValueError, match="resolution: the reference spans"):
        scanreg.prepare_correlative(_c([[0.0, 0.0], [1e5, 1e5]]), resolution=0.01)
    with pytest.raises(ValueError, match="points: expected shape"):
        scanreg.prepare_correlative(_c(np.zeros((4, 3))))
    with pytest.raises(ValueError, match="reference: expected shape"):
        scanreg._core.CorrelativeGrid(_c(np.zeros((4, 3))), 0.1, 0.1, 1)


def test_intel_local_relations_scan_to_scan() -> None:
    """Scan-to-scan correlative odometry on the Intel subset, evaluated on the 69 local
    Kümmerle relations (|t2 − t1| < 10 s), chained between the two scans of each relation.

    Measured (benchmarks/intel_scan_to_scan.py): raw odometry 0.052 ± 0.013 m, 1.22 ± 1.22°;
    correlative 0.027 ± 0.056 m, 0.34 ± 0.29°."""
    from scanreg.eval.relations import read_relations

    folder = data_dir("carmen-intel")
    log = read_carmen(folder / "intel_gfs_subset_clf_timestamps.clf")
    rel = read_relations(folder / "intel_gfs_subset.relations")
    stamps = log.timestamps
    points = [s.to_points(0.1, 40.0) for s in log.scans]
    cache: dict[int, SE2] = {}

    def step(k: int) -> SE2:  # T_{k-1, k}
        if k not in cache:
            cache[k] = scanreg.match_correlative(
                points[k],
                points[k - 1],
                init=log.motion_prior(k - 1, k),
                window=(0.3, 0.3, math.radians(10)),
                resolution=0.05,
                search="branch_and_bound",
            ).pose
        return cache[k]

    errs, odom_errs = [], []
    for t1, t2, ref in zip(rel.t1, rel.t2, rel.poses, strict=True):
        if abs(t2 - t1) >= 60.0:
            continue
        i, j = (int(np.argmin(np.abs(stamps - t))) for t in (t1, t2))
        assert abs(stamps[i] - t1) < 1e-4 and abs(stamps[j] - t2) < 1e-4
        lo, hi = min(i, j), max(i, j)
        est = SE2.identity()
        for k in range(lo + 1, hi + 1):
            est = est @ step(k)
        if i > j:
            est = est.inverse()
        odom = log.motion_prior(i, j)
        truth = SE2.from_vector([ref[0, 3], ref[1, 3], math.atan2(ref[1, 0], ref[0, 0])])
        for pose, out in ((est, errs), (odom, odom_errs)):
            e = (truth.inverse() @ pose).as_vector()
            out.append([math.hypot(e[0], e[1]), abs(math.degrees(e[2]))])
    err, odo = np.array(errs), np.array(odom_errs)
    assert len(err) == 69
    assert abs(odo[:, 0].mean() - 0.052) < 0.001 and abs(odo[:, 1].mean() - 1.22) < 0.01
    assert err[:, 0].mean() < 0.035 and err[:, 1].mean() < 0.45
    assert err[:, 1].mean() < odo[:, 1].mean() / 3  # heading: 3× better than wheel odometry
    assert np.median(err[:, 0]) < np.median(odo[:, 0]) / 2


_DETERMINISM_SCRIPT = """
import numpy as np, scanreg
from scanreg import SE2, simulate as sim
scene = sim.floor_plan(seed=2, num_people=0)
laser = sim.LaserModel.preset("sick_lms200")
a = SE2.from_vector([7.0, 0.3, 0.2])
ref = np.ascontiguousarray(sim.simulate_scan(scene, laser, a, seed=0).points)
src = np.ascontiguousarray(
    sim.simulate_scan(scene, laser, a @ SE2.from_vector([0.2, -0.1, 0.05]), seed=1).points
)
for search in ("exhaustive", "branch_and_bound"):
    r = scanreg.match_correlative(src, ref, window=(0.4, 0.4, 0.2), search=search)
    print(r.pose.as_vector().tobytes().hex(), r.covariance.tobytes().hex(), r.num_evaluated)
n = scanreg.match_ndt(src, ref, cell_size=1.0)
print(n.pose.as_vector().tobytes().hex(), n.covariance.tobytes().hex())
"""


def test_results_do_not_depend_on_the_thread_count() -> None:
    outputs = []
    for threads in ("1", "2", "3"):
        env = {**os.environ, "RAYON_NUM_THREADS": threads}
        run = subprocess.run(
            [sys.executable, "-c", _DETERMINISM_SCRIPT],
            env=env,
            capture_output=True,
            text=True,
            check=True,
        )
        outputs.append(run.stdout)
    assert outputs[0] == outputs[1] == outputs[2]
    assert len(outputs[0].splitlines()) == 3


def test_motion_cost_ranks_by_the_prediction_where_the_scan_cannot() -> None:
    # A featureless corridor: shifts along the axis score almost the same (the free search
    # still finds the truth from the walls' sampling). With ``init_covariance`` the ranking is
    # the posterior's: along the axis, where the scan barely prefers one shift, the
    # prediction 0.25 m ahead wins; across the axis and in heading, where the scan is sharp,
    # the prediction 15 cm and 3° off loses to the scan.
    scene = sim.corridor(length=200.0, width=2.0, closed_ends=False)
    a = SE2.from_vector([100.0, 0.1, 0.05])
    step = SE2.from_vector([0.2, 0.05, 0.03])
    ref = _c(sim.simulate_scan(scene, SICK, a, seed=0).points)
    src = _c(sim.simulate_scan(scene, SICK, a @ step, seed=1).points)
    grid = scanreg.prepare_correlative(ref, resolution=0.05, sigma=0.1)
    # The target is the scan taken at ``a`` (its frame): the match is ``step``.
    init = step @ SE2.from_vector([0.25, -0.15, 0.05])
    kw: dict[str, Any] = dict(init=init, window=(0.5, 0.3, 0.2), angular_resolution=0.01)
    free = grid.match(src, **kw)
    cov = np.diag([0.05**2, 0.3**2, 0.1**2])
    pulled = {s: grid.match(src, init_covariance=cov, search=s, **kw) for s in SEARCHES}
    assert pulled["exhaustive"].pose == pulled["branch_and_bound"].pose
    res = pulled["branch_and_bound"]
    err_free = free.pose.as_vector() - step.as_vector()
    err = res.pose.as_vector() - step.as_vector()
    assert abs(err_free[0]) <= 0.05  # free: the scan's faint preference along the axis
    assert 0.1 <= err[0] <= 0.25  # with the cost: pulled most of the way to the prediction
    assert abs(err[1]) <= 0.05 and abs(_wrap(err[2])) <= 0.02  # across: the scan's
    # The ranking is S − ½ δᵀ P δ over the window frame (δt = R_init ρ), recomputed in numpy.
    like = grid.likelihood.astype(np.float64)
    origin, c0 = np.array(grid.origin), init.as_vector()
    jac = np.eye(3)
    jac[:2, :2] = init.rotation
    info = np.linalg.inv(jac @ cov @ jac.T)
    best, arg = -np.inf, None
    for k in range(-20, 21):
        th = c0[2] + k * 0.01
        rot = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
        cells = np.floor((src @ rot.T + c0[:2] - origin) / 0.05).astype(int)
        for i in range(-10, 11):
            for j in range(-6, 7):
                cx, cy = cells[:, 0] + i, cells[:, 1] + j
                inside = (cx >= 0) & (cy >= 0) & (cx < like.shape[1]) & (cy < like.shape[0])
                d = np.array([0.05 * i, 0.05 * j, 0.01 * k])
                value = like[cy[inside], cx[inside]].sum() - 0.5 * d @ info @ d
                if value > best + 1e-9:
                    best, arg = value, c0 + d
    np.testing.assert_allclose(res.pose.as_vector(), arg, atol=1e-9)
    # The cost only ranks: the score is the scan's own at the chosen pose.
    same = grid.match(src, init=res.pose, window=(0.0, 0.0, 0.0))
    assert res.score == pytest.approx(same.score, rel=1e-12)


def test_motion_cost_does_not_override_a_basin_the_scan_prefers() -> None:
    # A room pins every direction: a prediction 0.2 m and 6° off with a σ of 0.1 m / 3°
    # still ends in the true basin (the cost at the truth, ~5 units, is far below what the
    # scan loses off it).
    scene, reference = _office_map()
    grid = scanreg.prepare_correlative(reference, resolution=0.05)
    truth = SE2.from_vector([3.0, 3.7, 0.4])
    scan = _c(sim.simulate_scan(scene, SICK, truth, seed=3).points)
    init = truth @ SE2.from_vector([0.15, -0.13, math.radians(6.0)])
    cov = np.diag([0.1**2, 0.1**2, math.radians(3.0) ** 2])
    res = grid.match(
        scan, init=init, window=(0.3, 0.3, 0.2), angular_resolution=0.01, init_covariance=cov
    )
    err = (truth.inverse() @ res.pose).as_vector()
    assert np.linalg.norm(err[:2]) <= 0.05 and abs(err[2]) <= 0.015


def test_motion_cost_bad_input_is_named() -> None:
    ref = _c(np.random.default_rng(0).uniform(-3, 3, (100, 2)))
    for bad, message in (
        (np.eye(2), r"init_covariance: expected shape \(3, 3\)"),
        (np.full((3, 3), np.nan), "init_covariance: must be finite and symmetric"),
        (np.diag([1.0, 0.0, 1.0]), "init_covariance: must be positive definite"),
        (np.array([[1.0, 2.0, 0], [0, 1, 0], [0, 0, 1]]), "must be finite and symmetric"),
    ):
        with pytest.raises(ValueError, match=message):
            scanreg.match_correlative(ref, ref, init_covariance=bad)
    with pytest.raises(TypeError, match="init_covariance"):
        scanreg.match_correlative(ref, ref, init_covariance=object())


def test_find_with_a_score_floor_is_the_full_answer_or_none() -> None:
    # find_correlative prunes below min_score: where the best candidate reaches it, the
    # answer is match_correlative's to the bit, with less work; where it does not, None.
    from scanreg.correlative import find_correlative, match_correlative

    scene = sim.floor_plan(seed=3, num_people=0)
    rng = np.random.default_rng(11)
    found = missing = 0
    for case in range(20):
        a = SE2.from_vector([rng.uniform(1, 20), rng.uniform(-0.8, 0.8), rng.uniform(-3, 3)])
        step = SE2.from_vector(rng.uniform(-0.5, 0.5, 3))
        ref = sim.simulate_scan(scene, SICK, a, seed=case).points
        src = sim.simulate_scan(scene, SICK, a @ step, seed=case, scan_index=1).points
        grid = scanreg.prepare_correlative(_c(ref), resolution=0.05)
        init = SE2.from_vector(rng.normal(0, 0.3, 3))
        kw: dict[str, Any] = dict(init=init, window=(0.6, 0.6, 0.5))
        full = match_correlative(_c(src), grid, **kw)
        floor = float(rng.uniform(0.3, 0.9))
        above = find_correlative(_c(src), grid, min_score=floor, **kw)
        if full.score >= floor:
            found += 1
            assert above is not None
            assert above.pose == full.pose and above.score == full.score
            assert np.array_equal(above.covariance, full.covariance)
            assert above.num_evaluated + above.num_bounds <= full.num_evaluated + full.num_bounds
        else:
            missing += 1
            assert above is None, (case, full.score, floor)
    assert found >= 5 and missing >= 5  # both outcomes were tested
    with pytest.raises(ValueError, match=r"min_score: must be in \[0, 1\], got 1.5"):
        find_correlative(_c(src), grid, min_score=1.5)


def test_an_updated_grid_is_the_grid_built_from_scratch() -> None:
    # A local map that slides along a path (the last 4 scans, world frame) as the 2D odometry's
    # does: each grid updated from the previous one equals a fresh build, cell for cell and bit
    # for bit, and so does a match against it; every other step in place (the old grid's
    # rasters changed where they change, its pooled levels pooled again there).
    scene, _ = _office_map()
    path = [SE2.from_vector([2.0 + 0.25 * k, 3.5 + 0.1 * k, 0.2 * k]) for k in range(10)]
    world = [
        path[k].apply(sim.simulate_scan(scene, SICK, path[k], seed=k).points)
        for k in range(len(path))
    ]
    grid = None
    for end in range(1, len(world) + 1):
        points = _c(np.concatenate(world[max(0, end - 4) : end]))
        built = scanreg.prepare_correlative(points, resolution=0.05)
        grid = built if grid is None else grid.updated(points, in_place=end % 2 == 0)
        assert grid.origin == built.origin and grid.shape == built.shape
        assert grid.levels == built.levels and grid.num_points == built.num_points
        np.testing.assert_array_equal(grid.likelihood, built.likelihood)
        np.testing.assert_array_equal(grid._native.distance_squared, built._native.distance_squared)
        scan = _c(sim.simulate_scan(scene, SICK, path[end - 1], seed=100 + end).points)
        init = path[end - 1] @ SE2.from_vector([0.1, -0.05, 0.03])
        a = grid.match(scan, init=init, window=(0.3, 0.3, 0.2))
        b = built.match(scan, init=init, window=(0.3, 0.3, 0.2))
        assert a.pose == b.pose and a.score == b.score and a.num_evaluated == b.num_evaluated
        np.testing.assert_array_equal(a.covariance, b.covariance)
    assert grid is not None
    with pytest.raises(ValueError, match="points"):
        grid.updated(np.array([[0.0, np.nan]]))
    with pytest.raises(ValueError, match="points"):
        grid.updated(np.array([[0.0, np.nan]]), in_place=True)
    with pytest.raises(TypeError, match="in_place"):
        grid.updated(points, in_place=1)  # type: ignore[arg-type]


def test_best_correlative_pose_matches_the_full_search_and_names_bad_input() -> None:
    from scanreg.correlative import best_correlative_pose

    rng = np.random.default_rng(5)
    walls = rng.uniform(-3.0, 3.0, (400, 2))
    grid = scanreg.prepare_correlative(walls, resolution=0.05)
    truth = SE2.from_vector([0.12, -0.07, 0.05])
    source = np.ascontiguousarray(truth.inverse().apply(walls[::2]))
    window = (0.3, 0.3, 0.2)
    full = scanreg.match_correlative(source, grid, init=SE2.identity(), window=window)
    pose = best_correlative_pose(source, grid, SE2.identity(), window)
    np.testing.assert_array_equal(pose.as_vector(), full.pose.as_vector())
    with pytest.raises(ValueError, match="source: is empty"):
        best_correlative_pose(np.zeros((0, 2)), grid, SE2.identity(), window)
    with pytest.raises(ValueError, match="source: point 1 has a non-finite"):
        best_correlative_pose(np.array([[0.0, 1.0], [np.nan, 0.0]]), grid, SE2.identity(), window)
    with pytest.raises(ValueError, match="source: expected shape"):
        best_correlative_pose(np.zeros((4, 3)), grid, SE2.identity(), window)
