//! The board↔PC line protocol of the USB serial console, defined once: the command bytes the PC
//! sends ([`Command`]), and for every line the board sends that the PC (`calib --port`) or a
//! test reacts to, its writer beside its parser ([`parse`] → [`Event`]).
//!
//! The firmware writes the lines with these writers (directly, or through
//! [`crate::formats::text::report`] and [`crate::formats::export`]); the PC never matches a sentence, only the
//! [`Event`] it parses to. A line that is none of these (the other report lines, an older firmware's C
//! snippet, warnings) parses to `None`: it is for people.
//!
//! No allocation, and no `core::fmt` float code (numbers with decimals go through
//! [`crate::formats::text::Fixed`]). The parsers are for the PC; the firmware links only the writers.

use crate::error::Error;
use crate::estimators::accel::AccelModel;
use crate::estimators::gyro::Method;
use crate::formats::log::{self, Row, END, HEADER, HEADER_MAG, HEADER_RAW};
use crate::formats::record::Record;
use crate::formats::text::{Fixed, Int, Text, M3, V3};
use crate::procedure::Phase;
use crate::Vec3;
use core::fmt::{self, Write};

/// A one-byte command from the PC (or a terminal). Letters are case-insensitive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command {
    /// `c`: calibrate, or continue after the re-clamp (as a short press of the button).
    Calibrate,
    /// `r`: raw-log mode on/off (as a long press).
    RawLog,
    /// `s`: the stored calibration (its record line and the JSON line).
    Stored,
    /// `p`: the sensor setup of the next calibration: the firmware's own, or Arduino_LSM9DS1's
    /// (119 Hz, ±2000 °/s, ±4 g), in turn.
    Setup,
    /// `h` (or anything unknown): the help.
    Help,
}

impl Command {
    /// Every command.
    pub const ALL: [Command; 5] = [Command::Calibrate, Command::RawLog, Command::Stored, Command::Setup, Command::Help];

    /// The byte that sends it.
    pub const fn byte(self) -> u8 {
        match self {
            Command::Calibrate => b'c',
            Command::RawLog => b'r',
            Command::Stored => b's',
            Command::Setup => b'p',
            Command::Help => b'h',
        }
    }

    /// The command of one received byte: `None` for line endings, spaces and NUL (terminals send
    /// them after every command), [`Command::Help`] for an unknown byte.
    pub fn decode(b: u8) -> Option<Self> {
        const CALIBRATE: u8 = Command::Calibrate.byte();
        const RAW_LOG: u8 = Command::RawLog.byte();
        const STORED: u8 = Command::Stored.byte();
        const SETUP: u8 = Command::Setup.byte();
        Some(match b.to_ascii_lowercase() {
            b'\r' | b'\n' | b' ' | b'\t' | 0 => return None,
            CALIBRATE => Command::Calibrate,
            RAW_LOG => Command::RawLog,
            STORED => Command::Stored,
            SETUP => Command::Setup,
            _ => Command::Help,
        })
    }
}

/// The help (the answer to [`Command::Help`]), one line each.
pub const HELP: [&str; 2] = [
    "commands: c calibrate, or go on after re-clamping (= the button); r raw log on/off; s stored calibration (JSON); p sensor setup: ours or Arduino's library's (119 Hz LSM9DS1, 100 Hz BMI270, +-2000 dps, +-4 g) in turn until reset; h help",
    "1200-baud touch (open at 1200 Bd, close): resets into the Arduino bootloader for bossac",
];

/// Said once USB is up.
pub const USB_STARTED: &str = "USB: started (CDC-ACM serial; type h for help)";
/// The answer to [`Command::Stored`] without a stored record.
pub const NO_RECORD: &str = "no calibration stored";

/// Which record line ([`record`]): what it says about the record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RecordLine {
    /// Loaded from flash at boot (and applied).
    Loaded,
    /// The answer to [`Command::Stored`] (followed by the JSON line).
    Stored,
    /// A calibration ended with this record stored and applied (followed by the JSON line).
    CalibrationDone,
}

impl RecordLine {
    const ALL: [RecordLine; 3] = [RecordLine::Loaded, RecordLine::Stored, RecordLine::CalibrationDone];

