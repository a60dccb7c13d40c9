//! The firmware's procedure (one servo + hand-held poses, `Config::DEFAULT`) on simulated rigs
//! with and without a moving gyro bias (issue 19's physics): the board warming up after
//! power-on (rise U(2, 6) °C along 1 − e^(−t/τ), τ U(60, 150) s, the log starting U(5, 30) s
//! after power-on), a zero-rate tempco U(±0.03, ±0.05) °/s/°C per axis, a bias random walk of
//! 5e-4 °/s/√s and the Earth's rotation at 45°. The same rigs both ways. Prints the runs that
//! fail (with their errors) and `E = Qᵀ K̂ K⁻¹ − I` (RMS over the 9 elements and the largest) of
//! those stored; `--json`: the last line is a JSON summary. A baseline for the tracked bias.
//!
//! `cargo run --profile host -p benchmarks --target host-tuple --bin drift-bench [--rigs N] [--json]`

use benchmarks::moments::Moments;
use calib_core::procedure::{Config, Procedure};
use clap::Parser;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rig_sim::harness::{run, Faults};
use rig_sim::pan_tilt;
use rig_sim::sim::{Rig, RigConfig, Warmup};
use rig_sim::variant::Variant;
use serde_json::json;

/// The procedure with and without a drifting gyro bias.
#[derive(Parser, Debug)]
#[command(name = "drift-bench")]
struct Args {
    /// Simulated rigs.
    #[arg(long, default_value_t = 8)]
    rigs: usize,
    /// Random seed.
    #[arg(long, default_value_t = 19)]
    seed: u64,
    /// Print a JSON summary as the last line.
    #[arg(long)]
    json: bool,
}

/// `cfg` with the drift physics on, drawn from `rng`.
fn drifting(mut cfg: RigConfig, rng: &mut impl Rng) -> RigConfig {
    cfg.warmup = Some(Warmup {
        rise_c: rng.random_range(2.0..6.0),
        tau_s: rng.random_range(60.0..150.0),
        since_power_on_s: rng.random_range(5.0..30.0),
    });
    cfg.temp_drift_c_per_s = 0.0;
    for a in 0..3 {
        let m: f64 = rng.random_range(0.03..0.05);
        cfg.gyro.bias_tempco_dps_per_c[a] = if rng.random_bool(0.5) { m } else { -m };
    }
    cfg.bias_rw_dps_rtsec = 5e-4;
    cfg.latitude_deg = Some(45.0);
    cfg
}

fn main() {
    let args = calib::cli_args();
    let args = Args::parse_from(args);
    let mut rows = vec![];
    println!("drift-bench: {} one-servo rigs, the firmware's procedure, without and with a drifting bias", args.rigs);
    println!("{:<10}{:>14}{:>14}{:>8}{:>8}", "bias", "RMS of E", "largest |E|", "stored", "failed");
    for drift in [false, true] {
        let (mut rms, mut largest, mut failed) = (vec![], vec![], vec![]);
        for i in 0..args.rigs {
            let base = Variant::Hobby.config(args.seed, i);
            let cfg = if drift { drifting(base, &mut ChaCha8Rng::seed_from_u64(args.seed * 1000 + i as u64)) } else { base };
            let mut rig = Rig::new(cfg, args.seed + i as u64);
            let mut p = Procedure::new(Config::DEFAULT, None);
            let out = run(&mut rig, &mut p, Faults::default(), 900.0, |_, _, _| {});
            match (out.stored.first(), out.error) {
                (Some(rec), _) => match pan_tilt::k_error(rec.gyro_k, rec.accel_m, &rig) {
                    Some((mx, r)) => {
                        rms.push(r);
                        largest.push(mx);
                    }
                    None => failed.push("no error matrix".to_string()),
                },
                (None, e) => failed.push(format!("{e:?}")),
            }
        }
        let name = if drift { "drifting" } else { "constant" };
        let (r, m) = (Moments::of(&rms).mean, largest.iter().fold(0.0f64, |a, b| a.max(*b)));
        println!("{name:<10}{r:>14.2e}{m:>14.2e}{:>8}{:>8}", rms.len(), failed.len());
        for f in &failed {
            println!("  failed: {f}");
        }
        rows.push(json!({"bias": name, "rms_mean": r, "max": m, "stored": rms.len(), "failed": failed}));
    }
    if args.json {
        println!("{}", json!({"rigs": args.rigs, "seed": args.seed, "rows": rows}));
    }
}
