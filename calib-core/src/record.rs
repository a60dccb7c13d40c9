//! The calibration record stored in flash: a fixed, versioned, little-endian layout with CRC-32.
//!
//! Layout v1 (`LEN` = 156 bytes): magic `GYRC`, version, gyro method, accel model, poses,
//! sequence (u32), rows (u16), reserved (u16), temperature (°C), gyro `K` (9, row-major),
//! gyro bias (3, °/s), accel `M` (9), accel offset (3, g), 1σ of diag `K` (3), invariant
//! relative spread before and after, condition number, axis tilt (°), pose span (°),
//! accel residual (g) — all `f32` — then CRC-32 (IEEE) of the preceding bytes.

use crate::accel::{AccelCal, AccelModel};
use crate::gyro::Method;
use crate::{Mat3, Vec3};

/// Record format version written by this code.
pub const VERSION: u8 = 1;
/// Encoded length (bytes) of a version-1 record.
pub const LEN: usize = 156;
const MAGIC: [u8; 4] = *b"GYRC";

/// Why bytes are not a valid record.
#[allow(missing_docs)] // variant fields are named with their units
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecodeError {
    /// Fewer bytes than the format needs.
    Truncated { len: u16, need: u16 },
    /// Not a record (erased flash reads 0xFF).
    BadMagic,
    /// A format version this firmware does not know.
    UnsupportedVersion(u8),
    /// The checksum does not match: torn write or corruption.
    BadCrc { stored: u32, computed: u32 },
    /// A field is NaN/infinite or an enum value is unknown.
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
}

impl core::fmt::Display for StoreError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            StoreError::Flash => "the flash could not be erased, written or read",
            StoreError::Verify => "the record read back differs from the one written",
            StoreError::RegionTooSmall => "the storage region is smaller than two pages",
            StoreError::Unavailable => "no storage available",
        })
    }
}

/// Everything a calibration stores and applies.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Record {
    /// Increases by one with every stored calibration.
    pub seq: u32,
    /// Sensor temperature during the calibration (°C).
    pub temp_c: f32,
    /// Gyro scale matrix `K` (`ω = K (g − b)`).
    pub gyro_k: Mat3,
    /// Gyro bias `b` (°/s).
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
    /// 1σ of the diagonal of `K`.
    pub sigma_k: Vec3,
    /// Relative spread (std / |mean|) of the invariant before calibration.
    pub invariant_before_rel: f32,
    /// Relative spread of the invariant after calibration.
    pub invariant_after_rel: f32,
    /// Condition number of the gyro normal matrix.
    pub condition: f32,
    /// Rotation-axis tilt from vertical (°).
    pub tilt_deg: f32,
    /// Pose span (°).
    pub span_deg: f32,
    /// Accelerometer residual RMS after calibration (g).
    pub accel_rms_g: f32,
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

    /// Encodes to the version-1 layout.
    pub fn encode(&self) -> [u8; LEN] {
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
        w.bytes(&[0, 0]);
        w.f32s(&[self.temp_c]);
        w.f32s(self.gyro_k.as_flattened());
        w.f32s(&self.gyro_bias_dps);
        w.f32s(self.accel_m.as_flattened());
        w.f32s(&self.accel_offset_g);
        w.f32s(&self.sigma_k);
        w.f32s(&[self.invariant_before_rel, self.invariant_after_rel, self.condition, self.tilt_deg, self.span_deg, self.accel_rms_g]);
        let crc = crc32(&w.buf[..LEN - 4]);
        w.bytes(&crc.to_le_bytes());
        w.buf
    }

    /// Decodes and validates bytes (extra bytes after the record are ignored).
    pub fn decode(bytes: &[u8]) -> Result<Record, DecodeError> {
        let truncated = |need: usize| DecodeError::Truncated { len: bytes.len().min(u16::MAX as usize) as u16, need: need as u16 };
        if bytes.len() < 5 {
            return Err(truncated(5));
        }
        if bytes[..4] != MAGIC {
            return Err(DecodeError::BadMagic);
        }
        if bytes[4] != VERSION {
            return Err(DecodeError::UnsupportedVersion(bytes[4]));
        }
        if bytes.len() < LEN {
            return Err(truncated(LEN));
        }
        let b = &bytes[..LEN];
        let stored = u32::from_le_bytes([b[LEN - 4], b[LEN - 3], b[LEN - 2], b[LEN - 1]]);
        let computed = crc32(&b[..LEN - 4]);
        if stored != computed {
            return Err(DecodeError::BadCrc { stored, computed });
        }
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
        let mut r = Reader { buf: b, at: 16, all_finite: true };
        let temp_c = r.f32();
        let gyro_k = r.mat3();
        let gyro_bias_dps = r.vec3();
        let accel_m = r.mat3();
        let accel_offset_g = r.vec3();
        let sigma_k = r.vec3();
        let rec = Record {
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
        };
        if !r.all_finite {
            return Err(DecodeError::InvalidField);
        }
        Ok(rec)
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
mod tests {
    use super::*;

    pub(crate) fn sample() -> Record {
        Record {
            seq: 7,
            temp_c: 24.5,
            gyro_k: [[1.01, 0.0, 0.0], [0.0, 0.99, 0.0], [0.0, 0.0, 1.02]],
            gyro_bias_dps: [0.5, -1.25, 2.0],
            method: Method::Sweep,
            accel_m: [[1.001, 0.002, 0.0], [0.0, 0.998, -0.001], [0.0, 0.0, 1.003]],
            accel_offset_g: [0.01, -0.02, 0.015],
            accel_model: AccelModel::NineParam,
            poses: 13,
            rows: 12,
            sigma_k: [1e-4, 2e-4, 1.5e-4],
            invariant_before_rel: 0.02,
            invariant_after_rel: 0.001,
            condition: 3.5,
            tilt_deg: 45.0,
            span_deg: 180.0,
            accel_rms_g: 0.0004,
        }
    }

    #[test]
    fn crc32_check_value() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn round_trip_and_distinct_errors() {
        let r = sample();
        let bytes = r.encode();
        assert_eq!(Record::decode(&bytes), Ok(r));
        assert!(matches!(Record::decode(&bytes[..100]), Err(DecodeError::Truncated { len: 100, need: 156 })));
        assert_eq!(Record::decode(&[0xFF; LEN]), Err(DecodeError::BadMagic));
        let mut v = bytes;
        v[4] = 2;
        assert_eq!(Record::decode(&v), Err(DecodeError::UnsupportedVersion(2)));
        let mut c = bytes;
        c[40] ^= 0x10;
        assert!(matches!(Record::decode(&c), Err(DecodeError::BadCrc { .. })));
    }

    #[test]
    fn non_finite_fields_are_invalid_even_with_a_good_crc() {
        let mut r = sample();
        r.gyro_k[1][1] = f32::NAN;
        assert_eq!(Record::decode(&r.encode()), Err(DecodeError::InvalidField));
    }
}
