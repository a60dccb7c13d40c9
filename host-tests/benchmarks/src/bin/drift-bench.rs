//! The firmware's procedure on the realistic rigs, whose gyro bias moves
//! (`RigConfig::drifting`: warm-up after power-on, bias and scale tempco, random walk, Earth rate), on the same
//! rigs with a constant bias (`RigConfig::constant_bias`), and on the same drifting rigs started
//! after a warm-up wait (the board powered `--wait-s` longer before the button): calibrate at once
//! with the tracked bias, or wait. Both plans: one servo + hand-held poses (`Config::DEFAULT`)
//! and the pan/tilt bracket (`Config::PAN_TILT`). Prints `E = Qᵀ K̂ K⁻¹ − I` (RMS over the 9
//! elements, mean over the rigs, and the largest element) of the stored results, the rig time
//! (button to store, plus the wait), the bias's temperature coefficient (in how many runs it was
//! reported, and the fraction of its axes within 2σ of the truth), and the runs that fail with
//! their errors. Each drifting rig draws its bias random walk from `BIAS_WALK_RANGE`; a second
//! table runs the drifting rigs at the range's ends and middle and gives the tempco's coverage
//! (1σ, 2σ) and the walk the calibration measured (median, `TempFit::walk_dps_rtsec`); a third
//! runs them at fixed ODR errors, the ends and middle of the range the rigs draw from
//! (`Setup::odr_error_range`).
//! `--json`: the last line is a JSON summary. `--setup arduino-lsm9ds1`: the sensor
//! at ±2000 °/s and ±4 g (70 m°/s and 0.122 mg per count), as Arduino_LSM9DS1 runs it; `--setup
//! bmi270`: the Rev2's BMI270 at the firmware's Rev2 setup (`RigConfig::on_bmi270`: 100 Hz,
//! ±500 °/s, ±2 g, its noise densities), `arduino-bmi270` at Arduino_BMI270_BMM150's (±2000 °/s,
//! ±4 g).
//!
//! `cargo run --profile host -p benchmarks --target host-tuple --bin drift-bench [--rigs N] [--setup S] [--json]`

use benchmarks::moments::Moments;
use benchmarks::setup::Setup;
use calib_core::procedure::{Config, Procedure, Report};
use clap::Parser;
use rig_sim::harness::{run, Faults};
use rig_sim::pan_tilt;
use rig_sim::sim::{Rig, RigConfig, BIAS_WALK_RANGE};
use rig_sim::variant::Variant;
use serde_json::json;

/// The procedure with a constant, a drifting and a waited-out drifting gyro bias.
#[derive(Parser, Debug)]
#[command(name = "drift-bench")]
struct Args {
    /// Simulated rigs per plan.
    #[arg(long, default_value_t = 8)]
    rigs: usize,
    /// Random seed.
    #[arg(long, default_value_t = 19)]
    seed: u64,
    /// The warm-up wait of the third row (s).
    #[arg(long, default_value_t = 300.0)]
    wait_s: f64,
    /// The sensor's ODR and full scales.
    #[arg(long, value_enum, default_value = "default")]
    setup: Setup,
    /// Print a JSON summary as the last line.
    #[arg(long)]
    json: bool,
}

#[derive(Clone, Copy, PartialEq)]
enum Bias {
    Constant,
    Drifting,
    Waited,
}

/// The tempco's coverage: runs that reported it, axes within 1σ and 2σ, axes, their 1σ
/// (°/s/°C); the walks the calibrations measured (°/s/√s).
#[derive(Default)]
struct TempcoScore {
    runs: usize,
    within: [usize; 2],
    axes: usize,
    sigmas: Vec<f64>,
    walks: Vec<f64>,
}

