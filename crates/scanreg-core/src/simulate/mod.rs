//! Scan simulation: ray casting of 2D lasers and spinning multi-ring LiDARs against a
//! scene of primitives, with range noise, dropouts, moving objects and motion distortion.
//!
//! One code path serves 2D and 3D: a 2D floor plan is a 3D scene of vertical walls and
//! cylinders, cast with horizontal beams from a sensor moving in the plane.
//!
//! * The scene is a flat table of primitives ([`geometry::PRIM_COLUMNS`] per row), each at
//!   its position at `start_time` and moving with a constant velocity during the scan.
//! * Each beam `i` fires at `start_time + time_offsets[i]` from the sensor pose at that
//!   instant ([`motion::Motion`]), along its sensor-frame unit direction.
//! * Noise is drawn from a per-beam counter-based stream keyed by `(seed, i)`
//!   ([`rng::BeamRng`]), so the output is identical for any thread count.

pub mod bvh;
pub mod geometry;
pub mod motion;
pub mod rng;

use crate::error::{Error, Result};
use bvh::{Aabb, Bvh};
use geometry::{parse_primitives, Primitive};
use motion::{Motion, Rigid};
use nalgebra::Vector3;
use rayon::prelude::*;
use rng::BeamRng;

/// A return within `[min_range, max_range]`, kept.
pub const STATUS_VALID: u8 = 0;
/// No surface within `max_range`.
pub const STATUS_NO_RETURN: u8 = 1;
/// A surface within range, but the echo was lost (random dropout).
pub const STATUS_DROPOUT: u8 = 2;
/// A surface closer than `min_range`.
pub const STATUS_TOO_CLOSE: u8 = 3;

/// The range sensor's measurement model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RangeModel {
    pub min_range: f64,
    pub max_range: f64,
    /// Standard deviation of the additive Gaussian range noise (m).
    pub range_sigma: f64,
    /// Probability that a beam hitting a surface in range returns nothing.
    pub dropout_probability: f64,
    pub seed: u64,
}

impl RangeModel {
    fn validate(&self) -> Result<()> {
        if !(self.max_range.is_finite() && self.max_range > 0.0) {
            return Err(Error::invalid(
                "max_range",
                format!("must be finite and > 0, got {}", self.max_range),
            ));
        }
        if !(self.min_range.is_finite() && self.min_range >= 0.0 && self.min_range < self.max_range)
        {
            return Err(Error::invalid(
                "min_range",
                format!("must be in [0, max_range), got {}", self.min_range),
            ));
        }
        if !(self.range_sigma.is_finite() && self.range_sigma >= 0.0) {
            return Err(Error::invalid(
                "range_sigma",
                format!("must be finite and >= 0, got {}", self.range_sigma),
            ));
        }
        if !(0.0..=1.0).contains(&self.dropout_probability) {
            return Err(Error::invalid(
                "dropout_probability",
                format!("must be in [0, 1], got {}", self.dropout_probability),
            ));
        }
        Ok(())
    }
}

/// Per-beam output of [`cast`], all in beam order.
#[derive(Debug, Clone, PartialEq)]
pub struct Cast {
    /// Exact distance to the first surface; `inf` if none within `max_range`.
    pub true_range: Vec<f64>,
    /// Measured range (true + noise, floored at 0) for valid beams, `NaN` otherwise.
    pub range: Vec<f64>,
    /// One of the `STATUS_*` codes.
    pub status: Vec<u8>,
    /// Row of the primitive hit (within `max_range`), `-1` for none.
    pub hit: Vec<i64>,
    /// `N * 3`: the measured point in the sensor frame at the beam's own firing time (what a
    /// driver reports; motion-distorted when the sensor moves). `NaN` for invalid beams.
    pub points: Vec<f64>,
    /// `N * 3`: the same point in the sensor frame at `reference_time`, using the true
    /// motion (a perfectly deskewed scan). `NaN` for invalid beams.
    pub points_reference: Vec<f64>,
}

