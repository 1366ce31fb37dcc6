//! Where the loop finds correspondences ([`NeighborSearch`]: a k-d tree, or odometry's voxel
//! map), and the target and source as the loop sees them.

use crate::knn::KdTree;

/// Where the loop finds correspondences: a k-d tree over a fixed cloud, or a voxel map that
/// odometry updates in place. A point's id indexes `points()` (`id * dim`) and the target's
/// normals and covariances.
pub trait NeighborSearch: Sync {
    fn dim(&self) -> usize;
    /// Size of the id space (attribute arrays hold this many entries).
    fn id_count(&self) -> usize;
    fn points(&self) -> &[f64];
    /// Nearest point within the squared gate `max_sq`, as `(id, squared distance)`.
    fn nearest_within(&self, q: &[f64], max_sq: f64) -> Option<(usize, f64)>;
    /// Whether any point lies within the squared gate `max_sq` (inclusive): the answer of
    /// `nearest_within(q, max_sq).is_some()`, where the index can stop at the first one.
    fn any_within(&self, q: &[f64], max_sq: f64) -> bool {
        self.nearest_within(q, max_sq).is_some()
    }
    /// [`Self::nearest_within`] with a likely answer `hint` when there is one (the previous
    /// iteration's correspondence); the same result, found faster where the index can use it.
    fn nearest_within_hinted(
        &self,
        q: &[f64],
        max_sq: f64,
        hint: Option<usize>,
    ) -> Option<(usize, f64)> {
        let _ = hint;
        self.nearest_within(q, max_sq)
    }
    /// [`Self::nearest_within_hinted`] and a certificate for the answer: a lower bound on the
    /// squared distance from `q` to every other point (to every point when there is no
    /// answer), searched out to `slack` beyond the answer (see [`Cert`]). `0`, no certificate,
    /// unless the index can give one.
    fn nearest_certified(
        &self,
        q: &[f64],
        max_sq: f64,
        hint: Option<usize>,
        slack: f64,
    ) -> (Option<(usize, f64)>, f64) {
        let _ = slack;
        (self.nearest_within_hinted(q, max_sq, hint), 0.0)
    }
    /// True when [`Self::nearest_certified`] gives certificates (else none are kept).
    fn certifies(&self) -> bool {
        false
    }
    /// True when the attributes were validated on the way in (no per-call finiteness scan).
    fn attributes_validated(&self) -> bool {
        false
    }
    /// Ids sharing one row of the target's covariances (row `id / group`): a voxel map keeps
    /// one covariance per voxel instead of a copy per point.
    fn covariance_group(&self) -> usize {
        1
    }
}

impl NeighborSearch for KdTree {
    fn dim(&self) -> usize {
        KdTree::dim(self)
    }
    fn id_count(&self) -> usize {
        self.len()
    }
    fn points(&self) -> &[f64] {
        KdTree::points(self)
    }
    fn nearest_within(&self, q: &[f64], max_sq: f64) -> Option<(usize, f64)> {
        KdTree::nearest_within(self, q, max_sq)
    }
    fn any_within(&self, q: &[f64], max_sq: f64) -> bool {
        KdTree::any_within(self, q, max_sq)
    }
    fn nearest_within_hinted(
        &self,
        q: &[f64],
        max_sq: f64,
        hint: Option<usize>,
    ) -> Option<(usize, f64)> {
        match hint {
            Some(h) => KdTree::nearest_within_hinted(self, q, max_sq, h),
            None => KdTree::nearest_within(self, q, max_sq),
        }
    }
    fn nearest_certified(
        &self,
        q: &[f64],
        max_sq: f64,
        hint: Option<usize>,
        slack: f64,
    ) -> (Option<(usize, f64)>, f64) {
        KdTree::nearest_certified(self, q, max_sq, hint, slack)
    }
    fn certifies(&self) -> bool {
        true
    }
}

/// The target: its neighbour search and, as the method needs, unit normals (`N * dim`; a zero
/// normal marks a point without one, which then never corresponds) or covariances
/// (`N * dim * dim`), indexed by point id.
pub struct Target<'a> {
    pub search: &'a dyn NeighborSearch,
    pub normals: Option<&'a [f64]>,
    pub covariances: Option<&'a [f64]>,
}

/// The source points (`N * dim`, source frame) and, for GICP, their covariances.
pub struct Source<'a> {
    pub points: &'a [f64],
    pub covariances: Option<&'a [f64]>,
}
