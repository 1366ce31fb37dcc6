use super::*;

/// Row-major homogeneous SE(2) pose rotating by `th` and translating by `(x, y)`.
fn planar_pose(th: f64, x: f64, y: f64) -> [f64; 9] {
    [th.cos(), -th.sin(), x, th.sin(), th.cos(), y, 0.0, 0.0, 1.0]
}

/// Options without a kernel, with the given per-coordinate source, target and normal variances
/// and one block per point.
fn unkernelled(method: Method, variances: [f64; 3]) -> Options {
    Options {
        method,
        kernel: Kernel::from_name("none", 1.0).unwrap(),
        source_variance: variances[0],
        target_variance: variances[1],
        normal_variance: variances[2],
        block_size: f64::INFINITY,
    }
}

/// Points with target normals (no covariances) and their correspondences.
fn with_normals<'a>(src: &'a [f64], tgt: &'a [f64], nrm: &'a [f64], corr: &'a [u32]) -> Input<'a> {
    Input {
        source: src,
        source_covariances: None,
        target: tgt,
        target_normals: Some(nrm),
        target_covariances: None,
        correspondences: corr,
        source_normals: None,
        target_linear: None,
    }
}

fn scene() -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<u32>) {
    // Source points near two walls; target = the same points slightly displaced; normals fixed.
    let mut src = Vec::new();
    let mut tgt = Vec::new();
    let mut nrm = Vec::new();
    let mut corr = Vec::new();
    for k in 0..12 {
        let s = k as f64 * 0.37;
        let (p, n) = if k % 2 == 0 {
            ([s, 2.0 + 0.01 * (k as f64).sin()], [0.0, 1.0])
        } else {
            ([3.0 + 0.02 * (k as f64).cos(), s - 1.0], [1.0, 0.0])
        };
        src.extend_from_slice(&p);
        tgt.extend_from_slice(&[p[0] + 0.03 * (k as f64).cos(), p[1] - 0.02]);
        nrm.extend_from_slice(&n);
        // two source points share each target point, to exercise the shared-target sum
        corr.push((k / 2 * 2) as u32);
    }
    (src, tgt, nrm, corr)
}

/// One direction per coordinate of array `which` (0 source, 1 target, 2 normals) of `len`
/// values, for [`fd_meat`].
fn unit_dirs(which: usize, len: usize) -> Vec<(usize, Vec<f64>)> {
    (0..len)
        .map(|c| {
            let mut v = vec![0.0; len];
            v[c] = 1.0;
            (which, v)
        })
        .collect()
}

fn check_method(method: Method) {
    let (src, tgt, nrm, corr) = scene();
    let pose = planar_pose(0.141f64.atan2(0.99), 0.2, -0.1);
    let input = with_normals(&src, &tgt, &nrm, &corr);
    let meat_of = |opts: &Options| {
        let out = analyse(&input, &pose, 2, opts).unwrap();
        SMatrix::<f64, 3, 3>::from_row_slice(&out.censi_meat)
    };
    // Source noise: (∂g/∂p)(∂g/∂p)ᵀ summed over every source coordinate.
    let opts = unkernelled(method, [1.0, 0.0, 0.0]);
    let fd = fd_meat::<Planar, 2, 3>(&input, &opts, &pose, &unit_dirs(0, src.len()));
    let meat = meat_of(&opts);
    assert!(
        (meat - fd).norm() < 1e-5 * fd.norm(),
        "{method:?}: {meat} vs {fd}"
    );
    // Target noise: derivatives of the points sharing a target are summed before squaring.
    let opts_t = unkernelled(method, [0.0, 1.0, 0.0]);
    let fd = fd_meat::<Planar, 2, 3>(&input, &opts_t, &pose, &unit_dirs(1, tgt.len()));
    let meat = meat_of(&opts_t);
    assert!(
        (meat - fd).norm() < 1e-5 * fd.norm(),
        "{method:?} target: {meat} vs {fd}"
    );
}

