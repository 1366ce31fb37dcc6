//! Nearest-neighbour indices over 2D/3D points.
//!
//! * [`KdTree`]: an immutable k-d tree of our own (median split on the widest axis, points
//!   reordered into contiguous 16-point leaf buckets, iterative traversal with a fixed stack,
//!   no allocation per query), built once and queried many times. Exact queries: nearest
//!   neighbour within a gate (the gate prunes from the start; optionally with a certificate, a
//!   lower bound on every other point's distance, which lets ICP skip the next search), k
//!   nearest (a sorted array of at most `k`, in the caller's buffer), all within a radius.
//!
//! Distances are **squared** Euclidean throughout. Ties (equal distances) are broken by the
//! lower point index everywhere (nearest, k-NN, radius), so results
//! are reproducible; batch queries run in parallel with rayon, one result per query, in input
//! order, so they do not depend on the thread count.

use crate::error::{Error, Result};
use crate::points::check_points;
use crate::reduce::MIN_PAR_ITEMS;
use rayon::prelude::*;

/// Points per leaf bucket (at most; a leaf is split while it holds more).
const LEAF_SIZE: usize = 16;
/// Traversal stack depth: the tree is balanced (median splits), so its depth is
/// `ceil(log2(N / LEAF_SIZE)) + 1 <= 33` for `N < 2^32`; each level pushes at most one node.
/// No larger: the stacks are zeroed on every query.
const STACK: usize = 34;
const LEAF: u32 = u32::MAX;
/// Nodes of at least this many points build their two halves in parallel (below it a join
/// costs more than the half it would move to another thread).
const PAR_BUILD_MIN: usize = 8192;
/// Lower bounds are shrunk by this before pruning, so that their rounding (they are updated
/// incrementally) can never prune a cell holding a point at the bound: queries stay exact.
const SHRINK: f64 = 1.0 - 1e-12;

/// One node: a leaf holds points `lo..hi` of the reordered arrays; an inner node splits at
/// `split` on axis `axis` (left child: coordinate `<= split`, right child: `>= split`).
#[derive(Clone, Copy)]
struct Node {
    axis: u32,
    lo: u32,
    hi: u32,
    right: u32,
    split: f64,
}

/// The tree proper for a fixed dimension: points reordered into contiguous leaf buckets,
/// `ids[j]` the original index of `pts[j]`. Node 0 is the root; an inner node's left child
/// is the next node (depth-first layout).
struct Inner<const D: usize> {
    nodes: Vec<Node>,
    pts: Vec<[f64; D]>,
    ids: Vec<u32>,
    /// Every leaf's bucket and cell (the box its ancestors' splits bound; `±inf` at the
    /// edges), for searches that start from a known point ([`Self::nearest_hinted`]).
    leaves: Vec<Leaf<D>>,
    /// The leaf holding each original point index.
    leaf_of: Vec<u32>,
    /// Where each original point index sits in `pts`.
    slot_of: Vec<u32>,
}

struct Leaf<const D: usize> {
    lo: u32,
    hi: u32,
    /// 2D: the leaf's points are sorted along this axis (the widest of their box), so a scan
    /// from a known point outward stops once the gap along it alone exceeds the best.
    axis: u32,
    cell_lo: [f64; D],
    cell_hi: [f64; D],
}

#[inline(always)]
fn sq_dist<const D: usize>(a: &[f64; D], b: &[f64; D]) -> f64 {
    let mut d = 0.0;
    for c in 0..D {
        let e = a[c] - b[c];
        d += e * e;
    }
    d
}

/// `(d, i) < (bd, bi)` lexicographically: the tie rule (lower index wins at equal distance).
#[inline(always)]
fn before(d: f64, i: u32, bd: f64, bi: u32) -> bool {
    d < bd || (d == bd && i < bi)
}

/// Offer `(id, d)` to `out[start..]`, the best (at most `k`, `k >= 1`) found so far, sorted by
/// (squared distance, index): kept when fewer than `k` are held or it comes before the last,
/// which it then displaces. Every exact k-NN search shares it (the tree's, the 2D sweep of
/// `normal_noise`), so they hold the same set in the same order.
#[inline(always)]
pub(crate) fn offer_k(out: &mut Vec<(u32, f64)>, start: usize, k: usize, id: u32, d: f64) {
    if out.len() - start == k {
        let (wi, wd) = out[out.len() - 1];
        if !before(d, id, wd, wi) {
            return;
        }
        out.pop();
    }
    // Insertion into the sorted tail (element-wise shift: k is small).
    out.push((id, d));
    let buf = &mut out[start..];
    let mut pos = buf.len() - 1;
    while pos > 0 {
        let prev = buf[pos - 1];
        if !before(d, id, prev.1, prev.0) {
            break;
        }
        buf[pos] = prev;
        pos -= 1;
    }
    buf[pos] = (id, d);
}

