//! The calibration record stored in flash: a fixed, versioned, little-endian layout with CRC-32.
//!
//! Layout v6 (`LEN` = 320 bytes): the v5 layout, its vectors and matrices in the board frame
//! ([`crate::board`]). Versions 1–5 held them in the part's raw axes (the LSM9DS1's magnetometer
//! in its accelerometer's, the BMM150's taken as the BMI270's) and load converted into the board
//! frame by the part's map ([`Record::from_part_axes`]).
//!
//! Layout v5 (`LEN` = 320 bytes): the v4 layout, then before the CRC the magnetometer's
//! calibration ([`MagCal`]): `A` (9, row-major), offset (3, µT), field strength and its 1σ (µT),
//! dip and its 1σ (°), alignment and its 1σ (°), residual (µT), coverage (0..1), all `f32`, then
//! samples (`u16`), poses (`u8`) and a reserved 0; all zeros with flags bit 2 when there is none
//! (no magnetometer read, or a pan/tilt run: no hand-held step).
//!
//! Layout v4 (`LEN_V4` = 236 bytes, written before the magnetometer; loads without one): the v3
//! layout, then before the CRC the part the calibration was
//! made with (`u8`: 0 LSM9DS1, 1 BMI270), the BMI270's GYR_CAS (`i8`, 0 for an LSM9DS1), its
//! flags (`u8`: bit 0 the BMI270's gyro user gain was enabled) and a reserved 0.
//!
//! Layout v3 (`LEN_V3` = 232 bytes, written before the Rev2 support; loads as an LSM9DS1's): the
//! v2 layout up to the angle from coplanar, then the sensor
//! setup the calibration was made at (ODR Hz, gyro full scale °/s, accelerometer full scale g)
//! and the gyro bias's temperature coefficient (3, °/s per °C), its 1σ (3) and the temperature
//! range over which it was fitted (2, °C), all `f32` (zeros with flags bit 1 when it is unknown),
//! then the CRC. `b(T) = b + c (T − temp_c)`.
//!
//! Layout v2 (`LEN_V2` = 188 bytes, written before the tempco) still loads, as made at the only
//! setup that firmware had (119 Hz, ±500 °/s, ±2 g) with the tempco unknown: magic `GYRC`,
//! version, gyro method, accel model, poses,
//! sequence (u32), rows (u16), flags (u16: bit 0 the temperature is unknown, bit 1 the tempco is
//! unknown (v3), the others 0),
//! temperature (°C, 0 when unknown), gyro `K` (9, row-major),
//! gyro bias (3, °/s), accel `M` (9), accel offset (3, g), 1σ of every element of `K` (9,
//! row-major), invariant relative spread before and after, condition number, axis tilt (°),
//! pose span (°), accel residual (g), residual RMS of the gyro fit, angle of the axes from
//! coplanar (°) — all `f32` — then CRC-32 (IEEE) of the preceding bytes. No field is ever NaN or
//! infinite: [`Record::encode`] refuses such a record, [`Record::decode`] rejects one.
//!
//! Layout v1 (`LEN_V1` = 156 bytes, written before the full `K`) still loads: the same up to the
//! accel offset, then the 1σ of the diagonal of `K` only (3), the six quality fields, the CRC.

use crate::estimators::accel::{AccelCal, AccelModel};
use crate::estimators::bias::TempCo;
use crate::estimators::full::FullCal;
use crate::estimators::gyro::{GyroCal, Method};
use crate::estimators::mag::MagCal;
use crate::{Mat3, Vec3};

/// Record format version written by this code: the board frame.
pub const VERSION: u8 = 6;
/// Encoded length (bytes) of a version-5 or -6 record (the longest a reader needs).
pub const LEN: usize = 320;
/// Encoded length (bytes) of a version-4 record.
pub const LEN_V4: usize = 236;
/// Encoded length (bytes) of a version-3 record.
pub const LEN_V3: usize = 232;
/// Encoded length (bytes) of a version-2 record.
pub const LEN_V2: usize = 188;
/// Encoded length (bytes) of a version-1 record.
pub const LEN_V1: usize = 156;
const MAGIC: [u8; 4] = *b"GYRC";
/// `f32` fields of the magnetometer's part (v5).
const MAG_F32S: usize = 20;

/// Why bytes are not a valid record.
#[allow(missing_docs)] // variant fields are named with their units
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecodeError {
    /// Fewer bytes than the format needs.
    Truncated { len: u16, need: u16 },
    /// Not a record (erased flash reads 0xFF).
    BadMagic,
    /// A format version this firmware does not know, or one of 1–5 (the part's raw axes, not
    /// the board frame) where calib-core's `older-records` feature is off (the firmware): kept
    /// in flash, not applied.
    UnsupportedVersion(u8),
    /// The checksum does not match: torn write or corruption.
    BadCrc { stored: u32, computed: u32 },
    /// A field is NaN/infinite or beyond what a part can have, or an enum value is unknown.
    InvalidField,
}

/// Why a record could not be stored (the shell's storage reports it to the procedure).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreError {
    /// The flash driver failed (erase, write or read).
    Flash,
    /// The record read back differs from the one written.
    Verify,
    /// The storage region is too small for two record pages.
    RegionTooSmall,
    /// No storage to write to (the region may belong to the bootloader, or it failed at boot).
    Unavailable,
    /// The record holds a NaN or an infinite number ([`NotFinite`]): not written.
    NotFinite,
}

/// A record holding a NaN, an infinite number or a value beyond what a part can have
/// ([`Record::check_finite`]): never encoded, stored, applied or exported.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NotFinite;

impl core::fmt::Display for NotFinite {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("a field of the record is NaN, infinite or beyond what a part can have")
    }
}

