//! `calib_core::formats::export` on the host: the firmware's hand-written JSON is the serde schema
//! (`RecordJson`) field for field, parses and round-trips, its `gyro` and `accel` are calib's own
//! keys; the C snippet and the Rust constants compile; `calib LOG --export`.

use calib::csvlog;
use calib::offline;
use calib::port::record_from_json;
use calib_core::estimators::accel::AccelModel;
use calib_core::estimators::bias::TempCo;
use calib_core::estimators::gyro::Method;
use calib_core::formats::export::{self, Format, NotFinite, RecordJson, Source};
use calib_core::formats::record::{Record, SensorSetup};
use common::{calib, simulated_log};
use rig_sim::variant::Variant;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use crate::common;

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
    Record { seq: 3, temp_c: Some(24.25), ..calibrated().1.record().unwrap() }
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

/// Every leaf of a JSON value with its path (`quality.sigma_K[2][1]`) and its value (a number as
/// the f64 it reads as, whatever its digits).
fn leaves(v: &serde_json::Value) -> BTreeMap<String, String> {
    fn walk(v: &serde_json::Value, at: String, out: &mut BTreeMap<String, String>) {
        let leaf = match v {
            serde_json::Value::Object(m) => return m.iter().for_each(|(k, v)| walk(v, format!("{at}.{k}"), out)),
            serde_json::Value::Array(a) => return a.iter().enumerate().for_each(|(i, v)| walk(v, format!("{at}[{i}]"), out)),
            serde_json::Value::Number(n) => format!("number {:?}", n.as_f64().unwrap()),
            serde_json::Value::String(s) => format!("string {s}"),
            other => other.to_string(),
        };
        out.insert(at, leaf);
    }
    let mut out = BTreeMap::new();
    walk(v, String::new(), &mut out);
    out
}

/// The paths of [`leaves`], with the kind of value there.
fn paths(v: &serde_json::Value) -> BTreeSet<String> {
    leaves(v).into_iter().map(|(at, v)| format!("{at}: {}", v.split(' ').next().unwrap_or_default())).collect()
}

/// A record whose every value is written exactly at its decimals (binary fractions), with the
/// fields JSON does not carry at 0.
fn exact_record() -> Record {
    Record {
        seq: 5,
        temp_c: Some(24.25),
        gyro_k: [[1.0078125, -0.0078125, 0.0], [0.0078125, 0.9921875, 0.0], [0.0, 0.5, 1.015625]],
        gyro_bias_dps: [0.5, -1.25, 2.03125],
        method: Method::Full,
        accel_m: [[1.0, 0.0, 0.0], [0.0, 0.9921875, 0.0], [0.0, 0.0, 1.0078125]],
        accel_offset_g: [0.015625, -0.03125, 0.0],
        accel_model: AccelModel::NineParam,
        poses: 25,
        rows: 38,
        sigma_k: [[0.001953125, 0.005859375, 0.0], [0.0, 0.00390625, 0.0], [0.0, 0.0, 0.0078125]],
        invariant_before_rel: 0.0,
        invariant_after_rel: 0.0,
        condition: 3.125,
        tilt_deg: 0.0,
        span_deg: 0.0,
        accel_rms_g: 0.0078125,
        residual_rms: 0.015625,
        non_coplanar_deg: 54.125,
        setup: SensorSetup { odr_hz: 952.0, gyro_range_dps: 2000.0, accel_range_g: 4.0, ..SensorSetup::DEFAULT },
        tempco: Some(TempCo {
            dps_per_c: [0.03125, -0.046875, 0.015625],
            sigma_dps_per_c: [0.015625, 0.03125, 0.0625],
            range_c: [24.0, 27.5],
        }),
        mag: Some(calib_core::estimators::mag::MagCal {
            a: [[1.015625, 0.0078125, 0.0], [0.0078125, 0.984375, -0.015625], [0.0, 0.015625, 1.0]],
            offset_ut: [12.5, -30.25, 4.125],
            field_ut: 48.5,
            sigma_field_ut: 0.125,
            dip_deg: 61.25,
            sigma_dip_deg: 0.125,
            alignment_deg: 1.5,
            sigma_alignment_deg: 0.375,
            residual_ut: 0.25,
            coverage: 0.875,
            samples: 140,
            poses: 11,
        }),
    }
}