impl TempcoScore {
    /// A run's reports against the rig's true coefficient, and the walk it measured.
    fn add(&mut self, reports: &[Report], truth: &nalgebra::Vector3<f64>, walk: Option<f32>) {
        for r in reports {
            if let Report::TempCo(Some(c)) = r {
                self.runs += 1;
                for k in 0..3 {
                    self.axes += 1;
                    let off = (c.dps_per_c[k] as f64 - truth[k]).abs();
                    self.sigmas.push(c.sigma_dps_per_c[k] as f64);
                    for (n, w) in self.within.iter_mut().enumerate() {
                        *w += usize::from(off <= (n + 1) as f64 * c.sigma_dps_per_c[k] as f64);
                    }
                }
            }
        }
        self.walks.extend(walk.map(|q| q as f64));
    }

    /// Within 1σ and 2σ (fractions; 0 without a run).
    fn cover(&self) -> [f64; 2] {
        self.within.map(|w| if self.axes > 0 { w as f64 / self.axes as f64 } else { 0.0 })
    }

    /// The medians of the 1σ and of the walk measured (0 without one).
    fn medians(&mut self) -> [f64; 2] {
        [&mut self.sigmas, &mut self.walks].map(|v| {
            v.sort_by(f64::total_cmp);
            v.get(v.len() / 2).copied().unwrap_or(0.0)
        })
    }
}

/// E's RMS and largest element of every stored run, each element over the 1σ the record gives
/// it, the times (s) and the failures.
#[derive(Default)]
struct Scores {
    rms: Vec<f64>,
    largest: Vec<f64>,
    z: Vec<f64>,
    times: Vec<f64>,
    failed: Vec<String>,
}

impl Scores {
    /// A run on `rig` (`wait_s` before the press).
    fn add(&mut self, out: &rig_sim::harness::Run, rig: &Rig, wait_s: f64) {
        match (out.stored.first(), out.error) {
            (Some(rec), _) => match pan_tilt::k_error_matrix(rec.gyro_k, rec.accel_m, rig) {
                Some(e) => {
                    self.rms.push((e.norm_squared() / 9.0).sqrt());
                    self.largest.push(e.amax());
                    self.z.extend(pan_tilt::k_error_z(&e, rec.sigma_k));
                    self.times.push(out.end_s - rig_sim::harness::PRESS_AT_S + wait_s);
                }
                None => self.failed.push("no error matrix".to_string()),
            },
            (None, e) => self.failed.push(format!("{e:?}")),
        }
    }

    /// The mean RMS of E, its largest element over the runs and the mean time (s).
    fn summary(&self) -> (f64, f64, f64) {
        (Moments::of(&self.rms).mean, self.largest.iter().fold(0.0f64, |a, b| a.max(*b)), Moments::of(&self.times).mean)
    }

    /// The fraction of E's elements within 2σ of the record's (none without a run).
    fn within_2sigma(&self) -> Option<f64> {
        (!self.z.is_empty()).then(|| self.z.iter().filter(|z| **z <= 2.0).count() as f64 / self.z.len() as f64)
    }
}

/// A fraction as a percentage, "-" for none.
fn pct(x: Option<f64>) -> String {
    x.map_or("-".into(), |x| format!("{:.0}%", 100.0 * x))
}

/// The rig and the procedure's configuration of `plan` for rig `i`.
fn configs(plan: &str, args: &Args, i: usize) -> (RigConfig, Config) {
    let setup = args.setup.setup();
    let (base, cfg): (RigConfig, Config) = match plan {
        "one-servo" => (Variant::Hobby.config(args.seed, i), Config { setup, ..Config::DEFAULT }),
        _ => (pan_tilt::rig_config(args.seed, i), Config { setup, ..Config::PAN_TILT }),
    };
    (args.setup.rig(base, args.seed.wrapping_mul(31).wrapping_add(i as u64)), cfg)
}

/// The firmware's procedure of `plan` on rig `i`, its configuration changed by `edit` first: the
/// run, the rig after it and the bias walk the calibration measured (°/s/√s).
fn calibrate(plan: &str, args: &Args, i: usize, edit: impl FnOnce(&mut RigConfig)) -> (rig_sim::harness::Run, Rig, Option<f32>) {
    let (mut rig_cfg, cfg) = configs(plan, args, i);
    edit(&mut rig_cfg);
    let mut rig = Rig::new(rig_cfg, args.seed + i as u64);
    let mut p = Procedure::new(cfg, None);
    let out = run(&mut rig, &mut p, Faults::default(), 900.0, |_, _, _| {});
    (out, rig, p.bias_walk_dps_rtsec())
}

