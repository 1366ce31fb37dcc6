use super::*;
use crate::icp::{self, Method, Optimizer, Settings, Source, Target};
use crate::knn::KdTree;
use crate::normals::local_geometry;
use crate::Kernel;

/// A deterministic pseudo-random cloud in a 20 m cube (no RNG dependency).
fn cloud(n: usize, dim: usize, seed: u64) -> Vec<f64> {
    let mut s = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (0..n * dim)
        .map(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) * 20.0 - 10.0
        })
        .collect()
}

fn brute(points: &[f64], dim: usize, q: &[f64], max_sq: f64) -> Option<f64> {
    points
        .chunks_exact(dim)
        .map(|p| p.iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum::<f64>())
        .filter(|d| *d <= max_sq)
        .min_by(|a, b| a.total_cmp(b))
}

#[test]
fn nearest_is_exact_for_every_gate() {
    for dim in [2, 3] {
        let pts = cloud(3000, dim, 7);
        let mut map = VoxelMap::new(dim, 0.7, 1024, 0.0, Attributes::None).unwrap();
        assert_eq!(map.insert(&pts, None, None).unwrap(), 3000);
        let queries = cloud(300, dim, 99);
        // Gates below, at and far above the voxel size (the last one scans every voxel).
        for gate in [0.1, 0.7, 2.5, 1e6] {
            for q in queries.chunks_exact(dim) {
                let want = brute(&pts, dim, q, gate * gate);
                let got = map.nearest_within(q, gate * gate).map(|(j, d)| {
                    // The id must point at a point at that distance.
                    let p = &NeighborSearch::points(&map)[j * dim..(j + 1) * dim];
                    let d2: f64 = p.iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum();
                    assert_eq!(d2, d);
                    d
                });
                assert_eq!(got, want, "dim {dim} gate {gate}");
            }
        }
    }
}

/// The least `(distance, id)` over the map's stored points: the id a search must return.
fn brute_id(map: &VoxelMap, q: &[f64], max_sq: f64) -> Option<(usize, f64)> {
    let (dim, cap) = (map.dim, map.max_per_voxel);
    let mut best: Option<(usize, f64)> = None;
    for (s, &count) in map.counts.iter().enumerate() {
        for j in s * cap..s * cap + count as usize {
            let p = &map.points[j * dim..(j + 1) * dim];
            let d: f64 = p.iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum();
            if d <= max_sq && best.is_none_or(|(bi, bd)| d < bd || (d == bd && j < bi)) {
                best = Some((j, d));
            }
        }
    }
    best
}

#[test]
fn wide_gates_walk_blocks_and_stay_exact() {
    // Clusters on a lattice (tied distances: the id decides) far apart, queries in the gaps
    // and beyond the map, gates from a few voxels to the whole map, near the origin and in
    // UTM coordinates; the block index must follow every insertion and eviction.
    for dim in [2, 3] {
        for offset in [0.0, 4.3e6] {
            let mut map = VoxelMap::new(dim, 0.5, 16, 0.0, Attributes::None).unwrap();
            let mut batch = Vec::new();
            for (i, v) in cloud(40, dim, 3).chunks_exact(dim).enumerate() {
                for k in 0..6 {
                    for (c, x) in v.iter().enumerate() {
                        let step = if c == k % dim {
                            0.25 * (k / dim) as f64
                        } else {
                            0.0
                        };
                        batch.push(offset + 3.0 * x.round() + step + 0.5 * (i % 2) as f64);
                    }
                }
            }
            map.insert(&batch, None, None).unwrap();
            let queries: Vec<f64> = cloud(200, dim, 11)
                .iter()
                .map(|x| offset + 2.5 * x)
                .collect();
            for round in 0..3 {
                for gate in [2.6, 6.0, 40.0, 1e4] {
                    for q in queries.chunks_exact(dim) {
                        let want = brute_id(&map, q, gate * gate);
                        assert_eq!(
                            map.nearest_within(q, gate * gate),
                            want,
                            "dim {dim} gate {gate}"
                        );
                    }
                }
                // Change the map: the next round must see the change.
                let center = vec![offset; dim];
                if round == 0 {
                    map.remove_far(&center, 15.0).unwrap();
                } else {
                    let more: Vec<f64> = cloud(50, dim, 20 + round)
                        .iter()
                        .map(|x| offset + x)
                        .collect();
                    map.insert(&more, None, None).unwrap();
                }
            }
        }
    }
}

