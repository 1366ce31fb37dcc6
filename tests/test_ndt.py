"""2D NDT: recovery on simulated scans (scan-to-map and scan-to-scan), the MbICP
self-matching protocol on real scans, the corridor's weak axis, hostile input."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import scanreg
from conftest import data_dir, office_map
from scanreg import SE2
from scanreg import simulate as sim
from scanreg.io import read_carmen

SICK = sim.LaserModel.preset("sick_lms200")


def _c(a: Any) -> np.ndarray[Any, np.dtype[np.float64]]:
    return np.ascontiguousarray(a, dtype=np.float64)


_office = office_map


def _free(scan: Any) -> bool:
    """The simulated sensor is not standing against (or in) furniture."""
    return bool(np.median(np.linalg.norm(scan.points, axis=1)) >= 1.0)


def test_scan_to_map_recovers_offsets() -> None:
    scene, reference = _office()
    target = scanreg.prepare_ndt(reference, cell_size=0.5)
    assert target.cell_sizes == (1.0, 0.5)
    rng = np.random.default_rng(1)
    errors = []
    for n in range(40):
        truth = SE2.from_vector([rng.uniform(2.5, 3.5), rng.uniform(3.3, 4.1), rng.uniform(-3, 3)])
        scan = sim.simulate_scan(scene, SICK, truth, seed=n)
        offset = rng.uniform([-0.15, -0.15, -0.05], [0.15, 0.15, 0.05])
        if not _free(scan):
            continue
        res = scanreg.match_ndt(
            _c(scan.points), target, init=SE2.from_vector(truth.as_vector() + offset)
        )
        e = (truth.inverse() @ res.pose).as_vector()
        errors.append([math.hypot(e[0], e[1]), abs(e[2]), res.converged])
    err = np.array(errors)
    ok = (err[:, 0] < 0.02) & (err[:, 1] < 0.005)
    assert len(err) >= 25 and ok.mean() >= 0.9, err[~ok]
    assert np.median(err[:, 0]) < 0.01 and np.median(err[:, 1]) < math.radians(0.1)
    assert err[ok, 2].all()  # the good ones say they converged


def test_scan_to_scan_recovers_offsets_and_reports_covariance() -> None:
    scene = sim.floor_plan(seed=1, num_people=0)
    rng = np.random.default_rng(1)
    good = total = 0
    for n in range(40):
        a = SE2.from_vector([rng.uniform(2.5, 3.5), rng.uniform(3.3, 4.1), rng.uniform(-3, 3)])
        ref = sim.simulate_scan(scene, SICK, a, seed=n)
        step = SE2.from_vector(rng.uniform([-0.2, -0.2, -0.1], [0.2, 0.2, 0.1]))
        src = sim.simulate_scan(scene, SICK, a @ step, seed=n, scan_index=1)
        if not (_free(ref) and _free(src)):
            continue
        res = scanreg.match_ndt(_c(src.points), _c(ref.points), cell_size=1.0)
        e = (step.inverse() @ res.pose).as_vector()
        total += 1
        if math.hypot(e[0], e[1]) < 0.03 and abs(e[2]) < 0.01:
            good += 1
            assert res.converged and np.isfinite(res.covariance).all()
            assert 0 < res.standard_deviations[0] < 0.05 and res.fitness > 0.8
            np.testing.assert_allclose(res.covariance @ res.information, np.eye(3), atol=1e-8)
            assert np.linalg.eigvalsh(res.information).min() > 0
    assert total >= 20 and good / total >= 0.9


def test_mbicp_laserazos_self_matching_small_offsets() -> None:
    log = read_carmen(data_dir("carmen-mbicp-laserazos", "laserazosSM3.log"))
    rng = np.random.default_rng(0)
    errors = []
    for i in rng.choice(len(log), 40, replace=False):
        scan = log.scans[int(i)]
        mask = scan.valid(min_range=0.05)
        noisy = scan.ranges[mask] + rng.normal(0.0, 0.01, int(mask.sum()))
        ang = scan.angles[mask]
        copy = np.c_[noisy * np.cos(ang), noisy * np.sin(ang)]
        lim = [0.1, 0.1, math.radians(15)]
        truth = SE2.from_vector(rng.uniform(np.negative(lim), lim))
        res = scanreg.match_ndt(_c(truth.inverse().apply(copy)), scan.to_points(0.05))
        e = (truth.inverse() @ res.pose).as_vector()
        errors.append([math.hypot(e[0], e[1]), abs(e[2])])
    err = np.array(errors)
    assert np.mean((err[:, 0] <= 0.06) & (err[:, 1] <= 0.02)) >= 0.95
    assert np.median(err[:, 0]) < 0.005 and np.median(err[:, 1]) < math.radians(0.1)


def test_corridor_is_weak_along_its_axis() -> None:
    scene = sim.corridor(length=200.0, width=2.0, closed_ends=False)
    a = SE2.from_vector([100.0, 0.1, 0.05])
    ref = _c(sim.simulate_scan(scene, SICK, a, seed=0).points)
    src = _c(sim.simulate_scan(scene, SICK, a @ SE2.from_vector([0.2, 0.05, 0.03]), seed=1).points)
    res = scanreg.match_ndt(src, ref, cell_size=1.0)
    assert abs(res.conditioning.weakest.vector[0]) > 0.95
    assert (
        res.conditioning.weakest.ratio < 1e-4
        or res.standard_deviations[0] > 5 * res.standard_deviations[1]
    )
    assert abs(res.pose.as_vector()[1] - 0.05) < 0.01 and abs(res.pose.angle - 0.03) < 0.005


def test_hostile_input_names_the_problem() -> None:
    ref = _c(np.random.default_rng(0).uniform(-3, 3, (200, 2)))
    target = scanreg.prepare_ndt(ref, cell_size=1.0)
    with pytest.raises(ValueError, match="target: a 2D NDT target for 3D source points"):
        scanreg.match_ndt(_c(np.zeros((4, 3))), target)
    with pytest.raises(ValueError, match="source: point 0 has a non-finite"):
        scanreg.match_ndt(_c([[np.inf, 0.0]]), target)
    with pytest.raises(ValueError, match=r"cell_size: 2\.0 differs"):
        scanreg.match_ndt(ref, target, cell_size=2.0)
    with pytest.raises(ValueError, match="max_iterations: must be >= 1"):
        scanreg.match_ndt(ref, target, max_iterations=0)
    with pytest.raises(ValueError, match="init: "):
        scanreg.match_ndt(ref, target, init=np.diag([2.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="cell_size: must be finite and > 0"):
        scanreg.prepare_ndt(ref, cell_size=0.0)
    with pytest.raises(ValueError, match="levels: must be in"):
        scanreg.prepare_ndt(ref, levels=0)
    with pytest.raises(ValueError, match="min_points: must be >= 3"):
        scanreg.prepare_ndt(ref, min_points=2)
    with pytest.raises(ValueError, match="min_eigen_ratio"):
        scanreg.prepare_ndt(ref, min_eigen_ratio=0.0)
    with pytest.raises(ValueError, match=r"no cell of 0\.01 m holds 3 points"):
        scanreg.prepare_ndt(_c([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]), cell_size=0.01, levels=1)
    far = scanreg.match_ndt(ref + 100.0, target)
    assert far.stop_reason == "no_overlap" and not far.converged and far.fitness == 0.0
