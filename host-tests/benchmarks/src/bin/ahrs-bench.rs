//! What the calibration buys a user of a standard AHRS filter: Madgwick's (the `ahrs` crate)
//! fed the same simulated motion — a hand turning the board between random attitudes for 60 s
//! after the calibration — as raw readings, with only the gyro calibrated, with gyro and
//! accelerometer calibrated and the magnetometer's ellipsoid alone (what the usual tools fit),
//! and fully calibrated (`gyrocal-calib`'s `K`, bias, `M` and the magnetometer's `A` with the
//! die's alignment), on one-servo rigs whose calibration log is the scripted protocol's. The
//! heading error of the filter's body x axis against the simulator's truth (in the calibrated
//! accelerometer's frame where that is the filter's frame), after 10 s of settling.
//! `--setup bmi270`: the Rev2's BMI270 and BMM150. `--json`: the last line is a JSON summary.
//!
//! `cargo run --profile host -p benchmarks --target host-tuple --bin ahrs-bench [--rigs N] [--setup S] [--json]`

use ahrs::{Ahrs, Madgwick};
use benchmarks::setup::Setup;
use calib::offline;
use calib_core::math::vec3::{mat_to_real, to_real};
use clap::Parser;
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rig_sim::heading::{calibrated_frame, heading_w};
use rig_sim::pan_tilt;
use rig_sim::sim::Rig;
use serde_json::json;

/// Heading error of an AHRS filter fed raw and calibrated readings.
#[derive(Parser, Debug)]
#[command(name = "ahrs-bench")]
struct Args {
    /// Simulated rigs.
    #[arg(long, default_value_t = 20)]
    rigs: usize,
    /// Random seed.
    #[arg(long, default_value_t = 34)]
    seed: u64,
    /// The simulated sensor and its settings (the Rev2's: `bmi270`).
    #[arg(long, value_enum, default_value = "default")]
    setup: Setup,
    /// Print a JSON summary as the last line.
    #[arg(long)]
    json: bool,
}

/// The motion after the calibration (s), the part scored (from this many s on), Madgwick's gain
/// (rad/s: the `ahrs` crate's and Madgwick's paper's 0.1).
const MOTION_S: f64 = 60.0;
const SETTLE_S: f64 = 10.0;
const BETA: f64 = 0.1;
/// Scored while the body x axis is at most this far above or below the horizon (°).
const ELEVATION_MAX: f64 = 60.0;

/// One way of feeding the filter: the corrections applied to gyro (°/s → rad/s), accelerometer
/// (g) and magnetometer (µT) readings, and the frame the filter's body axes are in (from B).
struct Feed {
    gyro: Box<dyn Fn(Vector3<f64>) -> Vector3<f64>>,
    accel: Box<dyn Fn(Vector3<f64>) -> Vector3<f64>>,
    mag: Box<dyn Fn(Vector3<f64>) -> Vector3<f64>>,
    frame: Matrix3<f64>,
}

/// The feeds of a calibration `c` on `rig` (`None` when it lacks a gyro `K` or a magnetometer).
fn feeds(c: &offline::Calibration, rig: &Rig) -> Option<Vec<Feed>> {
    let k = match (&c.full, &c.gyro) {
        (Some(Ok(f)), _) => f.k,
        (_, Ok(g)) => g.k,
        _ => return None,
    };
    let m = c.mag.as_ref()?;
    let cal = m.cal.as_ref().ok()?;
    let (ea, eo) = m.ellipsoid?;
    let (k, b) = (mat_to_real(&k), to_real(c.bias.bias_dps));
    let (am, ao) = (mat_to_real(&c.accel.m), to_real(c.accel.offset_g));
    let (ma, mo) = (mat_to_real(&cal.a), to_real(cal.offset_ut));
    let (ea, eo) = (mat_to_real(&ea), to_real(eo));
    let q = calibrated_frame(c.accel.m, rig)?;
    let rad = |v: Vector3<f64>| v.map(f64::to_radians);
    Some(vec![
        Feed { gyro: Box::new(rad), accel: Box::new(|a| a), mag: Box::new(|m| m), frame: Matrix3::identity() },
        Feed { gyro: Box::new(move |g| rad(k * (g - b))), accel: Box::new(|a| a), mag: Box::new(|m| m), frame: Matrix3::identity() },
        Feed {
            gyro: Box::new(move |g| rad(k * (g - b))),
            accel: Box::new(move |a| am * (a - ao)),
            mag: Box::new(move |m| ea * (m - eo)),
            frame: q,
        },
        Feed {
            gyro: Box::new(move |g| rad(k * (g - b))),
            accel: Box::new(move |a| am * (a - ao)),
            mag: Box::new(move |m| ma * (m - mo)),
            frame: q,
        },
    ])
}

