"""Issue 5: calibrated covariance, degeneracy named in pose coordinates, verdict with reasons.

Every test here can fail: each checks a measured quantity against what the physics of the
scene says (a corridor is degenerate along its axis, a room is not; NEES of a calibrated
covariance is inside the χ² band), not against a recorded output.
"""

from __future__ import annotations

import numpy as np
import pytest
import scanreg
from conftest import data_dir
from scanreg import SE2, SE3
from scanreg import simulate as sim
from scanreg.quality import nees_band, transform_covariance
from scanreg.verdict import VerdictThresholds

LASER = sim.LaserModel.preset("laser_360")
STEP2 = SE2.from_vector([0.3, 0.1, np.deg2rad(2.0)])


def _scan(scene: sim.Scene, pose: SE2, seed: int) -> np.ndarray:
    return np.ascontiguousarray(sim.simulate_scan(scene, LASER, pose, seed=seed).points)


def _pair(scene: sim.Scene, pose_a: SE2, seed: int) -> tuple[np.ndarray, np.ndarray]:
    return _scan(scene, pose_a, 2 * seed), _scan(scene, pose_a @ STEP2, 2 * seed + 1)


ROOM = sim.square_room(5.0)
CORRIDOR = sim.corridor(length=200.0, width=3.0)
ROOM_POSE = SE2.from_vector([0.5, 0.3, 0.3])
CORRIDOR_POSE = SE2.from_vector([100.0, 0.0, 0.0])


# --- degeneracy ---------------------------------------------------------------------------


def test_corridor_is_degenerate_along_its_axis_and_the_room_is_not() -> None:
    src, tgt = _pair(CORRIDOR, CORRIDOR_POSE, 0)
    res = scanreg.register(src, tgt, max_correspondence_distance=1.0)
    assert res.degeneracy is not None and res.degeneracy.degenerate
    (weak,) = res.degeneracy.weak_directions
    assert weak.description == "translation along (1.00, 0.00)"
    assert abs(weak.vector[0]) > 0.99
    assert res.degeneracy.eigenvalues[0] < 0.3 * res.degeneracy.threshold
    assert res.verdict is not None and not res.verdict.accepted
    assert any(
        r.startswith("degenerate: translation along (1.00, 0.00)") for r in res.verdict.reasons
    )
    # The covariance says so: the standard deviation along x is the prior's (δ/√3 for the
    # gate δ, plus the drift), not mm.
    assert np.sqrt(res.covariance[0, 0]) > 0.5
    assert np.sqrt(res.covariance[1, 1]) < 0.01

    src, tgt = _pair(ROOM, ROOM_POSE, 0)
    res = scanreg.register(src, tgt, max_correspondence_distance=1.0)
    assert res.degeneracy is not None and not res.degeneracy.degenerate
    assert res.degeneracy.eigenvalues[0] > 3 * res.degeneracy.threshold
    # Well constrained, but a square room turned by 90° fits as well: rejected as ambiguous
    # (tests/test_basin.py), and for that reason only.
    assert res.verdict is not None and not res.verdict.accepted
    assert [r.split(":")[0] for r in res.verdict.reasons] == ["ambiguous"], res.verdict.reasons


def test_degeneracy_is_named_for_point_to_point_too() -> None:
    # Point-to-point's own JᵀJ has N·I as its translation block: the analysis uses the plane
    # information from the target normals instead.
    src, tgt = _pair(CORRIDOR, CORRIDOR_POSE, 1)
    res = scanreg.register(src, tgt, method="point_to_point", max_correspondence_distance=1.0)
    assert res.degeneracy is not None
    assert res.degeneracy.basis == "plane_information"
    assert [w.description for w in res.degeneracy.weak_directions] == [
        "translation along (1.00, 0.00)"
    ]


def test_degeneracy_aware_solve_keeps_the_prior_along_the_axis() -> None:
    src, tgt = _pair(CORRIDOR, CORRIDOR_POSE, 2)
    truth = STEP2.inverse()
    init = truth @ SE2.from_vector([0.2, 0.05, 0.01])  # 20 cm off along the axis
    prior = np.diag([0.2**2, 0.2**2, 0.02**2])
    aware = scanreg.register(
        src,
        tgt,
        init=init,
        init_covariance=prior,
        degeneracy_aware=True,
        max_correspondence_distance=1.0,
    )
    # (The default holds a degenerate refined result too: hold_degenerate, below.)
    plain = scanreg.register(
        src, tgt, init=init, max_correspondence_distance=1.0, hold_degenerate=False
    )
    moved_aware = (init.inverse() @ aware.pose).log()
    moved_plain = (init.inverse() @ plain.pose).log()
    assert abs(moved_aware[0]) < 1e-3  # kept the initial guess along x ...
    assert abs(moved_plain[0]) > 10 * abs(moved_aware[0])  # ... where plain ICP drifted
    err = (aware.pose.inverse() @ truth).log()
    assert abs(err[1]) < 0.01 and abs(err[2]) < 0.002  # y and θ still solved
    assert aware.covariance[0, 0] == pytest.approx(0.2**2, rel=0.05)  # the prior's variance


# --- verdict ------------------------------------------------------------------------------


def test_partial_overlap_with_low_cost_is_rejected_for_overlap() -> None:
    src, tgt = _pair(ROOM, ROOM_POSE, 3)
    truth = STEP2.inverse()
    # The target keeps one wall: what overlaps fits perfectly (low cost), but little overlaps.
    keep = tgt[:, 1] < -3.0
    res = scanreg.register(
        src, np.ascontiguousarray(tgt[keep]), init=truth, max_correspondence_distance=0.3
    )
    assert res.quality is not None and res.verdict is not None
    assert res.quality.residual_rmse < 0.05  # the cost is low ...
    assert res.quality.overlap < 0.5  # ... but most of the source sees nothing
    assert not res.verdict.accepted
    assert f"overlap {res.quality.overlap:.2f} < 0.50" in res.verdict.reasons


def test_full_overlap_with_large_residual_is_rejected_for_cost() -> None:
    # The target is a bigger room: every source point has a target point inside the gate
    # (full overlap), but the best fit leaves ~0.35 m residuals (the seed's problem 5).
    src = _scan(ROOM, ROOM_POSE, 8)
    tgt = _scan(sim.square_room(5.7), ROOM_POSE, 9)
    res = scanreg.register(src, tgt, max_correspondence_distance=0.9)
    assert res.quality is not None and res.verdict is not None
    assert res.quality.overlap > 0.9
    assert res.quality.residual_rmse > 0.5 * res.quality.gate
    assert not res.verdict.accepted
    assert any(r.startswith("inlier RMSE") for r in res.verdict.reasons)
    assert not any(r.startswith("overlap") for r in res.verdict.reasons)


