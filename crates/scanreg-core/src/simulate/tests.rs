use super::geometry::*;
use super::*;

fn row(kind: f64, params: &[f64], velocity: [f64; 3]) -> Vec<f64> {
    let mut r = vec![0.0; PRIM_COLUMNS];
    r[0] = kind;
    r[1..1 + params.len()].copy_from_slice(params);
    r[8..11].copy_from_slice(&velocity);
    r
}

fn square_room(half: f64) -> Vec<f64> {
    let c = [[-half, -half], [half, -half], [half, half], [-half, half]];
    (0..4)
        .flat_map(|k| {
            let (a, b) = (c[k], c[(k + 1) % 4]);
            row(KIND_WALL, &[a[0], a[1], b[0], b[1], -1.0, 1.0], [0.0; 3])
        })
        .collect()
}

fn planar_beams(n: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let angles: Vec<f64> = (0..n)
        .map(|i| -std::f64::consts::PI + std::f64::consts::TAU * (i as f64 + 0.5) / n as f64)
        .collect();
    let dirs = angles
        .iter()
        .flat_map(|a| [a.cos(), a.sin(), 0.0])
        .collect();
    (angles, dirs, vec![0.0; n])
}

fn exact(max_range: f64) -> RangeModel {
    RangeModel {
        min_range: 0.0,
        max_range,
        range_sigma: 0.0,
        dropout_probability: 0.0,
        seed: 1,
    }
}

fn still() -> Motion {
    Motion::fixed(Rigid::identity())
}

#[test]
fn square_room_ranges_are_half_width_over_cosine() {
    let (angles, dirs, times) = planar_beams(360);
    let beams = Beams {
        directions: &dirs,
        time_offsets: &times,
    };
    let out = cast(&square_room(3.0), beams, 0.0, &still(), 0.0, &exact(50.0)).unwrap();
    for (i, a) in angles.iter().enumerate() {
        // Distance to the nearest wall along the beam: 3 / max(|cos a|, |sin a|).
        let expected = 3.0 / a.cos().abs().max(a.sin().abs());
        assert!((out.true_range[i] - expected).abs() < 1e-12, "beam {i}");
        assert_eq!(out.status[i], STATUS_VALID);
        assert_eq!(out.range[i], out.true_range[i]);
    }
}

#[test]
fn ground_plane_and_pole_in_3d() {
    let mut scene = row(KIND_PLANE, &[0.0, 0.0, 1.0, -1.7], [0.0; 3]);
    scene.extend(row(KIND_CYLINDER, &[8.0, 0.0, -1.7, 3.0, 0.25], [0.0; 3]));
    let el: f64 = -0.2;
    let dirs = [
        el.cos(),
        0.0,
        el.sin(),
        0.0,
        el.cos(),
        el.sin(),
        1.0,
        0.0,
        0.0,
    ];
    let beams = Beams {
        directions: &dirs,
        time_offsets: &[0.0; 3],
    };
    let out = cast(&scene, beams, 0.0, &still(), 0.0, &exact(100.0)).unwrap();
    let ground = 1.7 / (-el).sin();
    // Beam 0 reaches the pole (at x = 7.75 the beam is 1.6 m down, above the ground).
    assert!((out.true_range[0] - 7.75 / el.cos()).abs() < 1e-12);
    assert_eq!(out.hit[0], 1);
    assert!((out.true_range[1] - ground).abs() < 1e-12);
    assert_eq!(out.hit[1], 0);
    assert!((out.true_range[2] - 7.75).abs() < 1e-12);
}

