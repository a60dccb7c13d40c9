//! Bosch BMM150 magnetometer (the Nano 33 BLE Rev2's, at 0x10 on the same internal bus as the
//! BMI270): found as Bosch's BMM150_SensorAPI v2.0.0 does it (every step and its source:
//! `docs/rev2-sources.md` §6), then read: [`Bmm150`] wakes it, reads its trim registers and runs
//! it at the datasheet's high-accuracy preset, compensating every reading with Bosch's
//! floating-point equations (the hall resistance included; `docs/mag-sources.md`).
//!
//! The part powers up in suspend mode, where only POWER_CONTROL (0x4B) answers: CHIP_ID can only
//! be read once 0x4B bit 0 is set (datasheet BST-BMM150-DS001 §5.3), which takes the part to
//! sleep mode after a start-up time (`BMM150_START_UP_TIME`, 3 ms, in Bosch's `bmm150_init`).
//! Clearing the bit brings it back to suspend (datasheet §4.2.3; Bosch's
//! `bmm150_set_op_mode(BMM150_POWERMODE_SUSPEND)`).

use crate::lsm9ds1::BusFault;
use crate::watch::{Shared, Watch};
use calib_core::formats::text::Hex;
use embedded_hal::delay::DelayNs;
use embedded_hal::i2c::I2c;

/// I2C address on the Nano 33 BLE Rev2 (`BMM150_DEFAULT_I2C_ADDRESS`, CSB and SDO low).
pub const ADDR: u8 = 0x10;
/// CHIP_ID of a BMM150 (`BMM150_CHIP_ID`).
pub const CHIP_ID: u8 = 0x32;

/// Register addresses (Bosch's `bmm150_defs.h`).
pub mod reg {
    /// CHIP_ID (read-only; reads 0x00 in suspend mode).
    pub const CHIP_ID: u8 = 0x40;
    /// POWER_CONTROL: bit 0 the power control bit (0 suspend), bits 7 and 1 soft reset, bit 2
    /// SPI 3-wire. The one register that answers in suspend mode.
    pub const POWER_CONTROL: u8 = 0x4B;
    /// OP_MODE: bits 5:3 the data rate, bits 2:1 the operation mode (00 normal, 01 forced,
    /// 11 sleep).
    pub const OP_MODE: u8 = 0x4C;
    /// DATA_X_LSB: x (13 bits), y (13), z (15), RHALL (14 bits; bit 0 of 0x48 data ready): 8
    /// bytes to 0x49.
    pub const DATA: u8 = 0x42;
    /// REP_XY: nXY = 1 + 2 REP_XY.
    pub const REP_XY: u8 = 0x51;
    /// REP_Z: nZ = 1 + REP_Z.
    pub const REP_Z: u8 = 0x52;
    /// DIG_X1, DIG_Y1 (2 bytes).
    pub const DIG_X1: u8 = 0x5D;
    /// DIG_Z4 (2), DIG_X2, DIG_Y2 (4 bytes).
    pub const DIG_Z4: u8 = 0x62;
    /// DIG_Z2 (2), DIG_Z1 (2), DIG_XYZ1 (2), DIG_Z3 (2), DIG_XY2, DIG_XY1 (10 bytes).
    pub const DIG_Z2: u8 = 0x68;
}

/// POWER_CONTROL bit 0: 1 leaves suspend for sleep mode, 0 returns to suspend
/// (`BMM150_PWR_CNTRL_MSK`).
pub const POWER_BIT: u8 = 0x01;
/// POWER_CONTROL bits 7 and 1: both set start a soft reset (`BMM150_SET_SOFT_RESET`). The driver
/// never writes them back, so that its read-modify-writes cannot reset the part.
pub const SOFT_RESET_BITS: u8 = 0x82;
/// From setting the power bit to the first access beyond POWER_CONTROL (ms;
/// `BMM150_START_UP_TIME`, 3000 µs).
pub const START_UP_MS: u32 = 3;

/// The part's trim values (Bosch's `bmm150_trim_registers`), read once at start-up.
#[allow(missing_docs)] // Bosch's names
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Trim {
    pub x1: i8,
    pub y1: i8,
    pub x2: i8,
    pub y2: i8,
    pub z1: u16,
    pub z2: i16,
    pub z3: i16,
    pub z4: i16,
    pub xy1: u8,
    pub xy2: i8,
    /// 15 bits (Bosch masks the high byte with 0x7F).
    pub xyz1: u16,
}

