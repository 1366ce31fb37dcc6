//! Global 3D registration: the pose of one cloud in another with no initial guess.
//!
//! The pipeline, one idea per file:
//! 1. keypoints: a voxel grid of each cloud (centroids, [`crate::downsample`]), normals by
//!    k-NN PCA ([`crate::normals`]) oriented towards the centroid of the keypoint's FPFH
//!    neighbourhood (one radius search serves both): the side where the scene's mass lies
//!    (into a room, up from a road). The rule moves with the cloud and looks only nearby, so
//!    it survives a transform and a partial overlap; orienting towards the cloud's centroid
//!    does not survive cropping (on the 3DMatch pair 13 of 631 mutual matches were within a
//!    voxel of the truth with it; Open3D's normals give 21). Towards the centroid of the 150
//!    nearest keypoints gave 47 of 866 and the FPFH neighbourhood 37 of 963 (clique 80 vs
//!    64), at two fifths of the keypoint stage's time and the same results on the outdoor,
//!    KITTI and street pairs;
//! 2. [`fpfh`]: an FPFH descriptor per keypoint;
//! 3. [`correspondences`]: mutual nearest neighbours in descriptor space;
//! 4. [`pruning`]: the maximum clique of the pairwise length-consistency graph;
//! 5. [`gnc`]: GNC-TLS rotation + translation over the clique.
//!
//! Several hypotheses come from disjoint cliques (the next largest once the previous one's
//! vertices are removed): a repetitive scene (a corridor, a row of parked cars) has more than
//! one consistent set, and the caller's verification decides between them. Refinement and
//! the verdict are the Python layer's (`scanreg.register_global`).

pub mod correspondences;
pub mod fpfh;
pub mod gnc;
pub mod pruning;

use crate::downsample::{voxel_downsample, VoxelMethod};
use crate::error::{Error, Result};
use crate::knn::{canonical_order, KdTree};
use crate::normals::normal_from;
use crate::points::check_points;
use nalgebra::Vector3;
use rayon::prelude::*;
use std::time::Instant;

/// Fewest keypoints a cloud must keep after downsampling to be described at all.
pub const MIN_KEYPOINTS: usize = 10;
/// Smallest inlier set that defines a hypothesis (3 fix a pose; more rule out chance).
pub const MIN_CLIQUE: usize = 3;
/// The clique search of every hypothesis after the first gets the budget divided by this.
pub const LATER_BUDGET_DIVISOR: usize = 20;

/// Parameters of [`register_global`] (lengths in the units of the points).
#[derive(Debug, Clone, PartialEq)]
pub struct GlobalSettings {
    /// Voxel size of the keypoint grid.
    pub voxel_size: f64,
    /// Neighbours (keypoints) of the PCA that gives each normal.
    pub normal_neighbors: usize,
    /// Radius of the FPFH neighbourhood.
    pub feature_radius: f64,
    /// At most this many (nearest) neighbours inside `feature_radius`.
    pub max_feature_neighbors: usize,
    /// Largest distance of a correct correspondence after alignment (β).
    pub noise_bound: f64,
    /// Hypotheses to return at most.
    pub max_hypotheses: usize,
    /// Budget of the maximum-clique search, in bitset-word operations ([`pruning`]).
    pub clique_search_budget: usize,
}

/// One candidate pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Hypothesis {
    /// `T_target_source`, row-major 4x4.
    pub pose: [f64; 16],
    /// Correspondences in the clique it was solved from.
    pub clique_size: usize,
    /// Correspondences (of all) within the noise bound at `pose`.
    pub num_inliers: usize,
    /// Whether the clique search finished within its budget (the clique is maximum).
    pub exact: bool,
}

/// Keypoints of one cloud and their descriptors.
#[derive(Debug, Clone, PartialEq)]
pub struct Keypoints {
    /// `M * 3` voxel centroids.
    pub points: Vec<f64>,
    /// `M * 33` FPFH descriptors.
    pub descriptors: Vec<f32>,
    /// Whether each keypoint has a descriptor (a normal and a neighbour).
    pub valid: Vec<bool>,
}

