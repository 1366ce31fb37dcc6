//! How much surface normals scatter, measured on the data: within one scan (a normal against
//! its nearest neighbour's) and between two scans (matched normals). These set the degeneracy
//! threshold and Censi's normal term; the Python side (`scanreg.degeneracy`) documents the
//! models. One call each instead of a dozen array operations per registration.

use crate::error::{Error, Result};
use crate::knn::KdTree;
use crate::normals::Scratch;
use crate::reduce::SEQUENTIAL_MAX;
use crate::symeig::{sym2, sym3};
use rayon::prelude::*;

/// A normal shorter than this (squared) marks a point without one.
const VALID_SQ: f64 = 0.25;

/// At most this many target points are sampled by [`target_normal_noise`].
const TARGET_SAMPLE: usize = 2000;

fn at(data: &[f64], i: usize, dim: usize) -> &[f64] {
    &data[i * dim..(i + 1) * dim]
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// `1 − cos²` of two unit vectors (`cos` clamped to 1).
fn sine_squared(a: &[f64], b: &[f64]) -> f64 {
    let c = dot(a, b).abs().min(1.0);
    1.0 - c * c
}

fn mean(values: &[f64]) -> f64 {
    values.iter().sum::<f64>() / values.len() as f64
}

/// [`median_sorted`] of `values` without sorting them (two selections: the same middle values,
/// so the same result to the bit); `values` is reordered. Non-empty.
fn median_in_place(values: &mut [f64]) -> f64 {
    let n = values.len();
    let (lower, &mut upper, _) = values.select_nth_unstable_by(n / 2, f64::total_cmp);
    if n % 2 == 1 {
        upper
    } else {
        let below = lower
            .iter()
            .copied()
            .max_by(f64::total_cmp)
            .unwrap_or(upper);
        (below + upper) / 2.0
    }
}

/// Median of ascending `sorted` (the mean of the middle two for an even count).
pub fn median_sorted(sorted: &[f64]) -> f64 {
    let n = sorted.len();
    if n % 2 == 1 {
        sorted[n / 2]
    } else {
        (sorted[n / 2 - 1] + sorted[n / 2]) / 2.0
    }
}

fn check_normals(normals: &[f64], n: usize, dim: usize) -> Result<()> {
    if normals.len() != n * dim {
        return Err(Error::invalid(
            "normals",
            format!("expected {n} x {dim} values, got {}", normals.len()),
        ));
    }
    // A point without a normal has a zero row; NaN would poison the statistics silently.
    check_finite("normals", normals)
}

fn check_finite(arg: &'static str, data: &[f64]) -> Result<()> {
    if data.iter().any(|v| !v.is_finite()) {
        return Err(Error::invalid(arg, "contains NaN or inf"));
    }
    Ok(())
}

/// `(ε̂², ε̃²)`: half the mean and half the median of `sin²` between each valid normal of the
/// tree's points and its nearest neighbour's (the second entry of a 2-NN query), over up to
/// 2000 evenly spaced valid points. `NaN` for both without two valid normals or a valid pair.
pub fn target_normal_noise(tree: &KdTree, normals: &[f64]) -> Result<(f64, f64)> {
    let dim = tree.dim();
    check_normals(normals, tree.len(), dim)?;
    let mut buf = Vec::with_capacity(3);
    Ok(noise_with_neighbour(normals, dim, |i| {
        buf.clear();
        tree.knn_into(tree.point(i), 2, f64::INFINITY, &mut buf);
        buf.get(1).map(|&(j, _)| j as usize)
    }))
}

/// [`target_normal_noise`] with each point's nearest neighbour given by `nearest(i)` (a map
/// that already knows it: `crate::keyframe_map`); `normals` are `N * dim`, checked.
pub(crate) fn noise_with_neighbour(
    normals: &[f64],
    dim: usize,
    mut nearest: impl FnMut(usize) -> Option<usize>,
) -> (f64, f64) {
    let nan = (f64::NAN, f64::NAN);
    let n = normals.len() / dim;
    let valid: Vec<usize> = (0..n)
        .filter(|&i| dot(at(normals, i, dim), at(normals, i, dim)) > VALID_SQ)
        .collect();
    if valid.len() < 2 {
        return nan;
    }
    let step = (valid.len() / TARGET_SAMPLE).max(1);
    let mut sin2 = Vec::with_capacity(valid.len() / step + 1);
    for &i in valid.iter().step_by(step) {
        let Some(j) = nearest(i) else { continue };
        let nj = at(normals, j, dim);
        if dot(nj, nj) > VALID_SQ {
            sin2.push(sine_squared(at(normals, i, dim), nj));
        }
    }
    if sin2.is_empty() {
        return nan;
    }
    let m = mean(&sin2);
    (0.5 * m, 0.5 * median_in_place(&mut sin2))
}

/// Unit normal (smallest principal axis) of the `k` nearest points of `q`; sign arbitrary.
fn pca_normal(tree: &KdTree, q: &[f64], k: usize, buf: &mut Vec<(u32, f64)>) -> [f64; 3] {
    buf.clear();
    tree.knn_into(q, k, f64::INFINITY, buf);
    pca_of(tree, buf)
}

/// The unit normal of [`pca_normal`] from the `k` nearest neighbours already found (sorted by
/// (squared distance, index), as `knn_into` gives them).
fn pca_of(tree: &KdTree, buf: &[(u32, f64)]) -> [f64; 3] {
    pca_in(|j| tree.point(j), tree.dim(), buf)
}

/// [`pca_of`] with point `j` read through `point` (the tree's copy or the cloud itself: the
/// same values, so the same bits).
fn pca_in<'a>(point: impl Fn(usize) -> &'a [f64], dim: usize, buf: &[(u32, f64)]) -> [f64; 3] {
    // Two passes: mean, then centred scatter (no cancellation far from the origin).
    let mut centre = [0.0; 3];
    for &(j, _) in buf.iter() {
        for (c, v) in centre.iter_mut().zip(point(j as usize)) {
            *c += v;
        }
    }
    let m = buf.len() as f64;
    centre.iter_mut().for_each(|c| *c /= m);
    let mut s = [0.0; 9];
    for &(j, _) in buf.iter() {
        let p = point(j as usize);
        for r in 0..dim {
            for c in 0..dim {
                s[r * 3 + c] += (p[r] - centre[r]) * (p[c] - centre[c]);
            }
        }
    }
    if dim == 2 {
        let v = sym2(s[0], s[1], s[4]).1[0];
        [v[0], v[1], 0.0]
    } else {
        sym3(&s).1[0]
    }
}