/// Flags bit: the temperature is unknown.
const TEMP_UNKNOWN: u16 = 1;
/// Flags bit: the bias's temperature coefficient is unknown.
const TEMPCO_UNKNOWN: u16 = 2;
/// Flags bit: there is no magnetometer calibration.
const MAG_UNKNOWN: u16 = 4;

/// The part a calibration was made with. `K`, `b`, `M` and `o` are in the board frame
/// ([`crate::board`]), in the part's datasheet units (nothing else applied).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "lowercase"))]
pub enum Sensor {
    /// ST LSM9DS1 (Nano 33 BLE Rev1).
    #[default]
    Lsm9ds1,
    /// Bosch BMI270 (Rev2), read raw: its factory z→x cross-axis trim GYR_CAS is not applied
    /// (Bosch's API subtracts `gyr_cas · z / 512` from x; [`crate::estimators::frame`] gives the `K` for such
    /// data).
    Bmi270 {
        /// GYR_CAS (7-bit two's complement, −64..63; counts per 512 counts of z).
        gyr_cas: i8,
        /// The gyro user gain (GYR_USR_GAIN, set by the part's CRT) was enabled (0x77 bit 7):
        /// the raw data then holds it, and a `K` made without it does not apply.
        user_gain: bool,
    },
}

impl Sensor {
    /// The part's name.
    pub fn name(self) -> &'static str {
        match self {
            Sensor::Lsm9ds1 => "LSM9DS1",
            Sensor::Bmi270 { .. } => "BMI270",
        }
    }
}

/// The sensor settings a calibration was made at: a `K` holds for its part, full scale and ODR.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct SensorSetup {
    /// Output data rate (Hz).
    pub odr_hz: f32,
    /// Gyro full scale (°/s).
    pub gyro_range_dps: f32,
    /// Accelerometer full scale (g).
    pub accel_range_g: f32,
    /// The part (an LSM9DS1 where a log or a JSON line does not say).
    #[cfg_attr(feature = "serde", serde(default))]
    pub sensor: Sensor,
}

impl SensorSetup {
    /// The firmware's default (LSM9DS1 at 119 Hz, ±500 °/s, ±2 g): the only setup of the
    /// firmware that wrote version-1 and -2 records.
    pub const DEFAULT: SensorSetup = SensorSetup { odr_hz: 119.0, gyro_range_dps: 500.0, accel_range_g: 2.0, sensor: Sensor::Lsm9ds1 };
    /// What Arduino's Arduino_LSM9DS1 library sets in `IMU.begin()` (CTRL_REG1_G 0x78,
    /// CTRL_REG6_XL 0x70): 119 Hz, ±2000 °/s, ±4 g.
    pub const ARDUINO_LSM9DS1: SensorSetup = SensorSetup { odr_hz: 119.0, gyro_range_dps: 2000.0, accel_range_g: 4.0, ..Self::DEFAULT };
}

impl core::fmt::Display for StoreError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            StoreError::Flash => "the flash could not be erased, written or read",
            StoreError::Verify => "the record read back differs from the one written",
            StoreError::RegionTooSmall => "the storage region is smaller than two pages",
            StoreError::Unavailable => "no storage available",
            StoreError::NotFinite => "the record holds a NaN, an infinite number or a value beyond what a part can have",
        })
    }
}

/// Everything a calibration stores and applies.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Record {
    /// Increases by one with every stored calibration.
    pub seq: u32,
    /// Mean sensor temperature during the calibration (°C); `None`: no reading (a log has none).
    pub temp_c: Option<f32>,
    /// Gyro scale matrix `K` (`ω = K (g − b)`).
    pub gyro_k: Mat3,
    /// Gyro bias `b` (°/s): at `temp_c` when the tempco is known, else the latest of the
    /// calibration (the rests' line at its end).
    pub gyro_bias_dps: Vec3,
    /// Estimator that produced `K`.
    pub method: Method,
    /// Accelerometer calibration (`f = M (a − o)`).
    pub accel_m: Mat3,
    /// Accelerometer offset `o` (g).
    pub accel_offset_g: Vec3,
    /// Accelerometer model.
    pub accel_model: AccelModel,
    /// Static poses used by the gyro estimator.
    pub poses: u8,
    /// Least-squares rows used by the gyro estimator.
    pub rows: u16,
    /// 1σ of every element of `K` (row-major; a diagonal estimator's off-diagonal is 0).
    pub sigma_k: Mat3,
    /// Relative spread (std / |mean|) of the invariant before calibration (one-axis
    /// estimators; 0 for the full `K`).
    pub invariant_before_rel: f32,
    /// Relative spread of the invariant after calibration (one-axis; 0 for the full `K`).
    pub invariant_after_rel: f32,
    /// Condition number of the gyro normal matrix.
    pub condition: f32,
    /// Rotation-axis tilt from vertical (°; one-axis; for the full `K` the smallest over its axes).
    pub tilt_deg: f32,
    /// Pose span (°; one-axis; 0 for the full `K`).
    pub span_deg: f32,
    /// Accelerometer residual RMS after calibration (g).
    pub accel_rms_g: f32,
    /// RMS residual of the gyro fit (° for sweeps and the full `K`, dimensionless for the paper's).
    pub residual_rms: f32,
    /// Angle (°) of the full `K`'s axes from coplanar (0 for one axis; 0 in version-1 records).
    pub non_coplanar_deg: f32,
    /// The sensor settings it was made at.
    pub setup: SensorSetup,
    /// The gyro bias's temperature coefficient; `None`: unknown (too little temperature span,
    /// no temperature, or a record older than version 3).
    pub tempco: Option<TempCo>,
    /// The magnetometer's calibration (µT, in the frame of `accel_m`); `None`: none (no
    /// magnetometer read, a pan/tilt run, or a record older than version 5).
    pub mag: Option<MagCal>,
}