    fn prefix(self) -> &'static str {
        match self {
            RecordLine::Loaded => "loaded",
            RecordLine::Stored => "stored",
            RecordLine::CalibrationDone => "calibration done: stored",
        }
    }
}

/// A line of the board, parsed ([`parse`]). Borrowed text is the board's own words, for the user.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Event<'a> {
    /// Line `line` of [`HELP`].
    Help {
        /// Its index in [`HELP`].
        line: u8,
    },
    /// [`USB_STARTED`].
    UsbStarted,
    /// [`usb_dropped`]: bytes of lines the host did not read, since boot.
    UsbDropped {
        /// Bytes.
        bytes: u32,
    },
    /// [`ignored`].
    Ignored {
        /// The counts since boot.
        n: Ignored,
        /// The commands one loop tick takes.
        limit: u32,
    },
    /// [`sensor_ready`].
    SensorReady {
        /// Output data rate (Hz).
        odr_hz: u32,
        /// Gyro full scale (±°/s).
        gyro_dps: u32,
        /// Accelerometer full scale (±g).
        accel_g: u32,
    },
    /// [`record`]: a record's one-line summary.
    Record {
        /// Which line.
        line: RecordLine,
        /// The record's sequence number.
        seq: u32,
        /// Its gyro estimator.
        method: Method,
    },
    /// [`NO_RECORD`].
    NoRecord,
    /// The record as one line of JSON ([`crate::formats::export::Format::Json`]), after
    /// [`RecordLine::CalibrationDone`] and [`RecordLine::Stored`].
    ResultJson(&'a str),
    /// The raw log starts: [`HEADER`] ([`raw_log`]).
    RawLogStart,
    /// The raw log ends: [`END`] ([`raw_log`]).
    RawLogEnd,
    /// A raw-log row ([`log::write_row`]).
    Row(Row),
    /// [`plan`]: the poses a calibration will take.
    Plan {
        /// Rig poses.
        rig_poses: u32,
        /// Hand-held poses.
        handheld_poses: u32,
    },
    /// [`phase`]: a phase started.
    Phase {
        /// Which.
        phase: Phase,
        /// What the user must do, in the board's words.
        instruction: Option<&'a str>,
    },
    /// [`hand_held_pose`]: a hand-held pose was captured.
    HandHeldPose {
        /// Its index (0-based).
        index: u8,
    },
    /// [`rig_pose`]: a rig pose was captured.
    RigPose {
        /// Its index (0-based).
        index: u8,
    },
    /// [`failed`]: the calibration failed and nothing was stored.
    Failed {
        /// Why, in the board's words.
        reason: &'a str,
    },
}

// The writers' words as literals (each `core::fmt` argument costs flash), their parsers' beside
// them; the unit tests write and parse every line.

/// Writes `USB: <bytes> bytes dropped since boot (the host was not reading)`.
pub fn usb_dropped(w: &mut impl Write, bytes: u32) -> fmt::Result {
    write!(w, "USB: {} bytes dropped since boot (the host was not reading)", Int(bytes.into()))
}

fn parse_usb_dropped(l: &str) -> Option<Event<'_>> {
    let n = between(l, "USB: ", " bytes dropped since boot (the host was not reading)")?;
    Some(Event::UsbDropped { bytes: n.parse().ok()? })
}

/// Commands received and not carried out, since boot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Ignored {
    /// Beyond the commands one loop tick takes (a host sending faster than the board reads).
    pub beyond_tick: u32,
    /// `c` (or the button) while a calibration ran and was not waiting for the re-clamp.
    pub running: u32,
}

/// Writes the commands ignored since boot (`limit`: the commands one loop tick takes). Counts
/// since boot, so that a later line makes up for one a full log dropped.
pub fn ignored(w: &mut impl Write, n: Ignored, limit: u32) -> fmt::Result {
    let (beyond, limit, running) = (Int(n.beyond_tick.into()), Int(limit.into()), Int(n.running.into()));
    write!(w, "commands ignored since boot: {beyond} beyond the {limit} a loop tick takes, {running} c {}", Text(IGNORED_RUNNING))
}

const IGNORED_RUNNING: &str = "while a calibration ran (a press only ends its re-clamp step)";