def test_motion_bound_exceeded_is_rejected() -> None:
    src, tgt = _pair(ROOM, ROOM_POSE, 5)
    bound = VerdictThresholds(max_translation=0.1, max_rotation=np.deg2rad(1.0))
    res = scanreg.register(src, tgt, max_correspondence_distance=1.0, thresholds=bound)
    assert res.verdict is not None and not res.verdict.accepted
    moved = res.quality.translation_from_init if res.quality else 0.0
    assert moved == pytest.approx(np.hypot(0.3, 0.1), abs=0.02)
    assert f"moved {moved:.3g} from the initial guess > bound 0.1" in res.verdict.reasons
    assert any(r.startswith("rotated") for r in res.verdict.reasons)
    # Without the bound it passes every check but the square room's 90° ambiguity.
    no_probe = VerdictThresholds(basin_probe=False)
    ok = scanreg.register(src, tgt, max_correspondence_distance=1.0, thresholds=no_probe)
    assert ok.verdict is not None and ok.verdict.accepted, ok.verdict.reasons


def test_thresholds_argument_is_type_checked() -> None:
    src, tgt = _pair(ROOM, ROOM_POSE, 6)
    with pytest.raises(TypeError, match="thresholds"):
        scanreg.register(src, tgt, thresholds={"min_overlap": 0.5})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="init_covariance"):
        scanreg.register(src, tgt, init_covariance=np.eye(2))
    with pytest.raises(ValueError, match="covariance"):
        scanreg.register(src, tgt, covariance="magic")  # type: ignore[arg-type]


# --- covariance ---------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["point_to_point", "point_to_plane"])
def test_censi_matches_monte_carlo_on_a_small_problem(method: str) -> None:
    # Points of a room's walls 0.25 m apart, isotropic noise σ on source and target (Censi's
    # model): the spread of the estimates over 200 noise draws is what the closed form says.
    rng = np.random.default_rng(1)
    s = np.arange(-4.0, 4.01, 0.25)
    walls = np.concatenate(
        [np.c_[s, np.full_like(s, -4.0)], np.c_[np.full_like(s, 4.0), s], np.c_[s, 0.5 * s + 4.5]]
    )
    truth = SE2.from_vector([0.05, -0.03, 0.01])
    sigma = 0.01
    estimates, censi = [], []
    for _ in range(200):
        src = np.ascontiguousarray(walls + rng.normal(0, sigma, walls.shape))
        tgt = np.ascontiguousarray(truth.apply(walls) + rng.normal(0, sigma, walls.shape))
        res = scanreg.register(
            src,
            tgt,
            init=truth,
            method=method,
            max_correspondence_distance=0.1,  # type: ignore[arg-type]
        )
        estimates.append((truth.inverse() @ res.pose).log())
        assert res.covariances is not None
        censi.append(res.covariances.censi)
    emp = np.cov(np.array(estimates).T)
    pred = np.mean(censi, axis=0)
    ratio = np.diag(emp) / np.diag(pred)
    # 200 draws: the sample variance is within ±30 % of the truth at ~3σ.
    assert np.all((ratio > 0.7) & (ratio < 1.4)), ratio


def _jitter(k: int) -> list[float]:
    """``[x, y, yaw]`` of realisation ``k``'s sensor offset, ±0.15 m and ±2.9°, as in
    ``covariance_calibration.py --randomise-pose``."""
    rng = np.random.default_rng(20_000 + k)
    return [rng.uniform(-0.15, 0.15), rng.uniform(-0.15, 0.15), rng.uniform(-0.05, 0.05)]


def _mean_nees(
    scene: sim.Scene,
    pose_a: SE2,
    reps: int,
    *,
    randomise: bool = False,
    prior: np.ndarray | None = None,
    **kwargs: object,
) -> float:
    """Mean NEES of ``reps`` seeded realisations. ``randomise``: the sensor moved per
    realisation by ±0.15 m and ±2.9° of yaw (``covariance_calibration.py --randomise-pose``);
    ``prior``: the initial guess drawn from it, passed with the degeneracy-aware solve."""
    truth = STEP2.inverse()
    out = []
    for k in range(reps):
        pose = pose_a @ SE2.from_vector(_jitter(k)) if randomise else pose_a
        src, tgt = _pair(scene, pose, 100 + k)
        extra: dict[str, object] = dict(kwargs)
        if prior is not None:
            rng = np.random.default_rng(10_000 + k)
            extra.update(
                init=truth @ SE2.exp(rng.multivariate_normal(np.zeros(3), prior)),
                init_covariance=prior,
                degeneracy_aware=True,
            )
        res = scanreg.register(src, tgt, max_correspondence_distance=1.0, **extra)  # type: ignore[arg-type]
        d = (res.pose.inverse() @ truth).log()
        out.append(float(d @ res.information @ d))
    return float(np.mean(out))


PRIOR2 = np.diag([0.1**2, 0.1**2, np.deg2rad(1.0) ** 2])


@pytest.mark.parametrize(
    ("scene", "pose", "randomise", "prior"),
    [
        (ROOM, ROOM_POSE, False, None),
        (CORRIDOR, CORRIDOR_POSE, False, None),
        (CORRIDOR, CORRIDOR_POSE, True, None),
        (CORRIDOR, CORRIDOR_POSE, False, PRIOR2),
        (CORRIDOR, CORRIDOR_POSE, True, PRIOR2),
    ],
    ids=["room", "corridor", "corridor-at-a-heading", "corridor-prior", "corridor-heading-prior"],
)
def test_default_covariance_is_consistent(
    scene: sim.Scene, pose: SE2, randomise: bool, prior: np.ndarray | None
) -> None:
    # Seeded reduced version of benchmarks/covariance_calibration.py (the published table uses
    # 200 realisations; see docs/calibration.md).
    # Acceptance (issue 5): mean NEES inside the 95 % band or at worst within a factor 2 of
    # the dimension; the room sits at ~1.4 (sampling error, docs/calibration.md). The corridor
    # from the identity is over-cautious by construction: along its axis the prior is the
    # gate's (δ²/3) against a fixed 0.3 m step; it gave 1.41 / 1.25 here (fixed / at a
    # heading) while that prior was counted twice (δ² × 2) and the eigenvector's rotation
    # row was taken for random tilt. At a heading the weak axis snapped to x gave 35; with
    # a motion prior the converged lateral estimate follows the held along-axis one (2.4 ×
    # dof before the valley term).
    reps = 40
    lo, hi = nees_band(3, reps)
    mean = _mean_nees(scene, pose, reps, randomise=randomise, prior=prior)
    assert min(lo, 1.5) <= mean <= max(hi, 6.0), (mean, lo, hi)


