//! Whole logs on the PC: the format itself ([`calib_core::formats::log`]) is shared with the firmware's
//! raw-log mode; this adds reading a whole text into rows and writing one, and what only a whole
//! log shows: readings beyond the sensor's full scale, holes in time.

use calib_core::formats::log::{self, Bound, Line, PLAUSIBLE, STATED_MARGIN};
pub use calib_core::formats::log::{LogError, Row, HEADER};
use calib_core::formats::record::SensorSetup;
use calib_core::Time;
use std::borrow::Cow;

/// A parsed log.
#[derive(Debug, Clone, PartialEq)]
pub struct Log {
    /// The samples, in time order.
    pub rows: Vec<Row>,
    /// The line number of each row (same index).
    pub lines: Vec<u32>,
    /// Log messages between the rows that were skipped.
    pub messages: usize,
    /// The sensor setup the log states ([`log::write_setup`]; the firmware's raw log does), if
    /// it states one.
    pub setup: Option<SensorSetup>,
    /// The line number of a last line cut mid-row (the text ends without a newline in a row
    /// that does not parse: a recording stopped while writing), which was left out.
    pub cut_line: Option<u32>,
    /// Holes in time ([`Hole`]), each with what spans it; a hole between two rig poses is an
    /// error ([`LogError::HoleInRig`]).
    pub holes: Vec<Hole>,
}

/// A hole in time: no samples for more than [`HOLE_PERIODS`] median sample periods and more than
/// [`HOLE_MIN_S`] (every later time shifted by it: samples lost, a recording paused).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hole {
    /// The line of the first row after it.
    pub line: u32,
    /// The time between the rows on either side (s).
    pub gap_s: f64,
    /// The time of the row before it (s).
    pub t_s: f64,
    /// The median sample period (s).
    pub period_s: f64,
    /// What spans it.
    pub across: Across,
}

/// What a hole in time falls between, and so what the calibration does with it (the poses are
/// found as the calibration finds them, [`crate::offline::phases`]; no still pose spans a hole).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Across {
    /// Two hand-held poses (their first and last times, s): the move between them is left out,
    /// samples are missing from it (calib-core's `Rejected::Gap`); both poses are used.
    HandHeldMove {
        /// The pose before the hole.
        before: (f64, f64),
        /// The pose after it.
        after: (f64, f64),
    },
    /// A hand-held pose and a rig pose: no move between poses spans it.
    HandAndRig,
    /// It comes before the first pose: nothing spans it.
    BeforeThePoses,
    /// It comes after the last pose: nothing spans it, but the bias handed over (the rests' drift
    /// predicted to the log's end) is predicted across it. Longer than the log before it: an
    /// error ([`LogError::TimeJump`]).
    AfterThePoses,
}

impl std::fmt::Display for Hole {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "line {}: no samples for {:.2} s after t = {:.3} s ({:.0} sample periods; every later time is shifted by it): ",
            self.line,
            self.gap_s,
            self.t_s,
            self.gap_s / self.period_s
        )?;
        match self.across {
            Across::HandHeldMove { before, after } => write!(
                f,
                "the move between the hand-held poses at t = {:.1}-{:.1} s and {:.1}-{:.1} s spans it and is left out (samples \
                 are missing from it); both poses are used",
                before.0, before.1, after.0, after.1
            ),
            Across::HandAndRig => f.write_str("it lies between a hand-held pose and a rig pose: no move spans it, nothing is left out"),
            Across::BeforeThePoses => f.write_str("it comes before the first pose: no pose or move spans it, nothing is left out"),
            Across::AfterThePoses => f.write_str(
                "it comes after the last pose: no pose or move spans it, but the gyro bias handed over (the rests' drift \
                 predicted to the log's end) is predicted across it",
            ),
        }
    }
}

/// A hole in time is longer than this many median sample periods (a logger's jitter, a USB
/// frame of rows delivered late, a few rows lost are shorter)…
pub const HOLE_PERIODS: f64 = 10.0;
/// … and longer than this (s): as long as the shortest still pose the calibration uses, so the
/// board may have moved from one pose to another unseen. (Shorter gaps, above 0.1 s, already end
/// a pose and leave out a hand-held move with them: calib-core's `RotationLimits::max_gap_s`.)
pub const HOLE_MIN_S: f64 = 0.5;

