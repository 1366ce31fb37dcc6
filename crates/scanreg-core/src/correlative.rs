//! Correlative 2D scan matching (Olson 2009) with multi-resolution branch and bound
//! (Hess, Kohler, Rapp, Andor 2016).
//!
//! * [`LikelihoodGrid`]: the reference rasterised once. Cell value `g = exp(-d² / 2σ²)` with `d`
//!   the exact Euclidean distance from the cell centre to the nearest occupied cell centre
//!   (Felzenszwalb–Huttenlocher distance transform, separable, parallel over rows/columns):
//!   the Gaussian-blurred occupancy of Olson, but with `max` instead of a sum so overlapping
//!   walls do not add up. Near a wall `g ≈ 1 − d²/2σ²`, so a sum of `g` is, to second order,
//!   the Gaussian log-likelihood of the points — and saturates (robustly) far from walls.
//!   Max-pooled copies per level `h` (`2^h × 2^h` windows, Hess eq. 14) are precomputed.
//! * The search lattice (both methods, so they can be compared exactly): rotations
//!   `θ_k = θ₀ + k·δθ`, `k ∈ [−K, K]`; translations `t₀ + (i, j)·r`, `i ∈ [−I, I]`, `j ∈ [−J, J]`
//!   with `r` the grid resolution. For each rotation the source points are rotated, shifted by
//!   `t₀` and mapped to cells once; a candidate `(k, i, j)` scores
//!   `S = Σ_p g[c_p + (i, j)]`, summed in point order in `f64`.
//! * The best candidate is the largest `S`; ties go to the smallest `(k, i, j)`
//!   (lexicographic). Branch and bound explores every node whose bound is `≥` the best sum, so
//!   it returns exactly the exhaustive answer (the bound of a node is, term by term, `≥` the
//!   score of each leaf below it, and rounding is monotone, so the `f64` sums keep the order).
//! * Covariance (Olson 2009, §IV): with `p = exp(S − S_max)` over the evaluated candidates
//!   `x = (x, y, θ)`, `Σ = Σ p x xᵀ / Σ p − μ μᵀ`. The exhaustive search accumulates it over
//!   the whole window (slice by slice, rescaled like a log-sum-exp); branch and bound over a
//!   dense neighbourhood of the optimum.

use crate::error::{Error, Result};
use rayon::prelude::*;
use std::sync::{Arc, OnceLock};

/// Largest grid (cells per level) accepted: 2D maps beyond this need a coarser resolution.
pub const MAX_CELLS: usize = 64 * 1024 * 1024;
/// Deepest branch-and-bound level (`2^12` cells per node side).
pub const MAX_LEVELS: usize = 12;

/// Grids of at most this many cells are built, and searches of at most `SEQUENTIAL_WORK`
/// candidate-points run, on the calling thread: their parallel sections take microseconds
/// each, and every one handed to the pool and back costs a wake-up, the workers' idle spin and,
/// on a loaded machine, the wait for a core (the wrong-basin probe's correlative start, a
/// 3,600-cell grid and ~17 such sections, spent about as much CPU on those as on its work).
/// The results are the same either way (the same reductions in the same order).
const SEQUENTIAL_CELLS: usize = 1 << 16;
const SEQUENTIAL_WORK: u64 = 1 << 20;
/// Branch and bound scores a few per cent of its lattice (the probe's correlative start: 700 to
/// 2,800 bounds and leaves of 21,000 candidates): the same limit on the work it does.
const SEQUENTIAL_BNB_WORK: u64 = 1 << 23;

/// The `with_min_len` of every parallel section: a section no longer than this is not split,
/// so it runs where it is called, without the pool.
fn min_len(sequential: bool) -> usize {
    if sequential {
        usize::MAX
    } else {
        1
    }
}

/// Candidate-points of a search over `w` with `n` source points (the exhaustive count).
fn search_work(w: &Window, n: usize) -> u64 {
    let c = |h: i64| (2 * h.max(0) + 1) as u64;
    c(w.nx)
        .saturating_mul(c(w.ny))
        .saturating_mul(c(w.ntheta))
        .saturating_mul(n as u64)
}

/// One max-pooled grid: `value(x, y) = max g[x..x+w, y..y+w]` for `x ∈ [−(w−1), W−1]`.
#[derive(Debug, Clone)]
struct Level {
    shift: i64,
    width: i64,
    height: i64,
    data: Vec<f32>,
}

impl Level {
    #[inline]
    fn at(&self, x: i64, y: i64) -> f32 {
        let (xs, ys) = (x + self.shift, y + self.shift);
        // One unsigned comparison per axis: a negative index wraps past the size.
        if xs as u64 >= self.width as u64 || ys as u64 >= self.height as u64 {
            return 0.0;
        }
        self.data[(ys * self.width + xs) as usize]
    }
}

/// The rasterised reference: likelihood, squared distance and max-pooled levels.
///
/// The rasters cover a *canvas*: the lattice (`origin`, `width`, `height`: the cells the
/// reference and the blur's margin span), or after [`LikelihoodGrid::update`] a rectangle
/// around it, 0 (distance +∞) outside the lattice, so that a grid is updated without moving
/// its cells. Every read goes through canvas cells (a search's cells are the lattice's,
/// shifted by whole cells), and reads 0 (+∞) outside the lattice as outside the canvas.
#[derive(Debug, Clone)]
pub struct LikelihoodGrid {
    origin: [f64; 2],
    resolution: f64,
    sigma: f64,
    width: usize,
    height: usize,
    /// The global index of canvas cell `(0, 0)` and the canvas's `[width, height]` (cells).
    canvas: [i64; 2],
    canvas_size: [usize; 2],
    /// Squared distance to the nearest occupied cell, in cells², row-major (y rows), canvas.
    dist2: Vec<f32>,
    /// The likelihood itself (level 0), canvas.
    base: Level,
    /// `pooled[h − 1]` pools `2^h × 2^h` windows of level `h − 1` (over the canvas). Built on
    /// first use: a search needs only as many levels as its window is wide (an odometry
    /// window of ±6 cells uses 4 of the default 7), and each costs about a third of the base
    /// grid's build; an update pools again, in place, those built so far.
    pooled: Vec<OnceLock<Arc<Level>>>,
    /// [`LikelihoodGrid::update`]'s scratch.
    marks: Marks,
    /// `origin / resolution`: the global index (a multiple of the resolution from 0) of cell
    /// `(0, 0)`, so that two grids of the same resolution place their cells alike.
    offset: [i64; 2],
    /// The occupied cells, global `[y, x]` (cell + `offset`), sorted: what
    /// [`LikelihoodGrid::updated`] compares a new reference's with.
    occupied: Vec<[i64; 2]>,
}

/// The cells [`LikelihoodGrid::build`] lays a reference on: `origin = offset · resolution`.
struct Lattice {
    origin: [f64; 2],
    offset: [i64; 2],
    width: usize,
    height: usize,
}

/// A search window around an initial pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    /// `[x, y, θ]` of the window centre (the initial pose `T_reference_source`).
    pub center: [f64; 3],
    /// Half-widths in lattice steps: `i ∈ [−nx, nx]`, `j ∈ [−ny, ny]`, `k ∈ [−ntheta, ntheta]`.
    pub nx: i64,
    pub ny: i64,
    pub ntheta: i64,
    /// `δθ`, radians.
    pub angular_step: f64,
    /// A motion cost: the information matrix `P` (row-major 3×3, symmetric positive
    /// semi-definite) over the window frame's offsets `x = (i·r, j·r, k·δθ)` from `center`;
    /// each candidate's objective is then `S − ½ xᵀ P x` instead of `S` (a real-time
    /// correlative matcher's pull towards the prediction: of two nearly equal basins the one
    /// nearer `center`, in the prediction's own metric, wins). `None`: `S` alone.
    pub penalty: Option<[f64; 9]>,
}

/// The answer of a search.
#[derive(Debug, Clone, PartialEq)]
pub struct Match {
    /// `[x, y, θ]` of the best candidate (`T_reference_source`).
    pub pose: [f64; 3],
    /// Lattice index `(k, i, j)` of the best candidate.
    pub index: [i64; 3],
    /// `S_max = Σ_p g`.
    pub sum: f64,
    /// `S_max / N` in `[0, 1]`.
    pub score: f64,
    /// Fraction of source points within one cell (8-neighbourhood) of an occupied cell.
    pub fitness: f64,
    /// Olson's covariance over `[x, y, θ]` (window frame), row-major 3×3.
    pub covariance: [f64; 9],
    /// Weighted mean of the evaluated candidates, `[x, y, θ]`.
    pub mean: [f64; 3],
    /// Full-resolution candidates scored.
    pub evaluated: u64,
    /// Bounds computed on pooled levels (0 for the exhaustive search).
    pub bounds: u64,
    /// Candidates whose `p` entered the covariance.
    pub covariance_candidates: u64,
}

/// The motion cost in lattice units `u = (i, j, k)`: `½ uᵀ Q u` with `Q = S P S`,
/// `S = diag(r, r, δθ)`.
#[derive(Debug, Clone, Copy)]
struct Cost {
    q: [[f64; 3]; 3],
}

impl Cost {
    fn new(w: &Window, resolution: f64) -> Option<Cost> {
        let p = w.penalty?;
        let s = [resolution, resolution, w.angular_step];
        let mut q = [[0.0; 3]; 3];
        for a in 0..3 {
            for b in 0..3 {
                q[a][b] = p[a * 3 + b] * s[a] * s[b];
            }
        }
        Some(Cost { q })
    }

    #[inline]
    fn at(&self, i: f64, j: f64, k: f64) -> f64 {
        let u = [i, j, k];
        let mut v = 0.0;
        for a in 0..3 {
            for b in 0..3 {
                v += u[a] * self.q[a][b] * u[b];
            }
        }
        0.5 * v
    }

    /// A lower bound of the cost over `i ∈ [i0, i1]`, `j ∈ [j0, j1]` at rotation `k`: the
    /// minimum of the convex quadratic over the rectangle (its free minimum when inside, else
    /// the least of the four edges'), less a margin for round-off, so that a node's bound stays
    /// `≥` every leaf below it.
    fn lower_bound(&self, k: f64, i0: f64, i1: f64, j0: f64, j1: f64) -> f64 {
        let q = &self.q;
        // q(i, j) = ½ (a i² + 2 b i j + c j²) + (d i + e j) + f, with k fixed.
        let (a, b, c) = (q[0][0], q[0][1], q[1][1]);
        let (d, e) = (q[0][2] * k, q[1][2] * k);
        let det = a * c - b * b;
        let mut best = f64::INFINITY;
        if det > 1e-12 * (a * c).max(1e-300) {
            let i = (b * e - c * d) / det;
            let j = (b * d - a * e) / det;
            if (i0..=i1).contains(&i) && (j0..=j1).contains(&j) {
                best = self.at(i, j, k);
            }
        }
        if best.is_infinite() {
            // Along an edge i = const: ½ c j² + (b i + e) j + ..., minimised at j = −(b i + e)/c.
            for i in [i0, i1] {
                let j = if c > 0.0 {
                    (-(b * i + e) / c).clamp(j0, j1)
                } else {
                    j0
                };
                best = best.min(self.at(i, j, k));
                if c <= 0.0 {
                    best = best.min(self.at(i, j1, k));
                }
            }
            for j in [j0, j1] {
                let i = if a > 0.0 {
                    (-(b * j + d) / a).clamp(i0, i1)
                } else {
                    i0
                };
                best = best.min(self.at(i, j, k));
                if a <= 0.0 {
                    best = best.min(self.at(i1, j, k));
                }
            }
        }
        (best - 1e-9 * (1.0 + best.abs())).max(0.0)
    }
}

/// The source points of one rotation, as cells: `(cx, cy)` per point, less those that read 0
/// on every level wherever the window puts them (off the canvas by more than the window's
/// and the coarsest level's reach: an 80 m scan against a few nodes' submap).
struct Slice {
    cells: Vec<[i64; 2]>,
    /// How many points the rotation has (`cells` and the dropped ones): a score's divisor.
    points: usize,
}