/// The beams of one scan in the sensor frame.
#[derive(Debug, Clone, Copy)]
pub struct Beams<'a> {
    /// `N * 3` unit directions.
    pub directions: &'a [f64],
    /// `N` firing times relative to `start_time` (s).
    pub time_offsets: &'a [f64],
}

struct BeamOut {
    true_range: f64,
    range: f64,
    status: u8,
    hit: i64,
    point: [f64; 3],
    point_reference: [f64; 3],
}

/// Beams per parallel task; consecutive beams often share a firing time (one column of a
/// spinning LiDAR), so each task caches the last pose it computed.
const BEAM_CHUNK: usize = 1024;

struct Scene {
    prims: Vec<Primitive>,
    planes: Vec<usize>,
    bvh: Bvh,
}

impl Scene {
    fn new(table: &[f64], dt_min: f64, dt_max: f64) -> Result<Scene> {
        let prims = parse_primitives(table)?;
        let mut planes = Vec::new();
        let mut items = Vec::new();
        for (i, p) in prims.iter().enumerate() {
            match p.shape.bounds() {
                None => planes.push(i),
                Some((mut lo, mut hi)) => {
                    // Moving primitives: bounds swept over the scan's time span.
                    for k in 0..3 {
                        let (a, b) = (p.velocity[k] * dt_min, p.velocity[k] * dt_max);
                        lo[k] += a.min(b);
                        hi[k] += a.max(b);
                    }
                    items.push((i, Aabb { lo, hi }));
                }
            }
        }
        Ok(Scene {
            bvh: Bvh::build(&items),
            prims,
            planes,
        })
    }

    /// Closest hit `(t, row)` within `t_max` of the world ray fired `dt` after scene time.
    fn closest(&self, o: [f64; 3], d: [f64; 3], dt: f64, t_max: f64) -> Option<(f64, usize)> {
        let intersect = |id: usize| {
            let p = &self.prims[id];
            // A primitive moving at v is hit by the ray as if the ray moved at -v.
            let o = if p.is_moving() {
                [
                    o[0] - p.velocity[0] * dt,
                    o[1] - p.velocity[1] * dt,
                    o[2] - p.velocity[2] * dt,
                ]
            } else {
                o
            };
            p.shape.intersect(o, d)
        };
        let mut best: Option<(f64, usize)> = None;
        for &id in &self.planes {
            if let Some(t) = intersect(id) {
                if t <= t_max && best.is_none_or(|(bt, _)| t < bt) {
                    best = Some((t, id));
                }
            }
        }
        let limit = best.map_or(t_max, |(t, _)| t);
        match self.bvh.closest(o, d, limit, intersect) {
            Some(hit) if best.is_none_or(|(bt, _)| hit.0 < bt) && hit.0 <= t_max => Some(hit),
            _ => best,
        }
    }
}