def test_weak_variance_is_the_prior_plus_the_solves_own_move_along_the_axis() -> None:
    # From the identity the plain solve moves along the corridor by what the data do not fix
    # (up to 0.1 m here): the variance there is the prior's plus that move squared, counted
    # once (it was the prior's counted twice: 0.67 m² instead of ~0.35).
    # (hold_degenerate=False: the default holds the start along the axis, below.)
    pose = CORRIDOR_POSE @ SE2.from_vector(_jitter(1))
    src, tgt = _pair(CORRIDOR, pose, 1)
    res = scanreg.register(src, tgt, max_correspondence_distance=1.0, hold_degenerate=False)
    deg = res.degeneracy
    assert deg is not None and deg.degenerate and res.covariances is not None
    s_inv = deg.scaling()
    (w,) = deg.weak_basis().T
    moved = float(w @ (res.pose.log() / s_inv))
    assert abs(moved) > 0.05
    prior = float(w @ (np.asarray(res.covariances.prior) / np.outer(s_inv, s_inv)) @ w)
    assert prior == pytest.approx(1.0 / 3.0, rel=0.02)  # the gate's, 1 m: uniform within ±1 m
    cov = np.asarray(res.covariances.calibrated) / np.outer(s_inv, s_inv)
    assert float(w @ cov @ w) == pytest.approx(prior + moved**2, rel=1e-6)


def test_hold_degenerate_keeps_the_start_along_the_axis() -> None:
    # The refined 2D result held along its weak directions (hold_degenerate, the default): in
    # the corridor the solve drifted 0.11 m along the axis from a start 0.2 m off (error
    # 0.31 m); held, the estimate keeps the start there (the error is the start's, inside the
    # gate-wide prior's σ 0.58 m the covariance reports) and still solves across it.
    src, tgt = _pair(CORRIDOR, CORRIDOR_POSE, 2)
    truth = STEP2.inverse()
    init = truth @ SE2.from_vector([0.2, 0.05, 0.01])
    held = scanreg.register(src, tgt, init=init, max_correspondence_distance=1.0)
    free = scanreg.register(
        src, tgt, init=init, max_correspondence_distance=1.0, hold_degenerate=False
    )
    assert abs((init.inverse() @ held.pose).log()[0]) < 1e-3
    assert abs((init.inverse() @ free.pose).log()[0]) > 0.05
    err = (held.pose.inverse() @ truth).log()
    assert abs(err[1]) < 0.002 and abs(err[2]) < 0.001  # measured 0.3 mm, 0.1 mrad
    assert held.covariance[0, 0] == pytest.approx(1.0 / 3.0, rel=0.01)  # the gate-wide prior
    assert held.verdict is not None and not held.verdict.accepted  # still degenerate


def test_hessian_covariance_is_overconfident_in_the_corridor() -> None:
    # The check above can fail: the old default fails it by orders of magnitude.
    mean = _mean_nees(CORRIDOR, CORRIDOR_POSE, 10, covariance="hessian")
    assert mean > 100 * nees_band(3, 10)[1]


def test_every_kind_is_reported_and_the_setting_picks_one() -> None:
    src, tgt = _pair(ROOM, ROOM_POSE, 7)
    res = scanreg.register(src, tgt, covariance="censi")
    assert res.covariances is not None
    np.testing.assert_array_equal(res.covariance, res.covariances.censi)
    for kind in ("hessian", "censi", "block", "calibrated"):
        c = getattr(res.covariances, kind)
        assert c.shape == (3, 3) and np.all(np.linalg.eigvalsh(c) > 0)
    # calibrated covers both censi and block
    cal = res.covariances.calibrated
    for other in (res.covariances.censi, res.covariances.block):
        assert np.linalg.eigvalsh(cal - other)[0] > -1e-12 * np.abs(cal).max()


def test_transform_covariance_moves_the_tangent_to_the_left() -> None:
    rng = np.random.default_rng(0)
    pose = SE3.from_vector([1.0, -2.0, 0.5, 0.1, -0.2, 0.3])
    a = rng.normal(size=(6, 6))
    cov = a @ a.T * 1e-4
    # Monte Carlo: T exp(δ) = exp(Ad δ) T, so the left perturbation has covariance Ad Σ Adᵀ.
    deltas = rng.multivariate_normal(np.zeros(6), cov, size=4000)
    left = np.array([((pose @ SE3.exp(d)) @ pose.inverse()).log() for d in deltas])
    np.testing.assert_allclose(
        np.cov(left.T), transform_covariance(cov, pose.adjoint()), atol=3e-5, rtol=0.1
    )
    with pytest.raises(ValueError, match="adjoint"):
        transform_covariance(cov, np.eye(3))


def test_sampling_covariance_sees_the_degenerate_drift_and_not_the_room() -> None:
    src, tgt = _pair(CORRIDOR, CORRIDOR_POSE, 9)
    prior = np.diag([0.2**2, 0.05**2, 0.01**2])
    corridor = scanreg.sampling_covariance(
        src, tgt, init=STEP2.inverse(), init_covariance=prior, restarts=8, seed=1,
        max_correspondence_distance=1.0,
    )  # fmt: skip
    assert corridor.converged_fraction > 0.5
    assert corridor.offsets.shape[1] == 3
    # Along the corridor the restarts stay where they started: the spread is the prior's.
    assert np.sqrt(corridor.covariance[0, 0]) > 0.05
    src, tgt = _pair(ROOM, ROOM_POSE, 9)
    room = scanreg.sampling_covariance(
        src, tgt, init=STEP2.inverse(), init_covariance=prior, restarts=8, seed=1,
        max_correspondence_distance=1.0,
    )  # fmt: skip
    assert np.sqrt(room.covariance[0, 0]) < 0.01
    with pytest.raises(ValueError, match="restarts"):
        scanreg.sampling_covariance(src, tgt, restarts=1)


