//! Property tests of the gyro and accelerometer estimators on analytic, noise-free rig data:
//! exact recovery whatever the mounting and tilt, and each degenerate geometry named.

use calib_core::estimators::accel::AccelCalibrator;
use calib_core::estimators::axis::{GeometryLimits, Poses};
use calib_core::estimators::sweep::{Integrator, Moves};
use calib_core::estimators::{paper, sweep};
use calib_core::{Error, Vec3};
use nalgebra::{Rotation3, Unit, Vector3};
use proptest::prelude::*;
use rig_sim::harness::at;

/// Specific force (g, B) at shaft angle `th` (rad) for axis `u` (B) tilted `tilt` (rad) from vertical.
fn pose(u: &Vector3<f64>, tilt: f64, th: f64) -> Vector3<f64> {
    let e1 = u.cross(&Vector3::new(0.31, -0.52, 0.79)).normalize();
    let up0 = Rotation3::from_axis_angle(&Unit::new_normalize(e1), -tilt) * u;
    // The shaft turning by +th turns the world (gravity) by −th as seen in B.
    Rotation3::from_axis_angle(&Unit::new_normalize(*u), -th) * up0
}

fn f32v(v: Vector3<f64>) -> Vec3 {
    [v[0] as f32, v[1] as f32, v[2] as f32]
}

fn axis_strategy() -> impl Strategy<Value = Vector3<f64>> {
    (0.0..std::f64::consts::TAU, -0.8f64..0.8, prop::bool::ANY, prop::bool::ANY).prop_filter_map(
        "every component ≥ 0.2",
        |(az, z, sx, sy)| {
            let r = (1.0 - z * z).sqrt();
            let mut u = Vector3::new(r * az.cos(), r * az.sin(), z);
            if sx {
                u.x = -u.x;
            }
            if sy {
                u.y = -u.y;
            }
            (u.iter().all(|c| c.abs() >= 0.2)).then_some(u)
        },
    )
}

struct Rig {
    poses: Poses,
    moves: Moves,
}

/// Static poses every `step` degrees and moves back and forth between consecutive ones;
/// `Γ = K⁻¹ Δθ u` (the raw gyro integral of a diagonal-K gyro).
fn rig(u: &Vector3<f64>, tilt: f64, k: &Vector3<f64>, n: usize, step_deg: f64) -> Rig {
    let mut poses = Poses::new();
    let mut moves = Moves::new();
    for i in 0..n {
        poses.push(f32v(pose(u, tilt, (i as f64 * step_deg).to_radians()))).unwrap();
    }
    for i in 0..n - 1 {
        for (from, to, sign) in [(i, i + 1, 1.0), (i + 1, i, -1.0)] {
            let g = u.component_div(k) * (sign * step_deg);
            moves.push(from as u8, to as u8, [g[0], g[1], g[2]]).unwrap();
        }
    }
    Rig { poses, moves }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn sweep_recovers_k_for_any_mount_and_tilt(
        u in axis_strategy(), tilt_deg in 15.0f64..85.0,
        kx in 0.9f64..1.1, ky in 0.9f64..1.1, kz in 0.9f64..1.1, n in 4usize..10,
    ) {
        let k = Vector3::new(kx, ky, kz);
        let r = rig(&u, tilt_deg.to_radians(), &k, n, 150.0 / (n - 1) as f64);
        let cal = sweep::solve(&r.poses, &r.moves, &GeometryLimits::default()).unwrap();
        for i in 0..3 {
            prop_assert!(((cal.k[i][i] as f64) / k[i] - 1.0).abs() < 2e-5, "{:?} vs {:?}", cal.k, k);
        }
        prop_assert!(cal.quality.invariant_after.relative_std() < 1e-4);
    }

    #[test]
    fn paper_recovers_k_with_exact_speed(
        u in axis_strategy(), tilt_deg in 15.0f64..75.0,
        kx in 0.9f64..1.1, ky in 0.9f64..1.1, kz in 0.9f64..1.1, w in 5.0f64..60.0,
    ) {
        let k = Vector3::new(kx, ky, kz);
        let r = rig(&u, tilt_deg.to_radians(), &k, 8, 20.0);
        let gbar = u.component_div(&k) * w;
        let cal = paper::solve(&r.poses, f32v(gbar), w as f32, &GeometryLimits::default()).unwrap();
        for i in 0..3 {
            prop_assert!(((cal.k[i][i] as f64) / k[i] - 1.0).abs() < 2e-5, "{:?} vs {:?}", cal.k, k);
        }
        // A speed error goes straight into K (the reason for the sweep estimator).
        let biased = paper::solve(&r.poses, f32v(gbar), (w * 1.03) as f32, &GeometryLimits::default()).unwrap();
        prop_assert!(((biased.k[0][0] as f64) / k[0] - 1.03).abs() < 1e-4);
    }

    #[test]
    fn accel_six_param_recovers_any_gains_and_offsets(
        kx in 0.95f64..1.05, ky in 0.95f64..1.05, kz in 0.95f64..1.05,
        ox in -0.05f64..0.05, oy in -0.05f64..0.05, oz in -0.05f64..0.05, roll in 0.0f64..std::f64::consts::TAU,
    ) {
        let (m, o) = (Vector3::new(kx, ky, kz), Vector3::new(ox, oy, oz));
        let mut c = <AccelCalibrator>::new();
        let rot = Rotation3::from_euler_angles(roll, 0.3, -0.2);
        for f in [Vector3::x(), -Vector3::x(), Vector3::y(), -Vector3::y(), Vector3::z(), -Vector3::z()] {
            let f = rot * f;
            c.add_pose(f32v(f.component_div(&m) + o)).unwrap();
        }
        let cal = c.solve6().unwrap();
        // Six poses along a rotated frame can make the diagonal model nearly singular (the
        // squared direction cosines nearly dependent): the f32 readings' rounding then reaches
        // the gains through the fit's own condition number, which it reports. 1e-5 where it is
        // well conditioned, the rounding bound where it says it is not.
        let bound = 1e-5f64.max(f64::from(cal.condition).sqrt() * f64::from(f32::EPSILON));
        for i in 0..3 {
            prop_assert!(
                (cal.m[i][i] as f64 - m[i]).abs() < bound && (cal.offset_g[i] as f64 - o[i]).abs() < bound,
                "{:?} {:?} vs {m:?} {o:?}, condition {}", cal.m, cal.offset_g, cal.condition
            );
        }
    }
}

