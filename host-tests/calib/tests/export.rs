//! `calib_core::export` on the host: the JSON parses and round-trips, its `gyro` and `accel`
//! are calib's own keys; the C snippet and the Rust constants compile; `calib LOG --export`.

use calib::csvlog;
use calib::offline;
use calib::port::record_from_json;
use calib_core::export::{self, Format};
use calib_core::record::Record;
use common::{calib, simulated_log};
use rig_sim::variant::Variant;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

mod common;

/// A simulated log and calib's result on it, shared by the tests.
fn calibrated() -> &'static (String, offline::Calibration) {
    static C: OnceLock<(String, offline::Calibration)> = OnceLock::new();
    C.get_or_init(|| {
        let log = simulated_log(Variant::Hobby.config(9, 0)).0;
        let c = offline::calibrate(&csvlog::parse(&log).unwrap().rows, None).unwrap();
        (log, c)
    })
}

/// calib's record with a stored record's sequence number and temperature.
fn record() -> Record {
    Record { seq: 3, temp_c: 24.25, ..calibrated().1.record().unwrap() }
}

fn text(rec: &Record, f: Format) -> String {
    let mut s = String::new();
    export::write(&mut s, rec, f).unwrap();
    s
}

fn dir() -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("export");
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn keys(v: &serde_json::Value) -> Vec<String> {
    let mut k: Vec<String> = v.as_object().unwrap().keys().cloned().collect();
    k.sort();
    k
}

#[test]
fn json_parses_with_calibs_keys_and_round_trips_to_1e7() {
    let rec = record();
    let line = text(&rec, Format::Json);
    let v: serde_json::Value = serde_json::from_str(&line).unwrap();
    // The same `gyro` and `accel` as calib's output, value for value (to the decimals written).
    let calib_out: serde_json::Value = serde_json::from_str(&calibrated().1.json(0)).unwrap();
    for part in ["gyro", "accel"] {
        assert_eq!(keys(&v[part]), keys(&calib_out[part]), "{part}");
    }
    assert_eq!(v["gyro"]["method"], calib_out["gyro"]["method"]);
    let q = &v["quality"];
    assert_eq!((q["source"].as_str(), q["seq"].as_u64(), q["poses"].as_u64()), (Some("board"), Some(3), Some(rec.poses as u64)));
    for (i, j) in (0..3).flat_map(|i| (0..3).map(move |j| (i, j))) {
        let (k, ck) = (v["gyro"]["K"][i][j].as_f64().unwrap(), calib_out["gyro"]["K"][i][j].as_f64().unwrap());
        assert!((k - ck).abs() <= 5e-8 + 1e-9, "K[{i}][{j}] {k} vs {ck}");
    }
    // Rebuilt from its JSON: every exported field to its decimals.
    let back = record_from_json(&line).unwrap();
    let close = |a: &[f32], b: &[f32], tol: f32| a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol);
    assert!(close(back.gyro_k.as_flattened(), rec.gyro_k.as_flattened(), 1e-7), "{back:?}");
    assert!(close(back.accel_m.as_flattened(), rec.accel_m.as_flattened(), 1e-7));
    assert!(close(&back.gyro_bias_dps, &rec.gyro_bias_dps, 5.5e-6) && close(&back.accel_offset_g, &rec.accel_offset_g, 5.5e-7));
    assert!(close(back.sigma_k.as_flattened(), rec.sigma_k.as_flattened(), 1e-9));
    assert_eq!((back.seq, back.method, back.accel_model, back.poses, back.rows), (3, rec.method, rec.accel_model, rec.poses, rec.rows));
    assert!((back.temp_c - 24.25).abs() < 1e-6 && (back.accel_rms_g - rec.accel_rms_g).abs() <= 5e-8);
    // calib's own record (never stored) says so; an unknown temperature is null.
    let own = text(&calibrated().1.record().unwrap(), Format::Json);
    assert!(own.contains("\"source\":\"calib\",\"seq\":0,\"temp_c\":null,"), "{own}");
    assert!(record_from_json(&own).unwrap().temp_c.is_nan());
    // Bad result lines are named.
    assert!(record_from_json("{\"gyro\":").unwrap_err().starts_with("not the expected JSON"));
    let at = line.find("\"K\":[[").unwrap() + 6;
    let end = at + line[at..].find(',').unwrap();
    let no_k = format!("{}null{}", &line[..at], &line[end..]);
    assert!(record_from_json(&no_k).unwrap_err().starts_with("gyro K, bias_dps, accel M and offset_g must all be numbers"));
}

