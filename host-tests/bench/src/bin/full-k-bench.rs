//! The full 3×3 gyro K on simulated pan/tilt rigs: `calib`'s data-driven path on logs of a
//! scripted pan/tilt protocol (12 hand-held poses, then 4 tilt settings × pan 0–180° every 45°
//! and back), gyro cross-axis coupling U(±1 %), accelerometer misalignment U(±0.3 %), servo
//! angle-scale error U(±3 %), LSM9DS1 noise and ODR error. Error `E = Qᵀ K̂ K⁻¹ − I` after
//! aligning the calibrated accelerometer frame to the simulator's (`Q = polar(M̂ C_a)`): RMS over
//! the 9 elements and the largest; beside it the diagonal `K` from one axis (sweep) of the same
//! logs. `--json`: the last line is a JSON summary.

use bench::moments::Moments;
use calib::{csvlog, offline};
use clap::Parser;
use rig_sim::pan_tilt;
use rig_sim::sim::Rig;
use serde_json::json;

/// The full K on simulated pan/tilt rigs.
#[derive(Parser, Debug)]
#[command(name = "full-k-bench")]
struct Args {
    /// Simulated rigs.
    #[arg(long, default_value_t = 20)]
    rigs: usize,
    /// Random seed.
    #[arg(long, default_value_t = 2026)]
    seed: u64,
    /// Print a JSON summary as the last line.
    #[arg(long)]
    json: bool,
}

fn main() {
    let args = Args::parse_from(calib::cli_args());
    let (mut full, mut diag, mut failed) = ((vec![], vec![]), (vec![], vec![]), vec![]);
    for run in 0..args.rigs {
        let mut rig = Rig::new(pan_tilt::rig_config(args.seed, run), args.seed + run as u64);
        let log = pan_tilt::log(&mut rig, true);
        let c =
            match csvlog::parse(&log).map_err(|e| e.to_string()).and_then(|l| offline::calibrate(&l.rows, None).map_err(|e| e.to_string()))
            {
                Ok(c) => c,
                Err(e) => {
                    failed.push(e);
                    continue;
                }
            };
        match c.full.as_ref().map(|f| f.as_ref().map_err(|e| e.to_string())) {
            Some(Ok(f)) => {
                if let Some((mx, rms)) = pan_tilt::k_error(f.k, c.accel.m, &rig) {
                    full.0.push(mx);
                    full.1.push(rms);
                }
            }
            Some(Err(e)) => failed.push(e),
            None => failed.push("no full K attempted".into()),
        }
        if let Some((mx, rms)) = c.gyro.as_ref().ok().and_then(|g| pan_tilt::k_error(g.k, c.accel.m, &rig)) {
            diag.0.push(mx);
            diag.1.push(rms);
        }
    }
    let row = |name: &str, (mx, rms): &(Vec<f64>, Vec<f64>)| {
        let (r, m) = (Moments::of(rms).mean, mx.iter().fold(0.0f64, |a, b| a.max(*b)));
        println!("{name:<28}{r:>14.2e}{m:>14.2e}{:>8}", rms.len());
        json!({"method": name, "rms_mean": r, "max": m, "rigs": rms.len()})
    };
    println!("full-k-bench: {} simulated pan/tilt rigs (gyro cross-axis ±1 %, accel misalignment ±0.3 %, servo ±3 %)", args.rigs);
    println!("{:<28}{:>14}{:>14}{:>8}", "K", "RMS of E", "largest |E|", "rigs");
    let j = [row("full 3x3 (pan/tilt)", &full), row("diagonal, one axis (sweep)", &diag)];
    println!("failed: {} {:?}", failed.len(), failed);
    if args.json {
        println!("{}", json!({"rigs": args.rigs, "seed": args.seed, "rows": j, "failed": failed}));
    }
}
