"""The trust arithmetic in the core (``scanreg_core::trust``) equals the Python it replaced
(``tests/_reference_trust.py``) on the calibration scenes: the 2D room and corridor, the 3D
street and tunnel, every method (and a robust kernel, whose covariance is the sandwich).

Both sides read the same core outcome and the same per-correspondence sums; what is compared
is everything computed from them: the degeneracy, every covariance kind, the model shift, the
conditioning, the information and the motion χ². Matrices agree to 1e-12 of their largest
entry; eigenvectors up to sign (the core fixes each sign, LAPACK does not).
"""

from __future__ import annotations

import dataclasses
import importlib
import math
from typing import Any

import _reference_trust as ref
import numpy as np
import pytest
import scanreg
from scanreg import SE2, SE3
from scanreg import simulate as sim
from scanreg.quality import conditioning, information_from_covariance
from scanreg.trust import TrustInputs
from scanreg.verdict import VerdictThresholds

RTOL = 1e-12
NO_PROBE = VerdictThresholds(basin_probe=False)
LASER = sim.LaserModel.preset("laser_360")
STEP2 = SE2.from_vector([0.3, 0.1, np.deg2rad(2.0)])
STEP3 = SE3.from_vector([0.5, 0.1, 0.0, 0.0, 0.0, np.deg2rad(2.0)])


def _scans2d(scene: sim.Scene, pose: SE2, seed: int) -> tuple[np.ndarray, np.ndarray]:
    a, b = (
        np.ascontiguousarray(sim.simulate_scan(scene, LASER, p, seed=seed + k).points)
        for k, p in enumerate((pose, pose @ STEP2))
    )
    return b, a  # source: the moved scan


def _sweep(scene: sim.Scene, pose: SE3, seed: int) -> np.ndarray:
    pts = sim.simulate_sweep(scene, sim.LidarModel.preset("vlp16"), pose, seed=seed).points
    return scanreg.preprocess.voxel_downsample(np.ascontiguousarray(pts), 0.4).points


def _scans3d(scene: sim.Scene, pose: SE3, seed: int) -> tuple[np.ndarray, np.ndarray]:
    return _sweep(scene, pose @ STEP3, seed + 1), _sweep(scene, pose, seed)


SCENES: dict[str, Any] = {
    "room": lambda: _scans2d(sim.square_room(5.0), SE2.from_vector([0.5, 0.3, 0.3]), 0),
    "corridor": lambda: _scans2d(
        sim.corridor(length=200.0, width=3.0), SE2.from_vector([100.0, 0, 0]), 2
    ),
    "street": lambda: _scans3d(sim.street(seed=4), SE3.from_vector([0, 1.75, 1.73, 0, 0, 0]), 0),
    "tunnel": lambda: _scans3d(sim.tunnel(), SE3.from_vector([0, 0, 1.8, 0, 0, 0]), 2),
}
_CACHE: dict[str, tuple[np.ndarray, np.ndarray]] = {}


def _scene(name: str) -> tuple[np.ndarray, np.ndarray]:
    if name not in _CACHE:
        _CACHE[name] = SCENES[name]()
    return _CACHE[name]


def _close(got: Any, want: Any, what: str) -> None:
    got, want = np.asarray(got, dtype=np.float64), np.asarray(want, dtype=np.float64)
    assert got.shape == want.shape, what
    finite = np.isfinite(want)
    np.testing.assert_array_equal(np.isfinite(got), finite, err_msg=what)
    np.testing.assert_array_equal(got[~finite], want[~finite], err_msg=what)
    if finite.any():
        scale = max(float(np.abs(want[finite]).max()), 1e-300)
        err = float(np.abs(got[finite] - want[finite]).max()) / scale
        assert err <= RTOL, f"{what}: relative error {err:.2e}"


def _same_direction(got: Any, want: Any, what: str) -> None:
    g, w = np.asarray(got), np.asarray(want)
    _close(g * np.sign(g @ w), w, what)