/// Parses a whole log: lines before the header are skipped, comments skipped, log messages
/// skipped and counted, the data end at the end marker or the end of the text; time must
/// increase. A last line cut mid-row is left out and named ([`Log::cut_line`]). Then what only
/// the whole log shows ([`Log::check_full_scale`], [`Log::holes`]): a reading beyond the full
/// scale the log states or any MEMS part's, a hole in time between two rig poses, are errors
/// naming their line.
pub fn parse(text: &str) -> Result<Log, LogError> {
    let text = text.strip_prefix('\u{FEFF}').unwrap_or(text);
    let last = text.lines().count() as u32;
    let unterminated = !text.is_empty() && !text.ends_with('\n');
    let mut lines = text.lines().enumerate().map(|(i, l)| (i as u32 + 1, l));
    let cols = loop {
        match lines.next() {
            Some((_, l)) if log::is_header(l) => break log::parse_header(l.trim())?,
            Some(_) => {}
            None => return Err(LogError::NoHeader),
        }
    };
    let (mut rows, mut row_lines, mut messages, mut setup, mut cut_line) = (Vec::<Row>::new(), vec![], 0, None, None);
    for (n, l) in lines {
        let line = match log::parse_line(l, &cols, n) {
            Err(_) if unterminated && n == last && !rows.is_empty() => {
                cut_line = Some(n);
                break;
            }
            line => line?,
        };
        match line {
            Line::Skip => {}
            Line::Setup(s) => match setup {
                Some(old) if old != s => return Err(LogError::SetupChanged { line: n }),
                _ => setup = Some(s),
            },
            Line::Message => messages += 1,
            Line::End => break,
            Line::Row(r) => {
                if rows.last().is_some_and(|p| r.t.s() <= p.t.s()) {
                    return Err(LogError::NonMonotonicTime { line: n });
                }
                rows.push(r);
                row_lines.push(n);
            }
        }
    }
    if rows.is_empty() {
        return Err(LogError::Empty);
    }
    let mut log = Log { rows, lines: row_lines, messages, setup, cut_line, holes: vec![] };
    log.check_full_scale(setup.map(|s| s.gyro_range_dps), Bound::Setup)?;
    log.holes = holes(&log)?;
    Ok(log)
}

impl Log {
    /// Every reading within what its sensor can output: the gyro within [`STATED_MARGIN`] times
    /// `gyro_range_dps` (and the accelerometer within its margin of the setup line's range) when
    /// stated (`bound`: by the setup line or `--range`), and within any MEMS part's
    /// ([`PLAUSIBLE`]) always. A gyro or accelerometer whose median reading is beyond any part's
    /// is in other units (raw counts, mg), which the calibration names: not checked here.
    pub fn check_full_scale(&self, gyro_range_dps: Option<f32>, bound: Bound) -> Result<(), LogError> {
        if self.rows.is_empty() {
            return Ok(());
        }
        let max_abs = |v: &[f32; 3]| v.iter().fold(0.0f32, |m, x| m.max(x.abs()));
        let median = |f: &dyn Fn(&Row) -> f32| {
            let mut v: Vec<f32> = self.rows.iter().map(f).collect();
            v.sort_by(f32::total_cmp);
            v[v.len() / 2]
        };
        let accel_range = if bound == Bound::Setup { self.setup.map(|s| s.accel_range_g) } else { None };
        let limits = |plausible: f32, stated: Option<f32>, margin: f32| match stated {
            Some(r) if r * margin < plausible => (r * margin, bound),
            _ => (plausible, Bound::AnyPart),
        };
        let gyro = limits(PLAUSIBLE.gyro_dps, gyro_range_dps, STATED_MARGIN.0);
        let accel = limits(PLAUSIBLE.accel_g, accel_range, STATED_MARGIN.1);
        let check_gyro = gyro.1 != Bound::AnyPart || median(&|r| max_abs(&r.gyro_dps)) <= PLAUSIBLE.gyro_dps;
        let check_accel = accel.1 != Bound::AnyPart || median(&|r| max_abs(&r.accel_g)) <= PLAUSIBLE.accel_g;
        let beyond = |line: u32, column: &'static str, value: f32, (limit, bound): (f32, Bound)| {
            (value.abs() > limit).then_some(LogError::BeyondFullScale { line, column, value, limit, bound })
        };
        for (r, &line) in self.rows.iter().zip(&self.lines) {
            let gyro_cols = log::COLUMNS[4..7].iter().zip(r.gyro_dps).filter(|_| check_gyro).map(|(c, v)| (*c, v, gyro));
            let accel_cols = log::COLUMNS[1..4].iter().zip(r.accel_g).filter(|_| check_accel).map(|(c, v)| (*c, v, accel));
            let mag_cols =
                log::MAG_COLUMNS.iter().zip(r.mag_ut.unwrap_or_default()).map(|(c, v)| (*c, v, (PLAUSIBLE.mag_ut, Bound::AnyPart)));
            if let Some(e) = accel_cols.chain(gyro_cols).chain(mag_cols).find_map(|(c, v, l)| beyond(line, c, v, l)) {
                return Err(e);
            }
            let (lo, hi) = PLAUSIBLE.temp_c;
            if let Some(t) = r.temp_c.filter(|t| !(lo..=hi).contains(t)) {
                return Err(LogError::BeyondFullScale {
                    line,
                    column: log::TEMP_COLUMN,
                    value: t,
                    limit: if t < lo { lo } else { hi },
                    bound: Bound::AnyPart,
                });
            }
        }
        Ok(())
    }
}

