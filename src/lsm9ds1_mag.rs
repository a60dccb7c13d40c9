//! The LSM9DS1's magnetometer (I2C 0x1E, the Nano 33 BLE Rev1's) over embedded-hal 1.0: identity,
//! reset and configuration checked by read-back, data-ready reads in the accelerometer's axes
//! (µT), and a named error when it stops or sticks. Registers from ST DocID025715 (§8, Tables
//! 107–124; every fact and its source: `docs/mag-sources.md`).
//!
//! The magnetometer is a die of its own with its own address; it shares the bus with the
//! accelerometer/gyroscope driver ([`crate::lsm9ds1::Lsm9ds1::bus_mut`]), so each call borrows
//! the bus.

use crate::lsm9ds1::BusFault;
use crate::watch::{Shared, Watch};
use calib_core::formats::text::{Hex, Int};
use embedded_hal::delay::DelayNs;
use embedded_hal::i2c::I2c;

/// I2C address (SDO_M high on the Nano 33 BLE; DocID025715 Table 20).
pub const ADDR: u8 = 0x1E;
/// WHO_AM_I_M (DocID025715 Table 107).
pub const WHO_AM_I: u8 = 0x3D;
/// Wait after REBOOT + SOFT_RST before the first access (ms): the datasheet gives no figure;
/// Arduino's LSM9DS1 library waits 10 ms.
pub const RESET_WAIT_MS: u32 = 10;
/// Longest the part may take to answer after its reset (ms; Zephyr allows 50 ms); a NACK
/// before then is "not ready yet".
pub const RESET_TIMEOUT_MS: u32 = 50;

/// Register addresses (DocID025715 Table 21).
pub mod reg {
    /// Identity.
    pub const WHO_AM_I: u8 = 0x0F;
    /// TEMP_COMP, OM (x/y performance), DO (data rate), FAST_ODR, ST.
    pub const CTRL_REG1: u8 = 0x20;
    /// FS (full scale), REBOOT, SOFT_RST.
    pub const CTRL_REG2: u8 = 0x21;
    /// I2C_DISABLE, LP, SIM, MD (mode; 0x03 at reset: power-down).
    pub const CTRL_REG3: u8 = 0x22;
    /// OMZ (z performance), BLE.
    pub const CTRL_REG4: u8 = 0x23;
    /// BDU.
    pub const CTRL_REG5: u8 = 0x24;
    /// ZYXOR (bit 7), ZYXDA (bit 3).
    pub const STATUS: u8 = 0x27;
    /// OUT_X_L_M: x, y, z little-endian `i16`, 6 bytes.
    pub const OUT_X_L: u8 = 0x28;
}

/// The sub-address bit that makes a multi-byte read auto-increment (DocID025715 §5.1.1).
pub const AUTO_INCREMENT: u8 = 0x80;
/// CTRL_REG2_M: REBOOT (bit 3) and SOFT_RST (bit 2), both self-clearing.
pub const REBOOT_SOFT_RST: u8 = 0x0C;
/// STATUS_REG_M ZYXDA: a new x, y, z set.
pub const ZYXDA: u8 = 1 << 3;

/// Output data rate (CTRL_REG1_M DO).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Odr {
    /// 10 Hz.
    Hz10,
    /// 20 Hz (Arduino's LSM9DS1 library).
    Hz20,
    /// 40 Hz.
    Hz40,
    /// 80 Hz.
    Hz80,
}

impl Odr {
    /// Nominal rate (Hz).
    pub fn hz(self) -> f32 {
        match self {
            Odr::Hz10 => 10.0,
            Odr::Hz20 => 20.0,
            Odr::Hz40 => 40.0,
            Odr::Hz80 => 80.0,
        }
    }

    /// DO[2:0] (DocID025715 Table 111).
    fn code(self) -> u8 {
        match self {
            Odr::Hz10 => 0b100,
            Odr::Hz20 => 0b101,
            Odr::Hz40 => 0b110,
            Odr::Hz80 => 0b111,
        }
    }
}