CASES = [
    ("room", "point_to_line", "none"),
    ("room", "point_to_point", "none"),
    ("room", "gicp", "none"),
    ("room", "point_to_line", "huber"),
    ("corridor", "point_to_line", "none"),
    ("corridor", "point_to_point", "none"),
    ("corridor", "gicp", "none"),
    ("street", "point_to_plane", "none"),
    ("street", "point_to_point", "none"),
    ("street", "gicp", "huber"),
    ("tunnel", "point_to_plane", "none"),
    ("tunnel", "point_to_point", "none"),
    ("tunnel", "gicp", "none"),
]


@pytest.mark.parametrize(("scene", "method", "kernel"), CASES, ids=str)
def test_core_trust_equals_the_python_reference(scene: str, method: str, kernel: str) -> None:
    src, tgt = _scene(scene)
    target = scanreg.prepare(tgt, normals=True, covariances=method == "gicp")
    res = scanreg.register(
        src,
        target,
        method=method,  # type: ignore[arg-type]
        max_correspondence_distance=1.0,
        kernel=kernel,  # type: ignore[arg-type]
        thresholds=NO_PROBE,
        # A degenerate 2D result held at its start runs its analysis within the call: the
        # lazy inputs compared here are the refined result's.
        hold_degenerate=False,
    )
    # The lazy analysis's inputs, before it runs: the same outcome for both sides.
    args = res._trust._args
    assert args is not None
    ctx_fields, out, pose, _ = args
    ctx = ctx_fields if isinstance(ctx_fields, TrustInputs) else TrustInputs(**ctx_fields)
    dim = pose.DIM
    dof = 3 if dim == 2 else 6
    sigma2 = ref.residual_variance(out, ctx.components, ctx.settings.kernel, dof)
    want_corr = ref.correspondence_analysis(ctx, out)
    # The 2D sampling term is part of what is compared (not skipped for want of normals).
    assert (want_corr.sampling is not None) == (dim == 2)
    want = ref._covariance_estimates(ctx, out, pose, out.hessian, sigma2, want_corr)

    got = res.covariances
    deg = res.degeneracy
    assert got is not None and deg is not None
    want_deg = want_corr.degeneracy
    # Degeneracy: the same weak directions, named alike.
    assert deg.basis == want_deg.basis
    assert deg.threshold == want_deg.threshold
    assert [d.description for d in deg.weak_directions] == [
        d.description for d in want_deg.weak_directions
    ]
    _close(deg.information, want_deg.information, "degeneracy.information")
    _close(deg.eigenvalues, want_deg.eigenvalues, "degeneracy.eigenvalues")
    _close(deg.levers, want_deg.levers, "degeneracy.levers")
    for k, (a, b) in enumerate(zip(deg.directions, want_deg.directions, strict=True)):
        assert a.ratio == pytest.approx(b.ratio, rel=RTOL, abs=RTOL), k
        # An eigenvector is determined (up to sign) only where its eigenvalue is simple.
        vals = want_deg.eigenvalues
        above = k + 1 == dof or abs(vals[k + 1] - vals[k]) > 1e-6
        below = k == 0 or abs(vals[k] - vals[k - 1]) > 1e-6
        if above and below:
            _same_direction(a.vector, b.vector, f"direction {k}")
    _close(deg.weak_projector(), want_deg.weak_projector(), "weak projector")
    # Every covariance kind and the model shift.
    for kind in ("hessian", "censi", "block", "calibrated", "model_shift", "prior"):
        _close(getattr(got, kind), getattr(want, kind), kind)
    for name in ("point_variance", "normal_variance", "block_size", "num_blocks"):
        assert getattr(got, name) == pytest.approx(getattr(want, name), rel=RTOL), name
    # The chosen covariance, its information, the conditioning and the motion χ².
    _close(res.covariance, want.calibrated, "covariance")
    chosen = np.asarray(want.calibrated)
    want_info = (
        information_from_covariance(chosen) if np.isfinite(chosen).all() else np.zeros((dof, dof))
    )
    _close(res.information, want_info, "information")
    want_cond = conditioning(np.asarray(out.hessian), dim, ref.length_scale(ctx.source))
    cond = res.conditioning
    _close(cond.eigenvalues, want_cond.eigenvalues, "conditioning.eigenvalues")
    _close(cond.scaled_eigenvalues, want_cond.scaled_eigenvalues, "scaled eigenvalues")
    assert cond.length_scale == pytest.approx(want_cond.length_scale, rel=RTOL)
    for name in ("condition_number", "scaled_condition_number"):
        a, b = getattr(cond, name), getattr(want_cond, name)
        assert a == b or a == pytest.approx(b, rel=1e-9), name
    _same_direction(cond.weakest.vector, want_cond.weakest.vector, "weakest")
    assert cond.weakest.description == want_cond.weakest.description
    quality = res.quality
    assert quality is not None
    block = np.asarray(ref.prior(ctx))[:dim, :dim]
    t = np.asarray((ctx.start.inverse() @ pose).translation)
    assert quality.motion_nees == pytest.approx(float(t @ np.linalg.solve(block, t)), rel=RTOL)
    assert math.isclose(ctx.beam_phase_variance, ref.beam_phase_variance(ctx), rel_tol=RTOL)


