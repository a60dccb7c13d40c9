//! Nothing bad taken silently (issue 48 point 7): a corruption sweep of the public sessions
//! recorded on real IMUs (`../shared/data/real/`, [`calib::real`]). Each session is corrupted one
//! way at a time — rows cut, joined, split; NaN, infinite and empty numbers; repeated and
//! reversed times; readings of 1e30; binary, control and printable garbage; a repeated header; a
//! hole in time; a wrong last time; a full scale stated below the readings; unit and column
//! mistakes — and read as `gyrocal-calib` reads it, through the library (`csvlog::decode`,
//! `csvlog::parse`, `--range`'s check, `offline::calibrate_log`) and through the tool itself.
//! Every variant is refused with an error naming its line, warned about with its line, or (a
//! whole column's mistake) refused naming the mistake; the harmless ones (CRLF line ends, a
//! byte-order mark, the firmware's own messages between the rows) give the session's result.

use calib::csvlog::{self, Across, Log, LogError};
use calib::offline::{self, Calibration, Options};
use calib::real;
use calib_core::formats::export::{self, Format};
use calib_core::formats::log::Bound;
use calib_core::formats::protocol::{self, RecordLine};
use calib_core::procedure::Phase;
use calib_core::Time;
use common::calib;
use std::path::{Path, PathBuf};

use crate::common;

/// A session as a log, with the options it calibrates with.
struct Session {
    name: &'static str,
    text: String,
    /// `gyrocal-calib`'s options for it.
    args: &'static [&'static str],
}

impl Session {
    fn lines(&self) -> Vec<String> {
        self.text.lines().map(str::to_string).collect()
    }
}

/// imu_tk's Xsens session in the log's units: its raw 16-bit counts (as [`real::session`] gives
/// them) about 32768, the accelerometer at 4060 counts per g (its still poses' mean |a| after
/// imu_tk's 32768 offset and calib's accelerometer fit), the gyro at imu_tk's own initial scale
/// 1/6258 rad/s per count corrected by calib's `K` on it (1.31): 1/4800 rad/s.
fn xsens_in_units() -> String {
    let counts = csvlog::parse(&real::session("imu_tk_xsens.txt").unwrap()).unwrap();
    let mut text = csvlog::header();
    for r in &counts.rows {
        let row = csvlog::Row {
            accel_g: r.accel_g.map(|c| (c - 32768.0) / 4060.0),
            gyro_dps: r.gyro_dps.map(|c| ((c as f64 - 32768.0) / 4800.0).to_degrees() as f32),
            ..*r
        };
        csvlog::format_row(&mut text, &row);
    }
    text
}

fn sessions() -> Vec<Session> {
    vec![
        Session {
            name: "ferraris",
            text: real::session("imucal_ferraris_session.csv").unwrap_or_else(|e| panic!("the shared real recordings: {e}")),
            args: &["--whole-turns"],
        },
        Session { name: "xsens", text: xsens_in_units(), args: &[] },
    ]
}

