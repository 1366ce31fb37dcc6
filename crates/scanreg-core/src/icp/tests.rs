use super::centred::run;
use super::evaluate::{evaluate, Problem, NONE};
use super::pose::Pose;
use super::*;
use crate::group::{Group, Planar, Spatial};
use crate::kernel::Kernel;
use crate::knn::KdTree;
use crate::normals::{local_geometry, Regularization};
use crate::points::vec_at;
use crate::threads::in_pool;
use nalgebra::{SMatrix, SVector};

/// Points on the inside of a box room (floor, walls, ceiling) plus a pillar: every pose
/// direction is constrained. Deterministic pseudo-random jitter along each face.
fn room_3d() -> Vec<f64> {
    let mut pts = Vec::new();
    let mut s: u64 = 12345;
    let mut rnd = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    for _ in 0..4000 {
        let (u, v) = (rnd(), rnd());
        let face = (rnd() * 6.0) as usize;
        let p = match face {
            0 => [u * 10.0 - 5.0, v * 8.0 - 4.0, 0.0],
            1 => [u * 10.0 - 5.0, v * 8.0 - 4.0, 3.0],
            2 => [-5.0, v * 8.0 - 4.0, u * 3.0],
            3 => [5.0, v * 8.0 - 4.0, u * 3.0],
            4 => [u * 10.0 - 5.0, 4.0, v * 3.0],
            _ => [
                1.0 + 0.5 * (u * std::f64::consts::TAU).cos(),
                0.5 * (u * std::f64::consts::TAU).sin(),
                v * 3.0,
            ],
        };
        pts.extend_from_slice(&p);
    }
    pts
}

fn room_2d() -> Vec<f64> {
    // Irregular spacing along the walls: regularly spaced points make spurious p2p fixed points.
    let mut pts = Vec::new();
    let mut s: u64 = 777;
    let mut rnd = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    for _ in 0..400 {
        let u = rnd();
        pts.extend_from_slice(&[u * 10.0 - 5.0, -4.0]);
        pts.extend_from_slice(&[rnd() * 10.0 - 5.0, 4.0]);
        pts.extend_from_slice(&[-5.0, rnd() * 8.0 - 4.0]);
        pts.extend_from_slice(&[5.0, rnd() * 8.0 - 4.0]);
        let a = rnd() * std::f64::consts::TAU;
        pts.extend_from_slice(&[1.0 + 0.5 * a.cos(), 0.5 * a.sin()]);
    }
    pts
}

fn pose_flat<const D: usize>(p: &Pose<D>) -> Vec<f64> {
    p.to_flat()
}

fn truth_3d() -> Pose<3> {
    let (r, t) = Spatial::exp(&SVector::<f64, 6>::from_column_slice(&[
        0.3, -0.2, 0.1, 0.02, -0.03, 0.08,
    ]));
    Pose { r, t }
}

fn truth_2d() -> Pose<2> {
    let (r, t) = Planar::exp(&SVector::<f64, 3>::from_column_slice(&[0.3, -0.2, 0.07]));
    Pose { r, t }
}

/// Source = inverse(truth) applied to the target, so `T_target_source = truth`.
fn source_of<const D: usize>(target: &[f64], truth: &Pose<D>) -> Vec<f64> {
    let rt = truth.r.transpose();
    target
        .chunks_exact(D)
        .flat_map(|q| {
            let q = SVector::<f64, D>::from_column_slice(q);
            (rt * (q - truth.t)).iter().copied().collect::<Vec<_>>()
        })
        .collect()
}

/// A target with `g`'s normals (no covariances) and a source of bare points.
fn with_normals<'a>(
    tree: &'a KdTree,
    g: &'a crate::normals::LocalGeometry,
    src: &'a [f64],
) -> (Target<'a>, Source<'a>) {
    let target = Target {
        search: tree,
        normals: g.normals.as_deref(),
        covariances: None,
    };
    let source = Source {
        points: src,
        covariances: None,
    };
    (target, source)
}

