//! Benchmark of the offline `gyrocal-calib` path: simulated calibration logs (the procedure on
//! random realistic rigs, servo angle-scale error U(−3, 3) %, gyro and accelerometer cross-axis
//! misalignment: `Variant::HobbyMisaligned`), written as CSV, parsed back and calibrated as
//! `gyrocal-calib LOG` does; scored is the record it gives (what it prints and exports: the full
//! `K` its replay of the firmware's procedure stores, else the diagonal one), as
//! `E = Qᵀ K̂ K⁻¹ − I` per ODR and servo type. The continuous servo's rows replay calib-core's
//! procedure with a continuous servo, which no firmware build has. With `--json` the last line
//! is a JSON summary.
//!
//! `cargo run --profile host -p benchmarks --target host-tuple --bin calib-bench -- [--json] [--logs N]`

use calib::csvlog;
use calib::offline;
use calib_core::procedure::{Config, Procedure, ServoKind};
use clap::Parser;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rig_sim::harness::{record_log, Faults};
use rig_sim::pan_tilt::k_error;
use rig_sim::sim::{ContinuousServo, Rig, ServoModel};
use rig_sim::variant::Variant;
use serde_json::json;

/// The offline `gyrocal-calib` path on simulated logs: the error of the record it gives.
#[derive(Parser, Debug)]
#[command(name = "calib-bench")]
struct Args {
    /// Simulated logs per row.
    #[arg(long, default_value_t = 10)]
    logs: usize,
    /// Print a JSON summary as the last line.
    #[arg(long)]
    json: bool,
}

/// The rigs' seed (`Variant::HobbyMisaligned.config(RIG_SEED, i)`); log `i`'s noise is seeded
/// `NOISE_SEED + i`.
const RIG_SEED: u64 = 77;
/// See [`RIG_SEED`].
const NOISE_SEED: u64 = 100;

fn main() {
    let args = Args::parse_from(calib::cli_args());
    let (json_out, logs) = (args.json, args.logs);
    println!("calib-bench: {logs} simulated logs per row; E of the record gyrocal-calib gives, against the simulator's truth");
    println!("{:<12}{:>6}{:>11}{:>11}{:>8}{:>8}", "servo", "ODR", "RMS of E", "largest", "full K", "failed");
    let mut rows_json = vec![];
    for (servo, odrs) in [("positional", &[119.0, 238.0, 476.0, 952.0][..]), ("continuous", &[119.0, 476.0][..])] {
        for &odr in odrs {
            let (mut rms, mut max, mut full, mut failed) = (vec![], 0.0f64, 0, vec![]);
            for i in 0..logs {
                let mut cfg = Variant::HobbyMisaligned.config(RIG_SEED, i);
                cfg.odr_hz = odr;
                let mut pcfg = Config::default();
                if servo == "continuous" {
                    cfg.servo = ServoModel::Continuous(ContinuousServo::realistic(&mut ChaCha8Rng::seed_from_u64(i as u64)));
                    pcfg.servo = ServoKind::CONTINUOUS;
                }
                let mut rig = Rig::new(cfg, NOISE_SEED + i as u64);
                let mut p = Procedure::new(pcfg, None);
                let (text, _) = record_log(&mut rig, &mut p, Faults::default(), "");
                let rec = csvlog::parse(&text)
                    .map_err(|e| e.to_string())
                    .and_then(|l| offline::calibrate(&l.rows, None).map_err(|e| e.to_string()))
                    .and_then(|c| c.record().ok_or_else(|| "no gyro calibration".to_string()));
                match rec.map(|r| (r.method, k_error(r.gyro_k, r.accel_m, &rig))) {
                    Ok((method, Some((m, r)))) => {
                        full += usize::from(method == calib_core::estimators::gyro::Method::Full);
                        max = max.max(m);
                        rms.push(r);
                    }
                    Ok((_, None)) => failed.push("singular truth".to_string()),
                    Err(e) => failed.push(e),
                }
            }
            let mean = rms.iter().sum::<f64>() / rms.len().max(1) as f64;
            println!("{:<12}{:>6}{:>11.2e}{:>11.2e}{:>8}{:>8}", servo, odr, mean, max, full, failed.len());
            let path =
                if servo == "positional" { "replay of the firmware's procedure" } else { "replay of the procedure (no firmware build)" };
            rows_json.push(json!({"servo": servo, "odr_hz": odr, "path": path, "rms_mean": mean, "max": max, "scored": rms.len(), "full_k": full, "failed": failed}));
        }
    }
    if json_out {
        println!("{}", json!({"logs_per_row": logs, "rig_seed": RIG_SEED, "noise_seed": NOISE_SEED, "rows": rows_json}));
    }
}