#[test]
fn nearest_of_many_primitives_matches_brute_force() {
    // A few hundred spheres: the BVH must return the same hit as testing every one.
    let mut scene = Vec::new();
    let mut r = rng::BeamRng::new(9, 0);
    for _ in 0..300 {
        let c = [
            r.uniform() * 40.0 - 20.0,
            r.uniform() * 40.0 - 20.0,
            r.uniform() * 4.0 - 2.0,
        ];
        scene.extend(row(
            KIND_SPHERE,
            &[c[0], c[1], c[2], 0.2 + r.uniform()],
            [0.0; 3],
        ));
    }
    let prims = parse_primitives(&scene).unwrap();
    let (_, dirs, times) = planar_beams(720);
    let origin = Rigid {
        r: nalgebra::Matrix3::identity(),
        t: Vector3::new(0.3, -0.2, 0.1),
    };
    let out = cast(
        &scene,
        Beams {
            directions: &dirs,
            time_offsets: &times,
        },
        0.0,
        &Motion::fixed(origin),
        0.0,
        &exact(1e3),
    )
    .unwrap();
    for (i, d) in dirs.chunks_exact(3).enumerate() {
        let brute = prims
            .iter()
            .filter_map(|p| p.shape.intersect([0.3, -0.2, 0.1], [d[0], d[1], d[2]]))
            .fold(f64::INFINITY, f64::min);
        assert_eq!(out.true_range[i], brute, "beam {i}");
    }
}

#[test]
fn motion_distortion_matches_constant_velocity() {
    // Wall 10 m ahead; sensor drives at 5 m/s towards it; beam i fires at t_i.
    let scene = row(KIND_WALL, &[10.0, -50.0, 10.0, 50.0, -1.0, 1.0], [0.0; 3]);
    let v = 5.0;
    let eye = [
        1.0, 0., 0., 0., 0., 1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1.,
    ];
    let motion = Motion::new(&[0.0, 1.0], &eye, &[v, 0.0, 0.0, 0.0, 0.0, 0.0]).unwrap();
    let times: Vec<f64> = (0..11).map(|i| i as f64 * 0.01).collect();
    let dirs: Vec<f64> = times.iter().flat_map(|_| [1.0, 0.0, 0.0]).collect();
    let beams = Beams {
        directions: &dirs,
        time_offsets: &times,
    };
    let out = cast(&scene, beams, 0.0, &motion, 0.0, &exact(80.0)).unwrap();
    for (i, t) in times.iter().enumerate() {
        assert!((out.range[i] - (10.0 - v * t)).abs() < 1e-12);
        // Deskewed into the start frame every point lies on the wall at x = 10.
        assert!((out.points_reference[3 * i] - 10.0).abs() < 1e-12);
    }
}

#[test]
fn moving_primitive_is_hit_where_it_is_at_firing_time() {
    // A sphere at x = 5 moving away at 2 m/s, hit by beams at t = 0 and t = 0.5.
    let scene = row(KIND_SPHERE, &[5.0, 0.0, 0.0, 0.5], [2.0, 0.0, 0.0]);
    let dirs = [1.0, 0.0, 0.0, 1.0, 0.0, 0.0];
    let beams = Beams {
        directions: &dirs,
        time_offsets: &[0.0, 0.5],
    };
    let out = cast(&scene, beams, 10.0, &still(), 10.0, &exact(80.0)).unwrap();
    assert!((out.true_range[0] - 4.5).abs() < 1e-12);
    assert!((out.true_range[1] - 5.5).abs() < 1e-12);
}

#[test]
fn noise_dropout_and_limits() {
    let n = 20_000;
    let (_, dirs, times) = planar_beams(n);
    let model = RangeModel {
        min_range: 0.0,
        max_range: 50.0,
        range_sigma: 0.03,
        dropout_probability: 0.1,
        seed: 5,
    };
    let beams = Beams {
        directions: &dirs,
        time_offsets: &times,
    };
    let out = cast(&square_room(4.0), beams, 0.0, &still(), 0.0, &model).unwrap();
    let errs: Vec<f64> = (0..n)
        .filter(|&i| out.status[i] == STATUS_VALID)
        .map(|i| out.range[i] - out.true_range[i])
        .collect();
    let m = errs.len() as f64;
    let mean = errs.iter().sum::<f64>() / m;
    let std = (errs.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (m - 1.0)).sqrt();
    // ~18k samples: relative standard error of the std is 1/sqrt(2m) = 0.5 %; allow 3 %.
    assert!((std / 0.03 - 1.0).abs() < 0.03, "std {std}");
    assert!(mean.abs() < 0.0015, "mean {mean}");
    let dropped = out.status.iter().filter(|s| **s == STATUS_DROPOUT).count() as f64 / n as f64;
    // Binomial standard error sqrt(0.09 / 20000) = 0.002.
    assert!((dropped - 0.1).abs() < 0.01, "dropout rate {dropped}");
    // Short max range: the corners are beyond it.
    let beams = Beams {
        directions: &dirs,
        time_offsets: &times,
    };
    let out = cast(&square_room(4.0), beams, 0.0, &still(), 0.0, &exact(5.0)).unwrap();
    for i in 0..n {
        let valid = out.status[i] == STATUS_VALID;
        assert_eq!(valid, out.true_range[i] <= 5.0);
        assert_eq!(out.range[i].is_nan(), !valid);
    }
    let model = RangeModel {
        min_range: 4.5,
        ..exact(50.0)
    };
    let out = cast(&square_room(4.0), beams, 0.0, &still(), 0.0, &model).unwrap();
    assert!(out.status.contains(&STATUS_TOO_CLOSE) && out.status.contains(&STATUS_VALID));
}

