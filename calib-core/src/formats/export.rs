//! A calibration record for the user: one line of JSON (the `calib` tool's schema), a C snippet
//! to paste into Arduino/C code, or Rust constants. No allocation, no `core::fmt` float code:
//! numbers go through the log's fixed-point writer.
//!
//! Decimals written: `K` and `M` 7 (a K element round-trips to 5e-8, below f32's 6e-8 ulp at
//! 1); gyro bias 5 (10 µ°/s, the log's gyro resolution); accel offset 6 (1 µg, the log's accel
//! resolution); 1σ of `K` 9; accel residual 7 (0.1 µg); fit residual 6; temperature 2 (°C);
//! condition and angles 3. A value that cannot be written (NaN, infinite, or beyond 9.2e18 /
//! 10^decimals) is `null` in JSON, `NAN` (math.h) in C and `f32::NAN` in Rust; a valid record
//! has none in `K`, `b`, `M`, `o`.
//!
//! Every format states the sensor setup the calibration holds for (ODR, full scales) and the
//! gyro bias's temperature coefficient `c` with its 1σ and temperature range, or that it is
//! unknown: `b(T) = b + c (T − temp_c)`.
//!
//! JSON's `quality.source` is `board`, or `calib` for a record of sequence 0 (never stored: the
//! offline tool's result). An unknown temperature is `null`. With the `serde` feature,
//! [`RecordJson`] is the same JSON as a serde type (the PC writes and reads it with serde; the
//! firmware, without serde, writes it here by hand: `host-tests/calib/tests/export.rs` checks that
//! the two agree).
//!
//! The C and Rust formats are several lines separated by `\n` (no line ending after the last),
//! each at most [`MAX_LINE`] bytes.

use crate::estimators::bias::TempCo;
use crate::estimators::frame::DataFrame;
use crate::formats::log::{fixed, writable};
use crate::formats::record::{Record, Sensor};
use crate::formats::text::{Int, Text};
use crate::{Mat3, Vec3};
use core::fmt::{self, Write};

/// Output formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// One line: `{"gyro":{…},"accel":{…},"quality":{…}}`.
    Json,
    /// `static const float` arrays and `gyrocal_apply()`, with comments.
    C,
    /// `pub const` arrays, with comments.
    Rust,
}

/// Longest line of the C and Rust formats (bytes).
pub const MAX_LINE: usize = 120;

/// Decimals of `K` and `M`.
const D_MATRIX: u32 = 7;
/// Decimals of the gyro bias (°/s).
const D_BIAS: u32 = 5;
/// Decimals of the accelerometer offset (g).
const D_OFFSET: u32 = 6;
/// Decimals of the temperature (°C).
const D_TEMP: u32 = 2;
/// Decimals of the 1σ of `K`.
const D_SIGMA: u32 = 9;
/// Decimals of the condition number and the angle from coplanar (°).
const D_CONDITION: u32 = 3;
/// Decimals of the gyro fit's residual.
const D_RESIDUAL: u32 = 6;
/// Decimals of the accelerometer residual (g).
const D_ACCEL_RMS: u32 = 7;
/// Decimals of the tempco and its 1σ (°/s per °C).
const D_TEMPCO: u32 = 6;
/// Decimals of the ODR (Hz) and the full scales.
const D_SETUP: u32 = 1;
/// Decimals of the magnetometer's offset, field, angles, residual and coverage (nT, m°).
const D_MAG: u32 = 3;

/// The first bytes of the JSON line (its first key), by which [`crate::formats::protocol::parse`] knows it.
pub(crate) const JSON_START: &str = "{\"gyro\":";

/// Where a record comes from: JSON's `quality.source`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    /// Stored by a board (sequence ≥ 1).
    Board,
    /// The offline tool's result, never stored (sequence 0).
    Calib,
}

impl Source {
    /// Of a record: by its sequence number.
    pub fn of(rec: &Record) -> Source {
        if rec.seq == 0 {
            Source::Calib
        } else {
            Source::Board
        }
    }

    /// Its name in JSON.
    pub fn name(self) -> &'static str {
        match self {
            Source::Board => "board",
            Source::Calib => "calib",
        }
    }
}

/// The record's temperature (°C), NaN if it is unknown (written `null`).
fn temp_c(rec: &Record) -> f32 {
    rec.temp_c.unwrap_or(f32::NAN)
}

/// Writes `rec` in `format` (its raw frame).
pub fn write(w: &mut impl Write, rec: &Record, format: Format) -> fmt::Result {
    match format {
        Format::Json => json(w, rec),
        Format::C => c(w, rec, DataFrame::Board),
        Format::Rust => rust(w, rec, DataFrame::Board),
    }
}