impl Slice {
    /// Where a sum over `cells` starts: `Iterator::sum`'s −0.0 over all the points, but +0.0
    /// once a point was dropped (its +0.0 would have been added): the sums keep their bits.
    fn zero(&self) -> f64 {
        if self.cells.len() == self.points {
            -0.0
        } else {
            0.0
        }
    }
}

fn check_points(points: &[f64], arg: &'static str) -> Result<usize> {
    if !points.len().is_multiple_of(2) {
        return Err(Error::invalid(arg, "length is not a multiple of 2"));
    }
    let n = points.len() / 2;
    if n == 0 {
        return Err(Error::invalid(arg, "is empty (0 points)"));
    }
    if let Some(bad) = points.iter().position(|v| !v.is_finite()) {
        return Err(Error::invalid(
            arg,
            format!("point {} has a non-finite coordinate (NaN or inf)", bad / 2),
        ));
    }
    Ok(n)
}

/// 1-D squared distance transform (Felzenszwalb & Huttenlocher 2012, Alg. 1) of `f` in place.
fn dt1d(f: &mut [f64], v: &mut [usize], z: &mut [f64], out: &mut [f64]) {
    let n = f.len();
    if n == 0 {
        return;
    }
    let mut k = 0usize;
    v[0] = 0;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    for q in 1..n {
        if !f[q].is_finite() {
            continue;
        }
        loop {
            let p = v[k];
            if !f[p].is_finite() {
                // The first parabola may be "at infinity": replace it outright.
                v[k] = q;
                z[k] = f64::NEG_INFINITY;
                z[k + 1] = f64::INFINITY;
                break;
            }
            let (qf, pf) = (q as f64, p as f64);
            let s = ((f[q] + qf * qf) - (f[p] + pf * pf)) / (2.0 * qf - 2.0 * pf);
            if s <= z[k] && k > 0 {
                k -= 1;
                continue;
            }
            if s <= z[k] {
                v[k] = q;
                z[k] = f64::NEG_INFINITY;
                z[k + 1] = f64::INFINITY;
                break;
            }
            k += 1;
            v[k] = q;
            z[k] = s;
            z[k + 1] = f64::INFINITY;
            break;
        }
    }
    let mut k = 0usize;
    for (q, o) in out.iter_mut().enumerate() {
        let qf = q as f64;
        while z[k + 1] < qf {
            k += 1;
        }
        let p = v[k];
        let d = qf - p as f64;
        *o = if f[p].is_finite() {
            d * d + f[p]
        } else {
            f64::INFINITY
        };
    }
    f.copy_from_slice(out);
}

fn transform_lines(data: &mut [f64], len: usize, sequential: bool) {
    // One scratch per worker, not three allocations per line (`dt1d` writes every entry it
    // reads): a 180-point scan's grid has a few hundred lines, each a few hundred cells.
    data.par_chunks_mut(len)
        .with_min_len(min_len(sequential))
        .for_each_init(
            || (vec![0usize; len], vec![0.0; len + 1], vec![0.0; len]),
            |(v, z, out), line| {
                // A line without an occupied cell stays infinite (what `dt1d` writes back).
                if line.iter().any(|f| f.is_finite()) {
                    dt1d(line, v, z, out);
                }
            },
        );
}

/// Entries of [`Gaussian`]'s table at most (the probe's grids need about 220).
const GAUSSIAN_TABLE_MAX: usize = 1 << 16;

/// `exp(−d / 2s²) as f32` of a squared distance `d` in cells², by table where `d` is a whole
/// number (the distance transform's every finite value: sums of squared whole offsets, exact
/// in `f64`), so a grid's tens of thousands of cells cost a few hundred `exp`s. The table holds
/// the same expression's value at the same `d`: the same bits as computing each cell. Past
/// `−d / 2s² < −110` the value is `+0.0` in `f32` (`e^−110 ≈ 1.7e−48`, far below half the least
/// subnormal, `7e−46`, whatever the last bit of `exp`), where the table ends.
struct Gaussian {
    s2: f64,
    table: Vec<f32>,
}

impl Gaussian {
    fn new(s2: f64, cells: usize) -> Self {
        let last = (220.0 * s2).ceil();
        let cap = GAUSSIAN_TABLE_MAX.min(cells);
        let len = if last.is_finite() && last >= 0.0 {
            (last as usize).saturating_add(1).min(cap)
        } else {
            0
        };
        let table = (0..len)
            .map(|i| (-0.5 * i as f64 / s2).exp() as f32)
            .collect();
        Gaussian { s2, table }
    }

