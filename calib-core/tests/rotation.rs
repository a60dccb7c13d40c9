//! The full K from rotation constraints on synthetic hand-held moves generated here (no
//! simulator): exact recovery with no servo at all, independence from the Gauss–Newton start,
//! moves about one axis named, and bad moves rejected and counted.
//!
//! World frame W: z up; at rest the accelerometer measures `R_WBᵀ z` (1 g). A move slerps the
//! board between two attitudes with smooth-step timing; the raw gyro is `K⁻¹ ω_B`, `ω_B` the mean
//! rate over each sample interval (a MEMS gyro's decimated output).

use calib_core::estimators::bias::RestBias;
use calib_core::estimators::full::{Axes, FullLimits};
use calib_core::estimators::rotation::{
    PoseRest, Rejected, RotationLimits, Rotations, RowSum, EARTH_RATE_RAD_S, MAX_ROTATION_MOVES, MAX_ROTATION_POSES,
};
use calib_core::math::lsq::NormalEquations;
use calib_core::{Error, Time};
use nalgebra::{Matrix3, UnitQuaternion, Vector3};

type V3 = Vector3<f64>;

/// `diag(1.02, 0.97, 1.01)` with fixed off-diagonals of up to 1 %.
fn k_true() -> Matrix3<f64> {
    Matrix3::new(1.02, 0.008, -0.006, -0.01, 0.97, 0.004, 0.007, -0.009, 1.01)
}

fn vec_k(k: &Matrix3<f64>) -> [f64; 9] {
    core::array::from_fn(|i| k[(i % 3, i / 3)])
}

/// `n` attitudes about varied axes (or, `one_axis`, all about body x).
fn attitudes(one_axis: bool, n: usize) -> Vec<UnitQuaternion<f64>> {
    (0..n)
        .map(|i| {
            let a = i as f64;
            if one_axis {
                UnitQuaternion::from_euler_angles(0.7 * a + 0.3, 0.0, 0.0)
            } else {
                UnitQuaternion::from_euler_angles(0.9 * a, 0.6 * (a * 1.7).sin(), 1.3 * a)
            }
        })
        .collect()
}

/// Records poses and the moves between them at `hz` into `r`, with `rate` times the nominal
/// angular rate; pose `bad_bias` (if any) sees a gyro offset; no bias.
fn record<const M: usize, const C: usize, const P: usize>(
    r: &mut Rotations<M, C, P>,
    atts: &[UnitQuaternion<f64>],
    hz: f64,
    rate: f64,
    bad_bias: Option<usize>,
) -> Vec<Result<(), Rejected>> {
    record_drifting(r, atts, hz, rate, bad_bias, &|_| 0.0, false)
}

/// [`record`] with a bias `bias(t)` (°/s, every axis) that each pose's rest measures, or that a
/// `predicted` pose takes from t = 0 (its temperature, [`PoseRest::warm_c`], being `bias(t)`).
fn record_drifting<const M: usize, const C: usize, const P: usize>(
    r: &mut Rotations<M, C, P>,
    atts: &[UnitQuaternion<f64>],
    hz: f64,
    rate: f64,
    bad_bias: Option<usize>,
    bias: &dyn Fn(f64) -> f64,
    predicted: bool,
) -> Vec<Result<(), Rejected>> {
    let kinv = k_true().try_inverse().unwrap();
    let lim = RotationLimits::DEFAULT;
    let mut out = vec![];
    let mut t = 0.0;
    let pose = |r: &mut Rotations<M, C, P>, q: &UnitQuaternion<f64>, i: usize, t: f64| {
        let a = q.inverse() * V3::z();
        let off = if bad_bias == Some(i) { 0.5 } else { 0.0 };
        // A predicted pose (a hand's shaky one) gets the bias of t = 0 until it is settled; its
        // temperature is the bias's curve's (°C = °/s here: a tempco of 1 °/s/°C).
        let b = if predicted { bias(0.0) as f32 } else { bias(t) as f32 };
        let rest = RestBias::new(Time::from_s(t).unwrap(), Time::from_s(t).unwrap(), [off + b, b, b], [0.0; 3]);
        let warm_c = if predicted { bias(t) as f32 } else { f32::NAN };
        r.push_pose([a[0] as f32, a[1] as f32, a[2] as f32], 1e-5, PoseRest { bias: rest, predicted, warm_c, ..PoseRest::default() })
            .unwrap()
    };
    let mut prev = pose(r, &atts[0], 0, t);
    for (i, w) in atts.windows(2).enumerate() {
        let (qa, qb) = (w[0], w[1]);
        let dur = 1.5 / rate;
        let n = (dur * hz) as usize;
        r.begin(prev);
        let att = |x: f64| qa.slerp(&qb, x * x * (3.0 - 2.0 * x));
        for s in 0..=n + 1 {
            // The mean body rate over the sample interval, as a MEMS gyro's decimation filter
            // outputs it (0 at the move's first and last samples: the board rests at its poses).
            let (x0, x) = ((s.max(1) - 1).min(n) as f64 / n as f64, s.min(n) as f64 / n as f64);
            let omega = (att(x0).inverse() * att(x)).scaled_axis() * hz;
            let g = kinv * omega.map(f64::to_degrees) + V3::repeat(bias(t));
            r.add(Time::from_s(t).unwrap(), [g[0] as f32, g[1] as f32, g[2] as f32], false);
            t += 1.0 / hz;
        }
        let next = pose(r, &qb, i + 1, t - 1.0 / hz);
        out.push(r.end(next, &lim));
        prev = next;
    }
    out
}

