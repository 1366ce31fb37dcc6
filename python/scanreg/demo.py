"""The built-in demo: the whole job on generated data with exact truth, no download needed.

1. The main job (:mod:`scanreg.demo_mapping`): a 2D room tour mapped with loop closure (error
   before/after against the truth, loops accepted/rejected, the map's self-check), a second
   pass localized in the saved map from no pose, a 3D city-block loop mapped with loop
   closure, and a ``report.html`` of the 2D map. Needs the ``mapping`` extra (gtsam) and,
   for the report, ``report`` (plotly); without them these are skipped, naming the extra.
2. LiDAR odometry (:class:`scanreg.Odometry`) on a simulated street drive with motion
   distortion, and down a featureless tunnel with a noisy wheel-odometry prior that the
   degeneracy-aware update holds the axis to.
3. The paired-alignment lab: 200 points uniform in [-5, 5] × [-3, 3], moved by θ = 12°,
   t = (1.2, -0.7), observed with σ = 0.02 noise: the estimate against its covariance.
4. Scan statistics of a short simulated 2D and 3D run.

Every figure checked is printed with its threshold, PASS or FAIL; exit status 1 when any fails.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import simulate
from ._version import __version__
from .demo_mapping import Check, run_mapping_demo
from .paired import PairedAlignment, align_paired
from .pipeline.odometry import Odometry
from .transform import SE2, SE3

LAB_TRUTH = SE2.from_vector([1.2, -0.7, np.deg2rad(12.0)])
LAB_SIGMA = 0.02
LAB_POINTS = 200


@dataclass(frozen=True)
class LabRun:
    truth: SE2
    closed_form: PairedAlignment
    refined: PairedAlignment
    #: Error δ = log(T_est⁻¹ T_true) of the closed form, in its covariance's tangent.
    error: np.ndarray
    #: |δ_i| / σ_i for each coordinate.
    error_in_sigmas: np.ndarray


def paired_lab(seed: int = 0) -> LabRun:
    """Simulate the lab scene once and align it in closed form and with a Huber kernel."""
    rng = np.random.default_rng(seed)
    source = np.column_stack([rng.uniform(-5, 5, LAB_POINTS), rng.uniform(-3, 3, LAB_POINTS)])
    target = LAB_TRUTH.apply(source) + rng.normal(0.0, LAB_SIGMA, source.shape)
    closed = align_paired(source, target)
    refined = align_paired(source, target, kernel="huber")
    assert isinstance(closed.pose, SE2)  # 2D points give an SE2
    error = (closed.pose.inverse() @ LAB_TRUTH).log()
    return LabRun(
        truth=LAB_TRUTH,
        closed_form=closed,
        refined=refined,
        error=error,
        error_in_sigmas=np.abs(error) / closed.standard_deviations,
    )


def _row(name: str, v: np.ndarray, fmt: str = "{:+.5f}") -> str:
    return f"  {name:<30}" + "  ".join(fmt.format(x) for x in v)


def run_demo(seed: int = 0, output: str | Path = "scanreg-demo") -> int:
    """Every section, files into ``output``; exit status 0 when every check passes."""
    t0 = time.perf_counter()
    print(f"scanreg {__version__} demo (seed {seed}): every figure checked against the exact truth")
    print()
    checks = run_mapping_demo(seed, Path(output))
    checks += run_odometry_demo(seed)
    lab = paired_lab(seed)
    deg = np.array([1.0, 1.0, 180.0 / np.pi])
    print(f"scanreg demo: paired 2D alignment (200 points, σ = 0.02, seed {seed})")
    print(" " * 32 + "tx [m]     ty [m]     θ [deg]")
    print(_row("ground truth", lab.truth.as_vector() * deg))
    print(_row("closed form (Kabsch)", lab.closed_form.pose.as_vector() * deg))
    print(_row("refined (Gauss–Newton+Huber)", lab.refined.pose.as_vector() * deg))
    print(_row("predicted σ (closed form)", lab.closed_form.standard_deviations * deg, "{:.5f}"))
    print(_row("|error| / σ", lab.error_in_sigmas, "{:.2f}"))
    c = lab.closed_form
    print(f"  RMSE {c.residuals.rmse:.4f} m, σ̂ {np.sqrt(c.sigma2):.4f} m (true {LAB_SIGMA})")
    print(
        f"  condition number of JᵀJ {c.conditioning.condition_number:.1f}; "
        f"weakest: {c.conditioning.weakest.description}"
    )
    inside = bool((lab.error_in_sigmas < 3.0).all())
    print("  estimate inside 3σ of the predicted covariance:", "yes" if inside else "NO")
    checks.append(Check("paired lab: largest |error| / σ", float(lab.error_in_sigmas.max()), 3.0))
    print(checks[-1].line())
    _print_simulated(simulated_runs(seed))
    return _summary(checks, time.perf_counter() - t0)


def _summary(checks: list[Check], seconds: float) -> int:
    failed = [c for c in checks if not c.passed]
    print()
    if failed:
        print(f"scanreg demo: FAIL: {len(failed)} of {len(checks)} checks failed ({seconds:.0f} s)")
        for c in failed:
            print(c.line())
        return 1
    print(f"scanreg demo: PASS: all {len(checks)} checks ({seconds:.0f} s)")
    return 0


def run_odometry_demo(seed: int = 0, frames: int = 40) -> list[Check]:
    """Odometry on a simulated street and tunnel; the street's drift against 2 % of the path."""
    from .io.sequences import SimulatedSequence
    from .pipeline.odometry import OdometryConfig
    from .pipeline.run import evaluate_run, run_odometry

    print(f"scanreg demo: LiDAR odometry on simulated drives ({frames} VLP-16 sweeps, seed {seed})")
    config = OdometryConfig()
    street = SimulatedSequence("street", num_frames=frames, seed=seed)
    run = run_odometry(street, config)
    score = evaluate_run(run, street.ground_truth_at(config.reference_time))
    drift = score["end_error_m"] / score["path_length_m"]
    print(
        f"  street: {score['path_length_m']:.0f} m driven, end error {score['end_error_m']:.3f} m "
        f"({100 * drift:.2f} %), ATE {score['ate_rmse_m']:.3f} m, "
        f"{run.num_accepted}/{len(run.frames)} frames accepted, "
        f"{run.frames_per_second:.0f} frames/s"
    )
    last = run.frames[-1]
    sd = np.sqrt(np.diag(last.covariance))
    verdict = "accepted" if last.verdict else "; ".join(last.verdict.reasons)
    print(
        f"    last frame: σ = ({100 * sd[0]:.2f}, {100 * sd[1]:.2f}, {100 * sd[2]:.2f}) cm, "
        f"{np.degrees(sd[5]):.3f}° yaw (given the local map); verdict: {verdict}"
    )
    tunnel = SimulatedSequence("tunnel", num_frames=frames // 2, seed=seed)
    truth = tunnel.ground_truth_at(config.reference_time)
    rng = np.random.default_rng(seed)
    odo = Odometry(config)
    for k, frame in enumerate(tunnel):
        prior = None
        if k:  # a wheel odometry: the true increment, 2 % long, with 2 cm noise
            inc = SE3.from_matrix(np.linalg.inv(truth[k - 1]) @ truth[k]).log()
            inc[:3] = inc[:3] * 1.02 + rng.normal(0.0, 0.02, 3)
            prior = SE3.exp(inc)
        res = odo.step(frame.points, frame.timestamps, prior, stamp=frame.stamp)
    path = float(np.linalg.norm(truth[-1][:3, 3]))
    err = float(np.linalg.norm(res.pose.translation - truth[-1][:3, 3]))
    held = "; ".join(res.held_directions) or "nothing"
    print(
        f"  tunnel with a wheel prior: {path:.0f} m, end error {err:.3f} m; held to the prior: "
        f"{held} (σ there {100 * np.sqrt(res.covariance[0, 0]):.0f} cm, the prior's)"
    )
    ok = drift < 0.02
    print("  street drift below 2 % of the path:", "yes" if ok else "NO")
    check = Check("street drift, % of the path", 100 * drift, 2.0, "%")
    print(check.line())
    print()
    return [check]


# --- simulated scans (issue 3); registration/odometry on them comes with those issues ----
@dataclass(frozen=True)
class SimulatedStats:
    """Scan statistics of one short simulated run."""

    sensor: str
    scene: str
    num_scans: int
    #: Distance driven over the run (m), from the ground-truth poses.
    distance: float
    points_per_scan: float
    no_return_fraction: float
    dropout_fraction: float
    #: Fraction of valid returns that hit a moving object (dynamic outliers).
    dynamic_fraction: float
    #: Sample std of measured − true range over all valid returns, and the configured σ.
    range_error_std: float
    range_sigma: float
    #: Largest displacement between a raw (motion-distorted) point and its deskewed twin (m).
    max_distortion: float
    #: Count of valid returns per scene label, summed over the run.
    hits_by_label: tuple[tuple[str, int], ...]
    seconds_per_scan: float


def _returns(scan: simulate.LaserScan | simulate.LidarSweep) -> tuple[np.ndarray, ...]:
    """Status of every beam, and range error and primitive hit of every valid return."""
    if isinstance(scan, simulate.LaserScan):
        v = scan.valid
        return scan.status, (scan.ranges - scan.true_ranges)[v], scan.primitive_index[v]
    return scan.status_image.ravel(), scan.ranges - scan.true_ranges, scan.primitive_index


def _stats(run: simulate.SimulatedRun, scene_name: str, seconds: float) -> SimulatedStats:
    scans = run.scans
    parts = [_returns(s) for s in scans]
    status, errors, hits = (np.concatenate([p[k] for p in parts]) for k in range(3))
    dynamic = run.scene.dynamic[hits]
    labels, counts = np.unique(np.array(run.scene.labels)[hits], return_counts=True)
    order = np.argsort(-counts)
    distortion = max(float(np.abs(s.points - s.points_deskewed).max(initial=0.0)) for s in scans)
    positions = np.array([p.translation for p in run.poses])
    return SimulatedStats(
        sensor=run.sensor.name,
        scene=scene_name,
        num_scans=len(scans),
        distance=float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum()),
        points_per_scan=float(np.mean([s.points.shape[0] for s in scans])),
        no_return_fraction=float(np.mean(status == simulate.NO_RETURN)),
        dropout_fraction=float(np.mean(status == simulate.DROPOUT)),
        dynamic_fraction=float(dynamic.mean()),
        range_error_std=float(errors.std(ddof=1)),
        range_sigma=run.sensor.range_sigma,
        max_distortion=distortion,
        hits_by_label=tuple((str(labels[i]), int(counts[i])) for i in order),
        seconds_per_scan=seconds / len(scans),
    )