fn settings(method: Method, kernel: Kernel, optimizer: Optimizer) -> Settings {
    Settings {
        method,
        kernel,
        max_correspondence_distance: 1.0,
        max_iterations: 60,
        translation_tolerance: 1e-7,
        rotation_tolerance: 1e-8,
        optimizer,
        min_correspondences: 10,
        step_projector: None,
        extrapolate: true,
    }
}

fn identity(dim: usize) -> Vec<f64> {
    let m = dim + 1;
    (0..m * m)
        .map(|k| if k % (m + 1) == 0 { 1.0 } else { 0.0 })
        .collect()
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// The target's tree, normals and covariances, and the source's covariances (k = 10, plane
/// regularisation, viewpoint 0.3 on every axis).
fn geometry(
    tgt: &[f64],
    src: &[f64],
    dim: usize,
) -> (
    KdTree,
    crate::normals::LocalGeometry,
    crate::normals::LocalGeometry,
) {
    let tree = KdTree::build(tgt, dim).unwrap();
    let vp = vec![0.3; dim];
    let g = local_geometry(&tree, 10, &vp, true, Some(Regularization::Plane(1e-3))).unwrap();
    let stree = KdTree::build(src, dim).unwrap();
    let sg = local_geometry(&stree, 10, &vp, false, Some(Regularization::Plane(1e-3))).unwrap();
    (tree, g, sg)
}

/// [`geometry`]'s parts as a target and a source.
fn with_geometry<'a>(
    tree: &'a KdTree,
    g: &'a crate::normals::LocalGeometry,
    src: &'a [f64],
    sg: &'a crate::normals::LocalGeometry,
) -> (Target<'a>, Source<'a>) {
    let target = Target {
        search: tree,
        normals: g.normals.as_deref(),
        covariances: g.covariances.as_deref(),
    };
    let source = Source {
        points: src,
        covariances: sg.covariances.as_deref(),
    };
    (target, source)
}

/// The room of `dim` (target), the true pose (flat) and the source it gives.
fn room_case(dim: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    if dim == 3 {
        let tgt = room_3d();
        let src = source_of(&tgt, &truth_3d());
        (tgt, truth_3d().to_flat(), src)
    } else {
        let tgt = room_2d();
        let src = source_of(&tgt, &truth_2d());
        (tgt, truth_2d().to_flat(), src)
    }
}

fn run_case(
    dim: usize,
    method: Method,
    kernel: Kernel,
    optimizer: Optimizer,
) -> (Outcome, Vec<f64>) {
    let (tgt, truth, src) = room_case(dim);
    let (tree, g, sg) = geometry(&tgt, &src, dim);
    let (target, source) = with_geometry(&tree, &g, &src, &sg);
    let out = register(
        &source,
        &target,
        &identity(dim),
        &settings(method, kernel, optimizer),
    )
    .unwrap();
    (out, truth)
}

#[test]
fn recovers_known_pose_every_method_kernel_optimizer() {
    for dim in [2, 3] {
        for method in [Method::PointToPoint, Method::PointToPlane, Method::Gicp] {
            for kernel in [Kernel::None, Kernel::Huber(0.1), Kernel::Cauchy(0.2)] {
                for opt in [Optimizer::GaussNewton, Optimizer::LevenbergMarquardt] {
                    let (out, truth) = run_case(dim, method, kernel, opt);
                    let err = max_abs_diff(&out.pose, &truth);
                    assert!(
                        err < 1e-6,
                        "{dim}D {method:?} {kernel:?} {opt:?}: err {err}, {:?} after {}",
                        out.stop_reason,
                        out.iterations
                    );
                    assert_eq!(out.stop_reason, StopReason::Converged);
                    assert!(out.evaluation.sum_squared_distances < 1e-10);
                }
            }
        }
    }
}