/// `a.min(b)` for a running minimum `a` (never NaN) and a squared distance `b` (never −0):
/// the same value, by one comparison instead of `f64::min`'s NaN handling, on a per-point
/// path of the nearest-neighbour search.
#[inline(always)]
fn min_of(a: f64, b: f64) -> f64 {
    if b < a {
        b
    } else {
        a
    }
}

/// Make `(p, id)` the best `(distance², index)` if it comes before it.
#[inline(always)]
fn consider<const D: usize>(p: &[f64; D], id: u32, q: &[f64; D], best: &mut (f64, u32)) {
    let d = sq_dist(p, q);
    if d <= best.0 && before(d, id, best.0, best.1) {
        *best = (d, id);
    }
}

/// [`consider`], also keeping `second`: the nearest point seen other than the best (a best
/// displaced by a nearer point becomes a candidate for it; the gate sentinel does not).
#[inline(always)]
fn consider_second<const D: usize>(
    p: &[f64; D],
    id: u32,
    q: &[f64; D],
    best: &mut (f64, u32),
    second: &mut f64,
) {
    let d = sq_dist(p, q);
    if d <= best.0 && before(d, id, best.0, best.1) {
        if best.1 != u32::MAX {
            *second = min_of(*second, best.0);
        }
        *best = (d, id);
    } else if id != best.1 {
        *second = min_of(*second, d);
    }
}

/// [`consider`] the points of a sorted leaf in order away from the query, until `gap(p)` (the
/// offset along the sort axis, growing along the iteration) alone puts them beyond the best.
#[inline(always)]
fn scan_outward<'a, const D: usize>(
    points: impl Iterator<Item = (&'a [f64; D], &'a u32)>,
    q: &[f64; D],
    gap: impl Fn(&[f64; D]) -> f64,
    best: &mut (f64, u32),
) {
    for (p, &id) in points {
        let g = gap(p);
        if g > 0.0 && g * g > best.0 {
            break;
        }
        consider(p, id, q, best);
    }
}

/// Per-axis minimum and maximum of `items`' points.
fn bounds<const D: usize>(items: &[([f64; D], u32)]) -> ([f64; D], [f64; D]) {
    let mut lo = [f64::INFINITY; D];
    let mut hi = [f64::NEG_INFINITY; D];
    // Plain comparisons rather than f64::min/max, whose NaN handling did not vectorise (the
    // build took 18-23 % longer on a 25k-point cloud). The same box: a NaN is skipped either
    // way (and refused before a build), and only a zero's sign can differ, which no width
    // sees.
    for (p, _) in items {
        for c in 0..D {
            if p[c] < lo[c] {
                lo[c] = p[c];
            }
            if p[c] > hi[c] {
                hi[c] = p[c];
            }
        }
    }
    (lo, hi)
}

/// The axis along which `items` spread widest (the first of equals; 0 when empty).
fn widest_axis<const D: usize>(items: &[([f64; D], u32)]) -> usize {
    let (lo, hi) = bounds(items);
    widest_of(&lo, &hi)
}

/// The widest axis of the box `lo..hi` (the first of equals).
fn widest_of<const D: usize>(lo: &[f64; D], hi: &[f64; D]) -> usize {
    let mut axis = 0;
    for c in 1..D {
        if hi[c] - lo[c] > hi[axis] - lo[axis] {
            axis = c;
        }
    }
    axis
}

impl<const D: usize> Inner<D> {
    /// `par_min`: nodes of at least this many points build their halves in parallel (the
    /// layout does not depend on it; tests compare against `usize::MAX`, all sequential).
    fn build(points: &[f64], par_min: usize) -> Self {
        let mut items: Vec<([f64; D], u32)> = points
            .chunks_exact(D)
            .enumerate()
            .map(|(i, p)| (arr::<D>(p), i as u32))
            .collect();
        let n = items.len();
        let mut nodes = Vec::with_capacity(2 * n.div_ceil(LEAF_SIZE) + 1);
        let mut leaves = Vec::with_capacity(2 * n.div_ceil(LEAF_SIZE) + 1);
        let cell = ([f64::NEG_INFINITY; D], [f64::INFINITY; D]);
        Self::build_rec(&mut items, 0, cell, &mut nodes, &mut leaves, par_min);
        if D == 2 {
            // Only 2D searches scan a leaf outward from the hint (see `nearest_hinted`).
            for leaf in &mut leaves {
                let bucket = &mut items[leaf.lo as usize..leaf.hi as usize];
                let axis = widest_axis(bucket);
                bucket.sort_unstable_by(|a, b| a.0[axis].total_cmp(&b.0[axis]).then(a.1.cmp(&b.1)));
                leaf.axis = axis as u32;
            }
        }
        let (pts, ids): (Vec<[f64; D]>, Vec<u32>) = items.into_iter().unzip();
        let mut leaf_of = vec![0u32; n];
        let mut slot_of = vec![0u32; n];
        for (l, leaf) in leaves.iter().enumerate() {
            for slot in leaf.lo..leaf.hi {
                let id = ids[slot as usize] as usize;
                leaf_of[id] = l as u32;
                slot_of[id] = slot;
            }
        }
        Inner {
            nodes,
            pts,
            ids,
            leaves,
            leaf_of,
            slot_of,
        }
    }

