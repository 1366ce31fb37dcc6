use super::*;

fn lcg_cloud(n: usize, dim: usize, seed: u64, grid: bool) -> Vec<f64> {
    let mut s = seed;
    (0..n * dim)
        .map(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let u = (s >> 11) as f64 / (1u64 << 53) as f64;
            if grid {
                (u * 5.0).floor() // many duplicates and ties
            } else {
                u * 10.0 - 5.0
            }
        })
        .collect()
}

fn brute(points: &[f64], dim: usize, q: &[f64]) -> Vec<(u32, f64)> {
    let mut v: Vec<(u32, f64)> = points
        .chunks_exact(dim)
        .enumerate()
        .map(|(i, p)| {
            let d: f64 = p.iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum();
            (i as u32, d)
        })
        .collect();
    canonical(&mut v);
    v
}

/// The certified search answers exactly as the plain one, ties included, and its bound is
/// sound (no other point is nearer than it) and as strong as promised: at least the true
/// runner-up, or the answer grown by the slack, whichever is nearer.
#[test]
fn certified_nearest_is_exact_and_its_bound_sound() {
    for dim in [2, 3] {
        for grid in [false, true] {
            let pts = lcg_cloud(700, dim, 11 + dim as u64, grid);
            let qs = lcg_cloud(150, dim, 5, grid);
            let tree = KdTree::build(&pts, dim).unwrap();
            for (k, q) in qs.chunks_exact(dim).enumerate() {
                let b = brute(&pts, dim, q);
                for (max_sq, slack) in [(0.3, 0.0), (0.3, 0.2), (2.0, 0.05), (f64::INFINITY, 0.5)] {
                    // A hint that is the answer, a neighbour of it, or none.
                    let hint = match k % 3 {
                        0 => None,
                        1 => Some(b[0].0 as usize),
                        _ => Some(b[3].0 as usize),
                    };
                    let (got, clear) = tree.nearest_certified(q, max_sq, hint, slack);
                    assert_eq!(got, tree.nearest_within(q, max_sq), "{dim}D q{k}");
                    let grow = |d: f64| (d.sqrt() + slack).powi(2);
                    let (others, promised) = match got {
                        Some((i, d)) => (
                            b.iter()
                                .filter(|&&(j, _)| j as usize != i)
                                .collect::<Vec<_>>(),
                            grow(d),
                        ),
                        None => (b.iter().collect(), grow(max_sq)),
                    };
                    let runner_up = others[0].1;
                    assert!(
                        runner_up >= clear,
                        "{dim}D q{k}: a point at {runner_up} < {clear}"
                    );
                    assert!(
                        clear >= runner_up.min(promised) * (1.0 - 1e-12),
                        "{dim}D q{k}: bound {clear}, runner-up {runner_up}, promised {promised}"
                    );
                }
            }
        }
    }
}