#[test]
fn hand_held_moves_alone_give_the_full_k_whatever_the_start() {
    let mut r = <Rotations>::new();
    assert!(record(&mut r, &attitudes(false, 10), 952.0, 1.0, None).iter().all(|m| m.is_ok()));
    let with = Some((&r, &RotationLimits::DEFAULT));
    let truth = k_true();
    let mut results = vec![];
    for start in [None, Some(vec_k(&Matrix3::identity())), Some(vec_k(&(truth * 1.08))), Some(vec_k(&(truth * 0.93)))] {
        let cal = Axes::new().solve_from(&FullLimits::DEFAULT, with, start).expect("the full K");
        let k = Matrix3::from_fn(|i, j| cal.k[i][j] as f64);
        let e = (k * truth.try_inverse().unwrap() - Matrix3::identity()).amax();
        assert!(e < 2e-5, "start {start:?}: E {e:.2e}");
        assert!(
            cal.iterations < calib_core::estimators::full::GAUSS_NEWTON_ITERATIONS && cal.rotation_moves == 9,
            "{} iterations, {} moves",
            cal.iterations,
            cal.rotation_moves
        );
        results.push(k);
    }
    for k in &results[1..] {
        assert!((k - results[0]).amax() < 1e-6, "the result moved with the start: {:.2e}", (k - results[0]).amax());
    }
}

#[test]
fn rows_added_a_batch_at_a_time_are_the_rows_added_at_once_bit_for_bit() {
    // The firmware's solve adds the rotation rows in calls of bounded length: any batch size
    // gives the very same normal equations and residual sums.
    let mut r = <Rotations>::new();
    assert!(record(&mut r, &attitudes(false, 10), 952.0, 1.0, None).iter().all(|m| m.is_ok()));
    let (k, limits) = (vec_k(&(k_true() * 1.01)), RotationLimits::DEFAULT);
    let mut once = NormalEquations::<9>::new();
    let sums = r.add_rows(&mut once, &k, &limits).unwrap();
    let chunks: usize = r.moves().iter().map(|m| m.chunks()).sum();
    assert!(chunks > 40, "{chunks} chunks");
    for max_chunks in [1, 7, 40, usize::MAX] {
        let (mut ne, mut sum, mut calls) = (NormalEquations::<9>::new(), RowSum::new(), 0);
        let end = loop {
            if let Some(end) = r.add_rows_batch(&mut ne, &mut sum, &k, &limits, max_chunks).unwrap() {
                break end;
            }
            calls += 1;
            assert!(calls <= chunks, "no end");
        };
        assert_eq!(end, sums, "batches of {max_chunks} chunks");
        assert_eq!(ne, once, "batches of {max_chunks} chunks");
        assert!(max_chunks == usize::MAX || calls >= chunks / max_chunks.max(40) / 2, "{calls} calls");
    }
}

