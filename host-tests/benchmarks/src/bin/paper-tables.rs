//! Reproduces the simulation section of Li et al. (the paper in shared/seed) with calib-core,
//! prints our numbers beside the paper's in its table layout, then compares the paper's
//! estimator with the speed-free sweep estimator on a realistic hobby-servo rig.
//!
//! `cargo paper-tables [--json] [--runs N] [--noise-runs N] [--rig-runs N] [--seed S]`
//! With `--json` the last stdout line is a JSON summary of everything printed.

use benchmarks::hobby_servo;
use benchmarks::moments::Moments;
use benchmarks::paper_model::{run, PaperCase, PaperProtocol};
use calib_core::Error;
use clap::Parser;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::{json, Value};

/// The paper's simulation tables reproduced with calib-core, and the estimator comparison on
/// simulated hobby-servo rigs.
#[derive(Parser, Debug)]
#[command(name = "paper-tables")]
struct Args {
    /// Print a JSON summary of every table as the last line.
    #[arg(long)]
    json: bool,
    /// Runs of Tables I and II.
    #[arg(long, default_value_t = 100)]
    runs: usize,
    /// Runs per noise level of Table III (the paper used 100 000).
    #[arg(long, default_value_t = 10_000)]
    noise_runs: usize,
    /// Simulated rigs per variant of the hobby-servo comparison.
    #[arg(long, default_value_t = 20)]
    rig_runs: usize,
    /// Random seed.
    #[arg(long, default_value_t = 2024)]
    seed: u64,
}

/// Runs `n` cases; returns per-axis errors `K̂ − K` and the failures by reason.
fn batch(
    n: usize,
    rng: &mut ChaCha8Rng,
    proto: &PaperProtocol,
    mut make: impl FnMut(&mut ChaCha8Rng) -> PaperCase,
) -> ([Vec<f64>; 3], [Vec<f64>; 3], Vec<Error>) {
    let (mut est, mut uncal, mut failed) = ([vec![], vec![], vec![]], [vec![], vec![], vec![]], vec![]);
    for _ in 0..n {
        let case = make(rng);
        match run(&case, proto, rng) {
            Ok(k) => {
                for i in 0..3 {
                    est[i].push(k[i] - case.k[i]);
                    uncal[i].push(1.0 - case.k[i]);
                }
            }
            Err(e) => failed.push(e),
        }
    }
    (est, uncal, failed)
}

fn failures_json(f: &[Error]) -> Value {
    json!(f.iter().map(|e| e.to_string()).collect::<Vec<_>>())
}

/// Prints the failed runs grouped by reason.
fn print_failures(f: &[Error]) {
    let mut counts: Vec<(String, usize)> = vec![];
    for e in f {
        let name = format!("{e:?}");
        let name = name.split([' ', '{', '(']).next().unwrap_or("").to_string();
        match counts.iter_mut().find(|c| c.0 == name) {
            Some(c) => c.1 += 1,
            None => counts.push((name, 1)),
        }
    }
    println!("failed runs: {} {:?}", f.len(), counts);
}

const AXES: [&str; 3] = ["X", "Y", "Z"];

fn table1(args: &Args, rng: &mut ChaCha8Rng, proto: &PaperProtocol) -> Value {
    let paper = [
        [[0.0024, 0.0035, 0.9148], [0.0039, 0.0033, 0.1943], [0.0064, 0.0030, 0.1975]],
        [[0.0001, 1.8815e-6, 0.0067], [0.0001, 2.3400e-6, 0.0078], [0.0001, 1.4951e-6, 0.0063]],
    ];
    let (est, uncal, failed) = batch(args.runs, rng, proto, PaperCase::random);
    println!("\nTable I. Mean, variance and range of the scale-factor error before and after calibration");
    println!(
        "({} runs: K ~ U(0.9,1.1), bias ~ U(-2,2) deg/s, accel noise N(0,0.005^2), speed noise N(0,(0.05w)^2), w = 20 deg/s)",
        args.runs
    );
    println!("{:<13}{:<5}{:>24}{:>28}{:>24}", "Status", "Axis", "Mean (ours | paper)", "Variance (ours | paper)", "Range (ours | paper)");
    let mut out = vec![];
    for (s, (status, data)) in [("Uncalibrated", &uncal), ("Calibrated", &est)].into_iter().enumerate() {
        for i in 0..3 {
            let m = Moments::of(&data[i]);
            let p = paper[s][i];
            println!(
                "{:<13}{:<5}{:>11.4} | {:<10.4}{:>13.3e} | {:<12.3e}{:>10.4} | {:<10.4}",
                if i == 0 { status } else { "" },
                AXES[i],
                m.mean,
                p[0],
                m.variance,
                p[1],
                m.range,
                p[2]
            );
            out.push(json!({"status": status, "axis": AXES[i], "ours": m.json(),
                "paper": {"mean": p[0], "variance": p[1], "range": p[2]}}));
        }
    }
    print_failures(&failed);
    json!({"rows": out, "failed": failures_json(&failed)})
}