    /// Median split on the widest axis of the bounding box; returns the node's index. `cell`
    /// is the region the ancestors' splits leave to this node.
    fn build_rec(
        items: &mut [([f64; D], u32)],
        offset: usize,
        cell: ([f64; D], [f64; D]),
        nodes: &mut Vec<Node>,
        leaves: &mut Vec<Leaf<D>>,
        par_min: usize,
    ) -> usize {
        let me = nodes.len();
        let n = items.len();
        let leaf = Node {
            axis: LEAF,
            lo: offset as u32,
            hi: (offset + n) as u32,
            right: 0,
            split: 0.0,
        };
        nodes.push(leaf);
        let as_leaf = |leaves: &mut Vec<Leaf<D>>| {
            leaves.push(Leaf {
                lo: offset as u32,
                hi: (offset + n) as u32,
                axis: 0, // set once the leaf is sorted
                cell_lo: cell.0,
                cell_hi: cell.1,
            })
        };
        if n <= LEAF_SIZE {
            as_leaf(leaves);
            return me;
        }
        let (lo, hi) = bounds(items); // once per node: it gives the axis and the spread
        let axis = widest_of(&lo, &hi);
        if hi[axis] - lo[axis] <= 0.0 {
            as_leaf(leaves);
            return me; // all points identical: one (large) leaf
        }
        let mid = n / 2;
        items.select_nth_unstable_by(mid, |a, b| a.0[axis].total_cmp(&b.0[axis]));
        let split = items[mid].0[axis];
        let (l, r) = items.split_at_mut(mid);
        let (mut left_cell, mut right_cell) = (cell, cell);
        left_cell.1[axis] = split;
        right_cell.0[axis] = split;
        let right = if n >= par_min {
            // The halves are independent: build each into its own arrays on the pool, then
            // lay them out exactly as the sequential recursion would (left subtree right after
            // this node, then the right one; node links shifted by where each lands).
            let sub = |items: &mut [([f64; D], u32)], offset: usize, cell| {
                let (mut ns, mut ls) = (Vec::new(), Vec::new());
                Self::build_rec(items, offset, cell, &mut ns, &mut ls, par_min);
                (ns, ls)
            };
            let ((nl, ll), (nr, lr)) = rayon::join(
                || sub(l, offset, left_cell),
                || sub(r, offset + mid, right_cell),
            );
            let right = me + 1 + nl.len();
            for (sub_nodes, base) in [(nl, me + 1), (nr, right)] {
                nodes.extend(sub_nodes.into_iter().map(|mut nd| {
                    if nd.axis != LEAF {
                        nd.right += base as u32;
                    }
                    nd
                }));
            }
            leaves.extend(ll);
            leaves.extend(lr);
            right
        } else {
            Self::build_rec(l, offset, left_cell, nodes, leaves, par_min);
            Self::build_rec(r, offset + mid, right_cell, nodes, leaves, par_min)
        };
        nodes[me] = Node {
            axis: axis as u32,
            lo: offset as u32,
            hi: (offset + n) as u32,
            right: right as u32,
            split,
        };
        me
    }

