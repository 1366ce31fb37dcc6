use super::*;

/// Σ_i g_i at `pose` over fixed correspondences (the quantity whose z-derivative Censi needs).
fn total_score(input: &Input<'_>, opts: &Options, pose: &[f64]) -> SVector<f64, 3> {
    let r: SMatrix<f64, 2, 2> = SMatrix::from_fn(|i, j| pose[i * 3 + j]);
    let t: SVector<f64, 2> = SVector::from_fn(|i, _| pose[i * 3 + 2]);
    let mut g = SVector::<f64, 3>::zeros();
    for (i, &j) in input.correspondences.iter().enumerate() {
        if let Some(tm) = term::<Planar, 2, 3>(input, opts, &r, &t, i, j as usize) {
            g += tm.score;
        }
    }
    g
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

fn check_method(method: Method) {
    let (src, tgt, nrm, corr) = scene();
    let pose = [0.99, -0.141, 0.2, 0.141, 0.99, -0.1, 0.0, 0.0, 1.0];
    let (c, s) = (0.141f64.atan2(0.99).cos(), 0.141f64.atan2(0.99).sin());
    let pose = [c, -s, pose[2], s, c, pose[5], 0.0, 0.0, 1.0];
    let opts = Options {
        method,
        kernel: Kernel::from_name("none", 1.0).unwrap(),
        source_variance: 1.0,
        target_variance: 0.0,
        normal_variance: 0.0,
        block_size: f64::INFINITY,
    };
    let input = Input {
        source: &src,
        source_covariances: None,
        target: &tgt,
        target_normals: Some(&nrm),
        target_covariances: None,
        correspondences: &corr,
    };
    // Finite differences of Σ g over every source coordinate: (∂g/∂p)(∂g/∂p)ᵀ summed.
    let mut meat_fd = SMatrix::<f64, 3, 3>::zeros();
    let h = 1e-6;
    for c in 0..src.len() {
        let mut plus = src.clone();
        plus[c] += h;
        let mut minus = src.clone();
        minus[c] -= h;
        let gp = total_score(
            &Input {
                source: &plus,
                ..input
            },
            &opts,
            &pose,
        );
        let gm = total_score(
            &Input {
                source: &minus,
                ..input
            },
            &opts,
            &pose,
        );
        let d = (gp - gm) / (2.0 * h);
        meat_fd += d * d.transpose();
    }
    let out = analyse(&input, &pose, 2, &opts).unwrap();
    let meat = SMatrix::<f64, 3, 3>::from_row_slice(&out.censi_meat);
    assert!(
        (meat - meat_fd).norm() < 1e-5 * meat_fd.norm(),
        "{method:?}: {meat} vs {meat_fd}"
    );
    // Target noise: derivatives of the points sharing a target are summed before squaring.
    let opts_t = Options {
        source_variance: 0.0,
        target_variance: 1.0,
        ..opts
    };
    let mut meat_fd = SMatrix::<f64, 3, 3>::zeros();
    for c in 0..tgt.len() {
        let mut plus = tgt.clone();
        plus[c] += h;
        let mut minus = tgt.clone();
        minus[c] -= h;
        let gp = total_score(
            &Input {
                target: &plus,
                ..input
            },
            &opts_t,
            &pose,
        );
        let gm = total_score(
            &Input {
                target: &minus,
                ..input
            },
            &opts_t,
            &pose,
        );
        let d = (gp - gm) / (2.0 * h);
        meat_fd += d * d.transpose();
    }
    let out = analyse(&input, &pose, 2, &opts_t).unwrap();
    let meat = SMatrix::<f64, 3, 3>::from_row_slice(&out.censi_meat);
    assert!(
        (meat - meat_fd).norm() < 1e-5 * meat_fd.norm(),
        "{method:?} target: {meat} vs {meat_fd}"
    );
}

#[test]
fn normal_term_matches_finite_differences() {
    let (src, tgt, nrm, corr) = scene();
    let th = 0.141f64.atan2(0.99);
    let pose = [
        th.cos(),
        -th.sin(),
        0.2,
        th.sin(),
        th.cos(),
        -0.1,
        0.0,
        0.0,
        1.0,
    ];
    let opts = Options {
        method: Method::PointToPlane,
        kernel: Kernel::from_name("none", 1.0).unwrap(),
        source_variance: 0.0,
        target_variance: 0.0,
        normal_variance: 1.0,
        block_size: f64::INFINITY,
    };
    let input = Input {
        source: &src,
        source_covariances: None,
        target: &tgt,
        target_normals: Some(&nrm),
        target_covariances: None,
        correspondences: &corr,
    };
    // In 2D the normal turns about its one tangent t = (−n_y, n_x): Σ_n = t tᵀ.
    let mut meat_fd = SMatrix::<f64, 3, 3>::zeros();
    let h = 1e-6;
    for j in 0..tgt.len() / 2 {
        let t = [-nrm[2 * j + 1], nrm[2 * j]];
        let mut plus = nrm.clone();
        let mut minus = nrm.clone();
        for c in 0..2 {
            plus[2 * j + c] += h * t[c];
            minus[2 * j + c] -= h * t[c];
        }
        let gp = total_score(
            &Input {
                target_normals: Some(&plus),
                ..input
            },
            &opts,
            &pose,
        );
        let gm = total_score(
            &Input {
                target_normals: Some(&minus),
                ..input
            },
            &opts,
            &pose,
        );
        let d = (gp - gm) / (2.0 * h);
        meat_fd += d * d.transpose();
    }
    let out = analyse(&input, &pose, 2, &opts).unwrap();
    let meat = SMatrix::<f64, 3, 3>::from_row_slice(&out.censi_meat);
    assert!(
        (meat - meat_fd).norm() < 1e-5 * meat_fd.norm(),
        "{meat} vs {meat_fd}"
    );
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
    let input = Input {
        source: &src,
        source_covariances: None,
        target: &tgt,
        target_normals: Some(&nrm),
        target_covariances: None,
        correspondences: &corr,
    };
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
