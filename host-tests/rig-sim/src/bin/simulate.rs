//! `simulate OUT.csv [--seed N] [--odr HZ] [--servo positional|continuous | --tilt] [--hand
//! braced|free|none]`: writes the
//! log of a simulated calibration run (the firmware's procedure on the rig simulator, with a
//! simulated operator), in the format `calib` reads; the true K in a closing comment.

use calib_core::procedure::{Config, Procedure, ServoKind};
use clap::{Parser, ValueEnum};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rig_sim::harness::{record_log, Faults};
use rig_sim::pan_tilt;
use rig_sim::sim::{ContinuousServo, HandLevel, Rig, ServoModel};
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
    /// A pan/tilt bracket (the `tilt-servo` firmware's plan, the full K): shaft 30–50° from
    /// vertical, gyro cross-axis ±1 %, accelerometer misalignment ±0.3 %.
    #[arg(long, conflicts_with = "servo")]
    tilt: bool,
    /// The hand that holds the board for the hand-held poses: resting on a table, in the air,
    /// turning at the wrist, arm or nodding (`HandLevel`), or perfectly still (no real hand is).
    #[arg(long, default_value = "braced", value_parser = ["braced", "free", "wrist", "arm", "nod", "none"])]
    hand: String,
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
    simulate(&a.out, a.seed, odr, a.servo == ServoArg::Continuous, a.tilt, HandLevel::parse(&a.hand).unwrap_or_default())
}

fn simulate(path: &str, seed: u64, odr: f64, continuous: bool, tilt: bool, hand: Option<HandLevel>) -> ExitCode {
    let mut cfg = if tilt { pan_tilt::rig_config(seed, 0) } else { Variant::Hobby.config(seed, 0) };
    cfg.odr_hz = odr;
    cfg.hand = hand;
    let mut pcfg = if tilt { Config::PAN_TILT } else { Config::DEFAULT };
    if continuous {
        cfg.servo = ServoModel::Continuous(ContinuousServo::realistic(&mut ChaCha8Rng::seed_from_u64(seed)));
        pcfg.servo = ServoKind::CONTINUOUS;
    }
    let mut rig = Rig::new(cfg, seed);
    let mut p = Procedure::new(pcfg, None);
    let header = format!("# simulated by simulate, seed {seed}, ODR {odr} Hz, hand {}\n", hand.map_or("none", HandLevel::name));
    let (mut out, outcome) = record_log(&mut rig, &mut p, Faults::default(), &header);
    let k = rig.truth().gyro_k;
    out.push_str(&format!("# true K diagonal: {:.6} {:.6} {:.6}\n", k[(0, 0)], k[(1, 1)], k[(2, 2)]));
    out.push_str(&format!("# true K: {:?}\n", k.transpose().as_slice()));
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
