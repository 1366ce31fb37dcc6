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
use crate::normals::plane_covariance;
use crate::points::voxel_of;
use crate::points::{check_points, floor};
use crate::reduce::MIN_PAR_ITEMS;
use rayon::prelude::*;
use rustc_hash::FxHashMap;
use std::sync::OnceLock;

/// What each map point carries besides its position.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Attributes {
    None,
    /// A unit normal per point (point-to-plane / point-to-line).
    Normals,
    /// A `dim x dim` covariance per point (GICP), given by the caller.
    Covariances,
    /// GICP covariances the map computes itself: each voxel's points' sample covariance,
    /// regularised as a plane (eigenvalues `(ε, 1, 1)` / `(ε, 1)`, Segal et al. 2009), shared
    /// by its points and refreshed for the voxels an insertion touches. A voxel with fewer
    /// than `dim + 2` points gets the identity (a point-to-point-like factor).
    VoxelCovariances,
}

impl Attributes {
    pub fn from_name(name: &str) -> Result<Self> {
        match name {
            "none" => Ok(Attributes::None),
            "normals" => Ok(Attributes::Normals),
            "covariances" => Ok(Attributes::Covariances),
            "voxel_covariances" => Ok(Attributes::VoxelCovariances),
            other => Err(Error::invalid(
                "attributes",
                format!(
                    "unknown {other:?}; expected 'none', 'normals', 'covariances' or \
                     'voxel_covariances'"
                ),
            )),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Attributes::None => "none",
            Attributes::Normals => "normals",
            Attributes::Covariances => "covariances",
            Attributes::VoxelCovariances => "voxel_covariances",
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

#[derive(Debug, Clone, Copy)]
struct Entry {
    slot: u32,
    count: u32,
}

pub struct VoxelMap {
    dim: usize,
    voxel_size: f64,
    inv: f64,
    max_per_voxel: usize,
    min_spacing_sq: f64,
    attributes: Attributes,
    /// Voxel key -> its slot and point count (the count here too, so a search reads one
    /// table entry instead of the entry and then `counts`: a cache miss less per voxel).
    slots: FxHashMap<u64, Entry>,
    /// Per slot: its voxel key and how many points it holds (0 for a free slot).
    keys: Vec<u64>,
    counts: Vec<u32>,
    points: Vec<f64>,
    normals: Vec<f64>,
    covariances: Vec<f64>,
    free: Vec<u32>,
    len: usize,
    /// Voxel indices are packed relative to this voxel (the first point inserted into an empty
    /// map), so the ±2^20-voxel range is around the map, not around the world origin: a map
    /// in UTM coordinates (10⁶-10⁷ m) works like one at the origin.
    base: [i64; 3],
    /// The occupied voxels by block, for wide gates (see [`Blocks`]); built by the first
    /// search that needs it after a change, dropped by every change.
    blocks: OnceLock<Blocks>,
}

/// Voxels per block edge in [`Blocks`].
const BLOCK: i64 = 4;
/// From this reach (voxels from the query's voxel to the gate box's edge) a search that the
/// 3^dim neighbours did not settle walks [`Blocks`] instead of shells: a shell walk costs a
/// hash lookup per voxel *volume* in the gate, `(2r + 1)^dim`, found or not.
const BLOCK_REACH: i64 = 4;

/// Occupied voxels grouped by block of `BLOCK^dim` voxels, with each voxel's table entry and
/// integer coordinates (relative to `base`). A wide gate (the odometry's adaptive gate reaches
/// 10-15 m at 1 m voxels when a fast turn defeats the constant-velocity prediction) then costs
/// a lookup per *block* in the gate plus the occupied voxels near the query, instead of one per
/// voxel volume — or, past the occupied-voxel count, every point in the map.
struct Blocks {
    voxels: FxHashMap<u64, Vec<BlockVoxel>>,
}

/// An occupied voxel of a block: its table entry and its indices (relative to `base`).
type BlockVoxel = (Entry, [i64; 3]);

/// The inverse of [`pack`].
#[inline]
fn unpack(key: u64) -> [i64; 3] {
    const OFF: i64 = 1 << 20;
    const MASK: u64 = (1 << 21) - 1;
    [
        ((key >> 42) & MASK) as i64 - OFF,
        ((key >> 21) & MASK) as i64 - OFF,
        (key & MASK) as i64 - OFF,
    ]
}

/// Voxel indices packed 21 bits per axis (offset by 2^20): one u64 hashes and compares in one
/// instruction. `None` outside ±2^20 voxels (±1048 km at 1 m voxels).
#[inline]
fn pack(x: i64, y: i64, z: i64) -> Option<u64> {
    const OFF: i64 = 1 << 20;
    let ok = |v: i64| (-OFF..OFF).contains(&v);
    (ok(x) && ok(y) && ok(z))
        .then(|| ((x + OFF) as u64) << 42 | ((y + OFF) as u64) << 21 | (z + OFF) as u64)
}

/// The 3^dim voxel offsets around (and including) a voxel: itself first, then those sharing a
/// face, an edge, a corner — roughly nearest first, so the best point is found early and the
/// farther boxes are skipped.
fn neighbour_offsets(dim: usize) -> &'static [[i64; 3]] {
    static OFFSETS: OnceLock<[Vec<[i64; 3]>; 2]> = OnceLock::new();
    let all = OFFSETS.get_or_init(|| {
        let build = |dim: usize| {
            let zs: &[i64] = if dim == 3 { &[-1, 0, 1] } else { &[0] };
            let mut v: Vec<[i64; 3]> = Vec::new();
            for x in -1..=1 {
                for y in -1..=1 {
                    for &z in zs {
                        v.push([x, y, z]);
                    }
                }
            }
            v.sort_by_key(|o| o.iter().filter(|&&c| c != 0).count());
            v
        };
        [build(2), build(3)]
    });
    &all[dim - 2]
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
            base: [0; 3],
            blocks: OnceLock::new(),
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

    /// Point ids that share one covariance row: `max_per_voxel` for voxel covariances (one
    /// row per voxel: its points' ids are `slot * max_per_voxel + k`), else 1.
    pub fn covariance_group(&self) -> usize {
        if self.attributes == Attributes::VoxelCovariances {
            self.max_per_voxel
        } else {
            1
        }
    }

    /// Flat covariances, row `id / covariance_group()` for point `id`, when the map stores
    /// covariances.
    pub fn covariances(&self) -> Option<&[f64]> {
        matches!(
            self.attributes,
            Attributes::Covariances | Attributes::VoxelCovariances
        )
        .then_some(self.covariances.as_slice())
    }

    /// [`pack`] relative to `base`.
    #[inline]
    fn pack(&self, x: i64, y: i64, z: i64) -> Option<u64> {
        let [bx, by, bz] = self.base;
        pack(x.checked_sub(bx)?, y.checked_sub(by)?, z.checked_sub(bz)?)
    }

    fn key(&self, p: &[f64]) -> Result<u64> {
        voxel_of(p, self.inv)
            .and_then(|[x, y, z]| self.pack(x, y, z))
            .ok_or_else(|| {
                Error::invalid(
                    "points",
                    format!(
                        "coordinates too far from the map's first point for voxel size {} (more \
                         than 2^20 voxels along an axis)",
                        self.voxel_size
                    ),
                )
            })
    }

    fn allocate(&mut self, key: u64) -> u32 {
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
                    Attributes::Covariances | Attributes::VoxelCovariances => {
                        let rows = cap / self.covariance_group();
                        self.covariances
                            .resize(self.covariances.len() + rows * self.dim * self.dim, 0.0)
                    }
                }
                s
            }
        };
        self.slots.insert(key, Entry { slot, count: 0 });
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
        self.blocks = OnceLock::new();
        if self.slots.is_empty() && n > 0 {
            // No key is stored: re-anchor at the first point (see `base`).
            if let Some(v) = voxel_of(&points[..dim], self.inv) {
                self.base = v;
            }
        }
        let keys = points
            .par_chunks_exact(dim)
            .with_min_len(4096)
            .map(|p| self.key(p))
            .collect::<Result<Vec<_>>>()?;
        match (self.attributes, normals, covariances) {
            (Attributes::None | Attributes::VoxelCovariances, None, None) => {}
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
        let mut touched: Vec<usize> = Vec::new();
        // Sweeps arrive in scan order, so consecutive points mostly share a voxel: the last
        // voxel's slot is remembered, and the table entries' counts are brought up to date once
        // at the end (from `counts`, which this loop keeps).
        let mut last: Option<(u64, usize)> = None;
        for (i, key) in keys.into_iter().enumerate() {
            let p = &points[i * dim..(i + 1) * dim];
            let slot = match last {
                Some((k, s)) if k == key => s,
                _ => {
                    let s = match self.slots.get(&key) {
                        Some(e) => e.slot as usize,
                        None => self.allocate(key) as usize,
                    };
                    last = Some((key, s));
                    s
                }
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
            if touched.last() != Some(&slot) {
                touched.push(slot);
            }
        }
        touched.sort_unstable();
        touched.dedup();
        for &slot in &touched {
            if let Some(e) = self.slots.get_mut(&self.keys[slot]) {
                e.count = self.counts[slot];
            }
        }
        if self.attributes != Attributes::VoxelCovariances {
            return Ok(kept);
        }
        // Each voxel's covariance depends on its own points only: computed in parallel, then
        // written (the same values whatever the thread count).
        let d2 = dim * dim;
        let fresh: Vec<[f64; 9]> = touched
            .par_iter()
            .with_min_len(MIN_PAR_ITEMS)
            .map(|&slot| self.voxel_covariance(slot))
            .collect();
        for (&slot, cov) in touched.iter().zip(&fresh) {
            self.covariances[slot * d2..(slot + 1) * d2].copy_from_slice(&cov[..d2]);
        }
        Ok(kept)
    }

    /// The plane-regularised covariance of one voxel's points (its slot's single covariance
    /// row).
    fn voxel_covariance(&self, slot: usize) -> [f64; 9] {
        let (dim, cap) = (self.dim, self.max_per_voxel);
        let count = self.counts[slot] as usize;
        let pts = &self.points[slot * cap * dim..(slot * cap + count) * dim];
        let mut mean = [0.0; 3];
        for p in pts.chunks_exact(dim) {
            for c in 0..dim {
                mean[c] += p[c] / count as f64;
            }
        }
        let mut m = [0.0; 9];
        for p in pts.chunks_exact(dim) {
            for a in 0..dim {
                for b in 0..dim {
                    m[a * dim + b] += (p[a] - mean[a]) * (p[b] - mean[b]);
                }
            }
        }
        plane_covariance(&m, count, dim)
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
        self.blocks = OnceLock::new();
        let (dim, cap) = (self.dim, self.max_per_voxel);
        let mut removed = 0;
        let mut freed = Vec::new();
        self.slots.retain(|_, &mut Entry { slot, .. }| {
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
                Attributes::VoxelCovariances => {
                    for _ in 0..count {
                        out.covariances
                            .extend_from_slice(&self.covariances[s * d2..(s + 1) * d2]);
                    }
                }
            }
        }
        out
    }

    /// Nearest map point within `max_distance` (finite) of each query, in parallel:
    /// `(ids, squared distances)` with `-1` / `inf` where none.
    pub fn nearest_batch(
        &self,
        queries: &[f64],
        max_distance: f64,
    ) -> Result<(Vec<i64>, Vec<f64>)> {
        check_points("query_points", queries, self.dim)?;
        if !max_distance.is_finite() || max_distance < 0.0 {
            return Err(Error::invalid(
                "max_distance",
                format!("must be finite and >= 0, got {max_distance}"),
            ));
        }
        let max_sq = max_distance * max_distance;
        let found: Vec<(i64, f64)> = queries
            .par_chunks_exact(self.dim)
            .with_min_len(MIN_PAR_ITEMS)
            .map(|q| match self.nearest_within(q, max_sq) {
                Some((j, d)) => (j as i64, d),
                None => (-1, f64::INFINITY),
            })
            .collect();
        Ok(found.into_iter().unzip())
    }

    fn group_blocks(&self) -> Blocks {
        let mut voxels: FxHashMap<u64, Vec<BlockVoxel>> = FxHashMap::default();
        for (&key, &e) in &self.slots {
            let v = unpack(key);
            let [bx, by, bz] = v.map(|i| i.div_euclid(BLOCK));
            let block = pack(bx, by, bz).expect("a block index is within the voxel index range");
            voxels.entry(block).or_default().push((e, v));
        }
        Blocks { voxels }
    }

    /// Squared distance from `q` to the box of `size` voxels per edge whose lowest voxel is
    /// `corner` (relative to `base`), shrunk per side by a millionth of a voxel (plus a
    /// rounding error of `q`): a point's voxel comes from rounding `p / v`, so the point can
    /// lie that far outside its voxel's box, and a skip must never miss it.
    fn box_sq(&self, q: &[f64], corner: [i64; 3], size: i64) -> f64 {
        let mut sum = 0.0;
        for c in 0..self.dim {
            let a = (corner[c] + self.base[c]) as f64 * self.voxel_size;
            let b = a + size as f64 * self.voxel_size;
            let gap = if q[c] < a {
                a - q[c]
            } else if q[c] > b {
                q[c] - b
            } else {
                0.0
            };
            let gap = (gap - 1e-6 * self.voxel_size - 1e-12 * q[c].abs()).max(0.0);
            sum += gap * gap;
        }
        sum
    }

    /// The rest of a wide search (gate box `lo..=hi`, absolute voxel indices): the blocks the
    /// box overlaps, nearest first, the walk ending at the first block farther than the best
    /// point so far; in each block, the voxels not farther than it. Exact, and equal to the
    /// shell walk: a voxel the neighbour pass already scanned is scanned again, which changes
    /// nothing (the best is the least `(distance, id)` in any order).
    fn search_blocks(
        &self,
        q: &[f64],
        max_sq: f64,
        lo: &[i64; 3],
        hi: &[i64; 3],
        best: &mut Option<(usize, f64)>,
    ) {
        let blocks = self.blocks.get_or_init(|| self.group_blocks());
        let mut blo = [0i64; 3];
        let mut bhi = [0i64; 3];
        let mut in_box = 1.0;
        for c in 0..self.dim {
            blo[c] = (lo[c] - self.base[c]).div_euclid(BLOCK);
            bhi[c] = (hi[c] - self.base[c]).div_euclid(BLOCK);
            in_box *= (bhi[c] - blo[c] + 1) as f64;
        }
        let block_sq = |b: [i64; 3]| self.box_sq(q, b.map(|i| i * BLOCK), BLOCK);
        let mut near: Vec<(f64, &[BlockVoxel])> = Vec::new();
        if in_box <= blocks.voxels.len() as f64 {
            for x in blo[0]..=bhi[0] {
                for y in blo[1]..=bhi[1] {
                    for z in blo[2]..=bhi[2] {
                        if let Some(v) = pack(x, y, z).and_then(|k| blocks.voxels.get(&k)) {
                            near.push((block_sq([x, y, z]), v));
                        }
                    }
                }
            }
        } else {
            for (&key, v) in &blocks.voxels {
                let b = unpack(key);
                if (0..self.dim).all(|c| (blo[c]..=bhi[c]).contains(&b[c])) {
                    near.push((block_sq(b), v));
                }
            }
        }
        near.retain(|&(d, _)| d <= max_sq);
        near.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        for (d, voxels) in near {
            // `>`, not `>=`: a point at exactly the best distance with a lower id still wins.
            if best.is_some_and(|(_, bd)| d > bd) {
                break;
            }
            for (e, v) in voxels {
                let vd = self.box_sq(q, *v, 1);
                if vd <= max_sq && !best.is_some_and(|(_, bd)| vd > bd) {
                    self.scan_nearest(q, max_sq, e, best);
                }
            }
        }
    }

    fn scan_nearest(&self, q: &[f64], max_sq: f64, e: &Entry, best: &mut Option<(usize, f64)>) {
        let (dim, cap) = (self.dim, self.max_per_voxel);
        for k in 0..e.count as usize {
            let j = e.slot as usize * cap + k;
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

    fn covariance_group(&self) -> usize {
        VoxelMap::covariance_group(self)
    }

    /// Exact: visits the voxels the gate's bounding box overlaps (per axis
    /// `floor((q - g) / v) ..= floor((q + g) / v)`), nearest first, or every occupied voxel
    /// when that is fewer; past `BLOCK_REACH` voxels, the occupied ones by block.
    fn nearest_within(&self, q: &[f64], max_sq: f64) -> Option<(usize, f64)> {
        let g = max_sq.sqrt();
        let mut lo = [0i64; 3];
        let mut hi = [0i64; 3];
        let mut visits = 1.0;
        for c in 0..self.dim {
            let a = floor((q[c] - g) * self.inv);
            let b = floor((q[c] + g) * self.inv);
            visits *= b - a + 1.0;
            if !(a.abs() < 9.0e15 && b.abs() < 9.0e15) {
                visits = f64::INFINITY;
                break;
            }
            lo[c] = a as i64;
            hi[c] = b as i64;
        }
        let mut best = None;
        let wide = (0..self.dim).any(|c| hi[c] - lo[c] > 2 * BLOCK_REACH);
        if visits.is_infinite() || (visits > self.slots.len() as f64 && !wide) {
            for e in self.slots.values() {
                self.scan_nearest(q, max_sq, e, &mut best);
            }
            return best;
        }
        // The query's own voxel, then its neighbours nearest face first, each skipped when its
        // box is farther than the best point so far (most are: the hash lookups dominate).
        // Then shell by shell (Chebyshev distance r ≥ 2), clipped to the gate's box: a voxel
        // beyond shell r is more than r voxel sizes away along some axis, so once the best
        // distance is within r·v (plus `margin`) no further shell can beat it — exact, and
        // usually done after the first shell.
        let mut center = [0i64; 3];
        // Per axis, the distance from q to its voxel's lower and upper faces.
        let mut below = [0.0f64; 3];
        let mut above = [0.0f64; 3];
        for c in 0..self.dim {
            let f = floor(q[c] * self.inv);
            center[c] = f as i64;
            below[c] = (q[c] - f * self.voxel_size).max(0.0);
            above[c] = (self.voxel_size - below[c]).max(0.0);
        }
        // After shell r every unvisited point is farther than r·v plus this.
        let margin = (0..self.dim)
            .map(|c| below[c].min(above[c]))
            .fold(f64::INFINITY, f64::min);
        let reach = (0..self.dim)
            .map(|c| (center[c] - lo[c]).max(hi[c] - center[c]))
            .max()
            .unwrap_or(0);
        for off in neighbour_offsets(self.dim) {
            let mut box_sq = 0.0;
            for c in 0..self.dim {
                box_sq += match off[c] {
                    -1 => below[c] * below[c],
                    1 => above[c] * above[c],
                    _ => 0.0,
                };
            }
            // `>`, not `>=`: a point at exactly the best distance with a lower id still wins.
            if box_sq > max_sq || best.is_some_and(|(_, d)| box_sq > d) {
                continue;
            }
            let key = self.pack(center[0] + off[0], center[1] + off[1], center[2] + off[2]);
            if let Some(e) = key.and_then(|k| self.slots.get(&k)) {
                self.scan_nearest(q, max_sq, e, &mut best);
            }
        }
        let shell = self.voxel_size + margin;
        if reach <= 1 || best.is_some_and(|(_, d)| d <= shell * shell) {
            return best;
        }
        if reach >= BLOCK_REACH {
            self.search_blocks(q, max_sq, &lo, &hi, &mut best);
            return best;
        }
        for r in 2..=reach {
            let x0 = (center[0] - r).max(lo[0]);
            let x1 = (center[0] + r).min(hi[0]);
            let y0 = (center[1] - r).max(lo[1]);
            let y1 = (center[1] + r).min(hi[1]);
            let z0 = (center[2] - r).max(lo[2]);
            let z1 = (center[2] + r).min(hi[2]);
            for x in x0..=x1 {
                let x_edge = (x - center[0]).abs() == r;
                for y in y0..=y1 {
                    let on_shell = x_edge || (y - center[1]).abs() == r;
                    let mut visit = |z: i64| {
                        if let Some(e) = self.pack(x, y, z).and_then(|k| self.slots.get(&k)) {
                            self.scan_nearest(q, max_sq, e, &mut best);
                        }
                    };
                    if on_shell {
                        for z in z0..=z1 {
                            visit(z);
                        }
                    } else {
                        // Interior of this x-y column: only the two z faces are on the shell.
                        if center[2] - r >= z0 {
                            visit(center[2] - r);
                        }
                        if r > 0 && center[2] + r <= z1 {
                            visit(center[2] + r);
                        }
                    }
                }
            }
            let shell = r as f64 * self.voxel_size + margin;
            if best.is_some_and(|(_, d)| d <= shell * shell) {
                break;
            }
        }
        best
    }
}

#[cfg(test)]
mod tests;