def test_the_scenes_cover_weak_and_well_constrained_results() -> None:
    # The comparison above means something only if both branches of the arithmetic run: the
    # prior along weak directions (corridor, tunnel) and the well-constrained one (room, street).
    flags = {}
    for name, method in (("corridor", "point_to_line"), ("room", "point_to_line")):
        src, tgt = _scene(name)
        res = scanreg.register(src, tgt, method=method, max_correspondence_distance=1.0)
        assert res.degeneracy is not None
        flags[name] = res.degeneracy.degenerate
    assert flags == {"corridor": True, "room": False}


def test_trust_numbers_refuses_malformed_input_naming_the_argument() -> None:
    from scanreg import _core

    src, tgt = _scene("room")
    target = scanreg.prepare(tgt)
    res = scanreg.register(src, target, thresholds=NO_PROBE)
    _, out, _, _ = res._trust._args  # type: ignore[misc]
    ana = _core.censi_analysis(
        src, tgt, out.pose, np.asarray(out.correspondences), method="point_to_line",
        kernel="none", kernel_scale=1.0, source_variance=1.0, target_variance=1.0,
        block_size=2.0, target_normals=target.normals,
    )  # fmt: skip
    good: dict[str, Any] = {
        "method": "point_to_line",
        "levers": np.ones(1),
        "prior": np.eye(3),
        "drift": np.zeros(3),
        "motion": np.zeros(2),
        "length_scale": 1.0,
        "covariance": "calibrated",
        "num_correspondences": 100,
        "sum_squared_distances": 1.0,
    }
    assert _core.trust_numbers(ana, np.eye(3), 1e-4, **good).calibrated.shape == (3, 3)
    for key, bad, msg in (
        ("prior", np.eye(2), "prior: expected a"),
        ("levers", np.ones(3), "levers: expected 1 values"),
        ("covariance", "best", "covariance: unknown"),
        ("method", "nearest", "method: unknown"),
        ("drift", np.zeros(6), "drift: expected 3 values"),
    ):
        with pytest.raises(ValueError, match=msg):
            _core.trust_numbers(ana, np.eye(3), 1e-4, **{**good, key: bad})
    with pytest.raises(ValueError, match="hessian: expected a"):
        _core.trust_numbers(ana, np.eye(6), 1e-4, **good)
    with pytest.raises(ValueError, match="source: is empty"):
        _core.trust_scene(np.zeros((0, 2)), 1.0)
    with pytest.raises(ValueError, match=r"source_normals: expected \d+ values"):
        _core.censi_analysis(
            src, tgt, out.pose, np.asarray(out.correspondences), method="point_to_line",
            kernel="none", kernel_scale=1.0, source_variance=1.0, target_variance=1.0,
            block_size=2.0, target_normals=target.normals, source_normals=np.zeros((3, 2)),
        )  # fmt: skip
    system = np.eye(3), np.eye(3)
    _core.trust_numbers(ana, np.eye(3), 1e-4, **good, sampling_system=system)
    with pytest.raises(ValueError, match="sampling_system: expected a"):
        _core.trust_numbers(ana, np.eye(3), 1e-4, **good, sampling_system=(np.eye(2), np.eye(3)))
    # The sampling system: one correspondence per source point, a (D, D) rotation; an index
    # beyond the target or a missing normal leaves that point out instead of reading past it.
    corr = np.asarray(out.correspondences, dtype=np.int64)
    args = (src, corr, np.eye(2), 0.5)
    assert _core.trust_sampling(*args, target_normals=target.normals) is not None
    assert _core.trust_sampling(*args) is None  # neither normals nor covariances
    with pytest.raises(ValueError, match="correspondences: expected"):
        _core.trust_sampling(src, corr[:-1], np.eye(2), 0.5, target_normals=target.normals)
    with pytest.raises(ValueError, match="rotation: expected a"):
        _core.trust_sampling(src, corr, np.eye(3), 0.5, target_normals=target.normals)
    # A GICP target's least-spread axis is the same normal (closed form in the core).
    both = scanreg.prepare(tgt, normals=True, covariances=True)
    h, m = _core.trust_sampling(*args, target_normals=both.normals)  # type: ignore[misc]
    hc, mc = _core.trust_sampling(*args, target_covariances=both.covariances)  # type: ignore[misc]
    _close(hc, h, "H from covariances")
    _close(mc, m, "M from covariances")
    far = np.full_like(corr, 10**9)
    assert _core.trust_sampling(src, far, np.eye(2), 0.5, target_normals=target.normals) is None


