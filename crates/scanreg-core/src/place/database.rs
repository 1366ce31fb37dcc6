//! A growing database of Scan Contexts: shortlist by ring key, rank by the full distance
//! (Kim & Kim 2018, Sec. IV).

use super::distance::scan_context_distance;
use super::scan_context::ring_key;
use crate::error::{Error, Result};
use rayon::prelude::*;

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
    /// dropped. Candidates are compared in parallel; the result does not depend on the thread
    /// count.
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
        let mut shortlist: Vec<(f64, usize)> = self.ring_keys[..searchable * self.rings]
            .par_chunks_exact(self.rings)
            .with_min_len(256)
            .enumerate()
            .map(|(i, k)| {
                let d2: f64 = k.iter().zip(&key).map(|(a, b)| (a - b) * (a - b)).sum();
                (d2.sqrt(), i)
            })
            .collect();
        let keep = num_candidates.min(shortlist.len());
        let by_key = |a: &(f64, usize), b: &(f64, usize)| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
        if keep < shortlist.len() {
            shortlist.select_nth_unstable_by(keep, by_key);
            shortlist.truncate(keep);
        }
        shortlist.sort_by(by_key);
        let size = self.rings * self.sectors;
        let mut matches: Vec<PlaceMatch> = shortlist
            .par_iter()
            .map(|&(key_distance, i)| {
                let entry = &self.descriptors[i * size..(i + 1) * size];
                let m = scan_context_distance(descriptor, entry, self.rings, self.sectors);
                PlaceMatch {
                    index: i,
                    distance: m.distance,
                    yaw: m.yaw,
                    ring_key_distance: key_distance,
                }
            })
            .filter(|m| m.distance <= max_distance)
            .collect();
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
        assert!(db.add(&[1.0; 3]).is_err());
        assert!(db.add(&[f64::NAN; 8]).is_err());
    }
}
