//! The recorded log, defined once for the firmware's raw-log mode and the offline tool: one CSV
//! row per IMU sample under the header
//! `t_s,ax_g,ay_g,az_g,gx_dps,gy_dps,gz_dps,servo_deg,tilt_deg`.
//!
//! - `t_s`: MCU timestamp (s); `a*_g`: raw accelerometer (g); `g*_dps`: raw gyro (°/s);
//!   `servo_deg`, `tilt_deg`: the commanded rotation and tilt servo angles (°), empty while that
//!   servo is not commanded. Rows with both empty are hand-held.
//! - Optional `mx_ut,my_ut,mz_ut` ([`MAG_COLUMNS`], all three or none): the raw magnetometer
//!   (µT, in the board frame), empty on rows without a new reading.
//! - Optional `temp_c` ([`TEMP_COLUMN`]): the sensor's temperature the procedure saw with the
//!   sample (°C, to 0.01 °C), empty without one. The bias's warm-up follows it, so that a replay
//!   needs it to give the firmware's result.
//! - Lines starting with `#` are comments. Lines before the header are ignored (a logger's
//!   preamble); [`END`] ends the data (what follows is ignored). After the header, a line of
//!   printable text that starts with a letter or punctuation and is not row-like is a log message
//!   (the firmware's other log lines in raw-log mode, [`is_message`]), skipped and counted; any
//!   other line must be a valid row with the header's number of fields, and anything else
//!   (control bytes, replaced invalid UTF-8, a second header) is named with its line. Columns are
//!   found by name, `tilt_deg` may be absent, extra columns (in the header) are ignored.
//!
//! Numbers are written with fixed decimals (µs, µg, 10 µ°/s, 0.01°) by integer arithmetic, so
//! the firmware needs no float-formatting code.

use crate::formats::record::{Sensor, SensorSetup};
use crate::formats::text::Int;
use crate::Time;
use core::fmt::{self, Write};

/// The header line.
pub const HEADER: &str = "t_s,ax_g,ay_g,az_g,gx_dps,gy_dps,gz_dps,servo_deg,tilt_deg";
/// The header with the magnetometer's columns ([`MAG_COLUMNS`]): the raw log of firmware before
/// the temperature column.
pub const HEADER_MAG: &str = "t_s,ax_g,ay_g,az_g,gx_dps,gy_dps,gz_dps,servo_deg,tilt_deg,mx_ut,my_ut,mz_ut";
/// The header with the magnetometer's and the temperature's columns: the firmware's raw log.
pub const HEADER_RAW: &str = "t_s,ax_g,ay_g,az_g,gx_dps,gy_dps,gz_dps,servo_deg,tilt_deg,mx_ut,my_ut,mz_ut,temp_c";
/// The comment line that ends a raw log (raw-log mode switched off).
pub const END: &str = "# end of raw log";
/// The comment that states the sensor setup the rows after it were sampled at ([`write_setup`]).
pub const SETUP: &str = "# sensor setup:";
/// Column names, in the order written.
pub const COLUMNS: [&str; 9] = ["t_s", "ax_g", "ay_g", "az_g", "gx_dps", "gy_dps", "gz_dps", "servo_deg", "tilt_deg"];
/// The optional magnetometer columns, written after [`COLUMNS`] by [`write_mag`].
pub const MAG_COLUMNS: [&str; 3] = ["mx_ut", "my_ut", "mz_ut"];
/// The optional temperature column, written after [`MAG_COLUMNS`] by [`write_temp`].
pub const TEMP_COLUMN: &str = "temp_c";
/// Longest row [`write_row`], [`write_mag`] and [`write_temp`] write (bytes, without the newline).
pub const MAX_ROW: usize = 160;

/// One IMU sample of a log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Row {
    /// MCU timestamp.
    pub t: Time,
    /// Raw accelerometer (g).
    pub accel_g: [f32; 3],
    /// Raw gyro (°/s).
    pub gyro_dps: [f32; 3],
    /// Commanded rotation-servo angle (°); `None` while no servo is commanded.
    pub servo_deg: Option<f32>,
    /// Commanded tilt-servo angle (°); `None` without a tilt servo (or no column).
    pub tilt_deg: Option<f32>,
    /// Raw magnetometer (µT, accelerometer axes); `None` without a new reading (or no columns).
    pub mag_ut: Option<[f32; 3]>,
    /// Sensor temperature (°C); `None` without a reading (or no column).
    pub temp_c: Option<f32>,
}

