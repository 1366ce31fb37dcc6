//! Correspondences by mutual nearest neighbour in descriptor space.
//!
//! An exact k-d tree over the `f32` rows of each side (as Open3D matches FPFH with FLANN's
//! single k-d tree): FPFH histograms fill a thin part of their 33 dimensions, so a query
//! visits a few leaves, not all (on the benchmark's 4000-5500 keypoints per cloud the two
//! tree searches took a quarter to a sixth of the blocked brute force they replace, which is
//! kept as the tests' reference). Each source row's nearest target row and each target row's
//! nearest source row are found independently (in parallel) and the mutual pairs kept. Ties
//! go to the lowest index: a subtree is skipped only when its bound is strictly worse than the
//! best so far, so the answer is the brute force's, whatever the thread count.

use rayon::prelude::*;

/// Rows per leaf of the descriptor tree.
const LEAF: usize = 16;

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

#[inline]
fn better(a: (f32, u32), b: (f32, u32)) -> bool {
    a.0 < b.0 || (a.0 == b.0 && a.1 < b.1)
}

enum Node {
    Leaf {
        start: usize,
        end: usize,
    },
    Split {
        axis: usize,
        value: f32,
        left: usize,
        right: usize,
    },
}

/// An exact nearest-neighbour index over rows of `dim` `f32` values.
struct DescriptorTree<'a> {
    rows: &'a [f32],
    dim: usize,
    /// Row indices, grouped by leaf.
    order: Vec<u32>,
    nodes: Vec<Node>,
}

impl<'a> DescriptorTree<'a> {
    fn build(rows: &'a [f32], dim: usize, ids: Vec<u32>) -> Self {
        let mut tree = DescriptorTree {
            rows,
            dim,
            order: ids,
            nodes: Vec::new(),
        };
        let n = tree.order.len();
        tree.split(0, n);
        tree
    }

    fn value(&self, row: u32, axis: usize) -> f32 {
        self.rows[row as usize * self.dim + axis]
    }

    /// Node over `order[start..end]`: split at the median of the axis of largest spread (rows
    /// equal to the median may fall on either side; the search bound holds for both).
    fn split(&mut self, start: usize, end: usize) -> usize {
        let id = self.nodes.len();
        if end - start <= LEAF {
            self.nodes.push(Node::Leaf { start, end });
            return id;
        }
        let mut lo = vec![f32::INFINITY; self.dim];
        let mut hi = vec![f32::NEG_INFINITY; self.dim];
        for &r in &self.order[start..end] {
            let row = &self.rows[r as usize * self.dim..(r as usize + 1) * self.dim];
            for (c, &v) in row.iter().enumerate() {
                lo[c] = lo[c].min(v);
                hi[c] = hi[c].max(v);
            }
        }
        let axis = (0..self.dim)
            .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])).then(b.cmp(&a)))
            .unwrap_or(0);
        if hi[axis] <= lo[axis] {
            // Identical rows: nothing to split on.
            self.nodes.push(Node::Leaf { start, end });
            return id;
        }
        let mid = start + (end - start) / 2;
        let (rows, dim) = (self.rows, self.dim);
        let key = |r: &u32| (rows[*r as usize * dim + axis], *r);
        self.order[start..end].select_nth_unstable_by(mid - start, |a, b| {
            key(a).0.total_cmp(&key(b).0).then(a.cmp(b))
        });
        let value = self.value(self.order[mid], axis);
        self.nodes.push(Node::Leaf { start, end }); // placeholder, replaced below
        let left = self.split(start, mid);
        let right = self.split(mid, end);
        self.nodes[id] = Node::Split {
            axis,
            value,
            left,
            right,
        };
        id
    }

    /// Nearest row to `q` as `(squared distance, row)`.
    fn nearest(&self, q: &[f32], offsets: &mut [f32]) -> (f32, u32) {
        self.better_than(q, (f32::INFINITY, u32::MAX), offsets)
    }

    /// The nearest row to `q` if it beats `best` (`(squared distance, row)`, ties to the lower
    /// row), else `best`: with a tight `best` most cells are pruned from the start.
    fn better_than(&self, q: &[f32], mut best: (f32, u32), offsets: &mut [f32]) -> (f32, u32) {
        offsets.iter_mut().for_each(|o| *o = 0.0);
        self.search(0, q, 0.0, offsets, &mut best);
        best
    }

    /// Search below `node`, whose cell lies at least `bound` (squared) from `q`: the sum of
    /// the squared `offsets` of `q` from the cell along each split axis crossed so far (Arya &
    /// Mount's incremental distance; the single-axis bound visited far more cells in 33-D).
    fn search(
        &self,
        node: usize,
        q: &[f32],
        bound: f32,
        offsets: &mut [f32],
        best: &mut (f32, u32),
    ) {
        match self.nodes[node] {
            Node::Leaf { start, end } => {
                for &r in &self.order[start..end] {
                    let row = &self.rows[r as usize * self.dim..(r as usize + 1) * self.dim];
                    let d = sq_dist(q, row);
                    if better((d, r), *best) {
                        *best = (d, r);
                    }
                }
            }
            Node::Split {
                axis,
                value,
                left,
                right,
            } => {
                let diff = q[axis] - value;
                let (near, far) = if diff < 0.0 {
                    (left, right)
                } else {
                    (right, left)
                };
                self.search(near, q, bound, offsets, best);
                let old = offsets[axis];
                let far_bound = bound - old * old + diff * diff;
                // `<=`: a row at exactly the best distance with a lower index may lie there;
                // the slack covers the rounding of the running bound against the rows' own
                // f32 sums, so a near-tie is never pruned on a rounding error.
                if far_bound <= best.0 * (1.0 + 1e-4) {
                    offsets[axis] = diff;
                    self.search(far, q, far_bound, offsets, best);
                    offsets[axis] = old;
                }
            }
        }
    }
}