/// The holes in time of a log and what spans each; a hole between two rig poses is an error
/// (the one-axis and pan/tilt estimators integrate the gyro from pose to pose: across the hole
/// that turn is unknown), and so is one after the last pose longer than the log before it (a
/// bad time: the bias handed over would be extrapolated across it).
fn holes(log: &Log) -> Result<Vec<Hole>, LogError> {
    let rows = &log.rows;
    let Some((period_s, _)) = crate::offline::sample_intervals(rows) else { return Ok(vec![]) };
    let at: Vec<usize> =
        (1..rows.len()).filter(|&i| rows[i].t.s() - rows[i - 1].t.s() > (HOLE_PERIODS * period_s).max(HOLE_MIN_S)).collect();
    if at.is_empty() {
        return Ok(vec![]);
    }
    let segments = crate::offline::phases(rows).segments;
    at.into_iter()
        .map(|i| {
            let (line, gap_s, t_s) = (log.lines[i], rows[i].t.s() - rows[i - 1].t.s(), rows[i - 1].t.s());
            let before = segments.iter().rfind(|s| s.last < i);
            let after = segments.iter().find(|s| s.first >= i);
            let span = |s: &crate::offline::Segment| (rows[s.first].t.s(), rows[s.last].t.s());
            let across = match (before, after) {
                (None, _) => Across::BeforeThePoses,
                (_, None) if gap_s > t_s - rows[0].t.s() => return Err(LogError::TimeJump { line, gap_s: gap_s as f32, t: rows[i - 1].t }),
                (_, None) => Across::AfterThePoses,
                (Some(b), Some(a)) if b.is_rig_pose() && a.is_rig_pose() => {
                    return Err(LogError::HoleInRig { line, gap_s: gap_s as f32, t: rows[i - 1].t });
                }
                (Some(b), Some(a)) if !b.is_rig_pose() && !a.is_rig_pose() => Across::HandHeldMove { before: span(b), after: span(a) },
                _ => Across::HandAndRig,
            };
            Ok(Hole { line, gap_s, t_s, period_s, across })
        })
        .collect()
}

/// A log file's text: UTF-8, or lines before the header (a logger's preamble, ignored) that are
/// not, read with their bytes replaced. A byte that is not UTF-8 at or after the header is an
/// error naming its line and offset ([`LogError::NotText`]).
pub fn decode(bytes: &[u8]) -> Result<Cow<'_, str>, LogError> {
    if let Ok(text) = std::str::from_utf8(bytes) {
        return Ok(Cow::Borrowed(text));
    }
    let text = String::from_utf8_lossy(bytes);
    // A replaced byte never swallows a newline: the lines are the bytes' lines.
    let header = text.lines().position(log::is_header).map_or(u32::MAX, |i| i as u32 + 1);
    let mut at = 0usize;
    for chunk in bytes.utf8_chunks() {
        at += chunk.valid().len();
        if !chunk.invalid().is_empty() {
            let line = bytes[..at].iter().filter(|b| **b == b'\n').count() as u32 + 1;
            if line >= header {
                return Err(LogError::NotText { line, byte: at as u64 });
            }
        }
        at += chunk.invalid().len();
    }
    Ok(text)
}

/// The header line, with its newline.
pub fn header() -> String {
    format!("{HEADER}\n")
}