def _sweep(scene: sim.Scene, pose: SE3, seed: int) -> np.ndarray:
    pts = sim.simulate_sweep(scene, sim.LidarModel.preset("vlp16"), pose, seed=seed).points
    return scanreg.preprocess.voxel_downsample(np.ascontiguousarray(pts), 0.3).points


STEP3 = SE3.from_vector([0.5, 0.1, 0.0, 0.0, 0.0, np.deg2rad(2.0)])


def _moved(pose_a: SE3, k: int) -> SE3:
    """``pose_a`` moved for realisation ``k`` by :func:`_jitter` (in the ground plane)."""
    x, y, yaw = _jitter(k)
    return pose_a @ SE3.from_vector([x, y, 0, 0, 0, yaw])


@pytest.mark.parametrize(
    ("name", "method", "randomise", "with_prior"),
    [
        ("tunnel", "point_to_plane", False, True),
        ("tunnel", "point_to_plane", True, True),
        ("tunnel", "point_to_plane", True, False),
        ("street", "gicp", True, True),
        ("tunnel", "gicp", True, True),
    ],
    ids=str,
)
def test_default_covariance_is_consistent_in_3d(
    name: str, method: str, randomise: bool, with_prior: bool
) -> None:
    # Reduced, seeded version of the 3D rows of docs/calibration.md: the tunnel with a motion
    # prior and the degeneracy-aware solve (200 realisations: 0.83 × dof; with the sensor
    # moved per realisation, 1.29 × dof, where the weak axis snapped to the sensor's x gave
    # 2.4 ×), the street with GICP, sensor moved (1.06 × dof; with the fixed pose one
    # voxel-grid phase's bias, 8σ, is sampled 12 times: 3.5 × dof, as point-to-plane's). The
    # tunnel from the identity at a heading: the eigenvector's systematic pitch tilt (the ring
    # pattern) claimed ~0.4 mrad of pitch the truth does not have (2.9 × dof here before
    # _axis_cover). The tunnel's GICP with a prior: its held pose's point noise and block
    # scores over every pair counted the rings' misfit off their lock as noise (2.1–2.2 here,
    # 0.37 × dof over 100 realisations; over the determined pairs 0.84 ×).
    scene, pose_a = (
        (sim.tunnel(), SE3.from_vector([0, 0, 1.8, 0, 0, 0]))
        if name == "tunnel"
        else (sim.street(seed=4), SE3.from_vector([0, 1.75, 1.73, 0, 0, 0]))
    )
    truth = STEP3.inverse()
    prior = np.diag([0.1**2] * 3 + [np.deg2rad(1.0) ** 2] * 3)
    reps = 12
    nees = []
    for k in range(reps):
        pose = _moved(pose_a, k) if randomise else pose_a
        src = _sweep(scene, pose, 2 * k)
        tgt = scanreg.prepare(_sweep(scene, pose @ STEP3, 2 * k + 1), covariances=True)
        if with_prior:
            rng = np.random.default_rng(k)
            init = truth @ SE3.exp(rng.multivariate_normal(np.zeros(6), prior))
            res = scanreg.register(
                src,
                tgt,
                method=method,  # type: ignore[arg-type]
                init=init,
                init_covariance=prior,
                degeneracy_aware=True,
                max_correspondence_distance=1.0,
            )
        else:
            res = scanreg.register(src, tgt, method=method, max_correspondence_distance=1.0)  # type: ignore[arg-type]
        assert res.degeneracy is not None
        assert res.degeneracy.degenerate == (name == "tunnel")
        d = (res.pose.inverse() @ truth).log()
        nees.append(float(d @ res.information @ d))
    assert 3.0 <= float(np.mean(nees)) <= 12.0, nees


def _street_pair(k: int) -> tuple[np.ndarray, scanreg.PreparedTarget]:
    """The calibration street, the sensor moved per realisation (:func:`_moved`)."""
    pose_a = _moved(SE3.from_vector([0, 1.75, 1.73, 0, 0, 0]), k)
    street = sim.street(seed=4)
    return _sweep(street, pose_a, 2 * k), scanreg.prepare(_sweep(street, pose_a @ STEP3, 2 * k + 1))


def test_point_to_point_covariance_is_the_plane_estimates_plus_their_offset() -> None:
    # The contract, against the public API: point-to-point's calibrated covariance is the
    # point-to-line estimate's (re-solved from the point-to-point pose, same settings) plus
    # the offset between the two as δδᵀ, and that offset is its model_shift. The re-solve is
    # the plain solve (no refinement in the basin: scanreg.slide.refine_in_basin).
    src, tgt = _pair(ROOM, ROOM_POSE @ SE2.from_vector(_jitter(3)), 3)
    target = scanreg.prepare(tgt)
    pp = scanreg.register(src, target, method="point_to_point", max_correspondence_distance=1.0)
    pl = scanreg.register(
        src,
        target,
        method="point_to_line",
        init=pp.pose,
        max_correspondence_distance=1.0,
        refine_in_basin=False,
    )
    assert pp.covariances is not None and pl.covariances is not None
    offset = (pp.pose.inverse() @ pl.pose).log()
    assert np.linalg.norm(offset[:2]) > 1e-4  # the two estimates do differ
    np.testing.assert_allclose(pp.covariances.model_shift, offset, rtol=1e-9, atol=1e-15)
    want = np.asarray(pl.covariances.calibrated) + np.outer(offset, offset)
    np.testing.assert_allclose(pp.covariances.calibrated, want, rtol=1e-9, atol=1e-18)


def test_point_to_point_default_covariance_is_consistent_in_the_room() -> None:
    # Point-to-point settles where the sampling offsets along the walls balance: its noise
    # covariances were 10× and the one-step model shift 3.2× over-confident here (35
    # realisations: 10.1 with the previous code, whose error std was 2.0 mm against 1.0–1.25
    # claimed).
    mean = _mean_nees(ROOM, ROOM_POSE, 35, randomise=True, method="point_to_point")
    assert 1.5 <= mean <= 6.0, mean