/// Time of each stage of [`register_global`], seconds (both clouds together where a stage
/// runs on both: they run side by side).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StageSeconds {
    /// Voxel grid, k-d tree, normals and their orientation.
    pub keypoints: f64,
    /// FPFH descriptors.
    pub descriptors: f64,
    /// Mutual nearest neighbours in descriptor space.
    pub matching: f64,
    /// Consistency graph and maximum cliques.
    pub pruning: f64,
    /// GNC-TLS and the inlier count of each clique.
    pub solve: f64,
}

/// Result of [`register_global`].
#[derive(Debug, Clone, PartialEq)]
pub struct GlobalRegistration {
    /// Best first: by inlier count, then clique size.
    pub hypotheses: Vec<Hypothesis>,
    pub source: Keypoints,
    pub target: Keypoints,
    /// Mutual nearest-neighbour pairs `(source keypoint, target keypoint)`.
    pub correspondences: Vec<(u32, u32)>,
    pub seconds: StageSeconds,
    /// The process's CPU time per stage (every thread's; NaN where the platform has no
    /// such clock): on a shared machine the wall time also counts other jobs' turns.
    pub cpu_seconds: StageSeconds,
}

/// CPU seconds the whole process has used (all threads), NaN where unavailable.
fn process_cpu_seconds() -> f64 {
    #[cfg(unix)]
    {
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: `ts` is a valid, writable timespec; the call only writes to it.
        if unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) } == 0 {
            return ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9;
        }
    }
    f64::NAN
}

/// `(wall, cpu)` seconds.
type Lap = (f64, f64);

/// Wall and process-CPU stopwatch of one stage.
#[derive(Clone, Copy)]
struct Clock {
    wall: Instant,
    cpu: f64,
}

impl Clock {
    fn start() -> Self {
        Clock {
            wall: Instant::now(),
            cpu: process_cpu_seconds(),
        }
    }

    /// `(wall, cpu)` seconds since [`Clock::start`].
    fn elapsed(&self) -> Lap {
        (
            self.wall.elapsed().as_secs_f64(),
            process_cpu_seconds() - self.cpu,
        )
    }
}

fn check_settings(s: &GlobalSettings) -> Result<()> {
    for (name, v) in [
        ("voxel_size", s.voxel_size),
        ("feature_radius", s.feature_radius),
        ("noise_bound", s.noise_bound),
    ] {
        if !v.is_finite() || v <= 0.0 {
            return Err(Error::invalid(
                name,
                format!("must be finite and > 0, got {v}"),
            ));
        }
    }
    if s.normal_neighbors < 3 {
        return Err(Error::invalid(
            "normal_neighbors",
            format!("must be >= 3 to fit a plane, got {}", s.normal_neighbors),
        ));
    }
    for (name, v) in [
        ("max_feature_neighbors", s.max_feature_neighbors),
        ("max_hypotheses", s.max_hypotheses),
        ("clique_search_budget", s.clique_search_budget),
    ] {
        if v == 0 {
            return Err(Error::invalid(name, "must be >= 1"));
        }
    }
    Ok(())
}

/// One cloud's keypoints before description: the voxel centroids' index, oriented normals
/// and each one's FPFH neighbourhood.
struct Oriented {
    tree: KdTree,
    normals: Vec<f64>,
    neighbourhoods: Vec<Vec<(u32, f64)>>,
}