#[test]
fn a_store_sized_for_a_whole_log_keeps_every_move_the_firmwares_has_no_room_for() {
    // 40 poses, 39 moves: the firmware's store holds 32 poses and keeps at most 24 of the moves
    // between them (its RAM; here its chunks may run out first); a PC's store sized for the log
    // keeps them all.
    let atts = attitudes(false, 40);
    let mut board = <Rotations>::new();
    let no_room = record(&mut board, &atts[..MAX_ROTATION_POSES], 238.0, 1.0, None).iter().filter(|m| **m == Err(Rejected::Full)).count();
    println!("MEASURED the firmware's store: {no_room} of {} moves without room", MAX_ROTATION_POSES - 1);
    assert!(no_room >= MAX_ROTATION_POSES - 1 - MAX_ROTATION_MOVES, "{no_room}");
    assert_eq!(
        board.push_pose([0.0, 0.0, 1.0], 1e-5, PoseRest::default()),
        Err(Error::CapacityExceeded { max: MAX_ROTATION_POSES as u8 }),
        "a pose beyond the store is refused, named"
    );
    let mut pc = Rotations::<64, 8192, 64>::new();
    assert!(record(&mut pc, &atts, 238.0, 1.0, None).iter().all(|m| m.is_ok()));
    let cal = Axes::new().solve_with(&FullLimits::DEFAULT, Some((&pc, &RotationLimits::DEFAULT))).expect("the full K");
    assert_eq!(cal.rotation_moves, 39);
    let e = (Matrix3::from_fn(|i, j| cal.k[i][j] as f64) * k_true().try_inverse().unwrap() - Matrix3::identity()).amax();
    assert!(e < 2e-5, "E {e:.2e}");
}

#[test]
fn a_bias_that_drifts_between_the_rests_is_tracked() {
    // 0.3 °/s per minute on every axis: 7.5e-3 ° over a 1.5 s move if it were left in.
    let truth = k_true();
    let solve = |drift: f64| {
        let mut r = <Rotations>::new();
        assert!(record_drifting(&mut r, &attitudes(false, 10), 238.0, 1.0, None, &|t| drift * t, false).iter().all(|m| m.is_ok()));
        let cal = Axes::new().solve_with(&FullLimits::DEFAULT, Some((&r, &RotationLimits::DEFAULT))).expect("the full K");
        let k = Matrix3::from_fn(|i, j| cal.k[i][j] as f64);
        (k * truth.try_inverse().unwrap() - Matrix3::identity()).amax()
    };
    let (still, drifting) = (solve(0.0), solve(0.005));
    assert!(drifting < 2e-5 && (drifting - still).abs() < 5e-6, "E {drifting:.2e} drifting vs {still:.2e} without");
}

#[test]
fn moves_about_one_axis_are_named() {
    let mut r = <Rotations>::new();
    record(&mut r, &attitudes(true, 10), 238.0, 1.0, None);
    let e = Axes::new().solve_with(&FullLimits::DEFAULT, Some((&r, &RotationLimits::DEFAULT))).unwrap_err();
    assert!(matches!(e, Error::RotationAxesCoplanar { .. }), "{e:?}");
}

#[test]
fn brisk_moves_are_integrated_and_only_steps_beyond_the_limit_are_rejected() {
    // 10× the rate at 59.5 Hz: 0.15 s moves of up to ~1000 °/s, ~17° between two samples (a
    // brisk hand at a low rate): kept, and the full K as accurate as from slow moves.
    let mut r = <Rotations>::new();
    let out = record(&mut r, &attitudes(false, 10), 59.5, 10.0, None);
    assert!(out.iter().all(|m| m.is_ok()), "{out:?}");
    let cal = Axes::new().solve_with(&FullLimits::DEFAULT, Some((&r, &RotationLimits::DEFAULT))).expect("the full K");
    let k = Matrix3::from_fn(|i, j| cal.k[i][j] as f64);
    let e = (k * k_true().try_inverse().unwrap() - Matrix3::identity()).amax();
    assert!(e < 1e-4, "brisk moves: E {e:.2e}");
    // 15× at 59.5 Hz: steps beyond 20° per sample (fewer than 3 samples per radian): rejected,
    // counted, and the worst step named.
    let mut r = <Rotations>::new();
    let out = record(&mut r, &attitudes(false, 10), 59.5, 15.0, None);
    assert!(out.contains(&Err(Rejected::TooFast)), "{out:?}");
    assert_eq!(r.rejected()[Rejected::TooFast as usize] as usize, out.iter().filter(|m| m.is_err()).count());
    assert!(r.worst()[Rejected::TooFast as usize] > 20.0);
    // A pose whose still gyro mean is off by 0.5 °/s: both of its moves are rejected.
    let mut r = <Rotations>::new();
    let out = record(&mut r, &attitudes(false, 10), 238.0, 1.0, Some(4));
    assert_eq!(out.iter().filter(|m| **m == Err(Rejected::BiasDrifted)).count(), 2, "{out:?}");
    assert_eq!(r.moves().len(), 7);
    // A saturated sample.
    let mut r = <Rotations>::new();
    r.push_pose([0.0, 0.0, 1.0], 1e-4, RestBias::default()).unwrap();
    r.push_pose([0.0, 1.0, 0.0], 1e-4, RestBias::default()).unwrap();
    r.begin(0);
    r.add(Time::from_s(0.0).unwrap(), [90.0, 0.0, 0.0], false);
    r.add(Time::from_s(0.01).unwrap(), [90.0, 0.0, 0.0], true);
    assert_eq!(r.end(1, &RotationLimits::DEFAULT), Err(Rejected::Saturated));
}

