//! The full 3×3 gyro K on simulated pan/tilt rigs (gyro cross-axis coupling U(±1 %),
//! accelerometer misalignment U(±0.3 %), servo angle-scale error U(±3 %), LSM9DS1 noise and ODR
//! error), two ways on the same rigs:
//! - the firmware's own pan/tilt plan (`Procedure` with `Config::PAN_TILT`, the `tilt-servo`
//!   build): no hand-held step, the accelerometer from the rig poses; its rig time;
//! - `calib`'s data-driven path on logs of a scripted pan/tilt protocol as another tool would
//!   record it (12 hand-held poses, then 4 tilt settings × pan 0–180° every 45° and back).
//!
//! Error `E = Qᵀ K̂ K⁻¹ − I` after aligning the calibrated accelerometer frame to the simulator's
//! (`Q = polar(M̂ C_a)`): RMS over the 9 elements and the largest; beside each the diagonal `K`
//! from one axis (sweep) of the same run. `--json`: the last line is a JSON summary.

use benchmarks::moments::Moments;
use benchmarks::setup::Setup;
use calib::{csvlog, offline};
use calib_core::estimators::gyro::Method;
use calib_core::procedure::{Config, Procedure, Report};
use clap::Parser;
use rig_sim::harness::{run, Faults};
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
    /// The simulated sensor and its settings (the Rev2's: `bmi270`).
    #[arg(long, value_enum, default_value = "default")]
    setup: Setup,
    /// Print a JSON summary as the last line.
    #[arg(long)]
    json: bool,
}

fn main() {
    let args = Args::parse_from(calib::cli_args());
    // Per row: (largest |E| per rig, RMS of E per rig, failures named).
    let (mut full, mut diag, mut fw_full, mut fw_diag) = (Row::default(), Row::default(), Row::default(), Row::default());
    let mut rig_s = vec![];
    for run_idx in 0..args.rigs {
        // The firmware's plan: from the press to the stored record.
        let cfg = args.setup.rig(pan_tilt::rig_config(args.seed, run_idx), args.seed + run_idx as u64);
        let mut rig = Rig::new(cfg, args.seed + run_idx as u64);
        let mut p = Procedure::new(Config { setup: args.setup.setup(), ..Config::PAN_TILT }, None);
        let mut pressed = None;
        let out = run(&mut rig, &mut p, Faults::default(), 900.0, |s, servo, _| {
            if servo.is_some() {
                pressed.get_or_insert(s.t_s);
            }
        });
        match (out.stored.first(), out.error) {
            (Some(rec), _) => {
                fw_full.add(pan_tilt::k_error(rec.gyro_k, rec.accel_m, &rig).ok_or("no error matrix".into()));
                rig_s.push(out.end_s - pressed.unwrap_or(0.0));
                let sweep = out.reports.iter().find_map(|r| match r {
                    Report::Gyro(g) if g.method == Method::Sweep => Some(g.k),
                    _ => None,
                });
                fw_diag.add(
                    sweep
                        .ok_or_else(|| "no sweep K reported".to_string())
                        .and_then(|k| pan_tilt::k_error(k, rec.accel_m, &rig).ok_or("no error matrix".into())),
                );
            }
            (None, e) => {
                fw_full.add(Err(format!("{e:?}")));
                fw_diag.add(Err(format!("{e:?}")));
            }
        }
        let mut rig = Rig::new(cfg, args.seed + run_idx as u64);
        let log = pan_tilt::log(&mut rig, true);
        let c =
            match csvlog::parse(&log).map_err(|e| e.to_string()).and_then(|l| offline::calibrate(&l.rows, None).map_err(|e| e.to_string()))
            {
                Ok(c) => c,
                Err(e) => {
                    full.add(Err(e.clone()));
                    diag.add(Err(e));
                    continue;
                }
            };
        full.add(match c.full.as_ref().map(|f| f.as_ref().map_err(|e| e.to_string())) {
            Some(Ok(f)) => pan_tilt::k_error(f.k, c.accel.m, &rig).ok_or("no error matrix".into()),
            Some(Err(e)) => Err(e),
            None => Err("no full K attempted".into()),
        });
        // The diagonal sweep K beside the full one (`quality.estimators`).
        diag.add(
            c.sweep
                .as_ref()
                .map_err(|e| e.to_string())
                .and_then(|g| pan_tilt::k_error(g.k, c.accel.m, &rig).ok_or("no error matrix".into())),
        );
    }
    let row = |name: &str, r: &Row| {
        let (rms, m) = (Moments::of(&r.rms).mean, r.max.iter().fold(0.0f64, |a, b| a.max(*b)));
        println!("{name:<40}{rms:>14.2e}{m:>14.2e}{:>8}{:>8}", r.rms.len(), r.failed.len());
        for f in &r.failed {
            println!("    failed: {f}");
        }
        json!({"method": name, "rms_mean": rms, "max": m, "rigs": r.rms.len(), "failed": r.failed})
    };
    println!(
        "full-k-bench: {} simulated pan/tilt rigs (gyro cross-axis ±1 %, accel misalignment ±0.3 %, servo ±3 %), the {:?} setup",
        args.rigs, args.setup
    );
    println!("{:<40}{:>14}{:>14}{:>8}{:>8}", "K", "RMS of E", "largest |E|", "rigs", "failed");
    let j = [
        row("full 3x3, firmware pan/tilt plan", &fw_full),
        row("diagonal, one axis (sweep), firmware", &fw_diag),
        row("full 3x3, calib on scripted logs", &full),
        row("diagonal, one axis (sweep), calib", &diag),
    ];
    let rig_time = Moments::of(&rig_s);
    let rig_max = rig_s.iter().fold(0.0f64, |a, b| a.max(*b));
    println!("firmware plan: rig time {:.1} s mean, {rig_max:.1} s max (press to stored)", rig_time.mean);
    if args.json {
        println!(
            "{}",
            json!({"rigs": args.rigs, "seed": args.seed, "setup": args.setup.json(), "rows": j, "rig_time_s": {"mean": rig_time.mean, "max": rig_max}})
        );
    }
}

/// One row of the table: per rig scored, the largest |E| and the RMS of E; every rig not scored
/// with its reason.
#[derive(Default)]
struct Row {
    max: Vec<f64>,
    rms: Vec<f64>,
    failed: Vec<String>,
}

impl Row {
    /// A rig's `(largest |E|, RMS of E)`, or why it has none.
    fn add(&mut self, r: Result<(f64, f64), String>) {
        match r {
            Ok((mx, rms)) => {
                self.max.push(mx);
                self.rms.push(rms);
            }
            Err(e) => self.failed.push(e),
        }
    }
}