/// Downsample and orient normals (stage 1 of the module docs).
fn oriented(arg: &'static str, points: &[f64], s: &GlobalSettings) -> Result<Oriented> {
    let n = check_points(arg, points, 3)?;
    let grid = voxel_downsample(points, 3, s.voxel_size, VoxelMethod::Centroid)?;
    let m = grid.index.len();
    if m < MIN_KEYPOINTS {
        return Err(Error::invalid(
            arg,
            format!(
                "too small for descriptors: {n} points leave {m} keypoints at voxel_size {} \
                 (at least {MIN_KEYPOINTS} needed); pass a smaller voxel_size",
                s.voxel_size
            ),
        ));
    }
    let tree = KdTree::build(&grid.points, 3)?;
    let mut centroid = [0.0; 3];
    for p in grid.points.chunks_exact(3) {
        for c in 0..3 {
            centroid[c] += p[c] / m as f64;
        }
    }
    let (mut normals, neighbourhoods) = normals_and_neighbourhoods(
        &tree,
        s.normal_neighbors.min(m),
        &centroid,
        s.feature_radius,
        s.max_feature_neighbors,
    );
    orient_locally(
        &tree,
        &mut normals,
        &neighbourhoods,
        &centroid,
        s.voxel_size,
    );
    Ok(Oriented {
        tree,
        normals,
        neighbourhoods,
    })
}

/// A keypoint's radius neighbourhood: the same points as [`fpfh::neighbourhoods`] gives, in
/// the tree's order (nothing downstream depends on their order but the last bits of sums).
type Neighbourhood = Vec<(u32, f64)>;

/// What [`crate::normals::local_geometry`] (normals from the `k` nearest, towards
/// `viewpoint`) and then [`fpfh::neighbourhoods`] give, from one radius search per point:
/// its `k` nearest by (squared distance, index), in that order, are the k-NN search's
/// whenever the radius holds that many (a k-NN search only where it does not). The two
/// searches had cost a fifth of the core's time. The search is left unsorted and only the `k`
/// nearest are put in order (and the `max_neighbors` nearest picked, when there are more):
/// sorting every neighbourhood of ~80 points had been 8 % of the core's time on the 3DMatch
/// pair.
fn normals_and_neighbourhoods(
    tree: &KdTree,
    k: usize,
    viewpoint: &[f64; 3],
    radius: f64,
    max_neighbors: usize,
) -> (Vec<f64>, Vec<Neighbourhood>) {
    let sq = radius * radius;
    let (normals, found): (Vec<[f64; 3]>, Vec<Neighbourhood>) = (0..tree.len())
        .into_par_iter()
        .map_init(Vec::new, |knn, i| {
            let p = tree.point(i);
            let mut within = Vec::new();
            tree.radius_unsorted_into(p, sq, &mut within);
            let normal = if within.len() >= k {
                if within.len() > k {
                    within.select_nth_unstable_by(k - 1, canonical_order);
                }
                within[..k].sort_unstable_by(canonical_order);
                normal_from(tree, p, &within[..k], viewpoint)
            } else {
                knn.clear();
                tree.knn_into(p, k, f64::INFINITY, knn);
                normal_from(tree, p, knn, viewpoint)
            };
            (normal, within)
        })
        .unzip();
    let flat: Vec<f64> = normals.iter().flatten().copied().collect();
    let valid = fpfh::has_normal(&flat);
    let neighbourhoods = found
        .into_par_iter()
        .enumerate()
        .map(|(i, within)| {
            if !valid[i] {
                return Vec::new();
            }
            let mut kept: Vec<(u32, f64)> = within
                .into_iter()
                .filter(|&(j, _)| j as usize != i && valid[j as usize])
                .collect();
            if kept.len() > max_neighbors {
                kept.select_nth_unstable_by(max_neighbors - 1, canonical_order);
                kept.truncate(max_neighbors);
            }
            kept.into_iter().map(|(j, d2)| (j, d2.sqrt())).collect()
        })
        .collect();
    (flat, neighbourhoods)
}

fn describe(o: Oriented) -> Result<Keypoints> {
    let (descriptors, valid) = fpfh::fpfh_from(&o.tree, &o.normals, &o.neighbourhoods);
    Ok(Keypoints {
        points: o.tree.points().to_vec(),
        descriptors,
        valid,
    })
}

