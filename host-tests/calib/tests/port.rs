//! `calib --port` without hardware: a fake board on the master side of a pseudo-terminal plays a
//! simulated log through the firmware's procedure (button presses on [`Command::Calibrate`], the
//! procedure's report lines and the other lines through `calib_core::formats::protocol`'s writers, its
//! record as calib-core's JSON), the session on the slave.
#![cfg(unix)]

use calib::csvlog;
use calib::port::{self, Awaiting, Options, SessionError, K_TOLERANCE};
use calib_core::formats::export::{self, Format};
use calib_core::formats::log;
use calib_core::formats::protocol::{self, Command, Event, RecordLine};
use calib_core::formats::record::{Record, StoreError};
use calib_core::formats::text;
use calib_core::procedure::{Config, Led, Phase, Procedure, Report, Sample, Shell};
use calib_core::Error;
use common::calib;
use rig_sim::harness::{record_log, Faults};
use rig_sim::sim::Rig;
use rig_sim::variant::Variant;
use serialport::{SerialPort, TTYPort};
use std::io::{Cursor, Read, Write};
use std::path::PathBuf;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use crate::common;

/// Two simulated runs of the default procedure on one rig, shared by the tests: the first from
/// an empty flash, the second from the record the first stored.
struct Runs {
    first: String,
    stored: Record,
    second: String,
    second_record: Record,
}

fn runs() -> &'static Runs {
    static RUNS: OnceLock<Runs> = OnceLock::new();
    RUNS.get_or_init(|| {
        let run = |seed, stored| {
            let mut rig = Rig::new(Variant::Hobby.config(8, 0), seed);
            let (log, out) = record_log(&mut rig, &mut Procedure::new(Config::DEFAULT, stored), Faults::default(), "");
            (log, out.stored[0])
        };
        let (first, stored) = run(3, None);
        let (second, second_record) = run(4, Some(stored));
        Runs { first, stored, second, second_record }
    })
}

fn sim_log() -> &'static str {
    &runs().first
}

/// How the fake board misbehaves.
#[derive(Clone, Copy, Default)]
struct Quirks {
    /// Never answers (its port open).
    silent: bool,
    /// Adds this to K[0][1] in its JSON line.
    k_offset: f32,
    /// Does not send these rows (they are still sampled: USB dropped them).
    drop_rows: Option<(usize, usize)>,
    /// Is in raw-log mode already: the first `r` switches it off.
    raw_on: bool,
    /// Fails the calibration once it starts.
    fails: bool,
    /// The record in its flash (the run starts from it).
    stored: Option<Record>,
}

/// The board's report lines, in the firmware's wording; its JSON after the calibration-done line.
struct Lines {
    out: Vec<String>,
    k_offset: f32,
}

impl Shell for Lines {
    fn servo(&mut self, _: u8, _: u16) {}
    fn servo_off(&mut self, _: u8) {}
    fn led(&mut self, _: Led) {}
    fn report(&mut self, r: &Report) {
        let mut l = String::new();
        text::report(&mut l, r).unwrap();
        self.out.push(l);
        if let Report::Done(rec) = r {
            let mut rec = *rec;
            rec.gyro_k[0][1] += self.k_offset;
            let mut j = String::new();
            export::write(&mut j, &rec, Format::Json).unwrap();
            self.out.push(j);
        }
    }
    fn store(&mut self, _: &Record) -> Result<(), StoreError> {
        Ok(())
    }
    fn apply(&mut self, _: &Record) {}
}

/// Waits (≤ 60 s) for the command `want`, ignoring others; false if it never came.
fn wait_for(m: &mut TTYPort, want: Command) -> bool {
    let t0 = Instant::now();
    let mut b = [0u8; 1];
    while t0.elapsed() < Duration::from_secs(60) {
        if m.read(&mut b).is_ok_and(|n| n == 1) && Command::decode(b[0]) == Some(want) {
            return true;
        }
    }
    false
}

/// The line a protocol writer writes.
fn line(f: impl FnOnce(&mut String) -> std::fmt::Result) -> String {
    let mut s = String::new();
    f(&mut s).unwrap();
    s
}

/// The error the failing fake board reports.
const FAILURE: Error = Error::ServoNotTurning { channel: 0, commanded_deg: 30.0, measured_deg: 0.2 };

fn send(m: &mut TTYPort, lines: &mut Vec<String>) -> std::io::Result<()> {
    let mut bytes = Vec::new();
    for l in lines.drain(..) {
        bytes.extend_from_slice(l.as_bytes());
        bytes.extend_from_slice(b"\r\n");
    }
    m.write_all(&bytes)
}