fn table2(args: &Args, rng: &mut ChaCha8Rng, proto: &PaperProtocol) -> Value {
    // Paper Table II: one example run per axis.
    let paper = [[-0.0165, -0.0049, -0.0027], [0.04406, -0.0103, -0.0015], [-0.0999, -0.0108, -0.0009]];
    let with_error = |pre: bool| {
        move |r: &mut ChaCha8Rng| PaperCase {
            accel_scale: std::array::from_fn(|_| r.random_range(0.95..1.05)),
            // U(-0.005, 0.005) m/s^2, in g.
            accel_offset_g: std::array::from_fn(|_| r.random_range(-0.005..0.005) / 9.80665),
            precalibrate_accel: pre,
            ..PaperCase::random(r)
        }
    };
    let (clean, uncal, f0) = batch(args.runs, rng, proto, PaperCase::random);
    let (raw, _, f1) = batch(args.runs, rng, proto, with_error(false));
    let (pre, _, f2) = batch(args.runs, rng, proto, with_error(true));
    println!("\nTable II. Scale-factor error with and without accelerometer error (RMS over {} runs; paper: one run)", args.runs);
    println!("accel scale ~ U(0.95,1.05), offset ~ U(-0.005,0.005) m/s^2; pre-calibration: 6 axis poses, 6-parameter fit (Ye et al.)");
    println!(
        "{:<5}{:>22}{:>26}{:>30}{:>28}",
        "Axis", "Uncal. (ours|paper)", "CR acc err (ours|paper)", "CR acc err+precal (ours)", "CR no acc err (ours|paper)"
    );
    let mut rows = vec![];
    for i in 0..3 {
        let m = [&uncal, &raw, &pre, &clean].map(|d| Moments::of(&d[i]).rms);
        println!(
            "{:<5}{:>12.4} | {:<8.4}{:>14.4} | {:<8.4}{:>22.4}{:>16.4} | {:<8.4}",
            AXES[i], m[0], paper[i][0], m[1], paper[i][1], m[2], m[3], paper[i][2]
        );
        rows.push(json!({"axis": AXES[i], "rms_uncalibrated": m[0], "rms_with_accel_error": m[1],
            "rms_with_accel_error_precalibrated": m[2], "rms_without_accel_error": m[3],
            "paper_example": {"uncalibrated": paper[i][0], "with_accel_error": paper[i][1], "without_accel_error": paper[i][2]}}));
    }
    let failed: Vec<Error> = f0.into_iter().chain(f1).chain(f2).collect();
    print_failures(&failed);
    json!({"rows": rows, "failed": failures_json(&failed)})
}