def test_model_shift_covers_the_street_point_to_plane_bias() -> None:
    # The street's point-to-plane estimate is 2.5–2.8 cm short along the road, 10× its noise
    # (docs/calibration.md): the pairs whose source and target normals disagree pull it. The
    # model-error term (one step without them) points the same way and brings the default
    # covariance within the factor 2; without it (censi ∨ block) the NEES is several × dof.
    truth = STEP3.inverse()
    with_term, without = [], []
    for k in range(6):
        src, tgt = _street_pair(k)
        res = scanreg.register(src, tgt, method="point_to_plane", max_correspondence_distance=1.0)
        assert res.covariances is not None
        d = (res.pose.inverse() @ truth).log()
        shift = np.asarray(res.covariances.model_shift)
        assert d[0] < -0.015 and shift[0] < -0.01, (d, shift)
        cal = np.asarray(res.covariances.calibrated)
        with_term.append(float(d @ np.linalg.solve(cal, d)))
        without.append(float(d @ np.linalg.solve(cal - np.outer(shift, shift), d)))
    assert float(np.mean(with_term)) <= 12.0, with_term
    assert float(np.mean(without)) > 18.0, without


def test_model_shift_is_small_where_there_is_no_bias_and_zero_for_gicp() -> None:
    src, tgt = _pair(ROOM, ROOM_POSE, 3)
    res = scanreg.register(src, tgt, max_correspondence_distance=1.0)
    assert res.covariances is not None
    shift = np.asarray(res.covariances.model_shift)
    sigma = np.sqrt(np.diag(res.covariances.calibrated))
    assert shift.shape == (3,) and np.any(shift != 0)
    assert np.all(np.abs(shift) < sigma), (shift, sigma)  # below the noise: no inflation
    g = scanreg.register(src, tgt, method="gicp", max_correspondence_distance=1.0)
    assert g.covariances is not None  # 2D: no linear neighbourhoods, no GICP shift
    np.testing.assert_array_equal(g.covariances.model_shift, np.zeros(3))
    # Along a corridor's weak axis the term is left out (the prior speaks there).
    src, tgt = _pair(CORRIDOR, CORRIDOR_POSE, 3)
    c = scanreg.register(src, tgt, max_correspondence_distance=1.0)
    assert c.covariances is not None and c.degeneracy is not None and c.degeneracy.degenerate
    assert abs(float(np.asarray(c.covariances.model_shift)[0])) < 1e-4


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def test_gicp_systems_of_the_censi_pass_equal_numpy() -> None:
    # GICP's model shift reads two systems the censi pass sums: its own JᵀWJ and JᵀWr over
    # every correspondence and over those whose target neighbourhood is not linear. Checked
    # here against a direct numpy sum (W = (C_q + R C_p Rᵀ)⁻¹, J = [I, −[p]×], r = Rᵀe).
    src, tgt = _street_pair(1)
    tgt = scanreg.prepare(tgt.points, covariances=True)
    assert tgt.covariances is not None and tgt.linear is not None and tgt.linear.any()
    scov = scanreg.prepare(src, covariances=True).covariances
    assert scov is not None
    pose = STEP3.inverse() @ SE3.from_vector([0.02, -0.01, 0.01, 0.002, -0.001, 0.003])
    t = pose.as_matrix()
    rot = t[:3, :3]
    nearest = tgt.nearest(np.ascontiguousarray(src @ rot.T + t[:3, 3]), 1.0)
    corr = np.asarray(nearest.indices, dtype=np.int64)
    ana = scanreg._core.censi_analysis(
        src,
        tgt.points,
        t,
        corr,
        method="gicp",
        kernel="none",
        kernel_scale=1.0,
        source_variance=1.0,
        target_variance=1.0,
        block_size=1.0,
        target_normals=tgt.normals,
        source_covariances=scov,
        target_covariances=tgt.covariances,
        target_linear=tgt.linear,
    )
    ok = corr >= 0
    j = corr[ok]
    p = src[ok]
    e = p @ rot.T + t[:3, 3] - tgt.points[j]
    w = np.linalg.inv(tgt.covariances[j] + np.einsum("ab,nbc,dc->nad", rot, scov[ok], rot))
    wl = np.einsum("ba,nbc,cd->nad", rot, w, rot)
    jac = np.concatenate(
        [np.broadcast_to(np.eye(3), (len(p), 3, 3)), -np.array([_skew(x) for x in p])], axis=2
    )
    h = np.einsum("nai,nab,nbj->nij", jac, wl, jac)
    g = np.einsum("nai,nab,nb->ni", jac, wl, e @ rot)
    det = ~np.asarray(tgt.linear)[j]
    for got, want in (
        (ana.hessian, h.sum(0)),
        (ana.score, g.sum(0)),
        (ana.determined_hessian, h[det].sum(0)),
        (ana.determined_score, g[det].sum(0)),
    ):
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.abs(want).max())
    assert ana.num_determined_pairs == int(det.sum()) < int(ok.sum())


def test_gicp_model_shift_reaches_its_bias_along_the_road() -> None:
    # In the street GICP's minimum sits 4-8 mm behind the truth along the road in every
    # realisation (a bias: 1.5σ of the Euclidean point-noise covariance, 3.4σ of the one along
    # the normal); the pairs whose target neighbourhood is not linear (rings and poles left
    # out) put the minimum 40-60 % of that way back, which model_shift reports.
    src, tgt = _street_pair(0)
    target = scanreg.prepare(tgt.points, covariances=True)
    res = scanreg.register(src, target, method="gicp", max_correspondence_distance=1.0)
    assert res.covariances is not None
    d = (res.pose.inverse() @ STEP3.inverse()).log()
    shift = np.asarray(res.covariances.model_shift)
    assert d[0] < -0.003 and 0.2 * d[0] > shift[0] > d[0], (d, shift)
    cal = np.asarray(res.covariances.calibrated)
    sigma_without = np.sqrt(np.diag(cal - np.outer(shift, shift)))
    assert abs(d[0]) > 2.0 * sigma_without[0], (d, sigma_without)  # the bias, uncovered
    assert abs(d[0]) < 2.0 * np.sqrt(cal[0, 0]), (d, cal[0, 0])  # covered with the shift


def test_point_to_point_model_shift_reaches_its_sampling_bias() -> None:
    # Point-to-point's minimum sits ~12 cm along the road in the street (a sampling bias): its
    # distance to the point-to-plane minimum of the agreeing pairs says so.
    src, tgt = _street_pair(0)
    res = scanreg.register(src, tgt, method="point_to_point", max_correspondence_distance=1.0)
    assert res.covariances is not None
    d = (res.pose.inverse() @ STEP3.inverse()).log()
    shift = np.asarray(res.covariances.model_shift)
    assert d[0] < -0.05 and 0.5 * d[0] > shift[0] > 2.0 * d[0], (d, shift)