impl Trim {
    /// From the three bursts Bosch's `read_trim_registers` reads: 0x5D (2), 0x62 (4), 0x68 (10).
    pub fn from_bursts(x1y1: [u8; 2], z4x2y2: [u8; 4], b: [u8; 10]) -> Self {
        let le = |l: u8, h: u8| u16::from_le_bytes([l, h]);
        Self {
            x1: x1y1[0] as i8,
            y1: x1y1[1] as i8,
            x2: z4x2y2[2] as i8,
            y2: z4x2y2[3] as i8,
            z4: le(z4x2y2[0], z4x2y2[1]) as i16,
            z2: le(b[0], b[1]) as i16,
            z1: le(b[2], b[3]),
            xyz1: le(b[4], b[5] & 0x7F),
            z3: le(b[6], b[7]) as i16,
            xy2: b[8] as i8,
            xy1: b[9],
        }
    }

    /// The field (µT, the part's axes) from raw x, y (13-bit), z (15-bit) and the hall
    /// resistance: Bosch's floating-point `compensate_x/y/z`. `None` where Bosch returns its
    /// overflow value (an ADC overflow, a zero hall resistance or trim).
    pub fn compensate(&self, x: i16, y: i16, z: i16, rhall: u16) -> Option<[f32; 3]> {
        if x == -4096 || y == -4096 || z == -16384 || rhall == 0 || self.xyz1 == 0 || self.z1 == 0 || self.z2 == 0 {
            return None;
        }
        let r = self.xyz1 as f32 * 16384.0 / rhall as f32 - 16384.0;
        let p = self.xy2 as f32 * (r * r / 268_435_456.0) + r * self.xy1 as f32 / 16384.0 + 256.0;
        let xy = |raw: i16, d1: i8, d2: i8| ((raw as f32 * (p * (d2 as f32 + 160.0)) / 8192.0) + d1 as f32 * 8.0) / 16.0;
        let z0 = z as f32 - self.z4 as f32;
        let z2 = self.z3 as f32 * (rhall as f32 - self.xyz1 as f32);
        let z4 = self.z2 as f32 + self.z1 as f32 * rhall as f32 / 32768.0;
        Some([xy(x, self.x1, self.x2), xy(y, self.y1, self.y2), (z0 * 131072.0 - z2) / (z4 * 4.0) / 16.0])
    }
}

/// The BMM150's settings: repetitions and data rate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config {
    /// REP_XY (nXY = 1 + 2 REP_XY).
    pub rep_xy: u8,
    /// REP_Z (nZ = 1 + REP_Z).
    pub rep_z: u8,
    /// Data-rate code (OP_MODE bits 5:3: 10, 2, 6, 8, 15, 20, 25, 30 Hz).
    pub odr_code: u8,
    /// No new reading for this long (ms) is a stopped part.
    pub stall_ms: u32,
    /// This many new readings in a row with the same counts are a stuck part.
    pub stuck_readings: u16,
}

impl Config {
    /// The datasheet's high-accuracy preset (nXY 47, nZ 83, 20 Hz: 0.3 µT RMS; REP_Z 0x52 as
    /// the datasheet's nZ and Linux's driver, not Bosch's API's 0x29: `docs/mag-sources.md`),
    /// the noise a calibration wants. Stopped after 500 ms (10 periods) without a reading,
    /// stuck after 40 identical ones (2 s).
    pub const HIGH_ACCURACY: Config = Config { rep_xy: 0x17, rep_z: 0x52, odr_code: 0b101, stall_ms: 500, stuck_readings: 40 };
}

/// Why the BMM150 gave no reading.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ReadError {
    /// An I2C transfer failed.
    Bus(BusFault),
    /// Another CHIP_ID at 0x10 (0x00: the part did not leave suspend).
    WrongId(u8),
    /// The trim registers hold a zero where Bosch's compensation divides by them (DIG_XYZ1,
    /// DIG_Z1, DIG_Z2): the part's NVM did not load.
    TrimInvalid,
    /// A register did not keep the value written.
    ConfigMismatch {
        /// Register address.
        reg: u8,
        /// Value written.
        wrote: u8,
        /// Value read back.
        read: u8,
    },
    /// No new reading for `ms` (its limit `limit_ms`).
    Stalled {
        /// Time since the last new reading (ms).
        ms: u32,
        /// The limit (ms).
        limit_ms: u32,
    },
    /// `readings` new readings in a row with the same counts: stuck.
    Stuck {
        /// Identical readings in a row.
        readings: u16,
    },
}

impl core::fmt::Display for ReadError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let shared = match *self {
            ReadError::WrongId(id) => return write!(f, "BMM150: CHIP_ID 0x{} at 0x10 (expected 0x32)", Hex(id.into(), 2)),
            ReadError::TrimInvalid => {
                return f.write_str("BMM150: its trim registers hold zeros (DIG_XYZ1, DIG_Z1 or DIG_Z2): no compensation")
            }
            ReadError::Bus(b) => Shared::Bus(b),
            ReadError::ConfigMismatch { reg, wrote, read } => Shared::ConfigMismatch { reg, wrote, read },
            ReadError::Stalled { ms, limit_ms } => Shared::Stalled { ms, limit_ms },
            ReadError::Stuck { readings } => Shared::Stuck { readings },
        };
        shared.write(f, "BMM150", ADDR)
    }
}

