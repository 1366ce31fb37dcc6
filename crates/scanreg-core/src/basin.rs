//! The wrong-basin probe's outcome comparison (`scanreg.basin.probe_basin`): which of the
//! restarts' poses came back to the result, which an alternative the result's covariance
//! already covers, and for the rest — the distinct outcomes — the offset from the result and
//! the fraction of the source they explain within the tight gate. One pass over the outcomes
//! instead of a relative pose, a logarithm, a χ² and a nearest-neighbour call per outcome in
//! Python (those were about a fifth of a restarted probe's cost on 2D Intel pairs).

use crate::correlative::{match_branch_and_bound, LikelihoodGrid, Window};
use crate::error::{Error, Result};
use crate::icp::{Home, NeighborSearch, Outcome, Restarts, Settings, Source, StopReason, Target};
use crate::lie::{se2_log, se3_log};
use crate::points::{check_points, split_pose};
use nalgebra::{DMatrix, Matrix3, Vector3};

/// What an outcome is, relative to the result.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// The restart failed (its stop reason was neither converged nor max_iterations).
    Failed = 0,
    /// Within half the tight gate and 1° of the result: the result itself.
    Back = 1,
    /// Further away, but inside the result's covariance (χ² ≤ `chi2`): the same answer.
    Covered = 2,
    /// A distinct outcome: its offset and fraction are reported.
    Distinct = 3,
}

/// Per outcome, in the order given.
#[derive(Debug, Clone, PartialEq)]
pub struct Outcomes {
    pub kinds: Vec<Kind>,
    /// `log(result⁻¹ · pose)` per outcome (`dof` values each, translation first); zeros for
    /// a failed outcome.
    pub offsets: Vec<f64>,
    /// Fraction of the source within the tight gate of a target point at the outcome (NaN
    /// unless distinct).
    pub fractions: Vec<f64>,
}

/// `vᵀ A⁺ v` for the pseudo-inverse of the symmetric `a` (`dof × dof`, row-major), the
/// eigenvalues below `1e-15 · max |λ|` dropped (numpy's `pinv(hermitian=True)` cut-off).
fn pinv_quadratic(info: &DMatrix<f64>, e: &[f64]) -> f64 {
    let n = e.len();
    let mut s = 0.0;
    for i in 0..n {
        let mut row = 0.0;
        for j in 0..n {
            row += info[(i, j)] * e[j];
        }
        s += e[i] * row;
    }
    s
}

fn pseudo_inverse(cov: &[f64], dof: usize) -> DMatrix<f64> {
    let a = DMatrix::from_row_slice(dof, dof, cov);
    let a = (&a + a.transpose()) * 0.5;
    let eig = a.symmetric_eigen();
    let largest = eig.eigenvalues.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let cutoff = 1e-15 * largest;
    let mut out = DMatrix::<f64>::zeros(dof, dof);
    for (k, &l) in eig.eigenvalues.iter().enumerate() {
        if l.abs() > cutoff {
            let v = eig.eigenvectors.column(k);
            out += (v * v.transpose()) / l;
        }
    }
    out
}

/// Source points (flat, `dim` per point) moved by `(r, t)` (row-major) with a target point
/// within `max_sq` (squared, inclusive): `overlap`'s `num_found`, without its statistics (each
/// query stops at the first point inside the gate instead of looking on for the nearest).
pub fn within(
    search: &dyn NeighborSearch,
    source: &[f64],
    r: &[f64],
    t: &[f64],
    max_sq: f64,
) -> usize {
    use rayon::prelude::*;
    let dim = t.len();
    let hit = |p: &[f64]| {
        let mut q = [0.0; 3];
        for (row, out) in q.iter_mut().enumerate().take(dim) {
            *out = (0..dim).map(|c| p[c] * r[row * dim + c]).sum::<f64>() + t[row];
        }
        search.any_within(&q[..dim], max_sq)
    };
    // A count: the same for any split of the work.
    if source.len() / dim.max(1) <= PARALLEL_MIN_POINTS {
        source.chunks_exact(dim).filter(|p| hit(p)).count()
    } else {
        source
            .par_chunks_exact(dim)
            .with_min_len(PARALLEL_MIN_POINTS)
            .filter(|p| hit(p))
            .count()
    }
}