    /// The least whole radius (cells) beyond which `at` is `+0.0` in `f32` (the likelihood's
    /// whole support: a grid cut there holds every bit a full distance transform's would).
    fn reach(&self) -> i64 {
        // `at` does not increase with d and is 0 past d = 220 s²: bisect for the least whole
        // d where it is 0 (`lo` is never 0, `hi` always is).
        let (mut lo, mut hi) = (0.0f64, (220.0 * self.s2).ceil() + 1.0);
        while hi - lo > 1.0 {
            let mid = ((lo + hi) / 2.0).floor();
            if self.at(mid) == 0.0 {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        // The disc must hold every d² < hi.
        lo.sqrt().ceil() as i64
    }

    fn at(&self, d: f64) -> f32 {
        let i = d as usize; // saturating: NaN and negatives to 0, caught by the equality
        if i < self.table.len() && i as f64 == d {
            return self.table[i];
        }
        let x = -0.5 * d / self.s2;
        if x < -110.0 {
            0.0
        } else {
            x.exp() as f32
        }
    }
}

fn transpose(data: &[f64], width: usize, height: usize, sequential: bool) -> Vec<f64> {
    let mut out = vec![0.0; data.len()];
    out.par_chunks_mut(height)
        .with_min_len(min_len(sequential))
        .enumerate()
        .for_each(|(x, col)| {
            for (y, c) in col.iter_mut().enumerate() {
                *c = data[y * width + x];
            }
        });
    out
}

/// The larger of two likelihoods: `f32::max` without its NaN handling, which keeps the
/// pooling loops from vectorising to plain maxima. The same bits: likelihoods are finite and
/// `>= +0.0` (an `exp` or `+0.0`, never `-0.0`), so equal values are the same value.
#[inline(always)]
fn larger(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// `out = max(a, b)` elementwise where `b` is `a` shifted right by `half` (zeros outside), over
/// `a.len() + half` outputs: the 1-D step of a 2 × 2 max with stride `half`. Likelihoods are
/// ≥ 0, so the zero padding never wins a maximum it should not.
fn max_with_shifted(a: &[f32], half: usize, out: &mut [f32]) {
    let n = a.len();
    debug_assert_eq!(out.len(), n + half);
    let lead = half.min(n);
    out[..lead].copy_from_slice(&a[..lead]);
    for c in lead..n {
        out[c] = larger(a[c], a[c - half]);
    }
    let tail = n.max(half);
    out[tail..n + half].copy_from_slice(&a[tail - half..n]);
    for o in out.iter_mut().take(half).skip(n) {
        *o = 0.0; // only when the level is narrower than the stride
    }
}

/// [`max_with_shifted`] appended to `out` (its `a.len() + half` values, in order).
fn push_max_with_shifted(a: &[f32], half: usize, out: &mut Vec<f32>) {
    let n = a.len();
    let lead = half.min(n);
    out.extend_from_slice(&a[..lead]);
    out.extend(
        a[lead..]
            .iter()
            .zip(&a[..n - lead])
            .map(|(x, y)| larger(*x, *y)),
    );
    if half > n {
        out.resize(out.len() + (half - n), 0.0); // only when the level is narrower than the stride
    }
    out.extend_from_slice(&a[n.max(half) - half..n]);
}

/// The two pooled rows output row `r` takes the maximum of: row `r − half` and row `r` of
/// `rows` (`hp` rows of `wu` values), each where it exists.
fn row_pair(
    rows: &[f32],
    r: usize,
    half: usize,
    hp: usize,
    wu: usize,
) -> (Option<&[f32]>, Option<&[f32]>) {
    let upper = r
        .checked_sub(half)
        .filter(|&j| j < hp)
        .map(|j| &rows[j * wu..(j + 1) * wu]);
    let lower = (r < hp).then(|| &rows[r * wu..(r + 1) * wu]);
    (upper, lower)
}

/// Level `h` from level `h − 1` (`prev`, stride `half = 2^(h−1)`): each cell the maximum of the
/// 2 × 2 cells `half` apart, i.e. of a `2^h × 2^h` window of the likelihood. Separable: rows
/// first, then pairs of rows, without per-cell bounds checks.
fn pool(prev: &Level, half: i64, base_w: i64, base_h: i64, sequential: bool) -> Level {
    let w = 2 * half;
    let shift = w - 1;
    let width = base_w + shift;
    let height = base_h + shift;
    let (wp, hp, h) = (prev.width as usize, prev.height as usize, half as usize);
    debug_assert_eq!(width as usize, wp + h);
    debug_assert_eq!(height as usize, hp + h);
    let wu = width as usize;
    if sequential {
        // Each output written once, in order, into buffers that start empty (no zeroed buffers
        // filled again). The same maxima of the same cells: a maximum is exact.
        let mut rows = Vec::with_capacity(hp * wu);
        for a in prev.data.chunks_exact(wp) {
            push_max_with_shifted(a, h, &mut rows);
        }
        let mut data = Vec::with_capacity(wu * height as usize);
        for r in 0..height as usize {
            match row_pair(&rows, r, h, hp, wu) {
                (Some(a), Some(b)) => data.extend(a.iter().zip(b).map(|(x, y)| larger(*x, *y))),
                (Some(a), None) | (None, Some(a)) => data.extend_from_slice(a),
                (None, None) => data.resize(data.len() + wu, 0.0),
            }
        }
        return Level {
            shift,
            width,
            height,
            data,
        };
    }
    let mut rows = vec![0.0f32; hp * wu];
    rows.par_chunks_mut(wu)
        .zip(prev.data.par_chunks(wp))
        .with_min_len(min_len(sequential))
        .for_each(|(out, a)| max_with_shifted(a, h, out));
    let mut data = vec![0.0f32; wu * height as usize];
    data.par_chunks_mut(wu)
        .with_min_len(min_len(sequential))
        .enumerate()
        .for_each(|(r, out)| match row_pair(&rows, r, h, hp, wu) {
            (Some(a), Some(b)) => {
                for ((o, x), y) in out.iter_mut().zip(a).zip(b) {
                    *o = larger(*x, *y);
                }
            }
            (Some(a), None) | (None, Some(a)) => out.copy_from_slice(a),
            (None, None) => {}
        });
    Level {
        shift,
        width,
        height,
        data,
    }
}

/// Cells `[i0, i1)` of row `j` of the level pooled from `prev` with stride `half`, written to
/// `out` (`i1 − i0` values): each the maximum of prev's cells `(i − half | i, j − half | j)`
/// that exist, 0 where none does ([`pool`]'s values: all are ≥ 0, and a maximum is exact
/// whatever the order in which it is taken).
fn pool_run(prev: &Level, half: i64, j: i64, i0: i64, i1: i64, out: &mut [f32]) {
    let (pw, ph) = (prev.width, prev.height);
    let row = |jp: i64| {
        (jp >= 0 && jp < ph).then(|| &prev.data[(jp * pw) as usize..((jp + 1) * pw) as usize])
    };
    let rows = [row(j - half), row(j)];
    if i0 >= half && i1 <= pw {
        // Both columns of every cell exist (all but the level's edges): a loop without
        // bounds tests, which vectorises.
        let (a, b, n) = ((i0 - half) as usize, i0 as usize, (i1 - i0) as usize);
        match rows {
            // One pass over both rows: the values of the row-by-row loop below (whose zero
            // start never wins: likelihoods are >= 0).
            [Some(r0), Some(r1)] => {
                let cells = out
                    .iter_mut()
                    .zip(r0[b..b + n].iter().zip(&r0[a..a + n]))
                    .zip(r1[b..b + n].iter().zip(&r1[a..a + n]));
                for ((o, (x0, y0)), (x1, y1)) in cells {
                    *o = larger(larger(*x0, *y0), larger(*x1, *y1));
                }
            }
            _ => {
                out.fill(0.0);
                for r in rows.iter().flatten() {
                    for ((o, x), y) in out.iter_mut().zip(&r[b..b + n]).zip(&r[a..a + n]) {
                        *o = larger(*o, larger(*x, *y));
                    }
                }
            }
        }
        return;
    }
    for (o, i) in out.iter_mut().zip(i0..i1) {
        let mut v = 0.0f32;
        for r in rows.iter().flatten() {
            if i < pw {
                v = larger(v, r[i as usize]);
            }
            let k = i - half;
            if k >= 0 && k < pw {
                v = larger(v, r[k as usize]);
            }
        }
        *o = v;
    }
}

/// Pool again, in place, the cells of `level` (stride `half`, from `prev`, its level below,
/// already up to date) whose window holds a cell of a base block marked in `changed`
/// (`blocks_x` blocks a row, of `DIRTY_BLOCK²` cells, on the canvas): every other cell holds
/// the maximum it held. A keyframe changes a few per cent of a long-range laser's local map
/// (the Freiburg hospital's: 1 % of 1.2 M cells, in 5 % of the blocks). The same bits as
/// [`pool`] (tested).
fn repool_in_place(prev: &Level, level: &mut Level, half: i64, changed: &[bool], blocks_x: usize) {
    let b = DIRTY_BLOCK as i64;
    let shift = 2 * half - 1;
    let (width, height) = (level.width, level.height);
    // The changed blocks' columns, by block row.
    let by_row: Vec<Vec<i64>> = changed
        .chunks(blocks_x)
        .map(|row| (0..row.len() as i64).filter(|&x| row[x as usize]).collect())
        .collect();
    let mut runs: Vec<(i64, i64)> = Vec::new();
    for j in 0..height {
        // Level cell (i, j) pools the base cells [i − shift, i] × [j − shift, j]: row j meets
        // the block rows from (j − shift) / b to j / b, and a changed block of column bx
        // makes its cells [bx·b, bx·b + b − 1 + shift] stale.
        let (lo, hi) = ((j - shift).max(0) / b, (j / b).min(by_row.len() as i64 - 1));
        runs.clear();
        for row in by_row
            .iter()
            .take((hi + 1).max(0) as usize)
            .skip(lo as usize)
        {
            runs.extend(
                row.iter()
                    .map(|&bx| (bx * b, (bx * b + b + shift).min(width))),
            );
        }
        if runs.is_empty() {
            continue;
        }
        runs.sort_unstable();
        let o = (j * width) as usize;
        let mut pool_cells = |i0: i64, i1: i64| {
            let out = &mut level.data[o + i0 as usize..o + i1 as usize];
            pool_run(prev, half, j, i0, i1, out);
        };
        let (mut i0, mut i1) = runs[0];
        for &(s0, s1) in &runs[1..] {
            if s0 <= i1 {
                i1 = i1.max(s1);
            } else {
                pool_cells(i0, i1);
                (i0, i1) = (s0, s1);
            }
        }
        pool_cells(i0, i1);
    }
}

/// Largest disc [`stamped`] lays (offsets held in memory): a blur hundreds of cells wide
/// takes the distance transform instead.
const MAX_STAMP_OFFSETS: usize = 1 << 20;

/// The grid's margin in cells around the reference: `4σ` and one cell (beyond, the
/// likelihood is < 3.4e-4 of a hit).
fn support(sigma: f64, resolution: f64) -> i64 {
    (4.0 * sigma / resolution).ceil() as i64 + 1
}

/// Likelihood and squared distance (cells²) by stamping a disc of radius `reach` around each
/// occupied cell, clipped to the lattice.
fn stamped(
    occupied: &[usize],
    width: usize,
    height: usize,
    reach: i64,
    gauss: &Gaussian,
) -> (Vec<f32>, Vec<f32>) {
    let offsets = disc_stamps(reach, gauss);
    let mut likelihood = vec![0.0f32; width * height];
    let mut dist2 = vec![f32::INFINITY; width * height];
    let (w, h) = (width as i64, height as i64);
    for &c in occupied {
        let (cx, cy) = ((c % width) as i64, (c / width) as i64);
        for &(dx, dy, d, g) in &offsets {
            let (x, y) = (cx + dx, cy + dy);
            if x < 0 || y < 0 || x >= w || y >= h {
                continue;
            }
            let i = (y * w + x) as usize;
            if d < dist2[i] {
                dist2[i] = d;
                likelihood[i] = g;
            }
        }
    }
    (likelihood, dist2)
}

/// Likelihood and squared distance (cells²) by the exact distance transform (Felzenszwalb
/// and Huttenlocher's, along rows then columns), the distance cut at `reach` as [`stamped`]
/// cuts it (the likelihood is `+0.0` there either way: [`Gaussian::reach`]).
fn transformed(
    occupied: &[usize],
    width: usize,
    height: usize,
    reach: i64,
    gauss: &Gaussian,
) -> (Vec<f32>, Vec<f32>) {
    let mut d2 = vec![f64::INFINITY; width * height];
    for &c in occupied {
        d2[c] = 0.0;
    }
    let seq = width * height <= SEQUENTIAL_CELLS;
    transform_lines(&mut d2, width, seq); // along x (rows)
    let mut cols = transpose(&d2, width, height, seq);
    transform_lines(&mut cols, height, seq); // along y (columns)
    let cut = (reach * reach) as f64;
    // Both grids row-major straight from the columns (no transpose back).
    let mut likelihood = vec![0.0f32; width * height];
    let mut dist2 = vec![f32::INFINITY; width * height];
    likelihood
        .par_chunks_mut(width)
        .zip(dist2.par_chunks_mut(width))
        .with_min_len(min_len(seq))
        .enumerate()
        .for_each(|(y, (like, dist))| {
            for (x, (l, e)) in like.iter_mut().zip(dist.iter_mut()).enumerate() {
                let d = cols[x * height + y];
                if d <= cut {
                    *l = gauss.at(d);
                    *e = d as f32;
                }
            }
        });
    (likelihood, dist2)
}

/// The offsets `(dx, dy)` of a disc of radius `reach` cells (`dx² + dy² ≤ reach²`).
fn disc_offsets(reach: i64) -> Vec<(i64, i64)> {
    (-reach..=reach)
        .flat_map(|dy| (-reach..=reach).map(move |dx| (dx, dy)))
        .filter(|&(dx, dy)| dx * dx + dy * dy <= reach * reach)
        .collect()
}

/// Each cell of the disc of radius `reach` with its squared distance (cells²) and likelihood:
/// what an occupied cell stamps around itself.
fn disc_stamps(reach: i64, gauss: &Gaussian) -> Vec<(i64, i64, f32, f32)> {
    disc_offsets(reach)
        .into_iter()
        .map(|(dx, dy)| {
            let d = (dx * dx + dy * dy) as f64;
            (dx, dy, d as f32, gauss.at(d))
        })
        .collect()
}

/// [`disc_stamps`] by rows, each row's squared distances and likelihoods in runs of `dx`.
struct DiscRows {
    reach: i64,
    /// Half-width of the row `dy = r − reach` and where its values start.
    rows: Vec<(i64, usize)>,
    d: Vec<f32>,
    g: Vec<f32>,
}

impl DiscRows {
    fn new(reach: i64, gauss: &Gaussian) -> Self {
        let (mut rows, mut d, mut g) = (Vec::new(), Vec::new(), Vec::new());
        for row in disc_stamps(reach, gauss).chunk_by(|a, b| a.1 == b.1) {
            rows.push((-row[0].0, d.len()));
            d.extend(row.iter().map(|s| s.2));
            g.extend(row.iter().map(|s| s.3));
        }
        DiscRows { reach, rows, d, g }
    }

    /// The disc around `(cx, cy)` clipped to `view` (`[x0, y0, x1, y1]`): per row its `y`, the
    /// cells `[x0, x1)` and where their values start in `d` and `g`.
    fn rows(
        &self,
        cx: i64,
        cy: i64,
        view: [i64; 4],
    ) -> impl Iterator<Item = (i64, i64, i64, usize)> + '_ {
        self.rows
            .iter()
            .enumerate()
            .filter_map(move |(r, &(half, start))| {
                let y = cy + r as i64 - self.reach;
                let (x0, x1) = ((cx - half).max(view[0]), (cx + half + 1).min(view[2]));
                (y >= view[1] && y < view[3] && x0 < x1)
                    .then(|| (y, x0, x1, start + (x0 - (cx - half)) as usize))
            })
    }
}

/// The cells of sorted, deduplicated `old` not in `new` and of `new` not in `old`.
fn differences(old: &[[i64; 2]], new: &[[i64; 2]]) -> (Vec<[i64; 2]>, Vec<[i64; 2]>) {
    let (mut i, mut j) = (0, 0);
    let (mut removed, mut added) = (Vec::new(), Vec::new());
    while i < old.len() && j < new.len() {
        match old[i].cmp(&new[j]) {
            std::cmp::Ordering::Less => {
                removed.push(old[i]);
                i += 1;
            }
            std::cmp::Ordering::Greater => {
                added.push(new[j]);
                j += 1;
            }
            std::cmp::Ordering::Equal => {
                i += 1;
                j += 1;
            }
        }
    }
    removed.extend_from_slice(&old[i..]);
    added.extend_from_slice(&new[j..]);
    (removed, added)
}

/// Side of the blocks an update marks (cells).
const DIRTY_BLOCK: usize = 16;

/// The scratch of [`LikelihoodGrid::update`]: a mark per canvas cell, the cell stamped again
/// in this update when its mark is the update's generation, kept from update to update so
/// that a large canvas is not cleared each time. Not part of the grid's value: a clone starts
/// afresh.
#[derive(Debug, Default)]
struct Marks {
    mark: Vec<u32>,
    generation: u32,
}

impl Clone for Marks {
    fn clone(&self) -> Self {
        Marks::default()
    }
}

/// Whether a block of `blocks` (`blocks_x` a row) within `reach` (Chebyshev) of canvas cell
/// `(x, y)` is marked: a superset of the cells that may have a marked cell within reach.
fn near_marked(blocks: &[bool], blocks_x: usize, x: i64, y: i64, reach: i64) -> bool {
    let b = DIRTY_BLOCK as i64;
    let rows = blocks.len() / blocks_x;
    let (bx0, bx1) = (
        ((x - reach).max(0) / b) as usize,
        (((x + reach).max(0) / b) as usize).min(blocks_x - 1),
    );
    let (by0, by1) = (
        ((y - reach).max(0) / b) as usize,
        (((y + reach).max(0) / b) as usize).min(rows - 1),
    );
    (by0..=by1).any(|by| blocks[by * blocks_x + bx0..=by * blocks_x + bx1].contains(&true))
}

/// The parts `[x0, x1)` of `[a0, a1)` outside `[b0, b1)` (empty ranges where there is none).
fn outside(a0: i64, a1: i64, b0: i64, b1: i64) -> [(i64, i64); 2] {
    if b1 <= a0 || b0 >= a1 || b0 >= b1 {
        return [(a0, a1), (0, 0)];
    }
    [(a0, b0.min(a1)), (b1.max(a0), a1)]
}

fn check_settings(resolution: f64, sigma: f64, levels: usize) -> Result<()> {
    if !(resolution.is_finite() && resolution > 0.0) {
        return Err(Error::invalid(
            "resolution",
            format!("must be finite and > 0, got {resolution}"),
        ));
    }
    if !(sigma.is_finite() && sigma > 0.0) {
        return Err(Error::invalid(
            "sigma",
            format!("must be finite and > 0, got {sigma}"),
        ));
    }
    if levels > MAX_LEVELS {
        return Err(Error::invalid(
            "levels",
            format!("at most {MAX_LEVELS}, got {levels}"),
        ));
    }
    Ok(())
}

impl Lattice {
    /// The cells of `reference` (checked finite, non-empty) with the blur's margin.
    fn of(reference: &[f64], resolution: f64, sigma: f64) -> Result<Self> {
        // The margin holds the blur's whole support around every reference cell.
        let margin = support(sigma, resolution) as f64;
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in reference.chunks_exact(2) {
            for a in 0..2 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        // Cell boundaries on multiples of the resolution: the lattice does not depend on
        // where the reference happens to start.
        let first = [
            (lo[0] / resolution).floor() - margin,
            (lo[1] / resolution).floor() - margin,
        ];
        let origin = [first[0] * resolution, first[1] * resolution];
        let cells_x = ((hi[0] - origin[0]) / resolution).floor() + margin + 1.0;
        let cells_y = ((hi[1] - origin[1]) / resolution).floor() + margin + 1.0;
        if cells_x * cells_y > MAX_CELLS as f64 || !(cells_x * cells_y).is_finite() {
            return Err(Error::invalid(
                "resolution",
                format!(
                    "the reference spans {cells_x} × {cells_y} cells at {resolution} m \
                     (more than {MAX_CELLS}); use a coarser resolution"
                ),
            ));
        }
        Ok(Lattice {
            origin,
            offset: [first[0] as i64, first[1] as i64],
            width: cells_x as usize,
            height: cells_y as usize,
        })
    }

    /// The cells `reference`'s points fall in, row-major indices, sorted and deduplicated.
    fn occupied(&self, reference: &[f64], resolution: f64) -> Vec<usize> {
        let (origin, width, height) = (self.origin, self.width, self.height);
        let mut occupied: Vec<usize> = reference
            .chunks_exact(2)
            .map(|p| {
                let cx = ((p[0] - origin[0]) / resolution).floor() as usize;
                let cy = ((p[1] - origin[1]) / resolution).floor() as usize;
                cy.min(height - 1) * width + cx.min(width - 1)
            })
            .collect();
        occupied.sort_unstable();
        occupied.dedup();
        occupied
    }

    /// Row-major indices as global `[y, x]` (the order is kept: sorted stays sorted).
    fn global(&self, cells: &[usize]) -> Vec<[i64; 2]> {
        cells
            .iter()
            .map(|&c| {
                [
                    (c / self.width) as i64 + self.offset[1],
                    (c % self.width) as i64 + self.offset[0],
                ]
            })
            .collect()
    }
}

impl LikelihoodGrid {
    /// Rasterise `reference` (flat `(N, 2)`, metres) at `resolution` (m/cell) with blur `sigma`
    /// (m), and precompute `levels` max-pooled grids (`0` = none: exhaustive search only).
    pub fn build(reference: &[f64], resolution: f64, sigma: f64, levels: usize) -> Result<Self> {
        check_points(reference, "reference")?;
        check_settings(resolution, sigma, levels)?;
        let lattice = Lattice::of(reference, resolution, sigma)?;
        Ok(Self::rasterise(
            reference, lattice, resolution, sigma, levels,
        ))
    }

    /// The distance transform and likelihood of `reference` on the given lattice, within the
    /// likelihood's support ([`Gaussian::reach`]): a cell farther than that from every
    /// reference cell holds likelihood 0 (what the full transform gives there too) and
    /// distance +∞.
    fn rasterise(
        reference: &[f64],
        lattice: Lattice,
        resolution: f64,
        sigma: f64,
        levels: usize,
    ) -> Self {
        let (width, height) = (lattice.width, lattice.height);
        let occupied = lattice.occupied(reference, resolution);
        let gauss = Gaussian::new((sigma / resolution).powi(2), width * height);
        let reach = gauss.reach();
        let disc = ((2 * reach + 1) * (2 * reach + 1)) as usize;
        // Stamping a disc per occupied cell costs O(cells occupied · reach²), the distance
        // transform O(cells) over ~4 passes: a long-range laser's local map (80 m across at
        // 5 cm, 2.5 M cells, a few thousand occupied) stamps several times faster. The same
        // grid either way (tested).
        let stamp =
            disc <= MAX_STAMP_OFFSETS && occupied.len().saturating_mul(disc) < 4 * width * height;
        let (likelihood, dist2) = if stamp {
            stamped(&occupied, width, height, reach, &gauss)
        } else {
            transformed(&occupied, width, height, reach, &gauss)
        };
        let base = Level {
            shift: 0,
            width: width as i64,
            height: height as i64,
            data: likelihood,
        };
        let global = lattice.global(&occupied);
        LikelihoodGrid {
            origin: lattice.origin,
            resolution,
            sigma,
            width,
            height,
            dist2,
            base,
            canvas: lattice.offset,
            canvas_size: [width, height],
            pooled: (0..levels).map(|_| OnceLock::new()).collect(),
            marks: Marks::default(),
            offset: lattice.offset,
            occupied: global,
        }
    }

    /// The grid of `reference` — what [`LikelihoodGrid::build`] gives with this grid's
    /// resolution, blur and levels, to the bit — computed from this one
    /// ([`LikelihoodGrid::update`] of a copy).
    pub fn updated(&self, reference: &[f64]) -> Result<Self> {
        let mut grid = self.clone();
        grid.update(reference)?;
        Ok(grid)
    }

    /// This grid made the grid of `reference` (what [`LikelihoodGrid::build`] gives with its
    /// resolution, blur and levels, to the bit), in place; unchanged on an error. A cell's
    /// likelihood and distance are those of the nearest occupied cell within the blur's
    /// support ([`Gaussian::reach`]), so: a cell near an occupied cell that disappeared, or one
    /// the lattice gained, is stamped again from the occupied cells near it; any other keeps
    /// its value, lowered by the discs of the occupied cells that appeared (a nearer cell can
    /// only lower a minimum); the pooled levels are pooled again where their window holds a
    /// base cell that changed. A local map that gains a keyframe and drops its oldest changes
    /// a few hundred of its thousands of occupied cells.
    ///
    /// The rasters live on a canvas a margin wider than the lattice, 0 (distance +∞) outside
    /// it, so that a lattice that moves or resizes within the canvas moves no cell: only a
    /// lattice that leaves it lays a new canvas (and pools its levels again on first use).
    pub fn update(&mut self, reference: &[f64]) -> Result<()> {
        check_points(reference, "reference")?;
        let (resolution, sigma) = (self.resolution, self.sigma);
        let lattice = Lattice::of(reference, resolution, sigma)?;
        let (width, height) = (lattice.width, lattice.height);
        let occupied = lattice.occupied(reference, resolution);
        let global = lattice.global(&occupied);
        let gauss = Gaussian::new((sigma / resolution).powi(2), width * height);
        let reach = gauss.reach();
        let fits = lattice.offset[0] >= self.canvas[0]
            && lattice.offset[1] >= self.canvas[1]
            && lattice.offset[0] + width as i64 <= self.canvas[0] + self.canvas_size[0] as i64
            && lattice.offset[1] + height as i64 <= self.canvas[1] + self.canvas_size[1] as i64;
        if !fits {
            self.recanvas(&lattice);
        }
        // The old and the new lattice on the canvas, [x0, y0, x1, y1].
        let old = self.view();
        self.origin = lattice.origin;
        self.offset = lattice.offset;
        self.width = width;
        self.height = height;
        let new = self.view();
        let canvas = self.canvas;
        let [cw, ch] = self.canvas_size;
        let blocks_x = cw.div_ceil(DIRTY_BLOCK);
        let blocks = blocks_x * ch.div_ceil(DIRTY_BLOCK);
        let block =
            |x: i64, y: i64| (y as usize / DIRTY_BLOCK) * blocks_x + x as usize / DIRTY_BLOCK;
        // Blocks holding a cell stamped again, and blocks whose likelihood changed.
        let mut dirty = vec![false; blocks];
        let mut changed = vec![false; blocks];
        if self.marks.mark.len() != cw * ch {
            self.marks = Marks {
                mark: vec![0; cw * ch],
                generation: 0,
            };
        }
        self.marks.generation = self.marks.generation.wrapping_add(1);
        if self.marks.generation == 0 {
            self.marks.mark.fill(0);
            self.marks.generation = 1;
        }
        let generation = self.marks.generation;
        let mark = &mut self.marks.mark;
        let like = &mut self.base.data;
        let dist = &mut self.dist2;
        let cw = cw as i64;
        // The cells stamped again, with their likelihood before (bits).
        let mut cleared: Vec<(usize, u32)> = Vec::new();
        // The cells the lattice lost: 0 and +∞, as the canvas is outside the lattice.
        for y in old[1]..old[3] {
            let parts = if y >= new[1] && y < new[3] {
                outside(old[0], old[2], new[0], new[2])
            } else {
                [(old[0], old[2]), (0, 0)]
            };
            for (x0, x1) in parts {
                for x in x0..x1 {
                    let i = (y * cw + x) as usize;
                    if like[i].to_bits() != 0 {
                        changed[block(x, y)] = true;
                    }
                    like[i] = 0.0;
                    dist[i] = f32::INFINITY;
                }
            }
        }
        // The cells it gained (0 and +∞ until stamped): stamped again.
        for y in new[1]..new[3] {
            let parts = if y >= old[1] && y < old[3] {
                outside(new[0], new[2], old[0], old[2])
            } else {
                [(new[0], new[2]), (0, 0)]
            };
            for (x0, x1) in parts {
                for x in x0..x1 {
                    let i = (y * cw + x) as usize;
                    mark[i] = generation;
                    dirty[block(x, y)] = true;
                    cleared.push((i, like[i].to_bits()));
                }
            }
        }
        let disc = DiscRows::new(reach, &gauss);
        let on_canvas = |c: &[i64; 2]| (c[1] - canvas[0], c[0] - canvas[1]);
        let (removed, added) = differences(&self.occupied, &global);
        // A cell whose nearest occupied cell disappeared may have another: cleared, then
        // stamped again (below) by every occupied cell with a cleared cell within reach. A
        // cell nearer another occupied cell keeps its value (when that one disappeared too,
        // the cell is cleared with its disc).
        for c in &removed {
            let (cx, cy) = on_canvas(c);
            for (y, x0, x1, k) in disc.rows(cx, cy, new) {
                for x in x0..x1 {
                    let i = (y * cw + x) as usize;
                    if mark[i] != generation && dist[i] >= disc.d[k + (x - x0) as usize] {
                        mark[i] = generation;
                        dirty[block(x, y)] = true;
                        cleared.push((i, like[i].to_bits()));
                        like[i] = 0.0;
                        dist[i] = f32::INFINITY;
                    }
                }
            }
        }
        if !cleared.is_empty() {
            for c in &global {
                let (cx, cy) = on_canvas(c);
                if !near_marked(&dirty, blocks_x, cx, cy, reach) {
                    continue;
                }
                for (y, x0, x1, k) in disc.rows(cx, cy, new) {
                    // A row whose blocks hold no cleared cell is skipped whole (the discs that
                    // reach a cleared cell mostly lie beside it).
                    let by = y as usize / DIRTY_BLOCK * blocks_x;
                    let (b0, b1) = (x0 as usize / DIRTY_BLOCK, (x1 - 1) as usize / DIRTY_BLOCK);
                    if !dirty[by + b0..=by + b1].contains(&true) {
                        continue;
                    }
                    let cells = (y * cw + x0) as usize..(y * cw + x1) as usize;
                    let n = cells.len();
                    let stamp = disc.d[k..k + n].iter().zip(&disc.g[k..k + n]);
                    for (((e, l), m), (&d, &g)) in dist[cells.clone()]
                        .iter_mut()
                        .zip(&mut like[cells.clone()])
                        .zip(&mark[cells])
                        .zip(stamp)
                    {
                        if d < *e && *m == generation {
                            *e = d;
                            *l = g;
                        }
                    }
                }
            }
        }
        for c in &added {
            let (cx, cy) = on_canvas(c);
            for (y, x0, x1, k) in disc.rows(cx, cy, new) {
                for x in x0..x1 {
                    let i = (y * cw + x) as usize;
                    let (d, g) = (disc.d[k + (x - x0) as usize], disc.g[k + (x - x0) as usize]);
                    if d < dist[i] {
                        if mark[i] != generation && like[i].to_bits() != g.to_bits() {
                            changed[block(x, y)] = true;
                        }
                        dist[i] = d;
                        like[i] = g;
                    }
                }
            }
        }
        // Stamped again: mostly their old value back; only the blocks that changed count.
        for &(i, before) in &cleared {
            if like[i].to_bits() != before {
                let (x, y) = ((i as i64) % cw, (i as i64) / cw);
                changed[block(x, y)] = true;
            }
        }
        self.occupied = global;
        // The levels pooled so far, again where they can have changed (each from the one
        // below, already up to date); the others are pooled on first use.
        let base = &self.base;
        let pooled = &mut self.pooled;
        for h in 1..=pooled.len() {
            let (below, here) = pooled.split_at_mut(h - 1);
            let Some(level) = here[0].get_mut() else {
                break; // (levels are pooled from the bottom: none above is either)
            };
            let prev: &Level = if h == 1 {
                base
            } else {
                below[h - 2].get().expect("the level below is pooled")
            };
            let half = 1i64 << (h - 1);
            repool_in_place(prev, Arc::make_mut(level), half, &changed, blocks_x);
        }
        Ok(())
    }

    /// The lattice on the canvas: `[x0, y0, x1, y1]` (cells).
    fn view(&self) -> [i64; 4] {
        let x0 = self.offset[0] - self.canvas[0];
        let y0 = self.offset[1] - self.canvas[1];
        [x0, y0, x0 + self.width as i64, y0 + self.height as i64]
    }

    /// A new canvas around `lattice` (a margin of an eighth of its size, at least 32 cells,
    /// on every side), holding the current lattice's cells where the two overlap; the levels
    /// are pooled again on first use. The lattice's fields are left to the caller (the
    /// current lattice, on the new canvas, is what [`LikelihoodGrid::view`] then gives).
    fn recanvas(&mut self, lattice: &Lattice) {
        let margin = |n: usize| (n / 8).max(32);
        let (mut mx, mut my) = (margin(lattice.width), margin(lattice.height));
        if (lattice.width + 2 * mx) * (lattice.height + 2 * my) > MAX_CELLS {
            (mx, my) = (0, 0); // (the lattice itself is within the limit)
        }
        let canvas = [lattice.offset[0] - mx as i64, lattice.offset[1] - my as i64];
        let (cw, ch) = (lattice.width + 2 * mx, lattice.height + 2 * my);
        let mut like = vec![0.0f32; cw * ch];
        let mut dist = vec![f32::INFINITY; cw * ch];
        // The current lattice's cells that are on the new canvas (global x0, y0, x1, y1).
        let x0 = self.offset[0].max(canvas[0]);
        let x1 = (self.offset[0] + self.width as i64).min(canvas[0] + cw as i64);
        let y0 = self.offset[1].max(canvas[1]);
        let y1 = (self.offset[1] + self.height as i64).min(canvas[1] + ch as i64);
        let old_w = self.canvas_size[0] as i64;
        for y in y0..y1.max(y0) {
            if x0 >= x1 {
                break;
            }
            let from = ((y - self.canvas[1]) * old_w + x0 - self.canvas[0]) as usize;
            let to = ((y - canvas[1]) * cw as i64 + x0 - canvas[0]) as usize;
            let n = (x1 - x0) as usize;
            like[to..to + n].copy_from_slice(&self.base.data[from..from + n]);
            dist[to..to + n].copy_from_slice(&self.dist2[from..from + n]);
        }
        self.base = Level {
            shift: 0,
            width: cw as i64,
            height: ch as i64,
            data: like,
        };
        self.dist2 = dist;
        // The lattice's cells that are not on the new canvas are dropped: the view becomes
        // their intersection (its cells outside it are 0, as the canvas outside a lattice).
        let (nx0, ny0) = (x0.min(x1), y0.min(y1));
        self.offset = [nx0, ny0];
        self.width = (x1 - nx0).max(0) as usize;
        self.height = (y1 - ny0).max(0) as usize;
        self.canvas = canvas;
        self.canvas_size = [cw, ch];
        self.pooled = (0..self.pooled.len()).map(|_| OnceLock::new()).collect();
    }

    /// Level `h` (`0`: the likelihood), pooling it on first use.
    fn level(&self, h: usize) -> &Level {
        if h == 0 {
            return &self.base;
        }
        self.pooled[h - 1].get_or_init(|| {
            let half = 1i64 << (h - 1);
            let prev = self.level(h - 1);
            let [w, h] = self.canvas_size;
            Arc::new(pool(
                prev,
                half,
                w as i64,
                h as i64,
                w * h <= SEQUENTIAL_CELLS,
            ))
        })
    }

    pub fn origin(&self) -> [f64; 2] {
        self.origin
    }
    pub fn resolution(&self) -> f64 {
        self.resolution
    }
    pub fn sigma(&self) -> f64 {
        self.sigma
    }
    /// `(width, height)` in cells (x, y).
    pub fn shape(&self) -> (usize, usize) {
        (self.width, self.height)
    }
    /// Pooled levels available for branch and bound.
    pub fn levels(&self) -> usize {
        self.pooled.len()
    }
    /// The likelihood, row-major `height × width` (row = y).
    pub fn likelihood(&self) -> Vec<f32> {
        self.on_lattice(&self.base.data)
    }
    /// Squared distance to the nearest occupied cell (cells²), row-major `height × width`.
    pub fn dist2(&self) -> Vec<f32> {
        self.on_lattice(&self.dist2)
    }

    /// The lattice's cells of a canvas raster.
    fn on_lattice(&self, raster: &[f32]) -> Vec<f32> {
        let [x0, y0, x1, y1] = self.view();
        let cw = self.canvas_size[0] as i64;
        let mut out = Vec::with_capacity(self.width * self.height);
        for y in y0..y1 {
            out.extend_from_slice(&raster[(y * cw + x0) as usize..(y * cw + x1) as usize]);
        }
        out
    }

    /// Canvas cell `(x, y)`'s squared distance (+∞ off the canvas).
    fn dist2_at(&self, x: i64, y: i64) -> f32 {
        let [w, h] = self.canvas_size;
        if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
            return f32::INFINITY;
        }
        self.dist2[y as usize * w + x as usize]
    }

    fn slice(&self, source: &[f64], center: [f64; 3], theta: f64, reach: [i64; 2]) -> Slice {
        let (s, c) = theta.sin_cos();
        let inv = 1.0 / self.resolution;
        // The lattice's cells (from its origin, as a build places them), on the canvas.
        let [dx, dy, _, _] = self.view();
        // A level reads cells `[−shift, canvas)` (0 beyond), its shift at most the coarsest's.
        let shift = (1i64 << self.pooled.len()) - 1;
        let [cw, ch] = self.canvas_size;
        let live = |v: i64, r: i64, size: usize| v + r >= -shift && v - r < size as i64;
        let cells: Vec<[i64; 2]> = source
            .chunks_exact(2)
            .map(|p| {
                let x = c * p[0] - s * p[1] + center[0];
                let y = s * p[0] + c * p[1] + center[1];
                [
                    ((x - self.origin[0]) * inv).floor() as i64 + dx,
                    ((y - self.origin[1]) * inv).floor() as i64 + dy,
                ]
            })
            .filter(|c| live(c[0], reach[0], cw) && live(c[1], reach[1], ch))
            .collect();
        Slice {
            cells,
            points: source.len() / 2,
        }
    }

    #[inline]
    fn sum(&self, level: usize, slice: &Slice, i: i64, j: i64) -> f64 {
        let g = self.level(level);
        slice
            .cells
            .iter()
            .fold(slice.zero(), |t, c| t + g.at(c[0] + i, c[1] + j) as f64)
    }

    /// [`Self::sum`] at the `K` offsets `at` in one pass over the slice: each total is added
    /// in the points' order from the same start as `sum` adds it (the same bits), but `K`
    /// independent totals keep the pipeline busy where one waits on its previous addition
    /// (a branch and bound's bounds are such chains of dependent additions).
    #[inline]
    fn sums<const K: usize>(&self, level: usize, slice: &Slice, at: &[[i64; 2]; K]) -> [f64; K] {
        let g = self.level(level);
        let mut total = [slice.zero(); K];
        for c in &slice.cells {
            for (t, o) in total.iter_mut().zip(at) {
                *t += g.at(c[0] + o[0], c[1] + o[1]) as f64;
            }
        }
        total
    }

    fn fitness(&self, slice: &Slice, i: i64, j: i64) -> f64 {
        let hits = slice
            .cells
            .iter()
            .filter(|c| self.dist2_at(c[0] + i, c[1] + j) <= 2.0)
            .count();
        hits as f64 / slice.points as f64
    }

    fn slices(&self, source: &[f64], w: &Window, sequential: bool) -> Vec<Slice> {
        (0..(2 * w.ntheta + 1) as usize)
            .into_par_iter()
            .with_min_len(min_len(sequential))
            .map(|i| {
                let k = i as i64 - w.ntheta;
                self.slice(
                    source,
                    w.center,
                    w.center[2] + k as f64 * w.angular_step,
                    [w.nx.max(0), w.ny.max(0)],
                )
            })
            .collect()
    }

    fn finish(
        &self,
        w: &Window,
        slices: &[Slice],
        best: (f64, [i64; 3]),
        moments: Moments,
        evaluated: u64,
        bounds: u64,
    ) -> Match {
        let [k, i, j] = best.1;
        let slice = &slices[(k + w.ntheta) as usize];
        // `best.0` is the objective (less the motion cost, if any): report the scan's own sum.
        let sum = self.sum(0, slice, i, j);
        let n = slice.points as f64;
        let (covariance, mean) = moments.covariance(w, self.resolution);
        Match {
            pose: [
                w.center[0] + i as f64 * self.resolution,
                w.center[1] + j as f64 * self.resolution,
                w.center[2] + k as f64 * w.angular_step,
            ],
            index: [k, i, j],
            sum,
            score: sum / n,
            fitness: self.fitness(slice, i, j),
            covariance,
            mean,
            evaluated,
            bounds,
            covariance_candidates: moments.count,
        }
    }
}

fn check_window(w: &Window) -> Result<()> {
    if !w.center.iter().all(|v| v.is_finite()) {
        return Err(Error::invalid("init", "contains NaN or inf"));
    }
    if w.nx < 0 || w.ny < 0 || w.ntheta < 0 {
        return Err(Error::invalid("window", "half-widths must be >= 0"));
    }
    if !(w.angular_step.is_finite() && w.angular_step > 0.0) {
        return Err(Error::invalid(
            "angular_resolution",
            format!("must be finite and > 0, got {}", w.angular_step),
        ));
    }
    if let Some(p) = w.penalty {
        let symmetric = (0..3).all(|a| (0..3).all(|b| p[a * 3 + b] == p[b * 3 + a]));
        if !p.iter().all(|v| v.is_finite()) || !symmetric || (0..3).any(|a| p[a * 4] < 0.0) {
            return Err(Error::invalid(
                "penalty",
                "must be a finite, symmetric positive semi-definite 3x3 matrix",
            ));
        }
    }
    let count = (2 * w.nx + 1) as f64 * (2 * w.ny + 1) as f64 * (2 * w.ntheta + 1) as f64;
    if count > 1e12 {
        return Err(Error::invalid(
            "window",
            format!("{count:.3e} candidates; shrink the window or coarsen the steps"),
        ));
    }
    Ok(())
}

/// Streaming weighted moments of `(i, j, k)` with weights `exp(S − ref)`, rescaled when a
/// larger reference arrives (the log-sum-exp trick), so no score surface is stored.
#[derive(Debug, Clone, Copy)]
struct Moments {
    reference: f64,
    w: f64,
    m1: [f64; 3],
    m2: [[f64; 3]; 3],
    count: u64,
}

impl Moments {
    fn new() -> Self {
        Moments {
            reference: f64::NEG_INFINITY,
            w: 0.0,
            m1: [0.0; 3],
            m2: [[0.0; 3]; 3],
            count: 0,
        }
    }

    fn rescale(&mut self, reference: f64) {
        if reference > self.reference {
            let f = if self.reference.is_finite() {
                (self.reference - reference).exp()
            } else {
                0.0
            };
            self.w *= f;
            for a in 0..3 {
                self.m1[a] *= f;
                for b in 0..3 {
                    self.m2[a][b] *= f;
                }
            }
            self.reference = reference;
        }
    }

    /// `x = (i, j, k)` in lattice steps.
    fn add(&mut self, sum: f64, x: [f64; 3]) {
        self.rescale(sum);
        let p = (sum - self.reference).exp();
        self.w += p;
        for a in 0..3 {
            self.m1[a] += p * x[a];
            for b in 0..3 {
                self.m2[a][b] += p * x[a] * x[b];
            }
        }
        self.count += 1;
    }

    fn merge(mut self, other: Moments) -> Moments {
        if !other.reference.is_finite() {
            return self;
        }
        self.rescale(other.reference);
        let f = (other.reference - self.reference).exp();
        self.w += f * other.w;
        for a in 0..3 {
            self.m1[a] += f * other.m1[a];
            for b in 0..3 {
                self.m2[a][b] += f * other.m2[a][b];
            }
        }
        self.count += other.count;
        self
    }

    /// Covariance and mean over `[x, y, θ]` (metres, radians; the mean is absolute).
    fn covariance(&self, w: &Window, resolution: f64) -> ([f64; 9], [f64; 3]) {
        let scale = [resolution, resolution, w.angular_step];
        let mu = self.m1.map(|m| m / self.w);
        let mut cov = [0.0; 9];
        for a in 0..3 {
            for b in 0..3 {
                let c = self.m2[a][b] / self.w - mu[a] * mu[b];
                cov[a * 3 + b] = c * scale[a] * scale[b];
            }
        }
        // Cancellation can leave tiny negative variances when one candidate dominates.
        for a in 0..3 {
            cov[a * 4] = cov[a * 4].max(0.0);
        }
        let mean = [
            w.center[0] + mu[0] * resolution,
            w.center[1] + mu[1] * resolution,
            w.center[2] + mu[2] * w.angular_step,
        ];
        (cov, mean)
    }
}

/// Best of two `(sum, key)`: larger sum, then smaller key.
#[inline]
fn better(a: (f64, [i64; 3]), b: (f64, [i64; 3])) -> bool {
    a.0 > b.0 || (a.0 == b.0 && a.1 < b.1)
}

/// Score every candidate of the window (parallel over θ); covariance over all of them.
pub fn match_exhaustive(grid: &LikelihoodGrid, source: &[f64], w: &Window) -> Result<Match> {
    let n = check_points(source, "source")?;
    check_window(w)?;
    let seq = search_work(w, n) <= SEQUENTIAL_WORK;
    let slices = grid.slices(source, w, seq);
    let cost = Cost::new(w, grid.resolution);
    let per_theta: Vec<((f64, [i64; 3]), Moments)> = slices
        .par_iter()
        .with_min_len(min_len(seq))
        .enumerate()
        .map(|(idx, slice)| {
            let k = idx as i64 - w.ntheta;
            let mut best = (f64::NEG_INFINITY, [k, 0, 0]);
            let mut m = Moments::new();
            for i in -w.nx..=w.nx {
                for j in -w.ny..=w.ny {
                    let s = grid.sum(0, slice, i, j);
                    m.add(s, [i as f64, j as f64, k as f64]);
                    let o = match &cost {
                        Some(c) => s - c.at(i as f64, j as f64, k as f64),
                        None => s,
                    };
                    if better((o, [k, i, j]), best) {
                        best = (o, [k, i, j]);
                    }
                }
            }
            (best, m)
        })
        .collect();
    let mut best = (f64::NEG_INFINITY, [i64::MAX; 3]);
    let mut moments = Moments::new();
    for (b, m) in per_theta {
        if better(b, best) {
            best = b;
        }
        moments = moments.merge(m);
    }
    let evaluated = moments.count;
    Ok(grid.finish(w, &slices, best, moments, evaluated, 0))
}

struct BnB<'a> {
    grid: &'a LikelihoodGrid,
    slices: &'a [Slice],
    w: &'a Window,
    cost: Option<Cost>,
    best: (f64, [i64; 3]),
    evaluated: u64,
    bounds: u64,
}

/// The bounds of up to four nodes of one rotation (`keys`, all on `level`): each node's
/// bound (level > 0) or leaf's objective (level 0), the sum on that level less the motion
/// cost's minimum over the node's block of candidates ([`with_cost`]); the sums taken
/// together ([`LikelihoodGrid::sums`]).
fn node_bounds(
    grid: &LikelihoodGrid,
    slice: &Slice,
    w: &Window,
    cost: &Option<Cost>,
    level: usize,
    keys: &[[i64; 3]],
) -> Vec<f64> {
    debug_assert!(keys.len() <= 4);
    let at = |n: usize| {
        let k = keys[n.min(keys.len() - 1)];
        [k[1], k[2]]
    };
    let sums: Vec<f64> = match keys.len() {
        0 => Vec::new(),
        1 => vec![grid.sum(level, slice, keys[0][1], keys[0][2])],
        2 => grid.sums(level, slice, &[at(0), at(1)]).to_vec(),
        _ => grid
            .sums(level, slice, &[at(0), at(1), at(2), at(3)])
            .to_vec(),
    };
    keys.iter()
        .zip(sums)
        .map(|(&key, sum)| with_cost(sum, w, cost, level, key))
        .collect()
}

/// A node's sum less the motion cost's minimum over its block of candidates.
fn with_cost(sum: f64, w: &Window, cost: &Option<Cost>, level: usize, key: [i64; 3]) -> f64 {
    match cost {
        None => sum,
        Some(c) if level == 0 => sum - c.at(key[1] as f64, key[2] as f64, key[0] as f64),
        Some(c) => {
            let span = (1i64 << level) - 1;
            let (i1, j1) = ((key[1] + span).min(w.nx), (key[2] + span).min(w.ny));
            let low = c.lower_bound(
                key[0] as f64,
                key[1] as f64,
                i1 as f64,
                key[2] as f64,
                j1 as f64,
            );
            sum - low
        }
    }
}

#[derive(Clone, Copy)]
struct Node {
    bound: f64,
    key: [i64; 3],
    level: usize,
}

impl BnB<'_> {
    /// The nodes `keys` (up to four of one rotation) on `level`, bounded together.
    fn nodes(&mut self, level: usize, keys: &[[i64; 3]]) -> Vec<Node> {
        let Some(first) = keys.first() else {
            return Vec::new();
        };
        let slice = &self.slices[(first[0] + self.w.ntheta) as usize];
        let bounds = node_bounds(self.grid, slice, self.w, &self.cost, level, keys);
        if level == 0 {
            self.evaluated += keys.len() as u64;
        } else {
            self.bounds += keys.len() as u64;
        }
        keys.iter()
            .zip(bounds)
            .map(|(&key, bound)| Node { bound, key, level })
            .collect()
    }