/// What a variant must give.
#[derive(Debug, Clone, Copy)]
enum Expect {
    /// Refused with an error that starts `line N:` and says this (exit 3).
    Refused(u32, &'static str),
    /// Calibrated, with a warning on stderr naming line N and saying this.
    Warned(u32, &'static str),
    /// A whole column's mistake: refused (or no gyro `K`) with exit code and this said.
    Named(i32, &'static str),
    /// Harmless: the session's rows and result, no warning.
    Same,
}

struct Variant {
    name: &'static str,
    bytes: Vec<u8>,
    args: Vec<String>,
    expect: Expect,
}

/// The text of `lines` (newline-terminated).
fn join(lines: &[String]) -> Vec<u8> {
    lines.iter().flat_map(|l| format!("{l}\n").into_bytes()).collect()
}

/// `lines` with field `k` of line `n` (1-based) rewritten by `f`.
fn with_field(lines: &[String], n: u32, k: usize, f: impl Fn(&str) -> String) -> Vec<u8> {
    let mut out = lines.to_vec();
    let mut fields: Vec<String> = out[n as usize - 1].split(',').map(str::to_string).collect();
    fields[k] = f(&fields[k]);
    out[n as usize - 1] = fields.join(",");
    join(&out)
}

/// `lines` with `insert` before line `n`.
fn inserted(lines: &[String], n: u32, insert: &[u8]) -> Vec<u8> {
    let at = join(&lines[..n as usize - 1]);
    [at.as_slice(), insert, b"\n", &join(&lines[n as usize - 1..])].concat()
}

/// `lines` with the time of every row from line `n` on shifted by `by` s.
fn shifted(lines: &[String], n: u32, by: f64) -> Vec<String> {
    let mut out = lines.to_vec();
    for l in &mut out[n as usize - 1..] {
        let (t, rest) = l.split_once(',').unwrap();
        *l = format!("{:.6},{rest}", t.parse::<f64>().unwrap() + by);
    }
    out
}

/// The line of the first row of `log` with a reading beyond `limit` in `readings`.
fn first_beyond(log: &Log, readings: impl Fn(&csvlog::Row) -> [f32; 3], limit: f32) -> u32 {
    let i = log.rows.iter().position(|r| readings(r).iter().any(|v| v.abs() > limit)).expect("a reading beyond the limit");
    log.lines[i]
}

/// The firmware's lines between the rows of its raw log: its protocol lines, a record's line and
/// its JSON, C and Rust exports.
fn firmware_messages(c: &Calibration) -> Vec<String> {
    let rec = c.record().expect("the session calibrates");
    let line = |f: &dyn Fn(&mut String) -> std::fmt::Result| {
        let mut s = String::new();
        f(&mut s).unwrap();
        s
    };
    let mut out: Vec<String> = protocol::HELP.iter().map(|h| h.to_string()).collect();
    out.extend([protocol::USB_STARTED.to_string(), protocol::NO_RECORD.to_string()]);
    out.push(line(&|w| protocol::usb_dropped(w, 1234)));
    out.push(line(&|w| protocol::sensor_ready(w, 119, 2000, 4)));
    out.push(line(&|w| protocol::plan(w, 13, 12)));
    out.extend([Phase::Bias, Phase::HandHeld, Phase::RigPoses, Phase::Done].map(|p| line(&|w| protocol::phase(w, p))));
    out.push(line(&|w| protocol::hand_held_pose(w, 3, &[0.01, -0.99, 0.02])));
    out.push(line(&|w| protocol::rig_pose(w, 4, 90.0, &[0.7, 0.0, 0.7])));
    out.push(line(&|w| protocol::record(w, RecordLine::CalibrationDone, &rec)));
    out.push(line(&|w| protocol::failed(w, &calib_core::Error::NoUsableMove)));
    for f in [Format::Json, Format::C, Format::Rust] {
        out.extend(line(&|w| export::write(w, &rec, f)).lines().map(str::to_string));
    }
    out
}

/// The variants of a session (`base`: its log and calibration).
fn variants(s: &Session, base: &Log, c: &Calibration) -> Vec<Variant> {
    let lines = s.lines();
    let last = lines.len() as u32;
    // A row in the middle of the session.
    let n = last * 2 / 5;
    let v = |name, bytes, expect| Variant { name, bytes, args: vec![], expect };
    let swapped_header = |from: &str, to: &str| {
        let mut l = lines.clone();
        l[0] = l[0].replacen(from, to, 1);
        join(&l)
    };
    let all_rows = |f: &dyn Fn(&mut csvlog::Row)| {
        let mut text = csvlog::header();
        for r in &base.rows {
            let mut r = *r;
            f(&mut r);
            csvlog::format_row(&mut text, &r);
        }
        text.into_bytes()
    };
    let mut out = vec![
        // Rows cut, joined, split.
        v(
            "a row cut mid-line",
            {
                let mut l = lines.clone();
                l[n as usize - 1].truncate(lines[n as usize - 1].len() / 2);
                join(&l)
            },
            Expect::Refused(n, "fields, the header has"),
        ),
        v(
            "a row joined to the next (its newline lost)",
            {
                let mut l = lines.clone();
                let next = l.remove(n as usize);
                l[n as usize - 1] += &next;
                join(&l)
            },
            Expect::Refused(n, "fields, the header has"),
        ),
        v(
            "a field split in two (a decimal point turned comma)",
            with_field(&lines, n, 5, |f| f.replacen('.', ",", 1)),
            Expect::Refused(n, "a field split in two"),
        ),
        v(
            "two fields merged (a comma lost)",
            {
                let mut l = lines.clone();
                l[n as usize - 1] = lines[n as usize - 1].replacen(',', "", 1);
                join(&l)
            },
            Expect::Refused(n, "fields, the header has"),
        ),
        v(
            "an extra field at a row's end",
            {
                let mut l = lines.clone();
                l[n as usize - 1] += ",0.5";
                join(&l)
            },
            Expect::Refused(n, "a field split in two"),
        ),
        v(
            "the last line cut (the recording stopped mid-row)",
            {
                let mut bytes = join(&lines[..last as usize - 1]);
                bytes.extend_from_slice(&lines[last as usize - 1].as_bytes()[..lines[last as usize - 1].len() / 3]);
                bytes
            },
            Expect::Warned(last, "was cut mid-row"),
        ),
        // Numbers that are not.
        v("NaN in the gyro", with_field(&lines, n, 5, |_| "NaN".into()), Expect::Refused(n, "column gy_dps is not a finite number")),
        v("inf in the accelerometer", with_field(&lines, n, 1, |_| "inf".into()), Expect::Refused(n, "column ax_g is not a finite number")),
        v(
            "1e300 in the accelerometer (infinite as f32)",
            with_field(&lines, n, 3, |_| "1e300".into()),
            Expect::Refused(n, "column az_g is not a finite number"),
        ),
        v(
            "`nan` as the time (the firmware's word for a non-finite number)",
            with_field(&lines, n, 0, |_| "nan".into()),
            Expect::Refused(n, "column t_s is not a finite number"),
        ),
        v("an empty time", with_field(&lines, n, 0, |_| String::new()), Expect::Refused(n, "column t_s is not a finite number")),
        v(
            "an empty gyro field mid-log",
            with_field(&lines, n, 4, |_| String::new()),
            Expect::Refused(n, "column gx_dps is not a finite number"),
        ),
        // Time.
        v(
            "a duplicated time",
            {
                let prev = lines[n as usize - 2].split(',').next().unwrap().to_string();
                with_field(&lines, n, 0, |_| prev.clone())
            },
            Expect::Refused(n, "time does not increase"),
        ),
        v("a duplicated row", inserted(&lines, n + 1, lines[n as usize - 1].as_bytes()), Expect::Refused(n + 1, "time does not increase")),
        v(
            "two rows swapped",
            {
                let mut l = lines.clone();
                l.swap(n as usize - 1, n as usize);
                join(&l)
            },
            Expect::Refused(n + 1, "time does not increase"),
        ),
        v("a 20 s hole in time (every later time shifted)", join(&shifted(&lines, n, 20.0)), Expect::Warned(n, "no samples for 20.0")),
        v(
            "a last row with a wrong time (far in the future)",
            with_field(&lines, last, 0, |_| "1000000.000000".into()),
            Expect::Refused(last, "the time jumps by"),
        ),
        v(
            "a last row 2 s late",
            with_field(&lines, last, 0, |t| format!("{:.6}", t.parse::<f64>().unwrap() + 2.0)),
            Expect::Warned(last, "it comes after the last pose"),
        ),
        // Readings beyond any part's full scale.
        v(
            "a gyro reading of 1e30 °/s",
            with_field(&lines, n, 5, |_| "1e30".into()),
            Expect::Refused(n, "gy_dps 1e30 °/s is beyond any MEMS part's full scale"),
        ),
        v(
            "an accelerometer reading of -1e30 g",
            with_field(&lines, n, 3, |_| "-1e30".into()),
            Expect::Refused(n, "az_g -1e30 g is beyond any MEMS part's full scale"),
        ),
        v(
            "a gyro reading of 9000 °/s",
            with_field(&lines, n, 6, |_| "9000".into()),
            Expect::Refused(n, "gz_dps 9000 °/s is beyond any MEMS part's full scale"),
        ),
        // Garbage.
        v(
            "a row of binary garbage (not UTF-8)",
            inserted(&lines, n, b"\x9c\xff\x00\x13garbage\x1b[0m\xfe\xfe"),
            Expect::Refused(n, "is not UTF-8 text"),
        ),
        v(
            "a row of control bytes",
            inserted(&lines, n, b"\x00\x01\x02\x7f\x1b[2J\x08"),
            Expect::Refused(n, "not a row nor a log message: \"\\u{0}\\u{1}"),
        ),
        v(
            "a row of printable garbage",
            inserted(&lines, n, b"%$@!~^garbage|&"),
            Expect::Refused(n, "not a row nor a log message: \"%$@!~^garbage|&\""),
        ),
        v(
            "a row garbled at its start",
            with_field(&lines, n, 0, |t| format!("q{}", &t[1..])),
            Expect::Refused(n, "column t_s is not a finite number"),
        ),
        v(
            "a header repeated mid-log (two recordings joined)",
            inserted(&lines, n, lines[0].as_bytes()),
            Expect::Refused(n, "a second header"),
        ),
        // Full scales stated below the readings.
        Variant {
            name: "--range below the readings",
            bytes: join(&lines),
            args: vec!["--range".into(), "250".into()],
            expect: Expect::Refused(first_beyond(base, |r| r.gyro_dps, 300.0), "the full scale --range states"),
        },
        v(
            "a setup line stating ±245 °/s",
            inserted(&lines, 2, b"# sensor setup: odr_hz=100.0 gyro_range_dps=245.0 accel_range_g=16.0"),
            Expect::Refused(first_beyond(base, |r| r.gyro_dps, 294.0) + 1, "the full scale the log's setup line states"),
        ),
        // Whole columns in other units or places.
        v(
            "accelerometer and gyro columns swapped",
            swapped_header("ax_g,ay_g,az_g,gx_dps,gy_dps,gz_dps", "gx_dps,gy_dps,gz_dps,ax_g,ay_g,az_g"),
            Expect::Refused(first_beyond(base, |r| r.gyro_dps, 40.0), "g is beyond any MEMS part's full scale"),
        ),
        v("time in milliseconds", all_rows(&|r| r.t = Time::from_us(r.t.us() * 1000)), Expect::Named(1, "milliseconds")),
        v("accelerometer in m/s²", all_rows(&|r| r.accel_g = r.accel_g.map(|a| a * 9.80665)), Expect::Named(1, "m/s²")),
        v(
            "gyro in rad/s",
            all_rows(&|r| r.gyro_dps = r.gyro_dps.map(f32::to_radians)),
            Expect::Named(4, "partial calibration, missing gyro"),
        ),
        v(
            "gyro x and y columns swapped",
            swapped_header("gx_dps,gy_dps", "gy_dps,gx_dps"),
            Expect::Named(4, "partial calibration, missing gyro"),
        ),
        // Harmless.
        v("CRLF line ends", lines.iter().flat_map(|l| format!("{l}\r\n").into_bytes()).collect(), Expect::Same),
        v("a byte-order mark", [b"\xef\xbb\xbf".as_slice(), &join(&lines)].concat(), Expect::Same),
    ];
    // The firmware's own lines between the rows, one after every 97th row.
    let messages = firmware_messages(c);
    let mut l = lines.clone();
    for (k, m) in messages.iter().enumerate().rev() {
        l.insert(2 + 97 * k, m.clone());
    }
    out.push(v("the firmware's messages between the rows", join(&l), Expect::Same));
    // A hole between two rig poses: the session as a rig's (its servo column filled).
    let mut l = shifted(&lines, n, 20.0);
    for r in &mut l[1..] {
        *r = format!("{},90", r.trim_end_matches(','));
        if s.name == "xsens" {
            *r += ",";
        }
    }
    out.push(v("a 20 s hole between two rig poses", join(&l), Expect::Refused(n, "between two rig poses")));
    out
}

/// `gyrocal-calib`'s reading of a log through the library: the text, the rows, `--range`, the
/// calibration.
fn library(bytes: &[u8], args: &[String]) -> Result<(Log, Calibration), String> {
    let text = csvlog::decode(bytes).map_err(|e| e.to_string())?;
    let log = csvlog::parse(&text).map_err(|e| e.to_string())?;
    let range = args.iter().position(|a| a == "--range").map(|i| args[i + 1].parse::<f32>().unwrap());
    if let Some(r) = range {
        log.check_full_scale(Some(r), Bound::RangeOption).map_err(|e| e.to_string())?;
    }
    let options = Options { whole_turns: args.iter().any(|a| a == "--whole-turns"), range_dps: range, ..Options::default() };
    let c = offline::calibrate_log(&log, &options, None).map_err(|e| e.to_string())?;
    Ok((log, c))
}

fn dir() -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("corruption");
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The gyro `K` of the tool's JSON.
fn k(stdout: &str) -> serde_json::Value {
    serde_json::from_str::<serde_json::Value>(stdout.trim()).map(|j| j["gyro"]["K"].clone()).unwrap_or_default()
}

#[test]
fn every_corruption_of_the_real_sessions_is_refused_or_said_with_its_line() {
    for s in sessions() {
        let args: Vec<String> = s.args.iter().map(|a| a.to_string()).collect();
        let (base, c) = library(s.text.as_bytes(), &args).unwrap_or_else(|e| panic!("{}: {e}", s.name));
        let path = dir().join(format!("{}.csv", s.name));
        std::fs::write(&path, &s.text).unwrap();
        let (base_code, base_out, base_err) = calib(&[&[path.to_str().unwrap()], s.args].concat());
        assert_eq!(base_code, 0, "{}: {base_err}", s.name);
        assert!(!base_err.contains("warning"), "{}: {base_err}", s.name);
        let variants = variants(&s, &base, &c);
        assert!(variants.len() >= 30, "{} variants", variants.len());
        for v in variants {
            let what = format!("{}, {}", s.name, v.name);
            let path = dir().join(format!("{}-{}.csv", s.name, v.name.replace(|c: char| !c.is_ascii_alphanumeric(), "_")));
            std::fs::write(&path, &v.bytes).unwrap();
            let tool_args: Vec<&str> =
                [path.to_str().unwrap()].into_iter().chain(s.args.iter().copied()).chain(v.args.iter().map(String::as_str)).collect();
            let (code, out, err) = calib(&tool_args);
            let lib = library(&v.bytes, &[args.clone(), v.args.clone()].concat());
            println!("MEASURED {what}: exit {code}: {}", err.trim());
            match v.expect {
                Expect::Refused(line, says) => {
                    let named = format!("line {line}: ");
                    let e = lib.err().unwrap_or_else(|| panic!("{what}: taken by the library"));
                    assert!(e.starts_with(&named) && e.contains(says), "{what}: {e}");
                    // A library user who reads the bytes lossily gets the line too.
                    if v.args.is_empty() {
                        let lossy = csvlog::parse(&String::from_utf8_lossy(&v.bytes)).map(|_| ()).unwrap_err().to_string();
                        assert!(lossy.starts_with(&named), "{what}: read lossily: {lossy}");
                    }
                    assert_eq!((code, out.as_str()), (3, ""), "{what}: {err}");
                    assert!(err.contains(&format!(": {named}")) && err.contains(says), "{what}: {err}");
                }
                Expect::Warned(line, says) => {
                    let (log, c) = lib.unwrap_or_else(|e| panic!("{what}: {e}"));
                    assert_eq!(code, base_code, "{what}: {err}");
                    let warning = err
                        .lines()
                        .find(|l| l.contains("warning") && [":", " "].iter().any(|end| l.contains(&format!(": line {line}{end}"))))
                        .unwrap_or_else(|| panic!("{what}: {err}"));
                    assert!(warning.contains(says), "{what}: {warning}");
                    // What the warning says is what was done.
                    match (log.holes.as_slice(), log.cut_line) {
                        ([hole], None) => {
                            assert_eq!(hole.line, line, "{what}");
                            if let Across::HandHeldMove { .. } = hole.across {
                                assert!(warning.contains("is left out"), "{what}: {warning}");
                                let dropped = c.hand_moves.as_ref().map(|h| h.dropped["gap"]);
                                assert!(dropped >= Some(1), "{what}: {dropped:?} moves dropped for a gap");
                            }
                        }
                        ([], Some(cut)) => assert_eq!(cut, line, "{what}"),
                        (holes, cut) => panic!("{what}: holes {holes:?}, cut line {cut:?}"),
                    }
                }
                Expect::Named(want, says) => {
                    assert_eq!(code, want, "{what}: {err}");
                    assert!(err.contains(says), "{what}: {err}");
                    assert!(k(&out).is_null(), "{what}: a K from it: {out}");
                    assert!(lib.is_err() || lib.as_ref().is_ok_and(|(_, c)| c.record().is_none()), "{what}: a K from the library");
                }
                Expect::Same => {
                    let (log, _) = lib.unwrap_or_else(|e| panic!("{what}: {e}"));
                    assert_eq!(log.rows, base.rows, "{what}");
                    assert_eq!((code, k(&out)), (base_code, k(&base_out)), "{what}: {err}");
                    assert!(!err.contains("warning"), "{what}: {err}");
                }
            }
        }
    }
}

#[test]
fn the_firmware_s_messages_are_counted_and_garbage_among_them_is_named() {
    // The Ferraris session with the firmware's lines between its rows: each one counted as a
    // message; one of them garbled into control bytes (a glitch on the line) is named.
    let s = &sessions()[0];
    let (base, c) = library(s.text.as_bytes(), &["--whole-turns".to_string()]).unwrap();
    let messages = firmware_messages(&c);
    let mut lines = s.lines();
    for (k, m) in messages.iter().enumerate().rev() {
        lines.insert(2 + 10 * k, m.clone());
    }
    let text = join(&lines);
    let log = csvlog::parse(std::str::from_utf8(&text).unwrap()).unwrap();
    let blank = messages.iter().filter(|m| m.trim().is_empty() || m.trim().starts_with('#')).count();
    assert_eq!((log.messages, log.rows.len()), (messages.len() - blank, base.rows.len()));
    let garbled = lines.iter().position(|l| l.starts_with("phase: ")).unwrap();
    lines[garbled] = lines[garbled].replacen("phase", "ph\u{1}se", 1);
    let e = csvlog::parse(&String::from_utf8(join(&lines)).unwrap()).unwrap_err();
    assert!(matches!(e, LogError::NotALine { line, .. } if line == garbled as u32 + 1), "{e}");
    assert!(e.to_string().contains("\"ph\\u{1}se: "), "{e}");
}