/// The BMM150, measuring. Holds no bus: every call borrows it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Bmm150 {
    cfg: Config,
    trim: Trim,
    watch: Watch,
    /// Readings Bosch's compensation calls overflow (skipped).
    pub overflows: u32,
}

fn bus_err<E: embedded_hal::i2c::Error>(e: E) -> ReadError {
    ReadError::Bus(BusFault::of(e))
}

fn read_n<I: I2c, const N: usize>(i2c: &mut I, r: u8) -> Result<[u8; N], ReadError> {
    let mut b = [0u8; N];
    i2c.write_read(ADDR, &[r], &mut b).map_err(bus_err)?;
    Ok(b)
}

impl Bmm150 {
    /// Wakes the part (the power bit by read-modify-write, as `bmm150_init`), waits
    /// [`START_UP_MS`], checks CHIP_ID, reads the trim registers (Bosch's three bursts), writes
    /// the repetitions and then normal mode at the data rate, each read back. Bounded: a fixed
    /// number of transfers and one 3 ms wait. `now_us`: the MCU time a stall is counted from.
    pub fn init<I: I2c>(i2c: &mut I, cfg: Config, delay: &mut impl DelayNs, now_us: u64) -> Result<Self, ReadError> {
        let [found] = read_n::<I, 1>(i2c, reg::POWER_CONTROL)?;
        i2c.write(ADDR, &[reg::POWER_CONTROL, (found & !SOFT_RESET_BITS) | POWER_BIT]).map_err(bus_err)?;
        delay.delay_ms(START_UP_MS);
        match read_n::<I, 1>(i2c, reg::CHIP_ID)? {
            [CHIP_ID] => {}
            [id] => {
                // Not a BMM150 (or it did not wake): its register as it was, best effort.
                let _ = i2c.write(ADDR, &[reg::POWER_CONTROL, found]);
                return Err(ReadError::WrongId(id));
            }
        }
        let trim = Trim::from_bursts(read_n(i2c, reg::DIG_X1)?, read_n(i2c, reg::DIG_Z4)?, read_n(i2c, reg::DIG_Z2)?);
        if trim.xyz1 == 0 || trim.z1 == 0 || trim.z2 == 0 {
            return Err(ReadError::TrimInvalid);
        }
        for (r, v) in [(reg::REP_XY, cfg.rep_xy), (reg::REP_Z, cfg.rep_z), (reg::OP_MODE, (cfg.odr_code & 7) << 3)] {
            i2c.write(ADDR, &[r, v]).map_err(bus_err)?;
            let [read] = read_n::<I, 1>(i2c, r)?;
            if read != v {
                return Err(ReadError::ConfigMismatch { reg: r, wrote: v, read });
            }
        }
        Ok(Self { cfg, trim, watch: Watch::new(now_us), overflows: 0 })
    }

    /// The trim values read at start-up.
    pub fn trim(&self) -> &Trim {
        &self.trim
    }

    /// A new compensated reading (µT, in the board frame: [`calib_core::board::BMM150`] of the part's axes,
    /// UNVERIFIED on a board: `docs/frames.md`) if the data-ready bit says there
    /// is one at MCU time `now_us`; `Ok(None)` if not yet, or an overflow (counted). One 8-byte
    /// burst.
    pub fn read<I: I2c>(&mut self, i2c: &mut I, now_us: u64) -> Result<Option<[f32; 3]>, ReadError> {
        let b: [u8; 8] = read_n(i2c, reg::DATA)?;
        let limit_ms = self.cfg.stall_ms;
        if b[6] & 0x01 == 0 {
            return self.watch.idle(now_us, limit_ms).map(|()| None).map_err(|ms| ReadError::Stalled { ms, limit_ms });
        }
        // Bosch's `bmm150_read_mag_data`: the MSB (signed) above the LSB's top bits.
        let x = ((b[1] as i8 as i16) * 32) | (b[0] >> 3) as i16;
        let y = ((b[3] as i8 as i16) * 32) | (b[2] >> 3) as i16;
        let z = ((b[5] as i8 as i16) * 128) | (b[4] >> 1) as i16;
        let rhall = ((b[7] as u16) << 6) | (b[6] >> 2) as u16;
        self.watch.reading([x, y, z, rhall as i16], now_us, self.cfg.stuck_readings).map_err(|readings| ReadError::Stuck { readings })?;
        let m = self.trim.compensate(x, y, z, rhall);
        if m.is_none() {
            self.overflows = self.overflows.saturating_add(1);
        }
        Ok(m.map(|[x, y, z]| [-y, -x, -z]))
    }
}