/// Decimals written per column group: accelerometer, gyro, servo angles (the time: its µs, 6).
const DECIMALS: (u32, u32, u32) = (6, 5, 2);
/// Decimals of the magnetometer (1 nT).
const MAG_DECIMALS: u32 = 3;
/// Decimals of the temperature (0.01 °C).
const TEMP_DECIMALS: u32 = 2;

/// Writes `v` with `decimals` (≤ 9) fixed decimals, rounded half away from zero from its exact
/// value; NaN, an infinity or |v| ≥ 2⁶³ / 10^decimals is written as `nan`, which the parser
/// rejects. In integers: no `core::fmt` number code, no software `f64`.
#[inline(never)] // one copy for the log, the text lines and the exports (flash)
pub(crate) fn fixed(w: &mut dyn Write, v: f32, decimals: u32) -> fmt::Result {
    let decimals = decimals.min(9);
    match scaled(v, decimals) {
        Some(m) => decimal(w, v.is_sign_negative() && m > 0, m, decimals),
        None => w.write_str("nan"),
    }
}

/// Whether [`fixed`] writes `v` with `decimals` as a number (not as `nan`).
pub(crate) fn writable(v: f32, decimals: u32) -> bool {
    scaled(v, decimals.min(9)).is_some()
}

/// `|v| · 10^decimals` (`decimals` ≤ 9) rounded half away from zero, computed exactly from the
/// `f32`'s mantissa and exponent; `None` for a NaN, an infinity or a result ≥ 2⁶³.
fn scaled(v: f32, decimals: u32) -> Option<u64> {
    if !v.is_finite() {
        return None;
    }
    let bits = v.to_bits();
    let (exp, frac) = ((bits >> 23) & 0xFF, u64::from(bits & 0x7F_FFFF));
    // |v| = mantissa · 2^shift.
    let (mantissa, shift) = if exp == 0 { (frac, -149) } else { (frac | 0x80_0000, exp as i32 - 150) };
    // < 2²⁴ · 10⁹ < 2⁵⁴.
    let x = mantissa * 10u64.pow(decimals);
    if shift >= 0 {
        (x.leading_zeros() as i32 > shift).then(|| x << shift)
    } else if shift > -55 {
        let s = -shift;
        Some((x + (1 << (s - 1))) >> s)
    } else {
        Some(0)
    }
}

/// Writes `m · 10^−decimals` (a sign first when `negative`): digits from the least significant,
/// 32-bit divisions while they fit, the point after `decimals` of them, at least one before it.
pub(crate) fn decimal(w: &mut dyn Write, negative: bool, mut m: u64, decimals: u32) -> fmt::Result {
    let mut buf = [0u8; 24];
    let (mut n, mut k) = (buf.len(), 0);
    loop {
        if k == decimals && decimals > 0 {
            n -= 1;
            buf[n] = b'.';
        }
        let digit;
        (m, digit) = match u32::try_from(m) {
            Ok(m) => ((m / 10) as u64, m % 10),
            Err(_) => div10(m),
        };
        n -= 1;
        buf[n] = b'0' + digit as u8;
        k += 1;
        if k > decimals && m == 0 {
            break;
        }
    }
    if negative {
        n -= 1;
        buf[n] = b'-';
    }
    buf[n..].iter().try_for_each(|&b| w.write_char(b as char))
}

/// `m / 10` and `m % 10` by long division in 16-bit steps: 32-bit arithmetic, no 64-bit
/// division linked into the firmware.
fn div10(m: u64) -> (u64, u32) {
    let (mut q, mut r) = (0u64, 0u32);
    for shift in [48, 32, 16, 0] {
        let cur = (r << 16) | ((m >> shift) as u32 & 0xFFFF);
        q |= ((cur / 10) as u64) << shift;
        r = cur % 10;
    }
    (q, r)
}

/// `v` rounded to `decimals` as [`fixed`] writes it (half away from zero), as the nearest `f32`:
/// the rounded integer (below 2²⁴, exact in `f32`) over 10^decimals (exact), one correctly
/// rounded division. Beyond 2²⁴ on the grid an `f32`'s own spacing is coarser than the grid, and
/// `v` as written parses back to itself.
fn on_grid(v: f32, decimals: u32) -> f32 {
    match scaled(v, decimals) {
        Some(m) if m < 1 << 24 => {
            let r = m as f32 / 10u32.pow(decimals) as f32;
            if v.is_sign_negative() {
                -r
            } else {
                r
            }
        }
        _ => v,
    }
}