    /// Visit the tree depth-first, nearer child first, skipping any node whose lower-bound
    /// squared distance exceeds `bound()` (strictly, so ties at the bound are still seen).
    /// `leaf(lo, hi)` scans one bucket.
    ///
    /// The lower bound is the squared distance from `q` to the node's cell, kept per axis and
    /// updated incrementally (Arya & Mount 1993): descending to the far side of a split changes
    /// only that axis' offset, from the parent's to `|q − split|`. It prunes more than the
    /// single-axis bound `max(lb, diff²)` but costs more per node: it pays for k-NN and radius
    /// queries (many leaves), not for the nearest neighbour ([`Self::traverse_near`]).
    #[inline(always)]
    fn traverse(
        &self,
        q: &[f64; D],
        mut bound: impl FnMut() -> f64,
        mut leaf: impl FnMut(usize, usize),
    ) {
        // Plain arrays, not (u32, f64, [f64; D]) tuples: zeroed by memset (see traverse_near).
        let mut stack_node = [0u32; STACK];
        let mut stack_lb = [0.0f64; STACK];
        let mut stack_off = [[0.0f64; D]; STACK];
        let mut top = 1usize;
        while top > 0 {
            top -= 1;
            let (mut node, lb, off) = (stack_node[top], stack_lb[top], stack_off[top]);
            if lb * SHRINK > bound() {
                continue;
            }
            loop {
                let nd = &self.nodes[node as usize];
                if nd.axis == LEAF {
                    leaf(nd.lo as usize, nd.hi as usize);
                    break;
                }
                let axis = nd.axis as usize;
                let diff = q[axis] - nd.split;
                let (near, far) = if diff < 0.0 {
                    (node + 1, nd.right)
                } else {
                    (nd.right, node + 1)
                };
                let old = off[axis];
                let far_lb = lb - old * old + diff * diff;
                if far_lb * SHRINK <= bound() {
                    stack_node[top] = far;
                    stack_lb[top] = far_lb;
                    stack_off[top] = off;
                    stack_off[top][axis] = diff.abs();
                    top += 1;
                }
                node = near; // the near child keeps the parent's offsets
            }
        }
    }

    /// [`Self::traverse`] with the single-axis bound `max(lb, diff²)` and a 16-byte stack entry,
    /// for the nearest neighbour (few leaves: the cheap bound wins). No shrink needed: floating
    /// subtraction and squaring are monotonic, so a point beyond the split is never computed
    /// closer than `diff²`.
    ///
    /// `pruned(lb)` is told the lower bound of every cell it skips (the certified search keeps
    /// their minimum; the plain one passes a no-op).
    #[inline(always)]
    fn traverse_near(
        &self,
        q: &[f64; D],
        mut bound: impl FnMut() -> f64,
        mut leaf: impl FnMut(usize, usize),
        mut pruned: impl FnMut(f64),
    ) {
        // Two arrays of plain numbers rather than one of (u32, f64) pairs: their zeroing, paid
        // on every call, compiles to a short memset instead of 128 separate stores (it was
        // about a quarter of a 2D scan's nearest-neighbour time).
        let mut stack_node = [0u32; STACK];
        let mut stack_lb = [0.0f64; STACK];
        let mut top = 1usize;
        while top > 0 {
            top -= 1;
            let (mut node, lb) = (stack_node[top], stack_lb[top]);
            if lb > bound() {
                pruned(lb);
                continue;
            }
            loop {
                let nd = &self.nodes[node as usize];
                if nd.axis == LEAF {
                    leaf(nd.lo as usize, nd.hi as usize);
                    break;
                }
                let diff = q[nd.axis as usize] - nd.split;
                let (near, far) = if diff < 0.0 {
                    (node + 1, nd.right)
                } else {
                    (nd.right, node + 1)
                };
                let dd = diff * diff;
                let far_lb = if dd > lb { dd } else { lb };
                if far_lb <= bound() {
                    stack_node[top] = far;
                    stack_lb[top] = far_lb;
                    top += 1;
                } else {
                    pruned(far_lb);
                }
                node = near;
            }
        }
    }

    #[inline]
    fn nearest(&self, q: &[f64; D], max_sq: f64) -> Option<(usize, f64)> {
        self.nearest_from(q, max_sq, u32::MAX, usize::MAX)
    }

    /// [`Self::nearest`] starting from a known candidate `(bd, bi)` (`bi = u32::MAX`: none, `bd`
    /// the gate): every cell farther than `bd` is pruned from the start. The result is the
    /// same as a fresh search whenever the true nearest is within `bd`, which it is when `bd`
    /// is the distance to a real point `bi` (ties still go to the lowest index: a cell at
    /// exactly `bd` is visited). The leaf starting at `skip` (`usize::MAX`: none) has been
    /// scanned already and is not scanned again.
    #[inline]
    fn nearest_from(&self, q: &[f64; D], bd: f64, bi: u32, skip: usize) -> Option<(usize, f64)> {
        let mut best = (bd, bi);
        let pts = &self.pts;
        let ids = &self.ids;
        let bound = std::cell::Cell::new(bd);
        self.traverse_near(
            q,
            || bound.get(),
            |lo, hi| {
                if lo == skip {
                    return;
                }
                for (p, &id) in pts[lo..hi].iter().zip(&ids[lo..hi]) {
                    consider(p, id, q, &mut best);
                }
                bound.set(best.0);
            },
            |_| {},
        );
        let (bd, bi) = best;
        (bi != u32::MAX).then_some((bi as usize, bd))
    }

