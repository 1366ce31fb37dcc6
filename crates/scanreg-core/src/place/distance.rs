//! The Scan Context distance (Kim & Kim 2018, Eq. 5–6): the mean cosine distance of matching
//! sector columns, minimised over every column shift, whose argmin is the yaw between scans.

use crate::error::{Error, Result};
use std::f64::consts::PI;

/// The best column shift between two descriptors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShiftMatch {
    /// `1 - mean cosine similarity` of the column pairs where both columns have a return, in
    /// `[0, 2]` (0: identical up to scale); 1 when no column pair has returns in both.
    pub distance: f64,
    /// Yaw of `T_candidate_query` (rad, in `(-π, π]`): turning the query cloud by it lines it up
    /// with the candidate. The best shift refined by a parabola through its neighbours.
    pub yaw: f64,
    /// The best whole-column shift `s`: query column `j` matches candidate column `j + s`.
    pub shift: usize,
}

fn column_norms(d: &[f64], rings: usize, sectors: usize) -> Vec<f64> {
    (0..sectors)
        .map(|j| {
            (0..rings)
                .map(|i| d[i * sectors + j] * d[i * sectors + j])
                .sum::<f64>()
                .sqrt()
        })
        .collect()
}

/// Distance of the query to the candidate with the candidate's columns shifted by `shift`.
fn shifted_distance(
    query: &[f64],
    candidate: &[f64],
    qn: &[f64],
    cn: &[f64],
    rings: usize,
    sectors: usize,
    shift: usize,
) -> f64 {
    let mut sum = 0.0;
    let mut count = 0usize;
    for j in 0..sectors {
        let k = (j + shift) % sectors;
        if qn[j] == 0.0 || cn[k] == 0.0 {
            continue;
        }
        let dot: f64 = (0..rings)
            .map(|i| query[i * sectors + j] * candidate[i * sectors + k])
            .sum();
        sum += dot / (qn[j] * cn[k]);
        count += 1;
    }
    if count == 0 {
        1.0
    } else {
        1.0 - sum / count as f64
    }
}

/// [`scan_context_distance`] after checking the inputs: `rings >= 1`, `sectors >= 3`, both
/// descriptors `rings * sectors` long with finite values `>= 0`.
pub fn checked_scan_context_distance(
    query: &[f64],
    candidate: &[f64],
    rings: usize,
    sectors: usize,
) -> Result<ShiftMatch> {
    if rings == 0 || sectors < 3 {
        return Err(Error::invalid(
            "query",
            format!("need >= 1 ring and >= 3 sectors, got {rings} × {sectors}"),
        ));
    }
    for (name, d) in [("query", query), ("candidate", candidate)] {
        if d.len() != rings * sectors {
            return Err(Error::invalid(
                name,
                format!("expected {} values, got {}", rings * sectors, d.len()),
            ));
        }
        if !d.iter().all(|v| v.is_finite() && *v >= 0.0) {
            return Err(Error::invalid(name, "values must be finite and >= 0"));
        }
    }
    Ok(scan_context_distance(query, candidate, rings, sectors))
}

/// Compare two `rings × sectors` descriptors under every column shift (the paper narrows the
/// search with the sector key; all `sectors` shifts cost ~`rings · sectors²` products, a few
/// tens of microseconds at 20 × 60, so the search here is exhaustive and exact). The inputs
/// must be valid (see [`checked_scan_context_distance`]).
pub fn scan_context_distance(
    query: &[f64],
    candidate: &[f64],
    rings: usize,
    sectors: usize,
) -> ShiftMatch {
    let qn = column_norms(query, rings, sectors);
    let cn = column_norms(candidate, rings, sectors);
    let costs: Vec<f64> = (0..sectors)
        .map(|s| shifted_distance(query, candidate, &qn, &cn, rings, sectors, s))
        .collect();
    // First minimum on ties, so the result is deterministic.
    let mut best = 0;
    for (s, c) in costs.iter().enumerate() {
        if *c < costs[best] {
            best = s;
        }
    }
    let before = costs[(best + sectors - 1) % sectors];
    let after = costs[(best + 1) % sectors];
    let curvature = before - 2.0 * costs[best] + after;
    let offset = if curvature > 1e-12 {
        (0.5 * (before - after) / curvature).clamp(-0.5, 0.5)
    } else {
        0.0
    };
    let step = 2.0 * PI / sectors as f64;
    let mut yaw = (best as f64 + offset) * step;
    if yaw > PI {
        yaw -= 2.0 * PI;
    }
    ShiftMatch {
        distance: costs[best],
        yaw,
        shift: best,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_shifted_copy_is_at_distance_zero_with_its_shift() {
        let (rings, sectors) = (3, 10);
        let base: Vec<f64> = (0..rings * sectors)
            .map(|i| ((i * 7919) % 13) as f64)
            .collect();
        // Candidate column k = query column k - 3: query column j matches candidate j + 3.
        let mut cand = vec![0.0; rings * sectors];
        for i in 0..rings {
            for j in 0..sectors {
                cand[i * sectors + (j + 3) % sectors] = base[i * sectors + j];
            }
        }
        let m = scan_context_distance(&base, &cand, rings, sectors);
        assert_eq!(m.shift, 3);
        assert!(m.distance.abs() < 1e-12);
        assert!((m.yaw - 3.0 * 2.0 * PI / 10.0).abs() < 0.5 * 2.0 * PI / 10.0);
    }

    #[test]
    fn checked_refuses_bad_layouts() {
        assert!(checked_scan_context_distance(&[], &[], 20, 0).is_err());
        assert!(checked_scan_context_distance(&[1.0; 6], &[1.0; 5], 2, 3).is_err());
        assert!(checked_scan_context_distance(&[f64::NAN; 6], &[1.0; 6], 2, 3).is_err());
        assert!(checked_scan_context_distance(&[1.0; 6], &[1.0; 6], 2, 3).is_ok());
    }

    #[test]
    fn no_common_columns_is_distance_one() {
        let m = scan_context_distance(&[0.0; 6], &[1.0; 6], 2, 3);
        assert_eq!(m.distance, 1.0);
    }
}
