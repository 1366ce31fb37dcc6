//! Scene primitives and exact ray–primitive intersections.
//!
//! Every primitive is a closed **surface**: a ray reports the first crossing at a
//! parameter `t > EPS`, whether it enters or leaves the solid. A sensor inside a box
//! therefore sees the box's inner faces (a closed room or tunnel), inside a sphere its shell.
//!
//! Rays are `o + t d` with `|d| = 1`, so `t` is a range in metres.

use crate::error::{Error, Result};

/// Smallest accepted hit distance: avoids self-hits at the origin from round-off.
pub const EPS: f64 = 1e-9;

/// Columns of one primitive row in the flat scene table: `[kind, p0..p6, vx, vy, vz]`.
pub const PRIM_COLUMNS: usize = 11;

/// Kind codes of the scene table (column 0).
pub const KIND_PLANE: f64 = 0.0;
pub const KIND_BOX: f64 = 1.0;
pub const KIND_CYLINDER: f64 = 2.0;
pub const KIND_SPHERE: f64 = 3.0;
pub const KIND_WALL: f64 = 4.0;

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// Infinite plane `n · x = d` (`n` unit).
    Plane {
        n: [f64; 3],
        d: f64,
    },
    /// Box with centre `c`, half extents `h`, rotated by `yaw` about +z (cos, sin stored).
    Box {
        c: [f64; 3],
        h: [f64; 3],
        cos: f64,
        sin: f64,
    },
    /// Vertical cylinder with axis through `(cx, cy)`, from `z0` to `z1`, capped.
    Cylinder {
        cx: f64,
        cy: f64,
        z0: f64,
        z1: f64,
        r: f64,
    },
    Sphere {
        c: [f64; 3],
        r: f64,
    },
    /// Vertical rectangle over the segment `a → b` (xy), from `z0` to `z1`; zero thickness.
    Wall {
        a: [f64; 2],
        b: [f64; 2],
        z0: f64,
        z1: f64,
    },
}

/// A primitive and its constant velocity (m/s, world frame) relative to the scene time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Primitive {
    pub shape: Shape,
    pub velocity: [f64; 3],
}

impl Primitive {
    pub fn is_moving(&self) -> bool {
        self.velocity.iter().any(|v| *v != 0.0)
    }
}

fn bad(row: usize, msg: impl std::fmt::Display) -> Error {
    Error::invalid("primitives", format!("row {row}: {msg}"))
}

/// Parse the flat scene table (`n * PRIM_COLUMNS` values), validating every row.
pub fn parse_primitives(table: &[f64]) -> Result<Vec<Primitive>> {
    if !table.len().is_multiple_of(PRIM_COLUMNS) {
        return Err(Error::invalid(
            "primitives",
            format!(
                "length {} is not a multiple of {PRIM_COLUMNS} columns",
                table.len()
            ),
        ));
    }
    table
        .chunks_exact(PRIM_COLUMNS)
        .enumerate()
        .map(|(i, row)| parse_row(i, row))
        .collect()
}