/// Normals (PCA of the `k` nearest neighbours, `k` clamped to the point count) of at most
/// `max_points` evenly spaced points: `(indices, normals)`, normals `len(indices) * dim`.
pub fn sampled_normals(
    points: &[f64],
    dim: usize,
    k: usize,
    max_points: usize,
) -> Result<(Vec<usize>, Vec<f64>)> {
    if let Some((normals, _)) = swept_2d(points, dim, k, max_points) {
        return Ok(((0..points.len() / 2).collect(), normals));
    }
    let tree = KdTree::build(points, dim)?;
    let (idx, normals, _) = sampled_in(&tree, k, max_points, false)?;
    Ok((idx, normals))
}

/// [`sampled_normals`] and the cloud's median spacing
/// ([`crate::trust::scene::median_spacing`]) from one k-d tree: where the sample is every
/// point, the spacing is read off the normals' own searches (a point's nearest other point is
/// the second of its `k` neighbours, as a 2-NN query finds it), else one 2-NN pass of the same
/// tree. The 2D trust analysis reads both of the source.
pub fn sampled_normals_and_spacing(
    points: &[f64],
    dim: usize,
    k: usize,
    max_points: usize,
) -> Result<(Vec<usize>, Vec<f64>, f64)> {
    if k >= 2 {
        if let Some((normals, nearest)) = swept_2d(points, dim, k, max_points) {
            let spacing = crate::trust::scene::median_of_squared(nearest);
            return Ok(((0..points.len() / 2).collect(), normals, spacing));
        }
    }
    let tree = KdTree::build(points, dim)?;
    let (idx, normals, nearest) = sampled_in(&tree, k, max_points, true)?;
    let spacing = if idx.len() == tree.len() && k >= 2 {
        crate::trust::scene::median_of_squared(nearest)
    } else {
        crate::trust::scene::median_spacing(&tree)
    };
    Ok((idx, normals, spacing))
}