#[test]
fn normal_term_matches_finite_differences() {
    let (src, tgt, nrm, corr) = scene();
    let pose = planar_pose(0.141f64.atan2(0.99), 0.2, -0.1);
    let opts = unkernelled(Method::PointToPlane, [0.0, 0.0, 1.0]);
    let input = with_normals(&src, &tgt, &nrm, &corr);
    // In 2D the normal turns about its one tangent t = (−n_y, n_x): Σ_n = t tᵀ.
    let dirs: Vec<_> = (0..tgt.len() / 2)
        .map(|j| {
            let mut v = vec![0.0; nrm.len()];
            v[2 * j] = -nrm[2 * j + 1];
            v[2 * j + 1] = nrm[2 * j];
            (2, v)
        })
        .collect();
    let fd = fd_meat::<Planar, 2, 3>(&input, &opts, &pose, &dirs);
    let out = analyse(&input, &pose, 2, &opts).unwrap();
    let meat = SMatrix::<f64, 3, 3>::from_row_slice(&out.censi_meat);
    assert!((meat - fd).norm() < 1e-5 * fd.norm(), "{meat} vs {fd}");
}

#[test]
fn censi_meat_matches_finite_differences() {
    check_method(Method::PointToPoint);
    check_method(Method::PointToPlane);
}

#[test]
fn rejects_bad_correspondences() {
    let (src, tgt, nrm, mut corr) = scene();
    corr[0] = 99;
    let input = with_normals(&src, &tgt, &nrm, &corr);
    let opts = Options {
        method: Method::PointToPoint,
        kernel: Kernel::from_name("none", 1.0).unwrap(),
        source_variance: 1.0,
        target_variance: 1.0,
        normal_variance: 0.0,
        block_size: 1.0,
    };
    let pose = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    assert!(analyse(&input, &pose, 2, &opts).is_err());
}

/// `Σ_i g_i` at `pose` over fixed correspondences, skipping [`NONE`] (the quantity whose
/// derivatives Censi needs).
fn total_score<G: Geometry<D, N>, const D: usize, const N: usize>(
    input: &Input<'_>,
    opts: &Options,
    pose: &[f64],
) -> SVector<f64, N> {
    let r: SMatrix<f64, D, D> = SMatrix::from_fn(|i, j| pose[i * (D + 1) + j]);
    let t: SVector<f64, D> = SVector::from_fn(|i, _| pose[i * (D + 1) + D]);
    let mut g = SVector::<f64, N>::zeros();
    for (i, &j) in input.correspondences.iter().enumerate() {
        if j == NONE {
            continue;
        }
        if let Some(tm) = term::<G, D, N>(input, opts, &r, &t, i, j as usize) {
            g += tm.score;
        }
    }
    g
}

/// Orthonormal basis of the plane (line) orthogonal to the unit vector `n`.
fn tangent_basis<const D: usize>(n: &SVector<f64, D>) -> Vec<SVector<f64, D>> {
    let mut basis: Vec<SVector<f64, D>> = Vec::new();
    for k in 0..D {
        let mut v = SVector::<f64, D>::zeros();
        v[k] = 1.0;
        v -= n * n.dot(&v);
        for b in &basis {
            v -= b * b.dot(&v);
        }
        if v.norm() > 0.3 && basis.len() < D - 1 {
            basis.push(v.normalize());
        }
    }
    basis
}

/// `Σ_k (∂G/∂z_k)(∂G/∂z_k)ᵀ` by central differences, `G = Σ_i g_i`, over the directions
/// `dirs` (each a perturbation of one of the three arrays: 0 source, 1 target, 2 normals).
fn fd_meat<G: Geometry<D, N>, const D: usize, const N: usize>(
    input: &Input<'_>,
    opts: &Options,
    pose: &[f64],
    dirs: &[(usize, Vec<f64>)],
) -> SMatrix<f64, N, N> {
    let h = 1e-6;
    let mut meat = SMatrix::<f64, N, N>::zeros();
    for (which, dir) in dirs {
        let base = match which {
            0 => input.source,
            1 => input.target,
            _ => input.target_normals.unwrap(),
        };
        let shifted =
            |s: f64| -> Vec<f64> { base.iter().zip(dir).map(|(b, d)| b + s * d).collect() };
        let (plus, minus) = (shifted(h), shifted(-h));
        let at = |data: &[f64]| {
            let moved = match which {
                0 => Input {
                    source: data,
                    ..*input
                },
                1 => Input {
                    target: data,
                    ..*input
                },
                _ => Input {
                    target_normals: Some(data),
                    ..*input
                },
            };
            total_score::<G, D, N>(&moved, opts, pose)
        };
        let d = (at(&plus) - at(&minus)) / (2.0 * h);
        meat += d * d.transpose();
    }
    meat
}