def simulated_runs(seed: int = 0) -> tuple[SimulatedStats, SimulatedStats]:
    """A 2 s drive through the office floor plan (SICK LMS200-like laser at 10 Hz) and
    0.5 s down the street (HDL-64E-like LiDAR at 10 m/s, turning gently)."""
    office = simulate.floor_plan(seed=seed)
    walk = simulate.Trajectory.from_speed_and_yaw_rate(
        1.0, 0.0, duration=2.0, start=SE2.from_vector([1.0, 0.3, 0.0])
    )
    t0 = time.perf_counter()
    run2 = simulate.simulate_run(
        office, simulate.LaserModel.preset("sick_lms200"), walk, num_scans=20, seed=seed
    )
    t2 = time.perf_counter() - t0
    street = simulate.street(seed=seed)
    drive = simulate.Trajectory.from_speed_and_yaw_rate(
        10.0, 0.05, duration=0.5, dim=3, start=SE3.from_vector([-20.0, 1.75, 1.73, 0, 0, 0])
    )
    t0 = time.perf_counter()
    run3 = simulate.simulate_run(
        street, simulate.LidarModel.preset("hdl64"), drive, num_scans=5, seed=seed
    )
    t3 = time.perf_counter() - t0
    return _stats(run2, "office floor plan", t2), _stats(run3, "street", t3)


def _print_simulated(runs: tuple[SimulatedStats, ...]) -> None:
    print()
    print("scanreg demo: simulated scans (scanreg.simulate)")
    for r in runs:
        print(
            f"  {r.sensor} in the {r.scene}: {r.num_scans} scans over {r.distance:.1f} m, "
            f"{r.points_per_scan:.0f} points/scan, {1e3 * r.seconds_per_scan:.1f} ms/scan"
        )
        print(
            f"    no return {100 * r.no_return_fraction:.1f} %, dropouts "
            f"{100 * r.dropout_fraction:.2f} %, on moving objects {100 * r.dynamic_fraction:.1f} %"
        )
        print(
            f"    range error std {r.range_error_std:.4f} m (configured σ {r.range_sigma}); "
            f"largest motion distortion {r.max_distortion:.3f} m"
        )
        top = ", ".join(f"{name} {count}" for name, count in r.hits_by_label[:6])
        print(f"    returns by surface: {top}")