def test_noise_free_degenerate_fit_gives_finite_spd_information() -> None:
    # A noise-free line: zero residuals, the aware solve holds x. The covariance is ~0 across
    # the line (round-off of ±1e-54 used to give a negative variance, a NaN standard deviation
    # and an information matrix with a −4e92 diagonal); along it, the prior's.
    x = np.linspace(0, 10, 200)
    line = np.c_[x, np.zeros_like(x)]
    res = scanreg.register(
        line,
        line + np.array([0.01, 0.02]),
        method="point_to_line",
        degeneracy_aware=True,
        init_covariance=np.diag([0.01, 0.01, 0.001]),
    )
    assert res.covariances is not None
    for kind in ("hessian", "censi", "block", "calibrated"):
        c = getattr(res.covariances, kind)
        assert np.all(np.diag(c) >= 0.0), kind
        assert np.linalg.eigvalsh(c)[0] >= -1e-12 * np.abs(c).max(), kind
    assert np.all(np.isfinite(res.standard_deviations))
    assert res.standard_deviations[0] == pytest.approx(0.1)
    info = res.information
    assert np.all(np.isfinite(info)) and np.linalg.eigvalsh(info)[0] > 0


def test_trust_helpers_refuse_hostile_input_naming_the_argument() -> None:
    from scanreg.quality import information_from_covariance

    for bad in (np.zeros((0, 0)), np.ones((2, 3)), np.ones(3)):
        with pytest.raises(ValueError, match="cov: expected a square"):
            information_from_covariance(bad)
    with pytest.raises(TypeError, match="cov: expected a matrix of numbers"):
        information_from_covariance([["x", 0.0], [0.0, 1.0]])
    with pytest.raises(ValueError, match="cov: contains NaN"):
        information_from_covariance(np.array([[np.nan, 0.0], [0.0, 1.0]]))
    # An infinite variance is an undetermined direction: no information along it.
    np.testing.assert_array_equal(
        information_from_covariance(np.diag([np.inf, 4.0])), [[0.0, 0.0], [0.0, 0.25]]
    )
    np.testing.assert_allclose(
        information_from_covariance(np.diag([4.0, 0.25])), [[0.25, 0], [0, 4]]
    )
    src, tgt = _pair(CORRIDOR, CORRIDOR_POSE, 4)
    deg = scanreg.register(src, tgt, max_correspondence_distance=1.0).degeneracy
    assert deg is not None and deg.degenerate
    for bad in (-1e-4, float("inf")):
        with pytest.raises(ValueError, match="normal_noise: must be finite and >= 0"):
            deg.tilt_variances(bad)
    with pytest.raises(TypeError, match="normal_noise: expected a number"):
        deg.tilt_variances("0.01")  # type: ignore[arg-type]
    np.testing.assert_array_equal(deg.tilt_variances(float("nan")), np.zeros((1, 2)))
    tilt = deg.tilt_variances(1e-3)
    assert tilt.shape == (1, 2) and np.all(tilt > 0)
    np.testing.assert_allclose(deg.tilt_variances(2e-3), 2 * tilt)  # linear in the noise


# --- where a degenerate scene's NEES goes: the weak axis vs the rest (issue 23) ---------


def _nees_split(error: np.ndarray, res: scanreg.RegistrationResult) -> tuple[float, float]:
    """``(weak, rest)``: the NEES of ``error`` under ``res.covariance`` split into the marginal
    part along the result's one weak direction and the rest given it (per dof), in the scaled
    coordinates of its degeneracy analysis (``covariance_calibration.py``'s split, written
    out here for one weak direction: ``(wᵀe)² / wᵀCw``)."""
    deg = res.degeneracy
    assert deg is not None and len(deg.weak_directions) == 1
    s_inv = deg.scaling()
    (w,) = deg.weak_basis().T
    e = error / s_inv
    cov = np.asarray(res.covariance) / np.outer(s_inv, s_inv)
    total = float(e @ np.linalg.solve(cov, e))
    weak = float((w @ e) ** 2 / (w @ cov @ w))
    return weak, (total - weak) / (len(e) - 1)


def _gate_law_start(truth: SE2 | SE3, res_prior: np.ndarray, k: int) -> SE2 | SE3:
    """A start drawn from the gate-wide law the default call states along weak directions
    (uniform within ±√3 σ of ``res_prior``'s diagonal), seeded by ``k``."""
    half = np.sqrt(3.0 * np.diag(res_prior))
    return truth @ type(truth).exp(np.random.default_rng(30_000 + k).uniform(-half, half))  # type: ignore[operator, attr-defined]


def test_corridor_from_the_identity_is_cautious_by_its_fixed_step_not_by_its_model() -> None:
    # covariance_calibration.py's identity rows of the corridor sit under 0.5 × dof. Split by
    # axis: along the corridor the error is the calibration's fixed 0.3 m step against the
    # gate's σ = 0.58 m (a share of 0.3²/(1/3) = 0.27 by construction), and the rest, whose
    # cover for the weak axis's leak scales with σ², is cautious too. Started from the law
    # the default states (uniform within the gate), the same model is calibrated. Measured
    # (30 realisations, point-to-line, weak / rest): identity 0.25 / 0.83 (the rest
    # heavy-tailed), gate-law start 0.80 / 1.00; covariance_calibration.py at 100: identity
    # 0.28 / 0.67, gate 1.02 / 0.94.
    truth = STEP2.inverse()
    ident, gate = [], []
    for k in range(30):
        src, tgt = _pair(CORRIDOR, CORRIDOR_POSE @ SE2.from_vector(_jitter(k)), 400 + k)
        target = scanreg.prepare(tgt)
        res = scanreg.register(src, target, max_correspondence_distance=1.0)
        ident.append(_nees_split((res.pose.inverse() @ truth).log(), res))
        assert res.covariances is not None
        start = _gate_law_start(truth, np.asarray(res.covariances.prior), k)
        res = scanreg.register(src, target, init=start, max_correspondence_distance=1.0)
        gate.append(_nees_split((res.pose.inverse() @ truth).log(), res))
    (iw, ir), (gw, gr) = np.mean(ident, axis=0), np.mean(gate, axis=0)
    assert 0.18 <= iw <= 0.3, iw  # ≤ 0.3²/(1/3) = 0.27 plus sampling error
    assert 0.3 <= ir <= 1.3, ir  # heavy-tailed: 0.07–4.0 per realisation
    assert 0.5 <= gw <= 1.6 and 0.5 <= gr <= 1.6, (gw, gr)
    assert 0.5 <= (gw + 2 * gr) / 3 <= 2.0