/// A sample's readings as a row holds them (accelerometer to 1 µg, gyro to 10 µ°/s; the text
/// parses back to these very `f32`s). The firmware hands its procedure these, so that a replay
/// of its log sees exactly what it saw, whatever the sensor's sensitivity (a BMI270's counts are
/// not on the log's grid).
pub fn as_logged(accel_g: [f32; 3], gyro_dps: [f32; 3]) -> ([f32; 3], [f32; 3]) {
    let (da, dg, _) = DECIMALS;
    (accel_g.map(|v| on_grid(v, da)), gyro_dps.map(|v| on_grid(v, dg)))
}

/// A magnetometer reading as a row holds it (to 1 nT; parses back to these `f32`s).
pub fn mag_as_logged(m_ut: [f32; 3]) -> [f32; 3] {
    m_ut.map(|v| on_grid(v, MAG_DECIMALS))
}

/// A temperature as a row holds it (to 0.01 °C; parses back to this `f32`; a non-finite one is
/// none).
pub fn temp_as_logged(temp_c: Option<f32>) -> Option<f32> {
    temp_c.filter(|t| t.is_finite()).map(|t| on_grid(t, TEMP_DECIMALS))
}

/// Writes one row (no newline).
pub fn write_row(w: &mut impl Write, r: &Row) -> fmt::Result {
    let (da, dg, ds) = DECIMALS;
    decimal(w, r.t < Time::ZERO, r.t.us().unsigned_abs(), 6)?;
    for a in r.accel_g {
        w.write_char(',')?;
        fixed(w, a, da)?;
    }
    for g in r.gyro_dps {
        w.write_char(',')?;
        fixed(w, g, dg)?;
    }
    for s in [r.servo_deg, r.tilt_deg] {
        w.write_char(',')?;
        if let Some(s) = s {
            fixed(w, s, ds)?;
        }
    }
    Ok(())
}

/// Writes the three magnetometer fields of a row after [`write_row`] (empty without a reading),
/// for a log whose header ends with [`MAG_COLUMNS`].
pub fn write_mag(w: &mut impl Write, mag_ut: Option<[f32; 3]>) -> fmt::Result {
    for k in 0..3 {
        w.write_char(',')?;
        if let Some(m) = mag_ut {
            fixed(w, m[k], MAG_DECIMALS)?;
        }
    }
    Ok(())
}

/// Writes the temperature field of a row after [`write_mag`] (empty without one), for a log whose
/// header ends with [`TEMP_COLUMN`].
pub fn write_temp(w: &mut impl Write, temp_c: Option<f32>) -> fmt::Result {
    w.write_char(',')?;
    match temp_c {
        Some(t) => fixed(w, t, TEMP_DECIMALS),
        None => Ok(()),
    }
}

/// Writes the setup comment (no newline): `# sensor setup: odr_hz=119.0 gyro_range_dps=2000.0
/// accel_range_g=4.0 sensor=lsm9ds1`, or for a BMI270 `… sensor=bmi270 gyr_cas=-3 user_gain=0`.
/// The firmware writes it after the header and again when the setup changes.
pub fn write_setup(w: &mut impl Write, s: &SensorSetup) -> fmt::Result {
    w.write_str(SETUP)?;
    for (name, v) in [(" odr_hz=", s.odr_hz), (" gyro_range_dps=", s.gyro_range_dps), (" accel_range_g=", s.accel_range_g)] {
        w.write_str(name)?;
        fixed(w, v, 1)?;
    }
    match s.sensor {
        Sensor::Lsm9ds1 => w.write_str(" sensor=lsm9ds1"),
        Sensor::Bmi270 { gyr_cas, user_gain } => {
            write!(w, " sensor=bmi270 gyr_cas={} user_gain={}", Int(gyr_cas.into()), Int(user_gain.into()))
        }
    }
}

/// Reads a setup comment ([`write_setup`]; without `sensor=` an LSM9DS1's, as logs before the
/// Rev2 support); `None` for any other line, a value that is not a positive number, or a part
/// field out of its range.
pub fn parse_setup(line: &str) -> Option<SensorSetup> {
    let mut it = line.trim().strip_prefix(SETUP)?.split_whitespace();
    let mut field = |name: &str| -> Option<f32> {
        let v: f32 = value(&mut it, name)?.parse().ok()?;
        (v.is_finite() && v > 0.0).then_some(v)
    };
    let (odr_hz, gyro_range_dps, accel_range_g) = (field("odr_hz")?, field("gyro_range_dps")?, field("accel_range_g")?);
    let sensor = match it.next() {
        None | Some("sensor=lsm9ds1") => Sensor::Lsm9ds1,
        Some("sensor=bmi270") => {
            let gyr_cas: i8 = value(&mut it, "gyr_cas")?.parse().ok().filter(|c| (-64..64).contains(c))?;
            let user_gain = match value(&mut it, "user_gain")? {
                "0" => false,
                "1" => true,
                _ => return None,
            };
            Sensor::Bmi270 { gyr_cas, user_gain }
        }
        Some(_) => return None,
    };
    it.next().is_none().then_some(SensorSetup { odr_hz, gyro_range_dps, accel_range_g, sensor })
}