    /// Whether any point lies within `max_sq` of `q`: the search stops at the first one (a
    /// negative bound then prunes every cell left), instead of looking on for the nearest.
    #[inline]
    fn any_within(&self, q: &[f64; D], max_sq: f64) -> bool {
        let pts = &self.pts;
        let bound = std::cell::Cell::new(max_sq);
        self.traverse_near(
            q,
            || bound.get(),
            |lo, hi| {
                if pts[lo..hi].iter().any(|p| sq_dist(p, q) <= max_sq) {
                    bound.set(-1.0);
                }
            },
            |_| {},
        );
        bound.get() < 0.0
    }

    /// [`Self::nearest`] (the same answer, ties included) and a certificate for it: a lower
    /// bound `clear` on the squared distance from `q` to every point but the answer (to every
    /// point when there is none within `max_sq`). Cells are searched out to `slack` beyond the
    /// best so far, which makes `clear >= (√best + slack)²` unless a point lies nearer: a query
    /// that has since moved by less than `slack / 2` can then be answered without a search
    /// (see `icp::Cert`). `hint`: a known point and its squared distance `<= max_sq`.
    fn nearest_certified(
        &self,
        q: &[f64; D],
        max_sq: f64,
        hint: Option<(u32, f64)>,
        slack: f64,
    ) -> (Option<(usize, f64)>, f64) {
        let grow = |b: f64| {
            let r = b.sqrt() + slack;
            r * r
        };
        let mut best = hint.map_or((max_sq, u32::MAX), |(h, dh)| (dh, h));
        let mut second = f64::INFINITY; // nearest scanned point other than `best`
        let mut skip = usize::MAX;
        if let Some((h, _)) = hint {
            // The hint's leaf first; when q lies in its cell, everything outside the cell is at
            // least the cell margin away, which may settle the search at once.
            let leaf = &self.leaves[self.leaf_of[h as usize] as usize];
            let mut margin = f64::INFINITY;
            for ((&x, &lo), &hi) in q.iter().zip(&leaf.cell_lo).zip(&leaf.cell_hi) {
                let (below, above) = (x - lo, hi - x);
                if !(below >= 0.0 && above >= 0.0) {
                    margin = -1.0; // q is outside the hint's cell
                    break;
                }
                margin = margin.min(below.min(above));
            }
            if margin >= 0.0 {
                let (lo, hi) = (leaf.lo as usize, leaf.hi as usize);
                for (p, &id) in self.pts[lo..hi].iter().zip(&self.ids[lo..hi]) {
                    consider_second(p, id, q, &mut best, &mut second);
                }
                skip = lo;
                let m2 = margin * margin;
                if grow(best.0) < m2 {
                    return (Some((best.1 as usize, best.0)), second.min(m2));
                }
            }
        }
        let bound = std::cell::Cell::new(grow(best.0));
        let mut floor = f64::INFINITY; // the nearest skipped cell
        let (pts, ids) = (&self.pts, &self.ids);
        self.traverse_near(
            q,
            || bound.get(),
            |lo, hi| {
                if lo == skip {
                    return;
                }
                for (p, &id) in pts[lo..hi].iter().zip(&ids[lo..hi]) {
                    consider_second(p, id, q, &mut best, &mut second);
                }
                bound.set(grow(best.0));
            },
            |lb| floor = floor.min(lb),
        );
        let (bd, bi) = best;
        (
            (bi != u32::MAX).then_some((bi as usize, bd)),
            second.min(floor),
        )
    }

    /// [`Self::nearest`] from a known point `hint` at squared distance `dh <= max_sq`: if `q`
    /// lies in the hint's leaf cell and that leaf's best point is nearer than the cell's
    /// boundary, no other leaf can hold a point as near (every other point lies outside the
    /// cell or on its boundary), and the tree is not traversed at all; else a traversal bounded
    /// by that best. Exactly [`Self::nearest`]'s answer (float subtraction and squaring are
    /// monotonic, so an outside point is never computed nearer than the boundary).
    #[inline]
    fn nearest_hinted(&self, q: &[f64; D], hint: u32, dh: f64) -> Option<(usize, f64)> {
        let leaf = &self.leaves[self.leaf_of[hint as usize] as usize];
        let mut margin = f64::INFINITY;
        for c in 0..D {
            let below = q[c] - leaf.cell_lo[c];
            let above = leaf.cell_hi[c] - q[c];
            if !(below >= 0.0 && above >= 0.0) {
                return self.nearest_from(q, dh, hint, usize::MAX); // q is outside the hint's cell
            }
            margin = margin.min(below.min(above));
        }
        let (lo, hi) = (leaf.lo as usize, leaf.hi as usize);
        let (pts, ids) = (&self.pts[lo..hi], &self.ids[lo..hi]);
        let mut best = (dh, hint);
        if D == 3 {
            // A 3D leaf is a patch of surface: one sorted axis prunes little (measured
            // 0.96-1.06x), the plain scan stays.
            for (p, &id) in pts.iter().zip(ids) {
                consider(p, id, q, &mut best);
            }
        } else {
            // Outward from the hint along the leaf's sorted axis: past a point whose gap along
            // that axis alone exceeds the best, every further one is farther still (the
            // squared distance is that gap squared plus non-negative terms, in floats too).
            // 2D scans' leaves are stretches of wall: the scan stops after a few points.
            let (a, at) = (
                leaf.axis as usize,
                self.slot_of[hint as usize] as usize - lo,
            );
            let up = pts[at + 1..].iter().zip(&ids[at + 1..]);
            scan_outward(up, q, |p| p[a] - q[a], &mut best);
            let down = pts[..at].iter().zip(&ids[..at]).rev();
            scan_outward(down, q, |p| q[a] - p[a], &mut best);
        }
        let (bd, bi) = best;
        if bd < margin * margin {
            return Some((bi as usize, bd));
        }
        self.nearest_from(q, bd, bi, lo)
    }