fn main() {
    let args = Args::parse_from(calib::cli_args());
    println!(
        "ahrs-bench: {} simulated rigs, the {:?} setup, Madgwick (ahrs crate, beta {BETA}) over {MOTION_S} s of hand motion",
        args.rigs, args.setup
    );
    let names = ["raw", "gyro calibrated", "all, magnetometer ellipsoid alone", "fully calibrated"];
    let mut errs: Vec<Vec<f64>> = vec![vec![]; names.len()];
    let mut maxes = vec![0.0f64; names.len()];
    let mut failed = vec![];
    for run in 0..args.rigs {
        let seed = args.seed + run as u64;
        let mut rig = Rig::new(args.setup.rig(pan_tilt::rig_config(args.seed, run), seed), seed);
        let log = pan_tilt::log_at(&mut rig, true, &[0.0]);
        let c = match benchmarks::logs::calibrate(&log) {
            Ok(c) => c,
            Err(e) => {
                failed.push(e);
                continue;
            }
        };
        let Some(feeds) = feeds(&c, &rig) else {
            failed.push(format!("no gyro K or magnetometer calibration: {:?}", c.missing()));
            continue;
        };
        // The hand turns the board between random attitudes: 1–2 s a turn, 0.5–1.5 s held.
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xa5a5);
        let mut filters: Vec<Madgwick<f64>> = feeds.iter().map(|_| Madgwick::new(1.0 / rig.truth().odr_hz, BETA)).collect();
        let (mut last_mag, mut next_turn, mut started) = (None, 0.0, vec![false; feeds.len()]);
        let t0 = rig.truth().t_s;
        while rig.truth().t_s - t0 < MOTION_S {
            let t = rig.truth().t_s - t0;
            if t >= next_turn {
                let g: [f64; 4] = std::array::from_fn(|_| rng.sample(StandardNormal));
                let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(g[0], g[1], g[2], g[3]));
                let turn = rng.random_range(1.0..2.0);
                rig.detach_to(q, turn);
                next_turn = t + turn + rng.random_range(0.5..1.5);
            }
            let s = rig.next_sample();
            last_mag = s.mag_ut.map(to_real).or(last_mag);
            let Some(m) = last_mag else { continue };
            let truth = rig.truth();
            let field_w = truth.mag.map(|m| m.field_w).unwrap_or_default();
            for (k, (feed, f)) in feeds.iter().zip(filters.iter_mut()).enumerate() {
                if !started[k] {
                    // Started where its own first readings put it (TRIAD, as AHRS users do).
                    let (a, m) = ((feed.accel)(to_real(s.accel_g)), (feed.mag)(m));
                    let up = a.normalize();
                    let north = (m - up * m.dot(&up)).normalize();
                    let r = Matrix3::from_rows(&[north.transpose(), up.cross(&north).transpose(), up.transpose()]);
                    f.quat = UnitQuaternion::from_matrix(&r);
                    started[k] = true;
                }
                let _ = f.update(&(feed.gyro)(to_real(s.gyro_dps)), &(feed.accel)(to_real(s.accel_g)), &(feed.mag)(m));
                if truth.t_s - t0 < SETTLE_S {
                    continue;
                }
                // The filter's body x axis, in B then W; the filter's earth frame is NWU.
                let x_b = feed.frame.transpose() * Vector3::x();
                let v = f.quat * Vector3::x();
                let x_w = truth.q_wb * x_b;
                // A heading of x is defined while x is off the vertical (here: by 30° at least).
                if x_w[2].abs() > ELEVATION_MAX.to_radians().sin() {
                    continue;
                }
                let (Some(want), est) = (heading_w(&x_w, &field_w), (-v[1]).atan2(v[0]).to_degrees()) else { continue };
                let e = (est - want + 540.0).rem_euclid(360.0) - 180.0;
                errs[k].push(e);
                maxes[k] = maxes[k].max(e.abs());
            }
        }
    }
    println!("{:<36}{:>14}{:>10}", "fed", "RMS (deg)", "largest");
    let mut rows = vec![];
    for (k, name) in names.iter().enumerate() {
        let rms = (errs[k].iter().map(|e| e * e).sum::<f64>() / errs[k].len().max(1) as f64).sqrt();
        println!("{name:<36}{rms:>14.2}{:>10.2}", maxes[k]);
        rows.push(json!({"fed": name, "rms_deg": rms, "max_deg": maxes[k]}));
    }
    if !failed.is_empty() {
        println!("    failed {}: {failed:?}", failed.len());
    }
    if args.json {
        println!(
            "{}",
            json!({"bench": "ahrs-bench", "seed": args.seed, "rigs": args.rigs, "scored_rigs": args.rigs - failed.len(),
            "failed": failed, "setup": args.setup.json(), "motion_s": MOTION_S, "settle_s": SETTLE_S, "beta": BETA, "rows": rows})
        );
    }
}
