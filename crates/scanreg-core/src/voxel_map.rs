//! A bounded voxel-hash point map, updated in place: the local map of LiDAR odometry.
//!
//! Each occupied voxel owns one fixed-size *slot* of `max_per_voxel` points in flat arrays, so a
//! point's id (`slot * max_per_voxel + k`) indexes the points and their attributes (unit
//! normals or covariances, computed by the caller when the point is inserted) directly, and the
//! ICP loop reads the map without copying it. Inserting a frame touches only its voxels;
//! evicting far voxels returns their slots to a free list. Nothing is rebuilt per frame.
//!
//! A voxel stops accepting points once it holds `max_per_voxel`, and a new point closer than
//! `min_spacing` to a point already in its voxel is dropped: the map keeps the first,
//! well-spread observations of each surface patch instead of piling up every sweep.

use crate::error::{Error, Result};
use crate::icp::NeighborSearch;
use crate::knn::voxel_of;
use crate::points::check_points;
use rustc_hash::FxHashMap;

/// What each map point carries besides its position.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Attributes {
    None,
    /// A unit normal per point (point-to-plane / point-to-line).
    Normals,
    /// A `dim x dim` covariance per point (GICP).
    Covariances,
}

impl Attributes {
    pub fn from_name(name: &str) -> Result<Self> {
        match name {
            "none" => Ok(Attributes::None),
            "normals" => Ok(Attributes::Normals),
            "covariances" => Ok(Attributes::Covariances),
            other => Err(Error::invalid(
                "attributes",
                format!("unknown {other:?}; expected 'none', 'normals' or 'covariances'"),
            )),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Attributes::None => "none",
            Attributes::Normals => "normals",
            Attributes::Covariances => "covariances",
        }
    }
}

/// The map's points in slot order (a deterministic order for a given history of updates).
#[derive(Debug, Clone, PartialEq)]
pub struct MapContents {
    pub points: Vec<f64>,
    /// `len * dim` when the map stores normals, else empty.
    pub normals: Vec<f64>,
    /// `len * dim * dim` when the map stores covariances, else empty.
    pub covariances: Vec<f64>,
}

pub struct VoxelMap {
    dim: usize,
    voxel_size: f64,
    inv: f64,
    max_per_voxel: usize,
    min_spacing_sq: f64,
    attributes: Attributes,
    slots: FxHashMap<[i64; 3], u32>,
    /// Per slot: its voxel key and how many points it holds (0 for a free slot).
    keys: Vec<[i64; 3]>,
    counts: Vec<u32>,
    points: Vec<f64>,
    normals: Vec<f64>,
    covariances: Vec<f64>,
    free: Vec<u32>,
    len: usize,
}

fn positive(arg: &'static str, v: f64) -> Result<f64> {
    if !v.is_finite() || v <= 0.0 {
        return Err(Error::invalid(
            arg,
            format!("must be finite and > 0, got {v}"),
        ));
    }
    Ok(v)
}

fn check_attribute(arg: &'static str, data: &[f64], expected: usize) -> Result<()> {
    if data.len() != expected {
        return Err(Error::invalid(
            arg,
            format!("expected {expected} values, got {}", data.len()),
        ));
    }
    if data.iter().any(|v| !v.is_finite()) {
        return Err(Error::invalid(arg, "contains NaN or inf"));
    }
    Ok(())
}

impl VoxelMap {
    pub fn new(
        dim: usize,
        voxel_size: f64,
        max_per_voxel: usize,
        min_spacing: f64,
        attributes: Attributes,
    ) -> Result<Self> {
        if dim != 2 && dim != 3 {
            return Err(Error::invalid("dim", format!("must be 2 or 3, got {dim}")));
        }
        let voxel_size = positive("voxel_size", voxel_size)?;
        if !(1..=1024).contains(&max_per_voxel) {
            return Err(Error::invalid(
                "max_points_per_voxel",
                format!("must be in 1..=1024, got {max_per_voxel}"),
            ));
        }
        if !min_spacing.is_finite() || min_spacing < 0.0 {
            return Err(Error::invalid(
                "min_spacing",
                format!("must be finite and >= 0, got {min_spacing}"),
            ));
        }
        Ok(VoxelMap {
            dim,
            voxel_size,
            inv: 1.0 / voxel_size,
            max_per_voxel,
            min_spacing_sq: min_spacing * min_spacing,
            attributes,
            slots: FxHashMap::default(),
            keys: Vec::new(),
            counts: Vec::new(),
            points: Vec::new(),
            normals: Vec::new(),
            covariances: Vec::new(),
            free: Vec::new(),
            len: 0,
        })
    }