fn table3(args: &Args, rng: &mut ChaCha8Rng, proto: &PaperProtocol) -> Value {
    // Paper Table III: mean, variance, kurtosis, skewness of K per axis and noise level.
    let paper: [[[f64; 4]; 4]; 3] = [
        [
            [1.100, 2.374e-7, -0.006, 0.007],
            [1.100, 2.447e-7, -0.020, 0.011],
            [1.100, 9.853e-7, -0.005, 0.004],
            [1.099, 7.519e-5, 0.018, -0.004],
        ],
        [
            [0.899, 1.758e-6, -0.020, 0.008],
            [0.899, 1.765e-6, -0.020, 0.007],
            [0.900, 2.509e-6, -0.011, -0.006],
            [0.900, 7.738e-5, 0.002, 0.007],
        ],
        [
            [1.200, 4.846e-6, -0.019, 0.019],
            [1.200, 4.854e-6, -0.019, 0.019],
            [1.200, 5.562e-6, 0.0002, 0.004],
            [1.199, 7.980e-5, 0.010, -0.002],
        ],
    ];
    let sigmas = [0.01, 0.1, 1.0, 10.0];
    let k_true = [1.1, 0.9, 1.2];
    let mut per = vec![];
    for &s in &sigmas {
        let (est, _, failed) = batch(args.noise_runs, rng, proto, |r| PaperCase {
            k: k_true,
            gyro_noise_dps: s,
            omega_dps: 10.0,
            bias_known: true,
            geometry: Some(([0.48, -0.56, 0.67], 45.0)),
            ..PaperCase::random(r)
        });
        let k: [Vec<f64>; 3] = std::array::from_fn(|i| est[i].iter().map(|e| e + k_true[i]).collect());
        per.push((k, failed));
    }
    println!("\nTable III. Scale factors under gyro noise (K = [1.1, 0.9, 1.2], w = 10 deg/s, bias removed;\n {} runs per level, paper: 100000; fixed axis (0.48,-0.56,0.67), tilt 45 deg; {} rotation samples)", args.noise_runs, proto.rotation_samples * proto.noise_study_factor);
    println!(
        "{:<5}{:<12}{:>20}{:>26}{:>22}{:>22}",
        "Axis", "noise sd", "Mean (ours|paper)", "Variance (ours|paper)", "Kurtosis (ours|paper)", "Skewness (ours|paper)"
    );
    let mut rows = vec![];
    for i in 0..3 {
        for (j, &s) in sigmas.iter().enumerate() {
            let m = Moments::of(&per[j].0[i]);
            let p = paper[i][j];
            println!(
                "{:<5}{:<12}{:>9.3} | {:<8.3}{:>11.3e} | {:<11.3e}{:>8.3} | {:<10.3}{:>9.3} | {:<10.3}",
                if j == 0 { AXES[i] } else { "" },
                format!("N(0,{s}^2)"),
                m.mean,
                p[0],
                m.variance,
                p[1],
                m.kurtosis,
                p[2],
                m.skewness,
                p[3]
            );
            rows.push(json!({"axis": AXES[i], "noise_sd_dps": s, "ours": m.json(),
                "paper": {"mean": p[0], "variance": p[1], "kurtosis": p[2], "skewness": p[3]}}));
        }
    }
    let failed: Vec<Error> = per.into_iter().flat_map(|p| p.1).collect();
    print_failures(&failed);
    json!({"rows": rows, "failed": failures_json(&failed)})
}

fn main() {
    let args = Args::parse_from(calib::cli_args());
    let proto = PaperProtocol::default();
    println!("paper-tables: Li et al., field calibration of triaxial MEMS gyroscopes, reproduced with calib-core");
    println!(
        "Protocol choices the paper leaves open (ours): {} Hz sampling; {} static poses at random shaft angles,",
        proto.rate_hz, proto.poses
    );
    println!(
        "  {} samples averaged per pose; {} rotation samples; bias from {} rest samples; shaft tilt U({},{}) deg",
        proto.pose_samples, proto.rotation_samples, proto.rest_samples, proto.tilt_deg.0, proto.tilt_deg.1
    );
    println!(
        "  from vertical, random mounting with every axis component >= {}; gyro white noise 0.01 deg/s outside Table III;",
        proto.min_axis_component
    );
    println!("  poses must span >= 45 deg; seed {}.", args.seed);
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let t1 = table1(&args, &mut rng, &proto);
    let t2 = table2(&args, &mut rng, &proto);
    let t3 = table3(&args, &mut rng, &proto);
    let rig = hobby_servo::compare(args.rig_runs, args.seed);
    if args.json {
        println!(
            "{}",
            json!({"seed": args.seed, "runs": args.runs, "noise_runs": args.noise_runs, "table1": t1, "table2": t2, "table3": t3, "hobby_servo": rig})
        );
    }
}