/// The magnetometer's settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config {
    /// Output data rate.
    pub odr: Odr,
    /// Ultra-high performance on all three axes (OM = OMZ = 11: the lowest noise), else medium
    /// (Arduino's library: OM = 01, OMZ left at low power).
    pub ultra_high: bool,
    /// No new reading for this long (ms) is a stopped part.
    pub stall_ms: u32,
    /// This many new readings in a row with the same counts are a stuck part (the noise moves
    /// the last digits of every reading).
    pub stuck_readings: u16,
}

impl Config {
    /// 40 Hz, ultra-high performance, temperature compensated, ±4 gauss (0.14 mgauss/LSB), BDU:
    /// stopped after 250 ms (10 periods) without a reading, stuck after 40 identical ones (1 s).
    pub const DEFAULT: Config = Config { odr: Odr::Hz40, ultra_high: true, stall_ms: 250, stuck_readings: 40 };

    /// The registers to write, in order, with the values each must read back.
    fn registers(&self) -> [(u8, u8); 5] {
        let om = if self.ultra_high { 0b11 } else { 0b01 };
        [
            // TEMP_COMP | OM | DO.
            (reg::CTRL_REG1, 0x80 | (om << 5) | (self.odr.code() << 2)),
            // FS = ±4 gauss.
            (reg::CTRL_REG2, 0x00),
            // OMZ, little-endian.
            (reg::CTRL_REG4, if self.ultra_high { 0b11 << 2 } else { 0 }),
            // BDU: the outputs are not updated until both bytes are read.
            (reg::CTRL_REG5, 0x40),
            // Continuous conversion, I2C on, LP off: last, so that it starts at the settings.
            (reg::CTRL_REG3, 0x00),
        ]
    }
}

impl Default for Config {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Sensitivity at ±4 gauss (µT per LSB): 0.14 mgauss/LSB (DocID025715 Table 3).
pub const UT_PER_LSB: f32 = 0.014;

/// Why the magnetometer gave no reading.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// An I2C transfer failed: `Bus(BusFault::Nack)` at the first is no magnetometer at 0x1E.
    Bus(BusFault),
    /// Something answers at 0x1E with another WHO_AM_I.
    WrongId(u8),
    /// It did not answer within [`RESET_TIMEOUT_MS`] of its reset.
    ResetTimeout,
    /// A register did not keep the value written.
    ConfigMismatch {
        /// Register address.
        reg: u8,
        /// Value written.
        wrote: u8,
        /// Value read back.
        read: u8,
    },
    /// No new reading for `ms` (its limit `limit_ms`): the part stopped converting.
    Stalled {
        /// Time since the last new reading (ms).
        ms: u32,
        /// The limit (ms).
        limit_ms: u32,
    },
    /// `readings` new readings in a row with the same counts: the part is stuck.
    Stuck {
        /// Identical readings in a row.
        readings: u16,
    },
}

impl core::fmt::Display for Error {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let shared = match *self {
            Error::WrongId(id) => return write!(f, "LSM9DS1 magnetometer: WHO_AM_I_M 0x{} at 0x1E (expected 0x3D)", Hex(id.into(), 2)),
            Error::ResetTimeout => return write!(f, "LSM9DS1 magnetometer: no answer {} ms after its reset", Int(RESET_TIMEOUT_MS.into())),
            Error::Bus(b) => Shared::Bus(b),
            Error::ConfigMismatch { reg, wrote, read } => Shared::ConfigMismatch { reg, wrote, read },
            Error::Stalled { ms, limit_ms } => Shared::Stalled { ms, limit_ms },
            Error::Stuck { readings } => Shared::Stuck { readings },
        };
        shared.write(f, "LSM9DS1 magnetometer", ADDR)
    }
}

/// The magnetometer, configured. Holds no bus: every call borrows it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LsmMag {
    cfg: Config,
    watch: Watch,
}