fn main() {
    let args = Args::parse_from(calib::cli_args());
    let mut rows = vec![];
    let setup = args.setup.setup();
    println!(
        "drift-bench: {} rigs per plan, the firmware's procedure, seed {}, sensor at {} Hz, +-{} dps, +-{} g",
        args.rigs, args.seed, setup.odr_hz, setup.gyro_range_dps, setup.accel_range_g
    );
    println!(
        "{:<10}{:<22}{:>12}{:>14}{:>12}{:>10}{:>8}{:>8}{:>8}{:>10}",
        "plan", "bias", "RMS of E", "largest |E|", "E in 2 sig", "time s", "stored", "failed", "tempco", "in 2 sig"
    );
    for plan in ["one-servo", "pan-tilt"] {
        for bias in [Bias::Constant, Bias::Drifting, Bias::Waited] {
            let mut scores = Scores::default();
            let mut tempco = TempcoScore::default();
            // Squared bias errors at the run's end (°/s, per axis): the record's, the first rest's.
            let (mut bias_sq, mut first_sq) = (vec![], vec![]);
            for i in 0..args.rigs {
                let wait = if bias == Bias::Waited { args.wait_s } else { 0.0 };
                let (out, rig, walk) = calibrate(plan, &args, i, |c| {
                    if bias == Bias::Constant {
                        *c = c.constant_bias();
                    }
                    if let Some(w) = c.warmup.as_mut() {
                        w.since_power_on_s += wait;
                    }
                });
                tempco.add(&out.reports, &rig.config().gyro.bias_tempco_dps_per_c, walk);
                let t = rig.truth();
                if let (Some(rec), Some(first)) =
                    (out.stored.first(), out.reports.iter().find_map(|r| if let Report::Bias(b) = r { Some(b.bias_dps) } else { None }))
                {
                    // The record's bias applied at the end's temperature, as a sketch does.
                    let shift = |k: usize| match (rec.tempco, rec.temp_c) {
                        (Some(c), Some(t0)) => c.dps_per_c[k] as f64 * (t.temp_c - t0 as f64),
                        _ => 0.0,
                    };
                    for (k, first_k) in first.iter().enumerate() {
                        bias_sq.push((rec.gyro_bias_dps[k] as f64 + shift(k) - t.gyro_bias_dps[k]).powi(2));
                        first_sq.push((*first_k as f64 - t.gyro_bias_dps[k]).powi(2));
                    }
                }
                scores.add(&out, &rig, wait);
            }
            let name = match bias {
                Bias::Constant => "constant".to_string(),
                Bias::Drifting => "drifting".to_string(),
                Bias::Waited => format!("drifting, {:.0} s wait", args.wait_s),
            };
            let (r, m, t) = scores.summary();
            let (tempco_runs, cover) = (tempco.runs, tempco.cover()[1]);
            let (bias_rms, first_rms) = (Moments::of(&bias_sq).mean.sqrt(), Moments::of(&first_sq).mean.sqrt());
            let e_cover = scores.within_2sigma();
            println!(
                "{plan:<10}{name:<22}{r:>12.2e}{m:>14.2e}{:>12}{t:>10.0}{:>8}{:>8}{tempco_runs:>8}{:>9.0}%",
                pct(e_cover),
                scores.rms.len(),
                scores.failed.len(),
                100.0 * cover
            );
            println!("  bias error at the end {bias_rms:.4} dps RMS (the first rest's alone: {first_rms:.4})");
            for f in &scores.failed {
                println!("  failed: {f}");
            }
            rows.push(json!({"plan": plan, "bias": name, "rms_mean": r, "max": m, "e_within_2sigma": e_cover, "time_s": t, "stored": scores.rms.len(), "failed": scores.failed,
                "tempco_runs": tempco_runs, "tempco_within_2sigma": cover, "bias_rms_dps": bias_rms, "first_rest_bias_rms_dps": first_rms}));
        }
    }
    // The tempco's coverage over the walk's range: its ends and middle, and the per-rig draw.
    let (lo, hi) = BIAS_WALK_RANGE;
    println!(
        "\nthe bias's temperature coefficient by random walk (drifting rigs, the walk drawn log-uniform over {lo:.2e}..{hi:.2e} dps/rt s)"
    );
    println!("{:<10}{:>14}{:>8}{:>10}{:>10}{:>12}{:>16}", "plan", "walk", "tempco", "in 1 sig", "in 2 sig", "1 sig", "walk measured");
    let mut walk_rows = vec![];
    for plan in ["one-servo", "pan-tilt"] {
        for walk in [Some(lo), Some((lo * hi).sqrt()), Some(hi), None] {
            let mut tempco = TempcoScore::default();
            for i in 0..args.rigs {
                let (out, rig, measured) = calibrate(plan, &args, i, |c| {
                    if let Some(q) = walk {
                        c.bias_rw_dps_rtsec = q;
                    }
                });
                tempco.add(&out.reports, &rig.config().gyro.bias_tempco_dps_per_c, measured);
            }
            let name = walk.map_or("drawn".to_string(), |q| format!("{q:.2e}"));
            let ([one, two], [sigma, median]) = (tempco.cover(), tempco.medians());
            println!("{plan:<10}{name:>14}{:>8}{:>9.0}%{:>9.0}%{sigma:>12.4}{median:>16.2e}", tempco.runs, 100.0 * one, 100.0 * two);
            walk_rows.push(json!({"plan": plan, "walk": walk, "tempco_runs": tempco.runs, "within_1sigma": one, "within_2sigma": two,
                "sigma_median": sigma, "walk_measured_median": median}));
        }
    }
    // The accuracy across the part's ODR error: every rig at one fixed error.
    let (odr_lo, odr_hi) = args.setup.odr_error_range();
    println!(
        "\nE at fixed ODR errors (drifting rigs, every rig at the error; the rigs above draw it over {:+.1}..{:+.1} %)",
        100.0 * odr_lo,
        100.0 * odr_hi
    );
    println!("{:<10}{:>10}{:>12}{:>14}{:>12}{:>8}{:>8}", "plan", "ODR err", "RMS of E", "largest |E|", "E in 2 sig", "stored", "failed");
    let mut odr_rows = vec![];
    for plan in ["one-servo", "pan-tilt"] {
        for odr_error in [odr_lo, 0.5 * (odr_lo + odr_hi), odr_hi] {
            let mut scores = Scores::default();
            for i in 0..args.rigs {
                let (out, rig, _) = calibrate(plan, &args, i, |c| c.odr_error = odr_error);
                scores.add(&out, &rig, 0.0);
            }
            let ((r, m, _), cover) = (scores.summary(), scores.within_2sigma());
            let odr_pct = 100.0 * odr_error;
            println!("{plan:<10}{odr_pct:>9.1}%{r:>12.2e}{m:>14.2e}{:>12}{:>8}{:>8}", pct(cover), scores.rms.len(), scores.failed.len());
            for f in &scores.failed {
                println!("  failed: {f}");
            }
            odr_rows.push(json!({"plan": plan, "odr_error_pct": odr_pct, "rms_mean": r, "max": m, "e_within_2sigma": cover,
                "stored": scores.rms.len(), "failed": scores.failed}));
        }
    }
    if args.json {
        println!(
            "{}",
            json!({"rigs": args.rigs, "seed": args.seed, "setup": args.setup.json(), "rows": rows, "walk_range": [lo, hi], "walks": walk_rows,
                "odr_range_pct": [100.0 * odr_lo, 100.0 * odr_hi], "odr_rows": odr_rows})
        );
    }
}
