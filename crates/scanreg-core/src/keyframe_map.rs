//! A sliding local map of the last `K` keyframes, updated per keyframe instead of rebuilt.
//!
//! The map is the voxel-centroid downsampling of the union of the last `max_keyframes`
//! keyframes' points (world frame): one point per occupied voxel, the mean of every point of
//! those keyframes that fell into it — the same points, in the same order and to the bit, as
//! voxel-downsampling the concatenated keyframes. Each keyframe keeps its points grouped by
//! voxel, and each voxel where its points of every keyframe that saw it lie, so adding a
//! keyframe and dropping the oldest touch only the voxels those two keyframes saw, and a
//! touched centroid is summed again in the order a full downsampling sums it (no running
//! subtraction: the same bits whatever the history).
//!
//! Normals (k-NN PCA, [`crate::normals`]) are recomputed only where they can have changed: for
//! the voxels that are new or whose centroid moved, for those one of whose `k` neighbours moved
//! or left (each voxel keeps the ids of the neighbours its normal was computed from), and for
//! those with a new centroid within the radius of those `k` neighbours. Any other voxel has the
//! same `k` neighbours at the same places, so the map's normals are those of a full
//! recomputation (up to ties in the neighbour order). Keeping a normal whose
//! neighbourhood changed is not safe: a distant wall seen first by one sparse scan gets its
//! normal from points spread across a corner, and later keyframes fill it in.
//! Voxels live at stable ids and the map's rows are a list of ids: a keyframe moves only the
//! rows of the voxels it and the evicted keyframe touch, merged into the rest by their first
//! point, instead of sorting and moving every voxel and rehashing their keys.
//! Each voxel also keeps the distance to its nearest other point (the second of its `k`
//! neighbours), so the map's median spacing comes without a search of its own.
//! The k-d tree is rebuilt over the map on every insert: a few thousand 2D points build in tens
//! of microseconds, far less than the normals it saves.

#![allow(clippy::needless_range_loop)] // fixed-size coordinate loops read better indexed

use crate::error::{Error, Result};
use crate::knn::KdTree;
use crate::normal_noise::noise_with_neighbour;
use crate::normals::{eigen, facing, scatter, spans, Scratch};
use crate::points::{check_points, voxel_of};
use crate::trust::scene::median_of_squared;
use rustc_hash::FxHashMap;
use std::collections::VecDeque;

/// What one keyframe put into one voxel.
#[derive(Debug, Clone)]
struct Part {
    keyframe: u64,
    /// The keyframe's index of its first point in the voxel.
    first: usize,
    /// Its points in the voxel: `count` rows of the keyframe's `points` from `start`.
    start: u32,
    count: u32,
}

/// One keyframe in the window.
#[derive(Debug, Clone)]
struct Keyframe {
    id: u64,
    /// The voxels it touched, in the order of their first point.
    keys: Vec<[i64; 3]>,
    /// Its points grouped by voxel (in that order), each voxel's in input order: one
    /// allocation per keyframe rather than one per voxel.
    points: Vec<f64>,
}

/// No voxel (an empty neighbour slot, no nearest point).
const NONE: u32 = u32::MAX;

/// One occupied voxel: its key and parts (oldest keyframe first).
#[derive(Debug, Clone)]
struct Cell {
    key: [i64; 3],
    parts: Vec<Part>,
}

impl Cell {
    /// Where the voxel's row goes: the keyframe and index of its first point in the window.
    fn rank(&self) -> (u64, usize) {
        self.parts
            .first()
            .map_or((u64::MAX, usize::MAX), |p| (p.keyframe, p.first))
    }
}