/// The value of the next `name=value` word, if it is `name`'s.
fn value<'a>(it: &mut impl Iterator<Item = &'a str>, name: &str) -> Option<&'a str> {
    it.next()?.strip_prefix(name)?.strip_prefix('=')
}

/// Why a log line cannot be read. Lines are 1-based. (The PC's reader: the firmware only writes
/// logs, so none of this is in its flash.)
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LogError {
    /// No header line.
    NoHeader,
    /// A required column is missing from the header.
    MissingColumn(&'static str),
    /// A row has fewer fields than the header.
    ShortRow {
        /// Line number.
        line: u32,
        /// Fields found.
        have: u16,
        /// Fields the header names.
        need: u16,
    },
    /// A field is not a number (or NaN / infinite).
    BadNumber {
        /// Line number.
        line: u32,
        /// Column name.
        column: &'static str,
    },
    /// Time does not increase.
    NonMonotonicTime {
        /// Line number.
        line: u32,
    },
    /// The log has no data rows.
    Empty,
    /// A setup comment says another sensor setup than an earlier one: the rows are not one
    /// calibration's.
    SetupChanged {
        /// Line number.
        line: u32,
    },
    /// A row has more fields than the header: a field split in two (a `,` for a decimal point, a
    /// line garbled) shifts every column after it.
    LongRow {
        /// Line number.
        line: u32,
        /// Fields found.
        have: u16,
        /// Fields the header names.
        need: u16,
    },
    /// A line that is neither a row nor a log message ([`is_message`]): control bytes, replaced
    /// invalid UTF-8, binary garbage.
    NotALine {
        /// Line number.
        line: u32,
        /// The line's start, escaped.
        excerpt: Excerpt,
    },
    /// A second header after the first (two recordings joined: the firmware ends a raw log with
    /// [`END`] before it starts another).
    HeaderAgain {
        /// Line number.
        line: u32,
    },
    /// The file is not UTF-8 text from this line on (binary garbage, or another encoding).
    NotText {
        /// Line number.
        line: u32,
        /// Offset of the first byte that is not UTF-8, from the file's start.
        byte: u64,
    },
    /// A reading beyond what the sensor can output: its stated full scale, or any MEMS part's
    /// ([`Bound`]).
    BeyondFullScale {
        /// Line number.
        line: u32,
        /// Column name.
        column: &'static str,
        /// The reading (in the column's unit).
        value: f32,
        /// The largest |reading| the bound allows.
        limit: f32,
        /// Which bound.
        bound: Bound,
    },
    /// No samples for `gap_s` between two rig poses: the rig's move across the hole would be
    /// integrated over time in which nothing was measured.
    HoleInRig {
        /// Line number of the first row after the hole.
        line: u32,
        /// The time between the rows on either side (s).
        gap_s: f32,
        /// The time of the row before the hole.
        t: Time,
    },
    /// After the last pose, the time jumps by more than the whole log before it: a bad time (the
    /// gyro bias handed over, predicted to the log's end, would be predicted across it).
    TimeJump {
        /// Line number of the first row after the jump.
        line: u32,
        /// The jump (s).
        gap_s: f32,
        /// The time of the row before it.
        t: Time,
    },
}

/// Which full scale a reading is beyond ([`LogError::BeyondFullScale`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Bound {
    /// The log's setup comment ([`SETUP`]): the gyro's at 1.2 times the stated full scale (an
    /// LSM9DS1's counts at its datasheet sensitivity reach 1.17 times it: 32 768 × 8.75 m°/s =
    /// 286.7 °/s at ±245 °/s), the accelerometer's at 1.5 times (its ±16 g range: 32 768 ×
    /// 0.732 mg = 24.0 g).
    Setup,
    /// The gyro's full scale the user states (`gyrocal-calib --range`), at 1.2 times it as for
    /// [`Bound::Setup`].
    RangeOption,
    /// No full scale is stated: beyond any MEMS part's ([`PLAUSIBLE`]).
    AnyPart,
}