/// Writes `rec`'s calibration for data read as `frame` in C or Rust (its header says which);
/// `fmt::Error` for a frame the record's part has not ([`Record::in_frame`]) or for JSON, which
/// is always the raw record.
pub fn write_in(w: &mut impl Write, rec: &Record, format: Format, frame: DataFrame) -> fmt::Result {
    let r = rec.in_frame(frame).map_err(|_| fmt::Error)?;
    match format {
        Format::Json if frame == DataFrame::Board => json(w, &r),
        Format::Json => Err(fmt::Error),
        Format::C => c(w, &r, frame),
        Format::Rust => rust(w, &r, frame),
    }
}

/// One number, `nan` standing for a value that cannot be written, `suffix` after a written one.
fn num(w: &mut impl Write, v: f32, decimals: u32, nan: &str, suffix: &str) -> fmt::Result {
    if writable(v, decimals) {
        fixed(w, v, decimals)?;
        w.write_str(suffix)
    } else {
        w.write_str(nan)
    }
}

fn json_num(w: &mut impl Write, v: f32, decimals: u32) -> fmt::Result {
    num(w, v, decimals, "null", "")
}

fn json_vec(w: &mut impl Write, v: &Vec3, decimals: u32) -> fmt::Result {
    for (i, x) in v.iter().enumerate() {
        w.write_str(if i == 0 { "[" } else { "," })?;
        json_num(w, *x, decimals)?;
    }
    w.write_str("]")
}

fn json_mat(w: &mut impl Write, m: &Mat3, decimals: u32) -> fmt::Result {
    for (i, r) in m.iter().enumerate() {
        w.write_str(if i == 0 { "[" } else { "," })?;
        json_vec(w, r, decimals)?;
    }
    w.write_str("]")
}

fn json(w: &mut impl Write, r: &Record) -> fmt::Result {
    // Starts with JSON_START.
    w.write_str("{\"gyro\":{\"K\":")?;
    json_mat(w, &r.gyro_k, D_MATRIX)?;
    w.write_str(",\"bias_dps\":")?;
    json_vec(w, &r.gyro_bias_dps, D_BIAS)?;
    write!(w, ",\"method\":\"{}\"}},\"accel\":{{\"M\":", Text(r.method.name()))?;
    json_mat(w, &r.accel_m, D_MATRIX)?;
    w.write_str(",\"offset_g\":")?;
    json_vec(w, &r.accel_offset_g, D_OFFSET)?;
    w.write_str("},\"mag\":")?;
    match &r.mag {
        None => w.write_str("null")?,
        Some(m) => {
            w.write_str("{\"A\":")?;
            json_mat(w, &m.a, D_MATRIX)?;
            w.write_str(",\"offset_ut\":")?;
            json_vec(w, &m.offset_ut, D_MAG)?;
            w.write_str("}")?;
        }
    }
    write!(w, ",\"quality\":{{\"source\":\"{}\",\"seq\":{},\"temp_c\":", Text(Source::of(r).name()), Int(r.seq.into()))?;
    json_num(w, temp_c(r), D_TEMP)?;
    w.write_str(",\"sigma_K\":")?;
    json_mat(w, &r.sigma_k, D_SIGMA)?;
    write!(w, ",\"poses\":{},\"rows\":{},\"condition\":", Int(r.poses.into()), Int(r.rows.into()))?;
    json_num(w, r.condition, D_CONDITION)?;
    w.write_str(",\"residual_rms\":")?;
    json_num(w, r.residual_rms, D_RESIDUAL)?;
    w.write_str(",\"non_coplanar_deg\":")?;
    json_num(w, r.non_coplanar_deg, D_CONDITION)?;
    write!(w, ",\"accel_model\":\"{}\",\"accel_rms_g\":", Text(r.accel_model.name()))?;
    json_num(w, r.accel_rms_g, D_ACCEL_RMS)?;
    w.write_str(",\"setup\":{\"odr_hz\":")?;
    json_num(w, r.setup.odr_hz, D_SETUP)?;
    w.write_str(",\"gyro_range_dps\":")?;
    json_num(w, r.setup.gyro_range_dps, D_SETUP)?;
    w.write_str(",\"accel_range_g\":")?;
    json_num(w, r.setup.accel_range_g, D_SETUP)?;
    match r.setup.sensor {
        Sensor::Lsm9ds1 => w.write_str(",\"sensor\":\"lsm9ds1\"")?,
        Sensor::Bmi270 { gyr_cas, user_gain } => {
            let user_gain = Text(if user_gain { "true" } else { "false" });
            write!(w, ",\"sensor\":{{\"bmi270\":{{\"gyr_cas\":{},\"user_gain\":{user_gain}}}}}", Int(gyr_cas.into()))?
        }
    }
    w.write_str("},\"tempco\":")?;
    match r.tempco {
        None => w.write_str("null")?,
        Some(t) => {
            w.write_str("{\"dps_per_c\":")?;
            json_vec(w, &t.dps_per_c, D_TEMPCO)?;
            w.write_str(",\"sigma_dps_per_c\":")?;
            json_vec(w, &t.sigma_dps_per_c, D_TEMPCO)?;
            w.write_str(",\"range_c\":[")?;
            json_num(w, t.range_c[0], D_TEMP)?;
            w.write_str(",")?;
            json_num(w, t.range_c[1], D_TEMP)?;
            w.write_str("]}")?;
        }
    }
    w.write_str(",\"mag\":")?;
    match &r.mag {
        None => w.write_str("null")?,
        Some(m) => {
            for (i, (k, v)) in [
                ("field_ut", m.field_ut),
                ("sigma_field_ut", m.sigma_field_ut),
                ("dip_deg", m.dip_deg),
                ("sigma_dip_deg", m.sigma_dip_deg),
                ("alignment_deg", m.alignment_deg),
                ("sigma_alignment_deg", m.sigma_alignment_deg),
                ("residual_ut", m.residual_ut),
                ("coverage", m.coverage),
            ]
            .into_iter()
            .enumerate()
            {
                w.write_str(if i == 0 { "{\"" } else { ",\"" })?;
                w.write_str(k)?;
                w.write_str("\":")?;
                json_num(w, v, D_MAG)?;
            }
            write!(w, ",\"samples\":{},\"poses\":{}}}", Int(m.samples.into()), Int(m.poses.into()))?;
        }
    }
    w.write_str("}}")
}

