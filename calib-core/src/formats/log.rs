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
//!   preamble); [`END`] ends the data (what follows is ignored). After the header, a line whose
//!   first character cannot start a number is a log message (the firmware's other log lines in
//!   raw-log mode), skipped and counted; any other line must be a valid row. Columns are found
//!   by name, `tilt_deg` may be absent, extra columns are ignored.
//!
//! Numbers are written with fixed decimals (µs, µg, 10 µ°/s, 0.01°) by integer arithmetic, so
//! the firmware needs no float-formatting code.

use crate::formats::record::{Sensor, SensorSetup};
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
    /// MCU timestamp (s).
    pub t_s: f64,
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

/// Decimals written per column group: time, accelerometer, gyro, servo angles.
const DECIMALS: (u32, u32, u32, u32) = (6, 6, 5, 2);
/// Decimals of the magnetometer (1 nT).
const MAG_DECIMALS: u32 = 3;
/// Decimals of the temperature (0.01 °C).
const TEMP_DECIMALS: u32 = 2;

/// Writes `v` with `decimals` (≤ 9) fixed decimals; NaN or |v| ≥ 9.2e18 / 10^decimals is
/// written as `nan`, which the parser rejects. Digits by hand: no `core::fmt` number code.
#[inline(never)] // one copy for the log, the text lines and the exports (flash)
pub(crate) fn fixed(w: &mut dyn Write, v: f64, decimals: u32) -> fmt::Result {
    let scaled = v * 10u64.pow(decimals) as f64;
    if !(scaled.abs() < 9.2e18) {
        return w.write_str("nan");
    }
    // Round half away from zero without libm.
    let r = if scaled >= 0.0 { (scaled + 0.5) as i64 } else { (scaled - 0.5) as i64 };
    let mut m = r.unsigned_abs();
    // Digits, least significant first, with the decimal point after `decimals` of them.
    let mut buf = [0u8; 24];
    let mut n = 0;
    while n < decimals as usize || m > 0 || n <= decimals as usize {
        if n == decimals as usize && decimals > 0 {
            buf[n] = b'.';
            n += 1;
        }
        let (q, digit) = div10(m);
        buf[n] = b'0' + digit as u8;
        m = q;
        n += 1;
    }
    if r < 0 {
        buf[n] = b'-';
        n += 1;
    }
    buf[..n].iter().rev().try_for_each(|&b| w.write_char(b as char))
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

/// `v` rounded to `decimals` as [`fixed`] writes it (half away from zero), as the nearest `f32`.
fn on_grid(v: f32, decimals: u32) -> f32 {
    let scale = 10u64.pow(decimals) as f64;
    let scaled = v as f64 * scale;
    if !(scaled.abs() < 9.2e18) {
        return v;
    }
    let r = if scaled >= 0.0 { (scaled + 0.5) as i64 } else { (scaled - 0.5) as i64 };
    (r as f64 / scale) as f32
}

/// A sample's readings as a row holds them (accelerometer to 1 µg, gyro to 10 µ°/s; the text
/// parses back to these very `f32`s). The firmware hands its procedure these, so that a replay
/// of its log sees exactly what it saw, whatever the sensor's sensitivity (a BMI270's counts are
/// not on the log's grid).
pub fn as_logged(accel_g: [f32; 3], gyro_dps: [f32; 3]) -> ([f32; 3], [f32; 3]) {
    let (_, da, dg, _) = DECIMALS;
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
    let (dt, da, dg, ds) = DECIMALS;
    fixed(w, r.t_s, dt)?;
    for a in r.accel_g {
        w.write_char(',')?;
        fixed(w, a as f64, da)?;
    }
    for g in r.gyro_dps {
        w.write_char(',')?;
        fixed(w, g as f64, dg)?;
    }
    for s in [r.servo_deg, r.tilt_deg] {
        w.write_char(',')?;
        if let Some(s) = s {
            fixed(w, s as f64, ds)?;
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
            fixed(w, m[k] as f64, MAG_DECIMALS)?;
        }
    }
    Ok(())
}

/// Writes the temperature field of a row after [`write_mag`] (empty without one), for a log whose
/// header ends with [`TEMP_COLUMN`].
pub fn write_temp(w: &mut impl Write, temp_c: Option<f32>) -> fmt::Result {
    w.write_char(',')?;
    match temp_c {
        Some(t) => fixed(w, t as f64, TEMP_DECIMALS),
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
        fixed(w, v as f64, 1)?;
    }
    match s.sensor {
        Sensor::Lsm9ds1 => w.write_str(" sensor=lsm9ds1"),
        Sensor::Bmi270 { gyr_cas, user_gain } => write!(w, " sensor=bmi270 gyr_cas={gyr_cas} user_gain={}", u8::from(user_gain)),
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

/// Why a log line cannot be read. Lines are 1-based.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
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
        }
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
        t_s: num(0)?,
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

/// Classifies and reads one line after the header.
pub fn parse_line(text: &str, cols: &Columns, line: u32) -> Result<Line, LogError> {
    let t = text.trim();
    if t == END {
        Ok(Line::End)
    } else if let Some(s) = parse_setup(t) {
        Ok(Line::Setup(s))
    } else if t.is_empty() || t.starts_with('#') {
        Ok(Line::Skip)
    } else if !t.starts_with(|c: char| c.is_ascii_digit() || matches!(c, '-' | '+' | '.')) {
        Ok(Line::Message)
    } else {
        parse_row(t, cols, line).map(Line::Row)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