/// A small 2D scan's sampled normals when every point is sampled, and each point's squared
/// distance to its nearest other point: the k nearest neighbours found by a sweep along the
/// axis of larger extent, seeded with the k points around each one in scan order, instead of a
/// k-d tree (no tree to build; on a 180-point Intel scan the normals took ~60 µs against the
/// tree's ~69). The k nearest by (squared distance, index) are one set in one order whichever
/// exact search finds them, and the squared distance is the tree's expression, so the normals
/// are [`sampled_in`]'s to the bit. None where the tree runs: 3D, a sample
/// (`n > max_points`), a cloud large enough for the parallel path, a non-finite coordinate,
/// `k == 0`.
fn swept_2d(
    points: &[f64],
    dim: usize,
    k: usize,
    max_points: usize,
) -> Option<(Vec<f64>, Vec<f64>)> {
    let n = points.len() / 2;
    if dim != 2
        || k == 0
        || n == 0
        || n > max_points.max(1)
        || n > SEQUENTIAL_MAX
        || !points.iter().all(|v| v.is_finite())
    {
        return None;
    }
    let k = k.min(n);
    let pt = |i: usize| [points[2 * i], points[2 * i + 1]];
    let extent = |c: usize| {
        let (lo, hi) = (0..n).fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), i| {
            (lo.min(points[2 * i + c]), hi.max(points[2 * i + c]))
        });
        hi - lo
    };
    let axis = usize::from(extent(1) > extent(0));
    let mut order: Vec<u32> = (0..n as u32).collect();
    order.sort_unstable_by(|&a, &b| {
        points[2 * a as usize + axis]
            .total_cmp(&points[2 * b as usize + axis])
            .then(a.cmp(&b))
    });
    let mut normals = vec![0.0; 2 * n];
    let mut nearest = vec![f64::NAN; n];
    let mut buf: Vec<(u32, f64)> = Vec::with_capacity(k + 1);
    let other = 1 - axis;
    // One record per point in sweep order — its coordinate along the axis, across it, and its
    // index — read together by the inner loops below.
    let sorted: Vec<(f64, f64, u32)> = order
        .iter()
        .map(|&i| {
            (
                points[2 * i as usize + axis],
                points[2 * i as usize + other],
                i,
            )
        })
        .collect();
    let sq = |p: [f64; 2], q: [f64; 2]| {
        // The tree's sq_dist(p, q), term by term.
        let mut d = 0.0;
        for c in 0..2 {
            let e = p[c] - q[c];
            d += e * e;
        }
        d
    };
    let insert = |buf: &mut Vec<(u32, f64)>, j: u32, d: f64| crate::knn::offer_k(buf, 0, k, j, d);
    for (pos, &(qa, qb, qi)) in sorted.iter().enumerate() {
        let q = pt(qi as usize);
        // Seeded with the k points around this one in scan order (its neighbours along the
        // surface, mostly the k nearest themselves), the k-th distance is tight from the start;
        // the sweep then visits only what lies within it along the axis.
        let first = (qi as usize).saturating_sub(k / 2).min(n - k);
        buf.clear();
        for j in first..first + k {
            insert(&mut buf, j as u32, sq(pt(j), q));
        }
        let seeds = first as u32..(first + k) as u32;
        // Outward along the axis each way from the query, until the gap along it alone is
        // beyond the k-th distance.
        let mut worst = buf[k - 1].1;
        let (ahead, behind) = (&sorted[pos + 1..], &sorted[..pos]);
        sweep_side(ahead.iter(), (qa, qb), &seeds, k, &mut buf, &mut worst);
        sweep_side(
            behind.iter().rev(),
            (qa, qb),
            &seeds,
            k,
            &mut buf,
            &mut worst,
        );
        let v = pca_in(|j| &points[2 * j..2 * j + 2], 2, &buf);
        let i = qi as usize;
        normals[2 * i] = v[0];
        normals[2 * i + 1] = v[1];
        nearest[i] = buf.get(1).map_or(f64::NAN, |&(_, d)| d);
    }
    Some((normals, nearest))
}