/// What a record holds beside the gyro result.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Context {
    /// Sequence number of the record (the stored one's + 1; 0 for a record never stored).
    pub seq: u32,
    /// Mean sensor temperature during the calibration (°C), if any was read.
    pub temp_c: Option<f32>,
    /// Gyro bias (°/s).
    pub gyro_bias_dps: Vec3,
    /// The accelerometer calibration the gyro result was made in.
    pub accel: AccelCal,
    /// The sensor settings.
    pub setup: SensorSetup,
    /// The gyro bias's temperature coefficient, if the calibration determined it.
    pub tempco: Option<TempCo>,
    /// The magnetometer's calibration, if one was made (or reused with the accelerometer's).
    pub mag: Option<MagCal>,
}

impl Context {
    /// The record with no gyro result yet: `K = 0`, every gyro quality field 0.
    fn base(&self) -> Record {
        Record {
            seq: self.seq,
            temp_c: self.temp_c,
            gyro_k: [[0.0; 3]; 3],
            gyro_bias_dps: self.gyro_bias_dps,
            method: Method::Sweep,
            accel_m: self.accel.m,
            accel_offset_g: self.accel.offset_g,
            accel_model: self.accel.model,
            poses: 0,
            rows: 0,
            sigma_k: [[0.0; 3]; 3],
            invariant_before_rel: 0.0,
            invariant_after_rel: 0.0,
            condition: 0.0,
            tilt_deg: 0.0,
            span_deg: 0.0,
            accel_rms_g: self.accel.rms_after_g,
            residual_rms: 0.0,
            non_coplanar_deg: 0.0,
            setup: self.setup,
            tempco: self.tempco,
            mag: self.mag,
        }
    }

    /// The record of a one-axis estimator's (diagonal) result.
    pub fn one_axis(&self, cal: &GyroCal) -> Record {
        let (q, s) = (&cal.quality, cal.quality.sigma_k);
        Record {
            gyro_k: cal.k,
            method: cal.method,
            sigma_k: [[s[0], 0.0, 0.0], [0.0, s[1], 0.0], [0.0, 0.0, s[2]]],
            poses: q.poses,
            rows: q.rows,
            invariant_before_rel: q.invariant_before.relative_std(),
            invariant_after_rel: q.invariant_after.relative_std(),
            condition: q.condition,
            tilt_deg: q.tilt_deg,
            span_deg: q.span_deg,
            residual_rms: q.residual_rms,
            ..self.base()
        }
    }

    /// The record of a full `K`, made from `poses` distinct static poses; its tilt is the smallest
    /// of the axes it used (0 if none turned).
    pub fn full(&self, full: &FullCal, poses: u8) -> Record {
        let tilt_deg = full.axes.iter().filter(|a| a.moves > 0).map(|a| a.tilt_deg).reduce(f32::min).unwrap_or(0.0);
        Record {
            gyro_k: full.k,
            method: Method::Full,
            sigma_k: full.sigma_k,
            poses,
            rows: full.rows,
            condition: full.condition,
            tilt_deg,
            residual_rms: full.residual_rms_deg,
            non_coplanar_deg: full.non_coplanar_deg,
            ..self.base()
        }
    }
}

impl Record {
    /// The accelerometer part as a calibration to apply.
    pub fn accel(&self) -> AccelCal {
        AccelCal {
            m: self.accel_m,
            offset_g: self.accel_offset_g,
            model: self.accel_model,
            rms_after_g: self.accel_rms_g,
            ..AccelCal::IDENTITY
        }
    }

    /// Calibrated rate `K (g − b)` (°/s) from a raw gyro reading (°/s).
    pub fn apply_gyro(&self, g: Vec3) -> Vec3 {
        let d = [g[0] - self.gyro_bias_dps[0], g[1] - self.gyro_bias_dps[1], g[2] - self.gyro_bias_dps[2]];
        core::array::from_fn(|i| self.gyro_k[i][0] * d[0] + self.gyro_k[i][1] * d[1] + self.gyro_k[i][2] * d[2])
    }

    /// Every `f32` field (the temperature and the tempco if known) is finite, and the fields
    /// applied to readings are within what a part can have ([`Record::plausible`]): what is
    /// stored is what loads.
    pub fn check_finite(&self) -> Result<(), NotFinite> {
        let tempco = self.tempco_f32s();
        let scalars = [
            self.temp_c.unwrap_or(0.0),
            self.invariant_before_rel,
            self.invariant_after_rel,
            self.condition,
            self.tilt_deg,
            self.span_deg,
            self.accel_rms_g,
            self.residual_rms,
            self.non_coplanar_deg,
            self.setup.odr_hz,
            self.setup.gyro_range_dps,
            self.setup.accel_range_g,
        ];
        let mag = self.mag_f32s();
        let all = [
            self.gyro_k.as_flattened(),
            &self.gyro_bias_dps,
            self.accel_m.as_flattened(),
            &self.accel_offset_g,
            self.sigma_k.as_flattened(),
            &scalars,
            &tempco,
            &mag,
        ];
        if all.iter().all(|s| s.iter().all(|v| v.is_finite())) && self.plausible() {
            Ok(())
        } else {
            Err(NotFinite)
        }
    }

    /// The tempco's fields as stored: `c`, its 1σ, the temperature range (zeros when unknown).
    fn tempco_f32s(&self) -> [f32; 8] {
        let mut v = [0.0; 8];
        if let Some(t) = self.tempco {
            v[..3].copy_from_slice(&t.dps_per_c);
            v[3..6].copy_from_slice(&t.sigma_dps_per_c);
            v[6..].copy_from_slice(&t.range_c);
        }
        v
    }

