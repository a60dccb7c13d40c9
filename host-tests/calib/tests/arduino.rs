//! The GyroCal Arduino library (`calib-core/arduino/GyroCal`) compiled on the host with
//! `-Wall -Wextra -Werror -pedantic` and run on regions of the board's flash: it loads what
//! `calib_core::formats::region` loads (the same page, every field, calibrated outputs to 1e-6), refuses
//! what it refuses, and `calib LOG --export record` writes a region it reads.

use calib_core::formats::record::{crc32, Record, Sensor, SensorSetup, LEN};
use calib_core::formats::region::{self, PAGE, SLOTS};
use common::{calib, simulated_log};
use rig_sim::variant::Variant;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;

use crate::common;

const LIB: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../calib-core/arduino/GyroCal");
const ARDUINO_LSM9DS1: [f32; 4] = [119.0, 2000.0, 4.0, 0.0];
const ARDUINO_BMI270: [f32; 4] = [100.0, 2000.0, 4.0, 1.0];

fn dir() -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("arduino");
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn cc(prog: &str, args: &[&str]) {
    let o = Command::new(prog).args(args).output().unwrap_or_else(|e| panic!("{prog}: {e} (a C compiler is needed, as for Unicorn)"));
    assert!(o.status.success(), "{prog} {args:?}:\n{}", String::from_utf8_lossy(&o.stderr));
}

/// The library and tests/c/gyrocal_check.c built once; the header also checked as C++ (sketches
/// are C++).
fn checker() -> &'static Path {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    BIN.get_or_init(|| {
        let bin = dir().join("gyrocal_check");
        let (src, inc) = (format!("{LIB}/src/gyrocal.c"), format!("-I{LIB}/src"));
        let driver = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/c/gyrocal_check.c");
        let warn = ["-Wall", "-Wextra", "-Werror", "-pedantic"];
        cc("cc", &[&["-std=c99", "-O2"], &warn[..], &[&inc, &src, driver, "-o", bin.to_str().unwrap()]].concat());
        let cpp = dir().join("sketch.cpp");
        let sketch = "#include <gyrocal.h>\nstruct gyrocal cal;\nfloat f(const void *r) {\n  float g[3] = {1, 2, 3};\n  \
                      gyrocal_load_for(r, &GYROCAL_SETUP_ARDUINO_LSM9DS1, &cal);\n  gyrocal_from_arduino_lsm9ds1(g, nullptr);\n  \
                      gyrocal_gyro_dps(&cal, g, g);\n  return g[0];\n}\n";
        std::fs::write(&cpp, sketch).unwrap();
        cc("c++", &[&["-std=c++11", "-fsyntax-only"], &warn[..], &[&inc, cpp.to_str().unwrap()]].concat());
        bin
    })
}

/// What the library loaded, and its outputs.
#[derive(Debug, Default)]
struct Loaded {
    ok: bool,
    status: u8,
    seq: u32,
    page: usize,
    version: u8,
    said: String,
    values: std::collections::HashMap<String, Vec<f32>>,
    outs: Vec<[f32; 6]>,
    /// `mag_out` lines: calibrated fields (µT).
    mags: Vec<[f32; 3]>,
    /// `refreshed` lines: ok, field, residual, moved, offset.
    refreshed: Vec<[f32; 7]>,
}