/// The sampled normals of `tree`'s points and, with `nearest`, each sampled point's squared
/// distance to its nearest other point (the second of its neighbours; NaN with one point).
fn sampled_in(
    tree: &KdTree,
    k: usize,
    max_points: usize,
    nearest: bool,
) -> Result<(Vec<usize>, Vec<f64>, Vec<f64>)> {
    let dim = tree.dim();
    let n = tree.len();
    if k == 0 {
        return Err(Error::invalid("k", "must be >= 1"));
    }
    let k = k.min(n);
    let step = (n / max_points.max(1)).max(1);
    let idx: Vec<usize> = (0..n).step_by(step).collect();
    let second = |buf: &[(u32, f64)]| buf.get(1).map_or(f64::NAN, |&(_, d)| d);
    let normal = |buf: &mut Vec<(u32, f64)>, &i: &usize| {
        let v = pca_normal(tree, tree.point(i), k, buf);
        (v, second(buf))
    };
    let per_point: Vec<([f64; 3], f64)> = if idx.len() <= SEQUENTIAL_MAX {
        // In the tree's leaf order, each search bounded by the previous point's k-th distance
        // plus the step between them (as `local_geometry` does): the same k neighbours in the
        // same order, found with most of the traversal pruned.
        let mut scratch = Scratch::new(k);
        let mut out = vec![([0.0; 3], f64::NAN); idx.len()];
        for &i in tree.leaf_order() {
            let i = i as usize;
            if i.is_multiple_of(step) && i / step < out.len() {
                let buf = scratch.neighbours(tree, i, k);
                out[i / step] = (pca_of(tree, buf), second(buf));
            }
        }
        out
    } else {
        idx.par_iter()
            .map_init(|| Vec::with_capacity(k + 1), normal)
            .collect()
    };
    let normals = per_point
        .iter()
        .flat_map(|(v, _)| v[..dim].to_vec())
        .collect();
    let nearest = if nearest {
        per_point.iter().map(|&(_, d)| d).collect()
    } else {
        Vec::new()
    };
    Ok((idx, normals, nearest))
}