def test_trust_analysis_in_one_call_equals_the_separate_calls_and_names_bad_input() -> None:
    """``_core.trust_analysis`` (what a registration's analysis runs) against the same
    arithmetic composed from the separate core calls: equal to the bit; malformed input is
    refused naming the argument."""
    from scanreg import _core
    from scanreg.degeneracy import correspondence_normal_noise, sampled_normals

    src, tgt = _scene("room")
    target = scanreg.prepare(tgt)
    res = scanreg.register(src, target, thresholds=NO_PROBE)
    _, out, _, _ = res._trust._args  # type: ignore[misc]
    corr = np.asarray(out.correspondences, dtype=np.int64)
    sample, normals = sampled_normals(src, 10)
    eps2, eps2t = target.normal_noise
    levers, length, phase, prior = _core.trust_scene(src, 1.0)
    rot = np.ascontiguousarray(out.pose[:2, :2])
    nvar = correspondence_normal_noise(normals, target.normals, rot, corr[sample])
    ha, ga, na, hk, gk, nk = _core.normal_agreement_systems(
        sample, normals, src, tgt, target.normals, corr, out.pose, 0.995
    )
    system = _core.trust_sampling(src, corr, rot, 0.5, target_normals=target.normals)
    ana = _core.censi_analysis(
        src, tgt, out.pose, corr, method="point_to_line", kernel="none", kernel_scale=1.0,
        source_variance=1.0, target_variance=1.0, block_size=2.0, normal_variance=1.0,
        target_normals=target.normals,
    )  # fmt: skip
    common: dict[str, Any] = {"levers": levers, "prior": prior, "drift": np.zeros(3),
                              "motion": np.zeros(2), "length_scale": length}  # fmt: skip

    def call(**change: Any) -> Any:
        args: dict[str, Any] = {
            "source": src, "target": tgt, "pose_matrix": out.pose, "correspondences": corr,
            "method": "point_to_line", "kernel": "none", "kernel_scale": 1.0,
            "block_size": 2.0, "num_neighbors": 10, "target_normals": target.normals,
            "target_covariances": None, "source_covariances": None, "num_threads": None,
            "hessian": out.hessian, "sigma2": 1e-4, **common, "covariance": "calibrated",
            "num_correspondences": int(out.num_correspondences),
            "sum_squared_distances": float(out.sum_squared_distances), "score_outer": None,
            "effective_residuals": 0.0, "normal_noise": eps2, "typical_normal_noise": eps2t,
            "beam_phase_variance": phase, "max_step": 0.5, "min_agreement": 0.995,
            "sampling_scale": 1.0,
        }  # fmt: skip
        return _core.trust_analysis(**{**args, **change})

    got = call()
    # The noise the association hides (its arithmetic: test_core_trust_equals_the_python_
    # reference), added to the residuals' point variance.
    assert 0.0 < got.hidden_noise_variance < got.point_variance
    want = _core.trust_numbers(
        ana, out.hessian, 1e-4, method="point_to_line", covariance="calibrated",
        num_correspondences=int(out.num_correspondences),
        sum_squared_distances=float(out.sum_squared_distances), normal_noise=eps2,
        typical_normal_noise=eps2t, normal_variance=nvar, agreement=(ha, ga, na, hk, gk, nk),
        sampling_system=system, hidden_noise_variance=got.hidden_noise_variance, **common,
    )  # fmt: skip
    for name in ("calibrated", "censi", "block", "hessian", "model_shift", "information",
                 "degeneracy_information", "degeneracy_eigenvalues"):  # fmt: skip
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    assert got.normal_variance == nvar and got.num_blocks == ana.num_blocks
    assert got.point_variance == want.point_variance
    # The sampled normals it measured come back; given again, the same numbers.
    assert got.source_normals is not None
    np.testing.assert_array_equal(got.source_normals[1], normals)
    again = call(source_normals=got.source_normals)
    np.testing.assert_array_equal(again.calibrated, got.calibrated)
    # The sampling system's M scaled (the target's sampling density against the source's).
    assert system is not None
    scaled = _core.trust_numbers(
        ana, out.hessian, 1e-4, method="point_to_line", covariance="calibrated",
        num_correspondences=int(out.num_correspondences),
        sum_squared_distances=float(out.sum_squared_distances), normal_noise=eps2,
        typical_normal_noise=eps2t, normal_variance=nvar, agreement=(ha, ga, na, hk, gk, nk),
        sampling_system=(system[0], system[1] * 0.25),
        hidden_noise_variance=call(sampling_scale=0.25).hidden_noise_variance, **common,
    )  # fmt: skip
    np.testing.assert_array_equal(call(sampling_scale=0.25).calibrated, scaled.calibrated)
    # Given the target's spacing, the core measures the source's off the search of its sampled
    # normals (or, with them given, one 2-NN pass) and scales by min(1, ratio)²: the same
    # numbers as the scale computed outside, the spacing the brute-force median's.
    spacing = ref._median_spacing(src)
    assert target.spacing == pytest.approx(ref._median_spacing(tgt), rel=1e-15)
    ratio = min(1.0, target.spacing / spacing)
    for given in (None, got.source_normals):
        own = call(target_spacing=target.spacing, source_normals=given)
        assert own.source_spacing == pytest.approx(spacing, rel=1e-15)
        np.testing.assert_array_equal(own.calibrated, call(sampling_scale=ratio * ratio).calibrated)
    # A target twice as fine: the ratio is ½, the sampling term a quarter.
    half = call(target_spacing=0.5 * own.source_spacing, sampling_scale=1.0)
    np.testing.assert_array_equal(half.calibrated, call(sampling_scale=0.25).calibrated)
    assert math.isnan(call().source_spacing)
    # The verdict's overlap pass in the same call: overlap_statistics's tuple at the pose SE2
    # holds (rotation projected), with and without the outcome's certificates, at two gates.
    assert got.overlap is None
    for gate in (0.3, 0.05):
        for outcome in (None, out):
            alone = _core.overlap_statistics(
                target.index, src, res.pose.as_matrix(), gate, hints=corr, outcome=outcome
            )
            both = call(overlap_target=target.index, overlap_gate=gate, outcome=outcome)
            assert both.overlap == alone
            np.testing.assert_array_equal(both.calibrated, got.calibrated)
    assert call(overlap_target=target.index, overlap_gate=0.3).overlap[0] > 0.5 * len(src)
    # The scene pass in the same call: trust_scene's tuple, and the same numbers.
    assert got.scene is None
    folded = call(levers=None, prior=None, length_scale=None, scene_gate=1.0)
    f_levers, f_length, f_phase, f_prior = folded.scene
    np.testing.assert_array_equal(f_levers, levers)
    np.testing.assert_array_equal(f_prior, prior)
    assert f_length == length and math.isnan(f_phase)
    np.testing.assert_array_equal(folded.calibrated, got.calibrated)
    assert folded.motion_nees == got.motion_nees
    with pytest.raises(ValueError, match="scene_gate: required"):
        call(levers=None, prior=None, length_scale=None)
    with pytest.raises(ValueError, match="overlap_gate: required"):
        call(overlap_target=target.index)
    with pytest.raises(ValueError, match="overlap_gate: must be"):
        call(overlap_target=target.index, overlap_gate=-1.0)
    for change, msg in (
        ({"correspondences": corr[:-1]}, "correspondences: expected"),
        ({"source_normals": (np.array([10**6]), np.zeros((1, 2)))}, "source_normals: index"),
        ({"source_normals": (sample, normals[:-1])}, "source_normals: expected"),
        ({"prior": np.eye(2)}, "prior: expected a"),
        ({"method": "nearest"}, "method: unknown"),
        ({"target_normals": np.zeros((3, 2))}, "target_normals"),
    ):
        with pytest.raises(ValueError, match=msg):
            call(**change)