    /// The magnetometer's `f32` fields as stored (zeros when there is none).
    fn mag_f32s(&self) -> [f32; MAG_F32S] {
        let mut v = [0.0; MAG_F32S];
        if let Some(m) = &self.mag {
            v[..9].copy_from_slice(m.a.as_flattened());
            v[9..12].copy_from_slice(&m.offset_ut);
            v[12..].copy_from_slice(&[
                m.field_ut,
                m.sigma_field_ut,
                m.dip_deg,
                m.sigma_dip_deg,
                m.alignment_deg,
                m.sigma_alignment_deg,
                m.residual_ut,
                m.coverage,
            ]);
        }
        v
    }

    /// Encodes to the version-5 layout; a record with a NaN, infinite or implausible field is
    /// refused ([`Record::check_finite`]).
    pub fn encode(&self) -> Result<[u8; LEN], NotFinite> {
        self.check_finite()?;
        let mut w = Writer { buf: [0; LEN], at: 0 };
        w.bytes(&MAGIC);
        w.bytes(&[
            VERSION,
            match self.method {
                Method::Paper => 0,
                Method::Sweep => 1,
                Method::Full => 2,
            },
            match self.accel_model {
                AccelModel::None => 0,
                AccelModel::SixParam => 1,
                AccelModel::NineParam => 2,
            },
            self.poses,
        ]);
        w.bytes(&self.seq.to_le_bytes());
        w.bytes(&self.rows.to_le_bytes());
        let flags = if self.temp_c.is_none() { TEMP_UNKNOWN } else { 0 }
            | if self.tempco.is_none() { TEMPCO_UNKNOWN } else { 0 }
            | if self.mag.is_none() { MAG_UNKNOWN } else { 0 };
        w.bytes(&flags.to_le_bytes());
        w.f32s(&[self.temp_c.unwrap_or(0.0)]);
        w.f32s(self.gyro_k.as_flattened());
        w.f32s(&self.gyro_bias_dps);
        w.f32s(self.accel_m.as_flattened());
        w.f32s(&self.accel_offset_g);
        w.f32s(self.sigma_k.as_flattened());
        w.f32s(&[self.invariant_before_rel, self.invariant_after_rel, self.condition, self.tilt_deg, self.span_deg, self.accel_rms_g]);
        w.f32s(&[self.residual_rms, self.non_coplanar_deg]);
        w.f32s(&[self.setup.odr_hz, self.setup.gyro_range_dps, self.setup.accel_range_g]);
        w.f32s(&self.tempco_f32s());
        w.bytes(&match self.setup.sensor {
            Sensor::Lsm9ds1 => [0, 0, 0, 0],
            Sensor::Bmi270 { gyr_cas, user_gain } => [1, gyr_cas as u8, u8::from(user_gain), 0],
        });
        w.f32s(&self.mag_f32s());
        let (samples, poses) = self.mag.map_or((0, 0), |m| (m.samples, m.poses));
        w.bytes(&samples.to_le_bytes());
        w.bytes(&[poses, 0]);
        let crc = crc32(&w.buf[..LEN - 4]);
        w.bytes(&crc.to_le_bytes());
        Ok(w.buf)
    }

