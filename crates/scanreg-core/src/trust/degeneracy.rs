//! The weak directions of the normalised, scaled plane information (`scanreg.degeneracy`):
//! `Ĝ = S⁻¹ G S⁻¹ / n` with `S = diag(1.., L_a..)`, its eigen-analysis, and the tilt each
//! weak eigenvector carries from the normal noise.

use super::dense::{eigh, scale_both, sym, Mat, Vector};

/// Floor of the weak-direction threshold (a mean squared constraint per correspondence) when
/// the plane information counts every target normal: a linear neighbourhood (a sparse LiDAR's
/// ring, a pole) fits its normal anywhere about its line, and the information those guesses
/// claim sits inside `Ĝ` (0.019-0.023 per correspondence along the simulated VLP-16 tunnel's
/// axis), so the floor must sit above it.
pub const MIN_CONSTRAINT: f64 = 0.03;
/// The floor when the linear neighbourhoods are known and left out ([`floor`]): what is left
/// along the tunnel's axis is 0.0028 per correspondence and along the 2D corridor's 0.004-0.005
/// (clutter, the normals' own noise), while the weakest direction of simulated VLP-16 / HDL-32
/// street pairs keeps 0.017-0.027 (a rotation about a horizontal axis: the ground near the
/// sensor, at a short lever). Twice the corridor's.
pub const MIN_DETERMINED_CONSTRAINT: f64 = 0.01;
/// ... and at least this many correspondences' worth of it (a correspondence facing a
/// direction gives 1): a few stray correspondences must not be able to hold a direction of a
/// small cloud, whatever their share.
pub const MIN_FACING: f64 = 20.0;
/// The threshold is at least this many times the typical normal noise `ε̃²`.
pub const NOISE_FACTOR: f64 = 6.0;

#[derive(Debug, Clone, PartialEq)]
pub struct Degeneracy {
    /// `Ĝ`, symmetric, unitless.
    pub information: Mat,
    /// Rotation levers `L_a`.
    pub levers: Vector,
    /// Eigenvalues of `Ĝ`, ascending.
    pub eigenvalues: Vector,
    /// Its unit eigenvectors (columns), scaled coordinates.
    pub eigenvectors: Mat,
    /// The eigenvectors in tangent coordinates (`S⁻¹ v`), unit length in metres-equivalent.
    pub directions: Mat,
    pub threshold: f64,
    /// `ε̂²` (NaN: not measured).
    pub normal_noise: f64,
    /// `ε̃²` (NaN: not measured).
    pub typical_normal_noise: f64,
    pub num_correspondences: usize,
    /// `ε²` whose faked information was removed from `information` ([`noise_removed`]); NaN:
    /// not measured, nothing removed.
    pub removed_normal_noise: f64,
}

/// The plane information `G` less what normal noise of `ε²` per tangent axis adds to it in
/// expectation, `ε² N` (`N = Σ Aᵀ(I − m mᵀ)A`, [`crate::censi::Analysis`]), and the `ε²` used.
///
/// `ε²` is measured between the two scans: half the mean squared sine between each
/// correspondence's source and target normals, per tangent axis (`/ 2(D − 1)`). The mean, not
/// a median: the information a few badly wrong normals fake (a VLP-16 ring's neighbourhood is
/// nearly a line, its fitted normal can point anywhere about it) is a mean too. NaN (nothing
/// removed) with `dof` or fewer pairs.
pub fn noise_removed(
    information: &Mat,
    noise_information: &Mat,
    disagreement: f64,
    pairs: usize,
    dim: usize,
) -> (Mat, f64) {
    let dof = information.nrows();
    if pairs <= dof || !disagreement.is_finite() {
        return (information.clone(), f64::NAN);
    }
    let eps2 = disagreement / (pairs as f64 * 2.0 * (dim - 1) as f64);
    (information - noise_information * eps2, eps2)
}

/// `diag(S⁻¹)`: 1 for translation, `1/L_a` for rotation.
pub fn scaling(dim: usize, levers: &Vector) -> Vector {
    let mut s = Vector::from_element(dim + levers.len(), 1.0);
    for (a, l) in levers.iter().enumerate() {
        s[dim + a] = 1.0 / l;
    }
    s
}

/// Columns of `vecs` back in tangent units (`× s_inv`), each divided by the norm of the column
/// `/ norm_scale` (of itself when `None`).
pub fn unit_directions(vecs: &Mat, s_inv: &Vector, norm_scale: Option<&Vector>) -> Mat {
    let (n, m) = vecs.shape();
    let v = Mat::from_fn(n, m, |i, j| vecs[(i, j)] * s_inv[i]);
    let mut out = v.clone();
    for j in 0..m {
        let mut ss = 0.0;
        for i in 0..n {
            let x = match norm_scale {
                Some(d) => v[(i, j)] / d[i],
                None => v[(i, j)],
            };
            ss += x * x;
        }
        let norm = ss.sqrt();
        for i in 0..n {
            out[(i, j)] = v[(i, j)] / norm;
        }
    }
    out
}