fn parse_row(i: usize, row: &[f64]) -> Result<Primitive> {
    if let Some(k) = row.iter().position(|v| !v.is_finite()) {
        return Err(bad(i, format!("column {k} is not finite")));
    }
    let p = &row[1..8];
    let velocity = [row[8], row[9], row[10]];
    let positive = |v: f64, what: &str| -> Result<f64> {
        if v > 0.0 {
            Ok(v)
        } else {
            Err(bad(i, format!("{what} must be > 0, got {v}")))
        }
    };
    let shape = match row[0] {
        k if k == KIND_PLANE => {
            let norm = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            if norm < 1e-12 {
                return Err(bad(i, "plane normal is zero"));
            }
            if velocity.iter().any(|v| *v != 0.0) {
                return Err(bad(i, "planes are unbounded and cannot move"));
            }
            Shape::Plane {
                n: [p[0] / norm, p[1] / norm, p[2] / norm],
                d: p[3] / norm,
            }
        }
        k if k == KIND_BOX => Shape::Box {
            c: [p[0], p[1], p[2]],
            h: [
                positive(p[3], "half extent x")?,
                positive(p[4], "half extent y")?,
                positive(p[5], "half extent z")?,
            ],
            cos: p[6].cos(),
            sin: p[6].sin(),
        },
        k if k == KIND_CYLINDER => {
            if p[3] <= p[2] {
                return Err(bad(
                    i,
                    format!("cylinder top {} must exceed bottom {}", p[3], p[2]),
                ));
            }
            Shape::Cylinder {
                cx: p[0],
                cy: p[1],
                z0: p[2],
                z1: p[3],
                r: positive(p[4], "radius")?,
            }
        }
        k if k == KIND_SPHERE => Shape::Sphere {
            c: [p[0], p[1], p[2]],
            r: positive(p[3], "radius")?,
        },
        k if k == KIND_WALL => {
            if (p[2] - p[0]).hypot(p[3] - p[1]) < 1e-12 {
                return Err(bad(i, "wall has zero length"));
            }
            if p[5] <= p[4] {
                return Err(bad(
                    i,
                    format!("wall top {} must exceed bottom {}", p[5], p[4]),
                ));
            }
            Shape::Wall {
                a: [p[0], p[1]],
                b: [p[2], p[3]],
                z0: p[4],
                z1: p[5],
            }
        }
        k => return Err(bad(i, format!("unknown kind {k} (expected 0-4)"))),
    };
    Ok(Primitive { shape, velocity })
}

#[inline]
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The nearest root `> EPS` of `a t² + 2 b t + c = 0` that satisfies `accept`.
#[inline]
fn quadratic_first(a: f64, b: f64, c: f64, accept: impl Fn(f64) -> bool) -> Option<f64> {
    if a <= 0.0 {
        return None;
    }
    let disc = b * b - a * c;
    if disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    // Numerically stable pair of roots (no cancellation in -b ± sq).
    let q = if b > 0.0 { -(b + sq) } else { -b + sq };
    let (mut t0, mut t1) = if q != 0.0 { (q / a, c / q) } else { (0.0, 0.0) };
    if t0 > t1 {
        std::mem::swap(&mut t0, &mut t1);
    }
    [t0, t1].into_iter().find(|&t| t > EPS && accept(t))
}

impl Shape {
    /// Distance along the unit ray `o + t d` to the first surface crossing, if any.
    pub fn intersect(&self, o: [f64; 3], d: [f64; 3]) -> Option<f64> {
        match *self {
            Shape::Plane { n, d: dist } => {
                let denom = dot(n, d);
                if denom.abs() < 1e-15 {
                    return None;
                }
                let t = (dist - dot(n, o)) / denom;
                (t > EPS).then_some(t)
            }
            Shape::Sphere { c, r } => {
                let oc = [o[0] - c[0], o[1] - c[1], o[2] - c[2]];
                quadratic_first(1.0, dot(oc, d), dot(oc, oc) - r * r, |_| true)
            }
            Shape::Cylinder { cx, cy, z0, z1, r } => {
                let (ox, oy) = (o[0] - cx, o[1] - cy);
                let a = d[0] * d[0] + d[1] * d[1];
                let side =
                    quadratic_first(a, ox * d[0] + oy * d[1], ox * ox + oy * oy - r * r, |t| {
                        let z = o[2] + t * d[2];
                        z >= z0 && z <= z1
                    });
                let mut best = side;
                if d[2].abs() > 1e-15 {
                    for zc in [z0, z1] {
                        let t = (zc - o[2]) / d[2];
                        if t > EPS && best.is_none_or(|b| t < b) {
                            let (x, y) = (ox + t * d[0], oy + t * d[1]);
                            if x * x + y * y <= r * r {
                                best = Some(t);
                            }
                        }
                    }
                }
                best
            }
            Shape::Box { c, h, cos, sin } => {
                // Into the box frame: rotate by -yaw about z.
                let (px, py) = (o[0] - c[0], o[1] - c[1]);
                let lo = [cos * px + sin * py, -sin * px + cos * py, o[2] - c[2]];
                let ld = [cos * d[0] + sin * d[1], -sin * d[0] + cos * d[1], d[2]];
                let mut t_near = f64::NEG_INFINITY;
                let mut t_far = f64::INFINITY;
                for k in 0..3 {
                    if ld[k].abs() < 1e-15 {
                        if lo[k].abs() > h[k] {
                            return None;
                        }
                        continue;
                    }
                    let inv = 1.0 / ld[k];
                    let (mut a, mut b) = ((-h[k] - lo[k]) * inv, (h[k] - lo[k]) * inv);
                    if a > b {
                        std::mem::swap(&mut a, &mut b);
                    }
                    t_near = t_near.max(a);
                    t_far = t_far.min(b);
                }
                if t_near > t_far {
                    None
                } else if t_near > EPS {
                    Some(t_near)
                } else if t_far > EPS {
                    Some(t_far)
                } else {
                    None
                }
            }
            Shape::Wall { a, b, z0, z1 } => {
                // o + t d = a + s (b - a) in xy; cross products give t and s.
                let e = [b[0] - a[0], b[1] - a[1]];
                let denom = d[0] * e[1] - d[1] * e[0];
                if denom.abs() < 1e-15 {
                    return None;
                }
                let w = [a[0] - o[0], a[1] - o[1]];
                let t = (w[0] * e[1] - w[1] * e[0]) / denom;
                let s = (w[0] * d[1] - w[1] * d[0]) / denom;
                let z = o[2] + t * d[2];
                (t > EPS && (0.0..=1.0).contains(&s) && z >= z0 && z <= z1).then_some(t)
            }
        }
    }