/// Runs the library on `region` (with `setup`: refusing another), then on each input line
/// (`raw` or `lib`, gyro then accel).
fn load(region: &[u8], setup: Option<[f32; 4]>, inputs: &[(&str, [f32; 6])]) -> Loaded {
    static N: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let file = dir().join(format!("region{}.bin", N.fetch_add(1, std::sync::atomic::Ordering::Relaxed)));
    std::fs::write(&file, region).unwrap();
    let mut args = vec![file.to_str().unwrap().to_string()];
    args.extend(setup.iter().flatten().map(|v| v.to_string()));
    let mut child = Command::new(checker()).args(&args).stdin(Stdio::piped()).stdout(Stdio::piped()).spawn().unwrap();
    let mut stdin = child.stdin.take().unwrap();
    for (kind, v) in inputs {
        writeln!(stdin, "{kind} {}", v.map(|x| format!("{x:e}")).join(" ")).unwrap();
    }
    drop(stdin);
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "gyrocal_check failed");
    let mut l = Loaded::default();
    for line in String::from_utf8(out.stdout).unwrap().lines() {
        let (key, rest) = line.split_once(' ').unwrap();
        let words: Vec<&str> = rest.split(' ').collect();
        match key {
            "ok" => {
                let n = |i: usize| words[i].parse::<u32>().unwrap();
                (l.ok, l.status, l.seq, l.page, l.version) = (n(0) == 1, n(2) as u8, n(4), n(6) as usize, n(8) as u8);
            }
            "says" => l.said = rest.to_string(),
            "out" => l.outs.push(std::array::from_fn(|i| words[i].parse().unwrap())),
            "mag_out" => l.mags.push(std::array::from_fn(|i| words[i].parse().unwrap())),
            "refreshed" => l.refreshed.push(std::array::from_fn(|i| words[i].parse().unwrap())),
            _ => {
                l.values.insert(key.to_string(), words.iter().map(|w| w.parse().unwrap()).collect());
            }
        }
    }
    l
}

fn close(a: &[f32], b: &[f32], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}");
    for (x, y) in a.iter().zip(b) {
        assert!((x - y).abs() <= 1e-6 * y.abs().max(1.0), "{what}: {a:?} vs {b:?}");
    }
}

/// The library loaded `rec` from `page`, field for field, and calibrates as calib-core does.
fn same_as_calib_core(l: &Loaded, rec: &Record, page: usize, inputs: &[[f32; 6]]) {
    assert!(l.ok && l.status == 0 && l.said == "calibration loaded", "{l:?}");
    assert_eq!((l.seq, l.page), (rec.seq, page));
    let v = |k: &str| l.values[k].as_slice();
    close(v("k"), rec.gyro_k.as_flattened(), "K");
    close(v("bias"), &rec.gyro_bias_dps, "bias");
    close(v("m"), rec.accel_m.as_flattened(), "M");
    close(v("offset"), &rec.accel_offset_g, "offset");
    let s = rec.setup;
    close(&[v("setup")[0], v("gyro_range")[0], v("accel_range")[0]], &[s.odr_hz, s.gyro_range_dps, s.accel_range_g], "setup");
    let (sensor, cas, gain) = match s.sensor {
        Sensor::Lsm9ds1 => (0.0, 0.0, 0.0),
        Sensor::Bmi270 { gyr_cas, user_gain } => (1.0, gyr_cas as f32, f32::from(u8::from(user_gain))),
    };
    assert_eq!([v("sensor")[0], v("gyr_cas")[0], v("user_gain")[0]], [sensor, cas, gain], "the part");
    assert_eq!(v("temp_known")[0] == 1.0, rec.temp_c.is_some());
    close(v("temp"), &[rec.temp_c.unwrap_or(0.0)], "temp");
    assert_eq!(v("tempco_known")[0] == 1.0, rec.tempco.is_some());
    close(v("tempco"), &rec.tempco.map_or([0.0; 3], |t| t.dps_per_c), "tempco");
    assert_eq!(v("mag_known")[0] == 1.0, rec.mag.is_some());
    let identity = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    close(v("mag_a"), rec.mag.as_ref().map_or(&identity[..], |m| m.a.as_flattened()), "A");
    close(v("mag_offset"), &rec.mag.map_or([0.0; 3], |m| m.offset_ut), "magnetometer offset");
    close(&[v("mag_field")[0], v("mag_dip")[0]], &rec.mag.map_or([0.0; 2], |m| [m.field_ut, m.dip_deg]), "field and dip");
    assert_eq!(l.outs.len(), inputs.len());
    for (out, i) in l.outs.iter().zip(inputs) {
        let want = [rec.apply_gyro([i[0], i[1], i[2]]), rec.accel().apply([i[3], i[4], i[5]])].concat();
        close(out, &want, "calibrated sample");
    }
}