/// Cast every beam of one scan. See the module docs for the model.
pub fn cast(
    primitives: &[f64],
    beams: Beams<'_>,
    start_time: f64,
    motion: &Motion,
    reference_time: f64,
    model: &RangeModel,
) -> Result<Cast> {
    model.validate()?;
    let n = beams.time_offsets.len();
    if beams.directions.len() != 3 * n {
        return Err(Error::invalid(
            "directions",
            format!(
                "expected {n} directions (one per time offset), got {} values",
                beams.directions.len()
            ),
        ));
    }
    if let Some(i) = beams.directions.chunks_exact(3).position(|d| {
        let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        !(norm.is_finite() && (norm - 1.0).abs() < 1e-6)
    }) {
        return Err(Error::invalid(
            "directions",
            format!("direction {i} is not a finite unit vector"),
        ));
    }
    if beams.time_offsets.iter().any(|t| !t.is_finite()) {
        return Err(Error::invalid("time_offsets", "contains NaN or inf"));
    }
    if !start_time.is_finite() {
        return Err(Error::invalid(
            "start_time",
            format!("must be finite, got {start_time}"),
        ));
    }
    if !reference_time.is_finite() {
        return Err(Error::invalid(
            "reference_time",
            format!("must be finite, got {reference_time}"),
        ));
    }
    let dt_min = beams.time_offsets.iter().copied().fold(0.0, f64::min);
    let dt_max = beams.time_offsets.iter().copied().fold(0.0, f64::max);
    let scene = Scene::new(primitives, dt_min, dt_max)?;
    let reference_inv = motion.pose_at(reference_time).inverse();

    let mut out = Cast {
        true_range: vec![0.0; n],
        range: vec![0.0; n],
        status: vec![0; n],
        hit: vec![0; n],
        points: vec![0.0; 3 * n],
        points_reference: vec![0.0; 3 * n],
    };
    // Each task writes its own fixed range of beams straight into the outputs.
    out.true_range
        .par_chunks_mut(BEAM_CHUNK)
        .zip(out.range.par_chunks_mut(BEAM_CHUNK))
        .zip(out.status.par_chunks_mut(BEAM_CHUNK))
        .zip(out.hit.par_chunks_mut(BEAM_CHUNK))
        .zip(out.points.par_chunks_mut(3 * BEAM_CHUNK))
        .zip(out.points_reference.par_chunks_mut(3 * BEAM_CHUNK))
        .enumerate()
        .for_each(
            |(c, (((((true_range, range), status), hit), points), points_reference))| {
                let mut cached: Option<(f64, Rigid, Rigid)> = None;
                for j in 0..true_range.len() {
                    let i = c * BEAM_CHUNK + j;
                    let dt = beams.time_offsets[i];
                    let (pose, to_reference) = match cached {
                        Some((t, p, r)) if t == dt => (p, r),
                        _ => {
                            let p = motion.pose_at(start_time + dt);
                            let r = reference_inv.compose(&p);
                            cached = Some((dt, p, r));
                            (p, r)
                        }
                    };
                    let ds = &beams.directions[3 * i..3 * i + 3];
                    let ds = Vector3::new(ds[0], ds[1], ds[2]);
                    let b = cast_beam(&scene, model, i as u64, dt, ds, &pose, &to_reference);
                    true_range[j] = b.true_range;
                    range[j] = b.range;
                    status[j] = b.status;
                    hit[j] = b.hit;
                    points[3 * j..3 * j + 3].copy_from_slice(&b.point);
                    points_reference[3 * j..3 * j + 3].copy_from_slice(&b.point_reference);
                }
            },
        );
    Ok(out)
}

fn cast_beam(
    scene: &Scene,
    model: &RangeModel,
    index: u64,
    dt: f64,
    dir_sensor: Vector3<f64>,
    pose: &Rigid,
    to_reference: &Rigid,
) -> BeamOut {
    let d = pose.r * dir_sensor;
    let o = [pose.t.x, pose.t.y, pose.t.z];
    let hit = scene.closest(o, [d.x, d.y, d.z], dt, model.max_range);
    // Always draw both numbers so a beam's noise does not depend on the others' fate.
    let mut rng = BeamRng::new(model.seed, index);
    let u = rng.uniform();
    let z = rng.normal();
    let (true_range, id) = hit.map_or((f64::INFINITY, -1), |(t, id)| (t, id as i64));
    let status = if hit.is_none() {
        STATUS_NO_RETURN
    } else if true_range < model.min_range {
        STATUS_TOO_CLOSE
    } else if u < model.dropout_probability {
        STATUS_DROPOUT
    } else {
        STATUS_VALID
    };
    if status != STATUS_VALID {
        return BeamOut {
            true_range,
            range: f64::NAN,
            status,
            hit: id,
            point: [f64::NAN; 3],
            point_reference: [f64::NAN; 3],
        };
    }
    let range = (true_range + model.range_sigma * z).max(0.0);
    let p = dir_sensor * range;
    let q = to_reference.apply(p);
    BeamOut {
        true_range,
        range,
        status,
        hit: id,
        point: [p.x, p.y, p.z],
        point_reference: [q.x, q.y, q.z],
    }
}

#[cfg(test)]
mod tests;