fn parse_ignored(l: &str) -> Option<Event<'_>> {
    let rest = between(l, "commands ignored since boot: ", IGNORED_RUNNING)?;
    let (beyond, rest) = rest.split_once(" beyond the ")?;
    let (limit, running) = rest.split_once(" a loop tick takes, ")?;
    let running = running.strip_suffix(" c ")?;
    let n = Ignored { beyond_tick: beyond.parse().ok()?, running: running.parse().ok()? };
    Some(Event::Ignored { n, limit: limit.parse().ok()? })
}

/// Writes `LSM9DS1 ready: <odr> Hz, +-<gyro> dps, +-<accel> g`.
pub fn sensor_ready(w: &mut impl Write, odr_hz: u32, gyro_dps: u32, accel_g: u32) -> fmt::Result {
    let (odr_hz, gyro_dps, accel_g) = (Int(odr_hz.into()), Int(gyro_dps.into()), Int(accel_g.into()));
    write!(w, "LSM9DS1 ready: {odr_hz} Hz, +-{gyro_dps} dps, +-{accel_g} g")
}

fn parse_sensor_ready(l: &str) -> Option<Event<'_>> {
    let (odr, rest) = between(l, "LSM9DS1 ready: ", " g")?.split_once(" Hz, +-")?;
    let (gyro, accel) = rest.split_once(" dps, +-")?;
    Some(Event::SensorReady { odr_hz: odr.parse().ok()?, gyro_dps: gyro.parse().ok()?, accel_g: accel.parse().ok()? })
}

/// Writes a record's line: what it is, the sequence number, the estimator, `K` in full
/// (row-major) and the bias.
pub fn record(w: &mut impl Write, line: RecordLine, rec: &Record) -> fmt::Result {
    let what = Text(line.prefix());
    write!(
        w,
        "{what} record {} ({} K): K = {}, b = {} dps",
        Int(rec.seq.into()),
        Text(rec.method.name()),
        M3(rec.gyro_k, 6),
        V3(rec.gyro_bias_dps, 4)
    )
}

fn parse_record(l: &str) -> Option<Event<'_>> {
    let (line, rest) = RecordLine::ALL.into_iter().find_map(|k| Some((k, l.strip_prefix(k.prefix())?.strip_prefix(" record ")?)))?;
    let (seq, rest) = rest.split_once(" (")?;
    let (name, _) = rest.split_once(" K): ")?;
    Some(Event::Record { line, seq: seq.parse().ok()?, method: method(name)? })
}

/// The raw log's first line (`on`, [`HEADER_RAW`]: the magnetometer's columns empty on a board
/// without one) or its end marker ([`END`]).
pub fn raw_log(on: bool) -> &'static str {
    if on {
        HEADER_RAW
    } else {
        END
    }
}

/// Writes the plan announced when a calibration starts.
pub fn plan(w: &mut impl Write, rig_poses: usize, handheld_poses: usize) -> fmt::Result {
    let (rig_poses, handheld_poses) = (Int(rig_poses as i64), Int(handheld_poses as i64));
    write!(w, "plan: {rig_poses} rig poses, {handheld_poses} hand-held poses")
}

fn parse_plan(l: &str) -> Option<Event<'_>> {
    let (rig, hand) = between(l, "plan: ", " hand-held poses")?.split_once(" rig poses, ")?;
    Some(Event::Plan { rig_poses: rig.parse().ok()?, handheld_poses: hand.parse().ok()? })
}

/// Writes `phase: <name>[: <instruction>]`.
pub fn phase(w: &mut impl Write, p: Phase) -> fmt::Result {
    match p.instruction() {
        Some(i) => write!(w, "phase: {}: {}", Text(p.name()), Text(i)),
        None => write!(w, "phase: {}", Text(p.name())),
    }
}

fn parse_phase(l: &str) -> Option<Event<'_>> {
    let rest = l.strip_prefix("phase: ")?;
    let (name, instruction) = rest.split_once(": ").map_or((rest, None), |(n, i)| (n, Some(i)));
    Some(Event::Phase { phase: PHASES.into_iter().find(|p| p.name() == name)?, instruction })
}

/// Writes `hand-held pose <index>: a = [x y z] g` (the raw mean).
pub fn hand_held_pose(w: &mut impl Write, index: u8, accel_g: &Vec3) -> fmt::Result {
    write!(w, "hand-held pose {}: a = {} g", Int(index.into()), V3(*accel_g, 4))
}