/// Raw samples (gyro °/s, accel g) spread over the ranges.
fn samples() -> Vec<[f32; 6]> {
    vec![[0.0; 6], [1.5, -2.25, 3.0, 0.01, -0.02, 1.0], [-400.0, 250.0, 123.456, -1.9, 0.7, -0.3], [1999.0, -1800.0, 0.1, 3.9, -3.9, 0.5]]
}

fn raw(s: &[[f32; 6]]) -> Vec<(&'static str, [f32; 6])> {
    s.iter().map(|v| ("raw", *v)).collect()
}

/// calib's record of a simulated run (its setup the firmware's default).
fn record() -> &'static Record {
    static R: OnceLock<Record> = OnceLock::new();
    R.get_or_init(|| {
        let log = dir().join("sim.csv");
        std::fs::write(&log, simulated_log(Variant::Hobby.config(9, 0)).0).unwrap();
        let (log, out) = (log.to_str().unwrap().to_string(), dir().join("calib-region.bin"));
        let (code, _, err) = calib(&[&log, "--export", "record"]);
        assert_eq!(code, 2, "binary to a terminal is refused: {err}");
        assert!(err.contains("give --out FILE"), "{err}");
        let (code, _, err) = calib(&[&log, "--export", "record", "--out", out.to_str().unwrap()]);
        assert_eq!(code, 0, "{err}");
        let region = std::fs::read(&out).unwrap();
        assert_eq!(region.len(), SLOTS * PAGE);
        let (page, rec) = region::load(&region, PAGE).expect("calib's region holds a valid record");
        assert!(page == 0 && region[LEN..].iter().all(|&b| b == 0xFF), "the record in page A, all else erased");
        rec
    })
}

/// A region of two pages holding `a` and `b` (`None`: erased).
fn region_of(a: Option<&[u8]>, b: Option<&[u8]>) -> Vec<u8> {
    let mut r = vec![0xFF; SLOTS * PAGE];
    for (i, bytes) in [a, b].into_iter().enumerate() {
        if let Some(bytes) = bytes {
            r[i * PAGE..i * PAGE + bytes.len()].copy_from_slice(bytes);
        }
    }
    r
}

/// `bytes` with the CRC over all but its last 4 bytes made right.
fn with_crc(mut bytes: Vec<u8>) -> Vec<u8> {
    let n = bytes.len() - 4;
    let crc = crc32(&bytes[..n]);
    bytes[n..].copy_from_slice(&crc.to_le_bytes());
    bytes
}

#[test]
fn calibs_exported_region_loads_as_calib_core_loads_it_and_another_setup_is_refused() {
    let rec = record();
    let region = region::image(rec).unwrap();
    assert_eq!(rec.setup, SensorSetup::DEFAULT);
    same_as_calib_core(&load(&region, None, &raw(&samples())), rec, 0, &samples());
    let s = rec.setup;
    same_as_calib_core(&load(&region, Some([s.odr_hz, s.gyro_range_dps, s.accel_range_g, 0.0]), &raw(&samples())), rec, 0, &samples());
    // Made at ±500 °/s, asked for by a program that runs Arduino_LSM9DS1 (±2000 °/s): refused, and
    // nothing applied.
    let l = load(&region, Some(ARDUINO_LSM9DS1), &raw(&samples()));
    assert!(!l.ok && l.status == 2 && l.said.contains("another sensor, ODR or full scale"), "{l:?}");
    assert_eq!(l.values["gyro_range"], [500.0], "the refusal says what the record was made at");
    for (out, i) in l.outs.iter().zip(samples()) {
        assert_eq!(*out, i, "a refused record is never applied");
    }
    // A record made at the preset loads for it.
    let preset =
        Record { setup: SensorSetup { odr_hz: 119.0, gyro_range_dps: 2000.0, accel_range_g: 4.0, ..SensorSetup::DEFAULT }, ..*rec };
    same_as_calib_core(&load(&region::image(&preset).unwrap(), Some(ARDUINO_LSM9DS1), &[]), &preset, 0, &[]);
}