/// The floor of the threshold for `count` correspondences: [`MIN_CONSTRAINT`] when the
/// information may hold linear neighbourhoods' normals (`linear_known` false: a map's, a
/// covariance's, 2D), else [`MIN_DETERMINED_CONSTRAINT`] or [`MIN_FACING`] correspondences'
/// worth, the larger.
pub fn floor(linear_known: bool, count: usize) -> f64 {
    if linear_known {
        MIN_DETERMINED_CONSTRAINT.max(MIN_FACING / count.max(1) as f64)
    } else {
        MIN_CONSTRAINT
    }
}

/// Name the weak directions of `information` (`Σ JᵀJ` over `count` correspondences), below
/// `floor` ([`floor`]) or the normal-noise term.
pub fn analyse(
    information: &Mat,
    count: usize,
    dim: usize,
    levers: &Vector,
    normal_noise: f64,
    typical_normal_noise: f64,
    floor: f64,
) -> Degeneracy {
    let s_inv = scaling(dim, levers);
    let g = scale_both(&sym(information), &s_inv) / (count.max(1) as f64);
    let (mut vals, vecs) = eigh(&g);
    // With the noise removed the estimate can dip below zero: no information.
    vals.apply(|v| *v = v.max(0.0));
    let mut threshold = floor;
    if typical_normal_noise.is_finite() {
        threshold = threshold.max(NOISE_FACTOR * typical_normal_noise);
    }
    let directions = unit_directions(&vecs, &s_inv, Some(&s_inv));
    Degeneracy {
        information: g,
        levers: levers.clone(),
        eigenvalues: vals,
        eigenvectors: vecs,
        directions,
        threshold,
        normal_noise,
        typical_normal_noise,
        num_correspondences: count,
        removed_normal_noise: f64::NAN,
    }
}

impl Degeneracy {
    pub fn dim(&self) -> usize {
        self.information.nrows() - self.levers.len()
    }

    /// Eigenvalues below the threshold (they come first: ascending).
    pub fn num_weak(&self) -> usize {
        self.eigenvalues
            .iter()
            .filter(|&&v| v < self.threshold)
            .count()
    }

    pub fn scaling(&self) -> Vector {
        scaling(self.dim(), &self.levers)
    }

    /// `(dof, w)` weak eigenvectors, scaled coordinates.
    pub fn weak_basis(&self) -> Mat {
        super::dense::columns(&self.eigenvectors, 0, self.num_weak())
    }

    /// `(dof, dof − w)` the other eigenvectors.
    pub fn strong_basis(&self) -> Mat {
        let n = self.eigenvectors.ncols();
        super::dense::columns(&self.eigenvectors, self.num_weak(), n)
    }

    /// `(w, dof − w)` variance of each weak eigenvector's tilt towards each strong one from
    /// normal noise `ε²` (NaN: zeros): `ε² λ_j / (n (λ_j − λ_w)²)`, the gap floored at 1e-12.
    pub fn tilt_variances(&self, normal_noise: f64) -> Mat {
        let eps2 = if normal_noise.is_nan() {
            0.0
        } else {
            normal_noise
        };
        let nw = self.num_weak();
        let dof = self.eigenvalues.len();
        let n = self.num_correspondences.max(1) as f64;
        let vals = &self.eigenvalues;
        Mat::from_fn(nw, dof - nw, |i, j| {
            let gap = (vals[nw + j] - vals[i]).max(1e-12);
            eps2 * vals[nw + j] / (n * (gap * gap))
        })
    }
}

/// A degeneracy from its normalised information `Ĝ` as analysed before (same eigenvectors:
/// the decomposition is deterministic).
pub fn from_normalised(
    g: Mat,
    levers: Vector,
    threshold: f64,
    normal_noise: f64,
    typical_normal_noise: f64,
    count: usize,
    removed_normal_noise: f64,
) -> Degeneracy {
    let dim = g.nrows() - levers.len();
    let s_inv = scaling(dim, &levers);
    let (mut vals, vecs) = eigh(&g);
    vals.apply(|v| *v = v.max(0.0));
    let directions = unit_directions(&vecs, &s_inv, Some(&s_inv));
    Degeneracy {
        information: g,
        levers,
        eigenvalues: vals,
        eigenvectors: vecs,
        directions,
        threshold,
        normal_noise,
        typical_normal_noise,
        num_correspondences: count,
        removed_normal_noise,
    }
}