/// The end of [`record_drifting`]'s nine moves between the varied attitudes at 238 Hz, nominal rate (s).
const NINE_MOVES_END_S: f64 = 9.0 * (1.5 * 238.0 + 2.0) / 238.0;

/// The largest element of `E` of the full `K` the moves of `r` give alone.
fn largest_error(r: &Rotations) -> f64 {
    let cal = Axes::new().solve_from(&FullLimits::DEFAULT, Some((r, &RotationLimits::DEFAULT)), None).expect("the full K");
    let k = Matrix3::from_fn(|i, j| cal.k[i][j] as f64);
    (k * k_true().try_inverse().unwrap() - Matrix3::identity()).amax()
}

#[test]
fn predicted_pose_biases_settled_between_two_rests_give_the_drifting_bias_back() {
    // The bias drifts 0.02 deg/s per s; every pose's bias is a stale prediction (that of t = 0)
    // until two measured rests around them settle it on their line, which is the truth here.
    let drift = 0.02;
    let mut r = <Rotations>::new();
    assert!(record_drifting(&mut r, &attitudes(false, 10), 238.0, 1.0, None, &|t| drift * t, true).iter().all(|m| m.is_ok()));
    let stale = largest_error(&r);
    let (before, after) = (
        RestBias { t: Time::from_s(-1.0).unwrap(), residual_dps: [-0.02; 3] },
        RestBias { t: Time::from_s(NINE_MOVES_END_S + 1.0).unwrap(), residual_dps: [(drift * (NINE_MOVES_END_S + 1.0)) as f32; 3] },
    );
    r.settle_bias(&before, &after, None, [f32::NAN; 2]);
    let settled = largest_error(&r);
    println!("MEASURED stale predictions E {stale:.2e}, settled {settled:.2e}");
    assert!(stale > 1e-3 && settled < 2e-5, "stale {stale:.2e}, settled {settled:.2e}");
    // Settled once: a second pair of rests changes nothing.
    r.settle_bias(&RestBias { t: Time::from_s(-1.0).unwrap(), residual_dps: [5.0; 3] }, &after, None, [f32::NAN; 2]);
    assert_eq!(largest_error(&r), settled);
}

#[test]
fn settled_biases_follow_a_warm_up_by_the_temperature() {
    // The bias follows the temperature, which rises along 1 − e^(−t/τ): a line in time between
    // the two rests misses its curve; the poses' temperatures put it back (what is left: the
    // curve inside each 1.5 s move, ≈ 3e-5 of a turn).
    let curve = |t: f64| 0.3 * (1.0 - (-t / 5.0).exp());
    let mut r = <Rotations>::new();
    assert!(record_drifting(&mut r, &attitudes(false, 10), 238.0, 1.0, None, &curve, true).iter().all(|m| m.is_ok()));
    let rest = |t: f64| RestBias { t: Time::from_s(t).unwrap(), residual_dps: [curve(t) as f32; 3] };
    let temps = [curve(-1.0) as f32, curve(NINE_MOVES_END_S + 1.0) as f32];
    r.settle_bias(&rest(-1.0), &rest(NINE_MOVES_END_S + 1.0), None, temps);
    let on_line = largest_error(&r);
    r.follow_warmup(&[1.0; 3]);
    let followed = largest_error(&r);
    println!("MEASURED warm-up: bias on a line in time E {on_line:.2e}, following the temperature {followed:.2e}");
    assert!(on_line > 1e-3 && followed < 1e-4, "line {on_line:.2e}, followed {followed:.2e}");
    // Once: a second call changes nothing.
    r.follow_warmup(&[1.0; 3]);
    assert_eq!(largest_error(&r), followed);
}