#[test]
fn the_newest_valid_page_wins_and_garbage_is_never_applied() {
    let rec = |seq: u32| Record { seq, temp_c: Some(31.5), ..*record() };
    let enc = |r: &Record| r.encode().unwrap().to_vec();
    // Versions 1, 2 and 3 (as older firmware wrote them) from the v4 bytes: v3 is v4 without
    // the part; v2 is v3 up to the
    // angle from coplanar; v1 up to the accel offset, the diagonal of σK, the six quality fields.
    let v4 = enc(&rec(7));
    let mut v3 = [&v4[..228], &[0; 4]].concat();
    v3[4] = 3;
    let v3 = with_crc(v3);
    let mut v2 = [&v3[..184], &[0; 4]].concat();
    v2[4] = 2;
    v2[14] &= 1;
    let sigma_diag: Vec<u8> = [0usize, 4, 8].iter().flat_map(|i| v3[116 + 4 * i..120 + 4 * i].to_vec()).collect();
    let mut v1 = [&v3[..116], &sigma_diag, &v3[152..176], &[0; 4]].concat();
    v1[4] = 1;
    v1[14] &= 1;
    let (v1, v2) = (with_crc(v1), with_crc(v2));
    // A NaN written with a valid CRC (no encoder makes one; a sketch's data might).
    let mut nan = enc(&rec(9));
    nan[24..28].copy_from_slice(&f32::NAN.to_le_bytes());
    let nan = with_crc(nan);
    let mut flipped = enc(&rec(9));
    flipped[40] ^= 1;
    // Version 5: the v6 layout, the part's raw axes (converted on load); an LSM9DS1's and a
    // BMI270's (its magnetometer the BMM150's).
    let v5_of = |r: &Record| {
        let mut b = enc(r);
        b[4] = 5;
        with_crc(b)
    };
    let v5 = v5_of(&rec(8));
    let bmi = Sensor::Bmi270 { gyr_cas: 11, user_gain: false };
    let bmi_v5 = v5_of(&Record { setup: SensorSetup { sensor: bmi, ..SensorSetup::DEFAULT }, ..rec(8) });
    let mut future = enc(&rec(9));
    future[4] = 7;
    let future = with_crc(future);
    let sketch_data: Vec<u8> = (0..PAGE).map(|i| (i * 7 + 3) as u8).collect();
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("sequence wrap: B newer", region_of(Some(&enc(&rec(u32::MAX))), Some(&enc(&rec(0))))),
        ("sequence wrap: A newer", region_of(Some(&enc(&rec(0))), Some(&enc(&rec(u32::MAX))))),
        ("B torn", region_of(Some(&enc(&rec(3))), Some(&flipped))),
        ("A a NaN with a good CRC", region_of(Some(&nan), None)),
        ("A an unknown version", region_of(Some(&future), Some(&enc(&rec(2))))),
        ("v2 in B", region_of(None, Some(&v2))),
        ("v1 in A, v4 older in B", region_of(Some(&v1), Some(&enc(&rec(6))))),
        ("v3 in B, v4 older in A", region_of(Some(&enc(&rec(5))), Some(&v3))),
        ("v5 (the part's raw axes) in A", region_of(Some(&v5), None)),
        ("a BMI270's v5 in B", region_of(None, Some(&bmi_v5))),
        ("both erased", region_of(None, None)),
        ("a sketch's data over both", [&sketch_data[..], &sketch_data[..]].concat()),
    ];
    for (what, region) in cases {
        let l = load(&region, None, &raw(&samples()));
        match region::load(&region, PAGE) {
            Some((page, r)) => {
                same_as_calib_core(&l, &r, page, &samples());
                assert_eq!(l.version, region[page * PAGE + 4], "{what}");
            }
            None => {
                assert!(!l.ok && l.status == 1 && l.said.starts_with("no valid record"), "{what}: {l:?}");
                for (out, i) in l.outs.iter().zip(samples()) {
                    assert_eq!(*out, i, "{what}: nothing applied");
                }
            }
        }
        eprintln!("{what}: {}", if l.ok { format!("page {} seq {}", l.page, l.seq) } else { l.said.clone() });
    }
    // The cases above decide as expected (not only alike).
    let page_of = |a: Option<&[u8]>, b: Option<&[u8]>| region::load(&region_of(a, b), PAGE).map(|(p, r)| (p, r.seq));
    assert_eq!(page_of(Some(&enc(&rec(u32::MAX))), Some(&enc(&rec(0)))), Some((1, 0)));
    assert_eq!(page_of(Some(&v1), Some(&enc(&rec(6)))), Some((0, 7)));
    assert_eq!(page_of(Some(&nan), None), None);
}