/// What each voxel (by id) has once computed, one array per quantity: the passes over the
/// whole map each read one or two of them, not every voxel's record.
#[derive(Debug, Clone, Default)]
struct Geometry {
    /// Centroid.
    point: Vec<[f64; 3]>,
    normal: Vec<[f64; 3]>,
    valid: Vec<bool>,
    /// Squared distance to the farthest of the `k` neighbours the normal was computed from
    /// (`inf` while the map held fewer than `k` points).
    radius_sq: Vec<f64>,
    /// The voxel (its id) of the nearest other map point (the second of the `k` neighbours).
    nearest: Vec<u32>,
    /// Its squared distance (NaN while the map holds one point).
    nearest_sq: Vec<f64>,
    /// [`Cell::rank`], kept.
    rank: Vec<(u64, usize)>,
}

impl Geometry {
    /// Voxel `id` as new (nothing computed), `id <= len`.
    fn reset(&mut self, id: usize) {
        if id == self.point.len() {
            self.point.push([0.0; 3]);
            self.normal.push([0.0; 3]);
            self.valid.push(false);
            self.radius_sq.push(f64::INFINITY);
            self.nearest.push(NONE);
            self.nearest_sq.push(f64::NAN);
            self.rank.push((u64::MAX, usize::MAX));
        } else {
            self.point[id] = [0.0; 3];
            self.normal[id] = [0.0; 3];
            self.valid[id] = false;
            self.radius_sq[id] = f64::INFINITY;
            self.nearest[id] = NONE;
            self.nearest_sq[id] = f64::NAN;
            self.rank[id] = (u64::MAX, usize::MAX);
        }
    }
}

/// The map after an insert: points, their normals and the tree over them (row `i` of each is
/// the same voxel).
pub struct MapState {
    /// `M * dim` map points (voxel centroids).
    pub points: Vec<f64>,
    /// `M * dim` unit normals facing the viewpoint, zero where `!valid`.
    pub normals: Vec<f64>,
    /// Whether each point's neighbourhood spanned a line (2D) / plane (3D).
    pub valid: Vec<bool>,
    /// The k-d tree over `points`.
    pub tree: KdTree,
    /// Voxels whose normal was (re)computed by this insert.
    pub num_updated: usize,
    /// `(ε̂², ε̃²)` of the normals, as [`crate::normal_noise::target_normal_noise`] of `tree`
    /// and `normals` gives them (each point's nearest neighbour known from its normal's).
    pub normal_noise: (f64, f64),
    /// The median distance from a map point to its nearest other point (NaN with fewer than
    /// two points), as `scanreg.target.median_spacing` measures it with a 2-NN search.
    pub spacing: f64,
}

/// The sliding keyframe map (module docs).
#[derive(Debug, Clone)]
pub struct KeyframeMap {
    dim: usize,
    /// `1 / voxel_size`, or 0 for no downsampling (every point its own voxel).
    inv: f64,
    k: usize,
    max_keyframes: usize,
    viewpoint: [f64; 3],
    /// Every voxel by a stable id (its place here), live or free: a voxel keeps its id while
    /// it is in the map, so ids held across inserts (neighbours, nearest) need no rewrite
    /// when rows move.
    cells: Vec<Cell>,
    geo: Geometry,
    /// Ids of emptied voxels, for reuse.
    free: Vec<u32>,
    slot: FxHashMap<[i64; 3], u32>,
    /// The map's rows: the live voxel ids in the order of each voxel's first point in the
    /// window's keyframes, oldest first (the order of downsampling their concatenation).
    order: Vec<u32>,
    /// The ids of the `k` neighbours each voxel's normal was computed from (`k` per id,
    /// `NONE`-padded).
    neighbours: Vec<u32>,
    /// The window's keyframes, oldest first (consecutive ids).
    keyframes: VecDeque<Keyframe>,
    /// A keyframe's voxel key -> its part (kept to reuse the table's memory).
    parts_of: FxHashMap<[i64; 3], u32>,
    next_id: u64,
}