fn good_axis() -> Vector3<f64> {
    Vector3::new(0.45, -0.55, 0.7).normalize()
}

#[test]
fn sweep_degenerate_inputs_are_named_errors() {
    let k = Vector3::new(1.02, 0.98, 1.01);
    let lim = GeometryLimits::default();
    let vertical = rig(&good_axis(), 2f64.to_radians(), &k, 6, 30.0);
    assert!(matches!(sweep::solve(&vertical.poses, &vertical.moves, &lim), Err(Error::AxisNearVertical { .. })));
    let short = rig(&good_axis(), 0.7, &k, 6, 4.0);
    assert!(matches!(sweep::solve(&short.poses, &short.moves, &lim), Err(Error::AngleSpanTooSmall { .. })));
    let few = rig(&good_axis(), 0.7, &k, 3, 45.0);
    assert!(matches!(sweep::solve(&few.poses, &few.moves, &lim), Err(Error::TooFewPoses { have: 3, need: 4 })));
    let weak = rig(&Vector3::new(0.02, 0.6, 0.8).normalize(), 0.7, &k, 6, 30.0);
    assert!(matches!(sweep::solve(&weak.poses, &weak.moves, &lim), Err(Error::WeakSensorAxis { axis: 0, .. })));
    let good = rig(&good_axis(), 0.7, &k, 6, 30.0);
    assert_eq!(sweep::solve(&good.poses, &Moves::new(), &lim), Err(Error::NoUsableMove));
    // A gyro that reads nothing while the accelerometer saw the turns: no plausible K.
    let mut dead = Moves::new();
    dead.push(0, 3, [0.0; 3]).unwrap();
    assert!(matches!(sweep::solve(&good.poses, &dead, &lim), Err(Error::Singular)));
    let mut p = Poses::new();
    assert_eq!(p.push([f32::NAN, 0.0, 1.0]), Err(Error::NonFinite));
}

#[test]
fn paper_degenerate_inputs_are_named_errors() {
    let k = Vector3::new(1.0, 1.0, 1.0);
    let lim = GeometryLimits::default();
    let flat = rig(&good_axis(), 88f64.to_radians(), &k, 6, 30.0);
    let g = f32v(good_axis() * 20.0);
    assert!(matches!(paper::solve(&flat.poses, g, 20.0, &lim), Err(Error::AxisNearHorizontal { .. })));
    // The sweep estimator has no such limit: a horizontal axis is its best case.
    assert!(sweep::solve(&flat.poses, &flat.moves, &lim).is_ok());
    let good = rig(&good_axis(), 0.7, &k, 6, 30.0);
    assert!(matches!(paper::solve(&good.poses, [0.0; 3], 20.0, &lim), Err(Error::NoSpin { .. })));
    assert_eq!(paper::solve(&good.poses, [f32::NAN, 0.0, 0.0], 20.0, &lim), Err(Error::NonFinite));
}