/// A deterministic scene with generic (not axis-aligned) unit normals, shared target points
/// and one source point without a correspondence.
fn generic_scene<const D: usize>() -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<u32>) {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut uniform = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let targets = 9;
    let mut tgt = Vec::new();
    let mut nrm = Vec::new();
    for _ in 0..targets {
        let q: SVector<f64, D> = SVector::from_fn(|_, _| 3.0 * uniform());
        let n: SVector<f64, D> = SVector::<f64, D>::from_fn(|_, _| uniform() + 0.1).normalize();
        tgt.extend_from_slice(q.as_slice());
        nrm.extend_from_slice(n.as_slice());
    }
    let mut src = Vec::new();
    let mut corr = Vec::new();
    for i in 0..2 * targets + 1 {
        let p: SVector<f64, D> = SVector::from_fn(|_, _| 3.0 * uniform());
        src.extend_from_slice(p.as_slice());
        // two source points per target point (shared-target sum), the last one unmatched
        corr.push(if i == 2 * targets {
            NONE
        } else {
            (i / 2) as u32
        });
    }
    (src, tgt, nrm, corr)
}

/// Every unit-variance meat (source, target, normal) against central differences of the
/// summed score, for generic normals and a generic pose. Any profile: it compares the
/// optimised analytic code with the plain score, so a wrong projector `I − n nᵀ` (as
/// miscompiled at opt-level 3 with the axis-aligned normals of `scene`) fails here.
fn check_all_meats<G: Geometry<D, N>, const D: usize, const N: usize>(
    method: Method,
    pose: &[f64],
) -> Vec<String> {
    let (src, tgt, nrm, corr) = generic_scene::<D>();
    let opts = unkernelled(method, [1.0, 1.0, 1.0]);
    let input = with_normals(&src, &tgt, &nrm, &corr);
    let src_dirs = unit_dirs(0, src.len());
    let tgt_dirs = unit_dirs(1, tgt.len());
    let mut nrm_dirs = Vec::new();
    for j in 0..tgt.len() / D {
        let n: SVector<f64, D> = vec_at(&nrm, j);
        for t in tangent_basis(&n) {
            let mut v = vec![0.0; nrm.len()];
            v[j * D..(j + 1) * D].copy_from_slice(t.as_slice());
            nrm_dirs.push((2, v));
        }
    }
    let out = analyse(&input, pose, D, &opts).unwrap();
    let meat = |flat: &[f64]| SMatrix::<f64, N, N>::from_row_slice(flat);
    let mut cases = vec![
        ("source", meat(&out.source_meat), src_dirs),
        ("target", meat(&out.target_meat), tgt_dirs),
    ];
    if method == Method::PointToPlane {
        cases.push(("normal", meat(&out.normal_meat), nrm_dirs));
    }
    let mut total = SMatrix::<f64, N, N>::zeros();
    let mut failures = Vec::new();
    for (name, analytic, dirs) in cases {
        let fd = fd_meat::<G, D, N>(&input, &opts, pose, &dirs);
        if !(fd.norm() > 1e-3 && (analytic - fd).norm() < 1e-5 * fd.norm()) {
            failures.push(format!("{D}D {method:?} {name}: {analytic} vs {fd}"));
        }
        total += analytic;
    }
    // unit variances: the combined meat is the sum of the three
    if (meat(&out.censi_meat) - total).norm() > 1e-12 * total.norm() {
        failures.push(format!("{D}D {method:?}: censi_meat is not the sum"));
    }
    failures
}

