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
//! (1σ, 2σ) and the walk the calibration measured (median, `TempFit::walk_dps_rtsec`).
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

/// The rig and the procedure's configuration of `plan` for rig `i`.
fn configs(plan: &str, args: &Args, i: usize) -> (RigConfig, Config) {
    let setup = args.setup.setup();
    let (base, cfg): (RigConfig, Config) = match plan {
        "one-servo" => (Variant::Hobby.config(args.seed, i), Config { setup, ..Config::DEFAULT }),
        _ => (pan_tilt::rig_config(args.seed, i), Config { setup, ..Config::PAN_TILT }),
    };
    (args.setup.rig(base, args.seed.wrapping_mul(31).wrapping_add(i as u64)), cfg)
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
        "{:<10}{:<22}{:>12}{:>14}{:>10}{:>8}{:>8}{:>8}{:>10}",
        "plan", "bias", "RMS of E", "largest |E|", "time s", "stored", "failed", "tempco", "in 2 sig"
    );
    for plan in ["one-servo", "pan-tilt"] {
        for bias in [Bias::Constant, Bias::Drifting, Bias::Waited] {
            let (mut rms, mut largest, mut times, mut failed) = (vec![], vec![], vec![], vec![]);
            let mut tempco = TempcoScore::default();
            // Squared bias errors at the run's end (°/s, per axis): the record's, the first rest's.
            let (mut bias_sq, mut first_sq) = (vec![], vec![]);
            for i in 0..args.rigs {
                let (base, cfg) = configs(plan, &args, i);
                let mut rig_cfg = if bias == Bias::Constant { base.constant_bias() } else { base };
                let wait = if bias == Bias::Waited { args.wait_s } else { 0.0 };
                if let Some(w) = rig_cfg.warmup.as_mut() {
                    w.since_power_on_s += wait;
                }
                let mut rig = Rig::new(rig_cfg, args.seed + i as u64);
                let mut p = Procedure::new(cfg, None);
                let out = run(&mut rig, &mut p, Faults::default(), 900.0, |_, _, _| {});
                tempco.add(&out.reports, &rig_cfg.gyro.bias_tempco_dps_per_c, p.bias_walk_dps_rtsec());
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
                match (out.stored.first(), out.error) {
                    (Some(rec), _) => match pan_tilt::k_error(rec.gyro_k, rec.accel_m, &rig) {
                        Some((mx, r)) => {
                            rms.push(r);
                            largest.push(mx);
                            times.push(out.end_s - rig_sim::harness::PRESS_AT_S + wait);
                        }
                        None => failed.push("no error matrix".to_string()),
                    },
                    (None, e) => failed.push(format!("{e:?}")),
                }
            }
            let name = match bias {
                Bias::Constant => "constant".to_string(),
                Bias::Drifting => "drifting".to_string(),
                Bias::Waited => format!("drifting, {:.0} s wait", args.wait_s),
            };
            let (r, m, t) = (Moments::of(&rms).mean, largest.iter().fold(0.0f64, |a, b| a.max(*b)), Moments::of(&times).mean);
            let (tempco_runs, cover) = (tempco.runs, tempco.cover()[1]);
            let (bias_rms, first_rms) = (Moments::of(&bias_sq).mean.sqrt(), Moments::of(&first_sq).mean.sqrt());
            println!(
                "{plan:<10}{name:<22}{r:>12.2e}{m:>14.2e}{t:>10.0}{:>8}{:>8}{tempco_runs:>8}{:>9.0}%",
                rms.len(),
                failed.len(),
                100.0 * cover
            );
            println!("  bias error at the end {bias_rms:.4} dps RMS (the first rest's alone: {first_rms:.4})");
            for f in &failed {
                println!("  failed: {f}");
            }
            rows.push(json!({"plan": plan, "bias": name, "rms_mean": r, "max": m, "time_s": t, "stored": rms.len(), "failed": failed,
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
                let (mut rig_cfg, cfg) = configs(plan, &args, i);
                if let Some(q) = walk {
                    rig_cfg.bias_rw_dps_rtsec = q;
                }
                let mut rig = Rig::new(rig_cfg, args.seed + i as u64);
                let mut p = Procedure::new(cfg, None);
                let out = run(&mut rig, &mut p, Faults::default(), 900.0, |_, _, _| {});
                tempco.add(&out.reports, &rig_cfg.gyro.bias_tempco_dps_per_c, p.bias_walk_dps_rtsec());
            }
            let name = walk.map_or("drawn".to_string(), |q| format!("{q:.2e}"));
            let ([one, two], [sigma, median]) = (tempco.cover(), tempco.medians());
            println!("{plan:<10}{name:>14}{:>8}{:>9.0}%{:>9.0}%{sigma:>12.4}{median:>16.2e}", tempco.runs, 100.0 * one, 100.0 * two);
            walk_rows.push(json!({"plan": plan, "walk": walk, "tempco_runs": tempco.runs, "within_1sigma": one, "within_2sigma": two,
                "sigma_median": sigma, "walk_measured_median": median}));
        }
    }
    if args.json {
        println!(
            "{}",
            json!({"rigs": args.rigs, "seed": args.seed, "setup": args.setup.json(), "rows": rows, "walk_range": [lo, hi], "walks": walk_rows})
        );
    }
}
