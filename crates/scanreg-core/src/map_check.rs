//! Free-space evidence of posed 2D scans, for a map that checks itself without ground truth.
//!
//! A scan's return says "something stops beams here". Another scan whose beams around that
//! bearing, seen from its own pose, went on well beyond it saw through it: the two contradict
//! each other. In a consistent map that only happens where something moved (people, doors);
//! where the trajectory is wrong, a revisit puts its walls where the first visit saw through.
//!
//! Every scan becomes a range image (the nearest return in each of `bins` equal bearing bins,
//! empty bins unknown); every return of every scan is then looked up in every other scan that
//! could reach it. A scan *sees* the return when its three bins around the return's bearing all
//! hold a return no nearer than `margin` before it, and *sees through* it when all three lie
//! more than `margin` beyond it. Three bins rather than one: a thin object (a chair leg) between
//! two beams is missed by one scan and hit by another without any contradiction. Unknown bins
//! (no return: out of range, or thinned away) say nothing. A grid of cells would not do here:
//! a beam passing beside a chair leg crosses the leg's cell, and on the Intel log half of a
//! good map's returns fell in cells other scans had crossed (10 cm cells).

use crate::error::{Error, Result};
use rayon::prelude::*;
use rustc_hash::FxHashMap;

/// What [`see_through`] found at every return (input order).
#[derive(Debug, Clone, PartialEq)]
pub struct SeeThrough {
    /// Every return in the world frame (row-major `N x 2`).
    pub world: Vec<f64>,
    /// The returns judged (indices into the input; every `stride`-th).
    pub judged: Vec<usize>,
    /// Per judged return: the other scans that saw it (their beams reached it or beyond).
    pub seen: Vec<u32>,
    /// Of those, the scans whose beams went more than `margin` beyond it.
    pub seen_through: Vec<u32>,
}

fn check_input(poses: &[f64], points: &[f64], offsets: &[usize]) -> Result<usize> {
    if !poses.len().is_multiple_of(3) {
        return Err(Error::invalid(
            "poses",
            format!("expected rows of [x, y, θ], got {} values", poses.len()),
        ));
    }
    let scans = poses.len() / 3;
    if offsets.len() != scans + 1 {
        return Err(Error::invalid(
            "offsets",
            format!(
                "expected {} offsets (scans + 1), got {}",
                scans + 1,
                offsets.len()
            ),
        ));
    }
    if !points.len().is_multiple_of(2) {
        return Err(Error::invalid("points", "expected rows of [x, y]"));
    }
    let n = points.len() / 2;
    if offsets[0] != 0 || offsets[scans] != n || offsets.windows(2).any(|w| w[0] > w[1]) {
        return Err(Error::invalid(
            "offsets",
            format!("must rise from 0 to the number of points ({n})"),
        ));
    }
    if poses.iter().any(|v| !v.is_finite()) {
        return Err(Error::invalid("poses", "contains NaN or inf"));
    }
    if points.iter().any(|v| !v.is_finite()) {
        return Err(Error::invalid("points", "contains NaN or inf"));
    }
    Ok(scans)
}

/// One scan as seen from its own pose: the nearest return per bearing bin (NaN: none).
struct RangeImage {
    x: f64,
    y: f64,
    cos: f64,
    sin: f64,
    /// The farthest return: no return beyond it can be seen from here.
    reach: f64,
    ranges: Vec<f64>,
}

/// `atan2(y, x)` within 2e-5 rad (Abramowitz & Stegun 4.4.49 on the octant): cheaper than
/// libm's, and the bins it feeds are a degree wide.
fn fast_atan2(y: f64, x: f64) -> f64 {
    use std::f64::consts::{FRAC_PI_2, PI};
    let (ax, ay) = (x.abs(), y.abs());
    if ax == 0.0 && ay == 0.0 {
        return 0.0;
    }
    let z = ax.min(ay) / ax.max(ay);
    let z2 = z * z;
    let mut a = z
        * (0.999_866_0
            + z2 * (-0.330_299_5 + z2 * (0.180_141_0 + z2 * (-0.085_133_0 + z2 * 0.020_835_1))));
    if ay > ax {
        a = FRAC_PI_2 - a;
    }
    if x < 0.0 {
        a = PI - a;
    }
    if y < 0.0 {
        -a
    } else {
        a
    }
}

fn bin_of(bearing: f64, bins: usize) -> usize {
    let u = (bearing + std::f64::consts::PI) / std::f64::consts::TAU;
    ((u * bins as f64).floor() as usize).min(bins - 1)
}