#[test]
fn the_earths_rate_a_shaky_pose_cannot_measure_is_estimated_with_k() {
    // The gyro sees the Earth's rate (latitude 50°, world y north, z up) in every attitude; the
    // hand-held poses are too shaky to measure the bias, so each takes the bias of a rest in
    // the first pose's attitude (holding the Earth's rate of that attitude) until a rest in the
    // last pose's attitude settles them. Slow moves (6 s): the Earth's rate left in is ≈ 0.025°
    // per move, ≈ 3e-4 of K. The data have no noise: each move's integral is weighted as such
    // (0.001°), so that the Earth's rate's prior (|w| = 1) does not hold its estimate back.
    let limits = RotationLimits { gamma_sigma_deg: 0.001, ..RotationLimits::DEFAULT };
    let (lat, hz) = (50f64.to_radians(), 238.0);
    let earth_w = V3::new(0.0, lat.cos(), lat.sin()) * EARTH_RATE_RAD_S.to_degrees();
    let atts = attitudes(false, 10);
    let kinv = k_true().try_inverse().unwrap();
    let in_body = |q: &UnitQuaternion<f64>| q.inverse() * earth_w;
    let f32s = |v: V3| [v[0] as f32, v[1] as f32, v[2] as f32];
    let solve = |attitudes: bool| {
        let mut r = <Rotations>::new();
        let first = in_body(&atts[0]);
        // Frame 0 is the first rest's (the first pose's attitude).
        let frame = |q: &UnitQuaternion<f64>| (atts[0].inverse() * q).to_rotation_matrix().into_inner().map(|v| v as f32);
        let mut t = 0.0;
        let push = |r: &mut Rotations, q: &UnitQuaternion<f64>, t: f64| {
            let a = q.inverse() * V3::z();
            let rest = RestBias::new(Time::from_s(t).unwrap(), Time::from_s(t).unwrap(), f32s(first), [0.0; 3]);
            let i = r.push_pose(f32s(a), 1e-5, PoseRest { bias: rest, predicted: true, ..PoseRest::default() }).unwrap();
            if attitudes {
                r.push_attitude(i, frame(q));
            }
            i
        };
        let mut prev = push(&mut r, &atts[0], t);
        for w in atts.windows(2) {
            let (qa, qb) = (w[0], w[1]);
            let n = (6.0 * hz) as usize;
            r.begin(prev);
            let att = |x: f64| qa.slerp(&qb, x * x * (3.0 - 2.0 * x));
            for s in 0..=n + 1 {
                let (x0, x) = ((s.max(1) - 1).min(n) as f64 / n as f64, s.min(n) as f64 / n as f64);
                let omega = (att(x0).inverse() * att(x)).scaled_axis() * hz;
                let g = kinv * (omega.map(f64::to_degrees) + in_body(&att(x)));
                r.add(Time::from_s(t).unwrap(), f32s(g), false);
                t += 1.0 / hz;
            }
            let next = push(&mut r, &qb, t - 1.0 / hz);
            assert_eq!(r.end(next, &limits), Ok(()));
            prev = next;
        }
        let last = atts.last().unwrap();
        let (before, after) = (
            RestBias::new(Time::from_s(-1.0).unwrap(), Time::from_s(-1.0).unwrap(), f32s(first), [0.0; 3]),
            RestBias::new(Time::from_s(t + 1.0).unwrap(), Time::from_s(t + 1.0).unwrap(), f32s(in_body(last)), [0.0; 3]),
        );
        r.settle_bias(&before, &after, attitudes.then(|| frame(last)), [f32::NAN; 2]);
        let cal = Axes::new().solve_with(&FullLimits::DEFAULT, Some((&r, &limits))).expect("the full K");
        let k = Matrix3::from_fn(|i, j| cal.k[i][j] as f64);
        (k * k_true().try_inverse().unwrap() - Matrix3::identity()).amax()
    };
    let (without, with) = (solve(false), solve(true));
    println!("MEASURED the Earth's rate left in: E {without:.2e}; estimated with K: {with:.2e}");
    assert!(without > 1e-4 && with < 0.1 * without, "E {without:.2e} without the attitudes, {with:.2e} with");
}
