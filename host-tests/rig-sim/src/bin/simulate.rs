//! `simulate OUT.csv [--seed N] [--odr HZ] [--servo positional|continuous] [--tilt]`: writes the
//! log of a simulated calibration run (the firmware's procedure on the rig simulator, with a
//! simulated operator), in the format `calib` reads; the true K in a closing comment.

use calib_core::procedure::{Config, Procedure, ServoKind};
use clap::{Parser, ValueEnum};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rig_sim::harness::{record_log, Faults};
use rig_sim::sim::{ContinuousServo, PositionalServo, Rig, ServoModel, TiltStage};
use rig_sim::variant::Variant;
use std::process::ExitCode;

/// The log of a simulated calibration run.
#[derive(Parser, Debug)]
#[command(name = "simulate")]
struct Args {
    /// Where to write the log.
    out: String,
    /// Random seed of the rig.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Output data rate (Hz).
    #[arg(long, default_value = "119", value_parser = ["119", "238", "476", "952"])]
    odr: String,
    /// Rotation servo type.
    #[arg(long, value_enum, default_value_t = ServoArg::Positional)]
    servo: ServoArg,
    /// A tilt servo takes the accelerometer poses.
    #[arg(long)]
    tilt: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, ValueEnum)]
enum ServoArg {
    Positional,
    Continuous,
}

fn fail(code: u8, msg: impl std::fmt::Display) -> ExitCode {
    eprintln!("simulate: {msg}");
    ExitCode::from(code)
}

fn main() -> ExitCode {
    let a = Args::parse();
    let odr: f64 = a.odr.parse().unwrap_or(119.0);
    simulate(&a.out, a.seed, odr, a.servo == ServoArg::Continuous, a.tilt)
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
    let header = format!("# simulated by simulate, seed {seed}, ODR {odr} Hz\n");
    let (mut out, outcome) = record_log(&mut rig, &mut p, Faults::default(), &header);
    let k = rig.truth().gyro_k;
    out.push_str(&format!("# true K diagonal: {:.6} {:.6} {:.6}\n", k[(0, 0)], k[(1, 1)], k[(2, 2)]));
    if let Err(e) = std::fs::write(path, out) {
        return fail(2, format!("{path}: {e}"));
    }
    match outcome.error {
        None => {
            eprintln!(
                "simulate: wrote {path}: {} samples, {:.0} s; true K diagonal {:.6} {:.6} {:.6}",
                outcome.samples,
                outcome.end_s,
                k[(0, 0)],
                k[(1, 1)],
                k[(2, 2)]
            );
            ExitCode::SUCCESS
        }
        Some(e) => fail(1, format!("the simulated run failed: {e}")),
    }
}