#[test]
fn gradient_matches_finite_difference_of_cost() {
    // At a pose near the truth the correspondences do not change for tiny perturbations, so
    // g = ∂cost/∂δ exactly (cost = Σ ½|r|² without a kernel).
    for method in [Method::PointToPoint, Method::PointToPlane] {
        let tgt = room_3d();
        let src = source_of(&tgt, &truth_3d());
        let tree = KdTree::build(&tgt, 3).unwrap();
        let g = local_geometry(&tree, 10, &[0.3; 3], true, None).unwrap();
        let (target, source) = with_normals(&tree, &g, &src);
        let s = settings(method, Kernel::None, Optimizer::GaussNewton);
        let base = truth_3d();
        let (rd, td) = Spatial::exp(&SVector::<f64, 6>::from_column_slice(&[
            0.01, 0.0, 0.0, 0.0, 0.0, 0.004,
        ]));
        let at = base.compose(&rd, &td);
        let ev = evaluate_at(&source, &target, &at.to_flat(), &s).unwrap();
        for k in 0..6 {
            let h = 1e-6;
            let cost = |x: f64| {
                let mut d = SVector::<f64, 6>::zeros();
                d[k] = x;
                let (r, t) = Spatial::exp(&d);
                evaluate_at(&source, &target, &at.compose(&r, &t).to_flat(), &s)
                    .unwrap()
                    .cost
            };
            let fd = (cost(h) - cost(-h)) / (2.0 * h);
            assert!(
                (fd - ev.gradient[k]).abs() < 1e-4 * fd.abs().max(1.0),
                "{method:?} k={k}: fd {fd} vs {}",
                ev.gradient[k]
            );
        }
    }
}

#[test]
fn identical_for_one_and_two_threads() {
    let run = |n| {
        in_pool(Some(n), || {
            run_case(3, Method::Gicp, Kernel::Huber(0.1), Optimizer::GaussNewton).0
        })
        .unwrap()
    };
    let (a, b) = (run(1), run(2));
    assert_eq!(a.pose, b.pose);
    assert_eq!(a.evaluation.hessian, b.evaluation.hessian);
    assert_eq!(a.iterations, b.iterations);
}

/// Without a home, a restart is [`register`] from its start, bit for bit; a home reached
/// on the way stops it there, converged, in fewer iterations.
#[test]
fn restarts_are_the_registration_from_each_start() {
    for dim in [2, 3] {
        let (tgt, truth, src) = room_case(dim);
        let (tree, g, sg) = geometry(&tgt, &src, dim);
        let (target, source) = with_geometry(&tree, &g, &src, &sg);
        let s = settings(Method::Gicp, Kernel::None, Optimizer::GaussNewton);
        let start = identity(dim);
        let alone = register(&source, &target, &start, &s).unwrap();
        let plain = Restarts::new(&source, &target, &s, None).unwrap();
        let again = plain.solve(&start);
        assert_eq!(again.pose, alone.pose);
        assert_eq!(again.iterations, alone.iterations);
        let home = Home {
            pose: truth.clone(),
            radius: 0.05,
            cos_angle: 2f64.to_radians().cos(),
        };
        let homing = Restarts::new(&source, &target, &s, Some(&home)).unwrap();
        let stopped = homing.solve(&start);
        assert_eq!(stopped.stop_reason, StopReason::Converged);
        assert!(stopped.iterations < alone.iterations);
        assert!(max_abs_diff(&stopped.pose, &truth) < 0.1);
    }
}