impl KeyframeMap {
    /// An empty map of `dim`-D points (2 or 3): voxels of `voxel_size` (0: no downsampling),
    /// normals from `k >= dim` neighbours facing `viewpoint`, the last `max_keyframes >= 1`.
    pub fn new(
        dim: usize,
        voxel_size: f64,
        k: usize,
        max_keyframes: usize,
        viewpoint: &[f64],
    ) -> Result<Self> {
        if dim != 2 && dim != 3 {
            return Err(Error::invalid("dim", format!("must be 2 or 3, got {dim}")));
        }
        if !voxel_size.is_finite() || voxel_size < 0.0 {
            return Err(Error::invalid(
                "voxel_size",
                format!("must be finite and >= 0, got {voxel_size}"),
            ));
        }
        if k < dim {
            return Err(Error::invalid(
                "num_neighbors",
                format!("must be >= {dim} to fit a normal in {dim}D, got {k}"),
            ));
        }
        if max_keyframes == 0 {
            return Err(Error::invalid("max_keyframes", "must be >= 1, got 0"));
        }
        if viewpoint.len() != dim || viewpoint.iter().any(|v| !v.is_finite()) {
            return Err(Error::invalid(
                "viewpoint",
                format!("expected {dim} finite coordinates, got {viewpoint:?}"),
            ));
        }
        let mut vp = [0.0; 3];
        vp[..dim].copy_from_slice(viewpoint);
        Ok(KeyframeMap {
            dim,
            inv: if voxel_size > 0.0 {
                1.0 / voxel_size
            } else {
                0.0
            },
            k,
            max_keyframes,
            viewpoint: vp,
            cells: Vec::new(),
            geo: Geometry::default(),
            free: Vec::new(),
            slot: FxHashMap::default(),
            order: Vec::new(),
            neighbours: Vec::new(),
            keyframes: VecDeque::new(),
            parts_of: FxHashMap::default(),
            next_id: 0,
        })
    }

    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Map points.
    pub fn len(&self) -> usize {
        self.order.len()
    }

    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }

    /// Keyframes in the window.
    pub fn num_keyframes(&self) -> usize {
        self.keyframes.len()
    }

    /// The voxel key of every point (with no downsampling, a key no voxel can have).
    fn keys(&self, points: &[f64], id: u64) -> Result<Vec<[i64; 3]>> {
        let dim = self.dim;
        points
            .chunks_exact(dim)
            .enumerate()
            .map(|(i, p)| {
                if self.inv == 0.0 {
                    return Ok([i64::MIN, id as i64, i as i64]);
                }
                voxel_of(p, self.inv).ok_or_else(|| {
                    Error::invalid("voxel_size", "too small for the extent of the points")
                })
            })
            .collect()
    }

    /// A new voxel's id (a free one when there is one).
    fn allocate(&mut self, cell: Cell) -> u32 {
        let id = if let Some(id) = self.free.pop() {
            self.cells[id as usize] = cell;
            id
        } else {
            self.cells.push(cell);
            self.neighbours.extend(std::iter::repeat_n(NONE, self.k));
            (self.cells.len() - 1) as u32
        };
        self.geo.reset(id as usize);
        id
    }

    /// Add a keyframe's `N * dim` world-frame points (`N >= 1`, finite), dropping the oldest
    /// keyframe when the window is full; the map after the update.
    pub fn insert(&mut self, points: &[f64]) -> Result<MapState> {
        let dim = self.dim;
        let n = check_points("points", points, dim)?;
        if n == 0 {
            return Err(Error::invalid("points", "is empty"));
        }
        if n >= u32::MAX as usize {
            return Err(Error::invalid("points", "more than 2^32 - 2 points"));
        }
        let id = self.next_id;
        let keys = self.keys(points, id)?;
        // This keyframe's parts, one per voxel, in the order of the voxel's first point.
        let mine = &mut self.parts_of;
        mine.clear();
        let mut my_keys: Vec<[i64; 3]> = Vec::new();
        let mut firsts: Vec<usize> = Vec::new();
        let mut counts: Vec<u32> = Vec::new();
        let mut part_of: Vec<u32> = Vec::with_capacity(n);
        for (i, key) in keys.iter().enumerate() {
            let at = *mine.entry(*key).or_insert_with(|| {
                my_keys.push(*key);
                firsts.push(i);
                counts.push(0);
                (my_keys.len() - 1) as u32
            });
            counts[at as usize] += 1;
            part_of.push(at);
        }
        let mut starts = Vec::with_capacity(counts.len());
        let mut total = 0u32;
        for &c in &counts {
            starts.push(total);
            total += c;
        }
        let mut fill = starts.clone();
        let mut grouped = vec![0.0; n * dim];
        for (p, &at) in points.chunks_exact(dim).zip(&part_of) {
            let row = fill[at as usize] as usize;
            grouped[row * dim..(row + 1) * dim].copy_from_slice(p);
            fill[at as usize] += 1;
        }
        self.next_id += 1;

        // Voxels (by id) this insert changes: the evicted keyframe's (which move to a later
        // row or leave) and this keyframe's.
        let mut touched = vec![false; self.cells.len() + my_keys.len()];
        // Voxels whose first point changes (the evicted keyframe was their first) or that are
        // new: their rows move; every other voxel keeps its place relative to the rest.
        let mut moved: Vec<u32> = Vec::new();
        if self.keyframes.len() == self.max_keyframes {
            if let Some(old) = self.keyframes.pop_front() {
                for key in &old.keys {
                    if let Some(&s) = self.slot.get(key) {
                        // The oldest keyframe: its part is the voxel's first.
                        self.cells[s as usize]
                            .parts
                            .retain(|p| p.keyframe != old.id);
                        touched[s as usize] = true;
                        moved.push(s);
                    }
                }
            }
        }
        for (j, &key) in my_keys.iter().enumerate() {
            let part = Part {
                keyframe: id,
                first: firsts[j],
                start: starts[j],
                count: counts[j],
            };
            match self.slot.get(&key) {
                Some(&s) => {
                    self.cells[s as usize].parts.push(part);
                    touched[s as usize] = true;
                }
                None => {
                    let s = self.allocate(Cell {
                        key,
                        parts: vec![part],
                    });
                    self.slot.insert(key, s);
                    touched[s as usize] = true;
                    moved.push(s);
                }
            }
        }
        self.keyframes.push_back(Keyframe {
            id,
            keys: my_keys,
            points: grouped,
        });

        // The rows: the voxels that kept their first point stay in their order; the moved
        // ones that remain are merged in by their new first point; emptied voxels leave (their
        // ids freed, for the next insert: no voxel that remains refers to them once this one
        // has recomputed every neighbourhood that held them). The same order as sorting every
        // voxel by its first point, without the sort.
        let mut is_moved = vec![false; self.cells.len()];
        for &s in &moved {
            is_moved[s as usize] = true;
        }
        let cells = &self.cells;
        let mut arriving: Vec<((u64, usize), u32)> = Vec::with_capacity(moved.len());
        for &s in &moved {
            let cell = &cells[s as usize];
            if cell.parts.is_empty() {
                self.slot.remove(&cell.key);
                self.free.push(s);
            } else {
                self.geo.rank[s as usize] = cell.rank();
                arriving.push((cell.rank(), s));
            }
        }
        arriving.sort_unstable();
        let rank = &self.geo.rank;
        let mut order = Vec::with_capacity(self.order.len() + arriving.len());
        let mut next = arriving.iter().peekable();
        for &s in self.order.iter().filter(|&&s| !is_moved[s as usize]) {
            let here = rank[s as usize];
            while let Some(&&(r, a)) = next.peek() {
                if r >= here {
                    break;
                }
                order.push(a);
                next.next();
            }
            order.push(s);
        }
        order.extend(next.map(|&(_, a)| a));
        self.order = order;

        // Where the map changed: the new centroid of every touched voxel that remains (the
        // old ones are found through the neighbours that held them, below).
        let mut changed: Vec<f64> = Vec::new();
        for &s in &self.order {
            if !touched[s as usize] {
                continue;
            }
            let cell = &self.cells[s as usize];
            // As `voxel_downsample` sums a voxel: its first point, plus the others in
            // order, divided by the count when there is more than one.
            let kfs = &self.keyframes;
            let base = kfs.front().map_or(0, |kf| kf.id);
            let mut all = cell.parts.iter().flat_map(|p| {
                let rows = p.start as usize..(p.start + p.count) as usize;
                kfs[(p.keyframe - base) as usize].points[rows.start * dim..rows.end * dim]
                    .chunks_exact(dim)
            });
            let mut sum = [0.0; 3];
            let mut count = 0usize;
            if let Some(first) = all.next() {
                sum[..dim].copy_from_slice(first);
                count = 1;
            }
            for q in all {
                for c in 0..dim {
                    sum[c] += q[c];
                }
                count += 1;
            }
            if count > 1 {
                sum.iter_mut().for_each(|v| *v /= count as f64);
            }
            self.geo.point[s as usize] = sum;
            changed.extend_from_slice(&sum[..dim]);
        }

        let mut flat = Vec::with_capacity(self.order.len() * dim);
        for &s in &self.order {
            flat.extend_from_slice(&self.geo.point[s as usize][..dim]);
        }
        let tree = KdTree::build(&flat, dim)?;
        // A voxel's k neighbours can only have changed if one of them moved or left, or a
        // changed point (a new centroid) lies within its neighbourhood radius: those get their
        // normal again, the rest keep theirs — the same normals as a full recomputation, for a
        // fraction of it. (A point that was not a neighbour leaving changes nothing.)
        let arrived = if changed.is_empty() {
            None
        } else {
            Some(KdTree::build(&changed, dim)?)
        };
        let kk = self.k;
        let stale: Vec<bool> = self
            .order
            .iter()
            .map(|&s| {
                let s = s as usize;
                touched[s]
                    || self.neighbours[s * kk..(s + 1) * kk]
                        .iter()
                        .any(|&j| j != NONE && touched[j as usize])
                    || arrived.as_ref().is_some_and(|m| {
                        m.any_within(&self.geo.point[s][..dim], self.geo.radius_sq[s])
                    })
            })
            .collect();
        let k = self.k.min(self.order.len());
        // In the tree's leaf order, each query bounded by the previous one (as a full
        // recomputation does): consecutive points share most of their traversal.
        let mut scratch = Scratch::new(k);
        let mut num_updated = 0;
        for &i in tree.leaf_order() {
            let i = i as usize;
            if !stale[i] {
                continue;
            }
            num_updated += 1;
            let buf = scratch.neighbours(&tree, i, k);
            let s = self.order[i] as usize;
            let held = &mut self.neighbours[s * kk..(s + 1) * kk];
            held.fill(NONE);
            for (h, &(j, _)) in held.iter_mut().zip(buf) {
                *h = self.order[j as usize];
            }
            let geo = &mut self.geo;
            geo.radius_sq[s] = if k < self.k {
                f64::INFINITY
            } else {
                buf.last().map_or(f64::INFINITY, |&(_, d)| d)
            };
            // The k neighbours are sorted by (distance, index): the second is the nearest
            // other point, as the 2-NN query of the noise statistic finds it.
            geo.nearest[s] = buf.get(1).map_or(NONE, |&(j, _)| self.order[j as usize]);
            geo.nearest_sq[s] = buf.get(1).map_or(f64::NAN, |&(_, d)| d);
            let (vals, vecs) = eigen(&scatter(&tree, buf), dim);
            let valid = k >= dim && spans(&vals, dim);
            geo.valid[s] = valid;
            geo.normal[s] = if valid {
                facing(&vecs[0], tree.point(i), &self.viewpoint[..dim], dim)
            } else {
                [0.0; 3]
            };
        }
        let mut normals = Vec::with_capacity(flat.len());
        let mut row_of = vec![NONE; self.cells.len()];
        let geo = &self.geo;
        for (r, &s) in self.order.iter().enumerate() {
            normals.extend_from_slice(&geo.normal[s as usize][..dim]);
            row_of[s as usize] = r as u32;
        }
        // A voxel whose neighbours did not change kept its nearest one too (which is live:
        // a voxel whose neighbour left was recomputed).
        let order = &self.order;
        let normal_noise = noise_with_neighbour(&normals, dim, |r| {
            let j = geo.nearest[order[r] as usize];
            let row = row_of.get(j as usize).copied().unwrap_or(NONE);
            (row != NONE).then_some(row as usize)
        });
        // Kept like the nearest voxel: an unchanged neighbourhood has its nearest point at the
        // same place, so the map's spacing needs no search of its own.
        let spacing =
            median_of_squared(order.iter().map(|&s| geo.nearest_sq[s as usize]).collect());
        Ok(MapState {
            normal_noise,
            spacing,
            points: flat,
            normals,
            valid: order.iter().map(|&s| geo.valid[s as usize]).collect(),
            tree,
            num_updated,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::downsample::{voxel_downsample, VoxelMethod};
    use crate::normal_noise::target_normal_noise;
    use crate::normals::local_geometry;

    /// Points on the walls of a 4 x 3 m room, seen from `(x, 0)`, every 2 cm, jittered.
    fn room(x: f64, seed: u64) -> Vec<f64> {
        let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
        let mut jitter = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.01
        };
        let mut out = Vec::new();
        for i in 0..200 {
            let u = -2.0 + 0.02 * i as f64;
            if (u - x).abs() < 1.5 {
                out.extend_from_slice(&[u, 1.5 + jitter()]);
                out.extend_from_slice(&[u, -1.5 + jitter()]);
            }
        }
        for i in 0..150 {
            let v = -1.5 + 0.02 * i as f64;
            out.extend_from_slice(&[2.0 + jitter(), v]);
        }
        out
    }

    #[test]
    fn points_equal_downsampling_of_the_window() {
        let mut map = KeyframeMap::new(2, 0.05, 10, 3, &[0.0, 0.0]).unwrap();
        let frames: Vec<Vec<f64>> = (0..6).map(|j| room(-1.0 + 0.4 * j as f64, j)).collect();
        for (j, f) in frames.iter().enumerate() {
            let state = map.insert(f).unwrap();
            let window: Vec<f64> = frames[j.saturating_sub(2)..=j].concat();
            let want = voxel_downsample(&window, 2, 0.05, VoxelMethod::Centroid).unwrap();
            assert_eq!(state.points, want.points);
            assert_eq!(map.num_keyframes(), (j + 1).min(3));
            assert_eq!(state.tree.len(), map.len());
        }
    }

    #[test]
    fn normals_equal_a_full_recomputation() {
        let mut map = KeyframeMap::new(2, 0.05, 10, 2, &[0.0, 0.0]).unwrap();
        // Out and back: voxels emptied by an evicted keyframe are filled again later (their
        // ids reused), and rows move as their first keyframe leaves.
        for j in 0..10u64 {
            let x = 0.3 * (4 - (j as i64 - 4).abs()) as f64;
            let state = map.insert(&room(x, j)).unwrap();
            let full = local_geometry(&state.tree, 10, &[0.0, 0.0], true, None).unwrap();
            let full_normals = full.normals.unwrap();
            let mut same = 0;
            for i in 0..state.valid.len() {
                let a = &state.normals[2 * i..2 * i + 2];
                let b = &full_normals[2 * i..2 * i + 2];
                same += usize::from(a == b);
            }
            assert_eq!(same, state.valid.len());
            let (mean, median) = target_normal_noise(&state.tree, &state.normals).unwrap();
            assert_eq!(state.normal_noise, (mean, median));
            let (_, d2) = state.tree.knn_batch(&state.points, 2).unwrap();
            let mut second: Vec<f64> = d2.chunks_exact(2).map(|d| d[1]).collect();
            second.sort_by(f64::total_cmp);
            let m = second.len();
            let want = if m % 2 == 1 {
                second[m / 2]
            } else {
                (second[m / 2 - 1] + second[m / 2]) / 2.0
            };
            assert_eq!(state.spacing, want.sqrt());
            if j == 0 {
                assert_eq!(state.num_updated, state.valid.len());
            }
        }
    }

    #[test]
    fn a_neighbour_leaving_is_recomputed_alone() {
        // A diagonal wall meeting a straight one at (1, 1), then a keyframe far away: when the
        // diagonal's keyframe leaves, the straight wall's voxels by the corner are neither
        // touched nor near a new point, but their neighbours left (and their nearest one with
        // them): their normals and spacing must be those of the straight wall alone.
        let line = |a: [f64; 2], b: [f64; 2], n: usize| -> Vec<f64> {
            (0..n)
                .flat_map(|i| {
                    let t = i as f64 / n as f64;
                    [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]
                })
                .collect()
        };
        let frames = [
            line([0.0, 0.0], [1.0, 1.0], 70),
            line([1.0, 1.0], [2.0, 1.0], 50),
            line([8.0, -3.0], [8.0, -1.0], 100),
        ];
        let mut map = KeyframeMap::new(2, 0.05, 10, 2, &[0.0, -2.0]).unwrap();
        for (j, f) in frames.iter().enumerate() {
            let state = map.insert(f).unwrap();
            let full = local_geometry(&state.tree, 10, &[0.0, -2.0], true, None).unwrap();
            assert_eq!(state.normals, full.normals.unwrap(), "keyframe {j}");
            let (_, d2) = state.tree.knn_batch(&state.points, 2).unwrap();
            let second: Vec<f64> = d2.chunks_exact(2).map(|d| d[1]).collect();
            assert_eq!(state.spacing, median_of_squared(second), "keyframe {j}");
            let want = target_normal_noise(&state.tree, &state.normals).unwrap();
            assert_eq!(state.normal_noise, want, "keyframe {j}");
            if j == 2 {
                // Only the far keyframe's voxels and the corner's: not the whole map.
                assert!(state.num_updated < state.valid.len());
                assert!(state.num_updated > 40);
            }
        }
    }

    #[test]
    fn no_downsampling_keeps_every_point() {
        let mut map = KeyframeMap::new(2, 0.0, 5, 2, &[0.0, 0.0]).unwrap();
        let a = room(0.0, 1);
        let b = room(0.5, 2);
        let c = room(1.0, 3);
        assert_eq!(map.insert(&a).unwrap().points.len(), a.len());
        assert_eq!(map.insert(&b).unwrap().points.len(), a.len() + b.len());
        assert_eq!(map.insert(&c).unwrap().points.len(), b.len() + c.len());
    }

    #[test]
    fn bad_input_is_refused() {
        assert!(KeyframeMap::new(4, 0.05, 10, 3, &[0.0; 4]).is_err());
        assert!(KeyframeMap::new(2, -1.0, 10, 3, &[0.0, 0.0]).is_err());
        assert!(KeyframeMap::new(2, 0.05, 1, 3, &[0.0, 0.0]).is_err());
        assert!(KeyframeMap::new(2, 0.05, 10, 0, &[0.0, 0.0]).is_err());
        let mut map = KeyframeMap::new(2, 0.05, 10, 3, &[0.0, 0.0]).unwrap();
        assert!(map.insert(&[]).is_err());
        assert!(map.insert(&[0.0, f64::NAN]).is_err());
        assert!(map.insert(&[0.0, 1.0, 2.0]).is_err());
        // A single point: a map without normals, not an error.
        let state = map.insert(&[1.0, 2.0]).unwrap();
        assert_eq!(state.valid, vec![false]);
        assert!(state.spacing.is_nan());
    }
}