    fn sort(nodes: &mut [Node]) {
        nodes.sort_by(|a, b| b.bound.total_cmp(&a.bound).then(a.key.cmp(&b.key)));
    }

    fn explore(&mut self, nodes: &mut [Node]) {
        Self::sort(nodes);
        for n in nodes.iter() {
            // Ties must be explored: a leaf with an equal sum and a smaller key wins.
            if n.bound < self.best.0 {
                break;
            }
            if n.level == 0 {
                if better((n.bound, n.key), self.best) {
                    self.best = (n.bound, n.key);
                }
                continue;
            }
            let half = 1i64 << (n.level - 1);
            let mut keys = Vec::with_capacity(4);
            for di in [0, half] {
                let i = n.key[1] + di;
                if i > self.w.nx {
                    continue;
                }
                for dj in [0, half] {
                    let j = n.key[2] + dj;
                    if j > self.w.ny {
                        continue;
                    }
                    keys.push([n.key[0], i, j]);
                }
            }
            let mut children = self.nodes(n.level - 1, &keys);
            self.explore(&mut children);
        }
    }
}

/// Branch and bound over the same lattice as [`match_exhaustive`] (same answer); the
/// covariance is accumulated over a dense `±cov_radius`-step neighbourhood of the optimum
/// (clipped to the window).
pub fn match_branch_and_bound(
    grid: &LikelihoodGrid,
    source: &[f64],
    w: &Window,
    cov_radius: i64,
) -> Result<Match> {
    branch_and_bound(grid, source, w, cov_radius, f64::NEG_INFINITY)?
        .ok_or_else(|| Error::invalid("window", "holds no candidate"))
}