#[test]
fn stop_reasons() {
    let tgt = room_3d();
    let src = source_of(&tgt, &truth_3d());
    let tree = KdTree::build(&tgt, 3).unwrap();
    let target = Target {
        search: &tree,
        normals: None,
        covariances: None,
    };
    let source = Source {
        points: &src,
        covariances: None,
    };
    let mut s = settings(Method::PointToPoint, Kernel::None, Optimizer::GaussNewton);
    s.max_iterations = 2;
    let out = register(&source, &target, &identity(3), &s).unwrap();
    assert_eq!(out.stop_reason, StopReason::MaxIterations);
    assert_eq!(out.iterations, 2);
    // Source far away: nothing within the gate.
    let far: Vec<f64> = src.iter().map(|v| v + 100.0).collect();
    let source = Source {
        points: &far,
        covariances: None,
    };
    s.max_iterations = 30;
    let out = register(&source, &target, &identity(3), &s).unwrap();
    assert_eq!(out.stop_reason, StopReason::TooFewCorrespondences);
    assert_eq!(out.iterations, 0);
    assert_eq!(out.pose, identity(3));
    // All points on one plane: point-to-plane cannot fix in-plane motion.
    let plane: Vec<f64> = (0..400)
        .flat_map(|i| [(i % 20) as f64 * 0.2, (i / 20) as f64 * 0.2, 0.0])
        .collect();
    let ptree = KdTree::build(&plane, 3).unwrap();
    let g = local_geometry(&ptree, 8, &[0.0, 0.0, 5.0], true, None).unwrap();
    let target = Target {
        search: &ptree,
        normals: g.normals.as_deref(),
        covariances: None,
    };
    let shifted: Vec<f64> = plane
        .chunks(3)
        .flat_map(|p| [p[0], p[1], p[2] + 0.1])
        .collect();
    let source = Source {
        points: &shifted,
        covariances: None,
    };
    let s = settings(Method::PointToPlane, Kernel::None, Optimizer::GaussNewton);
    let out = register(&source, &target, &identity(3), &s).unwrap();
    assert_eq!(out.stop_reason, StopReason::Degenerate);
}

#[test]
fn rejects_bad_input() {
    let tgt = room_3d();
    let tree = KdTree::build(&tgt, 3).unwrap();
    let target = Target {
        search: &tree,
        normals: None,
        covariances: None,
    };
    let source = Source {
        points: &tgt,
        covariances: None,
    };
    let s = settings(Method::PointToPlane, Kernel::None, Optimizer::GaussNewton);
    let e = register(&source, &target, &identity(3), &s).unwrap_err();
    assert!(e.to_string().starts_with("target_normals:"), "{e}");
    let s = settings(Method::Gicp, Kernel::None, Optimizer::GaussNewton);
    let e = register(&source, &target, &identity(3), &s).unwrap_err();
    assert!(e.to_string().starts_with("target_covariances:"), "{e}");
    let mut s = settings(Method::PointToPoint, Kernel::None, Optimizer::GaussNewton);
    s.max_correspondence_distance = f64::NAN;
    let e = register(&source, &target, &identity(3), &s).unwrap_err();
    assert!(
        e.to_string().starts_with("max_correspondence_distance:"),
        "{e}"
    );
    let s = settings(Method::PointToPoint, Kernel::None, Optimizer::GaussNewton);
    let e = register(&source, &target, &identity(2), &s).unwrap_err();
    assert!(e.to_string().starts_with("init:"), "{e}");
    let e = register(
        &Source {
            points: &tgt[..4],
            covariances: None,
        },
        &target,
        &identity(3),
        &s,
    )
    .unwrap_err();
    assert!(e.to_string().starts_with("source:"), "{e}");
    assert!(in_pool(Some(0), || ()).is_err());
    assert!(Method::from_name("icp").is_err());
    assert!(Optimizer::from_name("newton").is_err());
}

