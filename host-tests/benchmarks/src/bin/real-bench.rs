//! `real-bench [--json]`: `gyrocal-calib`'s code on public sessions recorded on real IMUs by
//! other projects (`../shared/data/real/` beside the repository: sources, licences and
//! conversions in its README), beside a peer's result where one exists.
//!
//! The peer: imucal 2.6.0 (PyPI) `FerrarisCalibration` on the continuous Ferraris session with
//! its own section list (`example_data/example_ferraris_session_list.json`, 102.4 Hz), converted
//! to `ω = K (g − b)` as `K = (K_g R_g)⁻¹`. imu_tk publishes no result for its Xsens session.

use calib::csvlog;
use calib::offline::{self, Options};
use calib::real;
use clap::Parser;
use serde_json::{json, Value};
use std::process::ExitCode;

/// The real sessions, calibrated.
#[derive(Parser, Debug)]
#[command(name = "real-bench")]
struct Args {
    /// Print one JSON summary line at the end.
    #[arg(long)]
    json: bool,
}

/// One session under one set of options: the gyro `K` diagonal with its 1σ, or the error.
fn run(name: &str, label: &str, options: &Options, peer: Option<[f64; 3]>) -> Result<Value, String> {
    let log = csvlog::parse(&real::session(name)?).map_err(|e| format!("{name}: {e}"))?;
    let out = offline::calibrate_log(&log, options, None);
    let mut v = json!({ "session": name, "options": label, "peer_k": peer });
    match out {
        Err(e) => v["error"] = json!(e.to_string()),
        Ok(c) => {
            v["hand_moves"] = json!(c.hand_moves);
            match (&c.full, &c.gyro) {
                (Some(Ok(f)), _) => {
                    let k: Vec<f64> = (0..3).map(|i| f.k[i][i] as f64).collect();
                    let s: Vec<f64> = (0..3).map(|i| f.sigma_k[i][i] as f64).collect();
                    v["k"] = json!(k);
                    v["sigma_k"] = json!(s);
                    if let Some(p) = peer {
                        v["z"] = json!((0..3).map(|i| (k[i] - p[i]) / s[i]).collect::<Vec<_>>());
                    }
                }
                (_, Err(e)) => v["error"] = json!(e.to_string()),
                (_, Ok(g)) => v["error"] = json!(format!("no full K; a diagonal K of method {:?}", g.method)),
            }
        }
    }
    Ok(v)
}

fn main() -> ExitCode {
    let args = Args::parse_from(calib::cli_args());
    let whole = Options { whole_turns: true, ..Options::default() };
    let cases = [
        ("imucal_ferraris_session.csv", "--whole-turns", whole, Some(real::IMUCAL_FERRARIS_K)),
        ("imucal_ferraris_session.csv", "(none)", Options::default(), Some(real::IMUCAL_FERRARIS_K)),
        ("imucal_annotated_session.csv", "(none)", Options::default(), None),
        ("imu_tk_xsens.txt", "(none)", Options::default(), None),
    ];
    let mut rows = vec![];
    for (name, label, options, peer) in cases {
        match run(name, label, &options, peer) {
            Ok(v) => {
                println!("{name} {label}: {v}");
                rows.push(v);
            }
            Err(e) => {
                eprintln!("real-bench: {e}");
                return ExitCode::from(2);
            }
        }
    }
    if args.json {
        println!("{}", json!({ "sessions": rows }));
    }
    ExitCode::SUCCESS
}