    pub fn dim(&self) -> usize {
        self.dim
    }

    pub fn voxel_size(&self) -> f64 {
        self.voxel_size
    }

    pub fn max_per_voxel(&self) -> usize {
        self.max_per_voxel
    }

    pub fn attributes(&self) -> Attributes {
        self.attributes
    }

    /// Number of points held.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn num_voxels(&self) -> usize {
        self.slots.len()
    }

    /// Flat normals indexed by point id (zeros at unused ids), when the map stores normals.
    pub fn normals(&self) -> Option<&[f64]> {
        (self.attributes == Attributes::Normals).then_some(self.normals.as_slice())
    }

    /// Flat covariances indexed by point id, when the map stores covariances.
    pub fn covariances(&self) -> Option<&[f64]> {
        (self.attributes == Attributes::Covariances).then_some(self.covariances.as_slice())
    }

    fn key(&self, p: &[f64]) -> Result<[i64; 3]> {
        voxel_of(p, self.inv).ok_or_else(|| {
            Error::invalid(
                "points",
                format!(
                    "coordinates too large for voxel size {} (|p| / voxel_size >= 9e15)",
                    self.voxel_size
                ),
            )
        })
    }

    fn allocate(&mut self, key: [i64; 3]) -> u32 {
        let slot = match self.free.pop() {
            Some(s) => {
                self.keys[s as usize] = key;
                s
            }
            None => {
                let s = self.keys.len() as u32;
                let cap = self.max_per_voxel;
                self.keys.push(key);
                self.counts.push(0);
                self.points.resize(self.points.len() + cap * self.dim, 0.0);
                match self.attributes {
                    Attributes::None => {}
                    Attributes::Normals => self
                        .normals
                        .resize(self.normals.len() + cap * self.dim, 0.0),
                    Attributes::Covariances => self
                        .covariances
                        .resize(self.covariances.len() + cap * self.dim * self.dim, 0.0),
                }
                s
            }
        };
        self.slots.insert(key, slot);
        slot
    }

    /// Add points (world frame) with their attributes (`normals`: `N * dim`, unit length;
    /// `covariances`: `N * dim * dim`), as the map's `attributes` require. Returns how many were
    /// kept. Validates everything before changing the map.
    pub fn insert(
        &mut self,
        points: &[f64],
        normals: Option<&[f64]>,
        covariances: Option<&[f64]>,
    ) -> Result<usize> {
        let dim = self.dim;
        let n = check_points("points", points, dim)?;
        let keys = points
            .chunks_exact(dim)
            .map(|p| self.key(p))
            .collect::<Result<Vec<_>>>()?;
        match (self.attributes, normals, covariances) {
            (Attributes::None, None, None) => {}
            (Attributes::Normals, Some(nrm), None) => check_attribute("normals", nrm, n * dim)?,
            (Attributes::Covariances, None, Some(c)) => {
                check_attribute("covariances", c, n * dim * dim)?
            }
            (a, _, _) => {
                return Err(Error::invalid(
                    "attributes",
                    format!(
                        "this map stores {}: pass exactly those (normals given: {}, covariances given: {})",
                        a.name(),
                        normals.is_some(),
                        covariances.is_some()
                    ),
                ))
            }
        }
        let cap = self.max_per_voxel;
        let mut kept = 0;
        for (i, key) in keys.into_iter().enumerate() {
            let p = &points[i * dim..(i + 1) * dim];
            let slot = match self.slots.get(&key) {
                Some(&s) => s as usize,
                None => self.allocate(key) as usize,
            };
            let count = self.counts[slot] as usize;
            if count >= cap {
                continue;
            }
            let base = slot * cap;
            let crowded = (0..count).any(|k| {
                let q = &self.points[(base + k) * dim..(base + k + 1) * dim];
                let d: f64 = p.iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum();
                d < self.min_spacing_sq
            });
            if crowded {
                continue;
            }
            let id = base + count;
            self.points[id * dim..(id + 1) * dim].copy_from_slice(p);
            if let Some(nrm) = normals {
                self.normals[id * dim..(id + 1) * dim]
                    .copy_from_slice(&nrm[i * dim..(i + 1) * dim]);
            }
            if let Some(c) = covariances {
                let d2 = dim * dim;
                self.covariances[id * d2..(id + 1) * d2].copy_from_slice(&c[i * d2..(i + 1) * d2]);
            }
            self.counts[slot] += 1;
            self.len += 1;
            kept += 1;
        }
        Ok(kept)
    }

    /// Drop every voxel whose first point is farther than `max_distance` from `center`.
    /// Returns the number of points removed.
    pub fn remove_far(&mut self, center: &[f64], max_distance: f64) -> Result<usize> {
        if center.len() != self.dim || center.iter().any(|v| !v.is_finite()) {
            return Err(Error::invalid(
                "center",
                format!("expected {} finite values, got {:?}", self.dim, center),
            ));
        }
        let max_sq = positive("max_distance", max_distance)?.powi(2);
        let (dim, cap) = (self.dim, self.max_per_voxel);
        let mut removed = 0;
        let mut freed = Vec::new();
        self.slots.retain(|_, &mut slot| {
            let s = slot as usize;
            let p = &self.points[s * cap * dim..(s * cap + 1) * dim];
            let d: f64 = p.iter().zip(center).map(|(a, b)| (a - b) * (a - b)).sum();
            let keep = d <= max_sq;
            if !keep {
                removed += self.counts[s] as usize;
                freed.push(slot);
            }
            keep
        });
        for slot in freed {
            self.counts[slot as usize] = 0;
            self.free.push(slot);
        }
        // Lowest slots first: reuse keeps the arrays compact and the order deterministic.
        self.free.sort_unstable_by(|a, b| b.cmp(a));
        self.len -= removed;
        Ok(removed)
    }

    /// Every point (and attribute) in slot order.
    pub fn contents(&self) -> MapContents {
        let (dim, cap) = (self.dim, self.max_per_voxel);
        let d2 = dim * dim;
        let mut out = MapContents {
            points: Vec::with_capacity(self.len * dim),
            normals: Vec::new(),
            covariances: Vec::new(),
        };
        for (s, &count) in self.counts.iter().enumerate() {
            let (a, b) = (s * cap, s * cap + count as usize);
            out.points.extend_from_slice(&self.points[a * dim..b * dim]);
            match self.attributes {
                Attributes::None => {}
                Attributes::Normals => out
                    .normals
                    .extend_from_slice(&self.normals[a * dim..b * dim]),
                Attributes::Covariances => out
                    .covariances
                    .extend_from_slice(&self.covariances[a * d2..b * d2]),
            }
        }
        out
    }

    fn scan_nearest(&self, q: &[f64], max_sq: f64, slot: usize, best: &mut Option<(usize, f64)>) {
        let (dim, cap) = (self.dim, self.max_per_voxel);
        for k in 0..self.counts[slot] as usize {
            let j = slot * cap + k;
            let p = &self.points[j * dim..(j + 1) * dim];
            let d: f64 = p.iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum();
            if d <= max_sq && best.is_none_or(|(bi, bd)| d < bd || (d == bd && j < bi)) {
                *best = Some((j, d));
            }
        }
    }
}

