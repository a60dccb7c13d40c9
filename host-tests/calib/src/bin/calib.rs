//! `calib LOG.csv [--method paper|sweep] [--columns MAP] [--no-rotations]`: calibrates a recorded log with
//! calib-core and prints one JSON object. `calib --help` says everything. (A log to try it on:
//! `cargo run --release -p rig-sim --target host-tuple --bin simulate -- OUT.csv`.)
//!
//! Exit codes: 0 a full calibration, 4 partial, 1 nothing calibrated, 2 usage or I/O error,
//! 3 malformed log.

use calib::{csvlog, offline};
use calib_core::accel::AccelModel;
use calib_core::gyro::Method;
use clap::{Parser, ValueEnum};
use std::process::ExitCode;

fn fail(code: u8, msg: impl std::fmt::Display) -> ExitCode {
    eprintln!("calib: {msg}");
    ExitCode::from(code)
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
    log: String,
    /// Use only this gyro estimator (default: sweep, else paper).
    #[arg(long, value_enum)]
    method: Option<MethodArg>,
    /// Read a log with other column names or units: COLUMN=SOURCE[*F|/F],… e.g.
    /// `t_s=time/1000,ax_g=acc_x/9.80665,gx_dps=gyr_x*57.29578`.
    #[arg(long, value_name = "MAP")]
    columns: Option<String>,
    /// Leave out the rotation constraints of the moves between hand-held poses (to see what
    /// they add to the full K).
    #[arg(long)]
    no_rotations: bool,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum MethodArg {
    Paper,
    Sweep,
}

fn main() -> ExitCode {
    let args = Args::parse_from(calib::cli_args());
    let path = args.log;
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
    let c = match offline::calibrate_with(&log.rows, method, !args.no_rotations) {
        Ok(c) => c,
        Err(e) => return fail(1, format!("{path}: {e}")),
    };
    let missing = c.missing();
    match &c.gyro {
        Err(e) if c.accel.model == AccelModel::None && !matches!(c.full, Some(Ok(_))) => fail(1, format!("{path}: {e}")),
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