/// Writes `rig pose <index> at <servo> deg: A = [x y z] g`.
pub fn rig_pose(w: &mut impl Write, index: u8, servo_deg: f32, accel_g: &Vec3) -> fmt::Result {
    write!(w, "rig pose {} at {} deg: A = {} g", Int(index.into()), Fixed(servo_deg, 1), V3(*accel_g, 4))
}

fn parse_pose(l: &str) -> Option<Event<'_>> {
    if let Some(rest) = l.strip_prefix("hand-held pose ") {
        return Some(Event::HandHeldPose { index: rest.split_once(": a = ")?.0.parse().ok()? });
    }
    Some(Event::RigPose { index: l.strip_prefix("rig pose ")?.split_once(" at ")?.0.parse().ok()? })
}

/// Writes `calibration failed, nothing stored: <error>`.
pub fn failed(w: &mut impl Write, e: &Error) -> fmt::Result {
    write!(w, "calibration failed, nothing stored: {e}")
}

fn parse_failed(l: &str) -> Option<Event<'_>> {
    Some(Event::Failed { reason: l.strip_prefix("calibration failed, nothing stored: ")? })
}

/// Every phase, for [`parse`].
const PHASES: [Phase; 10] = [
    Phase::Idle,
    Phase::WaitRest,
    Phase::Bias,
    Phase::HandHeld,
    Phase::Reattach,
    Phase::RigPoses,
    Phase::Spin,
    Phase::Store,
    Phase::Done,
    Phase::Failed,
];
/// Every gyro estimator, for [`parse`] and the JSON schema.
pub(crate) const METHODS: [Method; 3] = [Method::Paper, Method::Sweep, Method::Full];
/// Every accelerometer model, for the JSON schema.
pub(crate) const ACCEL_MODELS: [AccelModel; 3] = [AccelModel::None, AccelModel::SixParam, AccelModel::NineParam];

/// The gyro estimator of this name ([`Method::name`]).
pub fn method(name: &str) -> Option<Method> {
    METHODS.into_iter().find(|m| m.name() == name)
}

/// The accelerometer model of this name ([`AccelModel::name`]).
pub fn accel_model(name: &str) -> Option<AccelModel> {
    ACCEL_MODELS.into_iter().find(|m| m.name() == name)
}

/// The text between `pre` and `post` in `l`, which must start with `pre` and end with `post`.
fn between<'a>(l: &'a str, pre: &str, post: &str) -> Option<&'a str> {
    l.strip_prefix(pre)?.strip_suffix(post)
}

/// What a line of the board is (trailing whitespace and line endings ignored); `None`: a line
/// the PC does not react to.
pub fn parse(line: &str) -> Option<Event<'_>> {
    let l = line.trim_end();
    if let Some(i) = HELP.iter().position(|h| *h == l) {
        return Some(Event::Help { line: i as u8 });
    }
    Some(match l {
        USB_STARTED => Event::UsbStarted,
        NO_RECORD => Event::NoRecord,
        HEADER | HEADER_MAG | HEADER_RAW => Event::RawLogStart,
        END => Event::RawLogEnd,
        _ if l.starts_with(crate::formats::export::JSON_START) => Event::ResultJson(l),
        _ if l.starts_with(|c: char| c.is_ascii_digit() || matches!(c, '-' | '+' | '.')) => {
            // A row of any header: with the magnetometer's three fields and the temperature's,
            // with the magnetometer's only (older firmware), or neither.
            let header = match l.split(',').count().saturating_sub(log::COLUMNS.len()) {
                0 => HEADER,
                1..=3 => HEADER_MAG,
                _ => HEADER_RAW,
            };
            Event::Row(log::parse_row(l, &log::parse_header(header).ok()?, 0).ok()?)
        }
        _ => return parse_prefixed(l),
    })
}

