//! What the magnetometer calibration buys: the tilt-compensated heading error over random
//! attitudes (`rig_sim::heading`, in the calibrated accelerometer's frame) of `gyrocal-calib`'s
//! magnetometer (hard and soft iron, and the die's rotation onto the accelerometer) beside the
//! ellipsoid alone that the usual tools fit, on simulated one-servo rigs with the board's
//! magnetometer (the site's field 40–60 µT at a dip of 50–70°, hard iron ±40 µT, soft iron ±5 %,
//! the die turned up to 2°, the servo's motor magnet near the board on the shaft): the scripted
//! one-servo protocol's logs and the logs of the firmware's own procedure, and that procedure's
//! own fit (the magnetometer of the record it stores, as the firmware computes it). `--setup bmi270`: the
//! Rev2's BMM150 (0.3 µT resolution). `--json`: the last line is a JSON summary.
//!
//! `cargo run --profile host -p benchmarks --target host-tuple --bin mag-bench [--rigs N] [--setup S] [--json]`

use benchmarks::setup::Setup;
use calib_core::procedure::{Config, Procedure};
use clap::Parser;
use rig_sim::harness::{record_log, Faults};
use rig_sim::heading::{heading_error, Applied};
use rig_sim::pan_tilt;
use rig_sim::sim::Rig;
use serde_json::json;

/// Heading error of the magnetometer calibration.
#[derive(Parser, Debug)]
#[command(name = "mag-bench")]
struct Args {
    /// Simulated rigs per row.
    #[arg(long, default_value_t = 20)]
    rigs: usize,
    /// Random seed.
    #[arg(long, default_value_t = 33)]
    seed: u64,
    /// The simulated sensor and its settings (the Rev2's: `bmi270`).
    #[arg(long, value_enum, default_value = "default")]
    setup: Setup,
    /// Print a JSON summary as the last line.
    #[arg(long)]
    json: bool,
}

/// Attitudes each calibration is scored at.
const ATTITUDES: usize = 500;

fn main() {
    let args = Args::parse_from(calib::cli_args());
    println!(
        "mag-bench: {} simulated rigs per row, the {:?} setup, heading error over {ATTITUDES} random attitudes",
        args.rigs, args.setup
    );
    println!("{:<34}{:>14}{:>10}{:>16}{:>10}{:>7}{:>9}", "log", "RMS (deg)", "max", "ellipsoid RMS", "max", "rigs", "rig out");
    let mut table = vec![];
    for (row, name) in ["one servo + 12 hand-held (script)", "firmware procedure's log"].iter().enumerate() {
        let (mut ours, mut ell, mut failed, mut left_out) = (vec![], vec![], vec![], 0usize);
        let (mut board, mut board_failed) = (vec![], vec![]);
        for run in 0..args.rigs {
            let seed = args.seed + run as u64;
            let cfg = args.setup.rig(pan_tilt::rig_config(args.seed + row as u64, run), seed);
            let mut rig = Rig::new(cfg, seed);
            let log = match row {
                0 => pan_tilt::log_at(&mut rig, true, &[0.0]),
                _ => {
                    let mut p = Procedure::new(Config { setup: args.setup.setup(), ..Config::DEFAULT }, None);
                    let (text, out) = record_log(&mut rig, &mut p, Faults::default(), "");
                    match out.stored.first().map(|r| (r, r.mag)) {
                        Some((r, Some(m))) => board.extend(heading_error(
                            &Applied { accel_m: r.accel_m, accel_o: r.accel_offset_g, mag_a: m.a, mag_o: m.offset_ut },
                            &rig,
                            ATTITUDES,
                            seed,
                        )),
                        Some((_, None)) => board_failed.push("a record without a magnetometer".to_string()),
                        None => board_failed.push(out.error.map_or("nothing stored".into(), |e| e.to_string())),
                    }
                    // The setup comment the firmware's raw log holds after its header.
                    let mut setup = String::new();
                    let _ = calib_core::formats::log::write_setup(&mut setup, &args.setup.setup());
                    let at = text.find('\n').map_or(0, |i| i + 1);
                    format!("{}{setup}\n{}", &text[..at], &text[at..])
                }
            };
            let c = match benchmarks::logs::calibrate(&log) {
                Ok(c) => c,
                Err(e) => {
                    failed.push(e);
                    continue;
                }
            };
            let Some(m) = c.mag.as_ref() else {
                failed.push("no magnetometer columns".into());
                continue;
            };
            left_out += m.left_out;
            let score = |mag_a, mag_o| {
                heading_error(&Applied { accel_m: c.accel.m, accel_o: c.accel.offset_g, mag_a, mag_o }, &rig, ATTITUDES, seed)
            };
            match &m.cal {
                Ok(cal) => ours.extend(score(cal.a, cal.offset_ut)),
                Err(e) => failed.push(e.to_string()),
            }
            ell.extend(m.ellipsoid.and_then(|(a, o)| score(a, o)));
        }
        let rms = |v: &[(f64, f64)]| (v.iter().map(|x| x.0 * x.0).sum::<f64>() / v.len().max(1) as f64).sqrt();
        let max = |v: &[(f64, f64)]| v.iter().map(|x| x.1).fold(0.0, f64::max);
        println!(
            "{name:<34}{:>14.3}{:>10.3}{:>16.3}{:>10.3}{:>7}{:>9}",
            rms(&ours),
            max(&ours),
            rms(&ell),
            max(&ell),
            ours.len(),
            left_out / args.rigs.max(1)
        );
        if !failed.is_empty() {
            println!("    failed {}: {failed:?}", failed.len());
        }
        table.push(json!({"log": name, "rigs": ours.len(), "failed": failed, "rms_deg": rms(&ours), "max_deg": max(&ours),
            "ellipsoid_rms_deg": rms(&ell), "ellipsoid_max_deg": max(&ell), "rig_readings_left_out_per_log": left_out / args.rigs.max(1)}));
        if row == 1 {
            // The same runs' records: the procedure's own fit, from the hand-held step alone.
            let name = "firmware procedure's record";
            println!(
                "{name:<34}{:>14.3}{:>10.3}{:>16.3}{:>10.3}{:>7}{:>9}",
                rms(&board),
                max(&board),
                rms(&ell),
                max(&ell),
                board.len(),
                0
            );
            if !board_failed.is_empty() {
                println!("    failed {}: {board_failed:?}", board_failed.len());
            }
            table.push(json!({"log": name, "rigs": board.len(), "failed": board_failed, "rms_deg": rms(&board), "max_deg": max(&board),
                "ellipsoid_rms_deg": rms(&ell), "ellipsoid_max_deg": max(&ell), "rig_readings_left_out_per_log": 0}));
        }
    }
    if args.json {
        println!(
            "{}",
            json!({"bench": "mag-bench", "seed": args.seed, "rigs": args.rigs, "attitudes": ATTITUDES, "setup": args.setup.json(), "rows": table})
        );
    }
}