/// Downsample, orient normals and describe one cloud.
pub fn keypoints(arg: &'static str, points: &[f64], s: &GlobalSettings) -> Result<Keypoints> {
    describe(oriented(arg, points, s)?)
}

/// Flip each normal towards the centroid of its FPFH neighbourhood (and itself); where that
/// centroid lies in the tangent plane (an isolated flat patch), towards the cloud's
/// `centroid` instead.
fn orient_locally(
    tree: &KdTree,
    normals: &mut [f64],
    neighbourhoods: &[Vec<(u32, f64)>],
    centroid: &[f64; 3],
    voxel_size: f64,
) {
    normals
        .par_chunks_mut(3)
        .zip(neighbourhoods.par_iter())
        .enumerate()
        .for_each(|(i, (n, nb))| {
            let p = tree.point(i);
            let mut lc = [p[0], p[1], p[2]];
            for &(j, _) in nb {
                let q = tree.point(j as usize);
                for c in 0..3 {
                    lc[c] += q[c];
                }
            }
            lc.iter_mut().for_each(|v| *v /= (nb.len() + 1) as f64);
            let side = |to: &[f64; 3]| (0..3).map(|c| n[c] * (to[c] - p[c])).sum::<f64>();
            let mut facing = side(&lc);
            if facing.abs() < 1e-3 * voxel_size {
                facing = side(centroid);
            }
            if facing < 0.0 {
                n.iter_mut().for_each(|v| *v = -*v);
            }
        });
}

/// Hypotheses from paired points (`source[i] ↔ target[i]`, `N * 3` each): successive
/// disjoint maximum cliques of the consistency graph with tolerance `2 β`, each solved by
/// GNC-TLS, ranked by inlier count over all pairs. Cliques smaller than [`MIN_CLIQUE`] or
/// with no determined rotation (collinear) give no hypothesis.
pub fn solve_correspondences(
    source: &[f64],
    target: &[f64],
    noise_bound: f64,
    max_hypotheses: usize,
    clique_search_budget: usize,
) -> Result<Vec<Hypothesis>> {
    solve_timed(
        source,
        target,
        noise_bound,
        max_hypotheses,
        clique_search_budget,
    )
    .map(|(h, _, _)| h)
}