/// The parallel build lays the tree out exactly as the sequential one: same nodes, same
/// point order, same leaves (so every query, ties included, answers the same).
#[test]
fn parallel_build_is_the_sequential_tree() {
    fn same<const D: usize>(a: &Inner<D>, b: &Inner<D>) {
        assert_eq!(a.nodes.len(), b.nodes.len());
        for (x, y) in a.nodes.iter().zip(&b.nodes) {
            assert_eq!(
                (x.axis, x.lo, x.hi, x.right, x.split.to_bits()),
                (y.axis, y.lo, y.hi, y.right, y.split.to_bits())
            );
        }
        assert!(a.pts == b.pts && a.ids == b.ids);
        assert!(a.leaf_of == b.leaf_of && a.slot_of == b.slot_of);
        assert_eq!(a.leaves.len(), b.leaves.len());
        for (x, y) in a.leaves.iter().zip(&b.leaves) {
            assert_eq!((x.lo, x.hi, x.axis), (y.lo, y.hi, y.axis));
            assert!(x.cell_lo == y.cell_lo && x.cell_hi == y.cell_hi);
        }
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    for grid in [false, true] {
        let p2 = lcg_cloud(20_000, 2, 3, grid);
        let p3 = lcg_cloud(20_000, 3, 4, grid);
        pool.install(|| {
            same(
                &Inner::<2>::build(&p2, 1000),
                &Inner::<2>::build(&p2, usize::MAX),
            );
            same(
                &Inner::<3>::build(&p3, 1000),
                &Inner::<3>::build(&p3, usize::MAX),
            );
        });
    }
}

#[test]
fn kdtree_matches_brute_force_with_ties() {
    for dim in [2, 3] {
        for grid in [false, true] {
            let pts = lcg_cloud(500, dim, 7 + dim as u64, grid);
            let qs = lcg_cloud(60, dim, 99, grid);
            let tree = KdTree::build(&pts, dim).unwrap();
            for q in qs.chunks_exact(dim) {
                let b = brute(&pts, dim, q);
                let (i, d) = tree.nearest_within(q, f64::INFINITY).unwrap();
                assert_eq!(d, b[0].1);
                assert_eq!(b.iter().find(|x| x.0 as usize == i).unwrap().1, d);
                let mut v = Vec::new();
                tree.knn_into(q, 10, f64::INFINITY, &mut v);
                let dk: Vec<f64> = v.iter().map(|x| x.1).collect();
                let bk: Vec<f64> = b[..10].iter().map(|x| x.1).collect();
                assert_eq!(dk, bk);
                let mut r = Vec::new();
                tree.radius_into(q, 1.5, &mut r);
                let br: Vec<(u32, f64)> = b.iter().copied().filter(|x| x.1 <= 1.5).collect();
                assert_eq!(r, br);
                // Gated: the nearest within the gate, ties to the lower index.
                let gate = 1.3f64;
                let want = b
                    .iter()
                    .find(|x| x.1 <= gate * gate)
                    .map(|x| (x.0 as usize, x.1));
                let gated = tree.nearest_within(q, gate * gate).map(|x| x.1);
                assert_eq!(gated, want.map(|x| x.1));
            }
        }
    }
}

#[test]
fn hinted_nearest_equals_the_plain_search() {
    // Any hint (the true answer, a far point, one beyond the gate, out of range), ties
    // included (grid clouds): the same (index, distance) as the search without a hint.
    for (dim, grid) in [(2, false), (2, true), (3, false), (3, true)] {
        let pts = lcg_cloud(500, dim, 7 + dim as u64, grid);
        let tree = KdTree::build(&pts, dim).unwrap();
        let queries = lcg_cloud(200, dim, 99, grid);
        for (n, q) in queries.chunks_exact(dim).enumerate() {
            for max_sq in [f64::INFINITY, 0.5, 0.0] {
                let want = tree.nearest_within(q, max_sq);
                for hint in [n, (n * 37) % 500, 499, 10_000] {
                    let got = tree.nearest_within_hinted(q, max_sq, hint);
                    assert_eq!(got, want, "dim {dim} grid {grid} q {q:?} hint {hint}");
                }
                if let Some((best, _)) = want {
                    assert_eq!(tree.nearest_within_hinted(q, max_sq, best), want);
                }
            }
        }
    }
    // A 2D scan: walls of evenly spaced points (sorted leaves end their scans early),
    // duplicated points and queries on the walls (exact ties), every point as the hint.
    let mut wall: Vec<f64> = (0..300)
        .flat_map(|i| {
            let t = f64::from(i % 100) * 0.05;
            match i / 100 {
                0 => [t, 0.0],
                1 => [5.0, t],
                _ => [t, 0.6 * t],
            }
        })
        .collect();
    wall.extend_from_within(..40);
    let tree = KdTree::build(&wall, 2).unwrap();
    for q in wall
        .chunks_exact(2)
        .chain(lcg_cloud(100, 2, 5, false).chunks_exact(2))
    {
        for max_sq in [f64::INFINITY, 0.01] {
            let want = tree.nearest_within(q, max_sq);
            for hint in 0..wall.len() / 2 {
                assert_eq!(
                    tree.nearest_within_hinted(q, max_sq, hint),
                    want,
                    "{q:?} {hint}"
                );
            }
        }
    }
}

#[test]
fn rejects_bad_input() {
    assert!(KdTree::build(&[], 3).is_err());
    assert!(KdTree::build(&[0.0, f64::NAN, 1.0], 3).is_err());
    let t = KdTree::build(&[0.0, 0.0, 1.0, 1.0], 2).unwrap();
    assert!(t.knn_batch(&[0.0, 0.0], 3).is_err());
    assert!(t.knn_batch(&[0.0, 0.0], 0).is_err());
    assert!(t.nearest_batch(&[0.0, 0.0], -1.0).is_err());
    assert!(t.nearest_batch(&[0.0, 0.0], f64::NAN).is_err());
}

/// `any_within` says whether the brute-force nearest lies within the gate, the gate included
/// (queries on a grid sit at exactly the gate from some points).
#[test]
fn any_within_agrees_with_brute_force() {
    for dim in [2, 3] {
        for grid in [false, true] {
            let pts = lcg_cloud(500, dim, 3 + dim as u64, grid);
            let qs = lcg_cloud(200, dim, 9, grid);
            let tree = KdTree::build(&pts, dim).unwrap();
            for q in qs.chunks_exact(dim) {
                let nearest = brute(&pts, dim, q)[0].1;
                for max_sq in [0.0, 0.05, 1.0, 2.0, f64::INFINITY, f64::NAN] {
                    assert_eq!(tree.any_within(q, max_sq), nearest <= max_sq, "{dim}D");
                }
                assert!(tree.any_within(q, nearest));
                assert!(nearest == 0.0 || !tree.any_within(q, nearest * 0.999));
            }
        }
    }
}