/// Below this many source points [`within`] runs on the calling thread (a 2D scan).
const PARALLEL_MIN_POINTS: usize = 2048;

/// The comparison of the restarts' outcomes with the result (see [`Kind`]), one outcome at a
/// time, in order: an outcome equal to an earlier distinct one reuses its overlap.
/// `tight`: the probe's tight gate (finite, > 0); `covariance`: the result's (`dof × dof`,
/// row-major), `None` when it is not finite (then only the fixed distances decide); `chi2`:
/// the χ² bound of "inside the covariance".
struct Classifier<'a> {
    search: &'a dyn NeighborSearch,
    source: &'a [f64],
    n: usize,
    dim: usize,
    dof: usize,
    m: usize,
    rr: Vec<f64>,
    rt: Vec<f64>,
    tight: f64,
    covariance: Option<&'a [f64]>,
    chi2: f64,
    // The pseudo-inverse only when an outcome did not come back (most do).
    info: Option<DMatrix<f64>>,
    poses: Vec<f64>,
    out: Outcomes,
}

impl<'a> Classifier<'a> {
    fn new(
        search: &'a dyn NeighborSearch,
        source: &'a [f64],
        result: &[f64],
        tight: f64,
        covariance: Option<&'a [f64]>,
        chi2: f64,
    ) -> Result<Self> {
        let dim = search.dim();
        let dof = if dim == 2 { 3 } else { 6 };
        let n = check_points("source", source, dim)?;
        if n == 0 {
            return Err(Error::invalid("source", "no points"));
        }
        let (rr, rt) = split_pose("result", result, dim)?;
        if !(tight.is_finite() && tight > 0.0) {
            return Err(Error::invalid(
                "tight",
                format!("must be finite and > 0, got {tight}"),
            ));
        }
        if let Some(c) = covariance {
            if c.len() != dof * dof || c.iter().any(|v| !v.is_finite()) {
                return Err(Error::invalid(
                    "covariance",
                    format!("expected {dof}x{dof} finite values, got {}", c.len()),
                ));
            }
        }
        Ok(Classifier {
            search,
            source,
            n,
            dim,
            dof,
            m: (dim + 1) * (dim + 1),
            rr: rr.to_vec(),
            rt: rt.to_vec(),
            tight,
            covariance,
            chi2,
            info: None,
            poses: Vec::new(),
            out: Outcomes {
                kinds: Vec::new(),
                offsets: Vec::new(),
                fractions: Vec::new(),
            },
        })
    }

    /// Classify the next outcome (`usable`: converged or at its iteration cap); its kind.
    fn push(&mut self, pose: &[f64], usable: bool) -> Result<Kind> {
        let (dim, dof, m) = (self.dim, self.dof, self.m);
        let k = self.out.kinds.len();
        self.poses.extend_from_slice(pose);
        self.out.offsets.extend(std::iter::repeat_n(0.0, dof));
        self.out.fractions.push(f64::NAN);
        let kind = self.kind(pose, usable)?;
        self.out.kinds.push(kind);
        if kind == Kind::Distinct {
            // Several restarts often land on the same pose: one overlap pass for them.
            let same = (0..k).find(|&j| {
                self.out.kinds[j] == Kind::Distinct && self.poses[j * m..(j + 1) * m] == *pose
            });
            self.out.fractions[k] = match same {
                Some(j) => self.out.fractions[j],
                None => {
                    let (pr, pt) = split_pose("poses", pose, dim)?;
                    let tight = self.tight;
                    within(self.search, self.source, &pr, &pt, tight * tight) as f64 / self.n as f64
                }
            };
        }
        Ok(kind)
    }

