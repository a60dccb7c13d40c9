//! The realistic benchmark of `paper-tables`: the firmware's procedure (the code that ships) on
//! simulated hobby-servo rigs (servo angle-scale error up to ±3 %, ODR error U(−5, −2) %, accelerometer
//! calibrated by the 9-parameter fit on 12 hand-held poses), both gyro estimators compared.

use crate::moments::Moments;
use calib_core::estimators::gyro::{GyroCal, Method};
use calib_core::procedure::{Config, Procedure, Report};
use calib_core::Error;
use rig_sim::harness::{run, Faults};
use rig_sim::sim::{Rig, RigConfig};
use rig_sim::variant::Variant;
use serde_json::{json, Value};

/// Both estimators' results and the truth of one trial.
#[derive(Debug, Clone, Copy)]
pub struct Trial {
    /// Sweep estimator.
    pub sweep: Result<GyroCal, Error>,
    /// Paper estimator with the nominal (commanded) speed.
    pub paper: Result<GyroCal, Error>,
    /// True diagonal of `K`.
    pub k_true: [f64; 3],
}

impl Trial {
    /// Relative scale errors `K̂_ii / K_ii − 1` of a result.
    pub fn rel_errors(&self, cal: &Result<GyroCal, Error>) -> Option<[f64; 3]> {
        cal.as_ref().ok().map(|c| std::array::from_fn(|i| c.k[i][i] as f64 / self.k_true[i] - 1.0))
    }
}

/// Runs the firmware's own procedure (calib-core, default configuration) on a rig, with the
/// simulated operator, and takes both estimators' reports.
pub fn trial(cfg: RigConfig, seed: u64) -> Result<Trial, Error> {
    let mut rig = Rig::new(cfg, seed);
    let mut p = Procedure::new(Config::default(), None);
    let out = run(&mut rig, &mut p, Faults::default(), 900.0, |_, _, _| {});
    // The truth at the run's mean temperature (the scale moves with it), as every bench scores.
    let k_true = std::array::from_fn(|i| rig.truth().gyro_k[(i, i)]);
    let result = |m: Method| {
        out.reports.iter().find_map(|r| match *r {
            Report::Gyro(c) if c.method == m => Some(Ok(c)),
            Report::EstimatorFailed { method, error } if method == m => Some(Err(error)),
            _ => None,
        })
    };
    match (result(Method::Sweep), result(Method::Paper)) {
        (Some(sweep), Some(paper)) => Ok(Trial { sweep, paper, k_true }),
        _ => Err(out.error.unwrap_or(Error::NoUsableMove)),
    }
}

/// Runs `runs` random realistic rigs under each [`Variant`] and prints both estimators side by
/// side (scale-factor error in %). Returns the JSON summary.
pub fn compare(runs: usize, seed: u64) -> Value {
    println!("\nHobby-servo rig ({runs} random rigs per variant; simulated LSM9DS1 at 119 Hz with ODR error U(-5, -2) %, scale,");
    println!("bias, noise, quantisation; servo lag, slew, dead band, vibration; MCU timestamps; accelerometer by our");
    println!("9-parameter fit on 12 hand-held poses). The firmware's procedure (calib-core, default configuration),");
    println!("with a simulated operator: rest and bias; 12 to 20 hand-held poses; on the shaft, static poses 0..180..0 deg, moves");
    println!("commanded at 30 deg/s (sweep); rotation commanded at 20 deg/s (paper, w_n = 20 deg/s). Error of diag(K), in %:");
    println!("{:<24}{:<8}{:>10}{:>10}{:>10}{:>8}", "variant", "method", "RMS", "max|e|", "mean", "failed");
    let mut out = serde_json::Map::new();
    for variant in [Variant::Hobby, Variant::ExactServo, Variant::HobbyMisaligned] {
        let (mut e_sweep, mut e_paper) = (vec![], vec![]);
        let (mut f_sweep, mut f_paper) = (vec![], vec![]);
        for r in 0..runs {
            match trial(variant.config(seed, r), r as u64 + 1) {
                Ok(s) => {
                    for (errs, cal, f) in [(&mut e_sweep, &s.sweep, &mut f_sweep), (&mut e_paper, &s.paper, &mut f_paper)] {
                        match s.rel_errors(cal) {
                            Some(e) => errs.extend(e.iter().map(|x| x * 100.0)),
                            None => f.push(cal.err().map(|e| e.to_string()).unwrap_or_default()),
                        }
                    }
                }
                Err(e) => {
                    f_sweep.push(e.to_string());
                    f_paper.push(e.to_string());
                }
            }
        }
        let (ms, mp) = (Moments::of(&e_sweep), Moments::of(&e_paper));
        let max = |e: &[f64]| e.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        for (method, m, e, f) in [("sweep", &ms, &e_sweep, &f_sweep), ("paper", &mp, &e_paper, &f_paper)] {
            println!("{:<24}{:<8}{:>10.4}{:>10.4}{:>10.4}{:>8}", variant.name(), method, m.rms, max(e), m.mean, f.len());
        }
        let ratio = if ms.rms > 0.0 { mp.rms / ms.rms } else { f64::INFINITY };
        println!("{:<24}paper RMS / sweep RMS = {:.2}", "", ratio);
        out.insert(
            variant.name().into(),
            json!({"sweep_rms_pct": ms.rms, "paper_rms_pct": mp.rms, "paper_over_sweep": ratio,
                   "sweep_max_pct": max(&e_sweep), "paper_max_pct": max(&e_paper),
                   "sweep": ms.json(), "paper": mp.json(), "sweep_failed": f_sweep, "paper_failed": f_paper}),
        );
    }
    Value::Object(out)
}