/// The largest |reading| of any MEMS part, per column group, with the part that reaches
/// nearest it: readings beyond are bad numbers ([`Bound::AnyPart`]).
///
/// - gyro 5000 °/s: the widest full scale is ±4000 °/s (ST's ISM330DHCX and LSM6DSV, TDK's
///   ICM-42686-P), whose counts reach 32 768 × 140 m°/s = 4588 °/s;
/// - accelerometer 40 g: the widest of an IMU is ±32 g (ST's LSM6DSO32, TDK's ICM-42686-P;
///   32 768 × 0.976 mg = 32.0 g); the LSM9DS1's ±16 g reaches 24 g;
/// - magnetometer 5000 µT: the widest is AKM's AK8963 (MPU-9250) at ±4912 µT (the LSM9DS1's
///   ±16 gauss is 1600 µT, Bosch's BMM150 ±2500 µT on z);
/// - temperature −150…+200 °C: beyond any part's sensor (the LSM9DS1's spans 25 ± 128 °C).
pub const PLAUSIBLE: Plausible = Plausible { gyro_dps: 5000.0, accel_g: 40.0, mag_ut: 5000.0, temp_c: (-150.0, 200.0) };

/// Bounds of [`PLAUSIBLE`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plausible {
    /// Largest |gyro reading| (°/s).
    pub gyro_dps: f32,
    /// Largest |accelerometer reading| (g).
    pub accel_g: f32,
    /// Largest |magnetometer reading| (µT).
    pub mag_ut: f32,
    /// Lowest and highest temperature (°C).
    pub temp_c: (f32, f32),
}

/// Stated full scales are exceeded by the counts of real parts by up to these factors (gyro,
/// accelerometer): see [`Bound::Setup`].
pub const STATED_MARGIN: (f32, f32) = (1.2, 1.5);

/// A line's start, escaped for an error message (printable ASCII as it is, anything else as
/// `\u{…}`; cut with `...` after about 40 bytes). Fixed size, so that [`LogError`] stays `Copy`.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Excerpt {
    text: [u8; Excerpt::MAX],
    len: u8,
}

impl Excerpt {
    const MAX: usize = 48;

    /// The excerpt of `line`.
    pub fn of(line: &str) -> Self {
        let mut e = Excerpt { text: [0; Excerpt::MAX], len: 0 };
        for c in line.chars() {
            let mut piece = [0u8; 12];
            let n = if (' '..='~').contains(&c) && c != '"' && c != '\\' {
                piece[0] = c as u8;
                1
            } else {
                let mut w = Bytes { buf: &mut piece, len: 0 };
                let _ = write!(w, "\\u{{{:x}}}", c as u32);
                w.len
            };
            if e.len as usize + n > Excerpt::MAX - 3 {
                e.push(b"...");
                break;
            }
            e.push(&piece[..n]);
        }
        e
    }

    fn push(&mut self, b: &[u8]) {
        let at = self.len as usize;
        self.text[at..at + b.len()].copy_from_slice(b);
        self.len += b.len() as u8;
    }

    /// The escaped text.
    pub fn as_str(&self) -> &str {
        core::str::from_utf8(&self.text[..self.len as usize]).unwrap_or("")
    }
}

impl fmt::Debug for Excerpt {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "\"{}\"", self.as_str())
    }
}

impl fmt::Display for Excerpt {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "\"{}\"", self.as_str())
    }
}

/// A fixed buffer as a [`Write`] (an escape is at most 10 bytes).
struct Bytes<'a> {
    buf: &'a mut [u8],
    len: usize,
}

impl Write for Bytes<'_> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        let end = self.len + s.len();
        self.buf.get_mut(self.len..end).ok_or(fmt::Error)?.copy_from_slice(s.as_bytes());
        self.len = end;
        Ok(())
    }
}

