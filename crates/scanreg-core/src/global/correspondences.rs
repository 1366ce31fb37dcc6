//! Correspondences by mutual nearest neighbour in descriptor space.
//!
//! 33-D FPFH descriptors defeat a k-d tree (in that many dimensions it visits most leaves), so
//! the search is a blocked brute force over `f32` rows: source rows in parallel blocks, each
//! block scanning every target row once and keeping both its row minima and its column minima;
//! the column minima of the blocks are merged afterwards. Ties go to the lowest index, and a
//! minimum with that tie rule does not depend on the order of merging, so the result does not
//! depend on the thread count.

use rayon::prelude::*;

/// Source rows per parallel block: large enough that a block's target scan amortises its
/// column-minimum buffer, small enough for ~64 blocks on a typical keypoint count.
const BLOCK: usize = 64;

/// Squared distance with eight independent partial sums: a single running sum is a serial
/// dependency chain the compiler may not reorder (float addition), eight lanes vectorise
/// (the descriptor search took 3× longer with the plain sum).
#[inline]
fn sq_dist(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0.0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for l in 0..8 {
            let d = x[l] - y[l];
            acc[l] += d * d;
        }
    }
    let mut tail = 0.0;
    for (x, y) in ra.iter().zip(rb) {
        tail += (x - y) * (x - y);
    }
    acc.iter().sum::<f32>() + tail
}

/// `(distance, index)` ordered by distance then index.
/// One block's result: each of its rows with its nearest target `(distance, index)`, and the
/// nearest of its rows to every target row.
type BlockMinima = (Vec<(u32, (f32, u32))>, Vec<(f32, u32)>);

#[inline]
fn better(a: (f32, u32), b: (f32, u32)) -> bool {
    a.0 < b.0 || (a.0 == b.0 && a.1 < b.1)
}

/// Pairs `(i, j)` where target row `j` is the nearest to source row `i` and source row `i` is
/// the nearest to target row `j` (Euclidean, rows of `dim` values). Rows whose `*_valid` flag
/// is false take no part. Sorted by `i`.
pub fn mutual_nearest(
    source: &[f32],
    source_valid: &[bool],
    target: &[f32],
    target_valid: &[bool],
    dim: usize,
) -> Vec<(u32, u32)> {
    let ns = source.len() / dim;
    let nt = target.len() / dim;
    let tgt_ids: Vec<u32> = (0..nt as u32)
        .filter(|&j| target_valid[j as usize])
        .collect();
    if tgt_ids.is_empty() {
        return Vec::new();
    }
    let none = (f32::INFINITY, u32::MAX);
    let blocks: Vec<BlockMinima> = (0..ns.div_ceil(BLOCK))
        .into_par_iter()
        .map(|b| {
            let rows: Vec<u32> = (b * BLOCK..((b + 1) * BLOCK).min(ns))
                .filter(|&i| source_valid[i])
                .map(|i| i as u32)
                .collect();
            let mut row_min = vec![none; rows.len()];
            let mut col_min = vec![none; nt];
            for &j in &tgt_ids {
                let t = &target[j as usize * dim..(j as usize + 1) * dim];
                for (r, &i) in rows.iter().enumerate() {
                    let s = &source[i as usize * dim..(i as usize + 1) * dim];
                    let d = sq_dist(s, t);
                    if better((d, j), row_min[r]) {
                        row_min[r] = (d, j);
                    }
                    if better((d, i), col_min[j as usize]) {
                        col_min[j as usize] = (d, i);
                    }
                }
            }
            (rows.into_iter().zip(row_min).collect(), col_min)
        })
        .collect();
    let mut col = vec![none; nt];
    for (_, cm) in &blocks {
        for (c, &m) in col.iter_mut().zip(cm) {
            if better(m, *c) {
                *c = m;
            }
        }
    }
    let mut out = Vec::new();
    for (rows, _) in blocks {
        for (i, (_, j)) in rows {
            if j != u32::MAX && col[j as usize].1 == i {
                out.push((i, j));
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_the_mutual_pairs_only() {
        // Source 2's nearest is target 1, whose nearest is source 0: not mutual.
        let s = [0.0f32, 0.0, 10.0, 0.0, 0.9, 0.0];
        let t = [10.2f32, 0.0, 0.1, 0.0];
        let m = mutual_nearest(&s, &[true; 3], &t, &[true; 2], 2);
        assert_eq!(m, vec![(0, 1), (1, 0)]);
        let m = mutual_nearest(&s, &[false, true, true], &t, &[true; 2], 2);
        assert_eq!(m, vec![(1, 0), (2, 1)]);
    }
}