/// The fake board: the firmware's main loop over the log's samples (button presses where the
/// servo columns change, as `calib::replay` finds them), every row sent in raw-log mode until its
/// calibration ends; the rows it went through. (Its buttons come at a sample's time, not the
/// simulator's, so its solve may end a step before or after the simulated board's, where the
/// log ends.)
fn board(mut m: TTYPort, log_text: &str, f: Quirks) -> std::io::Result<usize> {
    m.set_timeout(Duration::from_secs(5))?;
    if f.silent {
        // Open but mute (a closed master would be a hang-up, not silence).
        std::thread::sleep(Duration::from_secs(3));
        return Ok(0);
    }
    if !wait_for(&mut m, Command::Stored) {
        return Ok(0);
    }
    let mut sh = Lines { out: vec![], k_offset: f.k_offset };
    match &f.stored {
        Some(rec) => {
            sh.out.push(line(|s| protocol::record(s, RecordLine::Stored, rec)));
            sh.out.push(line(|s| export::write(s, rec, Format::Json)));
        }
        None => sh.out.push(protocol::NO_RECORD.into()),
    }
    send(&mut m, &mut sh.out)?;
    if f.raw_on && wait_for(&mut m, Command::RawLog) {
        send(
            &mut m,
            &mut vec!["0.500000,0.000000,0.000000,1.000000,0.00000,0.00000,0.00000,,,,,".into(), protocol::raw_log(false).into()],
        )?;
    }
    if !wait_for(&mut m, Command::RawLog) {
        return Ok(0);
    }
    let rows = csvlog::parse(log_text).unwrap().rows;
    let mut p = Procedure::new(Config::DEFAULT, f.stored);
    sh.out.push(protocol::raw_log(true).into());
    let mut prev_t = rows[0].t;
    let (mut started, mut through) = (false, 0);
    for (i, r) in rows.iter().enumerate() {
        let commanded = r.servo_deg.is_some() || r.tilt_deg.is_some();
        if commanded && (!started || p.phase() == Phase::Reattach) {
            send(&mut m, &mut sh.out)?;
            if !wait_for(&mut m, Command::Calibrate) {
                return Ok(0);
            }
            if !started {
                let (rig, hand) = p.plan();
                sh.out.push(line(|s| protocol::plan(s, rig as usize, hand as usize)));
            }
            if f.fails {
                sh.out.push(line(|s| protocol::failed(s, &FAILURE)));
                send(&mut m, &mut sh.out)?;
                wait_for(&mut m, Command::RawLog);
                return Ok(0);
            }
            if started {
                calib::replay::press_to_rig(&mut p, prev_t, &mut sh);
            } else {
                p.handle_button(prev_t);
                p.drive(prev_t, &mut sh);
            }
            started = true;
        }
        // The board's temperature, as its raw log writes it (the simulated log's).
        let temp_c = r.temp_c;
        if !f.drop_rows.is_some_and(|(a, b)| (a..b).contains(&i)) {
            let mut l = String::new();
            log::write_row(&mut l, r).and_then(|_| log::write_mag(&mut l, r.mag_ut)).and_then(|_| log::write_temp(&mut l, temp_c)).unwrap();
            sh.out.push(l);
        }
        // A field reading enters before its sample, as the firmware's `feed` does.
        if let Some(m) = r.mag_ut {
            p.handle_mag(m);
        }
        p.handle_sample(&Sample { t: r.t, accel_g: r.accel_g, gyro_dps: r.gyro_dps, temp_c });
        p.handle_tick(r.t);
        p.drive(r.t, &mut sh);
        if sh.out.len() >= 64 {
            send(&mut m, &mut sh.out)?;
        }
        through = i + 1;
        if matches!(p.phase(), Phase::Done | Phase::Failed) {
            break;
        }
        prev_t = r.t;
    }
    // The firmware's main loop ticks on without samples (2 ms apart): the solve's steps need
    // none, and the log, cut at the simulated board's store, may end a step or two before this
    // replay's (its button presses come at a sample's time, not the simulator's).
    for k in 1..=2000 {
        if !started || matches!(p.phase(), Phase::Done | Phase::Failed) {
            break;
        }
        p.handle_tick(prev_t.plus_s(k as f64 * 0.002));
        p.drive(prev_t.plus_s(k as f64 * 0.002), &mut sh);
    }
    send(&mut m, &mut sh.out)?;
    if wait_for(&mut m, Command::RawLog) {
        sh.out.push(protocol::raw_log(false).into());
        send(&mut m, &mut sh.out)?;
    }
    // Keep the master open until the session has read everything.
    std::thread::sleep(Duration::from_millis(500));
    Ok(through)
}