    fn kind(&mut self, pose: &[f64], usable: bool) -> Result<Kind> {
        let (dim, dof) = (self.dim, self.dof);
        let k = self.out.kinds.len();
        if !usable {
            return Ok(Kind::Failed);
        }
        let (rr, rt) = (&self.rr, &self.rt);
        let (pr, pt) = split_pose("poses", pose, dim)?;
        let cos_1deg = 1.0f64.to_radians().cos();
        let one_deg = 1.0f64.to_radians();
        let half = 0.5 * self.tight;
        let offsets = &mut self.out.offsets[k * dof..(k + 1) * dof];
        // rel = result⁻¹ · pose: (Rᵀ R_k, Rᵀ (t_k − t)).
        let e: Vec<f64> = if dim == 2 {
            let rot = |i: usize, j: usize| rr[i] * pr[j] + rr[2 + i] * pr[2 + j];
            let r = [rot(0, 0), rot(0, 1), rot(1, 0), rot(1, 1)];
            let d = [pt[0] - rt[0], pt[1] - rt[1]];
            let t = [rr[0] * d[0] + rr[2] * d[1], rr[1] * d[0] + rr[3] * d[1]];
            let cos = (r[0] + r[3]) / 2.0;
            offsets.copy_from_slice(&se2_log(r, t));
            if (t[0] * t[0] + t[1] * t[1]).sqrt() <= half && cos >= cos_1deg {
                return Ok(Kind::Back);
            }
            offsets.to_vec()
        } else {
            let ra = Matrix3::from_row_slice(rr);
            let rb = Matrix3::from_row_slice(&pr);
            let r = ra.transpose() * rb;
            let t = ra.transpose() * (Vector3::from_row_slice(&pt) - Vector3::from_row_slice(rt));
            let cos = (r.trace() - 1.0) / 2.0;
            offsets.copy_from_slice(&se3_log(r, t));
            if t.norm() <= half && cos >= cos_1deg {
                return Ok(Kind::Back);
            }
            offsets.to_vec()
        };
        let moved = e[..dim].iter().map(|v| v * v).sum::<f64>().sqrt();
        let turned = e[dim..].iter().map(|v| v * v).sum::<f64>().sqrt();
        if moved <= half && turned <= one_deg {
            return Ok(Kind::Back);
        }
        if let Some(c) = self.covariance {
            let inf = self.info.get_or_insert_with(|| pseudo_inverse(c, dof));
            if pinv_quadratic(inf, &e) <= self.chi2 {
                return Ok(Kind::Covered);
            }
        }
        Ok(Kind::Distinct)
    }
}

/// The probe's correlative start (2D): a coarse search of `grid` around the result, every
/// `stride`-th source point, `±half_width` cells each way and `±ntheta` steps of
/// `angular_step` (see `scanreg.basin`).
pub struct CorrelativeStart<'a> {
    pub grid: &'a LikelihoodGrid,
    pub stride: usize,
    pub half_width: i64,
    pub ntheta: i64,
    pub angular_step: f64,
}

/// What stops the restarts: the first *far* distinct outcome (beyond `near_move` or
/// `near_turn` of the result) that is not ruled out by `implausible` and explains more than
/// `stop_ratio` times `here` (the result's own tight-gate fraction) settles the verdict
/// (`scanreg.basin.probe_basin` reads the outcomes in the same order and stops there too).
pub struct Stop<'a> {
    pub here: f64,
    pub stop_ratio: f64,
    pub near_move: f64,
    pub near_turn: f64,
    pub implausible: Option<Implausible<'a>>,
}

/// A stated uncertainty of the start: an outcome beyond `chi2` of `start` under
/// `information` (`dof × dof`, row-major) is no rival.
pub struct Implausible<'a> {
    pub start: &'a [f64],
    pub information: &'a [f64],
    pub chi2: f64,
}

/// [`probe_restarts`]'s answer: the outcomes compared with the result (see [`Kind`]), up to
/// and including the one that stopped the probe, and their poses (`K` row-major homogeneous
/// matrices, the correlative start's outcome first).
#[derive(Debug, Clone, PartialEq)]
pub struct Probe {
    pub outcomes: Outcomes,
    pub poses: Vec<f64>,
}