impl RangeImage {
    fn new(pose: &[f64], points: &[f64], bins: usize) -> Self {
        let mut ranges = vec![f64::NAN; bins];
        let mut reach = 0.0f64;
        for p in points.chunks_exact(2) {
            let r = p[0].hypot(p[1]);
            let b = bin_of(p[1].atan2(p[0]), bins);
            if ranges[b].is_nan() || r < ranges[b] {
                ranges[b] = r; // empty, or farther: keep the nearest
            }
            reach = reach.max(r);
        }
        let (sin, cos) = pose[2].sin_cos();
        RangeImage {
            x: pose[0],
            y: pose[1],
            cos,
            sin,
            reach,
            ranges,
        }
    }

    /// `(seen, seen_through)` of the world point `w` from this scan.
    fn judge(&self, w: [f64; 2], margin: f64) -> (bool, bool) {
        let (dx, dy) = (w[0] - self.x, w[1] - self.y);
        let range = dx.hypot(dy);
        if range > self.reach || range <= margin {
            return (false, false);
        }
        // The point in this scan's frame: R^T (w - t).
        let (lx, ly) = (
            self.cos * dx + self.sin * dy,
            -self.sin * dx + self.cos * dy,
        );
        let bins = self.ranges.len();
        let b = bin_of(fast_atan2(ly, lx), bins);
        let mut nearest = f64::INFINITY;
        for k in [b + bins - 1, b, b + 1] {
            let r = self.ranges[k % bins];
            if r.is_nan() {
                return (false, false);
            }
            nearest = nearest.min(r);
        }
        if nearest < range - margin {
            return (false, false); // something nearer hid it: this scan cannot tell
        }
        (true, nearest > range + margin)
    }
}

/// How [`see_through`] judges (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeeThroughSettings {
    /// Bearing bins of the range images (at least 3; each no narrower than the beam spacing).
    pub bins: usize,
    /// Tolerance along the beam (m).
    pub margin: f64,
    /// Only scans within this distance of a return judge it (m).
    pub max_range: f64,
    /// Only scans more than this many scans away in order judge (a revisit, not the
    /// neighbours a person walking by or a small slip of the odometry would fool alike);
    /// scans of different sessions always judge each other.
    pub min_gap: usize,
    /// Judge every `stride`-th return (input order; >= 1): the fractions need far fewer than a
    /// run's every return, and the cost is per return and judging scan.
    pub stride: usize,
}