/// Appends one row and its newline.
pub fn format_row(out: &mut String, r: &Row) {
    let _ = log::write_row(out, r);
    out.push('\n');
}

/// Every column a log may have: [`log::COLUMNS`] then [`log::MAG_COLUMNS`].
fn all_columns() -> impl Iterator<Item = &'static str> {
    log::COLUMNS.iter().chain(log::MAG_COLUMNS.iter()).copied()
}

/// One column of `--columns`: this log column from that source column, times a factor.
#[derive(Debug, Clone, PartialEq)]
struct Source {
    name: String,
    factor: f64,
}

/// Converts a CSV log with other column names or units into this format. `spec` is a comma
/// list of `COLUMN=SOURCE`, `COLUMN=SOURCE*F` or `COLUMN=SOURCE/F` (e.g.
/// `t_s=time/1000,ax_g=acc_x/9.80665,gx_dps=gyr_x*57.29578`); a column not named is taken from a
/// source column of its own name, if any (servo columns may be absent: hand-held). The source's
/// header is its first line that is neither empty nor a `#` comment. The result has the source's
/// lines (comments and blank lines blank), so that its errors name the source's lines.
pub fn remap(text: &str, spec: &str) -> Result<String, String> {
    let mut map: Vec<(usize, Source)> = vec![];
    for item in spec.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let (col, src) = item.split_once('=').ok_or(format!("--columns: {item:?} is not COLUMN=SOURCE"))?;
        let at = all_columns()
            .position(|c| c == col.trim())
            .ok_or(format!("--columns: unknown column {col:?} (one of {HEADER},{})", log::MAG_COLUMNS.join(",")))?;
        let (name, factor) = match src.find(['*', '/']) {
            Some(i) => {
                let f: f64 = src[i + 1..].trim().parse().map_err(|_| format!("--columns: {:?} is not a number", &src[i + 1..]))?;
                if !(f.is_finite() && f != 0.0) {
                    return Err(format!("--columns: factor {f} must be finite and non-zero"));
                }
                (src[..i].trim(), if &src[i..i + 1] == "*" { f } else { 1.0 / f })
            }
            None => (src.trim(), 1.0),
        };
        map.push((at, Source { name: name.to_string(), factor }));
    }
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty() && !l.trim().starts_with('#'));
    let (at_header, source_header) = lines.next().ok_or("--columns: the log has no header line")?;
    let names: Vec<&str> = source_header.split(',').map(str::trim).collect();
    let mut from: [Option<(usize, f64)>; 12] = [None; 12];
    for (i, col) in all_columns().enumerate() {
        let src = map.iter().find(|(at, _)| *at == i).map(|(_, s)| s.clone()).unwrap_or(Source { name: col.to_string(), factor: 1.0 });
        from[i] = match names.iter().position(|n| *n == src.name) {
            Some(k) => Some((k, src.factor)),
            None if i >= 7 => None,
            None => return Err(format!("--columns: no source column {:?} for {col} in the header {source_header:?}", src.name)),
        };
    }
    let mag = match from[9..].iter().filter(|s| s.is_some()).count() {
        0 => false,
        3 => true,
        _ => return Err(format!("--columns: the magnetometer needs all three of {} or none", log::MAG_COLUMNS.join(","))),
    };
    // Line for line: an error in the converted log names the source's line (skipped lines empty).
    let mut out = "\n".repeat(at_header);
    out += &if mag { format!("{HEADER},{}\n", log::MAG_COLUMNS.join(",")) } else { header() };
    let mut next = at_header + 1;
    for (n, l) in lines {
        out.extend(std::iter::repeat_n('\n', n - next));
        next = n + 1;
        let f: Vec<&str> = l.split(',').map(str::trim).collect();
        let mut v = [None; 12];
        for (i, src) in from.iter().enumerate() {
            if let Some((k, factor)) = *src {
                let text = f.get(k).copied().unwrap_or("");
                if !text.is_empty() {
                    let x: f64 = text.parse().map_err(|_| format!("line {}: column {:?}: {text:?} is not a number", n + 1, names[k]))?;
                    v[i] = Some(x * factor);
                }
            }
        }
        let need = |i: usize| v[i].ok_or(format!("line {}: no value for {}", n + 1, log::COLUMNS[i]));
        let row = Row {
            t: Time::from_s(need(0)?).ok_or(format!("line {}: the time is beyond +-1e12 s", n + 1))?,
            accel_g: [need(1)? as f32, need(2)? as f32, need(3)? as f32],
            gyro_dps: [need(4)? as f32, need(5)? as f32, need(6)? as f32],
            servo_deg: v[7].map(|x| x as f32),
            tilt_deg: v[8].map(|x| x as f32),
            mag_ut: match (v[9], v[10], v[11]) {
                (Some(x), Some(y), Some(z)) => Some([x as f32, y as f32, z as f32]),
                _ => None,
            },
            temp_c: None,
        };
        let _ = log::write_row(&mut out, &row);
        if mag {
            let _ = log::write_mag(&mut out, row.mag_ut);
        }
        out.push('\n');
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use calib_core::formats::record::Sensor;

    #[test]
    fn parses_by_column_name_with_comments_preamble_and_empty_servo() {
        let log = "INFO boot line of a logger\n# made by hand\nservo_deg,t_s,ax_g,ay_g,az_g,gx_dps,gy_dps,gz_dps,extra\n\
                   10.5,0.0,0,0,1,0.1,0.2,0.3,x\n,0.01,0,0,1,0.1,0.2,0.3,y\n";
        // The header must name t_s first to be recognised; this one does not.
        assert_eq!(parse(log), Err(LogError::NoHeader));
        let log = log.replace("servo_deg,t_s,", "t_s,servo_deg,").replace("10.5,0.0,", "0.0,10.5,").replace(",0.01,", "0.01,,");
        let rows = parse(&log).unwrap().rows;
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0].servo_deg, Some(10.5));
        assert_eq!(rows[1].servo_deg, None);
        assert_eq!(rows[1].tilt_deg, None);
        assert_eq!(rows[1].gyro_dps, [0.1, 0.2, 0.3]);
    }

    #[test]
    fn bad_logs_are_named() {
        let h = header();
        assert_eq!(parse(""), Err(LogError::NoHeader));
        assert_eq!(parse("t_s,ax_g\n1,2\n"), Err(LogError::MissingColumn("ay_g")));
        assert_eq!(parse(&h), Err(LogError::Empty));
        assert!(matches!(parse(&format!("{h}0,1,2\n")), Err(LogError::ShortRow { line: 2, .. })));
        assert_eq!(parse(&format!("{h}0,a,0,1,0,0,0,,\n")), Err(LogError::BadNumber { line: 2, column: "ax_g" }));
        assert_eq!(parse(&format!("{h}0,NaN,0,1,0,0,0,,\n")), Err(LogError::BadNumber { line: 2, column: "ax_g" }));
        // Finite as an f64, infinite as the f32 a row holds (found by the log reader's fuzz target).
        assert_eq!(parse(&format!("{h}0,-1e300,0,1,0,0,0,,\n")), Err(LogError::BadNumber { line: 2, column: "ax_g" }));
        assert_eq!(parse(&format!("{h}0,0,0,1,0,0,4e38,,\n")), Err(LogError::BadNumber { line: 2, column: "gz_dps" }));
        assert_eq!(parse(&format!("{h}1,0,0,1,0,0,0,,\n1,0,0,1,0,0,0,,\n")), Err(LogError::NonMonotonicTime { line: 3 }));
    }

    #[test]
    fn lines_that_are_neither_rows_nor_messages_are_named() {
        let h = header();
        let row = |t: f64| format!("{t},0,0,1,0,0,0,,\n");
        let log = |mid: &str| format!("{h}{}{mid}\n{}", row(0.0), row(0.01));
        // The firmware's messages and a logger's lines are skipped and counted.
        for m in ["phase: bias", "{\"gyro\":{\"K\":[[1,0,0],[0,1,0],[0,0,1]]}}", "[INFO] x", "/* C */", "\u{2514}\u{2500} src/main.rs:1"] {
            assert_eq!(parse(&log(m)).map(|l| l.messages), Ok(1), "{m}");
        }
        let not_a_line = |mid: &str| match parse(&log(mid)) {
            Err(LogError::NotALine { line: 3, excerpt }) => excerpt.to_string(),
            other => panic!("{mid:?}: {other:?}"),
        };
        // Control bytes, replaced invalid UTF-8, printable garbage that no message starts with.
        assert_eq!(not_a_line("\u{1}\u{2}abc\u{7f}"), "\"\\u{1}\\u{2}abc\\u{7f}\"");
        assert_eq!(not_a_line("ok\u{FFFD}\u{FFFD}"), "\"ok\\u{fffd}\\u{fffd}\"");
        assert_eq!(not_a_line("@@%garbage"), "\"@@%garbage\"");
        assert!(not_a_line(&"\u{0}".repeat(100)).ends_with("...\""));
        // A row whatever its first field: `nan` (what the firmware writes for a non-finite number).
        assert_eq!(parse(&log("nan,0,0,1,0,0,0,,")), Err(LogError::BadNumber { line: 3, column: "t_s" }));
        assert_eq!(parse(&log(",0,0,1,0,0,0,,")), Err(LogError::BadNumber { line: 3, column: "t_s" }));
        // More fields than the header: a field split in two.
        assert_eq!(parse(&log("0.005,0,0,1,0,0,0,,,")), Err(LogError::LongRow { line: 3, have: 10, need: 9 }));
        // A second header.
        assert_eq!(parse(&log(HEADER)), Err(LogError::HeaderAgain { line: 3 }));
        // A byte that is not UTF-8: in the preamble read with it replaced, after the header named.
        let bytes = [b"pre\xff\n".as_slice(), log("phase: bias").as_bytes()].concat();
        assert_eq!(decode(&bytes).map(|t| parse(&t).unwrap().rows.len()), Ok(2));
        let bytes = [log("phase: bias").as_bytes(), b"\xfe\n".as_slice()].concat();
        assert_eq!(decode(&bytes), Err(LogError::NotText { line: 5, byte: bytes.len() as u64 - 2 }));
        // A byte-order mark before the header.
        assert_eq!(parse(&format!("\u{FEFF}{}", log(""))).map(|l| l.rows.len()), Ok(2));
    }

    #[test]
    fn readings_beyond_the_full_scale_are_named() {
        let setup = "# sensor setup: odr_hz=119.0 gyro_range_dps=245.0 accel_range_g=2.0\n";
        // The readings `a`, `g` on the first row (line 2), ordinary ones on the others.
        let log = |a: f32, g: f32| {
            let rows: String = (1..9).map(|i| format!("{},0,0,1,0,1.5,0,,\n", i as f32 * 0.01)).collect();
            format!("{}0,{a},0,1,0,{g},0,,\n{rows}", header())
        };
        let beyond = |text: &str| match parse(text) {
            Err(LogError::BeyondFullScale { line, column, limit, bound, .. }) => (line, column, limit, bound),
            other => panic!("{other:?}"),
        };
        // Any MEMS part's: 5000 °/s, 40 g, on the first row that has it.
        assert_eq!(beyond(&log(0.0, 1e30)), (2, "gy_dps", 5000.0, Bound::AnyPart));
        assert_eq!(beyond(&log(-41.0, 0.0)), (2, "ax_g", 40.0, Bound::AnyPart));
        assert!(parse(&log(39.0, 4900.0)).is_ok());
        // The stated full scale, with the margin an LSM9DS1's counts reach (±245 °/s: 286.7 °/s).
        let at = |a: f32, g: f32| log(a, g).replacen('\n', &format!("\n{setup}"), 1);
        assert!(parse(&at(2.9, 286.7)).is_ok());
        assert_eq!(beyond(&at(0.0, 300.0)), (3, "gy_dps", 294.0, Bound::Setup));
        assert_eq!(beyond(&at(3.1, 0.0)), (3, "ax_g", 3.0, Bound::Setup));
        // `--range`.
        let l = parse(&log(0.0, 100.0)).unwrap();
        assert!(l.check_full_scale(Some(100.0), Bound::RangeOption).is_ok());
        assert!(matches!(
            l.check_full_scale(Some(60.0), Bound::RangeOption),
            Err(LogError::BeyondFullScale { line: 2, bound: Bound::RangeOption, .. })
        ));
        // A column in other units (raw counts: its median beyond any part's) is left to the
        // calibration's unit checks; a magnetometer or temperature beyond any part's is named.
        let counts: String = (0..9).map(|i| format!("{},32768,32768,34816,0,0,0,,\n", i as f32 * 0.01)).collect();
        assert!(parse(&format!("{}{counts}", header())).is_ok());
        let e = parse(&format!("{HEADER},mx_ut,my_ut,mz_ut,temp_c\n0,0,0,1,0,0,0,,,20,5,-40,25\n0.01,0,0,1,0,0,0,,,20,5,-40,1e30\n"));
        assert!(matches!(e, Err(LogError::BeyondFullScale { line: 3, column: "temp_c", .. })), "{e:?}");
        let e = parse(&format!("{HEADER},mx_ut,my_ut,mz_ut\n0,0,0,1,0,0,0,,,20,5e4,-40\n"));
        assert!(matches!(e, Err(LogError::BeyondFullScale { line: 2, column: "my_ut", .. })), "{e:?}");
    }

    #[test]
    fn the_setup_comment_round_trips_and_a_change_is_an_error() {
        let line = |s: &SensorSetup| {
            let mut l = String::new();
            log::write_setup(&mut l, s).unwrap();
            l
        };
        let a = line(&SensorSetup::ARDUINO_LSM9DS1);
        assert_eq!(a, "# sensor setup: odr_hz=119.0 gyro_range_dps=2000.0 accel_range_g=4.0 sensor=lsm9ds1");
        let bmi = SensorSetup { odr_hz: 100.0, sensor: Sensor::Bmi270 { gyr_cas: -3, user_gain: true }, ..SensorSetup::DEFAULT };
        assert_eq!(line(&bmi), "# sensor setup: odr_hz=100.0 gyro_range_dps=500.0 accel_range_g=2.0 sensor=bmi270 gyr_cas=-3 user_gain=1");
        for s in [SensorSetup::DEFAULT, SensorSetup::ARDUINO_LSM9DS1, SensorSetup { odr_hz: 952.0, ..SensorSetup::DEFAULT }, bmi] {
            assert_eq!(log::parse_setup(&line(&s)), Some(s));
        }
        // A log from before the Rev2 support: an LSM9DS1's.
        let old = "# sensor setup: odr_hz=119.0 gyro_range_dps=2000.0 accel_range_g=4.0";
        assert_eq!(log::parse_setup(old), Some(SensorSetup::ARDUINO_LSM9DS1));
        for bad in [
            "# sensor setup: odr_hz=119.0 gyro_range_dps=2000.0",
            "# sensor setup: odr_hz=-1.0 gyro_range_dps=2000.0 accel_range_g=4.0",
            "# sensor setup: odr_hz=100.0 gyro_range_dps=500.0 accel_range_g=2.0 sensor=bmi270 gyr_cas=64 user_gain=0",
            "# sensor setup: odr_hz=100.0 gyro_range_dps=500.0 accel_range_g=2.0 sensor=bmi270 gyr_cas=1",
            "# sensor setup: odr_hz=100.0 gyro_range_dps=500.0 accel_range_g=2.0 sensor=bmi160",
        ] {
            assert_eq!(log::parse_setup(bad), None, "{bad}");
        }
        let row = "0.0,0,0,1,0,0,0,,\n";
        let log = format!("{}{a}\n{row}{a}\n", header());
        assert_eq!(parse(&log).unwrap().setup, Some(SensorSetup::ARDUINO_LSM9DS1));
        assert_eq!(parse(&format!("{}{row}", header())).unwrap().setup, None);
        let changed = format!("{log}{}\n", line(&SensorSetup::DEFAULT));
        assert_eq!(parse(&changed), Err(LogError::SetupChanged { line: 5 }));
    }

    #[test]
    fn format_then_parse_round_trips_and_the_end_marker_ends_the_data() {
        let r = Row {
            t: Time::from_s(1.25).unwrap(),
            accel_g: [0.5, -0.25, 0.75],
            gyro_dps: [1.5, -2.0, 3.0],
            servo_deg: Some(30.0),
            tilt_deg: None,
            mag_ut: None,
            temp_c: None,
        };
        let mut s = header();
        format_row(&mut s, &r);
        format_row(&mut s, &Row { t: Time::from_s(1.5).unwrap(), servo_deg: None, tilt_deg: Some(-25.0), ..r });
        s.insert_str(header().len(), "phase: bias, a log message\n");
        s.push_str(calib_core::formats::log::END);
        s.push_str("\nINFO a log line after the raw log\n");
        let log = parse(&s).unwrap();
        assert_eq!(log.messages, 1);
        let rows = log.rows;
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0], r);
        assert_eq!((rows[1].servo_deg, rows[1].tilt_deg), (None, Some(-25.0)));
    }

    #[test]
    fn other_tools_logs_convert_by_name_and_unit() {
        let text = "# from another tool\ntime_ms,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z\n0,0,0,9.80665,0.01,0,0\n10,0,9.80665,0,0,0.02,0\n";
        let spec = "t_s=time_ms/1000,ax_g=acc_x/9.80665,ay_g=acc_y/9.80665,az_g=acc_z/9.80665,gx_dps=gyr_x*57.29578,gy_dps=gyr_y*57.29578,gz_dps=gyr_z*57.29578";
        let rows = parse(&remap(text, spec).unwrap()).unwrap().rows;
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[1].t.s(), 0.01);
        assert_eq!(rows[0].accel_g, [0.0, 0.0, 1.0]);
        assert!((rows[0].gyro_dps[0] - 0.5729578).abs() < 1e-5 && rows[1].servo_deg.is_none());
        assert!(remap(text, "t_s=nope").unwrap_err().contains("no source column \"nope\""));
        assert!(remap(text, "x=time_ms").unwrap_err().contains("unknown column"));
        assert!(remap(text, "t_s=time_ms/0").is_err());
    }

    #[test]
    fn magnetometer_columns_are_optional_and_empty_without_a_reading() {
        let mut s = format!("{HEADER},mx_ut,my_ut,mz_ut\n");
        let r = Row {
            t: Time::from_s(1.0).unwrap(),
            accel_g: [0.0, 0.0, 1.0],
            gyro_dps: [0.0; 3],
            servo_deg: None,
            tilt_deg: None,
            mag_ut: Some([21.5, -3.25, -40.125]),
            temp_c: None,
        };
        for row in [r, Row { t: Time::from_s(1.01).unwrap(), mag_ut: None, ..r }] {
            let _ = log::write_row(&mut s, &row);
            let _ = log::write_mag(&mut s, row.mag_ut);
            s.push('\n');
        }
        let back = parse(&s).unwrap().rows;
        assert_eq!((back[0].mag_ut, back[1].mag_ut), (Some([21.5, -3.25, -40.125]), None));
        // Two of the three columns: named, not guessed.
        let e = parse(&format!("{HEADER},mx_ut,my_ut\n1,0,0,1,0,0,0,,,1,2\n")).unwrap_err();
        assert_eq!(e, LogError::MissingColumn("mz_ut"));
        // A field that is not a number.
        let e = parse(&format!("{HEADER},mx_ut,my_ut,mz_ut\n1,0,0,1,0,0,0,,,1,x,2\n")).unwrap_err();
        assert!(matches!(e, LogError::BadNumber { line: 2, column: "my_ut" }), "{e:?}");
        // --columns maps a source's magnetometer (gauss) into µT.
        let text = "time,ax,ay,az,gx,gy,gz,magx,magy,magz\n0.5,0,0,1,0,0,0,0.2,-0.1,0.4\n";
        let spec = "t_s=time,ax_g=ax,ay_g=ay,az_g=az,gx_dps=gx,gy_dps=gy,gz_dps=gz,mx_ut=magx*100,my_ut=magy*100,mz_ut=magz*100";
        let rows = parse(&remap(text, spec).unwrap()).unwrap().rows;
        assert_eq!(rows[0].mag_ut, Some([20.0, -10.0, 40.0]));
        let partial = spec.split(",mx_ut").next().unwrap().to_string() + ",mx_ut=magx";
        assert!(remap(text, &partial).unwrap_err().contains("all three"));
    }

    #[test]
    fn fixed_decimals_are_exact_for_sensor_counts() {
        // Every LSB value of the ±2 g / ±500 °/s ranges survives the text round trip.
        for counts in [-32768i32, -12345, -1, 0, 1, 777, 32767] {
            let r = Row {
                t: Time::from_s(12345.678901).unwrap(),
                accel_g: [counts as f32 * 0.000061; 3],
                gyro_dps: [counts as f32 * 0.0175; 3],
                servo_deg: Some(-12.34),
                tilt_deg: Some(90.0),
                mag_ut: None,
                temp_c: None,
            };
            let mut s = header();
            format_row(&mut s, &r);
            let back = parse(&s).unwrap().rows[0];
            assert!((back.t.s() - r.t.s()).abs() < 1e-6);
            for i in 0..3 {
                assert!((back.accel_g[i] - r.accel_g[i]).abs() <= 5e-7, "{counts}: {} vs {}", back.accel_g[i], r.accel_g[i]);
                assert!((back.gyro_dps[i] - r.gyro_dps[i]).abs() <= 5e-6);
            }
            assert_eq!(back.servo_deg, Some(-12.34));
        }
    }
}
