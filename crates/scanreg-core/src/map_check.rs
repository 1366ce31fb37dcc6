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
//!
//! 3D scans ([`see_through_3d`]) are judged alike over azimuth × elevation bins, the
//! neighbourhood three by three bins.

use crate::error::{Error, Result};
use rayon::prelude::*;
use rustc_hash::FxHashMap;

/// What [`see_through`] (and [`see_through_3d`]) found at every return (input order).
#[derive(Debug, Clone, PartialEq)]
pub struct SeeThrough {
    /// The returns judged (indices into the input; every `stride`-th).
    pub judged: Vec<usize>,
    /// Each judged return in the world frame (row-major `len(judged) x 2`; `x 3` in 3D).
    pub world: Vec<f64>,
    /// Per judged return: the other scans that saw it (their beams reached it or beyond).
    pub seen: Vec<u32>,
    /// Of those, the scans whose beams went more than `margin` beyond it.
    pub seen_through: Vec<u32>,
}

fn check_input(
    poses: &[f64],
    pose_len: usize,
    points: &[f64],
    dim: usize,
    offsets: &[usize],
) -> Result<usize> {
    if !poses.len().is_multiple_of(pose_len) {
        let what = if pose_len == 3 {
            "[x, y, θ]"
        } else {
            "[R (row-major), t]"
        };
        return Err(Error::invalid(
            "poses",
            format!("expected rows of {what}, got {} values", poses.len()),
        ));
    }
    let scans = poses.len() / pose_len;
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
    if !points.len().is_multiple_of(dim) {
        let what = if dim == 2 { "[x, y]" } else { "[x, y, z]" };
        return Err(Error::invalid("points", format!("expected rows of {what}")));
    }
    let n = points.len() / dim;
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

/// A scan as seen from its own pose: the nearest return per bin of direction (2D: bearing;
/// 3D: azimuth × elevation), empty bins unknown.
trait RangeImage: Sync {
    /// The sensor in the world frame (z = 0 in 2D).
    fn origin(&self) -> [f64; 3];
    /// One of this scan's returns (its own frame) in the world frame.
    fn to_world(&self, p: &[f64]) -> [f64; 3];
    /// `(seen, seen_through)` of the world point `w` from this scan.
    fn judge(&self, w: [f64; 3], margin: f64) -> (bool, bool);
}

/// The verdict of a range image on a point `range` away whose neighbourhood of bins holds
/// `nearest` (the least range there; `None` when a bin is unknown).
fn verdict(nearest: Option<f64>, range: f64, margin: f64) -> (bool, bool) {
    match nearest {
        // Something nearer hid it, or a bin is unknown: this scan cannot tell.
        None => (false, false),
        Some(r) if r < range - margin => (false, false),
        Some(r) => (true, r > range + margin),
    }
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

/// The elevation bin of `elevation` in [-π/2, π/2].
fn elevation_bin(elevation: f64, bins: usize) -> usize {
    let u = (elevation + std::f64::consts::FRAC_PI_2) / std::f64::consts::PI;
    ((u * bins as f64).floor().max(0.0) as usize).min(bins - 1)
}

/// A 2D scan's range image over bearing bins.
struct RangeImage2 {
    x: f64,
    y: f64,
    cos: f64,
    sin: f64,
    /// The farthest return: no return beyond it can be seen from here.
    reach: f64,
    ranges: Vec<f64>,
}

impl RangeImage2 {
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
        RangeImage2 {
            x: pose[0],
            y: pose[1],
            cos,
            sin,
            reach,
            ranges,
        }
    }
}

impl RangeImage for RangeImage2 {
    fn origin(&self) -> [f64; 3] {
        [self.x, self.y, 0.0]
    }

    fn to_world(&self, p: &[f64]) -> [f64; 3] {
        [
            self.x + self.cos * p[0] - self.sin * p[1],
            self.y + self.sin * p[0] + self.cos * p[1],
            0.0,
        ]
    }

    fn judge(&self, w: [f64; 3], margin: f64) -> (bool, bool) {
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
        let nearest = [b + bins - 1, b, b + 1]
            .iter()
            .map(|k| self.ranges[k % bins])
            .try_fold(f64::INFINITY, |m, r| (!r.is_nan()).then(|| m.min(r)));
        verdict(nearest, range, margin)
    }
}

/// A 3D scan's range image over azimuth × elevation bins.
struct RangeImage3 {
    t: [f64; 3],
    /// `R_world_scan`, row-major.
    rot: [f64; 9],
    reach: f64,
    azimuths: usize,
    elevations: usize,
    ranges: Vec<f64>,
}

impl RangeImage3 {
    fn new(pose: &[f64], points: &[f64], azimuths: usize, elevations: usize) -> Self {
        let mut ranges = vec![f64::NAN; azimuths * elevations];
        let mut reach = 0.0f64;
        for p in points.chunks_exact(3) {
            let flat = p[0].hypot(p[1]);
            let r = flat.hypot(p[2]);
            let k = elevation_bin(p[2].atan2(flat), elevations) * azimuths
                + bin_of(p[1].atan2(p[0]), azimuths);
            if ranges[k].is_nan() || r < ranges[k] {
                ranges[k] = r;
            }
            reach = reach.max(r);
        }
        let mut rot = [0.0; 9];
        rot.copy_from_slice(&pose[..9]);
        RangeImage3 {
            t: [pose[9], pose[10], pose[11]],
            rot,
            reach,
            azimuths,
            elevations,
            ranges,
        }
    }
}

impl RangeImage for RangeImage3 {
    fn origin(&self) -> [f64; 3] {
        self.t
    }

    fn to_world(&self, p: &[f64]) -> [f64; 3] {
        let r = &self.rot;
        [
            self.t[0] + r[0] * p[0] + r[1] * p[1] + r[2] * p[2],
            self.t[1] + r[3] * p[0] + r[4] * p[1] + r[5] * p[2],
            self.t[2] + r[6] * p[0] + r[7] * p[1] + r[8] * p[2],
        ]
    }

    fn judge(&self, w: [f64; 3], margin: f64) -> (bool, bool) {
        let d = [w[0] - self.t[0], w[1] - self.t[1], w[2] - self.t[2]];
        let range = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        if range > self.reach || range <= margin {
            return (false, false);
        }
        let r = &self.rot; // R^T d
        let lx = r[0] * d[0] + r[3] * d[1] + r[6] * d[2];
        let ly = r[1] * d[0] + r[4] * d[1] + r[7] * d[2];
        let lz = r[2] * d[0] + r[5] * d[1] + r[8] * d[2];
        let (az, el) = (self.azimuths, self.elevations);
        let b = bin_of(fast_atan2(ly, lx), az);
        let e = elevation_bin(fast_atan2(lz, lx.hypot(ly)), el);
        if e == 0 || e + 1 >= el {
            return (false, false); // no full neighbourhood: straight up or down
        }
        let nearest = (e - 1..=e + 1)
            .flat_map(|row| [b + az - 1, b, b + 1].map(|k| row * az + k % az))
            .map(|k| self.ranges[k])
            .try_fold(f64::INFINITY, |m, r| (!r.is_nan()).then(|| m.min(r)));
        verdict(nearest, range, margin)
    }
}

/// How [`see_through`] judges (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeeThroughSettings {
    /// Bearing (azimuth) bins of the range images (at least 3; each no narrower than the beam
    /// spacing).
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

impl SeeThroughSettings {
    fn check(&self) -> Result<()> {
        if self.stride == 0 {
            return Err(Error::invalid("stride", "must be >= 1"));
        }
        if self.bins < 3 {
            return Err(Error::invalid(
                "bins",
                format!("must be at least 3, got {}", self.bins),
            ));
        }
        if !(self.margin.is_finite() && self.margin >= 0.0) {
            return Err(Error::invalid(
                "margin",
                format!("must be >= 0, got {}", self.margin),
            ));
        }
        if !(self.max_range.is_finite() && self.max_range > 0.0) {
            return Err(Error::invalid(
                "max_range",
                format!("must be finite and > 0, got {}", self.max_range),
            ));
        }
        Ok(())
    }
}

fn check_sessions(sessions: Option<&[u32]>, scans: usize) -> Result<()> {
    match sessions {
        Some(v) if v.len() != scans => Err(Error::invalid(
            "sessions",
            format!("expected one per scan ({scans}), got {}", v.len()),
        )),
        _ => Ok(()),
    }
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
    let scans = check_input(poses, 3, points, 2, offsets)?;
    check_sessions(sessions, scans)?;
    settings.check()?;
    let images: Vec<RangeImage2> = (0..scans)
        .into_par_iter()
        .map(|s| {
            let pts = &points[2 * offsets[s]..2 * offsets[s + 1]];
            RangeImage2::new(&poses[3 * s..3 * s + 3], pts, settings.bins)
        })
        .collect();
    Ok(judge_all(&images, points, 2, offsets, sessions, settings))
}

/// [`see_through`] for 3D scans: `points` row-major `N x 3`, `poses[s]` the 12 values of
/// `T_world_scan` as `[R row-major, t]`, the range images `settings.bins` azimuth by
/// `elevation_bins` elevation bins over [-90°, 90°] (each no narrower than the rings'
/// spacing). `world` holds 3 columns.
pub fn see_through_3d(
    poses: &[f64],
    points: &[f64],
    offsets: &[usize],
    sessions: Option<&[u32]>,
    settings: SeeThroughSettings,
    elevation_bins: usize,
) -> Result<SeeThrough> {
    let scans = check_input(poses, 12, points, 3, offsets)?;
    check_sessions(sessions, scans)?;
    settings.check()?;
    if elevation_bins < 3 {
        return Err(Error::invalid(
            "elevation_bins",
            format!("must be at least 3, got {elevation_bins}"),
        ));
    }
    let images: Vec<RangeImage3> = (0..scans)
        .into_par_iter()
        .map(|s| {
            let pts = &points[3 * offsets[s]..3 * offsets[s + 1]];
            RangeImage3::new(
                &poses[12 * s..12 * s + 12],
                pts,
                settings.bins,
                elevation_bins,
            )
        })
        .collect();
    Ok(judge_all(&images, points, 3, offsets, sessions, settings))
}

/// Every return of every scan judged by the other scans' range images (checked input).
fn judge_all<I: RangeImage>(
    images: &[I],
    points: &[f64],
    dim: usize,
    offsets: &[usize],
    sessions: Option<&[u32]>,
    settings: SeeThroughSettings,
) -> SeeThrough {
    let SeeThroughSettings {
        margin,
        max_range,
        min_gap,
        stride,
        ..
    } = settings;
    let same_session = |a: usize, b: usize| sessions.is_none_or(|v| v[a] == v[b]);
    // The scans by cubic cells of `max_range`: a return's judges lie in its cell's neighbours.
    let cell = |w: [f64; 3]| w.map(|v| (v / max_range).floor() as i64);
    let mut buckets: FxHashMap<[i64; 3], Vec<usize>> = FxHashMap::default();
    for (o, im) in images.iter().enumerate() {
        buckets.entry(cell(im.origin())).or_default().push(o);
    }
    let layers: &[i64] = if dim == 2 { &[0] } else { &[-1, 0, 1] };
    let range2 = max_range * max_range;
    #[allow(clippy::type_complexity)]
    let per_scan: Vec<(Vec<f64>, Vec<usize>, Vec<u32>, Vec<u32>)> = (0..images.len())
        .into_par_iter()
        .map(|s| {
            let me = &images[s];
            let local = &points[dim * offsets[s]..dim * offsets[s + 1]];
            let mut world = Vec::with_capacity(local.len() / stride + dim);
            let mut judged = Vec::new();
            let mut seen = Vec::new();
            let mut through = Vec::new();
            for (k, p) in local.chunks_exact(dim).enumerate() {
                let index = offsets[s] + k;
                if !index.is_multiple_of(stride) {
                    continue;
                }
                let w = me.to_world(p);
                world.extend_from_slice(&w[..dim]);
                let (mut a, mut b) = (0u32, 0u32);
                let [ci, cj, ck] = cell(w);
                for di in -1..=1 {
                    for dj in -1..=1 {
                        for &dk in layers {
                            let Some(near) = buckets.get(&[ci + di, cj + dj, ck + dk]) else {
                                continue;
                            };
                            for &o in near {
                                if same_session(o, s) && o.abs_diff(s) <= min_gap {
                                    continue;
                                }
                                let im = &images[o];
                                let c = im.origin();
                                let (dx, dy, dz) = (w[0] - c[0], w[1] - c[1], w[2] - c[2]);
                                if dx * dx + dy * dy + dz * dz > range2 {
                                    continue;
                                }
                                let (saw, past) = im.judge(w, margin);
                                a += u32::from(saw);
                                b += u32::from(past);
                            }
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
        world: Vec::new(),
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
    out
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
        let rows: Vec<f64> = g
            .judged
            .iter()
            .flat_map(|&i| [all.world[2 * i], all.world[2 * i + 1]])
            .collect();
        assert_eq!(g.world, rows);
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

    /// A 3D scan of a wall at `x = wall` over `y, z` in [-1, 1] m (5 cm apart), from `(x, 0, 0)`.
    fn wall_scan_3d(x: f64, wall: f64) -> Vec<f64> {
        (0..=40)
            .flat_map(|i| {
                (0..=40).flat_map(move |j| {
                    [
                        wall - x,
                        -1.0 + 0.05 * f64::from(i),
                        -1.0 + 0.05 * f64::from(j),
                    ]
                })
            })
            .collect()
    }

    /// `[R row-major, t]` of a turn by `yaw` about z at `t`.
    fn pose_3d(t: [f64; 3], yaw: f64) -> [f64; 12] {
        let (s, c) = yaw.sin_cos();
        [c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0, t[0], t[1], t[2]]
    }

    #[test]
    fn in_3d_a_wall_seen_twice_agrees_and_a_ghost_contradicts() {
        let poses = [pose_3d([0.0; 3], 0.0), pose_3d([0.5, 0.0, 0.0], 0.0)].concat();
        let pts = [wall_scan_3d(0.0, 3.0), wall_scan_3d(0.5, 3.0)].concat();
        let n = pts.len() / 3;
        let mid = 20 * 41 + 20; // y = z = 0
        let g = see_through_3d(&poses, &pts, &[0, n / 2, n], None, settings(90, 0.2), 45).unwrap();
        assert_eq!((g.seen[mid], g.seen_through[mid]), (1, 0));
        assert_eq!(g.world.len(), 3 * n);
        let pts = [wall_scan_3d(0.0, 3.0), wall_scan_3d(0.5, 4.0)].concat();
        let g = see_through_3d(&poses, &pts, &[0, n / 2, n], None, settings(90, 0.2), 45).unwrap();
        assert_eq!((g.seen[mid], g.seen_through[mid]), (1, 1));
        assert_eq!((g.seen[n / 2 + mid], g.seen_through[n / 2 + mid]), (0, 0));
        assert_eq!(
            &g.world[3 * (n / 2 + mid)..3 * (n / 2 + mid + 1)],
            &[4.0, 0.0, 0.0]
        );
        // The second scan turned by 90° and its points turned back: the same world, the same
        // verdicts.
        let turned = std::f64::consts::FRAC_PI_2;
        let back: Vec<f64> = wall_scan_3d(0.5, 4.0)
            .chunks_exact(3)
            .flat_map(|p| [p[1], -p[0], p[2]])
            .collect();
        let poses_t = [pose_3d([0.0; 3], 0.0), pose_3d([0.5, 0.0, 0.0], turned)].concat();
        let pts_t = [wall_scan_3d(0.0, 3.0), back].concat();
        let t = see_through_3d(
            &poses_t,
            &pts_t,
            &[0, n / 2, n],
            None,
            settings(90, 0.2),
            45,
        )
        .unwrap();
        assert_eq!((t.seen[mid], t.seen_through[mid]), (1, 1));
        let err = |r: Result<SeeThrough>| r.unwrap_err().to_string();
        assert!(err(see_through_3d(
            &poses[..11],
            &pts,
            &[0, n],
            None,
            settings(90, 0.2),
            45
        ))
        .starts_with("poses:"));
        assert!(err(see_through_3d(
            &poses,
            &pts,
            &[0, n / 2, n],
            None,
            settings(90, 0.2),
            2
        ))
        .starts_with("elevation_bins:"));
        assert!(err(see_through_3d(
            &poses,
            &pts[..4],
            &[0, 1, 1],
            None,
            settings(90, 0.2),
            45
        ))
        .starts_with("points:"));
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
