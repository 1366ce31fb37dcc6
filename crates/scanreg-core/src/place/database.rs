//! A growing database of Scan Contexts: shortlist by ring key, rank by the full distance
//! (Kim & Kim 2018, Sec. IV).

use super::distance::scan_context_distance;
use super::scan_context::ring_key;
use crate::error::{Error, Result};
use rayon::prelude::*;

/// Shortlists shorter than this are compared on the calling thread: one comparison costs
/// ~50 µs at 20 × 60, so the paper's 10 take 0.5 ms — less than waking the pool costs on
/// the loaded 2-core machine (a query of a 150-keyframe database measured 4–6 ms with both
/// steps parallel).
pub const PARALLEL_MIN_CANDIDATES: usize = 32;
/// Databases smaller than this are shortlisted on the calling thread (a ring-key distance
/// is ~20 flops).
pub const PARALLEL_MIN_ENTRIES: usize = 16_384;

/// One retrieved place.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaceMatch {
    /// Insertion index of the entry in the database.
    pub index: usize,
    /// Scan Context distance (see [`super::ShiftMatch::distance`]).
    pub distance: f64,
    /// Yaw of `T_entry_query` (rad).
    pub yaw: f64,
    /// Euclidean distance of the ring keys (the shortlist's criterion).
    pub ring_key_distance: f64,
}

/// Descriptors of one layout, kept in insertion order.
#[derive(Debug, Clone)]
pub struct ScanContextDatabase {
    rings: usize,
    sectors: usize,
    descriptors: Vec<f64>,
    ring_keys: Vec<f64>,
}

impl ScanContextDatabase {
    pub fn new(rings: usize, sectors: usize) -> Result<Self> {
        if rings == 0 || sectors < 3 {
            return Err(Error::invalid(
                "num_rings",
                format!("need num_rings >= 1 and num_sectors >= 3, got {rings} × {sectors}"),
            ));
        }
        Ok(Self {
            rings,
            sectors,
            descriptors: Vec::new(),
            ring_keys: Vec::new(),
        })
    }

    pub fn len(&self) -> usize {
        self.ring_keys.len() / self.rings
    }

    pub fn is_empty(&self) -> bool {
        self.ring_keys.is_empty()
    }

    pub fn shape(&self) -> (usize, usize) {
        (self.rings, self.sectors)
    }

    fn check(&self, descriptor: &[f64], name: &'static str) -> Result<()> {
        if descriptor.len() != self.rings * self.sectors {
            return Err(Error::invalid(
                name,
                format!(
                    "expected {} × {} = {} values, got {}",
                    self.rings,
                    self.sectors,
                    self.rings * self.sectors,
                    descriptor.len()
                ),
            ));
        }
        if !descriptor.iter().all(|v| v.is_finite() && *v >= 0.0) {
            return Err(Error::invalid(name, "values must be finite and >= 0"));
        }
        Ok(())
    }

    /// Append a descriptor; returns its index.
    pub fn add(&mut self, descriptor: &[f64]) -> Result<usize> {
        self.check(descriptor, "descriptor")?;
        self.descriptors.extend_from_slice(descriptor);
        self.ring_keys
            .extend(ring_key(descriptor, self.rings, self.sectors));
        Ok(self.len() - 1)
    }