impl fmt::Display for LogError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            LogError::NoHeader => write!(f, "no header line (expected {HEADER})"),
            LogError::MissingColumn(c) => write!(f, "missing column {c:?} in the header (expected {HEADER})"),
            LogError::ShortRow { line, have, need } => write!(f, "line {line}: {have} fields, the header has {need}"),
            LogError::BadNumber { line, column } => write!(f, "line {line}: column {column} is not a finite number"),
            LogError::NonMonotonicTime { line } => write!(f, "line {line}: time does not increase"),
            LogError::Empty => f.write_str("the log has no data rows"),
            LogError::SetupChanged { line } => {
                write!(f, "line {line}: the sensor setup changes (ODR or full scale): log one setup per file")
            }
            LogError::LongRow { line, have, need } => {
                write!(f, "line {line}: {have} fields, the header has {need} (a field split in two shifts the columns after it)")
            }
            LogError::NotALine { line, excerpt } => write!(
                f,
                "line {line}: not a row nor a log message: {excerpt} (garbage in the log: a log message is printable text \
                 starting with a letter or a bracket)"
            ),
            LogError::HeaderAgain { line } => {
                write!(f, "line {line}: a second header (two recordings joined?): calibrate one recording per file")
            }
            LogError::NotText { line, byte } => {
                write!(f, "line {line}: byte {byte} is not UTF-8 text (binary garbage, or another encoding): a log is ASCII text")
            }
            LogError::BeyondFullScale { line, column, value, limit, bound } => {
                let unit = unit(column);
                if value.abs() >= 1e6 {
                    write!(f, "line {line}: {column} {value:e} {unit} is beyond ")?;
                } else {
                    write!(f, "line {line}: {column} {value} {unit} is beyond ")?;
                }
                match bound {
                    Bound::Setup => write!(f, "the full scale the log's setup line states (readings reach at most {limit} {unit})"),
                    Bound::RangeOption => {
                        write!(f, "the full scale --range states (readings reach at most {limit} {unit}): --range is not this log's?")
                    }
                    Bound::AnyPart => {
                        write!(f, "any MEMS part's full scale ({limit} {unit}): a bad number, or the column is not in {unit} (raw counts?)")
                    }
                }
            }
            LogError::HoleInRig { line, gap_s, t } => write!(
                f,
                "line {line}: no samples for {gap_s:.2} s after t = {} s, between two rig poses: the rig's move across \
                 the hole cannot be measured; record again, or calibrate the log up to line {} and from line {line} apart",
                t.display(3),
                line.saturating_sub(1)
            ),
            LogError::TimeJump { line, gap_s, t } => write!(
                f,
                "line {line}: the time jumps by {gap_s:.2} s after t = {} s, more than the whole log before it, with \
                 no pose after it: a bad time? (the gyro bias handed over would be predicted across it); cut the log at \
                 line {}",
                t.display(3),
                line.saturating_sub(1)
            ),
        }
    }
}

/// The unit of a column, by its name's suffix.
fn unit(column: &str) -> &'static str {
    match column.rsplit('_').next() {
        Some("g") => "g",
        Some("dps") => "°/s",
        Some("ut") => "µT",
        Some("c") => "°C",
        Some("deg") => "°",
        _ => "s",
    }
}

/// Where each column is in a header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Columns {
    /// Field index of the first eight columns of [`COLUMNS`].
    idx: [usize; 8],
    /// Field index of `tilt_deg`, if present.
    tilt: Option<usize>,
    /// Field indices of [`MAG_COLUMNS`], if present.
    mag: Option<[usize; 3]>,
    /// Field index of [`TEMP_COLUMN`], if present.
    temp: Option<usize>,
    /// Fields in the header.
    count: usize,
}

impl Columns {
    /// Whether the header has `tilt_deg`.
    pub fn has_tilt(&self) -> bool {
        self.tilt.is_some()
    }

    /// Whether the header has the magnetometer's columns.
    pub fn has_mag(&self) -> bool {
        self.mag.is_some()
    }
}

/// Whether `line` (trimmed) is the header of this format: it names `t_s` first.
pub fn is_header(line: &str) -> bool {
    line.trim().split(',').next().map(str::trim) == Some("t_s")
}

/// Reads a header line.
pub fn parse_header(line: &str) -> Result<Columns, LogError> {
    let mut idx = [0usize; 8];
    for (slot, name) in idx.iter_mut().zip(COLUMNS) {
        *slot = line.split(',').position(|n| n.trim() == name).ok_or(LogError::MissingColumn(name))?;
    }
    let tilt = line.split(',').position(|n| n.trim() == COLUMNS[8]);
    let find = |name: &str| line.split(',').position(|n| n.trim() == name);
    let mag = match MAG_COLUMNS.map(find) {
        [Some(x), Some(y), Some(z)] => Some([x, y, z]),
        [None, None, None] => None,
        found => return Err(LogError::MissingColumn(MAG_COLUMNS[found.iter().position(Option::is_none).unwrap_or(0)])),
    };
    Ok(Columns { idx, tilt, mag, temp: find(TEMP_COLUMN), count: line.split(',').count() })
}