#[test]
fn capacity_spacing_and_eviction() {
    let mut map = VoxelMap::new(3, 1.0, 3, 0.1, Attributes::None).unwrap();
    // Five points in one voxel, two of them closer than the spacing to an earlier one.
    let pts = [
        0.1, 0.1, 0.1, 0.15, 0.1, 0.1, 0.5, 0.5, 0.5, 0.9, 0.9, 0.9, 0.3, 0.3, 0.3,
    ];
    assert_eq!(map.insert(&pts, None, None).unwrap(), 3); // (0.15..) too close; last one over capacity
    assert_eq!(map.len(), 3);
    assert_eq!(map.num_voxels(), 1);
    let far = [50.0, 0.0, 0.0, 50.2, 0.0, 0.0];
    assert_eq!(map.insert(&far, None, None).unwrap(), 2);
    assert_eq!(map.num_voxels(), 2);
    // Evict around the origin with a 10 m radius: the far voxel goes.
    assert_eq!(map.remove_far(&[0.0, 0.0, 0.0], 10.0).unwrap(), 2);
    assert_eq!((map.len(), map.num_voxels()), (3, 1));
    assert!(map.nearest_within(&[50.0, 0.0, 0.0], 1.0).is_none());
    // The freed slot is reused: the id space does not grow.
    let ids = map.id_count();
    map.insert(&[-30.0, 0.0, 0.0], None, None).unwrap();
    assert_eq!(map.id_count(), ids);
    assert_eq!(map.contents().points.len(), 4 * 3);
}

#[test]
fn rejects_bad_input_without_changing_the_map() {
    let mut map = VoxelMap::new(3, 1.0, 5, 0.0, Attributes::Normals).unwrap();
    let pts = [0.0, 0.0, 0.0, 1.0, 1.0, 1.0];
    let err = map.insert(&pts, None, None).unwrap_err();
    assert!(err.to_string().starts_with("attributes:"), "{err}");
    let err = map
        .insert(&pts, Some(&[0.0, 0.0, 1.0, f64::NAN, 0.0, 1.0]), None)
        .unwrap_err();
    assert!(err.to_string().contains("normals: contains NaN"), "{err}");
    let err = map
        .insert(&[1e300, 0.0, 0.0], Some(&[0.0, 0.0, 1.0]), None)
        .unwrap_err();
    assert!(err.to_string().starts_with("points:"), "{err}");
    assert!(map.is_empty());
    assert!(VoxelMap::new(4, 1.0, 5, 0.0, Attributes::None).is_err());
    assert!(VoxelMap::new(3, 0.0, 5, 0.0, Attributes::None).is_err());
    assert!(VoxelMap::new(3, 1.0, 0, 0.0, Attributes::None).is_err());
    assert!(map.remove_far(&[0.0, 0.0], 1.0).is_err());
    assert!(map.remove_far(&[0.0, 0.0, 0.0], -1.0).is_err());
}