def test_tunnel_locks_to_zero_motion_along_its_axis_whatever_the_start() -> None:
    # In the simulated tunnel the estimate along the axis is where the two sweeps' ring
    # patterns coincide — zero motion — whatever the start: from a start drawn within the
    # gate the error along the axis is the calibration's 0.5 m step in every realisation, so
    # the identity rows' weak share is 0.5²/(1/3) = 0.75 by construction. Across the axis
    # GICP was over-cautious while its 3D point variance came from the Euclidean residuals
    # (rest 0.22 here, 0.30 at 100 realisations); along the normal, as its cost sees the
    # residual, it reads as point-to-plane: rest 0.54 (point-to-plane) and 0.50 (GICP) over
    # these 6 realisations, weak 0.75 for both.
    tunnel, pose_a = sim.tunnel(), SE3.from_vector([0, 0, 1.8, 0, 0, 0])
    truth = STEP3.inverse()
    rest: dict[str, list[float]] = {"point_to_plane": [], "gicp": []}
    for k in range(6):
        pose = _moved(pose_a, k)
        src = _sweep(tunnel, pose, 2 * k)
        tgt = scanreg.prepare(_sweep(tunnel, pose @ STEP3, 2 * k + 1), covariances=True)
        for method in rest:
            res = scanreg.register(src, tgt, method=method, max_correspondence_distance=1.0)  # type: ignore[arg-type]
            weak, r = _nees_split((res.pose.inverse() @ truth).log(), res)
            assert weak == pytest.approx(0.75, abs=0.06), (method, k, weak)
            rest[method].append(r)
        assert res.covariances is not None
        start = _gate_law_start(truth, np.asarray(res.covariances.prior), k)
        res = scanreg.register(
            src, tgt, method="point_to_plane", init=start, max_correspondence_distance=1.0
        )
        deg = res.degeneracy
        assert deg is not None and deg.degenerate
        (w,) = deg.weak_basis().T
        along = float(w @ ((res.pose.inverse() @ truth).log() / deg.scaling()))
        assert abs(abs(along) - 0.5) < 0.03, (k, along)
    assert np.mean(rest["point_to_plane"]) > 0.4
    assert np.mean(rest["gicp"]) > 0.4


def test_valley_term_is_the_coupling_not_the_jitter_of_the_held_re_solves() -> None:
    # The held re-solves at ±h: their common (symmetric) offset is sampling jitter — a
    # degenerate valley is a symmetry, a straight line in the tangent — and gives nothing;
    # opposite offsets are a coupling b = e/h.
    from scanreg.trust import valley_coupling

    e = np.array([0.0, 0.004, -0.001])
    assert np.allclose(valley_coupling(e, e, 0.1), 0.0)
    np.testing.assert_allclose(valley_coupling(e, -e, 0.1), e / 0.1)
    np.testing.assert_allclose(valley_coupling(None, e, 0.1), e / 0.1)
    assert valley_coupling(None, None, 0.1) is None


def test_corridor_with_a_prior_is_calibrated_across_its_axis() -> None:
    # With a motion prior and the degeneracy-aware solve, along the axis the error is the
    # prior's (weak part ~1). Across it the valley term had counted the held re-solves' own
    # sampling jitter (2–45 mdeg of heading between re-solves 0.05 m apart) on top of the
    # sampling term that covers it: rest 0.57 × dof (point-to-line, 100 realisations of
    # covariance_calibration.py), 0.98 with the coupling alone. Measured here (30): weak
    # 0.90, rest 0.72 (0.49 with the second moment of both re-solves).
    truth = STEP2.inverse()
    parts = []
    for k in range(30):
        src, tgt = _pair(CORRIDOR, CORRIDOR_POSE @ SE2.from_vector(_jitter(k)), 500 + k)
        rng = np.random.default_rng(10_000 + k)
        res = scanreg.register(
            src,
            tgt,
            init=truth @ SE2.exp(rng.multivariate_normal(np.zeros(3), PRIOR2)),
            init_covariance=PRIOR2,
            degeneracy_aware=True,
            max_correspondence_distance=1.0,
        )
        parts.append(_nees_split((res.pose.inverse() @ truth).log(), res))
    weak, rest = np.mean(parts, axis=0)
    assert 0.6 <= weak <= 1.5, weak
    assert 0.62 <= rest <= 1.5, rest


def test_corridor_heading_sigma_follows_its_error() -> None:
    # The 2D sampling term is measured from the scan: along the corridor's clean walls a
    # sample sliding one beam step changes no residual, so the heading keeps the noise's σ.
    # The fixed beam-phase term it replaced (Δα²/12) claimed 12× the error here (RMS of
    # error/σ 0.08, benchmarks/corridor_coupling.py); measured here: 0.97 / 1.02 / 0.37.
    truth = STEP2.inverse()
    ratios = []
    for k in range(15):
        src, tgt = _pair(CORRIDOR, CORRIDOR_POSE @ SE2.from_vector(_jitter(k)), 300 + k)
        rng = np.random.default_rng(10_000 + k)
        res = scanreg.register(
            src,
            tgt,
            max_correspondence_distance=1.0,
            init=truth @ SE2.exp(rng.multivariate_normal(np.zeros(3), PRIOR2)),
            init_covariance=PRIOR2,
            degeneracy_aware=True,
        )
        d = (res.pose.inverse() @ truth).log()
        ratios.append(d / np.sqrt(np.diag(res.covariance)))
    rms = np.sqrt(np.mean(np.square(ratios), axis=0))
    assert 0.6 <= rms[0] <= 1.6 and 0.6 <= rms[1] <= 1.6, rms
    assert 0.25 <= rms[2] <= 1.6, rms


