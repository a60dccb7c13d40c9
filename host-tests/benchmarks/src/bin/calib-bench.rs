//! Benchmark of the offline `calib` path: simulated calibration logs (the procedure on random
//! realistic rigs, servo angle-scale error U(−3, 3) %), written as CSV, parsed back and
//! calibrated with the default method. Prints the scale-factor error per ODR and servo type;
//! with `--json` the last line is a JSON summary.
//!
//! `cargo run --release -p host-tests --target host-tuple --bin calib-bench [--json] [--logs N]`

use benchmarks::moments::Moments;
use calib::csvlog;
use calib::offline;
use calib_core::procedure::{Config, Procedure, ServoKind};
use clap::Parser;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rig_sim::harness::{record_log, Faults};
use rig_sim::sim::{ContinuousServo, Rig, ServoModel};
use rig_sim::variant::Variant;
use serde_json::json;

/// The offline `calib` path on simulated logs, error of diag(K) per ODR and servo type.
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

fn main() {
    let args = Args::parse_from(calib::cli_args());
    let (json_out, logs) = (args.json, args.logs);
    println!("calib-bench: {logs} simulated logs per row; error of diag(K) in % against the simulator's truth");
    println!("{:<12}{:>6}{:>10}{:>10}{:>10}{:>8}", "servo", "ODR", "RMS", "max|e|", "mean", "failed");
    let mut rows_json = vec![];
    for (servo, odrs) in [("positional", &[119.0, 238.0, 476.0, 952.0][..]), ("continuous", &[119.0, 476.0][..])] {
        for &odr in odrs {
            let (mut errs, mut failed) = (vec![], vec![]);
            for i in 0..logs {
                let mut cfg = Variant::Hobby.config(77, i);
                cfg.odr_hz = odr;
                let mut pcfg = Config::default();
                if servo == "continuous" {
                    cfg.servo = ServoModel::Continuous(ContinuousServo::realistic(&mut ChaCha8Rng::seed_from_u64(i as u64)));
                    pcfg.servo = ServoKind::CONTINUOUS;
                }
                let mut rig = Rig::new(cfg, i as u64 + 100);
                let mut p = Procedure::new(pcfg, None);
                let (text, _) = record_log(&mut rig, &mut p, Faults::default(), "");
                let k = rig.truth().gyro_k;
                let gyro = csvlog::parse(&text)
                    .map_err(|e| e.to_string())
                    .and_then(|l| offline::calibrate(&l.rows, None).map_err(|e| e.to_string()))
                    .and_then(|c| c.gyro.map_err(|e| e.to_string()));
                match gyro {
                    Ok(g) => errs.extend((0..3).map(|a| (g.k[a][a] as f64 / k[(a, a)] - 1.0) * 100.0)),
                    Err(e) => failed.push(e),
                }
            }
            let m = Moments::of(&errs);
            let max = errs.iter().fold(0.0f64, |a, b| a.max(b.abs()));
            println!("{:<12}{:>6}{:>10.4}{:>10.4}{:>10.4}{:>8}", servo, odr, m.rms, max, m.mean, failed.len());
            rows_json.push(json!({"servo": servo, "odr_hz": odr, "rms_pct": m.rms, "max_pct": max, "mean_pct": m.mean, "failed": failed}));
        }
    }
    if json_out {
        println!("{}", json!({"logs_per_row": logs, "rows": rows_json}));
    }
}
