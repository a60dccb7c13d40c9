//! `calib LOG.csv [--method paper|sweep] [--columns MAP]`: calibrates a recorded log with
//! calib-core and prints one JSON object. `calib --simulate OUT.csv [--seed N] [--odr HZ]
//! [--servo positional|continuous] [--tilt]` writes a log of a simulated calibration run (the
//! firmware's procedure on the rig simulator). `calib --help` says everything.
//!
//! Exit codes: 0 a full calibration, 4 partial, 1 nothing calibrated, 2 usage or I/O error,
//! 3 malformed log.

use calib_core::gyro::Method;
use calib_core::procedure::{Config, Procedure, ServoKind};
use host_tests::csvlog;
use host_tests::offline;
use host_tests::servo_protocol::Variant;
use host_tests::session::{record_log, Faults};
use host_tests::sim::{ContinuousServo, PositionalServo, Rig, ServoModel, TiltStage};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use calib_core::accel::AccelModel;
use clap::{Parser, ValueEnum};
use std::process::ExitCode;

fn fail(code: u8, msg: impl std::fmt::Display) -> ExitCode {
    eprintln!("calib: {msg}");
    ExitCode::from(code)
}

fn simulate(path: &str, seed: u64, odr: f64, continuous: bool, tilt: bool) -> ExitCode {
    let mut cfg = Variant::Hobby.config(seed, 0);
    cfg.odr_hz = odr;
    let mut pcfg = Config::default();
    if tilt {
        let servo = PositionalServo::realistic(&mut ChaCha8Rng::seed_from_u64(seed + 1));
        cfg.tilt = Some(TiltStage { servo, hinge_deg: 45.0 });
        pcfg.tilt_accel = true;
    }
    if continuous {
        cfg.servo = ServoModel::Continuous(ContinuousServo::realistic(&mut ChaCha8Rng::seed_from_u64(seed)));
        pcfg.servo = ServoKind::CONTINUOUS;
    }
    let mut rig = Rig::new(cfg, seed);
    let mut p = Procedure::new(pcfg, None);
    let header = format!("# simulated by calib --simulate, seed {seed}, ODR {odr} Hz\n");
    let (mut out, outcome) = record_log(&mut rig, &mut p, Faults::default(), &header);
    let k = rig.truth().gyro_k;
    out.push_str(&format!("# true K diagonal: {:.6} {:.6} {:.6}\n", k[(0, 0)], k[(1, 1)], k[(2, 2)]));
    if let Err(e) = std::fs::write(path, out) {
        return fail(2, format!("{path}: {e}"));
    }
    match outcome.error {
        None => {
            eprintln!(
                "calib: wrote {path}: {} samples, {:.0} s; true K diagonal {:.6} {:.6} {:.6}",
                outcome.samples, outcome.end_s, k[(0, 0)], k[(1, 1)], k[(2, 2)]
            );
            ExitCode::SUCCESS
        }
        Some(e) => fail(1, format!("the simulated run failed: {e}")),
    }
}

/// Gyro and accelerometer calibration of a recorded log with the firmware's own calib-core code.
///
/// Exit codes: 0 a full calibration; 4 partial (the log supports only part of it: the JSON has
/// what could be calibrated and `quality.missing` names the rest); 1 nothing could be
/// calibrated; 2 usage or file error; 3 malformed log.
#[derive(Parser, Debug)]
#[command(name = "calib", version)]
struct Args {
    /// The log to calibrate (CSV: t_s,ax_g,ay_g,az_g,gx_dps,gy_dps,gz_dps,servo_deg[,tilt_deg]).
    #[arg(required_unless_present = "simulate")]
    log: Option<String>,
    /// Use only this gyro estimator (default: sweep, else paper).
    #[arg(long, value_enum)]
    method: Option<MethodArg>,
    /// Read a log with other column names or units: COLUMN=SOURCE[*F|/F],… e.g.
    /// `t_s=time/1000,ax_g=acc_x/9.80665,gx_dps=gyr_x*57.29578`.
    #[arg(long, value_name = "MAP")]
    columns: Option<String>,
    /// Instead: write the log of a simulated calibration run (the firmware's procedure on the
    /// rig simulator) to this file.
    #[arg(long, value_name = "OUT.csv", conflicts_with_all = ["log", "method", "columns"])]
    simulate: Option<String>,
    /// Simulation: random seed of the rig.
    #[arg(long, default_value_t = 1, requires = "simulate")]
    seed: u64,
    /// Simulation: output data rate (Hz).
    #[arg(long, default_value = "119", value_parser = ["119", "238", "476", "952"], requires = "simulate")]
    odr: String,
    /// Simulation: rotation servo type.
    #[arg(long, value_enum, default_value_t = ServoArg::Positional, requires = "simulate")]
    servo: ServoArg,
    /// Simulation: a tilt servo takes the accelerometer poses.
    #[arg(long, requires = "simulate")]
    tilt: bool,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum MethodArg {
    Paper,
    Sweep,
}

#[derive(Clone, Copy, Debug, PartialEq, ValueEnum)]
enum ServoArg {
    Positional,
    Continuous,
}

fn main() -> ExitCode {
    let args = Args::parse_from(host_tests::cli_args());
    if let Some(path) = args.simulate {
        let odr: f64 = args.odr.parse().unwrap_or(119.0);
        return simulate(&path, args.seed, odr, args.servo == ServoArg::Continuous, args.tilt);
    }
    let Some(path) = args.log else { return fail(2, "no log given") };
    let method = args.method.map(|m| match m {
        MethodArg::Paper => Method::Paper,
        MethodArg::Sweep => Method::Sweep,
    });
    let mut text = match std::fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) => return fail(2, format!("{path}: {e}")),
    };
    if let Some(spec) = &args.columns {
        text = match csvlog::remap(&text, spec) {
            Ok(t) => t,
            Err(e) => return fail(3, format!("{path}: {e}")),
        };
    }
    let log = match csvlog::parse(&text) {
        Ok(l) => l,
        Err(e) => return fail(3, format!("{path}: {e}")),
    };
    let c = match offline::calibrate(&log.rows, method) {
        Ok(c) => c,
        Err(e) => return fail(1, format!("{path}: {e}")),
    };
    let missing = c.missing();
    match &c.gyro {
        Err(e) if c.accel.model == AccelModel::None => fail(1, format!("{path}: {e}")),
        _ => {
            println!("{}", c.json(log.messages));
            for m in &missing {
                eprintln!("calib: {path}: partial calibration, missing {m}");
            }
            if missing.is_empty() {
                ExitCode::SUCCESS
            } else {
                ExitCode::from(4)
            }
        }
    }
}