#[test]
fn arduino_lsm9ds1_readings_are_put_back_in_datasheet_units() {
    // Counts as the sensor gives them at ±2000 °/s and ±4 g; Arduino_LSM9DS1's readings of them.
    let counts = [[1000.0f32, -2000.0, 32767.0, 8192.0, -16384.0, 4096.0], [-32768.0, 5.0, 0.0, 1.0, -1.0, 30000.0]];
    let lib: Vec<(&str, [f32; 6])> =
        counts.iter().map(|c| ("lib", std::array::from_fn(|i| c[i] * if i < 3 { 2000.0 } else { 4.0 } / 32768.0))).collect();
    // In the board frame: datasheet units, and (−x, y, z) of the raw axes (a left-handed triad).
    let datasheet: Vec<[f32; 6]> = counts
        .iter()
        .map(|c| std::array::from_fn(|i| c[i] * if i < 3 { 0.070 } else { 0.000122 } * if i % 3 == 0 { -1.0 } else { 1.0 }))
        .collect();
    // No record: the readings in datasheet units and the board frame, nothing else.
    let l = load(&region_of(None, None), None, &lib);
    for (out, want) in l.outs.iter().zip(&datasheet) {
        close(out, want, "Arduino_LSM9DS1's reading in datasheet units");
    }
    assert!((-l.outs[0][0] / (1000.0 * 2000.0 / 32768.0) - 1.0 - 0.146_88).abs() < 1e-5, "its gyro reads 12.8 % low");
    // With a record made at its configuration: calibrated as calib-core calibrates the datasheet units.
    let preset =
        Record { setup: SensorSetup { odr_hz: 119.0, gyro_range_dps: 2000.0, accel_range_g: 4.0, ..SensorSetup::DEFAULT }, ..*record() };
    let l = load(&region::image(&preset).unwrap(), Some(ARDUINO_LSM9DS1), &lib);
    same_as_calib_core(&l, &preset, 0, &datasheet);
}