    /// `out[start..]` is kept sorted by (distance, index), at most `k` long.
    ///
    /// (Tried and measured slower or no better at k = 20 on a LiDAR scan: a binary max-heap,
    /// and an unsorted buffer of `2k` compacted by selection; most candidates are accepted
    /// here and the sorted insertion's short shifts are cheap.)
    #[inline]
    fn knn(&self, q: &[f64; D], k: usize, max_sq: f64, out: &mut Vec<(u32, f64)>) {
        let start = out.len();
        let pts = &self.pts;
        let ids = &self.ids;
        let worst = std::cell::Cell::new(max_sq);
        // The k-th neighbour's distance once k are held (the bound for pruning).
        let mut wd = max_sq;
        self.traverse(
            q,
            || worst.get(),
            |lo, hi| {
                for (p, &id) in pts[lo..hi].iter().zip(&ids[lo..hi]) {
                    let d = sq_dist(p, q);
                    if d > wd {
                        continue; // beyond the gate, or (once full) behind the k-th
                    }
                    offer_k(out, start, k, id, d);
                    if out.len() - start == k {
                        wd = out[out.len() - 1].1;
                        worst.set(wd);
                    }
                }
            },
        );
    }

    #[inline]
    fn radius(&self, q: &[f64; D], sq_radius: f64, out: &mut Vec<(u32, f64)>) {
        let start = out.len();
        self.radius_unsorted(q, sq_radius, out);
        canonical(&mut out[start..]);
    }

    #[inline]
    fn radius_unsorted(&self, q: &[f64; D], sq_radius: f64, out: &mut Vec<(u32, f64)>) {
        let pts = &self.pts;
        let ids = &self.ids;
        self.traverse(
            q,
            || sq_radius,
            |lo, hi| {
                for j in lo..hi {
                    let d = sq_dist(&pts[j], q);
                    if d <= sq_radius {
                        out.push((ids[j], d));
                    }
                }
            },
        );
    }
}

enum Tree {
    D2(Inner<2>),
    D3(Inner<3>),
}

/// An immutable k-d tree over `N` points of dimension 2 or 3 (it keeps its own copy).
pub struct KdTree {
    dim: usize,
    points: Vec<f64>,
    tree: Tree,
}

/// Result of a batch nearest-neighbour query: `index[i] = -1` and `squared_distance[i] = inf`
/// where query `i` has no point within the gate.
#[derive(Debug, Clone, PartialEq)]
pub struct NearestBatch {
    pub index: Vec<i64>,
    pub squared_distance: Vec<f64>,
}

/// Result of a batch radius query in compressed-row form: the neighbours of query `i` are
/// `index[offsets[i]..offsets[i+1]]`, sorted by (distance, index).
#[derive(Debug, Clone, PartialEq)]
pub struct RadiusBatch {
    pub offsets: Vec<i64>,
    pub index: Vec<i64>,
    pub squared_distance: Vec<f64>,
}

#[inline(always)]
fn arr<const D: usize>(q: &[f64]) -> [f64; D] {
    let mut a = [0.0; D];
    a.copy_from_slice(&q[..D]);
    a
}

/// The canonical order of neighbours: by (squared distance, index), independent of tree layout.
pub fn canonical_order(a: &(u32, f64), b: &(u32, f64)) -> std::cmp::Ordering {
    a.1.total_cmp(&b.1).then(a.0.cmp(&b.0))
}

/// Sort neighbour lists by (distance, index): a canonical order independent of tree layout.
fn canonical(v: &mut [(u32, f64)]) {
    v.sort_unstable_by(canonical_order);
}