/// Runs a tool if it exists: `None` (with a note) if not.
fn tool(prog: &str, args: &[&str]) -> Option<std::process::Output> {
    match Command::new(prog).args(args).output() {
        Ok(o) => Some(o),
        Err(e) => {
            eprintln!("note: {prog} not runnable ({e}): that check is skipped");
            None
        }
    }
}

#[test]
fn the_c_snippet_compiles() {
    let snippet = text(&record(), Format::C);
    assert!(snippet.lines().all(|l| l.len() <= export::MAX_LINE));
    let user = "\nfloat use_all(void) {\n    float g[3] = {1.0f, 2.0f, 3.0f}, w[3];\n    gyrocal_apply(g, w);\n    \
                return w[0] + ACCEL_M[0][0] * (g[0] - ACCEL_OFFSET_G[0]);\n}\n";
    let c = dir().join("gyrocal.c");
    std::fs::write(&c, snippet + user).unwrap();
    let c = c.to_str().unwrap();
    let Some(o) = tool("cc", &["-std=c99", "-Wall", "-Wextra", "-Werror", "-fsyntax-only", c]) else { return };
    assert!(o.status.success(), "cc: {}", String::from_utf8_lossy(&o.stderr));
    // Arduino sketches are C++.
    if let Some(o) = tool("c++", &["-x", "c++", "-Wall", "-Wextra", "-Werror", "-fsyntax-only", c]) {
        assert!(o.status.success(), "c++: {}", String::from_utf8_lossy(&o.stderr));
    }
}

#[test]
fn the_rust_constants_compile() {
    let rs = dir().join("gyrocal.rs");
    std::fs::write(&rs, text(&record(), Format::Rust) + "\n").unwrap();
    let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
    let out = dir().join("gyrocal.rmeta");
    let args = [
        "--edition",
        "2021",
        "--crate-type",
        "lib",
        "--emit",
        "metadata",
        "-D",
        "warnings",
        "-o",
        out.to_str().unwrap(),
        rs.to_str().unwrap(),
    ];
    let Some(o) = tool(&rustc, &args) else { return };
    assert!(o.status.success(), "rustc: {}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn calib_exports_an_offline_result() {
    let log = dir().join("sim.csv");
    std::fs::write(&log, &calibrated().0).unwrap();
    let log = log.to_str().unwrap();
    let (code, out, err) = calib(&[log, "--export", "c"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("static const float GYRO_K[3][3] = {") && !out.contains("\"quality\""), "{out}");
    let file = dir().join("gyrocal.h");
    let (code, out, err) = calib(&[log, "--export", "json", "--out", file.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("\"quality\":{\"missing\":[]"), "calib's own JSON stays on stdout: {out}");
    let exported = std::fs::read_to_string(&file).unwrap();
    assert_eq!(exported.lines().count(), 1);
    let (got, want) = (record_from_json(exported.trim()).unwrap().gyro_k, calibrated().1.record().unwrap().gyro_k);
    assert!(got.as_flattened().iter().zip(want.as_flattened()).all(|(a, b)| (a - b).abs() <= 1e-7), "{got:?} {want:?}");
    let (code, _, err) = calib(&["--out", "x.h", log]);
    assert_eq!(code, 2, "--out needs --export: {err}");
}