/// Judge every return of every scan (`points`, row-major `N x 2` in its scan's frame, scan `s`
/// holding rows `offsets[s]..offsets[s + 1]`, posed at `poses[s] = [x, y, θ]` =
/// `T_world_scan`, the sensor at the scan's origin) from the other scans `settings` admits.
/// `sessions`: each scan's session (a joint map of several runs; `None`: one run).
pub fn see_through(
    poses: &[f64],
    points: &[f64],
    offsets: &[usize],
    sessions: Option<&[u32]>,
    settings: SeeThroughSettings,
) -> Result<SeeThrough> {
    let scans = check_input(poses, points, offsets)?;
    if let Some(v) = sessions {
        if v.len() != scans {
            return Err(Error::invalid(
                "sessions",
                format!("expected one per scan ({scans}), got {}", v.len()),
            ));
        }
    }
    let same_session = |a: usize, b: usize| sessions.is_none_or(|v| v[a] == v[b]);
    let SeeThroughSettings {
        bins,
        margin,
        max_range,
        min_gap,
        stride,
    } = settings;
    if stride == 0 {
        return Err(Error::invalid("stride", "must be >= 1"));
    }
    if bins < 3 {
        return Err(Error::invalid(
            "bins",
            format!("must be at least 3, got {bins}"),
        ));
    }
    if !(margin.is_finite() && margin >= 0.0) {
        return Err(Error::invalid(
            "margin",
            format!("must be >= 0, got {margin}"),
        ));
    }
    if !(max_range.is_finite() && max_range > 0.0) {
        return Err(Error::invalid(
            "max_range",
            format!("must be finite and > 0, got {max_range}"),
        ));
    }
    let scan_points = |s: usize| &points[2 * offsets[s]..2 * offsets[s + 1]];
    let images: Vec<RangeImage> = (0..scans)
        .into_par_iter()
        .map(|s| RangeImage::new(&poses[3 * s..3 * s + 3], scan_points(s), bins))
        .collect();
    // The scans by square cells of `max_range`: a return's judges lie in its cell's 3 x 3.
    let cell = |x: f64, y: f64| {
        [
            (x / max_range).floor() as i64,
            (y / max_range).floor() as i64,
        ]
    };
    let mut buckets: FxHashMap<[i64; 2], Vec<usize>> = FxHashMap::default();
    for (o, im) in images.iter().enumerate() {
        buckets.entry(cell(im.x, im.y)).or_default().push(o);
    }
    let range2 = max_range * max_range;
    #[allow(clippy::type_complexity)]
    let per_scan: Vec<(Vec<f64>, Vec<usize>, Vec<u32>, Vec<u32>)> = (0..scans)
        .into_par_iter()
        .map(|s| {
            let me = &images[s];
            let local = scan_points(s);
            let mut world = Vec::with_capacity(local.len());
            let mut judged = Vec::new();
            let mut seen = Vec::new();
            let mut through = Vec::new();
            for (k, p) in local.chunks_exact(2).enumerate() {
                let w = [
                    me.x + me.cos * p[0] - me.sin * p[1],
                    me.y + me.sin * p[0] + me.cos * p[1],
                ];
                world.extend_from_slice(&w);
                let index = offsets[s] + k;
                if !index.is_multiple_of(stride) {
                    continue;
                }
                let (mut a, mut b) = (0u32, 0u32);
                let [ci, cj] = cell(w[0], w[1]);
                for di in -1..=1 {
                    for dj in -1..=1 {
                        let Some(near) = buckets.get(&[ci + di, cj + dj]) else {
                            continue;
                        };
                        for &o in near {
                            if same_session(o, s) && o.abs_diff(s) <= min_gap {
                                continue;
                            }
                            let im = &images[o];
                            let (dx, dy) = (w[0] - im.x, w[1] - im.y);
                            if dx * dx + dy * dy > range2 {
                                continue;
                            }
                            let (saw, past) = im.judge(w, margin);
                            a += u32::from(saw);
                            b += u32::from(past);
                        }
                    }
                }
                judged.push(index);
                seen.push(a);
                through.push(b);
            }
            (world, judged, seen, through)
        })
        .collect();
    let mut out = SeeThrough {
        world: Vec::with_capacity(points.len()),
        judged: Vec::new(),
        seen: Vec::new(),
        seen_through: Vec::new(),
    };
    for (w, j, a, b) in per_scan {
        out.world.extend(w);
        out.judged.extend(j);
        out.seen.extend(a);
        out.seen_through.extend(b);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(bins: usize, margin: f64) -> SeeThroughSettings {
        SeeThroughSettings {
            bins,
            margin,
            max_range: 10.0,
            min_gap: 0,
            stride: 1,
        }
    }

    /// A scan of a wall at `x = wall` across `y` in [-1, 1] m (2 cm apart), from `(x, 0)`
    /// facing +x.
    fn wall_scan(x: f64, wall: f64) -> Vec<f64> {
        (0..=100)
            .flat_map(|k| [wall - x, -1.0 + 0.02 * f64::from(k)])
            .collect()
    }

    #[test]
    fn a_wall_seen_twice_agrees_and_a_ghost_contradicts() {
        let poses = [0.0, 0.0, 0.0, 0.5, 0.0, 0.0];
        // Both see the wall at x = 3: each sees the other's returns, none through.
        let pts = [wall_scan(0.0, 3.0), wall_scan(0.5, 3.0)].concat();
        let n = pts.len() / 2;
        let g = see_through(&poses, &pts, &[0, n / 2, n], None, settings(360, 0.2)).unwrap();
        // The middle return of the first scan (y = 0) is seen by the second, not through.
        assert_eq!((g.seen[50], g.seen_through[50]), (1, 0));
        // The second scan sees its wall 1 m further (at x = 4): it saw through the first
        // scan's wall, and the first scan, whose beams stop at 3 m, cannot tell about it.
        let pts = [wall_scan(0.0, 3.0), wall_scan(0.5, 4.0)].concat();
        let g = see_through(&poses, &pts, &[0, n / 2, n], None, settings(360, 0.2)).unwrap();
        assert_eq!((g.seen[50], g.seen_through[50]), (1, 1));
        assert_eq!((g.seen[n / 2 + 50], g.seen_through[n / 2 + 50]), (0, 0));
        assert_eq!(&g.world[2 * (n / 2 + 50)..2 * (n / 2 + 51)], &[4.0, 0.0]);
        // Neighbours in order do not judge each other with a gap of one, nor beyond range.
        let gap = SeeThroughSettings {
            min_gap: 1,
            ..settings(360, 0.2)
        };
        let g = see_through(&poses, &pts, &[0, n / 2, n], None, gap).unwrap();
        assert!(g.seen.iter().all(|&v| v == 0));
        // ... unless they are of different sessions (two runs): then the gap does not apply.
        let two = see_through(&poses, &pts, &[0, n / 2, n], Some(&[0, 1]), gap).unwrap();
        assert_eq!((two.seen[50], two.seen_through[50]), (1, 1));
        let one = see_through(&poses, &pts, &[0, n / 2, n], Some(&[3, 3]), gap).unwrap();
        assert_eq!(one, g);
        let wrong = see_through(&poses, &pts, &[0, n / 2, n], Some(&[0]), gap);
        assert!(wrong.unwrap_err().to_string().starts_with("sessions:"));
        let near = SeeThroughSettings {
            max_range: 2.0,
            ..settings(360, 0.2)
        };
        let g = see_through(&poses, &pts, &[0, n / 2, n], None, near).unwrap();
        assert_eq!(g.seen[50], 0);
        // Every third return judged: the same figures for those.
        let thinned = SeeThroughSettings {
            stride: 3,
            ..settings(360, 0.2)
        };
        let all = see_through(&poses, &pts, &[0, n / 2, n], None, settings(360, 0.2)).unwrap();
        let g = see_through(&poses, &pts, &[0, n / 2, n], None, thinned).unwrap();
        assert_eq!(g.judged, (0..n).step_by(3).collect::<Vec<_>>());
        let picked: Vec<u32> = g.judged.iter().map(|&i| all.seen_through[i]).collect();
        assert_eq!(g.seen_through, picked);
        assert_eq!(g.world, all.world);
    }

    #[test]
    fn the_pose_turns_the_points_and_unknown_bearings_say_nothing() {
        // The first scan faces +y from (0, -3): its wall is the line y = 0.
        let first: Vec<f64> = (0..=40)
            .flat_map(|k| [3.0, -1.0 + 0.05 * f64::from(k)])
            .collect();
        let poses = [
            0.0,
            -3.0,
            std::f64::consts::FRAC_PI_2,
            0.0,
            -2.0,
            std::f64::consts::FRAC_PI_2,
        ];
        // The second sees a single return 1 m beyond that wall: too sparse to see through.
        let pts = [first.clone(), vec![3.0, 0.0]].concat();
        let n = pts.len() / 2;
        let g = see_through(&poses, &pts, &[0, n - 1, n], None, settings(360, 0.2)).unwrap();
        assert!((g.world[40] - 0.0).abs() < 1e-12 && (g.world[41] - 0.0).abs() < 1e-12);
        assert_eq!((g.seen[20], g.seen_through[20]), (0, 0));
    }

    #[test]
    fn fast_atan2_is_within_its_bound() {
        for k in 0..10_000 {
            let a = -3.2 + 6.4 * f64::from(k) / 10_000.0;
            let (y, x) = (a.sin() * 2.5, a.cos() * 2.5);
            assert!((fast_atan2(y, x) - y.atan2(x)).abs() < 2e-5, "{a}");
        }
        assert_eq!(fast_atan2(0.0, 0.0), 0.0);
    }

    #[test]
    fn bad_input_names_the_argument() {
        let err = |r: Result<SeeThrough>| r.unwrap_err().to_string();
        assert!(
            err(see_through(&[0.0; 2], &[], &[0], None, settings(360, 0.0))).starts_with("poses:")
        );
        assert!(err(see_through(
            &[0.0; 3],
            &[1.0, 0.0],
            &[0, 2],
            None,
            settings(360, 0.0)
        ))
        .starts_with("offsets:"));
        assert!(err(see_through(
            &[0.0; 3],
            &[1.0, 0.0],
            &[0, 1],
            None,
            settings(2, 0.0)
        ))
        .starts_with("bins:"));
        assert!(err(see_through(
            &[0.0; 3],
            &[1.0, 0.0],
            &[0, 1],
            None,
            settings(360, -1.0)
        ))
        .starts_with("margin:"));
        assert!(err(see_through(
            &[0.0; 3],
            &[f64::NAN, 0.0],
            &[0, 1],
            None,
            settings(360, 0.0)
        ))
        .starts_with("points:"));
        let far = SeeThroughSettings {
            max_range: 0.0,
            ..settings(360, 0.0)
        };
        assert!(
            err(see_through(&[0.0; 3], &[1.0, 0.0], &[0, 1], None, far)).starts_with("max_range:")
        );
    }
}