macro_rules! with_tree {
    ($self:expr, $t:ident, $d:ident => $body:expr) => {
        match &$self.tree {
            Tree::D2($t) => {
                const $d: usize = 2;
                $body
            }
            Tree::D3($t) => {
                const $d: usize = 3;
                $body
            }
        }
    };
}

/// Check a query gate (a distance, not squared): `>= 0`, may be `inf`, not NaN.
pub fn check_max_distance(arg: &'static str, max_distance: f64) -> Result<f64> {
    if max_distance.is_nan() || max_distance < 0.0 {
        return Err(Error::invalid(
            arg,
            format!("must be >= 0 (inf for no limit), got {max_distance}"),
        ));
    }
    Ok(max_distance * max_distance)
}

impl KdTree {
    /// Build the tree. `points` is `N * dim` row-major.
    pub fn build(points: &[f64], dim: usize) -> Result<Self> {
        let n = check_points("points", points, dim)?;
        if n == 0 {
            return Err(Error::invalid(
                "points",
                "is empty; a neighbour index needs at least one point",
            ));
        }
        if n >= u32::MAX as usize {
            return Err(Error::invalid("points", "more than 2^32 - 2 points"));
        }
        let tree = if dim == 2 {
            Tree::D2(Inner::<2>::build(points, PAR_BUILD_MIN))
        } else {
            Tree::D3(Inner::<3>::build(points, PAR_BUILD_MIN))
        };
        Ok(KdTree {
            dim,
            points: points.to_vec(),
            tree,
        })
    }

    pub fn dim(&self) -> usize {
        self.dim
    }