/// The syntax of an array initialiser: brackets, a float's suffix and NaN.
struct Syntax {
    open: &'static str,
    close: &'static str,
    suffix: &'static str,
    nan: &'static str,
}

const C_SYNTAX: Syntax = Syntax { open: "{", close: "}", suffix: "f", nan: "NAN" };
const RUST_SYNTAX: Syntax = Syntax { open: "[", close: "]", suffix: "", nan: "f32::NAN" };

fn array(w: &mut impl Write, s: &Syntax, v: &Vec3, decimals: u32) -> fmt::Result {
    for (i, x) in v.iter().enumerate() {
        w.write_str(if i == 0 { s.open } else { ", " })?;
        num(w, *x, decimals, s.nan, s.suffix)?;
    }
    w.write_str(s.close)
}

/// A 3×3 initialiser, one row per line (after `decl`'s line).
fn matrix(w: &mut impl Write, s: &Syntax, decl: &str, m: &Mat3) -> fmt::Result {
    writeln!(w, "{decl} = {}", s.open)?;
    for r in m {
        w.write_str("    ")?;
        array(w, s, r, D_MATRIX)?;
        w.write_str(",\n")?;
    }
    writeln!(w, "{};", s.close)
}

/// The header comment lines, each between `open` and `close`: what the record is, the part and
/// the data `frame` it applies to, and the two models with their units.
fn header(w: &mut impl Write, r: &Record, frame: DataFrame, open: &str, close: &str) -> fmt::Result {
    write!(w, "{open}gyrocal calibration record {}, {} K, accelerometer model {}, sensor ", r.seq, r.method.name(), r.accel_model.name())?;
    num(w, temp_c(r), 1, "temperature unknown", " degC")?;
    writeln!(w, "{close}")?;
    match r.setup.sensor {
        Sensor::Lsm9ds1 => write!(w, "{open}Part: LSM9DS1")?,
        Sensor::Bmi270 { gyr_cas, user_gain } => {
            write!(w, "{open}Part: BMI270, GYR_CAS {gyr_cas}, user gain {}", if user_gain { "on" } else { "off" })?
        }
    }
    writeln!(w, "{close}")?;
    writeln!(w, "{open}Data: {}{close}", frame.describe())?;
    writeln!(w, "{open}Gyro:  omega = K (g - b): g gyro reading (deg/s), b = GYRO_BIAS_DPS (deg/s), omega (deg/s){close}")?;
    writeln!(w, "{open}Accel: f = M (a - o): a accel reading (g), o = ACCEL_OFFSET_G (g), f calibrated (g){close}")?;
    writeln!(w, "{open}K maps the gyro into the calibrated accelerometer's frame; both matrices row-major.{close}")?;
    w.write_str(open)?;
    w.write_str("Holds for the sensor at ")?;
    num(w, r.setup.odr_hz, 0, "?", " Hz, +-")?;
    num(w, r.setup.gyro_range_dps, 0, "?", " deg/s, +-")?;
    num(w, r.setup.accel_range_g, 0, "?", " g")?;
    writeln!(w, "{close}")?;
    match r.tempco {
        None => writeln!(w, "{open}Gyro bias tempco unknown: the calibration's temperature did not span enough.{close}")?,
        Some(t) => tempco_comment(w, &t, open, close)?,
    }
    match &r.mag {
        None => writeln!(w, "{open}No magnetometer calibration (none read, or a pan/tilt run).{close}"),
        Some(m) => {
            writeln!(w, "{open}Mag:   m = A (r - o): r magnetometer reading (uT, board frame), o = MAG_OFFSET_UT{close}")?;
            write!(w, "{open}(uT), m calibrated (uT) in the frame of K and M; field ")?;
            num(w, m.field_ut, 2, "?", " uT, dip ")?;
            num(w, m.dip_deg, 2, "?", " deg")?;
            writeln!(w, "{close}")?;
            writeln!(w, "{open}Dip {}.{close}", crate::formats::text::DIP_SIGN)
        }
    }
}