#[test]
fn a_rev2_record_applies_to_arduino_bmi270_readings_and_never_to_an_lsm9ds1_s() {
    // A record made on a Rev2 at Arduino_BMI270_BMM150's setup, with a factory trim of -23/512.
    let sensor = Sensor::Bmi270 { gyr_cas: -23, user_gain: false };
    let mut rec = Record { setup: SensorSetup { odr_hz: 100.0, gyro_range_dps: 2000.0, accel_range_g: 4.0, sensor }, ..*record() };
    rec.gyro_k[0][2] = 0.004;
    let region = region::image(&rec).unwrap();
    // What that library returns for raw readings: Bosch's CAS on counts (C's truncating division),
    // then x = -y, y = -x; in its units (2000/32768 dps, 4/32768 g per count). (Where Bosch's x
    // saturates at ±32768 counts no loader can undo it.)
    let counts = [[1000i32, -2000, 32767, 8192, -16384, 4096], [-30000, 5, -517, 1, -1, 30000]];
    let (dps, g) = (2000.0f32 / 32768.0, 4.0f32 / 32768.0);
    // The counts are Bosch's axes; the board frame's reading is (y, −x, z) of them.
    let datasheet: Vec<[f32; 6]> = counts
        .iter()
        .map(|c| {
            let v = |i: usize| c[i] as f32 * if i < 3 { dps } else { g };
            [v(1), -v(0), v(2), v(4), -v(3), v(5)]
        })
        .collect();
    // Version 1.1.0 on (remapped) and 1.0.x (Bosch's axes, CAS applied).
    let lib: Vec<(&str, [f32; 6])> = counts
        .iter()
        .flat_map(|c| {
            let x = (c[0] - (-23 * c[2]) / 512).clamp(-32768, 32767);
            [
                ("bmi", [-c[1] as f32 * dps, -x as f32 * dps, c[2] as f32 * dps, -c[4] as f32 * g, -c[3] as f32 * g, c[5] as f32 * g]),
                ("bmi10", [x as f32 * dps, c[1] as f32 * dps, c[2] as f32 * dps, c[3] as f32 * g, c[4] as f32 * g, c[5] as f32 * g]),
            ]
        })
        .collect();
    let l = load(&region, Some(ARDUINO_BMI270), &lib);
    // Calibrated as calib-core calibrates the board frame's readings, to CAS's truncation (< 1
    // count of x).
    assert!(l.ok, "{l:?}");
    assert_eq!(l.outs.len(), 2 * datasheet.len());
    for (out, r) in l.outs.iter().zip(datasheet.iter().flat_map(|d| [d, d])) {
        let want = [rec.apply_gyro([r[0], r[1], r[2]]), rec.accel().apply([r[3], r[4], r[5]])].concat();
        for i in 0..6 {
            assert!((out[i] - want[i]).abs() <= 1.5 * dps, "{out:?} vs {want:?}");
        }
    }
    same_as_calib_core(&load(&region, Some(ARDUINO_BMI270), &raw(&datasheet)), &rec, 0, &datasheet);
    // The same numbers on an LSM9DS1 (a program for a Rev1 board): refused.
    let l = load(&region, Some([100.0, 2000.0, 4.0, 0.0]), &[]);
    assert!(!l.ok && l.status == 2, "{l:?}");
}