    pub fn len(&self) -> usize {
        self.points.len() / self.dim
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The indexed points, `N * dim` row-major.
    pub fn points(&self) -> &[f64] {
        &self.points
    }

    /// The point indices in the tree's leaf order (a permutation of `0..N`): consecutive
    /// entries are spatially close, so batch work over the indexed points itself (normals,
    /// covariances) runs in this order for cache locality.
    pub fn leaf_order(&self) -> &[u32] {
        match &self.tree {
            Tree::D2(t) => &t.ids,
            Tree::D3(t) => &t.ids,
        }
    }

    /// Point `i` as a slice of `dim` coordinates.
    pub fn point(&self, i: usize) -> &[f64] {
        &self.points[i * self.dim..(i + 1) * self.dim]
    }

    /// The nearest point to `q` (`dim` coordinates) and its squared distance, if that distance
    /// is `<= max_sq`. With equal distances the lowest index is returned.
    #[inline]
    pub fn nearest_within(&self, q: &[f64], max_sq: f64) -> Option<(usize, f64)> {
        with_tree!(self, t, D => t.nearest(&arr::<D>(q), max_sq))
    }

    /// Whether some point lies within `max_sq` (squared, inclusive) of `q`: the same answer
    /// as `nearest_within(q, max_sq).is_some()`, stopping at the first point found.
    #[inline]
    pub fn any_within(&self, q: &[f64], max_sq: f64) -> bool {
        !max_sq.is_nan() && with_tree!(self, t, D => t.any_within(&arr::<D>(q), max_sq))
    }

    /// [`Self::nearest_within`] given a likely answer `hint` (a point index, e.g. the previous
    /// ICP iteration's correspondence): the search starts with the bound set by the hint, so
    /// it prunes most of the tree at once. Exactly the same result as `nearest_within`.
    #[inline]
    pub fn nearest_within_hinted(
        &self,
        q: &[f64],
        max_sq: f64,
        hint: usize,
    ) -> Option<(usize, f64)> {
        let d = self.dim;
        let Some(h) = hint
            .checked_mul(d)
            .and_then(|start| self.points.get(start..start + d))
        else {
            return self.nearest_within(q, max_sq);
        };
        let dh: f64 = h.iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum();
        if dh.is_nan() || dh > max_sq {
            return self.nearest_within(q, max_sq);
        }
        with_tree!(self, t, D => t.nearest_hinted(&arr::<D>(q), hint as u32, dh))
    }

    /// [`Self::nearest_within_hinted`] with a certificate: also a lower bound on the squared
    /// distance from `q` to every point but the answer (every point when there is none), the
    /// search reaching `slack` beyond the answer (see `Inner::nearest_certified`).
    #[inline]
    pub fn nearest_certified(
        &self,
        q: &[f64],
        max_sq: f64,
        hint: Option<usize>,
        slack: f64,
    ) -> (Option<(usize, f64)>, f64) {
        let d = self.dim;
        let hint = hint.and_then(|h| {
            let p = self.points.get(h.checked_mul(d)?..h * d + d)?;
            let dh: f64 = p.iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum();
            (dh <= max_sq).then_some((h as u32, dh))
        });
        with_tree!(self, t, D => t.nearest_certified(&arr::<D>(q), max_sq, hint, slack))
    }

    /// The `k` nearest points to `q` (fewer if `max_sq` is finite), appended to `out` sorted
    /// by (squared distance, index). `k >= 1`.
    pub fn knn_into(&self, q: &[f64], k: usize, max_sq: f64, out: &mut Vec<(u32, f64)>) {
        if k == 0 {
            return;
        }
        out.reserve(k + 1);
        with_tree!(self, t, D => t.knn(&arr::<D>(q), k, max_sq, out));
    }

    /// Every point within `sq_radius` (squared, inclusive) of `q`, appended to `out` sorted by
    /// (squared distance, index).
    pub fn radius_into(&self, q: &[f64], sq_radius: f64, out: &mut Vec<(u32, f64)>) {
        with_tree!(self, t, D => t.radius(&arr::<D>(q), sq_radius, out));
    }

    /// [`KdTree::radius_into`] in the tree's own order (deterministic for a given tree, not
    /// sorted): for a caller that needs only some of them in order ([`canonical_order`]).
    pub fn radius_unsorted_into(&self, q: &[f64], sq_radius: f64, out: &mut Vec<(u32, f64)>) {
        with_tree!(self, t, D => t.radius_unsorted(&arr::<D>(q), sq_radius, out));
    }

    fn check_queries(&self, queries: &[f64]) -> Result<usize> {
        check_points("query_points", queries, self.dim)
    }

    /// Nearest neighbour of every query point within `max_distance` (not squared; `inf` for
    /// no limit).
    pub fn nearest_batch(&self, queries: &[f64], max_distance: f64) -> Result<NearestBatch> {
        self.check_queries(queries)?;
        let max_sq = check_max_distance("max_distance", max_distance)?;
        let res: Vec<(i64, f64)> = queries
            .par_chunks_exact(self.dim)
            .with_min_len(MIN_PAR_ITEMS)
            .map(|q| match self.nearest_within(q, max_sq) {
                Some((i, d)) => (i as i64, d),
                None => (-1, f64::INFINITY),
            })
            .collect();
        let (index, squared_distance) = res.into_iter().unzip();
        Ok(NearestBatch {
            index,
            squared_distance,
        })
    }

    /// The `k` nearest neighbours of every query point: `M * k` indices and squared distances,
    /// row `i` sorted by (distance, index). `1 <= k <= N`.
    pub fn knn_batch(&self, queries: &[f64], k: usize) -> Result<(Vec<i64>, Vec<f64>)> {
        self.check_queries(queries)?;
        check_k("k", k, self.len())?;
        let rows: Vec<Vec<(u32, f64)>> = queries
            .par_chunks_exact(self.dim)
            .with_min_len(MIN_PAR_ITEMS)
            .map(|q| {
                let mut v = Vec::with_capacity(k);
                self.knn_into(q, k, f64::INFINITY, &mut v);
                v
            })
            .collect();
        let mut index = Vec::with_capacity(rows.len() * k);
        let mut dist = Vec::with_capacity(rows.len() * k);
        for row in rows {
            for (i, d) in row {
                index.push(i as i64);
                dist.push(d);
            }
        }
        Ok((index, dist))
    }

    /// All neighbours within `radius` (not squared, inclusive) of every query point.
    pub fn radius_batch(&self, queries: &[f64], radius: f64) -> Result<RadiusBatch> {
        self.check_queries(queries)?;
        if !radius.is_finite() || radius < 0.0 {
            return Err(Error::invalid(
                "radius",
                format!("must be finite and >= 0, got {radius}"),
            ));
        }
        let sq = radius * radius;
        let rows: Vec<Vec<(u32, f64)>> = queries
            .par_chunks_exact(self.dim)
            .with_min_len(MIN_PAR_ITEMS)
            .map(|q| {
                let mut v = Vec::new();
                self.radius_into(q, sq, &mut v);
                v
            })
            .collect();
        let total: usize = rows.iter().map(Vec::len).sum();
        let mut out = RadiusBatch {
            offsets: Vec::with_capacity(rows.len() + 1),
            index: Vec::with_capacity(total),
            squared_distance: Vec::with_capacity(total),
        };
        out.offsets.push(0);
        for row in rows {
            for (i, d) in row {
                out.index.push(i as i64);
                out.squared_distance.push(d);
            }
            out.offsets.push(out.index.len() as i64);
        }
        Ok(out)
    }
}

/// `1 <= k <= n`.
pub fn check_k(arg: &'static str, k: usize, n: usize) -> Result<()> {
    if k < 1 {
        return Err(Error::invalid(arg, format!("must be >= 1, got {k}")));
    }
    if k > n {
        return Err(Error::invalid(
            arg,
            format!("is {k} but there are only {n} points"),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests;
