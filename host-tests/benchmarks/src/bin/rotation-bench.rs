//! The full 3×3 gyro K from every rotation a log holds: `calib`'s data-driven path with the
//! rotation constraints of the hand-held moves on and off, on simulated logs of three rigs
//! (gyro cross-axis U(±1 %), accelerometer misalignment U(±0.3 %), servo angle-scale error
//! U(±3 %), LSM9DS1 noise and ODR error): one servo + 12 hand-held poses, pan/tilt + 12
//! hand-held poses, 12 hand-held poses and no servo; and the firmware's own procedure (default
//! configuration, one servo, the simulated operator's 12 to 20 hand-held poses) on the same kind of
//! rigs; the board held by a braced hand (`--hand free|none` for the others). Error
//! `E = Qᵀ K̂ K⁻¹ − I` after aligning the
//! calibrated accelerometer frame to the simulator's. `--json`: the last line is a JSON summary.

use benchmarks::moments::Moments;
use benchmarks::setup::Setup;
use calib::{csvlog, offline};
use calib_core::procedure::{Config, Procedure};
use clap::Parser;
use rig_sim::harness::{run, Faults};
use rig_sim::pan_tilt;
use rig_sim::sim::{HandLevel, Rig, RigConfig};
use serde_json::json;

/// The full K from every rotation in a log.
#[derive(Parser, Debug)]
#[command(name = "rotation-bench")]
struct Args {
    /// Simulated rigs per row.
    #[arg(long, default_value_t = 20)]
    rigs: usize,
    /// Random seed.
    #[arg(long, default_value_t = 2027)]
    seed: u64,
    /// The simulated sensor and its settings (the Rev2's: `bmi270`).
    #[arg(long, value_enum, default_value = "default")]
    setup: Setup,
    /// The hand that holds the board for the hand-held poses: braced (the realistic presets'),
    /// free (in the air), wrist, arm, nod (turning about a pivot away from the sensor:
    /// `rig_sim::sim::HandLevel`) or none (perfectly still).
    #[arg(long, default_value = "braced", value_parser = ["braced", "free", "wrist", "arm", "nod", "none"])]
    hand: String,
    /// Print a JSON summary as the last line.
    #[arg(long)]
    json: bool,
}

/// The three rigs: a log of each from one simulated rig.
fn log_of(rig_kind: usize, rig: &mut Rig) -> String {
    match rig_kind {
        0 => pan_tilt::log_at(rig, true, &[0.0]),
        1 => pan_tilt::log(rig, true),
        // No servo: only the hand-held rows (both servo columns empty) are kept.
        _ => pan_tilt::handheld_only(&pan_tilt::log_at(rig, true, &[])),
    }
}

/// The fractions of elements within 1σ and 2σ from the counts over `rigs` full `K`s.
fn coverage(c: [usize; 2], rigs: usize) -> [f64; 2] {
    c.map(|n| if rigs == 0 { 0.0 } else { n as f64 / (9 * rigs) as f64 })
}

/// [within 1σ, within 2σ, count] of the offline tool's gyro bias (against the truth at the
/// log's end, the instant it is given for), accelerometer offsets and diagonal gains (against
/// the simulator's `M = C_a⁻¹` in the fit's upper-triangular gauge), per axis.
fn covered_bias_accel(c: &offline::Calibration, rig: &Rig) -> [[usize; 3]; 3] {
    let t = rig.truth();
    let u = t.accel_c.try_inverse().and_then(|ca_inv| (ca_inv.transpose() * ca_inv).cholesky()).map(|ch| ch.l().transpose());
    let mut out = [[0usize; 3]; 3];
    for k in 0..3 {
        let s = c.accel_sigma.as_ref();
        let e = [
            Some(((c.bias.bias_dps[k] as f64 - t.gyro_bias_dps[k]).abs(), c.bias.sigma_dps[k] as f64)),
            s.map(|s| ((c.accel.offset_g[k] as f64 - t.accel_offset_g[k]).abs(), s.offset_g[k] as f64)),
            u.zip(s).map(|(u, s)| ((c.accel.m[k][k] as f64 - u[(k, k)]).abs(), s.gain[k] as f64)),
        ];
        for (o, e) in out.iter_mut().zip(e) {
            if let Some((e, s)) = e {
                *o = [o[0] + (e <= s) as usize, o[1] + (e <= 2.0 * s) as usize, o[2] + 1];
            }
        }
    }
    out
}