/// Reads a data row (line number `line` for errors).
pub fn parse_row(text: &str, cols: &Columns, line: u32) -> Result<Row, LogError> {
    let have = text.split(',').count();
    if have < cols.count {
        return Err(LogError::ShortRow { line, have: have as u16, need: cols.count as u16 });
    }
    if have > cols.count {
        return Err(LogError::LongRow { line, have: have.min(u16::MAX as usize) as u16, need: cols.count as u16 });
    }
    let field = |i: usize| text.split(',').nth(i).unwrap_or("").trim();
    let num = |c: usize| -> Result<f64, LogError> {
        let i = if c == 8 { cols.tilt.unwrap_or(usize::MAX) } else { cols.idx[c] };
        // Finite as the `f32` the row holds too (1e300 is a finite `f64`, an infinite `f32`:
        // found by the log reader's fuzz target).
        match field(i).parse::<f64>() {
            Ok(v) if (v as f32).is_finite() => Ok(v),
            _ => Err(LogError::BadNumber { line, column: COLUMNS[c] }),
        }
    };
    let opt = |c: usize| -> Result<Option<f32>, LogError> {
        let i = if c == 8 {
            match cols.tilt {
                Some(i) => i,
                None => return Ok(None),
            }
        } else {
            cols.idx[c]
        };
        if field(i).is_empty() {
            Ok(None)
        } else {
            num(c).map(|v| Some(v as f32))
        }
    };
    let mag_ut = match cols.mag {
        Some(idx) if idx.iter().any(|&i| !field(i).is_empty()) => {
            let mut m = [0.0f32; 3];
            for ((v, &i), column) in m.iter_mut().zip(&idx).zip(MAG_COLUMNS) {
                *v = match field(i).parse::<f64>() {
                    Ok(x) if (x as f32).is_finite() => x as f32,
                    _ => return Err(LogError::BadNumber { line, column }),
                };
            }
            Some(m)
        }
        _ => None,
    };
    let temp_c = match cols.temp.map(field) {
        Some(t) if !t.is_empty() => match t.parse::<f64>() {
            Ok(x) if (x as f32).is_finite() => Some(x as f32),
            _ => return Err(LogError::BadNumber { line, column: TEMP_COLUMN }),
        },
        _ => None,
    };
    Ok(Row {
        t: Time::from_s(num(0)?).ok_or(LogError::BadNumber { line, column: COLUMNS[0] })?,
        accel_g: [num(1)? as f32, num(2)? as f32, num(3)? as f32],
        gyro_dps: [num(4)? as f32, num(5)? as f32, num(6)? as f32],
        servo_deg: opt(7)?,
        tilt_deg: opt(8)?,
        mag_ut,
        temp_c,
    })
}

/// What a line of a log is, once the header has been seen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Line {
    /// Blank or a comment.
    Skip,
    /// The sensor setup of the rows that follow ([`write_setup`]).
    Setup(SensorSetup),
    /// The end of the raw log.
    End,
    /// A log message between rows (not a number first).
    Message,
    /// A sample.
    Row(Row),
}

/// Classifies and reads one line after the header: a row, a comment, the setup, the end, a log
/// message ([`is_message`]); a row-like line must parse ([`parse_row`]); anything else is
/// [`LogError::NotALine`], a second header [`LogError::HeaderAgain`].
pub fn parse_line(text: &str, cols: &Columns, line: u32) -> Result<Line, LogError> {
    let t = text.trim();
    if t == END {
        Ok(Line::End)
    } else if let Some(s) = parse_setup(t) {
        Ok(Line::Setup(s))
    } else if t.is_empty() || t.starts_with('#') {
        Ok(Line::Skip)
    } else if is_header(t) {
        Err(LogError::HeaderAgain { line })
    } else if row_like(t, cols) || (t.starts_with(|c: char| c.is_ascii_digit() || matches!(c, '-' | '+' | '.' | ',')) && !is_message(t)) {
        parse_row(t, cols, line).map(Line::Row)
    } else if is_message(t) {
        Ok(Line::Message)
    } else {
        Err(LogError::NotALine { line, excerpt: Excerpt::of(t) })
    }
}

/// A line that is a row whatever its first field: at least the header's fields, most of them
/// numbers or empty (`nan,0.1,…`, a row whose first bytes were garbled). The firmware's messages
/// with commas (its JSON) are mostly words.
fn row_like(t: &str, cols: &Columns) -> bool {
    let fields = t.split(',').count();
    let numbers = t.split(',').map(str::trim).filter(|f| f.is_empty() || f.parse::<f64>().is_ok()).count();
    fields >= cols.count && 2 * numbers > fields
}