    /// The `top_k` entries nearest to `descriptor`, best first (ties by index), among all but
    /// the `exclude_recent` most recently added: the `num_candidates` nearest by ring key,
    /// ranked by the Scan Context distance. Entries with a distance above `max_distance` are
    /// dropped. Large databases and shortlists are processed in parallel (maps only: the
    /// result does not depend on the thread count).
    pub fn query(
        &self,
        descriptor: &[f64],
        num_candidates: usize,
        top_k: usize,
        exclude_recent: usize,
        max_distance: f64,
    ) -> Result<Vec<PlaceMatch>> {
        self.check(descriptor, "descriptor")?;
        if num_candidates == 0 {
            return Err(Error::invalid("num_candidates", "must be >= 1"));
        }
        if max_distance.is_nan() {
            return Err(Error::invalid("max_distance", "must not be NaN"));
        }
        let searchable = self.len().saturating_sub(exclude_recent);
        let key = ring_key(descriptor, self.rings, self.sectors);
        let keys = &self.ring_keys[..searchable * self.rings];
        let key_distance = |(i, k): (usize, &[f64])| {
            let d2: f64 = k.iter().zip(&key).map(|(a, b)| (a - b) * (a - b)).sum();
            (d2.sqrt(), i)
        };
        let mut shortlist: Vec<(f64, usize)> = if searchable < PARALLEL_MIN_ENTRIES {
            keys.chunks_exact(self.rings)
                .enumerate()
                .map(key_distance)
                .collect()
        } else {
            keys.par_chunks_exact(self.rings)
                .with_min_len(1024)
                .enumerate()
                .map(key_distance)
                .collect()
        };
        let keep = num_candidates.min(shortlist.len());
        let by_key = |a: &(f64, usize), b: &(f64, usize)| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
        if keep < shortlist.len() {
            shortlist.select_nth_unstable_by(keep, by_key);
            shortlist.truncate(keep);
        }
        shortlist.sort_by(by_key);
        let size = self.rings * self.sectors;
        let compare = |&(key_distance, i): &(f64, usize)| {
            let entry = &self.descriptors[i * size..(i + 1) * size];
            let m = scan_context_distance(descriptor, entry, self.rings, self.sectors);
            PlaceMatch {
                index: i,
                distance: m.distance,
                yaw: m.yaw,
                ring_key_distance: key_distance,
            }
        };
        let mut matches: Vec<PlaceMatch> = if shortlist.len() < PARALLEL_MIN_CANDIDATES {
            shortlist.iter().map(compare).collect()
        } else {
            shortlist.par_iter().map(compare).collect()
        };
        matches.retain(|m| m.distance <= max_distance);
        matches.sort_by(|a, b| {
            a.distance
                .total_cmp(&b.distance)
                .then(a.index.cmp(&b.index))
        });
        matches.truncate(top_k);
        Ok(matches)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn retrieves_the_entry_it_was_given_and_honours_exclusions() {
        let mut db = ScanContextDatabase::new(2, 4).unwrap();
        let a = [1.0, 0.0, 2.0, 0.0, 0.0, 3.0, 0.0, 1.0];
        let b = [0.0, 5.0, 0.0, 5.0, 1.0, 1.0, 1.0, 1.0];
        assert_eq!(db.add(&a).unwrap(), 0);
        assert_eq!(db.add(&b).unwrap(), 1);
        let found = db.query(&a, 10, 1, 0, f64::INFINITY).unwrap();
        assert_eq!(found[0].index, 0);
        assert!(found[0].distance.abs() < 1e-12);
        let found = db.query(&b, 10, 2, 1, f64::INFINITY).unwrap();
        assert_eq!(found.len(), 1);
        assert_eq!(found[0].index, 0);
        assert!(db.query(&b, 10, 2, 2, f64::INFINITY).unwrap().is_empty());
        // A long shortlist takes the parallel path and ranks the same way.
        let serial = db.query(&b, 10, 2, 0, f64::INFINITY).unwrap();
        let parallel = db
            .query(&b, PARALLEL_MIN_CANDIDATES, 2, 0, f64::INFINITY)
            .unwrap();
        assert_eq!(serial, parallel);
        assert!(db.add(&[1.0; 3]).is_err());
        assert!(db.add(&[f64::NAN; 8]).is_err());
    }

    #[test]
    fn parallel_shortlist_ranks_as_the_serial_one() {
        let mut db = ScanContextDatabase::new(3, 8).unwrap();
        for e in 0..2 * PARALLEL_MIN_CANDIDATES {
            let d: Vec<f64> = (0..24).map(|i| ((i * 31 + e * 17) % 11) as f64).collect();
            db.add(&d).unwrap();
        }
        let q: Vec<f64> = (0..24).map(|i| ((i * 7) % 5) as f64).collect();
        let n = db.len();
        // Every entry shortlisted: serial pair by pair against the parallel query.
        let parallel = db.query(&q, n, n, 0, f64::INFINITY).unwrap();
        let mut serial: Vec<(f64, usize)> = (0..n)
            .map(|i| {
                let e = &db.descriptors[i * 24..(i + 1) * 24];
                (scan_context_distance(&q, e, 3, 8).distance, i)
            })
            .collect();
        serial.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let order: Vec<usize> = parallel.iter().map(|m| m.index).collect();
        assert_eq!(order, serial.iter().map(|s| s.1).collect::<Vec<_>>());
    }
}