/// The magnetometer's constants (when the record has them).
fn mag_consts(w: &mut impl Write, r: &Record, s: &Syntax, a_decl: &str, o_decl: &str) -> fmt::Result {
    let Some(m) = &r.mag else { return Ok(()) };
    w.write_str("\n")?;
    matrix(w, s, a_decl, &m.a)?;
    w.write_str(o_decl)?;
    array(w, s, &m.offset_ut, D_MAG)?;
    w.write_str(";")
}

/// The tempco's comment line: `b(T) = b + c (T - T_cal)`, `c` and its range.
fn tempco_comment(w: &mut impl Write, t: &TempCo, open: &str, close: &str) -> fmt::Result {
    write!(w, "{open}Gyro bias tempco: b(T) = b + c (T - T_cal), T_cal the temperature above, fitted over ")?;
    num(w, t.range_c[0], 1, "?", "..")?;
    num(w, t.range_c[1], 1, "?", " degC:")?;
    writeln!(w, "{close}")?;
    write!(w, "{open}c = ")?;
    array(w, &RUST_SYNTAX, &t.dps_per_c, D_TEMPCO)?;
    w.write_str(" deg/s/degC,")?;
    w.write_str(" 1 sigma ")?;
    array(w, &RUST_SYNTAX, &t.sigma_dps_per_c, D_TEMPCO)?;
    writeln!(w, "{close}")
}

fn c(w: &mut impl Write, r: &Record, frame: DataFrame) -> fmt::Result {
    let s = &C_SYNTAX;
    header(w, r, frame, "/* ", " */")?;
    matrix(w, s, "static const float GYRO_K[3][3]", &r.gyro_k)?;
    w.write_str("static const float GYRO_BIAS_DPS[3] = ")?;
    array(w, s, &r.gyro_bias_dps, D_BIAS)?;
    w.write_str(";\n")?;
    matrix(w, s, "static const float ACCEL_M[3][3]", &r.accel_m)?;
    w.write_str("static const float ACCEL_OFFSET_G[3] = ")?;
    array(w, s, &r.accel_offset_g, D_OFFSET)?;
    w.write_str(";\n")?;
    w.write_str(concat!(
        "/* out_dps = K (g_dps - b): the header's omega (deg/s). */\n",
        "static inline void gyrocal_apply(const float g_dps[3], float out_dps[3]) {\n",
        "    const float d[3] = {g_dps[0] - GYRO_BIAS_DPS[0], g_dps[1] - GYRO_BIAS_DPS[1], g_dps[2] - GYRO_BIAS_DPS[2]};\n",
        "    for (int i = 0; i < 3; i++) {\n",
        "        out_dps[i] = GYRO_K[i][0] * d[0] + GYRO_K[i][1] * d[1] + GYRO_K[i][2] * d[2];\n",
        "    }\n",
        "}",
    ))?;
    mag_consts(w, r, s, "static const float MAG_A[3][3]", "static const float MAG_OFFSET_UT[3] = ")
}

fn rust(w: &mut impl Write, r: &Record, frame: DataFrame) -> fmt::Result {
    let s = &RUST_SYNTAX;
    header(w, r, frame, "// ", "")?;
    w.write_str("/// Gyro scale matrix K (row-major, dimensionless): omega = K (g - b).\n")?;
    matrix(w, s, "pub const GYRO_K: [[f32; 3]; 3]", &r.gyro_k)?;
    w.write_str("/// Gyro bias b (deg/s).\npub const GYRO_BIAS_DPS: [f32; 3] = ")?;
    array(w, s, &r.gyro_bias_dps, D_BIAS)?;
    w.write_str(";\n/// Accelerometer matrix M (row-major, dimensionless): f = M (a - o).\n")?;
    matrix(w, s, "pub const ACCEL_M: [[f32; 3]; 3]", &r.accel_m)?;
    w.write_str("/// Accelerometer offset o (g).\npub const ACCEL_OFFSET_G: [f32; 3] = ")?;
    array(w, s, &r.accel_offset_g, D_OFFSET)?;
    w.write_str(";")?;
    if r.mag.is_some() {
        w.write_str("\n/// Magnetometer matrix A (row-major) and offset (uT): m = A (r - o).")?;
    }
    mag_consts(w, r, s, "pub const MAG_A: [[f32; 3]; 3]", "pub const MAG_OFFSET_UT: [f32; 3] = ")
}