#[test]
fn output_is_independent_of_thread_count() {
    let n = 5000;
    let (_, dirs, times) = planar_beams(n);
    let mut scene = square_room(6.0);
    scene.extend(row(
        KIND_CYLINDER,
        &[1.0, 1.0, -1.0, 1.0, 0.3],
        [0.5, 0.0, 0.0],
    ));
    let model = RangeModel {
        range_sigma: 0.02,
        dropout_probability: 0.05,
        ..exact(30.0)
    };
    let run = || {
        let beams = Beams {
            directions: &dirs,
            time_offsets: &times,
        };
        cast(&scene, beams, 0.0, &still(), 0.0, &model).unwrap()
    };
    let pool = |k| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(k)
            .build()
            .unwrap()
    };
    let one = pool(1).install(run);
    let many = pool(3).install(run);
    assert_eq!(one.status, many.status);
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&one.range), bits(&many.range));
    let other = cast(
        &scene,
        Beams {
            directions: &dirs,
            time_offsets: &times,
        },
        0.0,
        &still(),
        0.0,
        &RangeModel { seed: 2, ..model },
    )
    .unwrap();
    assert_ne!(bits(&one.range), bits(&other.range));
}

#[test]
fn rejects_hostile_input() {
    let (_, dirs, times) = planar_beams(4);
    let beams = Beams {
        directions: &dirs,
        time_offsets: &times,
    };
    let scene = square_room(1.0);
    let err = |m: RangeModel| {
        cast(&scene, beams, 0.0, &still(), 0.0, &m)
            .unwrap_err()
            .to_string()
    };
    assert!(err(RangeModel {
        max_range: f64::NAN,
        ..exact(1.0)
    })
    .starts_with("max_range"));
    assert!(err(RangeModel {
        min_range: 2.0,
        ..exact(1.0)
    })
    .starts_with("min_range"));
    assert!(err(RangeModel {
        range_sigma: -1.0,
        ..exact(1.0)
    })
    .starts_with("range_sigma"));
    assert!(err(RangeModel {
        dropout_probability: 1.5,
        ..exact(1.0)
    })
    .starts_with("dropout_probability"));
    let bad_dirs = [2.0, 0.0, 0.0];
    let e = cast(
        &scene,
        Beams {
            directions: &bad_dirs,
            time_offsets: &[0.0],
        },
        0.0,
        &still(),
        0.0,
        &exact(1.0),
    )
    .unwrap_err()
    .to_string();
    assert!(e.starts_with("directions"), "{e}");
    let e = cast(
        &scene,
        Beams {
            directions: &dirs[..3],
            time_offsets: &[f64::NAN],
        },
        0.0,
        &still(),
        0.0,
        &exact(1.0),
    )
    .unwrap_err()
    .to_string();
    assert!(e.starts_with("time_offsets"), "{e}");
    let e = cast(&scene, beams, f64::INFINITY, &still(), 0.0, &exact(1.0)).unwrap_err();
    assert!(e.to_string().starts_with("start_time"));
}