fn hand_name(hand: Option<HandLevel>) -> &'static str {
    hand.map_or("none", HandLevel::name)
}

fn main() {
    let args = Args::parse_from(calib::cli_args());
    let hand = HandLevel::parse(&args.hand).unwrap_or_default();
    let names = ["one servo + 12 hand-held poses", "pan/tilt + 12 hand-held poses", "12 hand-held poses, no servo"];
    let mut table = vec![];
    println!(
        "rotation-bench: {} simulated rigs per row (gyro cross-axis ±1 %, accel misalignment ±0.3 %, servo ±3 %), the {:?} setup, hand {}",
        args.rigs,
        args.setup,
        hand_name(hand)
    );
    println!("{:<38}{:<24}{:>12}{:>12}{:>7}", "rig", "rotations", "RMS of E", "largest", "rigs");
    for (kind, name) in names.iter().enumerate() {
        for on in [true, false] {
            let (mut rms, mut max, mut failed, mut cover) = (vec![], 0.0f64, vec![], [0usize; 2]);
            let mut ba = [[0usize; 3]; 3];
            for run in 0..args.rigs {
                let cfg = RigConfig { hand, ..args.setup.rig(pan_tilt::rig_config(args.seed + kind as u64, run), args.seed + run as u64) };
                let mut rig = Rig::new(cfg, args.seed + run as u64);
                let log = log_of(kind, &mut rig);
                let c = csvlog::parse(&log)
                    .map_err(|e| e.to_string())
                    .and_then(|l| offline::calibrate_with(&l.rows, None, on).map_err(|e| e.to_string()));
                if let Ok(c) = c.as_ref() {
                    let b = covered_bias_accel(c, &rig);
                    for (x, y) in ba.iter_mut().zip(b) {
                        *x = [x[0] + y[0], x[1] + y[1], x[2] + y[2]];
                    }
                }
                let k = match c.as_ref().map(|c| (c.full.as_ref(), &c.gyro, c.accel.m)) {
                    Ok((Some(Ok(f)), _, m)) => {
                        let [a, b] = pan_tilt::k_error_covered(f.k, f.sigma_k, m, &rig);
                        cover = [cover[0] + a, cover[1] + b];
                        Some((f.k, m))
                    }
                    Ok((_, Ok(g), m)) => Some((g.k, m)),
                    Ok((Some(Err(e)), _, _)) => {
                        failed.push(e.to_string());
                        None
                    }
                    Ok((None, Err(e), _)) => {
                        failed.push(e.to_string());
                        None
                    }
                    Err(e) => {
                        failed.push(e.clone());
                        None
                    }
                };
                if let Some((mx, r)) = k.and_then(|(k, m)| pan_tilt::k_error(k, m, &rig)) {
                    rms.push(r);
                    max = max.max(mx);
                }
            }
            let mean = Moments::of(&rms).mean;
            // One servo without the moves gives no full K: its row is the diagonal sweep K.
            let label = match (on, kind) {
                (true, _) => "on",
                (false, 0) => "off: diagonal K (sweep)",
                (false, _) => "off",
            };
            println!("{name:<38}{label:<24}{mean:>12.2e}{max:>12.2e}{:>7}", rms.len());
            if !failed.is_empty() {
                let mut kinds = failed.clone();
                kinds.sort();
                kinds.dedup();
                println!("    failed {}: {kinds:?}", failed.len());
            }
            let full_rigs = if on { rms.len() } else { 0 };
            let [c1, c2] = coverage(cover, full_rigs);
            if on {
                println!("    errors within 1 sigma {:.0} %, within 2 sigma {:.0} %", 100.0 * c1, 100.0 * c2);
            }
            let other = ba.map(|[a, b, n]| [a, b].map(|x| if n == 0 { 0.0 } else { x as f64 / n as f64 }));
            if on {
                for (what, [a, b]) in ["bias", "accel offset", "accel gain"].iter().zip(other) {
                    println!("    {what}: within 1 sigma {:.0} %, within 2 sigma {:.0} %", 100.0 * a, 100.0 * b);
                }
            }
            table.push(json!({"rig": name, "rotations": on, "label": label, "rms_mean": mean, "max": max, "rigs": rms.len(), "failed": failed,
                "within_1sigma": on.then_some(c1), "within_2sigma": on.then_some(c2),
                "bias_within": on.then_some(other[0]), "accel_offset_within": on.then_some(other[1]), "accel_gain_within": on.then_some(other[2])}));
        }
    }
    // The firmware's own procedure (default configuration) on the one-servo rigs: the full K it
    // stores, and the diagonal sweep K it reports beside it.
    let (mut full, mut diag, mut max, mut dmax, mut failed, mut cover) = (vec![], vec![], 0.0f64, 0.0f64, vec![], [0usize; 2]);
    let mut diag_failed = vec![];
    for run_idx in 0..args.rigs {
        let cfg = RigConfig { hand, ..args.setup.rig(pan_tilt::rig_config(args.seed, run_idx), args.seed + run_idx as u64) };
        let mut rig = Rig::new(cfg, args.seed + run_idx as u64);
        let mut p = Procedure::new(Config { setup: args.setup.setup(), ..Config::DEFAULT }, None);
        let out = run(&mut rig, &mut p, Faults::default(), 900.0, |_, _, _| {});
        let Some(rec) = out.stored.first() else {
            failed.push(format!("{:?}", out.error));
            diag_failed.push(format!("{:?}", out.error));
            continue;
        };
        if let Some((mx, r)) = pan_tilt::k_error(rec.gyro_k, rec.accel_m, &rig) {
            full.push(r);
            max = max.max(mx);
            let [a, b] = pan_tilt::k_error_covered(rec.gyro_k, rec.sigma_k, rec.accel_m, &rig);
            cover = [cover[0] + a, cover[1] + b];
        }
        let sweep = out.gyro_results().into_iter().find(|g| g.method == calib_core::estimators::gyro::Method::Sweep);
        match sweep.and_then(|g| pan_tilt::k_error(g.k, rec.accel_m, &rig)) {
            Some((mx, r)) => {
                diag.push(r);
                dmax = dmax.max(mx);
            }
            None => diag_failed.push("no sweep K reported".into()),
        }
    }
    let name = "one servo + 12..20 hand-held (firmware)";
    for (label, rms, mx, failed) in [("on", &full, max, &failed), ("off: diagonal K (sweep)", &diag, dmax, &diag_failed)] {
        let mean = Moments::of(rms).mean;
        println!("{name:<38}{label:<24}{mean:>12.2e}{mx:>12.2e}{:>7}", rms.len());
        let on = label == "on";
        let [c1, c2] = coverage(cover, full.len());
        if on {
            println!("    errors within 1 sigma {:.0} %, within 2 sigma {:.0} %", 100.0 * c1, 100.0 * c2);
        }
        if !failed.is_empty() {
            println!("    failed {}: {failed:?}", failed.len());
        }
        table.push(json!({"rig": name, "rotations": on, "label": label, "rms_mean": mean, "max": mx, "rigs": rms.len(), "failed": failed,
            "within_1sigma": on.then_some(c1), "within_2sigma": on.then_some(c2)}));
    }
    if args.json {
        println!("{}", json!({"rigs": args.rigs, "seed": args.seed, "setup": args.setup.json(), "hand": hand_name(hand), "rows": table}));
    }
}