pub use crate::formats::record::NotFinite;
#[cfg(feature = "serde")]
pub use schema::{AccelJson, GyroJson, MagJson, MagQualityJson, QualityJson, RecordJson, TempCoJson};

/// [`Format::Json`] as serde types (feature `serde`).
#[cfg(feature = "serde")]
mod schema {
    use super::*;
    use crate::estimators::accel::AccelModel;
    use crate::estimators::gyro::Method;
    use crate::formats::record::{NotFinite, SensorSetup};
    use serde::{Deserialize, Serialize};

    /// The JSON line of a record, field for field what [`Format::Json`] writes: the calibration
    /// to apply (`gyro`, `accel`), then its quality. `null` is a value that is unknown or could
    /// not be written.
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    pub struct RecordJson {
        /// `ω = K (g − b)`.
        pub gyro: GyroJson,
        /// `f = M (a − o)`.
        pub accel: AccelJson,
        /// `m = A (m_raw − o)`; `null`: none (absent in a record's JSON older than the
        /// magnetometer: none).
        #[serde(default)]
        pub mag: Option<MagJson>,
        /// Where the record comes from and how good it is.
        pub quality: QualityJson,
    }

    /// The magnetometer's calibration (also the `mag` of the offline tool's output).
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    pub struct MagJson {
        /// `A` (row-major): soft iron, scale and the die's alignment onto the accelerometer.
        #[serde(rename = "A")]
        pub a: Mat3,
        /// Hard iron and offset (µT, raw frame).
        pub offset_ut: Vec3,
    }

    /// The magnetometer's quality ([`crate::estimators::mag::MagCal`]'s figures).
    #[allow(missing_docs)] // named as MagCal's fields
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    pub struct MagQualityJson {
        pub field_ut: Option<f32>,
        pub sigma_field_ut: Option<f32>,
        pub dip_deg: Option<f32>,
        pub sigma_dip_deg: Option<f32>,
        pub alignment_deg: Option<f32>,
        pub sigma_alignment_deg: Option<f32>,
        pub residual_ut: Option<f32>,
        pub coverage: Option<f32>,
        pub samples: u16,
        pub poses: u8,
    }

    /// The gyro calibration (also the `gyro` of the offline tool's output).
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    pub struct GyroJson {
        /// Scale matrix (row-major).
        #[serde(rename = "K")]
        pub k: Mat3,
        /// Bias (raw °/s).
        pub bias_dps: Vec3,
        /// The estimator that made `K`.
        #[serde(with = "by_name")]
        pub method: Method,
    }

    /// The accelerometer calibration (also the `accel` of the offline tool's output).
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    pub struct AccelJson {
        /// Gain matrix (row-major).
        #[serde(rename = "M")]
        pub m: Mat3,
        /// Offset (raw g).
        pub offset_g: Vec3,
    }

    /// A record's quality fields (those of [`Record`] that JSON carries).
    #[allow(missing_docs)] // named as the record's fields
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    pub struct QualityJson {
        #[serde(with = "by_name")]
        pub source: Source,
        pub seq: u32,
        /// °C; `null`: unknown.
        pub temp_c: Option<f32>,
        #[serde(rename = "sigma_K")]
        pub sigma_k: [[Option<f32>; 3]; 3],
        pub poses: u8,
        pub rows: u16,
        pub condition: Option<f32>,
        pub residual_rms: Option<f32>,
        pub non_coplanar_deg: Option<f32>,
        #[serde(with = "by_name")]
        pub accel_model: AccelModel,
        pub accel_rms_g: Option<f32>,
        pub setup: SensorSetup,
        /// `null`: unknown.
        pub tempco: Option<TempCoJson>,
        /// `null`: no magnetometer calibration.
        #[serde(default)]
        pub mag: Option<MagQualityJson>,
    }

    /// The gyro bias's temperature coefficient (°/s per °C) with its 1σ, and the temperature
    /// range (°C) over which it was fitted.
    #[allow(missing_docs)] // named as [`TempCo`]'s fields
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    pub struct TempCoJson {
        pub dps_per_c: Vec3,
        pub sigma_dps_per_c: Vec3,
        pub range_c: [f32; 2],
    }

    /// `v` where [`Format::Json`] writes a number, `None` where it writes `null`.
    fn written(v: f32, decimals: u32) -> Option<f32> {
        writable(v, decimals).then_some(v)
    }