/// [`solve_correspondences`] and the `(wall, cpu)` seconds it spent pruning and solving.
fn solve_timed(
    source: &[f64],
    target: &[f64],
    noise_bound: f64,
    max_hypotheses: usize,
    clique_search_budget: usize,
) -> Result<(Vec<Hypothesis>, Lap, Lap)> {
    let n = check_points("source", source, 3)?;
    let nt = check_points("target", target, 3)?;
    if n != nt {
        return Err(Error::invalid(
            "target",
            format!("expected {n} points to pair with source, got {nt}"),
        ));
    }
    if !noise_bound.is_finite() || noise_bound <= 0.0 {
        return Err(Error::invalid(
            "noise_bound",
            format!("must be finite and > 0, got {noise_bound}"),
        ));
    }
    let mut t_prune = (0.0, 0.0);
    let mut t_solve = (0.0, 0.0);
    let add = |acc: &mut (f64, f64), (w, c): (f64, f64)| {
        acc.0 += w;
        acc.1 += c;
    };
    let clock = Clock::start();
    let graph = pruning::consistency_graph(source, target, 2.0 * noise_bound);
    add(&mut t_prune, clock.elapsed());
    let vec3 = |p: &[f64], i: usize| Vector3::new(p[3 * i], p[3 * i + 1], p[3 * i + 2]);
    let all_s: Vec<Vector3<f64>> = (0..n).map(|i| vec3(source, i)).collect();
    let all_t: Vec<Vector3<f64>> = (0..n).map(|i| vec3(target, i)).collect();
    let mut active = vec![true; n];
    let mut out = Vec::new();
    for k in 0..max_hypotheses {
        let clock = Clock::start();
        // The runner-up cliques lie among the first one's outliers, where proving a clique
        // maximum is the expensive part of the search (most of the pruning time on the
        // outdoor and KITTI pairs); a rival that matters is large and found early, so they
        // get a fraction of the budget.
        let budget = if k == 0 {
            clique_search_budget
        } else {
            (clique_search_budget / LATER_BUDGET_DIVISOR).max(1)
        };
        let (clique, exact) = pruning::max_clique(&graph, &active, budget);
        add(&mut t_prune, clock.elapsed());
        if clique.len() < MIN_CLIQUE {
            break;
        }
        for &v in &clique {
            active[v] = false;
        }
        let clock = Clock::start();
        let cs: Vec<_> = clique.iter().map(|&i| all_s[i]).collect();
        let ct: Vec<_> = clique.iter().map(|&i| all_t[i]).collect();
        let Some(sol) = gnc::gnc_tls(&cs, &ct, noise_bound, 100) else {
            add(&mut t_solve, clock.elapsed());
            continue;
        };
        let (r, t) = (sol.rotation, sol.translation);
        let b2 = noise_bound * noise_bound;
        let num_inliers = all_s
            .iter()
            .zip(&all_t)
            .filter(|(s, q)| (r * *s + t - *q).norm_squared() <= b2)
            .count();
        let pose = [
            r[(0, 0)],
            r[(0, 1)],
            r[(0, 2)],
            t[0],
            r[(1, 0)],
            r[(1, 1)],
            r[(1, 2)],
            t[1],
            r[(2, 0)],
            r[(2, 1)],
            r[(2, 2)],
            t[2],
            0.0,
            0.0,
            0.0,
            1.0,
        ];
        out.push(Hypothesis {
            pose,
            clique_size: clique.len(),
            num_inliers,
            exact,
        });
        add(&mut t_solve, clock.elapsed());
    }
    // Stable: equal counts keep the order of discovery (larger clique first).
    out.sort_by(|a, b| {
        b.num_inliers
            .cmp(&a.num_inliers)
            .then(b.clique_size.cmp(&a.clique_size))
    });
    Ok((out, t_prune, t_solve))
}