fn log_path(name: &str) -> PathBuf {
    let d = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("port");
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

/// A session against the fake board: its result, what the user saw, the saved log's path; the
/// log's rows the board went through.
fn session(name: &str, log: &'static str, f: Quirks, silence: Duration) -> (Result<port::Outcome, SessionError>, String, PathBuf, usize) {
    let (master, slave) = TTYPort::pair().unwrap();
    let path = slave.name().unwrap();
    let fake = std::thread::spawn(move || board(master, log, f));
    let mut opts = Options::new(log_path(name));
    opts.silence = silence;
    let mut ui = Vec::new();
    let mut p = port::open(&path).unwrap();
    let r = port::run(&mut *p, Cursor::new(b"\n".to_vec()), &mut ui, &opts);
    drop(p);
    let through = fake.join().unwrap().unwrap();
    drop(slave);
    let ui = String::from_utf8(ui).unwrap();
    eprintln!("--- {name}:\n{ui}{}", r.as_ref().err().map(|e| format!("error: {e}")).unwrap_or_default());
    (r, ui, opts.log, through)
}

#[test]
fn a_session_saves_the_log_shows_the_phases_and_cross_checks() {
    let (r, ui, path, through) = session("ok.csv", sim_log(), Quirks::default(), Duration::from_secs(20));
    let o = r.unwrap();
    // The log as received: every row the board sent, the messages between them.
    let saved = std::fs::read_to_string(&path).unwrap();
    assert!(!saved.contains('\r'));
    let (got, want) = (csvlog::parse(&saved).unwrap(), csvlog::parse(sim_log()).unwrap());
    assert!(got.rows.len() + 1 >= through && through > want.rows.len() / 2, "{} of {through} rows", got.rows.len());
    // The fake board sends the rows as the firmware does, the magnetometer's and the
    // temperature's fields included.
    assert!(want.rows.iter().any(|r| r.mag_ut.is_some()) && want.rows.iter().all(|r| r.temp_c.is_some()));
    assert_eq!(got.rows[..], want.rows[..got.rows.len()]);
    assert!(got.messages > 20, "{} messages", got.messages);
    let events: Vec<_> = saved.lines().filter_map(protocol::parse).collect();
    assert!(events.contains(&Event::RawLogEnd));
    assert_eq!(events.iter().filter(|e| matches!(e, Event::ResultJson(_))).count(), 1);
    assert_eq!(o.lines, saved.lines().count());
    // The board's result, parsed, and the cross-check.
    assert_eq!(protocol::parse(&o.json), Some(Event::ResultJson(&o.json)));
    let v: calib_core::formats::export::RecordJson = serde_json::from_str(&o.json).unwrap();
    assert_eq!(v.gyro.method, calib_core::estimators::gyro::Method::Full);
    assert_eq!(o.check.replayed, Some("default"));
    assert!(o.check.max_diff <= K_TOLERANCE, "{}", o.check.max_diff);
    assert_eq!(o.check.lost_rows, 0);
    assert_eq!(o.record.gyro_k, v.gyro.k);
    // What the user saw: the phases with their instructions, the prompt, the progress bar.
    for needle in ["phase hand-held: ", "phase reattach: ", "press Enter", "phase rig-poses", "cross-check passed"] {
        assert!(ui.contains(needle), "{needle:?} not shown");
    }
    // The bar ends full: the 13 rig poses and the hand-held ones, 12 or more (the step goes on
    // until its moves give K their goal), counted into the total as they come.
    let last = ui.lines().rfind(|l| l.contains(" poses (")).unwrap_or_default();
    let (done, rest) = last.split_once("] ").and_then(|(_, r)| r.split_once('/')).unwrap_or_default();
    let (total, hand) =
        rest.split_once(" poses (").and_then(|(t, r)| Some((t, r.split_once(" hand-held, 13 rig)")?.0))).unwrap_or_default();
    let n = |s: &str| s.parse::<usize>().unwrap_or(0);
    assert!(done == total && n(hand) >= 12 && n(total) == n(hand) + 13, "{last}");
}

#[test]
fn a_board_k_that_disagrees_fails_the_cross_check() {
    let (r, _, _, _) = session("bad-k.csv", sim_log(), Quirks { k_offset: 1e-3, ..Quirks::default() }, Duration::from_secs(20));
    let e = r.unwrap_err();
    assert_eq!(e.exit_code(), 5);
    // Where it differs, and not for a lost row or a log that does not replay.
    let SessionError::Mismatch { check, .. } = &e else { panic!("{e}") };
    assert_eq!((check.at, check.lost_rows, check.replayed), ((0, 1), 0, Some("default")), "{e}");
    assert!((check.max_diff - 1e-3).abs() < 1e-5, "{e}");
}

#[test]
fn rows_lost_on_usb_are_counted_in_the_cross_check_failure() {
    // Three rows in the middle of the first rig move after the re-clamp.
    let rows = csvlog::parse(sim_log()).unwrap().rows;
    // The re-clamp: the last row without a servo angle before the rig's (the solve's rows after
    // the last pose have none either).
    let last_rig = rows.iter().rposition(|r| r.servo_deg.is_some()).unwrap();
    let reclamped = rows[..last_rig].iter().rposition(|r| r.servo_deg.is_none()).unwrap();
    let moving = (reclamped + 2..rows.len()).find(|&i| rows[i].servo_deg != rows[i - 1].servo_deg).unwrap() + 20;
    let (r, _, path, _) =
        session("lost.csv", sim_log(), Quirks { drop_rows: Some((moving, moving + 3)), ..Quirks::default() }, Duration::from_secs(20));
    let e = r.unwrap_err();
    assert_eq!(e.exit_code(), 5);
    let SessionError::Mismatch { check, .. } = &e else { panic!("{e}") };
    assert_eq!((check.lost_rows, check.rows), (3, rows_until_done(&path)), "{e}");
}

/// Rows in a saved log.
fn rows_until_done(path: &PathBuf) -> usize {
    csvlog::parse(&std::fs::read_to_string(path).unwrap()).unwrap().rows.len()
}

#[test]
fn a_silent_board_is_a_timeout_error() {
    let (r, _, _, _) = session("silent.csv", sim_log(), Quirks { silent: true, ..Quirks::default() }, Duration::from_secs(1));
    let e = r.unwrap_err();
    assert!(matches!(e, SessionError::Silent { secs: 1, waiting_for: Awaiting::StoredRecord }), "{e}");
    assert_eq!(e.exit_code(), 6);
}

#[test]
fn a_port_that_does_not_exist_is_named() {
    let (code, out, err) = calib(&["--port", "/nonexistent/ttyACM9"]);
    assert_eq!(code, 2, "{err}");
    assert!(out.is_empty() && err.contains("/nonexistent/ttyACM9: cannot open the port"), "{err}");
    let (code, _, err) = calib(&["--log", "x.csv"]);
    assert_eq!(code, 2, "{err}");
}

#[test]
fn a_board_in_raw_log_mode_is_switched_back_on_and_a_failed_calibration_is_named() {
    let (r, _, path, _) =
        session("failed.csv", sim_log(), Quirks { raw_on: true, fails: true, ..Quirks::default() }, Duration::from_secs(20));
    let e = r.unwrap_err();
    assert_eq!(e.exit_code(), 1);
    assert!(matches!(&e, SessionError::CalibrationFailed(reason) if *reason == FAILURE.to_string()), "{e}");
    // The first raw log ended, the session's own started.
    let saved = std::fs::read_to_string(path).unwrap();
    let events: Vec<_> = saved.lines().map(protocol::parse).collect();
    assert!(events.windows(2).any(|w| w == [Some(Event::RawLogEnd), Some(Event::RawLogStart)]), "{saved}");
}

#[test]
fn a_run_from_the_stored_record_is_replayed_from_it() {
    // No hand-held poses: the board calibrates with its stored accelerometer calibration, which
    // calib gets from the answer to `s`.
    let r = &runs();
    let (res, ui, _, _) = session("stored.csv", &r.second, Quirks { stored: Some(r.stored), ..Quirks::default() }, Duration::from_secs(20));
    let o = res.unwrap();
    assert!(!ui.contains("phase hand-held"), "{ui}");
    assert_eq!((o.record.seq, o.check.replayed), (r.stored.seq + 1, Some("default")));
    assert!(o.check.max_diff <= K_TOLERANCE, "{}", o.check.max_diff);
    assert!(ui.contains("from the stored record"), "{ui}");
    // The simulated board's own record (from unrounded samples) agrees too. Without the stored
    // record the log is not replayed, and its one cone of rig poses gives no accelerometer.
    let c = port::cross_check(&r.second_record, &r.second, 0, Some(&r.stored)).unwrap();
    assert!(c.max_diff <= K_TOLERANCE / 10.0, "{}", c.max_diff);
    let e = port::cross_check(&r.second_record, &r.second, 0, None).unwrap_err();
    assert!(matches!(e, SessionError::Offline(_)), "{e}");
}