/// The point-to-point Hessian assembled from moments equals the sum of `A(p)ᵀA(p)` per point,
/// also far from the origin (where `|p|² − x²` would cancel).
#[test]
fn moment_hessian_equals_per_point_products() {
    fn check<G: Group<D, N>, const D: usize, const N: usize>(offset: f64) {
        let (mut h, mut k, mut kp, mut rot) = (
            SMatrix::<f64, N, N>::zeros(),
            0.0,
            SVector::<f64, D>::zeros(),
            SMatrix::<f64, D, D>::zeros(),
        );
        for i in 0..50 {
            let p = SVector::<f64, D>::from_fn(|r, _| {
                offset * (r as f64 + 1.0) + ((i * (r + 3)) as f64 * 0.37).sin() * 5.0
            });
            let w = 0.5 + (i as f64 * 0.11).cos().abs();
            let a = G::point_jacobian(&p);
            h += a.transpose() * a * w;
            k += w;
            kp += p * w;
            rot += G::rotation_moment(&p) * w;
        }
        let m = G::moment_hessian(k, &kp, &rot);
        let scale = h.amax();
        assert!(
            (m - h).amax() <= 1e-14 * scale,
            "{}",
            (m - h).amax() / scale
        );
    }
    for offset in [0.0, 1e5] {
        check::<Planar, 2, 3>(offset);
        check::<Spatial, 3, 6>(offset);
    }
}

/// The safeguarded extrapolation: the same pose as the plain loop on exact data, in fewer
/// point-to-point iterations (no more for point-to-plane/line), and nothing changes under
/// LM (GICP is never extrapolated: `register` gates on the method).
#[test]
fn extrapolation_recovers_the_pose_in_fewer_iterations() {
    for dim in [2, 3] {
        let (tgt, truth_flat, src) = if dim == 3 {
            let t = room_3d();
            let s = source_of(&t, &truth_3d());
            (t, pose_flat(&truth_3d()), s)
        } else {
            let t = room_2d();
            let s = source_of(&t, &truth_2d());
            (t, pose_flat(&truth_2d()), s)
        };
        let tree = KdTree::build(&tgt, dim).unwrap();
        let vp = vec![0.3; dim];
        let g = local_geometry(&tree, 10, &vp, true, None).unwrap();
        let (target, source) = with_normals(&tree, &g, &src);
        for (method, opt) in [
            (Method::PointToPoint, Optimizer::GaussNewton),
            (Method::PointToPoint, Optimizer::LevenbergMarquardt),
            (Method::PointToPlane, Optimizer::GaussNewton),
        ] {
            let run = |extrapolate: bool| {
                let s = Settings {
                    extrapolate,
                    ..settings(method, Kernel::None, opt)
                };
                register(&source, &target, &identity(dim), &s).unwrap()
            };
            let (on, off) = (run(true), run(false));
            for out in [&on, &off] {
                assert_eq!(out.stop_reason, StopReason::Converged);
                assert!(
                    max_abs_diff(&out.pose, &truth_flat) < 1e-6,
                    "{dim}D {method:?}"
                );
            }
            if method == Method::PointToPoint && opt == Optimizer::GaussNewton {
                assert!(
                    on.iterations < off.iterations,
                    "{dim}D: {} iterations with extrapolation, {} without",
                    on.iterations,
                    off.iterations
                );
            } else if method == Method::PointToPlane {
                assert!(on.iterations <= off.iterations, "{dim}D point-to-plane");
            } else {
                assert_eq!(
                    on.pose, off.pose,
                    "{dim}D {method:?} {opt:?}: not extrapolated"
                );
                assert_eq!(on.iterations, off.iterations);
            }
        }
    }
}