/// A log message of the known forms (trimmed): printable text (no control characters but tabs,
/// no U+FFFD, the mark of replaced invalid UTF-8) that starts with a letter (the firmware's
/// messages, a logger's level: `INFO …`), a bracket, `/`, `*` or `"` (the firmware's JSON `{…`,
/// its C and Rust export lines `{…`, `[…`, `/* …`, `// …`, `};`, a logger's `[INFO] …`,
/// `(HOST) …`, `<info> …`) or a box drawing character (probe-rs's location lines `└─ …`), or
/// whose first field is words (a space and a letter before any comma: the firmware's help line
/// `1200-baud touch (…`, defmt's timestamped `0.123456 INFO …`). A row-like line is never one.
pub fn is_message(t: &str) -> bool {
    let printable = t.chars().all(|c| (!c.is_control() || c == '\t') && c != '\u{FFFD}');
    let first = t.chars().next().is_some_and(|c| {
        c.is_alphabetic()
            || matches!(c, '{' | '}' | '[' | ']' | '(' | ')' | '<' | '>' | '/' | '*' | '"')
            || ('\u{2500}'..='\u{257F}').contains(&c)
    });
    let head = t.split(',').next().unwrap_or("");
    let words = head.contains(char::is_whitespace) && head.contains(char::is_alphabetic);
    printable && (first || words)
}

#[cfg(test)]
mod tests {
    use super::*;
    extern crate std;
    use std::string::String;

    /// `f32`s of every magnitude a log holds, both signs (xorshift, fixed seed).
    fn values() -> impl Iterator<Item = f32> {
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        (0..20_000).map(move |i| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let v = f32::from_bits(x as u32 & 0x7FFF_FFFF) % 4096.0 / [1.0, 1e3, 1e6][i % 3];
            if x >> 63 == 1 {
                -v
            } else {
                v
            }
        })
    }

    fn written(v: f32, decimals: u32) -> String {
        let mut s = String::new();
        fixed(&mut s, v, decimals).unwrap();
        s
    }

    /// [`fixed`] against `core::fmt`'s exact decimal expansion of the value (ties, where the two
    /// round differently, left out).
    #[test]
    fn fixed_writes_the_exact_value_correctly_rounded() {
        for v in values().filter(|v| v.is_finite()) {
            for d in [0, 2, 3, 5, 6, 9] {
                let exact = v as f64 * 10f64.powi(d as i32);
                if exact.abs() >= 1e15 || (exact.abs().fract() - 0.5).abs() < 1e-6 {
                    continue;
                }
                let want = std::format!("{:.*}", d as usize, v as f64);
                let want = if want.trim_start_matches(['-', '0', '.']).is_empty() { want.trim_start_matches('-').into() } else { want };
                assert_eq!(written(v, d), want, "{v:e} to {d} decimals");
            }
        }
        assert_eq!(
            (written(0.5, 0), written(-0.5, 0), written(2.5, 0), written(0.125, 2)),
            ("1".into(), "-1".into(), "3".into(), "0.13".into())
        );
        assert_eq!(
            (written(f32::NAN, 3), written(f32::INFINITY, 0), written(1e19, 0), written(-1e10, 9)),
            ("nan".into(), "nan".into(), "nan".into(), "nan".into())
        );
        assert_eq!((written(4.611_686e18, 0), written(f32::from_bits(1), 9)), ("4611686018427387904".into(), "0.000000000".into()));
    }

    /// A value on the grid, written, parses back to the very same `f32`, and is the nearest
    /// grid point to the value (within half a step and an `f32` rounding).
    #[test]
    fn on_grid_values_parse_back_to_themselves() {
        for v in values().filter(|v| v.is_finite()) {
            for d in [2, 3, 5, 6] {
                let g = on_grid(v, d);
                assert_eq!(written(g, d).parse::<f32>().unwrap(), g, "{v:e} to {d} decimals");
                let step = 10f64.powi(-(d as i32));
                assert!((g as f64 - v as f64).abs() <= 0.5 * step + (g.abs() as f64) * 6e-8, "{v:e} to {d} decimals: {g:e}");
            }
        }
    }

    #[test]
    fn long_division_by_ten_matches_u64_division() {
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        for m in [0, 9, 10, 65_535, 655_359, u32::MAX as u64, 1 << 48, 9_200_000_000_000_000_000, u64::MAX].into_iter().chain(
            (0..1000).map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                x
            }),
        ) {
            assert_eq!(div10(m), (m / 10, (m % 10) as u32), "{m}");
        }
    }
}