#[test]
fn sweep_handles_turns_beyond_half_a_revolution() {
    // Two poses 120° apart reached by turning 480° (continuous servo): the gyro picks the branch.
    let (u, k) = (good_axis(), Vector3::new(1.05, 0.95, 1.0));
    let mut poses = Poses::new();
    for th in [0.0f64, 120.0, 240.0, 60.0] {
        poses.push(f32v(pose(&u, 0.8, th.to_radians()))).unwrap();
    }
    let mut moves = Moves::new();
    for (from, to, turn) in [(0u8, 1u8, 480.0), (1, 2, 120.0), (2, 3, -180.0 - 360.0), (3, 0, -60.0)] {
        let g = u.component_div(&k) * turn;
        moves.push(from, to, [g[0], g[1], g[2]]).unwrap();
    }
    let cal = sweep::solve(&poses, &moves, &GeometryLimits::default()).unwrap();
    for i in 0..3 {
        assert!(((cal.k[i][i] as f64) / k[i] - 1.0).abs() < 2e-5, "{:?}", cal.k);
    }
}

#[test]
fn integrator_is_the_trapezoid_rule_on_the_mcu_clock() {
    let mut it = Integrator::new();
    // Irregular timestamps: a ramp from 0 to 10 °/s over 1 s integrates to exactly 5°.
    let mut t = 0.0;
    while t <= 1.0 + 1e-12 {
        it.add(at(t), [10.0 * t as f32, 0.0, -20.0 * t as f32]);
        t += if (t * 100.0).round() as i64 % 2 == 0 { 0.003 } else { 0.007 };
    }
    it.add(at(1.0), [10.0, 0.0, -20.0]);
    let g = it.gamma();
    assert!((g[0] - 5.0).abs() < 1e-5 && (g[2] + 10.0).abs() < 2e-5, "{g:?}");
}

fn finite(k: &[[f32; 3]; 3]) -> bool {
    k.iter().flatten().all(|v| v.is_finite())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// Any input, however wild: a finite result or a named error, never a panic or NaN.
    #[test]
    fn arbitrary_input_never_panics_or_gives_nan(
        raw in prop::collection::vec(prop::array::uniform3(any::<f32>()), 0..12),
        small in prop::collection::vec(prop::array::uniform3(-2.0f32..2.0), 0..12),
        gammas in prop::collection::vec((0u8..14, 0u8..14, prop::array::uniform3(-1e4f64..1e4)), 0..20),
        gbar in prop::array::uniform3(any::<f32>()), w in any::<f32>(),
    ) {
        let lim = GeometryLimits::default();
        for set in [&raw, &small] {
            let mut poses = Poses::new();
            let mut acc = <AccelCalibrator>::new();
            for p in set.iter() {
                let _ = poses.push(*p);
                let _ = acc.add_pose(*p);
            }
            let mut moves = Moves::new();
            for (from, to, g) in &gammas {
                moves.push(*from, *to, *g).unwrap();
            }
            if let Ok(c) = sweep::solve(&poses, &moves, &lim) {
                prop_assert!(finite(&c.k));
            }
            if let Ok(c) = paper::solve(&poses, gbar, w, &lim) {
                prop_assert!(finite(&c.k));
            }
            for cal in [acc.solve6(), acc.solve9()].into_iter().flatten() {
                prop_assert!(finite(&cal.m) && cal.offset_g.iter().all(|v| v.is_finite()));
            }
        }
    }

    #[test]
    fn accel_nine_param_recovers_any_triangular_model(
        d in prop::array::uniform3(0.95f64..1.05), off in prop::array::uniform3(-0.01f64..0.01),
        o in prop::array::uniform3(-0.05f64..0.05), roll in 0.0f64..std::f64::consts::TAU,
    ) {
        let m = nalgebra::Matrix3::new(d[0], off[0], off[1], 0.0, d[1], off[2], 0.0, 0.0, d[2]);
        let minv = m.try_inverse().unwrap();
        let rot = Rotation3::from_euler_angles(roll, 0.4, -0.3);
        let mut c = <AccelCalibrator>::new();
        for v in rig_sim::harness::icosahedron() {
            let f = rot * v;
            c.add_pose(f32v(minv * f + Vector3::from(o))).unwrap();
        }
        let cal = c.solve9().unwrap();
        for i in 0..3 {
            for j in 0..3 {
                prop_assert!((cal.m[i][j] as f64 - m[(i, j)]).abs() < 2e-5, "{:?} vs {}", cal.m, m);
            }
            prop_assert!((cal.offset_g[i] as f64 - o[i]).abs() < 2e-5);
        }
    }
}