def _split_beam_mbicp(count: int) -> list[tuple[np.ndarray, np.ndarray, SE2]]:
    """Real MbICP scans split into even (target) and odd beams (source, re-noised by 1 cm and
    moved by a known transform): ``covariance_calibration.py --split-beam``'s protocol."""
    from scanreg.io import read_carmen

    log = read_carmen(data_dir("carmen-mbicp-laserazos", "laserazosSM3.log"))
    rng = np.random.default_rng(0)
    out = []
    for i in np.linspace(0, len(log) - 1, count).round().astype(int):
        scan = log.scans[int(i)]
        valid = scan.valid(min_range=0.1, max_range=40.0)
        r, a = scan.ranges, scan.angles
        even, odd = (valid & (np.arange(len(r)) % 2 == k) for k in (0, 1))
        tgt = np.c_[r[even] * np.cos(a[even]), r[even] * np.sin(a[even])]
        ro = r[odd] + rng.normal(0.0, 0.01, int(odd.sum()))
        pts = np.c_[ro * np.cos(a[odd]), ro * np.sin(a[odd])]
        lim = np.array([0.2, 0.2, np.deg2rad(3.0)])
        truth = SE2.from_vector(rng.uniform(-lim, lim))
        src = np.ascontiguousarray(truth.inverse().apply(pts))
        out.append((src, np.ascontiguousarray(tgt), truth))
    return out


def test_real_split_beam_pairs_are_covered_in_translation_too() -> None:
    # Real scans carry what the simulator's clean walls do not: edges and clutter whose
    # samples the two halves place a beam step apart. The MbICP halves' error is in
    # translation as much as in heading: with a heading-only term their mean NEES was
    # 2.06 × dof (point-to-line, 40 pairs, 5 % outside χ²(3) at 99.9 %); the sampling term
    # covers both: measured here 1.11 × dof, largest NEES 10.4.
    nees = []
    for src, tgt, truth in _split_beam_mbicp(16):
        res = scanreg.register(src, tgt, method="point_to_line")
        d = (res.pose.inverse() @ truth).log()
        nees.append(float(d @ res.information @ d))
    mean = float(np.mean(nees))
    assert 0.5 * 3 <= mean <= 1.6 * 3, (mean, nees)
    assert max(nees) < 16.27, nees  # none outside χ²(3) at 99.9 %


def test_held_steps_are_the_weak_directions_about_the_centroid() -> None:
    # The hold's weak directions (scanreg.degeneracy.held_steps_2d): the closed-form smallest
    # eigenvalue against numpy's, and the projector the same motion in any frame.
    from scanreg.degeneracy import (
        _smallest_eigenvalue_3,
        held_steps_2d,
        weakest_about_centroid_2d,
    )

    rng = np.random.default_rng(3)
    for t in range(300):
        a = rng.normal(size=(3, 3)) * rng.uniform(0.01, 100.0)
        g = a @ a.T
        if t % 3 == 0:  # nearly degenerate along x
            g[0, :] *= 1e-3
            g[:, 0] *= 1e-3
        want = np.linalg.eigvalsh(g)
        assert _smallest_eigenvalue_3(g) == pytest.approx(want[0], abs=1e-9 * want[-1])
    # A corridor along x: normals ±y, the source 3-8 m ahead of its origin.
    src = np.column_stack([rng.uniform(3.0, 8.0, 200), rng.choice([-1.0, 1.0], 200)])
    normals = np.column_stack([np.zeros(200), src[:, 1]])
    jac = np.column_stack([normals, normals[:, 0] * -src[:, 1] + normals[:, 1] * src[:, 0]])
    h = jac.T @ jac
    held = held_steps_2d(h, src, 200)
    assert held is not None
    steps = held.projector
    np.testing.assert_allclose(steps @ np.array([1.0, 0.0, 0.0]), 0.0, atol=1e-12)  # x held
    np.testing.assert_allclose(steps @ np.array([0.0, 1.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-12)
    # The same scene 1 km away (points and origin moved): the same motion held.
    shift = np.array([1000.0, -700.0])
    ad = np.array([[1.0, 0.0, shift[1]], [0.0, 1.0, -shift[0]], [0.0, 0.0, 1.0]])
    far = held_steps_2d(np.linalg.inv(ad).T @ h @ np.linalg.inv(ad), src + shift, 200)
    assert far is not None
    np.testing.assert_allclose(far.projector, ad @ steps @ np.linalg.inv(ad), atol=1e-6)
    np.testing.assert_allclose(far.centred, held.centred, atol=1e-9)
    # The screen's plain-float eigenvalue: held_steps_2d's, below its floor and above.
    c = src.mean(axis=0)
    spread = float(np.sqrt(np.mean(np.sum((src - c) ** 2, axis=1))))
    nearly = h + np.diag([0.4, 0.0, 0.0])  # a few pairs facing x
    weakest = weakest_about_centroid_2d(nearly, (float(c[0]), float(c[1])), spread, 200)
    assert 0.0 < weakest < 0.03
    assert held_steps_2d(nearly, src, 200, floor=weakest * 1.001) is not None
    assert held_steps_2d(nearly, src, 200, floor=weakest * 0.999) is None
    assert held_steps_2d(h + np.diag([50.0, 0.0, 0.0]), src, 200) is None  # x faced: none
    assert held_steps_2d(h, src, 0) is None


def test_held_steps_refuse_bad_input_by_name() -> None:
    from scanreg.degeneracy import held_steps_2d, weakest_about_centroid_2d

    src = np.ones((5, 2))
    with pytest.raises(ValueError, match="hessian: contains NaN"):
        held_steps_2d(np.full((3, 3), np.nan), src, 10)
    with pytest.raises(ValueError, match=r"hessian: expected shape \(3, 3\)"):
        held_steps_2d(np.eye(2), src, 10)
    with pytest.raises(ValueError, match="source"):
        held_steps_2d(np.eye(3), np.ones((5, 3)), 10)
    with pytest.raises(ValueError, match="count"):
        held_steps_2d(np.eye(3), src, -1)
    with pytest.raises(ValueError, match="hessian: contains NaN"):
        weakest_about_centroid_2d(np.full((3, 3), np.nan), (0.0, 0.0), 1.0, 10)
    with pytest.raises(ValueError, match="centroid"):
        weakest_about_centroid_2d(np.eye(3), (0.0, np.inf), 1.0, 10)
    with pytest.raises(ValueError, match="spread"):
        weakest_about_centroid_2d(np.eye(3), (0.0, 0.0), np.nan, 10)
    with pytest.raises(ValueError, match="count"):
        weakest_about_centroid_2d(np.eye(3), (0.0, 0.0), 1.0, 0)