/// Variance of a normal's direction per tangent axis (rad²) between two scans: over the
/// sampled source points `sample` (normals `source_normals`, rotated by `rotation`,
/// row-major `dim x dim`) matched to target `correspondences[sample[i]]` (`< 0`: none),
/// the mean `sin²` of the best 90 % over `2 (D − 1)`. `NaN` with fewer than 10 valid pairs.
pub fn correspondence_normal_noise(
    sample: &[usize],
    source_normals: &[f64],
    target_normals: &[f64],
    rotation: &[f64],
    correspondences: &[i64],
    dim: usize,
) -> Result<f64> {
    check_normals(source_normals, sample.len(), dim)?;
    if rotation.len() != dim * dim {
        return Err(Error::invalid(
            "rotation",
            format!("expected {dim} x {dim}"),
        ));
    }
    check_finite("rotation", rotation)?;
    check_finite("target_normals", target_normals)?;
    let targets = target_normals.len() / dim;
    let mut matched = 0;
    let mut sin2 = Vec::with_capacity(sample.len());
    for (s, &i) in sample.iter().enumerate() {
        let Some(&j) = correspondences.get(i) else {
            return Err(Error::invalid("sample", format!("index {i} out of range")));
        };
        if j < 0 {
            continue;
        }
        let j = j as usize;
        if j >= targets {
            return Err(Error::invalid(
                "correspondences",
                format!("index {j} out of range"),
            ));
        }
        matched += 1;
        let ns = at(source_normals, s, dim);
        let mut rotated = [0.0; 3];
        for (r, out) in rotated.iter_mut().enumerate().take(dim) {
            *out = dot(at(rotation, r, dim), ns);
        }
        let rotated = &rotated[..dim];
        let nt = at(target_normals, j, dim);
        if dot(rotated, rotated) > VALID_SQ && dot(nt, nt) > VALID_SQ {
            sin2.push(sine_squared(rotated, nt));
        }
    }
    if matched < 10 || sin2.len() < 10 {
        return Ok(f64::NAN);
    }
    sin2.sort_by(f64::total_cmp);
    let kept = ((0.9 * sin2.len() as f64) as usize).max(1);
    Ok(mean(&sin2[..kept]) / (2.0 * (dim as f64 - 1.0)))
}