/// The whole restart path of the wrong-basin probe in one call: the correlative start (when
/// given), the registration from it and from each of `starts` (`home` stops a solve that
/// comes back to the result, see [`icp::Home`]), each outcome compared with the result as it
/// arrives (see [`Kind`]), and no more restarts once one settles the verdict ([`Stop`]). The
/// solves run in waves of the pool's size, read in order: the outcomes (and where the probe
/// stops) are the same for any thread count.
#[allow(clippy::too_many_arguments)]
pub fn probe_restarts(
    source: &Source<'_>,
    target: &Target<'_>,
    settings: &Settings,
    result: &[f64],
    starts: &[f64],
    correlative: Option<&CorrelativeStart<'_>>,
    home_radius: f64,
    home_cos_angle: f64,
    tight: f64,
    covariance: Option<&[f64]>,
    chi2: f64,
    stop: &Stop<'_>,
) -> Result<Probe> {
    use rayon::prelude::*;
    let search = target.search;
    let dim = search.dim();
    let dof = if dim == 2 { 3 } else { 6 };
    let mut c = Classifier::new(search, source.points, result, tight, covariance, chi2)?;
    let m = c.m;
    if !starts.len().is_multiple_of(m) {
        return Err(Error::invalid(
            "init_poses",
            format!("expected a multiple of {m} values, got {}", starts.len()),
        ));
    }
    for init in starts.chunks_exact(m) {
        split_pose("init_poses", init, dim)?;
    }
    if let Some(imp) = &stop.implausible {
        split_pose("implausible_start", imp.start, dim)?;
        if imp.information.len() != dof * dof {
            return Err(Error::invalid(
                "implausible_information",
                format!("expected {dof}x{dof} values, got {}", imp.information.len()),
            ));
        }
    }
    let mut inits: Vec<f64> = Vec::with_capacity(starts.len() + m);
    if let Some(cs) = correlative {
        if dim != 2 {
            return Err(Error::invalid("grid", "a correlative start is 2D only"));
        }
        if cs.stride == 0 {
            return Err(Error::invalid("stride", "must be >= 1"));
        }
        let sub: Vec<f64> = source
            .points
            .chunks_exact(2)
            .step_by(cs.stride)
            .flatten()
            .copied()
            .collect();
        let window = Window {
            center: [result[2], result[5], result[3].atan2(result[0])],
            nx: cs.half_width,
            ny: cs.half_width,
            ntheta: cs.ntheta,
            angular_step: cs.angular_step,
            penalty: None,
        };
        let found = match_branch_and_bound(cs.grid, &sub, &window, 0)?;
        let [x, y, th] = found.pose;
        let (s, co) = th.sin_cos();
        inits.extend_from_slice(&[co, -s, x, s, co, y, 0.0, 0.0, 1.0]);
    }
    inits.extend_from_slice(starts);
    let home = Home {
        pose: result.to_vec(),
        radius: home_radius,
        cos_angle: home_cos_angle,
    };
    let solver = Restarts::new(source, target, settings, Some(&home))?;
    let wave = rayon::current_num_threads().max(1);
    let mut poses = Vec::with_capacity(inits.len());
    'waves: for chunk in inits.chunks(wave * m) {
        let outs: Vec<Outcome> = if wave == 1 {
            chunk.chunks_exact(m).map(|i| solver.solve(i)).collect()
        } else {
            chunk.par_chunks_exact(m).map(|i| solver.solve(i)).collect()
        };
        for out in outs {
            let usable = matches!(
                out.stop_reason,
                StopReason::Converged | StopReason::MaxIterations
            );
            let kind = c.push(&out.pose, usable)?;
            poses.extend_from_slice(&out.pose);
            if kind == Kind::Distinct && settles(&c, stop, &out.pose, dim)? {
                break 'waves;
            }
        }
    }
    Ok(Probe {
        outcomes: c.out,
        poses,
    })
}