/// Global registration of `source` to `target` (`N * 3`, `M * 3`): see the module docs.
pub fn register_global(
    source: &[f64],
    target: &[f64],
    s: &GlobalSettings,
) -> Result<GlobalRegistration> {
    check_settings(s)?;
    let mut seconds = StageSeconds::default();
    let mut cpu_seconds = StageSeconds::default();
    let clock = Clock::start();
    let (src, tgt) = rayon::join(
        || oriented("source", source, s),
        || oriented("target", target, s),
    );
    let (src, tgt) = (src?, tgt?);
    (seconds.keypoints, cpu_seconds.keypoints) = clock.elapsed();
    let clock = Clock::start();
    let (src, tgt) = rayon::join(|| describe(src), || describe(tgt));
    let (src, tgt) = (src?, tgt?);
    (seconds.descriptors, cpu_seconds.descriptors) = clock.elapsed();
    let clock = Clock::start();
    let pairs = correspondences::mutual_nearest(
        &src.descriptors,
        &src.valid,
        &tgt.descriptors,
        &tgt.valid,
        fpfh::FPFH_DIM,
    );
    (seconds.matching, cpu_seconds.matching) = clock.elapsed();
    let mut ps = Vec::with_capacity(pairs.len() * 3);
    let mut pt = Vec::with_capacity(pairs.len() * 3);
    for &(i, j) in &pairs {
        ps.extend_from_slice(&src.points[3 * i as usize..3 * i as usize + 3]);
        pt.extend_from_slice(&tgt.points[3 * j as usize..3 * j as usize + 3]);
    }
    let (hypotheses, t_prune, t_solve) = solve_timed(
        &ps,
        &pt,
        s.noise_bound,
        s.max_hypotheses,
        s.clique_search_budget,
    )?;
    (seconds.pruning, cpu_seconds.pruning) = t_prune;
    (seconds.solve, cpu_seconds.solve) = t_solve;
    Ok(GlobalRegistration {
        hypotheses,
        source: src,
        target: tgt,
        correspondences: pairs,
        seconds,
        cpu_seconds,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lie::se3_exp;

    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*state >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn clique_then_gnc_survives_95_percent_outliers() {
        let truth = se3_exp(Vector3::new(3.0, -2.0, 0.5), Vector3::new(-0.4, 2.1, 1.0));
        let mut st = 11u64;
        let (mut s, mut q) = (Vec::new(), Vec::new());
        for i in 0..1000 {
            let p = Vector3::new(lcg(&mut st), lcg(&mut st), lcg(&mut st)) * 20.0;
            let r = if i % 20 == 0 {
                truth.apply(p)
                    + (Vector3::new(lcg(&mut st), lcg(&mut st), lcg(&mut st))
                        - Vector3::repeat(0.5))
                        * 0.05
            } else {
                Vector3::new(lcg(&mut st), lcg(&mut st), lcg(&mut st)) * 20.0
            };
            s.extend_from_slice(p.as_slice());
            q.extend_from_slice(r.as_slice());
        }
        let h = solve_correspondences(&s, &q, 0.1, 3, 50_000_000).unwrap();
        let best = &h[0];
        assert!(best.exact);
        assert!((45..=60).contains(&best.num_inliers), "{best:?}");
        let err_t = ((best.pose[3] - truth.t[0]).powi(2)
            + (best.pose[7] - truth.t[1]).powi(2)
            + (best.pose[11] - truth.t[2]).powi(2))
        .sqrt();
        assert!(err_t < 0.05, "{best:?} {truth:?}");
    }

    #[test]
    fn a_tiny_cloud_is_refused_by_name() {
        let pts: Vec<f64> = (0..15).map(|i| i as f64).collect();
        let s = GlobalSettings {
            voxel_size: 0.1,
            normal_neighbors: 10,
            feature_radius: 0.5,
            max_feature_neighbors: 100,
            noise_bound: 0.1,
            max_hypotheses: 3,
            clique_search_budget: 1000,
        };
        let e = register_global(&pts, &pts, &s).unwrap_err();
        assert!(e.to_string().starts_with("source: too small"), "{e}");
    }

    #[test]
    fn one_radius_search_gives_the_knn_normals_and_the_fpfh_neighbourhoods() {
        let mut st = 3u64;
        let mut pts = Vec::new();
        for _ in 0..600 {
            let (x, y) = (lcg(&mut st) * 4.0, lcg(&mut st) * 4.0);
            // A wavy sheet plus a few stray points (sparse spots fall back to k-NN).
            let z = if lcg(&mut st) < 0.05 {
                lcg(&mut st) * 3.0
            } else {
                (x * 1.7).sin() * 0.4
            };
            pts.extend_from_slice(&[x, y, z]);
        }
        let tree = KdTree::build(&pts, 3).unwrap();
        let centroid = [2.0, 2.0, 0.0];
        for radius in [0.15, 0.4, 0.9] {
            let (normals, nbrs) = normals_and_neighbourhoods(&tree, 20, &centroid, radius, 50);
            let geo = crate::normals::local_geometry(&tree, 20, &centroid, true, None).unwrap();
            assert_eq!(normals, geo.normals.unwrap());
            let valid = fpfh::has_normal(&normals);
            // The same points (in the tree's order, not sorted).
            let sorted: Vec<_> = nbrs
                .into_iter()
                .map(|mut v| {
                    v.sort_unstable_by(canonical_order);
                    v
                })
                .collect();
            assert_eq!(sorted, fpfh::neighbourhoods(&tree, &valid, radius, 50));
        }
    }
}