/// The lines that start with fixed words and go on with numbers or text.
fn parse_prefixed(l: &str) -> Option<Event<'_>> {
    [parse_failed, parse_phase, parse_pose, parse_plan, parse_usb_dropped, parse_ignored, parse_sensor_ready, parse_record]
        .iter()
        .find_map(|p| p(l))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::export::{self, Format};
    use crate::formats::record::tests::sample;
    use crate::time::secs;
    extern crate std;
    use std::string::String;

    /// The line a writer writes.
    fn line(f: impl FnOnce(&mut String) -> fmt::Result) -> String {
        let mut s = String::new();
        f(&mut s).unwrap();
        assert!(!s.contains('\n'), "{s:?}");
        s
    }

    #[test]
    fn every_command_byte_decodes_to_its_command_in_either_case() {
        for c in Command::ALL {
            assert_eq!(Command::decode(c.byte()), Some(c));
            assert_eq!(Command::decode(c.byte().to_ascii_uppercase()), Some(c));
        }
        for b in [b'?', b'x', 0xFF, 0x1B] {
            assert_eq!(Command::decode(b), Some(Command::Help), "{b:#x}");
        }
        for b in [b'\r', b'\n', b' ', b'\t', 0] {
            assert_eq!(Command::decode(b), None);
        }
    }

    #[test]
    fn the_help_and_the_instructions_name_the_command_bytes() {
        let named = |text: &str, c: Command| {
            let ch = c.byte() as char;
            text.split([';', ':', '(', ',']).any(|part| part.trim_start().starts_with(&std::format!("{ch} ")))
                || text.contains(&std::format!("send {ch})"))
                || text.contains(&std::format!("type {ch} "))
        };
        for c in Command::ALL {
            assert!(named(HELP[0], c), "{c:?} not in the help");
        }
        assert!(named(USB_STARTED, Command::Help));
        assert!(named(Phase::Reattach.instruction().unwrap(), Command::Calibrate));
        for (i, h) in HELP.iter().enumerate() {
            assert_eq!(parse(h), Some(Event::Help { line: i as u8 }));
        }
    }

    #[test]
    fn the_fixed_lines_parse_to_their_events() {
        assert_eq!(parse(USB_STARTED), Some(Event::UsbStarted));
        assert_eq!(parse(NO_RECORD), Some(Event::NoRecord));
        assert_eq!(parse(&std::format!("{NO_RECORD}\r\n")), Some(Event::NoRecord));
        assert_eq!(parse(raw_log(true)), Some(Event::RawLogStart));
        assert_eq!(parse(raw_log(false)), Some(Event::RawLogEnd));
        // The boot warning begins with the same words but is not the answer to `s`.
        assert_eq!(parse("no calibration stored: raw gyro readings until the button is pressed"), None);
        assert_eq!(parse("gyro bias [0.1 0.2 0.3] dps, 1 sigma [0.01 0.01 0.01], 100 samples"), None);
        assert_eq!(parse(""), None);
    }

    #[test]
    fn the_usb_and_sensor_lines_round_trip() {
        for bytes in [0, 4096, u32::MAX] {
            assert_eq!(parse(&line(|s| usb_dropped(s, bytes))), Some(Event::UsbDropped { bytes }));
        }
        for (beyond_tick, running) in [(0, 0), (56, 1), (u32::MAX, u32::MAX)] {
            let n = Ignored { beyond_tick, running };
            assert_eq!(parse(&line(|s| ignored(s, n, 8))), Some(Event::Ignored { n, limit: 8 }));
        }
        let l = line(|s| sensor_ready(s, 119, 500, 2));
        assert_eq!(l, "LSM9DS1 ready: 119 Hz, +-500 dps, +-2 g");
        assert_eq!(parse(&l), Some(Event::SensorReady { odr_hz: 119, gyro_dps: 500, accel_g: 2 }));
    }

    #[test]
    fn record_lines_and_the_json_line_round_trip() {
        for m in METHODS {
            let rec = Record { seq: 41, method: m, ..sample() };
            for kind in RecordLine::ALL {
                let l = line(|s| record(s, kind, &rec));
                assert_eq!(parse(&l), Some(Event::Record { line: kind, seq: 41, method: m }), "{l}");
            }
            let j = line(|s| export::write(s, &rec, Format::Json));
            assert_eq!(parse(&j), Some(Event::ResultJson(&j)));
        }
        let l = line(|s| record(s, RecordLine::CalibrationDone, &sample()));
        assert!(l.starts_with("calibration done: stored record 7 (sweep K): K = [1.010000 0.000000 0.000000; "), "{l}");
        // A C snippet (an older firmware's, after the JSON line) is for people.
        let mut c = String::new();
        export::write(&mut c, &sample(), Format::C).unwrap();
        assert!(c.lines().all(|l| parse(l).is_none()), "{c}");
    }

    #[test]
    fn rows_round_trip() {
        let row = Row {
            t: secs(12.5),
            accel_g: [0.25, -0.5, 1.0],
            gyro_dps: [0.125, 0.0, -2.5],
            servo_deg: Some(30.0),
            tilt_deg: None,
            mag_ut: None,
            temp_c: None,
        };
        assert_eq!(parse(&line(|s| log::write_row(s, &row))), Some(Event::Row(row)));
        let with = Row { mag_ut: Some([-12.5, 30.25, -41.0]), ..row };
        for r in [row, with] {
            assert_eq!(parse(&line(|s| log::write_row(s, &r).and_then(|_| log::write_mag(s, r.mag_ut)))), Some(Event::Row(r)));
        }
        // The firmware's rows: the temperature after the field, each empty or not.
        for r in [row, with, Row { temp_c: Some(31.25), ..row }, Row { temp_c: Some(-4.5), ..with }] {
            let l = line(|s| log::write_row(s, &r).and_then(|_| log::write_mag(s, r.mag_ut)).and_then(|_| log::write_temp(s, r.temp_c)));
            assert_eq!(parse(&l), Some(Event::Row(r)), "{l}");
        }
        assert_eq!(HEADER_MAG, std::format!("{HEADER},{}", log::MAG_COLUMNS.join(",")));
        assert_eq!(HEADER_RAW, std::format!("{HEADER_MAG},{}", log::TEMP_COLUMN));
        for h in [HEADER, HEADER_MAG, HEADER_RAW] {
            assert_eq!(parse(h), Some(Event::RawLogStart));
        }
    }

    #[test]
    fn procedure_lines_round_trip() {
        assert_eq!(parse(&line(|s| plan(s, 13, 12))), Some(Event::Plan { rig_poses: 13, handheld_poses: 12 }));
        for p in PHASES {
            let l = line(|s| phase(s, p));
            assert_eq!(parse(&l), Some(Event::Phase { phase: p, instruction: p.instruction() }), "{l}");
            // And as the procedure reports it.
            assert_eq!(l, line(|s| crate::formats::text::report(s, &crate::procedure::Report::Phase(p))));
        }
        for index in [0, 11, 255] {
            assert_eq!(parse(&line(|s| hand_held_pose(s, index, &[0.0, -0.6, 0.8]))), Some(Event::HandHeldPose { index }));
            assert_eq!(parse(&line(|s| rig_pose(s, index, -45.0, &[0.6, 0.0, 0.8]))), Some(Event::RigPose { index }));
        }
        let e = Error::ServoNotTurning { channel: 1, commanded_deg: 30.0, measured_deg: 0.5 };
        let l = line(|s| failed(s, &e));
        assert_eq!(parse(&l), Some(Event::Failed { reason: &line(|s| write!(s, "{e}")) }));
    }

    #[test]
    fn the_name_lists_are_complete() {
        // A new variant fails to compile here: add it here and to its list.
        for p in PHASES {
            match p {
                Phase::Idle
                | Phase::WaitRest
                | Phase::Bias
                | Phase::HandHeld
                | Phase::Reattach
                | Phase::RigPoses
                | Phase::Spin
                | Phase::Store
                | Phase::Done
                | Phase::Failed => {}
            }
        }
        for m in METHODS {
            match m {
                Method::Paper | Method::Sweep | Method::Full => assert_eq!(method(m.name()), Some(m)),
            }
        }
        for a in ACCEL_MODELS {
            match a {
                AccelModel::None | AccelModel::SixParam | AccelModel::NineParam => assert_eq!(accel_model(a.name()), Some(a)),
            }
        }
        let names = |n: &mut dyn Iterator<Item = &'static str>| n.collect::<std::collections::BTreeSet<_>>().len();
        assert_eq!(names(&mut PHASES.iter().map(|p| p.name())), PHASES.len());
        assert_eq!(names(&mut METHODS.iter().map(|p| p.name())), METHODS.len());
        assert_eq!(names(&mut ACCEL_MODELS.iter().map(|p| p.name())), ACCEL_MODELS.len());
    }
}