/// Whether the last distinct outcome (at `pose`) settles the verdict (see [`Stop`]).
fn settles(c: &Classifier<'_>, stop: &Stop<'_>, pose: &[f64], dim: usize) -> Result<bool> {
    let k = c.out.kinds.len() - 1;
    let dof = c.dof;
    let e = &c.out.offsets[k * dof..(k + 1) * dof];
    let moved = e[..dim].iter().map(|v| v * v).sum::<f64>().sqrt();
    let turned = e[dim..].iter().map(|v| v * v).sum::<f64>().sqrt();
    if moved <= stop.near_move && turned <= stop.near_turn {
        return Ok(false);
    }
    if let Some(imp) = &stop.implausible {
        let (sr, st) = split_pose("implausible_start", imp.start, dim)?;
        let (pr, pt) = split_pose("poses", pose, dim)?;
        let d = relative_log(&sr, &st, &pr, &pt, dim);
        let info = DMatrix::from_row_slice(dof, dof, imp.information);
        if pinv_quadratic(&info, &d) > imp.chi2 {
            return Ok(false);
        }
    }
    let f = c.out.fractions[k];
    Ok(stop.here > 0.0 && f > stop.stop_ratio * stop.here)
}

/// `log(a⁻¹ · b)` of two row-major poses split into rotation and translation.
fn relative_log(ar: &[f64], at: &[f64], br: &[f64], bt: &[f64], dim: usize) -> Vec<f64> {
    if dim == 2 {
        let rot = |i: usize, j: usize| ar[i] * br[j] + ar[2 + i] * br[2 + j];
        let r = [rot(0, 0), rot(0, 1), rot(1, 0), rot(1, 1)];
        let d = [bt[0] - at[0], bt[1] - at[1]];
        let t = [ar[0] * d[0] + ar[2] * d[1], ar[1] * d[0] + ar[3] * d[1]];
        se2_log(r, t).to_vec()
    } else {
        let ra = Matrix3::from_row_slice(ar);
        let rb = Matrix3::from_row_slice(br);
        let r = ra.transpose() * rb;
        let t = ra.transpose() * (Vector3::from_row_slice(bt) - Vector3::from_row_slice(at));
        se3_log(r, t).to_vec()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::knn::KdTree;

    fn se2(x: f64, y: f64, th: f64) -> [f64; 9] {
        let (s, c) = th.sin_cos();
        [c, -s, x, s, c, y, 0.0, 0.0, 1.0]
    }

    /// The restarts' `poses` (flat, row-major) compared with `result` one by one, as the
    /// probe compares each as it arrives (`usable[k]`: restart `k` converged or hit its cap).
    #[allow(clippy::too_many_arguments)]
    fn compare_outcomes(
        search: &dyn NeighborSearch,
        source: &[f64],
        result: &[f64],
        poses: &[f64],
        usable: &[bool],
        tight: f64,
        covariance: Option<&[f64]>,
        chi2: f64,
    ) -> Result<Outcomes> {
        let mut c = Classifier::new(search, source, result, tight, covariance, chi2)?;
        let m = c.m;
        if !poses.len().is_multiple_of(m) || usable.len() != poses.len() / m {
            return Err(Error::invalid("usable", "expected one per pose"));
        }
        for (pose, &ok) in poses.chunks_exact(m).zip(usable) {
            c.push(pose, ok)?;
        }
        Ok(c.out)
    }

    #[test]
    fn outcomes_are_classified_and_measured() {
        // An L of points; the source is the target itself, the result the identity.
        let target: Vec<f64> = (0..40)
            .flat_map(|i| {
                if i < 20 {
                    [i as f64 * 0.1, 0.0]
                } else {
                    [0.0, (i - 19) as f64 * 0.1]
                }
            })
            .collect();
        let tree = KdTree::build(&target, 2).unwrap();
        let result = se2(0.0, 0.0, 0.0);
        let mut poses = Vec::new();
        poses.extend(se2(0.001, 0.0, 0.001)); // back
        poses.extend(se2(0.05, 0.0, 0.0)); // inside the covariance
        poses.extend(se2(0.0, 0.0, std::f64::consts::FRAC_PI_2)); // distinct
        poses.extend(se2(0.0, 0.0, std::f64::consts::FRAC_PI_2)); // the same pose again
        poses.extend(se2(9.0, 9.0, 0.0)); // failed
        let cov = [0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01];
        let o = compare_outcomes(
            &tree,
            &target,
            &result,
            &poses,
            &[true, true, true, true, false],
            0.02,
            Some(&cov),
            16.266,
        )
        .unwrap();
        use Kind::*;
        assert_eq!(o.kinds, vec![Back, Covered, Distinct, Distinct, Failed]);
        // The quarter turn maps the y leg onto −x (nothing there) and the x leg onto the y
        // leg: the 20 x-leg points (the corner among them) plus none of the rest.
        let expected = o.fractions[2];
        assert!(expected > 0.0 && expected < 1.0, "{expected}");
        assert_eq!(o.fractions[3], expected);
        assert!((o.offsets[2 * 3 + 2] - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!(o.fractions[0].is_nan() && o.fractions[4].is_nan());
        // Without a covariance the 5 cm move is distinct too.
        let o = compare_outcomes(
            &tree, &target, &result, &poses, &[true; 5], 0.02, None, 16.266,
        )
        .unwrap();
        assert_eq!(o.kinds[1], Distinct);
        assert!(
            compare_outcomes(&tree, &target, &result, &poses, &[true; 4], 0.02, None, 1.0).is_err()
        );
        assert!(
            compare_outcomes(&tree, &target, &result, &poses, &[true; 5], 0.0, None, 1.0).is_err()
        );
    }

    /// A 4 m × 3 m room outline (10 cm spacing) with a short inner wall: nothing repeats
    /// under a quarter turn, a half turn nearly does.
    fn room() -> Vec<f64> {
        let mut pts = Vec::new();
        let mut seg = |a: [f64; 2], b: [f64; 2]| {
            let n = (((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt() / 0.1).ceil() as usize;
            for s in 0..n {
                let t = s as f64 / n as f64;
                pts.extend([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]);
            }
        };
        seg([-2.0, -1.5], [2.0, -1.5]);
        seg([2.0, -1.5], [2.0, 1.5]);
        seg([2.0, 1.5], [-2.0, 1.5]);
        seg([-2.0, 1.5], [-2.0, -1.5]);
        seg([0.5, -1.5], [0.5, -0.7]);
        pts
    }

    #[test]
    fn probe_restarts_equals_the_solves_then_the_comparison_and_stops_early() {
        use crate::icp::{Method, Optimizer, Restarts};
        use crate::Kernel;
        let target = room();
        let tree = KdTree::build(&target, 2).unwrap();
        let src = Source {
            points: &target,
            covariances: None,
        };
        let tgt = Target {
            search: &tree,
            normals: None,
            covariances: None,
        };
        let settings = Settings {
            method: Method::PointToPoint,
            kernel: Kernel::None,
            max_correspondence_distance: 1.0,
            max_iterations: 6,
            translation_tolerance: 1e-6,
            rotation_tolerance: 1e-6,
            optimizer: Optimizer::GaussNewton,
            min_correspondences: 10,
            step_projector: None,
            extrapolate: true,
        };
        let result = se2(0.0, 0.0, 0.0);
        let pi = std::f64::consts::PI;
        let mut starts = Vec::new();
        starts.extend(se2(0.3, 0.0, 0.0)); // comes back
        starts.extend(se2(0.0, 0.0, pi)); // the half turn: far, explains nearly all of it
        starts.extend(se2(0.0, 0.1, 0.01)); // comes back
        let cov = [1e-4, 0.0, 0.0, 0.0, 1e-4, 0.0, 0.0, 0.0, 1e-4];
        let (tight, chi2) = (0.1, 16.266);
        let home = Home {
            pose: result.to_vec(),
            radius: 0.045,
            cos_angle: 0.9f64.to_radians().cos(),
        };
        let stop_at = |stop_ratio: f64, implausible: Option<Implausible<'static>>| Stop {
            here: 1.0,
            stop_ratio,
            near_move: 0.5,
            near_turn: 10f64.to_radians(),
            implausible,
        };
        let never = stop_at(f64::INFINITY, None);
        let run = |stop: &Stop<'_>| {
            probe_restarts(
                &src,
                &tgt,
                &settings,
                &result,
                &starts,
                None,
                home.radius,
                home.cos_angle,
                tight,
                Some(&cov),
                chi2,
                stop,
            )
            .unwrap()
        };
        // Without a stop: the same as the solves, then the comparison.
        let all = run(&never);
        let solver = Restarts::new(&src, &tgt, &settings, Some(&home)).unwrap();
        let outs: Vec<_> = starts.chunks_exact(9).map(|i| solver.solve(i)).collect();
        let poses: Vec<f64> = outs.iter().flat_map(|o| o.pose.clone()).collect();
        let usable: Vec<bool> = outs
            .iter()
            .map(|o| {
                matches!(
                    o.stop_reason,
                    StopReason::Converged | StopReason::MaxIterations
                )
            })
            .collect();
        let compared = compare_outcomes(
            &tree,
            &target,
            &result,
            &poses,
            &usable,
            tight,
            Some(&cov),
            chi2,
        )
        .unwrap();
        assert_eq!(all.poses, poses);
        assert_eq!(all.outcomes.kinds, compared.kinds);
        assert_eq!(all.outcomes.offsets, compared.offsets);
        for (a, b) in all.outcomes.fractions.iter().zip(&compared.fractions) {
            assert!(a == b || (a.is_nan() && b.is_nan()));
        }
        assert_eq!(
            all.outcomes.kinds,
            vec![Kind::Back, Kind::Distinct, Kind::Back]
        );
        assert!(
            all.outcomes.fractions[1] > 0.5,
            "{:?}",
            all.outcomes.fractions
        );
        // The half turn settles the verdict (it explains more than half the result's
        // fraction): the restart after it never runs.
        let stop = stop_at(0.5, None);
        let early = run(&stop);
        assert_eq!(early.outcomes.kinds, vec![Kind::Back, Kind::Distinct]);
        assert_eq!(early.poses[..], all.poses[..18]);
        // A stated start uncertainty that rules the half turn out: no stop.
        static INFO: [f64; 9] = [1e4, 0.0, 0.0, 0.0, 1e4, 0.0, 0.0, 0.0, 1e4];
        static START: [f64; 9] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        let ruled_out = stop_at(
            0.5,
            Some(Implausible {
                start: &START,
                information: &INFO,
                chi2,
            }),
        );
        assert_eq!(run(&ruled_out).outcomes.kinds.len(), 3);
        // Bad input is named.
        let bad = probe_restarts(
            &src,
            &tgt,
            &settings,
            &result,
            &starts[..5],
            None,
            0.0,
            1.0,
            tight,
            None,
            chi2,
            &never,
        );
        assert!(bad.unwrap_err().to_string().contains("init_poses"));
    }

    #[test]
    fn se3_log_matches_a_known_transform() {
        // A turn of 0.3 rad about z with ρ = (1, 0, 0): t = V(φ) ρ.
        let th: f64 = 0.3;
        let r = Matrix3::new(
            th.cos(),
            -th.sin(),
            0.0,
            th.sin(),
            th.cos(),
            0.0,
            0.0,
            0.0,
            1.0,
        );
        let (a, b) = (th.sin() / th, (1.0 - th.cos()) / th);
        let t = Vector3::new(a, b, 0.0);
        let e = se3_log(r, t);
        for (v, w) in e.iter().zip([1.0, 0.0, 0.0, 0.0, 0.0, th]) {
            assert!((v - w).abs() < 1e-12, "{e:?}");
        }
    }
}