/// One side of the 2D sweep: offer each point of `side` (`(along, across, index)`, moving
/// away from the query `q` along the axis) to the k best in `buf`, skipping the `seeds` already
/// offered, until the gap along the axis alone exceeds the k-th distance `worst`. Inlined
/// (a closure here was called, not inlined, at every step).
#[inline(always)]
fn sweep_side<'a>(
    side: impl Iterator<Item = &'a (f64, f64, u32)>,
    q: (f64, f64),
    seeds: &std::ops::Range<u32>,
    k: usize,
    buf: &mut Vec<(u32, f64)>,
    worst: &mut f64,
) {
    for &(a, b, j) in side {
        let ea = a - q.0;
        if ea * ea > *worst {
            break;
        }
        if !seeds.contains(&j) {
            let eb = b - q.1;
            // The tree's sq_dist: two squares summed (its leading `0.0 +` adds nothing to a
            // square, and a sum of two terms is the same in either order).
            let d = ea * ea + eb * eb;
            if d <= *worst {
                crate::knn::offer_k(buf, 0, k, j, d);
                *worst = buf[k - 1].1;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on a line with normals along +y, every other one tilted by `tilt`.
    fn line(n: usize, tilt: f64) -> (Vec<f64>, Vec<f64>) {
        let pts = (0..n).flat_map(|i| [i as f64 * 0.1, 0.0]).collect();
        let nrm = (0..n)
            .flat_map(|i| {
                let a = if i % 2 == 0 { tilt } else { 0.0 };
                [a.sin(), a.cos()]
            })
            .collect();
        (pts, nrm)
    }

    /// The spacing read off the normals' searches (every point sampled) or a 2-NN pass (a
    /// sample) equals the brute-force median, numpy's rule for an even count included.
    #[test]
    fn spacing_from_the_normals_search_is_the_median_nearest_distance() {
        let brute = |pts: &[f64]| {
            let n = pts.len() / 2;
            let mut d: Vec<f64> = (0..n)
                .map(|i| {
                    (0..n)
                        .filter(|&j| j != i)
                        .map(|j| {
                            let (a, b) = (pts[2 * i] - pts[2 * j], pts[2 * i + 1] - pts[2 * j + 1]);
                            a * a + b * b
                        })
                        .fold(f64::INFINITY, f64::min)
                })
                .collect();
            d.sort_by(f64::total_cmp);
            let m = if n % 2 == 1 {
                d[n / 2]
            } else {
                (d[n / 2 - 1] + d[n / 2]) / 2.0
            };
            m.sqrt()
        };
        for n in [7usize, 40, 41] {
            // Irregular spacing along a curve: each point's nearest distance differs.
            let pts: Vec<f64> = (0..n)
                .flat_map(|i| {
                    let t = (i * i) as f64 * 0.01;
                    [t, (3.0 * t).sin()]
                })
                .collect();
            let want = brute(&pts);
            for max_points in [n, n / 3] {
                let (idx, nrm, got) = sampled_normals_and_spacing(&pts, 2, 5, max_points).unwrap();
                assert_eq!(got, want, "n {n} sample {max_points}");
                assert_eq!((idx, nrm), sampled_normals(&pts, 2, 5, max_points).unwrap());
            }
        }
        let (_, _, one) = sampled_normals_and_spacing(&[1.0, 2.0], 2, 1, 10).unwrap();
        assert!(one.is_nan());
    }

    /// The 2D sweep gives the k-d tree's normals and nearest distances to the bit: a scan-like
    /// ring with a depth jump, duplicated points and equal distances (ties broken by index), a
    /// cloud in scrambled order, every k from 1 to beyond the point count.
    #[test]
    fn swept_normals_equal_the_tree_search() {
        let mut ring: Vec<f64> = (0..150)
            .flat_map(|i| {
                let a = i as f64 * 0.04;
                let r = if (40..70).contains(&i) {
                    2.0
                } else {
                    5.0 + 0.3 * (3.0 * a).sin()
                };
                [r * a.cos(), r * a.sin()]
            })
            .collect();
        ring.extend_from_slice(&[1.0, 1.0, 1.0, 1.0, 1.0, 1.0]); // duplicates
        let grid: Vec<f64> = (0..64)
            .flat_map(|i| [(i % 8) as f64, (i / 8) as f64])
            .collect();
        let mut state = 7u64;
        let mut rnd = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let scrambled: Vec<f64> = (0..200).map(|_| rnd() * 3.0 - 1.0).collect();
        for (name, pts) in [("ring", &ring), ("grid", &grid), ("scrambled", &scrambled)] {
            let n = pts.len() / 2;
            let tree = KdTree::build(pts, 2).unwrap();
            for k in [1, 2, 5, 10, 17, n, n + 3] {
                let (normals, nearest) = swept_2d(pts, 2, k, 1500).expect("small 2D cloud");
                let (idx, want, want_nearest) = sampled_in(&tree, k, 1500, true).unwrap();
                assert_eq!(idx.len(), n);
                assert_eq!(normals, want, "{name} k {k}");
                let same = nearest
                    .iter()
                    .zip(&want_nearest)
                    .all(|(a, b)| a == b || (a.is_nan() && b.is_nan()));
                assert!(same, "{name} k {k}: nearest distances");
            }
        }
        // The tree's cases: 3D, a sample, a non-finite coordinate.
        assert!(swept_2d(&[0.0; 9], 3, 2, 10).is_none());
        assert!(swept_2d(&ring, 2, 5, 20).is_none());
        assert!(swept_2d(&[0.0, f64::NAN, 1.0, 1.0], 2, 1, 10).is_none());
    }

    #[test]
    fn target_noise_reads_the_tilt() {
        let (pts, nrm) = line(400, 0.01);
        let tree = KdTree::build(&pts, 2).unwrap();
        let (m, med) = target_normal_noise(&tree, &nrm).unwrap();
        // Every neighbour pair differs by the tilt.
        let want = 0.5 * 0.01f64.sin().powi(2);
        assert!(
            (m - want).abs() < 1e-15 && (med - want).abs() < 1e-15,
            "{m} {med}"
        );
    }

    #[test]
    fn target_noise_without_valid_normals_is_nan() {
        let (pts, _) = line(10, 0.0);
        let tree = KdTree::build(&pts, 2).unwrap();
        let (m, med) = target_normal_noise(&tree, &[0.0; 20]).unwrap();
        assert!(m.is_nan() && med.is_nan());
        assert!(target_normal_noise(&tree, &[0.0; 3]).is_err());
        let mut nan = [0.0; 20];
        nan[5] = f64::NAN;
        let e = target_normal_noise(&tree, &nan).unwrap_err();
        assert!(e.to_string().contains("normals"), "{e}");
    }

    #[test]
    fn correspondence_noise_refuses_non_finite_input() {
        let nrm = [0.0, 1.0, 0.0, 1.0];
        let eye = [1.0, 0.0, 0.0, 1.0];
        let ok = correspondence_normal_noise(&[0, 1], &nrm, &nrm, &eye, &[0, 1], 2);
        assert!(ok.is_ok());
        let nan_rot = [f64::NAN, 0.0, 0.0, 1.0];
        for (arg, src, tgt, rot) in [
            ("normals", [f64::NAN, 1.0, 0.0, 1.0], nrm, eye),
            ("target_normals", nrm, [0.0, f64::NAN, 0.0, 1.0], eye),
            ("rotation", nrm, nrm, nan_rot),
        ] {
            let e = correspondence_normal_noise(&[0, 1], &src, &tgt, &rot, &[0, 1], 2).unwrap_err();
            assert!(e.to_string().starts_with(arg), "{arg}: {e}");
        }
    }

    #[test]
    fn sampled_normals_of_a_line_are_perpendicular() {
        let pts: Vec<f64> = (0..50).flat_map(|i| [i as f64 * 0.1, 2.0]).collect();
        let (idx, nrm) = sampled_normals(&pts, 2, 5, 20).unwrap();
        assert_eq!(idx, (0..50).step_by(2).collect::<Vec<_>>());
        for v in nrm.chunks(2) {
            assert!(
                v[0].abs() < 1e-12 && (v[1].abs() - 1.0).abs() < 1e-12,
                "{v:?}"
            );
        }
    }

    #[test]
    fn sampled_normals_in_3d_face_off_a_plane() {
        let pts: Vec<f64> = (0..100)
            .flat_map(|i| [(i % 10) as f64, (i / 10) as f64, 1.0])
            .collect();
        let (_, nrm) = sampled_normals(&pts, 3, 8, 1000).unwrap();
        for v in nrm.chunks(3) {
            assert!((v[2].abs() - 1.0).abs() < 1e-12, "{v:?}");
        }
    }

    #[test]
    fn correspondence_noise_of_matching_normals_is_zero_and_needs_ten_pairs() {
        let (_, nrm) = line(40, 0.0);
        let sample: Vec<usize> = (0..40).collect();
        let corr: Vec<i64> = (0..40).collect();
        let eye = [1.0, 0.0, 0.0, 1.0];
        let v = correspondence_normal_noise(&sample, &nrm, &nrm, &eye, &corr, 2).unwrap();
        assert!(v.abs() < 1e-15, "{v}");
        let few: Vec<i64> = (0..40).map(|i| if i < 9 { i } else { -1 }).collect();
        let v = correspondence_normal_noise(&sample, &nrm, &nrm, &eye, &few, 2).unwrap();
        assert!(v.is_nan());
        let bad: Vec<i64> = vec![99; 40];
        assert!(correspondence_normal_noise(&sample, &nrm, &nrm, &eye, &bad, 2).is_err());
    }

    #[test]
    fn median_of_even_and_odd_counts() {
        assert_eq!(median_sorted(&[1.0, 2.0, 4.0]), 2.0);
        assert_eq!(median_sorted(&[1.0, 2.0, 4.0, 8.0]), 3.0);
        assert_eq!(median_in_place(&mut [4.0, 1.0, 2.0]), 2.0);
        assert_eq!(median_in_place(&mut [8.0, 1.0, 4.0, 2.0]), 3.0);
        assert_eq!(median_in_place(&mut [0.3]), 0.3);
    }
}