/// Skipping the searches a certificate settles changes nothing: every method, kernel and
/// optimiser, 2D and 3D, on a noisy partial-overlap pair with outliers (points that leave and
/// enter the gate) gives the same outcome to the bit as searching every time; and it does skip.
#[test]
fn certified_searches_change_nothing() {
    for dim in [2, 3] {
        let (tgt, truth, exact) = room_case(dim);
        // Two points in three, jittered by up to ±1 cm, and a far ring of outliers.
        let mut s: u64 = 99;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut src: Vec<f64> = Vec::new();
        for (i, p) in exact.chunks_exact(dim).enumerate() {
            if i % 3 != 0 {
                src.extend(p.iter().map(|v| v + 0.02 * (rnd() - 0.5)));
            }
        }
        for k in 0..40 {
            let a = k as f64 * 0.157;
            src.extend([20.0 * a.cos(), 20.0 * a.sin(), 1.0][..dim].iter().copied());
        }
        // And far from the origin (map coordinates): certificates keep their anchors as
        // offsets from the answer, so they stay exact and useful there.
        for shift in [0.0, 1e6] {
            let tgt: Vec<f64> = tgt.iter().map(|v| v + shift).collect();
            let src: Vec<f64> = src.iter().map(|v| v + shift).collect();
            let mut truth = truth.clone();
            for r in 0..dim {
                let rot: f64 = (0..dim).map(|c| truth[r * (dim + 1) + c]).sum();
                truth[r * (dim + 1) + dim] += shift - rot * shift;
            }
            let full = shift == 0.0; // every case at the origin, Gauss-Newton far from it
            let (tree, g, sg) = geometry(&tgt, &src, dim);
            let (target, source) = with_geometry(&tree, &g, &src, &sg);
            for method in [Method::PointToPoint, Method::PointToPlane, Method::Gicp] {
                for kernel in [Kernel::None, Kernel::Huber(0.05)] {
                    for opt in [Optimizer::GaussNewton, Optimizer::LevenbergMarquardt] {
                        if !full && opt != Optimizer::GaussNewton {
                            continue;
                        }
                        for gate in [0.5, 1.5] {
                            let st = Settings {
                                max_correspondence_distance: gate,
                                translation_tolerance: 1e-6,
                                rotation_tolerance: 1e-6,
                                ..settings(method, kernel, opt)
                            };
                            let run = |certify: bool| {
                                let mut pr = problem(&source, &target, &st).unwrap();
                                pr.certify = certify;
                                if dim == 2 {
                                    run::<Planar, 2, 3>(&pr, &identity(dim), &st)
                                } else {
                                    run::<Spatial, 3, 6>(&pr, &identity(dim), &st)
                                }
                            };
                            let (on, off) = (run(true), run(false));
                            let case = format!(
                                "{dim}D {method:?} {kernel:?} {opt:?} gate {gate} shift {shift}"
                            );
                            assert_eq!(on.pose, off.pose, "{case}");
                            assert_eq!(on.iterations, off.iterations, "{case}");
                            assert_eq!(on.stop_reason, off.stop_reason, "{case}");
                            assert_eq!(on.evaluation, off.evaluation, "{case}");
                            assert_eq!(on.correspondences, off.correspondences, "{case}");
                            // (Far away a pose's translation entries carry the rotation's
                            // error times the lever: checked at the origin.)
                            assert!(
                                !full || max_abs_diff(&on.pose, &truth) < 0.05,
                                "{case}: not recovered"
                            );
                        }
                    }
                }
            }
            // And most searches are skipped near convergence: the certificates of an
            // evaluation at the truth settle most points' searches a few tenths of a
            // millimetre away, every answer the search's.
            let st = settings(Method::PointToPoint, Kernel::None, Optimizer::GaussNewton);
            let pr = problem(&source, &target, &st).unwrap();
            let (settled, total) = if dim == 2 {
                skipped::<Planar, 2, 3>(&pr, &truth)
            } else {
                skipped::<Spatial, 3, 6>(&pr, &truth)
            };
            assert!(
                settled * 10 > total * 8,
                "{dim}D shift {shift}: {settled} of {total} settled"
            );
        }
    }
}