#[test]
fn all_meats_match_finite_differences_2d_and_3d() {
    let th = 0.3f64;
    let pose2 = planar_pose(th, 0.2, -0.1);
    let rot = nalgebra::Rotation3::from_scaled_axis(Vector3::new(0.2, -0.3, 0.25));
    let mut pose3 = [0.0; 16];
    for i in 0..3 {
        for j in 0..3 {
            pose3[i * 4 + j] = rot[(i, j)];
        }
    }
    pose3[3] = 0.3;
    pose3[7] = -0.2;
    pose3[11] = 0.1;
    pose3[15] = 1.0;
    let mut failures = Vec::new();
    for method in [Method::PointToPoint, Method::PointToPlane] {
        failures.extend(check_all_meats::<Planar, 2, 3>(method, &pose2));
        failures.extend(check_all_meats::<Spatial, 3, 6>(method, &pose3));
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn linear_targets_are_left_out_of_the_plane_information_only() {
    // The scene's target points 0, 4 and 8 flagged linear: the plane information (and the
    // count the degeneracy divides by) is that of the scene without their correspondences,
    // while the point noise along the normals still reads every residual; the determined
    // sums (`determined_plane_sum_squares`, `determined_block_meat`) are the scene's without.
    let (src, tgt, nrm, corr) = scene();
    let pose = planar_pose(0.141f64.atan2(0.99), 0.2, -0.1);
    let opts = unkernelled(Method::PointToPlane, [1.0, 1.0, 1.0]);
    let m = tgt.len() / 2;
    let linear: Vec<bool> = (0..m).map(|j| j % 4 == 0).collect();
    let flagged = Input {
        target_linear: Some(&linear),
        ..with_normals(&src, &tgt, &nrm, &corr)
    };
    let all = analyse(&with_normals(&src, &tgt, &nrm, &corr), &pose, 2, &opts).unwrap();
    let got = analyse(&flagged, &pose, 2, &opts).unwrap();
    let dropped: Vec<u32> = corr
        .iter()
        .map(|&j| if linear[j as usize] { NONE } else { j })
        .collect();
    let kept = analyse(&with_normals(&src, &tgt, &nrm, &dropped), &pose, 2, &opts).unwrap();
    assert!(got.linear_known && !all.linear_known);
    assert_eq!(
        all.num_determined_correspondences,
        all.num_plane_correspondences
    );
    assert_eq!(got.num_plane_correspondences, all.num_plane_correspondences);
    assert_eq!(
        got.num_determined_correspondences,
        kept.num_plane_correspondences
    );
    assert!(got.num_determined_correspondences < all.num_plane_correspondences);
    for (a, b) in got.plane_information.iter().zip(&kept.plane_information) {
        assert!((a - b).abs() < 1e-12, "{a} vs {b}");
    }
    assert_eq!(got.plane_sum_squares, all.plane_sum_squares);
    assert_eq!(got.hessian, all.hessian);
    assert_eq!(got.block_meat, all.block_meat);
    // The determined sums (a held GICP pose's noise terms) are the scene's without them.
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * b.abs().max(1e-300);
    assert!(got.determined_plane_sum_squares < got.plane_sum_squares);
    assert!(close(
        got.determined_plane_sum_squares,
        kept.plane_sum_squares
    ));
    assert_eq!(got.num_determined_blocks, kept.num_blocks);
    for (a, b) in got.determined_block_meat.iter().zip(&kept.block_meat) {
        assert!((a - b).abs() < 1e-12, "{a} vs {b}");
    }
    assert_eq!(all.determined_plane_sum_squares, all.plane_sum_squares);
    assert_eq!(all.determined_block_meat, all.block_meat);
    let short = [false; 2];
    let bad = Input {
        target_linear: Some(&short),
        ..with_normals(&src, &tgt, &nrm, &corr)
    };
    assert!(analyse(&bad, &pose, 2, &opts).is_err());
}

/// The lower-triangle outer products, mirrored, equal nalgebra's full `x xᵀ` sums to the bit,
/// and the counting sort gives the sorted pairs.
#[test]
fn lower_outer_products_and_pair_order_equal_the_full_forms() {
    let mut s = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64 * 20.0 - 10.0
    };
    let mut full = SMatrix::<f64, 6, 6>::zeros();
    let mut lower = SMatrix::<f64, 6, 6>::zeros();
    for _ in 0..500 {
        let x = SMatrix::<f64, 6, 3>::from_fn(|_, _| next());
        full += x * x.transpose();
        add_outer_lower(&mut lower, &x);
    }
    let bits = |m: &SMatrix<f64, 6, 6>| m.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&full), bits(&mirrored(lower)));
    let corr: Vec<u32> = (0..1000)
        .map(|_| {
            let v = next();
            if v < -8.0 {
                NONE
            } else {
                ((v + 10.0) * 3.0) as u32
            }
        })
        .collect();
    let mut want: Vec<(u32, u32)> = corr
        .iter()
        .enumerate()
        .filter(|(_, &j)| j != NONE)
        .map(|(i, &j)| (j, i as u32))
        .collect();
    want.sort_unstable();
    assert_eq!(pairs_by_target(&corr, 61), want);
}