    impl From<&Record> for RecordJson {
        fn from(r: &Record) -> Self {
            RecordJson {
                gyro: GyroJson { k: r.gyro_k, bias_dps: r.gyro_bias_dps, method: r.method },
                accel: AccelJson { m: r.accel_m, offset_g: r.accel_offset_g },
                mag: r.mag.map(|m| MagJson { a: m.a, offset_ut: m.offset_ut }),
                quality: QualityJson {
                    source: Source::of(r),
                    seq: r.seq,
                    temp_c: written(temp_c(r), D_TEMP),
                    sigma_k: r.sigma_k.map(|row| row.map(|v| written(v, D_SIGMA))),
                    poses: r.poses,
                    rows: r.rows,
                    condition: written(r.condition, D_CONDITION),
                    residual_rms: written(r.residual_rms, D_RESIDUAL),
                    non_coplanar_deg: written(r.non_coplanar_deg, D_CONDITION),
                    accel_model: r.accel_model,
                    accel_rms_g: written(r.accel_rms_g, D_ACCEL_RMS),
                    setup: r.setup,
                    tempco: r.tempco.map(|t| TempCoJson { dps_per_c: t.dps_per_c, sigma_dps_per_c: t.sigma_dps_per_c, range_c: t.range_c }),
                    mag: r.mag.map(|m| MagQualityJson {
                        field_ut: written(m.field_ut, D_MAG),
                        sigma_field_ut: written(m.sigma_field_ut, D_MAG),
                        dip_deg: written(m.dip_deg, D_MAG),
                        sigma_dip_deg: written(m.sigma_dip_deg, D_MAG),
                        alignment_deg: written(m.alignment_deg, D_MAG),
                        sigma_alignment_deg: written(m.sigma_alignment_deg, D_MAG),
                        residual_ut: written(m.residual_ut, D_MAG),
                        coverage: written(m.coverage, D_MAG),
                        samples: m.samples,
                        poses: m.poses,
                    }),
                },
            }
        }
    }

    impl RecordJson {
        /// The record it was written from. `K`, `b`, `M` and `o` must be numbers; a `null`
        /// temperature is unknown; a quality field written `null` (too large to print) reads 0, as
        /// the fields JSON does not carry (invariant spreads, tilt, span) do. Never a NaN.
        pub fn record(&self) -> Result<Record, NotFinite> {
            let (g, a, q) = (&self.gyro, &self.accel, &self.quality);
            let cal = [g.k.as_flattened(), &g.bias_dps, a.m.as_flattened(), &a.offset_g];
            let mag = self.mag.iter().flat_map(|m| m.a.as_flattened().iter().chain(&m.offset_ut));
            if cal.iter().any(|s| s.iter().any(|x| !x.is_finite())) || mag.clone().any(|x| !x.is_finite()) {
                return Err(NotFinite);
            }
            let v = |x: Option<f32>| x.filter(|x| x.is_finite()).unwrap_or(0.0);
            let mq = q.mag.unwrap_or(MagQualityJson {
                field_ut: None,
                sigma_field_ut: None,
                dip_deg: None,
                sigma_dip_deg: None,
                alignment_deg: None,
                sigma_alignment_deg: None,
                residual_ut: None,
                coverage: None,
                samples: 0,
                poses: 0,
            });
            let mag = self.mag.map(|m| crate::estimators::mag::MagCal {
                a: m.a,
                offset_ut: m.offset_ut,
                field_ut: v(mq.field_ut),
                sigma_field_ut: v(mq.sigma_field_ut),
                dip_deg: v(mq.dip_deg),
                sigma_dip_deg: v(mq.sigma_dip_deg),
                alignment_deg: v(mq.alignment_deg),
                sigma_alignment_deg: v(mq.sigma_alignment_deg),
                residual_ut: v(mq.residual_ut),
                coverage: v(mq.coverage),
                samples: mq.samples,
                poses: mq.poses,
            });
            let rec = Record {
                seq: q.seq,
                temp_c: q.temp_c,
                gyro_k: g.k,
                gyro_bias_dps: g.bias_dps,
                method: g.method,
                accel_m: a.m,
                accel_offset_g: a.offset_g,
                accel_model: q.accel_model,
                poses: q.poses,
                rows: q.rows,
                sigma_k: q.sigma_k.map(|row| row.map(v)),
                invariant_before_rel: 0.0,
                invariant_after_rel: 0.0,
                condition: v(q.condition),
                tilt_deg: 0.0,
                span_deg: 0.0,
                accel_rms_g: v(q.accel_rms_g),
                residual_rms: v(q.residual_rms),
                non_coplanar_deg: v(q.non_coplanar_deg),
                setup: q.setup,
                tempco: q.tempco.map(|t| TempCo { dps_per_c: t.dps_per_c, sigma_dps_per_c: t.sigma_dps_per_c, range_c: t.range_c }),
                mag,
            };
            rec.check_finite().map(|_| rec)
        }
    }

    /// A field written as its `name()` (as the firmware writes it), read back by that name.
    mod by_name {
        use crate::estimators::accel::AccelModel;
        use crate::estimators::gyro::Method;
        use crate::formats::export::Source;
        use core::fmt;
        use core::marker::PhantomData;
        use serde::de::{self, Unexpected, Visitor};
        use serde::{Deserializer, Serializer};