#[test]
fn the_boards_hand_written_line_is_the_serde_schema() {
    // The firmware's line (written without serde) read with the serde type: the same record, and
    // the serde type writes the same JSON (every field where the board writes it, null where it
    // writes null; value for value, every value here being exact at its decimals).
    let unknown = Record { temp_c: None, condition: 3e30, tempco: None, mag: None, ..exact_record() };
    for (what, rec, back) in [
        ("a stored record", exact_record(), exact_record()),
        // (a condition too large to print is written null and reads 0, never NaN)
        ("an unknown temperature and tempco, an unwritable condition", unknown, Record { condition: 0.0, ..unknown }),
        ("calib's own result", Record { seq: 0, ..exact_record() }, Record { seq: 0, ..exact_record() }),
    ] {
        let line = text(&rec, Format::Json);
        let read: RecordJson = serde_json::from_str(&line).unwrap_or_else(|e| panic!("{what}: {e}: {line}"));
        assert_eq!(read, RecordJson::from(&rec), "{what}");
        assert_eq!(read.record(), Ok(back), "{what}");
        let hand: serde_json::Value = serde_json::from_str(&line).unwrap();
        let serde = serde_json::to_value(RecordJson::from(&rec)).unwrap();
        assert_eq!(paths(&serde), paths(&hand), "{what}: the same fields");
        assert_eq!(leaves(&serde), leaves(&hand), "{what}: the same values");
        // Serialised to text, in the same order.
        let serde_line = serde_json::to_string(&RecordJson::from(&rec)).unwrap();
        let order = |s: &str| s.split('"').skip(1).step_by(2).map(String::from).collect::<Vec<_>>();
        assert_eq!(order(&serde_line), order(&line), "{what}");
    }
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
    let q: RecordJson = serde_json::from_str(&line).unwrap();
    assert_eq!((q.quality.source, q.quality.seq, q.quality.poses), (Source::Board, 3, rec.poses));
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
    assert!((back.temp_c.unwrap() - 24.25).abs() < 1e-6 && (back.accel_rms_g - rec.accel_rms_g).abs() <= 5e-8);
    // The serde type's fields are the hand-written line's.
    assert_eq!(paths(&serde_json::to_value(RecordJson::from(&rec)).unwrap()), paths(&v));
    // calib's own record (never stored) says so, with the temperature its log's replay saw; an
    // unknown temperature is null, in both.
    let own = calibrated().1.record().unwrap();
    let t = own.temp_c.expect("the log's temperature column");
    for json in [text(&own, Format::Json), serde_json::to_string(&RecordJson::from(&own)).unwrap()] {
        let j: RecordJson = serde_json::from_str(&json).unwrap();
        assert_eq!((j.quality.source, j.quality.seq), (Source::Calib, 0), "{json}");
        assert!((j.quality.temp_c.unwrap() - t).abs() <= 0.005, "{json}");
    }
    let unknown = Record { temp_c: None, ..own };
    for json in [text(&unknown, Format::Json), serde_json::to_string(&RecordJson::from(&unknown)).unwrap()] {
        assert!(json.contains("\"temp_c\":null") && !json.to_lowercase().contains("nan"), "{json}");
        assert_eq!(record_from_json(&json).unwrap().temp_c, None);
    }
    // Bad result lines are named.
    assert!(record_from_json("{\"gyro\":").unwrap_err().starts_with("not the expected JSON"));
    let at = line.find("\"K\":[[").unwrap() + 6;
    let end = at + line[at..].find(',').unwrap();
    let with_k = |k: &str| format!("{}{k}{}", &line[..at], &line[end..]);
    assert!(record_from_json(&with_k("null")).unwrap_err().starts_with("not the expected JSON"));
    assert_eq!(serde_json::from_str::<RecordJson>(&with_k("1e39")).unwrap().record(), Err(NotFinite));
    assert!(record_from_json(&with_k("1e39")).unwrap_err().starts_with(&NotFinite.to_string()));
    let unknown = line.replace("\"method\":\"full\"", "\"method\":\"fast\"");
    assert!(
        record_from_json(&unknown).unwrap_err().contains("expected the name of a gyro method"),
        "{}",
        record_from_json(&unknown).unwrap_err()
    );
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
    // Through serde: every number exact.
    let want = calibrated().1.record().unwrap();
    let got: RecordJson = serde_json::from_str(exported.trim()).unwrap();
    assert_eq!(got, RecordJson::from(&want));
    assert_eq!(record_from_json(exported.trim()).unwrap().gyro_k, want.gyro_k);
    let (code, _, err) = calib(&["--out", "x.h", log]);
    assert_eq!(code, 2, "--out needs --export: {err}");
    // A BMI270's data frames: an LSM9DS1's log has none; JSON is always the board frame's.
    let (code, out, err) = calib(&[log, "--export", "c", "--frame", "bosch"]);
    assert_eq!(code, 2, "{out}");
    assert!(err.contains("--frame: that data frame is another part's than the record's"), "{err}");
    for frame in ["board", "arduino-lsm9ds1"] {
        let (code, out, err) = calib(&[log, "--export", "c", "--frame", frame]);
        assert_eq!(code, 0, "{err}");
        assert!(out.contains(if frame == "board" { "/* Data: the board frame" } else { "/* Data: Arduino_LSM9DS1's readings" }), "{out}");
    }
    let (code, _, err) = calib(&[log, "--frame", "arduino"]);
    assert_eq!(code, 2, "--frame needs --export: {err}");
}