    /// Decodes and validates bytes of a version-5, -4, -3, -2 or -1 record (extra bytes after the
    /// record are ignored).
    pub fn decode(bytes: &[u8]) -> Result<Record, DecodeError> {
        let truncated = |need: usize| DecodeError::Truncated { len: bytes.len().min(u16::MAX as usize) as u16, need: need as u16 };
        if bytes.len() < 5 {
            return Err(truncated(5));
        }
        if bytes[..4] != MAGIC {
            return Err(DecodeError::BadMagic);
        }
        let len = match bytes[4] {
            1 => LEN_V1,
            2 => LEN_V2,
            3 => LEN_V3,
            4 => LEN_V4,
            5 | 6 => LEN,
            v => return Err(DecodeError::UnsupportedVersion(v)),
        };
        if bytes.len() < len {
            return Err(truncated(len));
        }
        let b = &bytes[..len];
        let stored = u32::from_le_bytes([b[len - 4], b[len - 3], b[len - 2], b[len - 1]]);
        let computed = crc32(&b[..len - 4]);
        if stored != computed {
            return Err(DecodeError::BadCrc { stored, computed });
        }
        // Without the conversion (the firmware) only this version's layout is read: the older
        // layouts' code is not linked.
        #[cfg(not(feature = "older-records"))]
        let len = match bytes[4] {
            VERSION => LEN,
            v => return Err(DecodeError::UnsupportedVersion(v)),
        };
        let method = match b[5] {
            0 => Method::Paper,
            1 => Method::Sweep,
            2 => Method::Full,
            _ => return Err(DecodeError::InvalidField),
        };
        let accel_model = match b[6] {
            0 => AccelModel::None,
            1 => AccelModel::SixParam,
            2 => AccelModel::NineParam,
            _ => return Err(DecodeError::InvalidField),
        };
        let flags = u16::from_le_bytes([b[14], b[15]]);
        let known = match len {
            LEN => TEMP_UNKNOWN | TEMPCO_UNKNOWN | MAG_UNKNOWN,
            LEN_V3 | LEN_V4 => TEMP_UNKNOWN | TEMPCO_UNKNOWN,
            _ => TEMP_UNKNOWN,
        };
        if flags & !known != 0 {
            return Err(DecodeError::InvalidField);
        }
        let mut r = Reader { buf: b, at: 16, all_finite: true };
        let temp_c = Some(r.f32()).filter(|_| flags & TEMP_UNKNOWN == 0);
        let gyro_k = r.mat3();
        let gyro_bias_dps = r.vec3();
        let accel_m = r.mat3();
        let accel_offset_g = r.vec3();
        let sigma_k = if len >= LEN_V2 {
            r.mat3()
        } else {
            let d = r.vec3();
            [[d[0], 0.0, 0.0], [0.0, d[1], 0.0], [0.0, 0.0, d[2]]]
        };
        let mut rec = Record {
            seq: u32::from_le_bytes([b[8], b[9], b[10], b[11]]),
            temp_c,
            gyro_k,
            gyro_bias_dps,
            method,
            accel_m,
            accel_offset_g,
            accel_model,
            poses: b[7],
            rows: u16::from_le_bytes([b[12], b[13]]),
            sigma_k,
            invariant_before_rel: r.f32(),
            invariant_after_rel: r.f32(),
            condition: r.f32(),
            tilt_deg: r.f32(),
            span_deg: r.f32(),
            accel_rms_g: r.f32(),
            residual_rms: 0.0,
            non_coplanar_deg: 0.0,
            setup: SensorSetup::DEFAULT,
            tempco: None,
            mag: None,
        };
        if len >= LEN_V2 {
            rec.residual_rms = r.f32();
            rec.non_coplanar_deg = r.f32();
        }
        if len >= LEN_V3 {
            rec.setup = SensorSetup { odr_hz: r.f32(), gyro_range_dps: r.f32(), accel_range_g: r.f32(), sensor: Sensor::Lsm9ds1 };
            let (c, sigma, range) = (r.vec3(), r.vec3(), [r.f32(), r.f32()]);
            if flags & TEMPCO_UNKNOWN == 0 {
                rec.tempco = Some(TempCo { dps_per_c: c, sigma_dps_per_c: sigma, range_c: range });
            }
        }
        if len >= LEN_V4 {
            rec.setup.sensor = match b[LEN_V3 - 4..LEN_V4 - 4] {
                [0, 0, 0, 0] => Sensor::Lsm9ds1,
                [1, cas, f, 0] if (-64..64).contains(&(cas as i8)) && f & !1 == 0 => {
                    Sensor::Bmi270 { gyr_cas: cas as i8, user_gain: f == 1 }
                }
                _ => return Err(DecodeError::InvalidField),
            };
        }
        if len == LEN {
            r.at = LEN_V4 - 4;
            let (a, offset_ut) = (r.mat3(), r.vec3());
            let q: [f32; 8] = core::array::from_fn(|_| r.f32());
            let (samples, poses) = (u16::from_le_bytes([b[LEN - 8], b[LEN - 7]]), b[LEN - 6]);
            if b[LEN - 5] != 0 {
                return Err(DecodeError::InvalidField);
            }
            if flags & MAG_UNKNOWN == 0 {
                let [field_ut, sigma_field_ut, dip_deg, sigma_dip_deg, alignment_deg, sigma_alignment_deg, residual_ut, coverage] = q;
                #[rustfmt::skip]
                let m = MagCal { a, offset_ut, field_ut, sigma_field_ut, dip_deg, sigma_dip_deg, alignment_deg, sigma_alignment_deg, residual_ut, coverage, samples, poses };
                rec.mag = Some(m);
            } else if a.as_flattened().iter().chain(&offset_ut).chain(&q).any(|v| *v != 0.0) || samples != 0 || poses != 0 {
                return Err(DecodeError::InvalidField);
            }
        }
        let rec = match bytes[4] {
            VERSION => rec,
            #[cfg(feature = "older-records")]
            _ => rec.from_part_axes(),
            #[cfg(not(feature = "older-records"))]
            v => return Err(DecodeError::UnsupportedVersion(v)),
        };
        if !r.all_finite || rec.check_finite().is_err() {
            return Err(DecodeError::InvalidField);
        }
        Ok(rec)
    }

    /// Whether the fields applied to readings are within what a part can have (far wider than
    /// any acceptance, so that only a crafted or corrupted record with a right CRC fails): `K`
    /// and `M` within 0.5 of the identity, the gyro bias within 4000 °/s and its tempco within
    /// 1 °/s/°C, the accelerometer's offset within 32 g, the temperature within −60..150 °C, the
    /// magnetometer's `A` within 10 and its offset within 5000 µT, the setup's rate within
    /// 0..10 kHz and its ranges within 0..4000 °/s and 0..32 g. Readings within a full scale then
    /// stay finite through every correction (a fuzzed `K` of 3.4e38 gave infinite rates).
    pub fn plausible(&self) -> bool {
        let near_identity = |m: &Mat3| (0..9).all(|i| (m[i / 3][i % 3] - if i % 4 == 0 { 1.0 } else { 0.0 }).abs() <= 0.5);
        let within = |v: &[f32], limit: f32| v.iter().all(|x| x.abs() <= limit);
        let s = &self.setup;
        near_identity(&self.gyro_k)
            && near_identity(&self.accel_m)
            && within(&self.gyro_bias_dps, 4000.0)
            && within(&self.accel_offset_g, 32.0)
            && self.temp_c.is_none_or(|t| (-60.0..=150.0).contains(&t))
            && self.tempco.is_none_or(|c| within(&c.dps_per_c, 1.0))
            && self.mag.is_none_or(|m| within(m.a.as_flattened(), 10.0) && within(&m.offset_ut, 5000.0))
            && s.odr_hz > 0.0
            && s.odr_hz <= 10_000.0
            && s.gyro_range_dps > 0.0
            && s.gyro_range_dps <= 4000.0
            && s.accel_range_g > 0.0
            && s.accel_range_g <= 32.0
    }
}

