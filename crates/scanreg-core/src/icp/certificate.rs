//! Search certificates: what a source point's nearest-neighbour search proved, so that the next
//! iteration can skip the search when the point has barely moved.

use super::evaluate::NONE;
use crate::points::vec_at;
use nalgebra::SVector;

/// What a source point's last search proved ([`NeighborSearch::nearest_certified`]): from the
/// anchor `a` (where the point was), every target point but the answer `id` (every point, when
/// there was none) lies at least `clear` away. Queried again from `tp`, `δ = |tp − a|`: by the
/// triangle inequality every other point is at least `clear − δ` away, so when
/// `|tp − q_id| < clear − δ` the nearest is still `id` (when there is none and the gate is below
/// `clear − δ`, still none) and the search is skipped. Near convergence the points move by
/// millimetres between iterations, and most searches are. The answer is the search's exactly
/// (the same point, the distance computed the same way); `CERT_MARGIN` absorbs the rounding.
///
/// Compact (16 bytes in 3D): `id` is the correspondence list's entry, and the anchor is kept
/// in `f32` as an offset from the answer (`≤` the gate, so micrometre-exact at any map scale),
/// `clear` shrunk by that rounding and rounded down.
#[derive(Clone, Copy)]
pub(super) struct Cert<const D: usize> {
    offset: [f32; D],
    clear: f32,
}

/// Relative margin on both sides of a certificate's test (rounding is ~1e-16 relative).
const CERT_MARGIN: f64 = 1e-9;
/// The furthest a certified search reaches past its answer, as a fraction of the gate: beyond
/// it the wider search costs more than the skipped ones save (measured on the Intel, KITTI and
/// outdoor pairs: 0.02-0.1 equally good, 0.2 worse).
pub(super) const CERT_SLACK_MAX: f64 = 0.05;

impl<const D: usize> Cert<D> {
    /// The anchor: the answer's point (the origin when none) plus the stored offset.
    #[inline]
    fn anchor(offset: &[f32; D], id: u32, pts: &[f64]) -> SVector<f64, D> {
        let mut a = SVector::<f64, D>::from_fn(|c, _| f64::from(offset[c]));
        if id != NONE {
            a += vec_at::<D>(pts, id as usize);
        }
        a
    }

    /// The certificate of a search from `tp` that found `id` (`NONE`: none) with bound `clear`.
    pub(super) fn new(tp: &SVector<f64, D>, id: u32, clear: f64, pts: &[f64]) -> Self {
        let base = if id == NONE {
            SVector::<f64, D>::zeros()
        } else {
            vec_at::<D>(pts, id as usize)
        };
        let offset: [f32; D] = std::array::from_fn(|c| (tp[c] - base[c]) as f32);
        // Stated from the rounded anchor: shrink the bound by the rounding, then round it down
        // (f32's relative rounding is 6e-8).
        let moved = (tp - Self::anchor(&offset, id, pts)).norm();
        let c = (clear - moved * (1.0 + CERT_MARGIN)) * (1.0 - 1e-6);
        Cert {
            offset,
            clear: if c > 0.0 {
                c.min(f64::from(f32::MAX)) as f32
            } else {
                0.0
            },
        }
    }

    /// From `tp`, the nearest point within the gate if this certificate (for answer `id`)
    /// settles it (`Ok(None)`: settled, none); `Err(δ)`, the move since the search, if not.
    #[inline]
    pub(super) fn answer(
        &self,
        tp: &SVector<f64, D>,
        id: u32,
        pts: &[f64],
        max_sq: f64,
    ) -> std::result::Result<Option<(usize, f64)>, f64> {
        let delta = (tp - Self::anchor(&self.offset, id, pts)).norm();
        let room = f64::from(self.clear) * (1.0 - CERT_MARGIN) - delta * (1.0 + CERT_MARGIN);
        if room.is_nan() || room <= 0.0 {
            return Err(delta);
        }
        if id == NONE {
            return if max_sq.sqrt() * (1.0 + CERT_MARGIN) < room {
                Ok(None)
            } else {
                Err(delta)
            };
        }
        let j = id as usize;
        // As the k-d tree computes it (coordinate order, point minus query), so the distance
        // is the search's to the bit.
        let mut d2 = 0.0;
        for c in 0..D {
            let e = pts[j * D + c] - tp[c];
            d2 += e * e;
        }
        if d2.sqrt() * (1.0 + CERT_MARGIN) < room {
            Ok((d2 <= max_sq).then_some((j, d2)))
        } else {
            Err(delta)
        }
    }
}

/// The certificates of a registration's last searches, kept with its outcome: a later pass at
/// (about) the returned pose — the verdict's overlap — answers its nearest-neighbour queries
/// from them instead of searching, exactly as the search would (see [`Cert`]). `ids[i]` is the
/// answer source point `i`'s certificate was stated for (`u32::MAX`: none), `data` holds each
/// certificate's anchor offset and bound (`D + 1` values a point).
#[derive(Debug, Clone, PartialEq)]
pub struct Certificates {
    dim: usize,
    ids: Vec<u32>,
    data: Vec<f32>,
    /// The target points the certificates were stated against (address and length of the
    /// search's `points()`): a pass against another index must not use them.
    target: (usize, usize),
}

impl Certificates {
    /// `certs[i]`, stated for the answer `ids[i]`, against the search whose points are `pts`;
    /// None unless there is one per source point.
    pub(super) fn new<const D: usize>(certs: &[Cert<D>], ids: &[u32], pts: &[f64]) -> Option<Self> {
        if certs.is_empty() || certs.len() != ids.len() {
            return None;
        }
        let mut data = Vec::with_capacity(certs.len() * (D + 1));
        for c in certs {
            data.extend_from_slice(&c.offset);
            data.push(c.clear);
        }
        Some(Certificates {
            dim: D,
            ids: ids.to_vec(),
            data,
            target: (pts.as_ptr() as usize, pts.len()),
        })
    }

    /// Source points covered (one certificate each).
    pub fn len(&self) -> usize {
        self.ids.len()
    }

    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }

    /// Whether these certificates were stated against the search whose points are `pts`
    /// (the same storage, not merely equal values).
    pub fn states(&self, pts: &[f64]) -> bool {
        self.target == (pts.as_ptr() as usize, pts.len())
    }

    /// The nearest point of `pts` within `max_sq` to the query `q` of source point `i`, when
    /// its certificate settles it (`Some(None)`: settled, none within the gate), exactly as
    /// the search would answer (the same point, the same squared distance to the bit); None
    /// when a search is needed.
    #[inline]
    pub fn answer(
        &self,
        i: usize,
        q: &[f64],
        pts: &[f64],
        max_sq: f64,
    ) -> Option<Option<(usize, f64)>> {
        match self.dim {
            2 => self.answer_d::<2>(i, q, pts, max_sq),
            _ => self.answer_d::<3>(i, q, pts, max_sq),
        }
    }

    #[inline]
    fn answer_d<const D: usize>(
        &self,
        i: usize,
        q: &[f64],
        pts: &[f64],
        max_sq: f64,
    ) -> Option<Option<(usize, f64)>> {
        let raw = &self.data[i * (D + 1)..(i + 1) * (D + 1)];
        let cert = Cert::<D> {
            offset: std::array::from_fn(|c| raw[c]),
            clear: raw[D],
        };
        let tp: SVector<f64, D> = vec_at(q, 0);
        cert.answer(&tp, self.ids[i], pts, max_sq).ok()
    }
}