impl NeighborSearch for VoxelMap {
    fn dim(&self) -> usize {
        self.dim
    }

    fn id_count(&self) -> usize {
        self.counts.len() * self.max_per_voxel
    }

    fn points(&self) -> &[f64] {
        &self.points
    }

    fn attributes_validated(&self) -> bool {
        true // checked on insertion
    }

    /// Exact: visits the voxels the gate's bounding box overlaps (per axis
    /// `floor((q - g) / v) ..= floor((q + g) / v)`), or every occupied voxel when that is fewer.
    fn nearest_within(&self, q: &[f64], max_sq: f64) -> Option<(usize, f64)> {
        let g = max_sq.sqrt();
        let mut lo = [0i64; 3];
        let mut hi = [0i64; 3];
        let mut visits = 1.0;
        for c in 0..self.dim {
            let a = ((q[c] - g) * self.inv).floor();
            let b = ((q[c] + g) * self.inv).floor();
            visits *= b - a + 1.0;
            if !(a.abs() < 9.0e15 && b.abs() < 9.0e15) {
                visits = f64::INFINITY;
                break;
            }
            lo[c] = a as i64;
            hi[c] = b as i64;
        }
        let mut best = None;
        if visits > self.slots.len() as f64 {
            for &slot in self.slots.values() {
                self.scan_nearest(q, max_sq, slot as usize, &mut best);
            }
            return best;
        }
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    if let Some(&slot) = self.slots.get(&[x, y, z]) {
                        self.scan_nearest(q, max_sq, slot as usize, &mut best);
                    }
                }
            }
        }
        best
    }
}

#[cfg(test)]
mod tests;