@pytest.mark.parametrize(
    ("scene", "method"),
    [
        ("corridor", "point_to_line"),
        ("corridor", "point_to_point"),
        ("tunnel", "point_to_plane"),
        # GICP held: the point variance and the block scores over the determined pairs
        ("tunnel", "gicp"),
    ],
    ids=str,
)
def test_degeneracy_aware_solve_equals_the_python_reference(
    scene: str, method: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The held analysis: the second solve's covariances with the first solve's weak directions
    # and the valley of the held re-solves (an input here, measured by the same solves).
    register_module = importlib.import_module("scanreg.register")  # the function shadows it
    calls: list[tuple[Any, Any, Any, Any]] = []
    original = register_module.correspondence_analysis

    def recording(ctx: Any, out: Any, *, held: Any = None, valley: Any = None) -> Any:
        calls.append((ctx, out, held, valley))
        return original(ctx, out, held=held, valley=valley)

    monkeypatch.setattr(register_module, "correspondence_analysis", recording)
    src, tgt = _scene(scene)
    dim = src.shape[1]
    dof = 3 if dim == 2 else 6
    res = scanreg.register(
        src,
        scanreg.prepare(tgt, covariances=method == "gicp"),
        method=method,  # type: ignore[arg-type]
        max_correspondence_distance=1.0,
        degeneracy_aware=True,
        init_covariance=np.diag([0.1**2] * dim + [np.deg2rad(1.0) ** 2] * (dof - dim)),
        thresholds=NO_PROBE,
    )
    assert len(calls) == 2, "the scene must be degenerate for the held solve to run"
    (ctx, out1, _, _), (_, out2, held, valley) = calls
    assert held is not None and valley is not None
    first = ref.correspondence_analysis(ctx, out1)
    second = dataclasses.replace(
        ref.correspondence_analysis(ctx, out2),
        degeneracy=first.degeneracy,
        valley=valley,
        held=True,
    )
    pose = scanreg.trust.pose_from_core(out2, src.shape[1])
    sigma2 = ref.residual_variance(out2, ctx.components, ctx.settings.kernel, dof)
    want = ref._covariance_estimates(ctx, out2, pose, out2.hessian, sigma2, second)
    got = res.covariances
    assert got is not None and res.degeneracy is not None
    assert [d.description for d in res.degeneracy.weak_directions] == [
        d.description for d in first.degeneracy.weak_directions
    ]
    for kind in ("hessian", "censi", "block", "calibrated", "model_shift"):
        _close(getattr(got, kind), getattr(want, kind), kind)
    _close(res.information, information_from_covariance(np.asarray(want.calibrated)), "info")