#[test]
fn the_magnetometer_applies_as_calib_core_and_its_offset_refreshes_in_the_sketch() {
    let rec = record();
    let mag = rec.mag.expect("calib's record of a simulated log holds the magnetometer");
    let region = region::image(rec).unwrap();
    let fields = [[20.0f32, -35.5, 41.0], [-60.0, 12.25, -3.0]];
    // Arduino_LSM9DS1's readMagneticField() of counts (400/32768 uT each, the magnetometer's axes).
    let counts = [1000.0f32, -2000.0, 3000.0];
    let mut inputs: Vec<(&str, [f32; 6])> = fields.iter().map(|f| ("mag", [f[0], f[1], f[2], 0.0, 0.0, 0.0])).collect();
    inputs.push(("lmag", [counts[0] * 400.0 / 32768.0, counts[1] * 400.0 / 32768.0, counts[2] * 400.0 / 32768.0, 0.0, 0.0, 0.0]));
    // Arduino_BMI270_BMM150's readMagneticField() of the first field: the BMM150's own axes,
    // (−y, −x, −z) of the board frame's (its own inverse).
    let f = fields[0];
    inputs.push(("bmm", [-f[1], -f[0], -f[2], 0.0, 0.0, 0.0]));
    let l = load(&region, None, &inputs);
    same_as_calib_core(&l, rec, 0, &[]);
    // The LSM9DS1 magnetometer's raw axes are the board frame's: datasheet units only.
    let datasheet = [counts[0] * 0.014, counts[1] * 0.014, counts[2] * 0.014];
    assert_eq!(l.mags.len(), 4);
    for (out, f) in l.mags.iter().zip(fields.iter().chain([&datasheet, &fields[0]])) {
        close(out, &mag.apply(*f), "calibrated field");
    }
    // The robot adds its own hard iron: a tumble's readings refit the offset, A kept.
    let a = nalgebra::Matrix3::from_fn(|i, j| mag.a[i][j] as f64);
    let a_inv = a.try_inverse().unwrap();
    let extra = nalgebra::Vector3::new(6.5, -4.0, 9.25);
    let o = nalgebra::Vector3::new(mag.offset_ut[0] as f64, mag.offset_ut[1] as f64, mag.offset_ut[2] as f64) + extra;
    let raw = |u: nalgebra::Vector3<f64>| {
        let m = a_inv * (u * 48.0) + o;
        [m[0] as f32, m[1] as f32, m[2] as f32, 0.0, 0.0, 0.0]
    };
    // 200 directions over the sphere (a Fibonacci lattice), and 60 on one circle.
    let sphere: Vec<_> = (0..200)
        .map(|i| {
            let z = 1.0 - (2 * i + 1) as f64 / 200.0;
            let phi = i as f64 * 2.399_963;
            ("tumble", raw(nalgebra::Vector3::new((1.0 - z * z).sqrt() * phi.cos(), (1.0 - z * z).sqrt() * phi.sin(), z)))
        })
        .collect();
    let circle: Vec<_> =
        (0..60).map(|i| ("tumble", raw(nalgebra::Vector3::new((i as f64 * 0.1).cos(), (i as f64 * 0.1).sin(), 0.0)))).collect();
    let end = ("refresh", [0.0; 6]);
    let mut script: Vec<(&str, [f32; 6])> = sphere[..49].to_vec();
    script.push(end);
    script.extend(circle);
    script.push(end);
    script.extend(sphere.iter().copied());
    script.push(end);
    let l = load(&region, None, &script);
    let [few, flat, tumble] = [l.refreshed[0], l.refreshed[1], l.refreshed[2]];
    let stored = mag.offset_ut;
    assert_eq!((few[0], &few[4..]), (0.0, &stored[..]), "49 readings: refused, offset kept");
    assert_eq!((flat[0], &flat[4..]), (0.0, &stored[..]), "one plane: refused, offset kept");
    assert_eq!(tumble[0], 1.0, "{tumble:?}");
    assert!((tumble[1] - 48.0).abs() < 0.01 && tumble[2] < 0.01, "field {} uT, residual {} uT", tumble[1], tumble[2]);
    assert!((tumble[3] as f64 - extra.norm()).abs() < 0.01, "moved {} uT", tumble[3]);
    for k in 0..3 {
        assert!((tumble[4 + k] as f64 - o[k]).abs() < 0.01, "offset {:?} vs {o:?}", &tumble[4..]);
    }
    // A record without a magnetometer: the identity, and no refresh.
    let none = Record { mag: None, ..*rec };
    let mut script = vec![("mag", [1.0, 2.0, 3.0, 0.0, 0.0, 0.0])];
    script.extend(sphere.iter().copied());
    script.push(end);
    let l = load(&region::image(&none).unwrap(), None, &script);
    same_as_calib_core(&l, &none, 0, &[]);
    assert_eq!(l.mags, [[1.0, 2.0, 3.0]]);
    assert_eq!(l.refreshed[0][0], 0.0);
}