fn bus<E: embedded_hal::i2c::Error>(e: E) -> Error {
    Error::Bus(BusFault::of(e))
}

fn read1<I: I2c>(i2c: &mut I, r: u8) -> Result<u8, Error> {
    let mut b = [0u8];
    i2c.write_read(ADDR, &[r], &mut b).map_err(bus)?;
    Ok(b[0])
}

impl LsmMag {
    /// Checks WHO_AM_I_M, reboots and resets the part (as Arduino's library: REBOOT + SOFT_RST,
    /// 10 ms), polls until it answers (≤ [`RESET_TIMEOUT_MS`]), writes `cfg` and reads every
    /// register back. Bounded: a fixed number of transfers and ≤ 50 ms of waiting. `now_us`:
    /// the MCU time, from which a stall is counted.
    pub fn init<I: I2c>(i2c: &mut I, cfg: Config, delay: &mut impl DelayNs, now_us: u64) -> Result<Self, Error> {
        match read1(i2c, reg::WHO_AM_I)? {
            WHO_AM_I => {}
            id => return Err(Error::WrongId(id)),
        }
        i2c.write(ADDR, &[reg::CTRL_REG2, REBOOT_SOFT_RST]).map_err(bus)?;
        delay.delay_ms(RESET_WAIT_MS);
        let mut back = false;
        for _ in RESET_WAIT_MS..=RESET_TIMEOUT_MS {
            match read1(i2c, reg::CTRL_REG2) {
                Ok(v) if v & REBOOT_SOFT_RST == 0 => {
                    back = true;
                    break;
                }
                Ok(_) | Err(Error::Bus(BusFault::Nack)) => delay.delay_ms(1),
                Err(e) => return Err(e),
            }
        }
        if !back {
            return Err(Error::ResetTimeout);
        }
        for (r, v) in cfg.registers() {
            i2c.write(ADDR, &[r, v]).map_err(bus)?;
            let read = read1(i2c, r)?;
            if read != v {
                return Err(Error::ConfigMismatch { reg: r, wrote: v, read });
            }
        }
        Ok(Self { cfg, watch: Watch::new(now_us) })
    }

    /// The settings.
    pub fn config(&self) -> &Config {
        &self.cfg
    }

    /// A new reading (µT, in the board frame: the magnetometer's raw axes, whose x is the
    /// accelerometer's −x, DocID025715 Figure 1) if ZYXDA says there is one at MCU time
    /// `now_us`; `Ok(None)` if not yet. Two transfers at most; [`Error::Stalled`] or
    /// [`Error::Stuck`] when the part stopped or stuck.
    pub fn read<I: I2c>(&mut self, i2c: &mut I, now_us: u64) -> Result<Option<[f32; 3]>, Error> {
        let limit_ms = self.cfg.stall_ms;
        if read1(i2c, reg::STATUS)? & ZYXDA == 0 {
            return self.watch.idle(now_us, limit_ms).map(|()| None).map_err(|ms| Error::Stalled { ms, limit_ms });
        }
        let mut b = [0u8; 6];
        i2c.write_read(ADDR, &[reg::OUT_X_L | AUTO_INCREMENT], &mut b).map_err(bus)?;
        let c = [i16::from_le_bytes([b[0], b[1]]), i16::from_le_bytes([b[2], b[3]]), i16::from_le_bytes([b[4], b[5]])];
        self.watch.reading([c[0], c[1], c[2], 0], now_us, self.cfg.stuck_readings).map_err(|readings| Error::Stuck { readings })?;
        Ok(Some(to_board_ut(c)))
    }
}

/// Counts (part axes, ±4 gauss) to µT in the board frame ([`calib_core::board::LSM9DS1_MAG`]).
pub fn to_board_ut(c: [i16; 3]) -> [f32; 3] {
    c.map(|v| v as f32 * UT_PER_LSB)
}