struct Writer {
    buf: [u8; LEN],
    at: usize,
}

impl Writer {
    fn bytes(&mut self, b: &[u8]) {
        self.buf[self.at..self.at + b.len()].copy_from_slice(b);
        self.at += b.len();
    }

    fn f32s(&mut self, v: &[f32]) {
        for x in v {
            self.bytes(&x.to_le_bytes());
        }
    }
}

struct Reader<'a> {
    buf: &'a [u8],
    at: usize,
    all_finite: bool,
}

impl Reader<'_> {
    fn f32(&mut self) -> f32 {
        let b = &self.buf[self.at..self.at + 4];
        self.at += 4;
        let v = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        self.all_finite &= v.is_finite();
        v
    }

    fn vec3(&mut self) -> Vec3 {
        [self.f32(), self.f32(), self.f32()]
    }

    fn mat3(&mut self) -> Mat3 {
        [self.vec3(), self.vec3(), self.vec3()]
    }
}

/// CRC-32 (IEEE 802.3, reflected, init and final XOR 0xFFFFFFFF), bitwise: no table in flash.
pub fn crc32(data: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &byte in data {
        crc ^= byte as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn sample() -> Record {
        Record {
            seq: 7,
            temp_c: Some(24.5),
            gyro_k: [[1.01, 0.0, 0.0], [0.0, 0.99, 0.0], [0.0, 0.0, 1.02]],
            gyro_bias_dps: [0.5, -1.25, 2.0],
            method: Method::Sweep,
            accel_m: [[1.001, 0.002, 0.0], [0.0, 0.998, -0.001], [0.0, 0.0, 1.003]],
            accel_offset_g: [0.01, -0.02, 0.015],
            accel_model: AccelModel::NineParam,
            poses: 13,
            rows: 12,
            sigma_k: [[1e-4, 3e-5, 0.0], [0.0, 2e-4, 0.0], [0.0, 0.0, 1.5e-4]],
            invariant_before_rel: 0.02,
            invariant_after_rel: 0.001,
            condition: 3.5,
            tilt_deg: 45.0,
            span_deg: 180.0,
            accel_rms_g: 0.0004,
            residual_rms: 0.02,
            non_coplanar_deg: 54.0,
            setup: SensorSetup::DEFAULT,
            tempco: Some(TempCo { dps_per_c: [0.03, -0.045, 0.01], sigma_dps_per_c: [0.002, 0.003, 0.0025], range_c: [24.0, 27.5] }),
            mag: Some(MagCal {
                a: [[1.02, 0.01, -0.02], [0.0, 0.97, 0.015], [0.02, -0.01, 1.01]],
                offset_ut: [12.5, -30.25, 4.0],
                field_ut: 48.5,
                sigma_field_ut: 0.125,
                dip_deg: 61.25,
                sigma_dip_deg: 0.0625,
                alignment_deg: 1.5,
                sigma_alignment_deg: 0.03125,
                residual_ut: 0.25,
                coverage: 0.85,
                samples: 140,
                poses: 12,
            }),
        }
    }

    /// `sample()` as a record older than version 5 loads it: no magnetometer.
    fn without_mag() -> Record {
        Record { mag: None, ..sample() }
    }

    #[test]
    fn crc32_check_value() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn round_trip_and_distinct_errors() {
        let r = sample();
        let bytes = r.encode().unwrap();
        assert_eq!(Record::decode(&bytes), Ok(r));
        assert!(matches!(Record::decode(&bytes[..100]), Err(DecodeError::Truncated { len: 100, need: 320 })));
        assert_eq!(Record::decode(&[0xFF; LEN]), Err(DecodeError::BadMagic));
        let mut v = bytes;
        v[4] = 7;
        assert_eq!(Record::decode(&v), Err(DecodeError::UnsupportedVersion(7)));
        let mut c = bytes;
        c[40] ^= 0x10;
        assert!(matches!(Record::decode(&c), Err(DecodeError::BadCrc { .. })));
    }

    /// `sample()` with a diagonal 1σ, as the version-1 encoder of the release before the full
    /// `K` (commit 2cb7b1f) wrote it.
    const GOLDEN_V1: &str = "475952430101020d070000000c0000000000c441ae47813f000000000000000000000000a4707d3f0000000000000000000000005c8f823f0000003f0000a0bf00000040c520803f6f12033b0000000000000000ee7c7f3f6f1283ba00000000000000004e62803f0ad7233c0ad7a3bc8fc2753c17b7d13817b7513952491d390ad7a33c6f12833a00006040000034420000344317b7d139c2c3aaa0";

    #[test]
    fn version_1_records_still_load_with_their_diagonal_sigma() {
        let mut v1 = [0xFFu8; LEN];
        for i in 0..LEN_V1 {
            v1[i] = u8::from_str_radix(&GOLDEN_V1[2 * i..2 * i + 2], 16).unwrap();
        }
        let sigma_k = [[1e-4, 0.0, 0.0], [0.0, 2e-4, 0.0], [0.0, 0.0, 1.5e-4]];
        assert_eq!(
            Record::decode(&v1),
            Ok(Record { sigma_k, residual_rms: 0.0, non_coplanar_deg: 0.0, tempco: None, ..without_mag() }.from_part_axes())
        );
        assert!(matches!(Record::decode(&v1[..150]), Err(DecodeError::Truncated { len: 150, need: 156 })));
        let mut torn = v1;
        torn[120] ^= 1;
        assert!(matches!(Record::decode(&torn), Err(DecodeError::BadCrc { .. })));
    }

    /// `sample()` without a tempco, as the version-2 encoder of the release before the tempco
    /// (commit 7bcd77a) wrote it.
    const GOLDEN_V2: &str = "475952430201020d070000000c0000000000c441ae47813f000000000000000000000000a4707d3f0000000000000000000000005c8f823f0000003f0000a0bf00000040c520803f6f12033b0000000000000000ee7c7f3f6f1283ba00000000000000004e62803f0ad7233c0ad7a3bc8fc2753c17b7d13882a8fb37000000000000000017b7513900000000000000000000000052491d390ad7a33c6f12833a00006040000034420000344317b7d1390ad7a33c000058421245c1de";

    #[test]
    fn version_2_records_still_load_at_the_default_setup_with_an_unknown_tempco() {
        let mut v2 = [0xFFu8; LEN];
        for i in 0..LEN_V2 {
            v2[i] = u8::from_str_radix(&GOLDEN_V2[2 * i..2 * i + 2], 16).unwrap();
        }
        assert_eq!(Record::decode(&v2), Ok(Record { tempco: None, ..without_mag() }.from_part_axes()));
        assert!(matches!(Record::decode(&v2[..180]), Err(DecodeError::Truncated { len: 180, need: 188 })));
        // Bit 1 (tempco unknown) is not a v2 flag.
        let mut flagged = v2;
        flagged[14] |= 0b10;
        let crc = crc32(&flagged[..LEN_V2 - 4]);
        flagged[LEN_V2 - 4..LEN_V2].copy_from_slice(&crc.to_le_bytes());
        assert_eq!(Record::decode(&flagged), Err(DecodeError::InvalidField));
    }

    #[test]
    fn an_unknown_tempco_round_trips_as_unknown_and_a_known_one_must_be_finite() {
        let r = Record { tempco: None, ..sample() };
        let bytes = r.encode().unwrap();
        assert_eq!((bytes[14], &bytes[200..228]), (0b10, &[0u8; 28][..]), "flag set, tempco zeros");
        assert_eq!(Record::decode(&bytes), Ok(r));
        let setup = SensorSetup { odr_hz: 952.0, gyro_range_dps: 2000.0, accel_range_g: 4.0, sensor: Sensor::Lsm9ds1 };
        let r = Record { setup, ..sample() };
        assert_eq!(Record::decode(&r.encode().unwrap()), Ok(r));
        let mut t = sample();
        if let Some(c) = t.tempco.as_mut() {
            c.sigma_dps_per_c[1] = f32::INFINITY;
        }
        assert_eq!(t.encode(), Err(NotFinite));
    }

    /// `bytes` with its CRC made good again.
    fn re_crc(mut bytes: [u8; LEN]) -> [u8; LEN] {
        let crc = crc32(&bytes[..LEN - 4]);
        bytes[LEN - 4..].copy_from_slice(&crc.to_le_bytes());
        bytes
    }

    #[test]
    fn a_non_finite_field_is_never_encoded_and_never_decoded_even_with_a_good_crc() {
        for poke in [
            |r: &mut Record| r.gyro_k[1][1] = f32::NAN,
            |r: &mut Record| r.tilt_deg = f32::INFINITY,
            |r: &mut Record| r.temp_c = Some(f32::NAN),
        ] {
            let mut r = sample();
            poke(&mut r);
            assert_eq!(r.encode(), Err(NotFinite), "{r:?}");
        }
        // K[1][1] (offset 20 + 4·4) written as NaN by something else, CRC good.
        let mut bytes = sample().encode().unwrap();
        bytes[36..40].copy_from_slice(&f32::NAN.to_le_bytes());
        assert_eq!(Record::decode(&re_crc(bytes)), Err(DecodeError::InvalidField));
    }

    #[test]
    fn a_finite_field_beyond_what_a_part_can_have_is_never_decoded() {
        // Found by the record fuzz target (host-tests/fuzz): K[0][1] = 3.4e38 with a good CRC
        // loaded, and turned every reading into an infinite rate.
        for (at, v) in [(24, f32::MAX), (20, 1.6), (56, 4001.0), (72, 0.6), (16, 151.0)] {
            let mut bytes = sample().encode().unwrap();
            bytes[at..at + 4].copy_from_slice(&v.to_le_bytes());
            assert_eq!(Record::decode(&re_crc(bytes)), Err(DecodeError::InvalidField), "{v} at {at}");
        }
        let mut bytes = sample().encode().unwrap();
        bytes[20..24].copy_from_slice(&1.4f32.to_le_bytes());
        assert!(Record::decode(&re_crc(bytes)).is_ok(), "a K of 1.4 is a part's");
    }

    #[test]
    fn an_unknown_temperature_is_encoded_as_unknown_and_unknown_flags_are_invalid() {
        let r = Record { temp_c: None, ..sample() };
        let bytes = r.encode().unwrap();
        assert_eq!((bytes[14], &bytes[16..20]), (1, &[0u8; 4][..]), "flag set, temperature 0");
        assert_eq!(Record::decode(&bytes), Ok(r));
        let mut other = bytes;
        other[14] = 0b1000;
        assert_eq!(Record::decode(&re_crc(other)), Err(DecodeError::InvalidField));
    }

    /// `sample()` as the version-3 encoder of the release before the Rev2's sensor field (commit
    /// 4c8113f) wrote it.
    const GOLDEN_V3: &str = "475952430301020d070000000c0000000000c441ae47813f000000000000000000000000a4707d3f0000000000000000000000005c8f823f0000003f0000a0bf00000040c520803f6f12033b0000000000000000ee7c7f3f6f1283ba00000000000000004e62803f0ad7233c0ad7a3bc8fc2753c17b7d13882a8fb37000000000000000017b7513900000000000000000000000052491d390ad7a33c6f12833a00006040000034420000344317b7d1390ad7a33c000058420000ee420000fa43000000408fc2f53cec5138bd0ad7233c6f12033ba69b443b0ad7233b0000c0410000dc4116b84922";

    #[test]
    fn version_3_records_still_load_as_an_lsm9ds1_s() {
        let mut v3 = [0xFFu8; LEN];
        for i in 0..LEN_V3 {
            v3[i] = u8::from_str_radix(&GOLDEN_V3[2 * i..2 * i + 2], 16).unwrap();
        }
        assert_eq!(Record::decode(&v3), Ok(without_mag().from_part_axes()));
        assert!(matches!(Record::decode(&v3[..231]), Err(DecodeError::Truncated { len: 231, need: 232 })));
    }

    #[test]
    fn the_part_round_trips_and_a_bad_part_field_is_invalid() {
        for sensor in [Sensor::Bmi270 { gyr_cas: -64, user_gain: true }, Sensor::Bmi270 { gyr_cas: 63, user_gain: false }] {
            let r = Record { setup: SensorSetup { sensor, ..SensorSetup::DEFAULT }, ..sample() };
            let bytes = r.encode().unwrap();
            assert_eq!(bytes[228], 1);
            assert_eq!(Record::decode(&bytes), Ok(r));
        }
        assert_eq!(&sample().encode().unwrap()[228..232], &[0, 0, 0, 0]);
        let bmi =
            Record { setup: SensorSetup { sensor: Sensor::Bmi270 { gyr_cas: 5, user_gain: false }, ..SensorSetup::DEFAULT }, ..sample() };
        // An unknown part, a CAS beyond 7 bits, an unknown flag, a reserved byte, an LSM9DS1 with a CAS.
        for (at, v) in [(228, 2u8), (229, 64), (229, 0xBF), (230, 2), (231, 1)] {
            let mut bytes = bmi.encode().unwrap();
            bytes[at] = v;
            assert_eq!(Record::decode(&re_crc(bytes)), Err(DecodeError::InvalidField), "byte {at} = {v}");
        }
        let mut lsm = sample().encode().unwrap();
        lsm[229] = 3;
        assert_eq!(Record::decode(&re_crc(lsm)), Err(DecodeError::InvalidField));
    }

    /// `sample()` made with a BMI270 (GYR_CAS −5, user gain on), as the version-4 encoder of the
    /// release before the magnetometer (commit b73f472) wrote it.
    const GOLDEN_V4: &str = "475952430401020d070000000c0000000000c441ae47813f000000000000000000000000a4707d3f0000000000000000000000005c8f823f0000003f0000a0bf00000040c520803f6f12033b0000000000000000ee7c7f3f6f1283ba00000000000000004e62803f0ad7233c0ad7a3bc8fc2753c17b7d13882a8fb37000000000000000017b7513900000000000000000000000052491d390ad7a33c6f12833a00006040000034420000344317b7d1390ad7a33c000058420000ee420000fa43000000408fc2f53cec5138bd0ad7233c6f12033ba69b443b0ad7233b0000c0410000dc4101fb0100c4dc2e69";

    #[test]
    fn version_4_records_still_load_without_a_magnetometer() {
        let mut v4 = [0xFFu8; LEN];
        for i in 0..LEN_V4 {
            v4[i] = u8::from_str_radix(&GOLDEN_V4[2 * i..2 * i + 2], 16).unwrap();
        }
        let sensor = Sensor::Bmi270 { gyr_cas: -5, user_gain: true };
        assert_eq!(
            Record::decode(&v4),
            Ok(Record { setup: SensorSetup { sensor, ..SensorSetup::DEFAULT }, ..without_mag() }.from_part_axes())
        );
        assert!(matches!(Record::decode(&v4[..235]), Err(DecodeError::Truncated { len: 235, need: 236 })));
        // Bit 2 (no magnetometer) is not a v4 flag.
        let mut flagged = v4;
        flagged[14] |= 0b100;
        let crc = crc32(&flagged[..LEN_V4 - 4]);
        flagged[LEN_V4 - 4..LEN_V4].copy_from_slice(&crc.to_le_bytes());
        assert_eq!(Record::decode(&flagged), Err(DecodeError::InvalidField));
    }

    #[test]
    fn the_magnetometer_round_trips_known_or_unknown_and_unknown_means_zeros() {
        let bytes = sample().encode().unwrap();
        assert_eq!((bytes[14] & 0b100, bytes[312], bytes[314]), (0, 140, 12), "flag clear, samples, poses");
        let none = without_mag();
        let bytes = none.encode().unwrap();
        assert_eq!((bytes[14], &bytes[232..316]), (0b100, &[0u8; 84][..]), "flag set, magnetometer zeros");
        assert_eq!(Record::decode(&bytes), Ok(none));
        // Unknown yet holding a value, a reserved byte set, a non-finite A: invalid.
        for (at, v) in [(240, 0x3Fu8), (312, 1), (315, 1)] {
            let mut b = bytes;
            b[at] = v;
            assert_eq!(Record::decode(&re_crc(b)), Err(DecodeError::InvalidField), "byte {at} = {v}");
        }
        let mut b = sample().encode().unwrap();
        b[232..236].copy_from_slice(&f32::NAN.to_le_bytes());
        assert_eq!(Record::decode(&re_crc(b)), Err(DecodeError::InvalidField));
        let mut m = sample();
        if let Some(c) = m.mag.as_mut() {
            c.offset_ut[2] = f32::INFINITY;
        }
        assert_eq!(m.encode(), Err(NotFinite));
    }
}