/// How many searches certificates settle near convergence: evaluations at `truth` and then
/// 0.22 mm steps from it (the second's searches certified with the first's move as
/// slack), counted on the third, each settled answer checked against a search.
fn skipped<G: Group<D, N>, const D: usize, const N: usize>(
    pr: &Problem<'_>,
    truth: &[f64],
) -> (usize, usize) {
    let mut d = SVector::<f64, N>::zeros();
    d[0] = 2e-4; // a translation: a turn about the frame's origin moves far points far
    d[1] = 1e-4;
    let (r, t) = G::exp(&d);
    let first = Pose::<D>::from_flat(truth);
    let second = first.compose(&r, &t);
    let third = second.compose(&r, &t);
    let (_, c1, k1) = evaluate::<G, D, N>(pr, &first, false, true, None, None, None);
    let (_, c2, k2) = evaluate::<G, D, N>(pr, &second, false, true, None, Some(&c1), Some(&k1));
    let tree = pr.target.search;
    let mut settled = 0;
    for (i, c) in k2.iter().enumerate() {
        let tp = third.r * vec_at::<D>(pr.source, i) + third.t;
        if let Ok(answer) = c.answer(&tp, c2[i], tree.points(), pr.max_sq) {
            assert_eq!(
                answer,
                tree.nearest_within(tp.as_slice(), pr.max_sq),
                "point {i}"
            );
            settled += 1;
        }
    }
    (settled, k2.len())
}

/// The overlap pass answered from a registration's certificates equals the searched one, to
/// the bit: at the returned pose, moved off it, with other gates, after a converged solve (its
/// final evaluation re-uses the last search's correspondences) and after an iteration cap (a
/// searched final evaluation); refused against another index.
#[test]
fn certificates_answer_the_overlap_as_its_search_does() {
    use crate::overlap::overlap;
    fn check<const D: usize>(tgt: &[f64], src: &[f64]) {
        let tree = KdTree::build(tgt, D).unwrap();
        let target = Target {
            search: &tree,
            normals: None,
            covariances: None,
        };
        let source = Source {
            points: src,
            covariances: None,
        };
        for (cap, want) in [(60, StopReason::Converged), (2, StopReason::MaxIterations)] {
            let mut s = settings(Method::PointToPoint, Kernel::None, Optimizer::GaussNewton);
            s.max_iterations = cap;
            let out = register(&source, &target, &identity(D), &s).unwrap();
            assert_eq!(out.stop_reason, want);
            let certs = out
                .certificates
                .as_ref()
                .expect("a k-d tree certifies its searches");
            assert_eq!(certs.len(), src.len() / D);
            let hints: Vec<i64> = out
                .correspondences
                .iter()
                .map(|&j| if j == NONE { -1 } else { i64::from(j) })
                .collect();
            let mut moved = out.pose.clone();
            moved[D] += 2e-3; // the first row's translation
            for pose in [&out.pose, &moved] {
                for gate in [1.0f64, 0.3, 0.05, 2.0] {
                    let (g2, w2) = (gate * gate, 0.25 * gate * gate);
                    let plain = overlap(&tree, src, pose, g2, w2, None, None).unwrap();
                    let fast = overlap(&tree, src, pose, g2, w2, Some(&hints), Some(certs));
                    assert_eq!(fast.unwrap(), plain, "cap {cap}, gate {gate}");
                }
            }
            let other = KdTree::build(tgt, D).unwrap();
            let e = overlap(&other, src, &out.pose, 1.0, 1.0, None, Some(certs)).unwrap_err();
            assert!(e.to_string().contains("certificates"), "{e}");
        }
    }
    // Jittered sources, so that the distances are not all zero.
    let jitter = |pts: Vec<f64>| -> Vec<f64> {
        pts.iter()
            .enumerate()
            .map(|(k, v)| v + 0.01 * (((k * 7919) % 101) as f64 / 101.0 - 0.5))
            .collect()
    };
    let tgt = room_3d();
    check::<3>(&tgt, &jitter(source_of(&tgt, &truth_3d())));
    let tgt = room_2d();
    check::<2>(&tgt, &jitter(source_of(&tgt, &truth_2d())));
}