/// [`match_branch_and_bound`]'s best candidate if its score is at least `min_score`, else
/// `None`. Every branch whose bound is below `min_score · N` is pruned from the start, so a
/// window that holds no match costs a small fraction of a full search (what a loop-closure
/// search over many candidates needs: most of them are not the place). The answer, when
/// there is one, is the full search's.
pub fn match_branch_and_bound_above(
    grid: &LikelihoodGrid,
    source: &[f64],
    w: &Window,
    cov_radius: i64,
    min_score: f64,
) -> Result<Option<Match>> {
    if !min_score.is_finite() {
        return Err(Error::invalid("min_score", "must be finite"));
    }
    let n = check_points(source, "source")?;
    // The objective is the sum over the points; leave a rounding margin so that a candidate
    // scoring exactly min_score is kept.
    let floor = min_score * n as f64 - 1e-9 * (1.0 + n as f64);
    branch_and_bound(grid, source, w, cov_radius, floor)
}

fn branch_and_bound(
    grid: &LikelihoodGrid,
    source: &[f64],
    w: &Window,
    cov_radius: i64,
    floor: f64,
) -> Result<Option<Match>> {
    let n = check_points(source, "source")?;
    check_window(w)?;
    if cov_radius < 0 {
        return Err(Error::invalid("covariance_radius", "must be >= 0"));
    }
    let seq = search_work(w, n) <= SEQUENTIAL_BNB_WORK;
    let span = 2 * w.nx.max(w.ny) + 1;
    let mut depth = 0usize;
    while (1i64 << depth) < span && depth < grid.levels() {
        depth += 1;
    }
    let slices = grid.slices(source, w, seq);
    let cost = Cost::new(w, grid.resolution);
    // Pool every level the search reads here, before the parallel sections: a level first
    // pooled inside a rayon task could re-enter its own OnceLock from a stolen task.
    let _ = grid.level(depth);
    let step = 1i64 << depth;
    // Root nodes: bounds in parallel (they dominate the work for shallow trees).
    let keys: Vec<[i64; 3]> = (-w.ntheta..=w.ntheta)
        .flat_map(|k| {
            let is: Vec<i64> = (-w.nx..=w.nx).step_by(step as usize).collect();
            let js: Vec<i64> = (-w.ny..=w.ny).step_by(step as usize).collect();
            is.into_iter()
                .flat_map(move |i| js.clone().into_iter().map(move |j| [k, i, j]))
        })
        .collect();
    // Four roots of one rotation at a time (a rotation's roots are consecutive in `keys`).
    let runs: Vec<&[[i64; 3]]> = keys
        .chunk_by(|a, b| a[0] == b[0])
        .flat_map(|run| run.chunks(4))
        .collect();
    let mut roots: Vec<Node> = runs
        .par_iter()
        .with_min_len(min_len(seq))
        .flat_map_iter(|run| {
            let slice = &slices[(run[0][0] + w.ntheta) as usize];
            let bounds = node_bounds(grid, slice, w, &cost, depth, run);
            run.iter().zip(bounds).map(|(&key, bound)| Node {
                bound,
                key,
                level: depth,
            })
        })
        .collect();
    let mut search = BnB {
        grid,
        slices: &slices,
        w,
        cost,
        best: (floor, [i64::MAX; 3]),
        evaluated: if depth == 0 { roots.len() as u64 } else { 0 },
        bounds: if depth == 0 { 0 } else { roots.len() as u64 },
    };
    search.explore(&mut roots);
    let best = search.best;
    if best.1 == [i64::MAX; 3] {
        return Ok(None);
    }
    let (evaluated, bounds) = (search.evaluated, search.bounds);
    // Covariance: a dense neighbourhood of the optimum.
    let [kb, ib, jb] = best.1;
    let ks: Vec<i64> =
        ((kb - cov_radius).max(-w.ntheta)..=(kb + cov_radius).min(w.ntheta)).collect();
    let moments = ks
        .par_iter()
        .with_min_len(min_len(seq))
        .map(|&k| {
            let slice = &slices[(k + w.ntheta) as usize];
            let mut m = Moments::new();
            for i in (ib - cov_radius).max(-w.nx)..=(ib + cov_radius).min(w.nx) {
                for j in (jb - cov_radius).max(-w.ny)..=(jb + cov_radius).min(w.ny) {
                    m.add(grid.sum(0, slice, i, j), [i as f64, j as f64, k as f64]);
                }
            }
            m
        })
        .collect::<Vec<_>>()
        .into_iter()
        .fold(Moments::new(), Moments::merge);
    Ok(Some(
        grid.finish(w, &slices, best, moments, evaluated, bounds),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn room() -> Vec<f64> {
        // An L-shaped room outline, 5 cm spacing, with a pillar: no symmetry.
        let mut pts = Vec::new();
        let mut seg = |a: [f64; 2], b: [f64; 2]| {
            let len = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
            let n = (len / 0.05).ceil() as usize;
            for s in 0..n {
                let t = s as f64 / n as f64;
                pts.push(a[0] + t * (b[0] - a[0]));
                pts.push(a[1] + t * (b[1] - a[1]));
            }
        };
        seg([-3.0, -2.0], [4.0, -2.0]);
        seg([4.0, -2.0], [4.0, 1.0]);
        seg([4.0, 1.0], [1.0, 1.0]);
        seg([1.0, 1.0], [1.0, 3.0]);
        seg([1.0, 3.0], [-3.0, 3.0]);
        seg([-3.0, 3.0], [-3.0, -2.0]);
        seg([-1.0, 0.0], [-0.6, 0.0]);
        seg([-0.6, 0.0], [-0.6, 0.4]);
        pts
    }

    fn transform(points: &[f64], pose: [f64; 3]) -> Vec<f64> {
        let (s, c) = pose[2].sin_cos();
        points
            .chunks_exact(2)
            .flat_map(|p| [c * p[0] - s * p[1] + pose[0], s * p[0] + c * p[1] + pose[1]])
            .collect()
    }

    fn inverse(pose: [f64; 3]) -> [f64; 3] {
        let (s, c) = pose[2].sin_cos();
        [
            -(c * pose[0] + s * pose[1]),
            s * pose[0] - c * pose[1],
            -pose[2],
        ]
    }

    #[test]
    fn distance_transform_is_exact() {
        let pts = [0.02, 0.02, 1.02, 0.52];
        let g = LikelihoodGrid::build(&pts, 0.1, 0.1, 0).unwrap();
        let (w, h) = g.shape();
        let o = g.origin();
        let cells: Vec<[f64; 2]> = pts
            .chunks_exact(2)
            .map(|p| [((p[0] - o[0]) / 0.1).floor(), ((p[1] - o[1]) / 0.1).floor()])
            .collect();
        for y in 0..h {
            for x in 0..w {
                let brute = cells
                    .iter()
                    .map(|c| (x as f64 - c[0]).powi(2) + (y as f64 - c[1]).powi(2))
                    .fold(f64::INFINITY, f64::min);
                // Exact within the likelihood's support (15 cells here), +∞ beyond.
                let expected = if brute <= 225.0 { brute } else { f64::INFINITY };
                assert_eq!(g.dist2()[y * w + x] as f64, expected, "cell {x},{y}");
            }
        }
    }

    #[test]
    fn the_reach_is_the_least_radius_past_which_the_likelihood_is_zero() {
        for s2 in [0.25, 1.0, 9.61, 1e6] {
            let g = Gaussian::new(s2, 1 << 16);
            let r = g.reach();
            let (inside, past) = (((r - 1) * (r - 1)) as f64, (r * r) as f64);
            assert!((1..=200).all(|k| g.at(past + k as f64) == 0.0), "s2 {s2}");
            assert!(
                (inside as i64 + 1..=past as i64).any(|d| g.at(d as f64) > 0.0),
                "s2 {s2}"
            );
        }
    }

    fn assert_same_grid(a: &LikelihoodGrid, b: &LikelihoodGrid, what: &str) {
        assert_eq!(a.origin(), b.origin(), "{what}: origin");
        assert_eq!(a.shape(), b.shape(), "{what}: shape");
        assert_eq!(a.offset, b.offset, "{what}: offset");
        assert_eq!(a.occupied, b.occupied, "{what}: occupied cells");
        assert_eq!(a.levels(), b.levels(), "{what}: levels");
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&a.dist2()), bits(&b.dist2()), "{what}: distance");
        assert_eq!(
            bits(&a.likelihood()),
            bits(&b.likelihood()),
            "{what}: likelihood"
        );
        // Off the lattice a canvas reads 0 and +∞, as off the canvas.
        for g in [a, b] {
            let [x0, y0, x1, y1] = g.view();
            let cw = g.canvas_size[0] as i64;
            for (i, (l, d)) in g.base.data.iter().zip(&g.dist2).enumerate() {
                let (x, y) = (i as i64 % cw, i as i64 / cw);
                if x < x0 || x >= x1 || y < y0 || y >= y1 {
                    assert!(
                        l.to_bits() == 0 && d.is_infinite(),
                        "{what}: canvas at {x},{y}"
                    );
                }
            }
        }
        // Every level cell whose window touches the lattice, and a margin around them.
        let (w, h) = (a.width as i64, a.height as i64);
        for lvl in 1..=a.levels() {
            let pad = (1i64 << lvl) + 2;
            let at = |g: &LikelihoodGrid, x: i64, y: i64| {
                let [dx, dy, _, _] = g.view();
                g.level(lvl).at(x + dx, y + dy).to_bits()
            };
            for y in -pad..h + pad {
                for x in -pad..w + pad {
                    assert_eq!(at(a, x, y), at(b, x, y), "{what}: level {lvl} at {x},{y}");
                }
            }
        }
    }

    #[test]
    fn an_updated_grid_is_the_grid_built_from_scratch() {
        // A sliding window of "keyframes" (the room seen from moving poses, with a sparse far
        // wall so that the stamping and the distance-transform builds both occur), each grid
        // updated from the previous one: every step equals a build of the same points, bit
        // for bit, and so does a search on it.
        let room = room();
        let far: Vec<f64> = (0..40)
            .flat_map(|k| [30.0 + 0.37 * k as f64, -5.0])
            .collect();
        let frames: Vec<Vec<f64>> = (0..12)
            .map(|k| {
                let pose = [0.21 * k as f64, -0.13 * k as f64, 0.05 * k as f64];
                let mut pts = transform(&room, pose);
                if k % 3 == 1 {
                    pts.extend_from_slice(&far);
                }
                pts.truncate(pts.len() - 2 * (k % 5)); // a few points fewer now and then
                pts
            })
            .collect();
        let window = 3;
        let mut grid: Option<LikelihoodGrid> = None;
        for end in 1..=frames.len() {
            let reference: Vec<f64> = frames[end.saturating_sub(window)..end].concat();
            let built = LikelihoodGrid::build(&reference, 0.05, 0.05, 5).unwrap();
            let next = match &grid {
                None => built.clone(),
                // Every other step in place, its levels pooled before (pooled again there).
                Some(g) if end % 2 == 0 => {
                    let mut g = g.clone();
                    let _ = g.level(g.levels());
                    g.update(&reference).unwrap();
                    g
                }
                Some(g) => g.updated(&reference).unwrap(),
            };
            assert_same_grid(&next, &built, &format!("window ending at {end}"));
            let w = Window {
                center: [0.2, -0.1, 0.03],
                nx: 6,
                ny: 6,
                ntheta: 5,
                angular_step: 0.01,
                penalty: None,
            };
            let scan = &frames[end - 1][..200];
            assert_eq!(
                match_branch_and_bound(&next, scan, &w, 3).unwrap(),
                match_branch_and_bound(&built, scan, &w, 3).unwrap()
            );
            grid = Some(next);
        }
        // A reference elsewhere entirely (no overlap of the lattices), and back.
        let g = grid.unwrap();
        let away = transform(&room, [100.0, 50.0, 1.0]);
        let moved = g.updated(&away).unwrap();
        assert_same_grid(
            &moved,
            &LikelihoodGrid::build(&away, 0.05, 0.05, 5).unwrap(),
            "away",
        );
        let back = moved.updated(&room).unwrap();
        assert_same_grid(
            &back,
            &LikelihoodGrid::build(&room, 0.05, 0.05, 5).unwrap(),
            "back",
        );
        // Bad input is refused as build refuses it, and leaves the grid as it was.
        assert!(g.updated(&[]).is_err());
        assert!(g.updated(&[0.0, f64::NAN]).is_err());
        let mut same = g.clone();
        assert!(same.update(&[1.0, f64::INFINITY]).is_err());
        assert_eq!(same.occupied, g.occupied);
        assert_eq!(same.likelihood(), g.likelihood());
    }

    #[test]
    fn an_update_repools_the_levels_the_grid_had_and_only_those() {
        // The grid with its first two of five levels pooled: an update pools those two again
        // where the base changed (equal to pooling the built grid's) and leaves the others to
        // be pooled on first use; on lattices that grow, shrink, shift and stay.
        let room = room();
        let poses = [
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0],  // the same points: nothing changes
            [0.02, 0.0, 0.0], // a sub-cell shift: many cells, same lattice or nearly
            [0.4, -0.3, 0.1], // moved: the lattice shifts
            [0.4, -0.3, 0.1],
            [-1.5, 2.0, -0.4], // farther
        ];
        let mut grid: Option<LikelihoodGrid> = None;
        let mut in_place = 0;
        for (k, pose) in poses.iter().enumerate() {
            let mut reference = transform(&room, *pose);
            if k == 4 {
                reference.truncate(reference.len() / 2); // half the room: the lattice shrinks
            }
            let built = LikelihoodGrid::build(&reference, 0.05, 0.05, 5).unwrap();
            let next = match grid {
                None => built.clone(),
                Some(mut g) => {
                    let _ = g.level(2);
                    let canvas = (g.canvas, g.canvas_size);
                    g.update(&reference).unwrap();
                    let kept: Vec<bool> = g.pooled.iter().map(|l| l.get().is_some()).collect();
                    // (A lattice that left the canvas lays a new one: pooled on first use.)
                    let expected = if (g.canvas, g.canvas_size) == canvas {
                        in_place += 1;
                        [true, true, false, false, false]
                    } else {
                        [false; 5]
                    };
                    assert_eq!(kept, expected, "step {k}");
                    g
                }
            };
            // (On a copy: comparing pools every level.)
            assert_same_grid(&next.clone(), &built, &format!("step {k}"));
            grid = Some(next);
        }
        assert!(in_place >= 3, "{in_place} updates kept their canvas");
    }

    #[test]
    fn stamping_and_the_distance_transform_give_the_same_grid() {
        // Scattered and clustered cells, some at the edges (discs clipped), a wide blur.
        let (width, height) = (61usize, 47usize);
        let mut occupied: Vec<usize> = (0..40)
            .map(|k| ((k * 104729) % height) * width + (k * 7919) % width)
            .chain([
                20 * width + 20,
                20 * width + 21,
                21 * width + 20,
                0,
                width * height - 1,
            ])
            .collect();
        occupied.sort_unstable();
        occupied.dedup();
        for sigma_cells in [1.0f64, 3.1] {
            let gauss = Gaussian::new(sigma_cells.powi(2), width * height);
            let reach = gauss.reach();
            let a = stamped(&occupied, width, height, reach, &gauss);
            let b = transformed(&occupied, width, height, reach, &gauss);
            assert_eq!(a.1, b.1);
            assert_eq!(a.0, b.0);
            // The cut drops no likelihood: every bit of the uncut transform's grid.
            let full = transformed(&occupied, width, height, 1 << 20, &gauss);
            assert_eq!(a.0, full.0);
            if sigma_cells == 1.0 {
                // e^−x underflows f32 past x ≈ 103.9: d² ≤ 207 cells².
                assert_eq!(reach, 15);
                assert!(a.1.iter().any(|d| d.is_infinite()));
            }
        }
    }

    #[test]
    fn pooled_levels_are_window_maxima_on_a_grid_narrower_than_the_stride() {
        // Two points: an ~11 × 12 cell grid, levels up to a 64-cell window (stride 32 > width).
        let g = LikelihoodGrid::build(&[0.0, 0.0, 0.15, 0.05], 0.1, 0.1, 6).unwrap();
        let base = g.level(0);
        for h in 1..=g.levels() {
            let (lvl, w) = (g.level(h), 1i64 << h);
            for y in -(w + 1)..base.height + 2 {
                for x in -(w + 1)..base.width + 2 {
                    let mut m = 0.0f32;
                    for dy in 0..w {
                        for dx in 0..w {
                            m = m.max(base.at(x + dx, y + dy));
                        }
                    }
                    assert_eq!(lvl.at(x, y), m, "level {h} at {x},{y}");
                }
            }
        }
    }

    #[test]
    fn pooling_on_the_calling_thread_equals_the_parallel_pooling() {
        // The room's grid and a two-point one (levels narrower than their stride).
        for (points, res) in [(room(), 0.1), (vec![0.0, 0.0, 0.15, 0.05], 0.1)] {
            let g = LikelihoodGrid::build(&points, res, res, 0).unwrap();
            let (w, h) = (g.width as i64, g.height as i64);
            let mut prev = Level {
                shift: 0,
                width: w,
                height: h,
                data: g.base.data.clone(),
            };
            for level in 1..=6 {
                let half = 1i64 << (level - 1);
                let seq = pool(&prev, half, w, h, true);
                let par = pool(&prev, half, w, h, false);
                assert_eq!(
                    (seq.shift, seq.width, seq.height),
                    (par.shift, par.width, par.height)
                );
                assert_eq!(seq.data, par.data, "level {level}");
                prev = seq;
            }
        }
    }

    #[test]
    fn pooled_levels_are_window_maxima() {
        let g = LikelihoodGrid::build(&room(), 0.1, 0.1, 3).unwrap();
        let base = g.level(0);
        for h in 1..=g.levels() {
            let lvl = g.level(h);
            let w = 1i64 << h;
            for y in (-(w - 1)..base.height).step_by(7) {
                for x in (-(w - 1)..base.width).step_by(5) {
                    let mut m = 0.0f32;
                    for dy in 0..w {
                        for dx in 0..w {
                            m = m.max(base.at(x + dx, y + dy));
                        }
                    }
                    assert_eq!(lvl.at(x, y), m, "level {h} at {x},{y}");
                }
            }
        }
    }

    #[test]
    fn recovers_a_known_offset_and_bnb_agrees() {
        let reference = room();
        let grid = LikelihoodGrid::build(&reference, 0.05, 0.05, 6).unwrap();
        let truth = [0.23, -0.17, 0.1];
        // source = T_ref_src^{-1} applied to the reference: matching must find `truth`.
        let source = transform(&reference, inverse(truth));
        let w = Window {
            center: [0.0, 0.0, 0.0],
            nx: 8,
            ny: 8,
            ntheta: 10,
            angular_step: 0.02,
            penalty: None,
        };
        let ex = match_exhaustive(&grid, &source, &w).unwrap();
        assert!((ex.pose[0] - truth[0]).abs() <= 0.05, "{:?}", ex.pose);
        assert!((ex.pose[1] - truth[1]).abs() <= 0.05, "{:?}", ex.pose);
        assert!((ex.pose[2] - truth[2]).abs() <= 0.02, "{:?}", ex.pose);
        assert_eq!(ex.evaluated, 17 * 17 * 21);
        assert!(ex.fitness > 0.95);
        let bb = match_branch_and_bound(&grid, &source, &w, 3).unwrap();
        assert_eq!(bb.index, ex.index);
        assert_eq!(bb.sum, ex.sum);
        assert!(bb.evaluated < ex.evaluated);
        // With a floor at or below the best score: the same answer, with less work.
        let above = match_branch_and_bound_above(&grid, &source, &w, 3, bb.score)
            .unwrap()
            .unwrap();
        // Everything but the work counts (fewer: 4 leaves and 181 bounds against 184 / 339).
        let same = |m: &Match| (m.pose, m.index, m.sum, m.score, m.covariance, m.mean);
        assert_eq!(same(&above), same(&bb));
        assert!(above.evaluated < bb.evaluated && above.bounds < bb.bounds);
        let low = match_branch_and_bound_above(&grid, &source, &w, 3, 0.5 * bb.score)
            .unwrap()
            .unwrap();
        assert_eq!((low.index, low.sum), (bb.index, bb.sum));
        assert!(low.evaluated + low.bounds <= bb.evaluated + bb.bounds);
        // Above it: nothing, found with a fraction of the bounds.
        let none = match_branch_and_bound_above(&grid, &source, &w, 3, bb.score + 1e-6).unwrap();
        assert!(none.is_none());
        // A window far from the truth holds nothing as good: pruned early.
        let off = Window {
            center: [1.5, 1.0, 0.6],
            ..w
        };
        let full = match_branch_and_bound(&grid, &source, &off, 3).unwrap();
        assert!(full.score < 0.6 * bb.score, "{}", full.score);
        let pruned = match_branch_and_bound_above(&grid, &source, &off, 3, 0.8 * bb.score);
        assert!(pruned.unwrap().is_none());
        assert!(match_branch_and_bound_above(&grid, &source, &w, 3, f64::NAN).is_err());
    }

    #[test]
    fn points_no_window_puts_on_the_grid_count_but_add_nothing() {
        // An 80 m scan against a small submap: its far points read 0 wherever the window puts
        // them. They are left out of the sums (the same bits) but divide the score.
        let reference = room();
        let grid = LikelihoodGrid::build(&reference, 0.05, 0.05, 4).unwrap();
        let near = transform(&reference, inverse([0.1, -0.05, 0.04]));
        let far: Vec<f64> = (0..300)
            .flat_map(|k| [60.0 + 0.05 * k as f64, -40.0 + 0.1 * k as f64])
            .collect();
        let both: Vec<f64> = near.iter().chain(&far).copied().collect();
        let w = Window {
            center: [0.0, 0.0, 0.0],
            nx: 6,
            ny: 6,
            ntheta: 4,
            angular_step: 0.02,
            penalty: None,
        };
        let (n_near, n_all) = ((near.len() / 2) as f64, (both.len() / 2) as f64);
        for m in [
            match_exhaustive(&grid, &near, &w).unwrap(),
            match_branch_and_bound(&grid, &near, &w, 2).unwrap(),
        ] {
            let ex = match_exhaustive(&grid, &both, &w).unwrap();
            let bb = match_branch_and_bound(&grid, &both, &w, 2).unwrap();
            for b in [&ex, &bb] {
                assert_eq!((b.index, b.sum.to_bits()), (m.index, m.sum.to_bits()));
                assert_eq!(b.score, m.sum / n_all);
                assert!((b.fitness - m.fitness * n_near / n_all).abs() < 1e-12);
            }
        }
        // Nothing on the grid: a sum of +0.0 (zeros added), as before any point was left out.
        let off = match_branch_and_bound(&grid, &far, &w, 2).unwrap();
        assert_eq!(off.sum.to_bits(), 0.0f64.to_bits());
        assert_eq!(off.score, 0.0);
    }

    #[test]
    fn ties_resolve_to_the_same_candidate() {
        // One source point and a long straight wall: every candidate that puts the point on
        // the wall scores exactly the same, so only the tie rule decides.
        let wall: Vec<f64> = (0..200)
            .flat_map(|k| [(k as f64 + 0.5) * 0.05 - 5.0, 1.01])
            .collect();
        let grid = LikelihoodGrid::build(&wall, 0.05, 0.05, 5).unwrap();
        for (center, ntheta) in [([0.3, 0.95, 0.0], 0), ([-0.2, 1.02, 0.0], 2)] {
            let w = Window {
                center,
                nx: 20,
                ny: 6,
                ntheta,
                angular_step: 0.01,
                penalty: None,
            };
            let ex = match_exhaustive(&grid, &[0.0, 0.0], &w).unwrap();
            let bb = match_branch_and_bound(&grid, &[0.0, 0.0], &w, 2).unwrap();
            assert_eq!(ex.index, bb.index);
            assert_eq!(ex.sum, bb.sum);
            assert_eq!(ex.index[1], -20, "the smallest key wins: {:?}", ex.index);
        }
    }

    #[test]
    fn hostile_input_is_an_error() {
        assert!(LikelihoodGrid::build(&[], 0.1, 0.1, 0).is_err());
        assert!(LikelihoodGrid::build(&[0.0, f64::NAN], 0.1, 0.1, 0).is_err());
        assert!(LikelihoodGrid::build(&[0.0, 0.0], 0.0, 0.1, 0).is_err());
        assert!(LikelihoodGrid::build(&[0.0, 0.0], 0.1, -1.0, 0).is_err());
        assert!(LikelihoodGrid::build(&[0.0, 0.0, 1e6, 1e6], 0.01, 0.01, 0).is_err());
        assert!(LikelihoodGrid::build(&[0.0, 0.0], 0.1, 0.1, 40).is_err());
        let g = LikelihoodGrid::build(&[0.0, 0.0], 0.1, 0.1, 0).unwrap();
        let w = Window {
            center: [0.0; 3],
            nx: 1,
            ny: 1,
            ntheta: 1,
            angular_step: 0.0,
            penalty: None,
        };
        assert!(match_exhaustive(&g, &[0.0, 0.0], &w).is_err());
        let w = Window {
            angular_step: 0.1,
            ..w
        };
        assert!(match_exhaustive(&g, &[0.0], &w).is_err());
        assert!(match_exhaustive(&g, &[0.0, 0.0], &w).is_ok());
    }

    #[test]
    fn motion_cost_picks_the_nearest_of_equal_candidates_and_bnb_agrees() {
        // A long wall: every shift along it scores the same, so without a cost the tie rule
        // takes the smallest key (the window's end); with one, the candidate nearest the
        // centre wins — and branch and bound, its bounds lowered by the cost, still returns
        // the exhaustive answer, over anisotropic and correlated costs.
        let wall: Vec<f64> = (0..400)
            .flat_map(|k| [(k as f64 + 0.5) * 0.05 - 10.0, 1.01])
            .collect();
        let grid = LikelihoodGrid::build(&wall, 0.05, 0.05, 6).unwrap();
        let source: Vec<f64> = (0..20).flat_map(|k| [k as f64 * 0.1 - 1.0, 1.0]).collect();
        let costs = [
            [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            [0.5, 0.0, 0.0, 0.0, 400.0, 0.0, 0.0, 0.0, 100.0],
            [2.0, 1.5, 0.3, 1.5, 2.0, 0.0, 0.3, 0.0, 50.0],
            [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 10.0],
        ];
        for (n, p) in costs.iter().enumerate() {
            for center in [[0.3, 0.95, 0.0], [-0.2, 1.07, 0.02]] {
                let w = Window {
                    center,
                    nx: 20,
                    ny: 6,
                    ntheta: 3,
                    angular_step: 0.01,
                    penalty: Some(*p),
                };
                let ex = match_exhaustive(&grid, &source, &w).unwrap();
                let bb = match_branch_and_bound(&grid, &source, &w, 2).unwrap();
                assert_eq!(ex.index, bb.index, "cost {n}");
                assert_eq!(ex.sum, bb.sum, "cost {n}");
                if n < 3 {
                    assert_eq!(ex.index[1], 0, "cost {n}: the centre along the wall");
                } else {
                    assert_eq!(ex.index[1], -20, "cost {n}: no cost along x, the tie rule");
                }
            }
        }
        let bad = Window {
            center: [0.0; 3],
            nx: 1,
            ny: 1,
            ntheta: 1,
            angular_step: 0.1,
            penalty: Some([1.0, 2.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]),
        };
        assert!(match_exhaustive(&grid, &source, &bad).is_err());
    }
}