    /// Axis-aligned bounds, or `None` for unbounded shapes (planes).
    pub fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        match *self {
            Shape::Plane { .. } => None,
            Shape::Sphere { c, r } => Some((
                [c[0] - r, c[1] - r, c[2] - r],
                [c[0] + r, c[1] + r, c[2] + r],
            )),
            Shape::Cylinder { cx, cy, z0, z1, r } => {
                Some(([cx - r, cy - r, z0], [cx + r, cy + r, z1]))
            }
            Shape::Box { c, h, cos, sin } => {
                let ex = cos.abs() * h[0] + sin.abs() * h[1];
                let ey = sin.abs() * h[0] + cos.abs() * h[1];
                Some((
                    [c[0] - ex, c[1] - ey, c[2] - h[2]],
                    [c[0] + ex, c[1] + ey, c[2] + h[2]],
                ))
            }
            Shape::Wall { a, b, z0, z1 } => Some((
                [a[0].min(b[0]), a[1].min(b[1]), z0],
                [a[0].max(b[0]), a[1].max(b[1]), z1],
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(v: [f64; 3]) -> [f64; 3] {
        let n = dot(v, v).sqrt();
        [v[0] / n, v[1] / n, v[2] / n]
    }

    #[test]
    fn plane_at_known_height() {
        let ground = Shape::Plane {
            n: [0.0, 0.0, 1.0],
            d: -1.8,
        };
        let el: f64 = -0.3;
        let d = [el.cos(), 0.0, el.sin()];
        let t = ground.intersect([0.0; 3], d).unwrap();
        assert!((t - 1.8 / (-el).sin()).abs() < 1e-12);
        assert!(ground.intersect([0.0; 3], [1.0, 0.0, 0.0]).is_none());
        assert!(ground.intersect([0.0; 3], unit([1.0, 0.0, 0.1])).is_none());
    }

    #[test]
    fn sphere_outside_and_inside() {
        let s = Shape::Sphere {
            c: [5.0, 0.0, 0.0],
            r: 1.0,
        };
        assert!((s.intersect([0.0; 3], [1.0, 0.0, 0.0]).unwrap() - 4.0).abs() < 1e-12);
        assert!((s.intersect([5.0, 0.0, 0.0], [0.0, 1.0, 0.0]).unwrap() - 1.0).abs() < 1e-12);
        assert!(s.intersect([0.0; 3], [-1.0, 0.0, 0.0]).is_none());
    }

    #[test]
    fn cylinder_side_cap_and_miss() {
        let c = Shape::Cylinder {
            cx: 10.0,
            cy: 0.0,
            z0: -1.0,
            z1: 3.0,
            r: 0.5,
        };
        // Horizontal ray: hits the side at 9.5.
        assert!((c.intersect([0.0; 3], [1.0, 0.0, 0.0]).unwrap() - 9.5).abs() < 1e-12);
        // Offset by y = 0.3: chord geometry, x = 10 - sqrt(0.25 - 0.09).
        let t = c.intersect([0.0, 0.3, 0.0], [1.0, 0.0, 0.0]).unwrap();
        assert!((t - (10.0 - (0.16f64).sqrt())).abs() < 1e-12);
        // From above, straight down onto the cap.
        let t = c.intersect([10.1, 0.0, 5.0], [0.0, 0.0, -1.0]).unwrap();
        assert!((t - 2.0).abs() < 1e-12);
        // Passes over the top.
        assert!(c.intersect([0.0, 0.0, 4.0], [1.0, 0.0, 0.0]).is_none());
    }

    #[test]
    fn box_from_outside_rotated_and_from_inside() {
        let b = Shape::Box {
            c: [0.0; 3],
            h: [2.0, 1.0, 1.0],
            cos: 1.0,
            sin: 0.0,
        };
        // Inside: the inner face.
        assert!((b.intersect([0.0; 3], [1.0, 0.0, 0.0]).unwrap() - 2.0).abs() < 1e-12);
        assert!((b.intersect([0.0; 3], [0.0, -1.0, 0.0]).unwrap() - 1.0).abs() < 1e-12);
        // Rotated 90°: the long axis now along y.
        let yaw = std::f64::consts::FRAC_PI_2;
        let r = Shape::Box {
            c: [5.0, 0.0, 0.0],
            h: [2.0, 1.0, 1.0],
            cos: yaw.cos(),
            sin: yaw.sin(),
        };
        assert!((r.intersect([0.0; 3], [1.0, 0.0, 0.0]).unwrap() - 4.0).abs() < 1e-12);
        assert!(r.intersect([0.0, 2.5, 0.0], [1.0, 0.0, 0.0]).is_none());
        let (lo, hi) = r.bounds().unwrap();
        assert!((lo[0] - 4.0).abs() < 1e-12 && (hi[1] - 2.0).abs() < 1e-12);
    }

    #[test]
    fn wall_hits_within_segment_and_height() {
        let w = Shape::Wall {
            a: [3.0, -1.0],
            b: [3.0, 1.0],
            z0: 0.0,
            z1: 2.0,
        };
        let d = unit([1.0, 0.3, 0.0]);
        let t = w.intersect([0.0, 0.0, 1.0], d).unwrap();
        assert!((t - 3.0 * (1.09f64).sqrt()).abs() < 1e-12);
        assert!(w
            .intersect([0.0, 0.0, 1.0], unit([1.0, 0.9, 0.0]))
            .is_none());
        assert!(w.intersect([0.0, 0.0, 2.5], [1.0, 0.0, 0.0]).is_none());
    }

    #[test]
    fn parse_rejects_bad_rows() {
        let mut row = vec![0.0; PRIM_COLUMNS];
        row[0] = KIND_SPHERE;
        row[4] = -1.0;
        let err = parse_primitives(&row).unwrap_err().to_string();
        assert!(
            err.contains("primitives") && err.contains("radius"),
            "{err}"
        );
        row[0] = 9.0;
        assert!(parse_primitives(&row)
            .unwrap_err()
            .to_string()
            .contains("unknown kind"));
        row[0] = KIND_SPHERE;
        row[4] = f64::NAN;
        assert!(parse_primitives(&row)
            .unwrap_err()
            .to_string()
            .contains("not finite"));
        assert!(parse_primitives(&row[..5]).is_err());
    }
}