/// Registration against the map gives the same pose as against a k-d tree of the same points
/// (both searches are exact and break ties alike up to id order, which a random cloud avoids).
#[test]
fn registration_against_map_equals_kd_tree() {
    let tgt = cloud(4000, 3, 3);
    let tree = KdTree::build(&tgt, 3).unwrap();
    let geo = local_geometry(&tree, 10, &[0.0; 3], true, None).unwrap();
    let normals = geo.normals.unwrap();
    let mut map = VoxelMap::new(3, 1.0, 1024, 0.0, Attributes::Normals).unwrap();
    map.insert(&tgt, Some(&normals), None).unwrap();
    // Source: the target moved by a small known motion.
    let (c, s) = (0.02f64.cos(), 0.02f64.sin());
    let src: Vec<f64> = tgt
        .chunks_exact(3)
        .flat_map(|p| {
            let (x, y, z) = (p[0] - 0.1, p[1] + 0.05, p[2]);
            [c * x + s * y, -s * x + c * y, z]
        })
        .collect();
    let settings = Settings {
        method: Method::PointToPlane,
        kernel: Kernel::None,
        max_correspondence_distance: 0.5,
        max_iterations: 30,
        translation_tolerance: 1e-9,
        rotation_tolerance: 1e-9,
        optimizer: Optimizer::GaussNewton,
        min_correspondences: 10,
        step_projector: None,
        extrapolate: true,
    };
    let init = [
        1.0, 0., 0., 0., 0., 1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1.,
    ];
    let source = Source {
        points: &src,
        covariances: None,
    };
    let by_tree = icp::register(
        &source,
        &Target {
            search: &tree,
            normals: Some(&normals),
            covariances: None,
        },
        &init,
        &settings,
    )
    .unwrap();
    let by_map = icp::register(
        &source,
        &Target {
            search: &map,
            normals: map.normals(),
            covariances: None,
        },
        &init,
        &settings,
    )
    .unwrap();
    assert_eq!(by_tree.iterations, by_map.iterations);
    for (a, b) in by_tree.pose.iter().zip(&by_map.pose) {
        assert!((a - b).abs() < 1e-12, "{a} vs {b}");
    }
    // And it is the truth: R = Rz(0.02), t = (0.1, -0.05, 0).
    assert!((by_map.pose[3] - 0.1).abs() < 1e-6, "{:?}", by_map.pose);
    assert!((by_map.pose[7] + 0.05).abs() < 1e-6, "{:?}", by_map.pose);
    assert!((by_map.pose[4] - s).abs() < 1e-6, "{:?}", by_map.pose);
}

#[test]
fn voxel_covariances_are_plane_regularised_per_voxel() {
    let mut map = VoxelMap::new(3, 1.0, 20, 0.0, Attributes::VoxelCovariances).unwrap();
    // A tilted plane patch z = 0.2 x inside one voxel, plus 2 points alone in another voxel.
    let mut pts = Vec::new();
    for i in 0..4 {
        for j in 0..4 {
            let (x, y) = (0.1 + 0.2 * i as f64, 0.1 + 0.2 * j as f64);
            pts.extend_from_slice(&[x, y, 0.5 + 0.2 * (x - 0.5)]);
        }
    }
    pts.extend_from_slice(&[5.5, 5.5, 5.5, 5.6, 5.5, 5.5]);
    assert_eq!(map.insert(&pts, None, None).unwrap(), 18);
    let covs = map.covariances().unwrap();
    let c = nalgebra::Matrix3::from_column_slice(&covs[0..9]);
    let e = c.symmetric_eigen();
    let mut vals: Vec<f64> = e.eigenvalues.iter().copied().collect();
    vals.sort_by(f64::total_cmp);
    assert!(
        (vals[0] - 1e-3).abs() < 1e-12 && (vals[1] - 1.0).abs() < 1e-12,
        "{vals:?}"
    );
    // Its thin direction is the plane normal (-0.2, 0, 1) / |.|.
    let n = e.eigenvectors.column(e.eigenvalues.imin()).into_owned();
    let want = nalgebra::Vector3::new(-0.2, 0.0, 1.0).normalize();
    assert!(n.dot(&want).abs() > 1.0 - 1e-9);
    // One row per voxel, which every point of it reads (and `contents` repeats per point);
    // the 2-point voxel gets the identity.
    assert_eq!(map.covariance_group(), 20);
    assert_eq!(covs.len(), 2 * 9);
    let listed = map.contents().covariances;
    assert_eq!(listed.len(), 18 * 9);
    assert!(listed[..16 * 9].chunks_exact(9).all(|r| r == &covs[0..9]));
    let id = NeighborSearch::nearest_within(&map, &[5.5, 5.5, 5.5], 1e-6)
        .unwrap()
        .0;
    let row = id / map.covariance_group();
    assert_eq!(
        &covs[row * 9..row * 9 + 9],
        &[1., 0., 0., 0., 1., 0., 0., 0., 1.]
    );
}