/// Nearest row of `tree` for every row of `queries` flagged valid, as `(squared distance,
/// row)` (`row` `u32::MAX` otherwise).
fn nearest_all(
    tree: &DescriptorTree<'_>,
    queries: &[f32],
    valid: &[bool],
    dim: usize,
) -> Vec<(f32, u32)> {
    let n = queries.len() / dim;
    (0..n)
        .into_par_iter()
        .with_min_len(64)
        .map_init(
            || vec![0.0f32; dim],
            |offsets, i| {
                if valid[i] {
                    tree.nearest(&queries[i * dim..(i + 1) * dim], offsets)
                } else {
                    (f32::INFINITY, u32::MAX)
                }
            },
        )
        .collect()
}

/// Pairs `(i, j)` where target row `j` is the nearest to source row `i` and source row `i` is
/// the nearest to target row `j` (Euclidean, rows of `dim` values). Rows whose `*_valid` flag
/// is false take no part. Sorted by `i`.
///
/// Each source row's nearest target row first; then only a target row that is some source
/// row's nearest can be in a pair, and only with the nearest `i` of those (ties to the lower
/// index), so its reverse search asks whether any source row beats that `i`: started from
/// `i`'s distance it prunes most of the tree at once (the reverse direction had cost as much
/// as the forward one). The distance is symmetric bit for bit, so the answer is the two
/// independent searches'.
pub fn mutual_nearest(
    source: &[f32],
    source_valid: &[bool],
    target: &[f32],
    target_valid: &[bool],
    dim: usize,
) -> Vec<(u32, u32)> {
    let ids = |valid: &[bool]| -> Vec<u32> {
        (0..valid.len() as u32)
            .filter(|&j| valid[j as usize])
            .collect()
    };
    let (src_ids, tgt_ids) = (ids(source_valid), ids(target_valid));
    if src_ids.is_empty() || tgt_ids.is_empty() {
        return Vec::new();
    }
    let (to_target, source_tree) = rayon::join(
        || {
            let tree = DescriptorTree::build(target, dim, tgt_ids);
            nearest_all(&tree, source, source_valid, dim)
        },
        || DescriptorTree::build(source, dim, src_ids),
    );
    // The best source row of each target row that is someone's nearest.
    let mut claim = vec![(f32::INFINITY, u32::MAX); target.len() / dim];
    for (i, &(d, j)) in to_target.iter().enumerate() {
        if j != u32::MAX && better((d, i as u32), claim[j as usize]) {
            claim[j as usize] = (d, i as u32);
        }
    }
    let claimed: Vec<(u32, (f32, u32))> = claim
        .iter()
        .enumerate()
        .filter(|(_, c)| c.1 != u32::MAX)
        .map(|(j, &c)| (j as u32, c))
        .collect();
    let mut pairs: Vec<(u32, u32)> = claimed
        .par_iter()
        .with_min_len(64)
        .map_init(
            || vec![0.0f32; dim],
            |offsets, &(j, c)| {
                let q = &target[j as usize * dim..(j as usize + 1) * dim];
                (source_tree.better_than(q, c, offsets).1 == c.1).then_some((c.1, j))
            },
        )
        .flatten()
        .collect();
    pairs.sort_unstable();
    pairs
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reference: every pair's distance, ties to the lowest index.
    fn brute_force(s: &[f32], t: &[f32], dim: usize) -> Vec<(u32, u32)> {
        let (ns, nt) = (s.len() / dim, t.len() / dim);
        let nearest = |a: &[f32], b: &[f32], nb: usize| -> u32 {
            let mut best = (f32::INFINITY, u32::MAX);
            for j in 0..nb {
                let d = sq_dist(a, &b[j * dim..(j + 1) * dim]);
                if better((d, j as u32), best) {
                    best = (d, j as u32);
                }
            }
            best.1
        };
        (0..ns)
            .filter_map(|i| {
                let j = nearest(&s[i * dim..(i + 1) * dim], t, nt);
                let back = nearest(&t[j as usize * dim..(j as usize + 1) * dim], s, ns);
                (back == i as u32).then_some((i as u32, j))
            })
            .collect()
    }

    #[test]
    fn the_tree_finds_the_brute_force_pairs() {
        let mut st = 5u64;
        let mut rnd = || {
            st = st
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((st >> 40) % 7) as f32 // coarse values: many ties and equal coordinates
        };
        let dim = 33;
        let s: Vec<f32> = (0..700 * dim).map(|_| rnd()).collect();
        let mut t: Vec<f32> = (0..500 * dim).map(|_| rnd()).collect();
        t[..40 * dim].copy_from_slice(&s[100 * dim..140 * dim]); // exact matches
        t[40 * dim..41 * dim].copy_from_slice(&s[..dim]);
        t[41 * dim..42 * dim].copy_from_slice(&s[..dim]); // a duplicate row: the tie rule
        let got = mutual_nearest(&s, &vec![true; 700], &t, &vec![true; 500], dim);
        let want = brute_force(&s, &t, dim);
        assert!(want.len() >= 40, "{}", want.len());
        assert_eq!(got, want);
    }

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
