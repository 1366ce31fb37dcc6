"""The pass search (scanreg.pipeline.pass_loops): a revisit seen across open space, which no
single scan closes, found by the node's last metres; a corridor's look-alikes refused."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scanreg import SE2
from scanreg import simulate as sim
from scanreg.pipeline.loops import LoopSettings, build_submap, match_loop
from scanreg.pipeline.pass_loops import match_pass, pass_points

LOOSE = np.diag([1.0, 1.0, 0.03])  # the graph's relative covariance: 1 m, 10° σ


def _hall() -> sim.Scene:
    """An irregular hall: 24 corners at random radii 11-15 m round (20, 12), no long wall."""
    b = sim.SceneBuilder(2)
    rng = np.random.default_rng(0)
    ang = np.sort(rng.uniform(0.0, 2.0 * math.pi, 24))
    rad = rng.uniform(11.0, 15.0, 24)
    b.polyline(
        [(20.0 + r * math.cos(a), 12.0 + r * math.sin(a)) for a, r in zip(ang, rad, strict=True)],
        closed=True,
    )
    return b.build()


def test_a_view_across_the_hall_closes_by_its_pass_and_not_elsewhere() -> None:
    # An earlier pass drives east along the hall's south side (a 180° laser facing east); the
    # current one drives west along its north side, 12 m away, facing west-south-west: each
    # scan sees a part of what the earlier pass saw. No single scan scores the loop search's
    # floor on the earlier pass; its last 8 m, laid by their (locally right) poses, do, at
    # one place only, and land on the truth from a prediction 0.5 m off.
    scene = _hall()
    laser = dataclasses.replace(sim.LaserModel.preset("sick_lms200"), max_range=30.0)
    old = {k: SE2.from_vector([14.0 + 0.5 * k, 5.0, 0.0]) for k in range(25)}
    scans = {k: sim.simulate_scan(scene, laser, p, seed=k).points for k, p in old.items()}
    wide = build_submap(12, list(range(25)), scans, old, resolution=0.05, voxel_size=0.05)
    sub = build_submap(12, list(range(10, 15)), scans, old, resolution=0.05, voxel_size=0.05)
    cur = [SE2.from_vector([26.0 - 0.5 * k, 17.0, math.pi - 0.4]) for k in range(17)]
    pts = {k: sim.simulate_scan(scene, laser, p, seed=100 + k).points for k, p in enumerate(cur)}
    travel = [0.5 * k for k in range(17)]
    settings = LoopSettings()
    truth = old[12].inverse() @ cur[16]
    predicted = truth @ SE2.from_vector([0.4, -0.3, 0.02])
    window = (3.0, math.radians(26.0))
    single = match_loop(
        pts[16], 16, sub, predicted, LOOSE, settings, window=window, search_submap=wide
    )
    assert not single.accepted and math.isnan(single.score), single.reasons
    first, laid = pass_points(16, pts, cur.__getitem__, travel, path=8.0, voxel_size=0.1)
    assert first == 0 and 500 < len(laid) < 800
    match = match_pass(laid, 16, wide, predicted, LOOSE, settings)
    error = truth.inverse() @ match.measured
    # Measured: 0.35, no pose 1.5 m off at half of it, 2 mm and 0.02° off.
    assert match.accepted and match.search == "pass", match.reasons
    assert 0.3 < match.score < 0.4 and match.rival == 0.0
    assert np.linalg.norm(error.translation) < 0.01 and abs(error.angle) < math.radians(0.1)
    assert match.information[0, 0] == pytest.approx(1.0 / settings.pass_sigma[0] ** 2)
    # Searched around a prediction 6 m off, where the pass is not: nothing.
    far = match_pass(laid, 16, wide, truth @ SE2.from_vector([0.0, 6.0, 0.0]), LOOSE, settings)
    assert not far.accepted and far.reasons[0].startswith("pass: correlative score < 0.10")
    # The graph certain of a pose 0.5 m off: the match fails χ² (it never overrules the graph).
    certain = np.diag([1e-4, 1e-4, 1e-6])
    checked = match_pass(laid, 16, wide, predicted, certain, settings)
    assert not checked.accepted and checked.reasons[0].startswith("inconsistent with the graph")


def test_a_corridor_pass_is_refused_as_ambiguous() -> None:
    # A corridor 2 m wide with nothing on its walls: the pass fits anywhere along it.
    scene = sim.corridor(length=80.0, width=2.0, closed_ends=False)
    laser = dataclasses.replace(sim.LaserModel.preset("laser_360"), max_range=8.0)
    old = {k: SE2.from_vector([20.0 + 0.5 * k, 0.1 * (k % 2), 0.0]) for k in range(25)}
    scans = {k: sim.simulate_scan(scene, laser, p, seed=k).points for k, p in old.items()}
    wide = build_submap(12, list(range(25)), scans, old, resolution=0.05, voxel_size=0.05)
    cur = [SE2.from_vector([34.0 - 0.5 * k, -0.2, math.pi]) for k in range(17)]
    pts = {k: sim.simulate_scan(scene, laser, p, seed=100 + k).points for k, p in enumerate(cur)}
    travel = [0.5 * k for k in range(17)]
    _, laid = pass_points(16, pts, cur.__getitem__, travel, path=8.0, voxel_size=0.1)
    truth = old[12].inverse() @ cur[16]
    match = match_pass(
        laid, 16, wide, truth @ SE2.from_vector([0.4, 0.1, 0.0]), LOOSE, LoopSettings()
    )
    # Measured: 0.97, a pose 1.6 m along it at 0.98 of that.
    assert not match.accepted and match.rival > 0.9, match.rival
    assert match.reasons[0].startswith("pass: ambiguous: a pose 1."), match.reasons


def test_pass_points_and_settings_name_what_is_wrong() -> None:
    poses = [SE2.from_vector([0.5 * k, 0.0, 0.0]) for k in range(10)]
    pts = {k: np.array([[1.0, 0.0], [1.0, 1.0]]) for k in range(10)}
    travel = [0.5 * k for k in range(10)]
    first, laid = pass_points(9, pts, poses.__getitem__, travel, path=2.0, voxel_size=0.0)
    # Nodes 5-9 (2 m of path), each scan's two points in node 9's frame.
    assert first == 5 and laid.shape == (10, 2)
    assert np.allclose(sorted(set(laid[:, 0].round(6))), [-1.0, -0.5, 0.0, 0.5, 1.0])
    with pytest.raises(ValueError, match=r"^node: 10 is not one of the 10 nodes"):
        pass_points(10, pts, poses.__getitem__, travel, path=2.0, voxel_size=0.0)
    with pytest.raises(ValueError, match=r"^path: must be finite and >= 0"):
        pass_points(9, pts, poses.__getitem__, travel, path=math.nan, voxel_size=0.0)
    for name, bad in (
        ("pass_min_score", 0.0),
        ("pass_rival_ratio", 1.5),
        ("pass_path", -1.0),
        ("pass_rival_exclusion", math.inf),
        ("pass_voxel_size", 0.0),
        ("pass_angular_resolution", math.nan),
    ):
        with pytest.raises(ValueError, match=rf"^{name}: must be"):
            LoopSettings(**{name: bad})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"^pass_sigma: "):
        LoopSettings(pass_sigma=(0.0, 0.01))