        pub(super) trait Named: Copy + 'static {
            /// What the names name (for an error).
            const WHAT: &'static str;
            const ALL: &'static [Self];
            fn name(self) -> &'static str;
        }

        impl Named for Method {
            const WHAT: &'static str = "a gyro method";
            const ALL: &'static [Self] = &crate::formats::protocol::METHODS;
            fn name(self) -> &'static str {
                Method::name(self)
            }
        }

        impl Named for AccelModel {
            const WHAT: &'static str = "an accelerometer model";
            const ALL: &'static [Self] = &crate::formats::protocol::ACCEL_MODELS;
            fn name(self) -> &'static str {
                AccelModel::name(self)
            }
        }

        impl Named for Source {
            const WHAT: &'static str = "a source (board or calib)";
            const ALL: &'static [Self] = &[Source::Board, Source::Calib];
            fn name(self) -> &'static str {
                Source::name(self)
            }
        }

        pub(super) fn serialize<T: Named, S: Serializer>(v: &T, s: S) -> Result<S::Ok, S::Error> {
            s.serialize_str(v.name())
        }

        pub(super) fn deserialize<'de, T: Named, D: Deserializer<'de>>(d: D) -> Result<T, D::Error> {
            struct Name<T>(PhantomData<T>);
            impl<T: Named> Visitor<'_> for Name<T> {
                type Value = T;
                fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                    write!(f, "the name of {}", T::WHAT)
                }
                fn visit_str<E: de::Error>(self, s: &str) -> Result<T, E> {
                    T::ALL.iter().copied().find(|v| v.name() == s).ok_or_else(|| E::invalid_value(Unexpected::Str(s), &self))
                }
            }
            d.deserialize_str(Name(PhantomData))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimators::gyro::Method;
    use crate::formats::record::tests::sample;
    use crate::formats::record::SensorSetup;
    extern crate std;
    use std::string::String;

    fn text(rec: &Record, f: Format) -> String {
        let mut s = String::new();
        write(&mut s, rec, f).unwrap();
        s
    }

    #[test]
    fn json_is_one_line_with_the_schema_and_seven_decimals() {
        let s = text(&sample(), Format::Json);
        assert_eq!(s.lines().count(), 1);
        assert!(s.starts_with("{\"gyro\":{\"K\":[[1.0100000,0.0000000,0.0000000],[0.0000000,0.9900000,"), "{s}");
        assert!(s.contains("\"bias_dps\":[0.50000,-1.25000,2.00000],\"method\":\"sweep\"},\"accel\":{\"M\":[[1.0010000,"), "{s}");
        assert!(s.contains("\"offset_g\":[0.010000,-0.020000,0.015000]}"), "{s}");
        assert!(s.contains("\"quality\":{\"source\":\"board\",\"seq\":7,\"temp_c\":24.50,\"sigma_K\":[[0.000100000,"), "{s}");
        assert!(s.contains("\"accel_model\":\"nine_param\",\"accel_rms_g\":0.0004000,"), "{s}");
        assert!(s.contains(",\"setup\":{\"odr_hz\":119.0,\"gyro_range_dps\":500.0,\"accel_range_g\":2.0,\"sensor\":\"lsm9ds1\"},\"tempco\":{\"dps_per_c\":[0.030000,-0.045000,0.010000],\"sigma_dps_per_c\":[0.002000,0.003000,0.002500],\"range_c\":[24.00,27.50]},"), "{s}");
        assert!(s.contains("\"offset_g\":[0.010000,-0.020000,0.015000]},\"mag\":{\"A\":[[1.0200000,0.0100000,-0.0200000],"), "{s}");
        assert!(s.ends_with("\"mag\":{\"field_ut\":48.500,\"sigma_field_ut\":0.125,\"dip_deg\":61.250,\"sigma_dip_deg\":0.063,\"alignment_deg\":1.500,\"sigma_alignment_deg\":0.031,\"residual_ut\":0.250,\"coverage\":0.850,\"samples\":140,\"poses\":12}}}"), "{s}");
        let unknown = text(&Record { tempco: None, mag: None, ..sample() }, Format::Json);
        assert!(unknown.contains("\"offset_g\":[0.010000,-0.020000,0.015000]},\"mag\":null,\"quality\":"), "{unknown}");
        assert!(unknown.ends_with("\"accel_range_g\":2.0,\"sensor\":\"lsm9ds1\"},\"tempco\":null,\"mag\":null}}"), "{unknown}");
        let bmi =
            Record { setup: SensorSetup { sensor: Sensor::Bmi270 { gyr_cas: -7, user_gain: true }, ..SensorSetup::DEFAULT }, ..sample() };
        let b = text(&bmi, Format::Json);
        assert!(b.contains("\"accel_range_g\":2.0,\"sensor\":{\"bmi270\":{\"gyr_cas\":-7,\"user_gain\":true}}},\"tempco\":"), "{b}");
    }

    #[test]
    fn non_finite_and_huge_values_are_null_nan() {
        let rec = Record { temp_c: None, condition: 3e30, gyro_k: [[f32::INFINITY, 0.0, 0.0], [0.0; 3], [0.0; 3]], ..sample() };
        let s = text(&rec, Format::Json);
        assert!(s.contains("\"K\":[[null,0.0000000,") && s.contains("\"temp_c\":null,") && s.contains("\"condition\":null,"), "{s}");
        assert!(!s.contains("nan"), "{s}");
        let c = text(&rec, Format::C);
        assert!(c.contains("{NAN, 0.0000000f, 0.0000000f}") && c.contains("sensor temperature unknown */"), "{c}");
        assert!(text(&rec, Format::Rust).contains("[f32::NAN, 0.0000000, 0.0000000]"));
    }

    #[test]
    fn c_and_rust_have_the_arrays_units_and_short_lines() {
        let rec = Record {
            method: Method::Full,
            seq: 12,
            gyro_k: [[1.0123457, -0.0023456, 0.0001], [0.0, 0.99, 0.0], [0.0, 0.0, 1.02]],
            ..sample()
        };
        let c = text(&rec, Format::C);
        for needle in [
            "record 12, full K, accelerometer model nine_param, sensor 24.5 degC */",
            "omega = K (g - b)",
            "f = M (a - o)",
            "static const float GYRO_K[3][3] = {\n    {1.0123457f, -0.0023456f, 0.0001000f},\n",
            "static const float GYRO_BIAS_DPS[3] = {0.50000f, -1.25000f, 2.00000f};",
            "static const float ACCEL_M[3][3] = {",
            "static const float ACCEL_OFFSET_G[3] = {0.010000f, -0.020000f, 0.015000f};",
            "static inline void gyrocal_apply(const float g_dps[3], float out_dps[3]) {",
        ] {
            assert!(c.contains(needle), "{needle:?} not in\n{c}");
        }
        let r = text(&rec, Format::Rust);
        assert!(r.contains("pub const GYRO_K: [[f32; 3]; 3] = [\n    [1.0123457, -0.0023456, 0.0001000],\n"), "{r}");
        assert!(r.contains("pub const ACCEL_OFFSET_G: [f32; 3] = [0.010000, -0.020000, 0.015000];"), "{r}");
        // The magnetometer's constants and comment when the record has them, none without.
        assert!(c.contains("static const float MAG_A[3][3] = {\n    {1.0200000f, 0.0100000f, -0.0200000f},\n"), "{c}");
        assert!(c.contains("static const float MAG_OFFSET_UT[3] = {12.500f, -30.250f, 4.000f};"), "{c}");
        assert!(c.contains("field 48.50 uT, dip 61.25 deg"), "{c}");
        assert!(c.contains("/* Dip positive: the field points down (northern hemisphere). */"), "{c}");
        assert!(r.contains("pub const MAG_OFFSET_UT: [f32; 3] = [12.500, -30.250, 4.000];"), "{r}");
        let none = text(&Record { mag: None, ..rec }, Format::C);
        assert!(!none.contains("MAG_A") && none.contains("No magnetometer calibration"), "{none}");
        assert!(
            c.contains("/* Part: LSM9DS1 */\n/* Data: the board frame (x towards USB, z out of the component side), datasheet units */"),
            "{c}"
        );
        let bmi = Record { setup: SensorSetup { sensor: Sensor::Bmi270 { gyr_cas: -7, user_gain: false }, ..SensorSetup::DEFAULT }, ..rec };
        let mut ard = String::new();
        write_in(&mut ard, &bmi, Format::C, DataFrame::ArduinoBmi270).unwrap();
        let k = bmi.in_frame(DataFrame::ArduinoBmi270).unwrap().gyro_k;
        assert!(ard.contains("/* Part: BMI270, GYR_CAS -7, user gain off */\n/* Data: Arduino_BMI270_BMM150 >= 1.1.0's readings"), "{ard}");
        let mut row = String::new();
        fixed(&mut row, k[0][0], D_MATRIX).unwrap();
        assert!(ard.contains(&std::format!("static const float GYRO_K[3][3] = {{\n    {{{row}f, ")), "{row} {ard}");
        assert_eq!(write_in(&mut String::new(), &rec, Format::C, DataFrame::BoschApi), Err(fmt::Error), "an LSM9DS1's record");
        assert_eq!(write_in(&mut String::new(), &bmi, Format::Json, DataFrame::BoschApi), Err(fmt::Error), "JSON is the board frame's");
        for s in [&c, &r, &ard] {
            assert!(!s.ends_with('\n'));
            assert!(s.lines().all(|l| l.len() <= MAX_LINE && l.is_ascii()), "{s}");
        }
    }
}
