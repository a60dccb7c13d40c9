//! `calib LOG.csv [--method paper|sweep]`: calibrates a recorded log with calib-core and prints
//! one JSON object. `calib --simulate OUT.csv [--seed N] [--odr HZ] [--servo positional|continuous]`
//! writes a log of a simulated calibration run (the firmware's procedure on the rig simulator).
//!
//! Exit codes: 0 success, 1 calibration failed, 2 usage or I/O error, 3 malformed log.

use calib_core::gyro::Method;
use calib_core::procedure::{Config, Procedure, ServoKind};
use host_tests::csvlog;
use host_tests::offline;
use host_tests::servo_protocol::Variant;
use host_tests::session::{record_log, Faults};
use host_tests::sim::{ContinuousServo, PositionalServo, Rig, ServoModel, TiltStage};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::process::ExitCode;

const USAGE: &str = "usage: calib LOG.csv [--method paper|sweep]\n       calib --simulate OUT.csv [--seed N] [--odr 119|238|476|952] [--servo positional|continuous] [--tilt]";

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

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (mut log, mut method, mut sim, mut seed, mut odr) = (None, None, None, 1u64, 119.0);
    let (mut continuous, mut tilt) = (false, false);
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = |name: &str| it.next().cloned().ok_or(format!("{name} needs a value"));
        let r: Result<(), String> = (|| {
            match a.as_str() {
                "--method" => {
                    method = Some(match value("--method")?.as_str() {
                        "paper" => Method::Paper,
                        "sweep" => Method::Sweep,
                        m => return Err(format!("unknown method {m:?} (paper or sweep)")),
                    })
                }
                "--simulate" => sim = Some(value("--simulate")?),
                "--seed" => seed = value("--seed")?.parse().map_err(|_| "--seed needs an integer")?,
                "--odr" => odr = value("--odr")?.parse().map_err(|_| "--odr needs a number")?,
                "--servo" => {
                    continuous = match value("--servo")?.as_str() {
                        "positional" => false,
                        "continuous" => true,
                        s => return Err(format!("unknown servo {s:?} (positional or continuous)")),
                    }
                }
                "--tilt" => tilt = true,
                "-h" | "--help" => return Err(USAGE.into()),
                s if s.starts_with("--") => return Err(format!("unknown option {s}\n{USAGE}")),
                s => log = Some(s.to_string()),
            }
            Ok(())
        })();
        if let Err(e) = r {
            return fail(2, e);
        }
    }
    if let Some(path) = sim {
        return simulate(&path, seed, odr, continuous, tilt);
    }
    let Some(path) = log else { return fail(2, USAGE) };
    let text = match std::fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) => return fail(2, format!("{path}: {e}")),
    };
    let rows = match csvlog::parse(&text) {
        Ok(l) => l.rows,
        Err(e) => return fail(3, format!("{path}: {e}")),
    };
    match offline::calibrate(&rows, method) {
        Ok(c) => {
            println!("{}", c.json());
            ExitCode::SUCCESS
        }
        Err(e) => fail(1, format!("{path}: {e}")),
    }
}
