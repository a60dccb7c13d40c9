//! LSM9DS1 accelerometer/gyroscope over I2C (embedded-hal 1.0): identity check, configuration,
//! FIFO status and reads, raw-to-physical conversion. Registers from ST DocID025715.
//!
//! The `lsm9ds1` crate is not used: it is written against embedded-hal 0.2, has no FIFO access
//! and owns the bus, while this driver needs the FIFO at 952 Hz and runs on the host against a
//! simulated register map through the same `I2c` trait.

use calib_core::formats::record::{Sensor, SensorSetup};
use calib_core::formats::text::Hex;
use embedded_hal::delay::DelayNs;
use embedded_hal::i2c::{ErrorKind, I2c};

/// I2C address of the accelerometer/gyroscope (SDO_AG high on the Nano 33 BLE).
pub const ADDR_AG: u8 = 0x6B;
/// I2C address of the BMI270 of the Nano 33 BLE Rev2.
pub const ADDR_BMI270: u8 = 0x68;
/// Expected WHO_AM_I of the accelerometer/gyroscope.
pub const WHO_AM_I_AG: u8 = 0x68;
/// BMI270 CHIP_ID.
pub const BMI270_CHIP_ID: u8 = 0x24;
/// FIFO depth (slots of gyro + accel).
pub const FIFO_DEPTH: u8 = 32;
/// Wait after SW_RESET before the first poll (ms): Arduino's LSM9DS1 library waits 10 ms.
pub const RESET_WAIT_MS: u32 = 10;
/// Longest the part may take to come back from SW_RESET (ms); Zephyr allows 50 ms after BOOT.
/// A NACK before then means "not ready yet".
pub const RESET_TIMEOUT_MS: u32 = 50;

/// Register addresses.
pub mod reg {
    /// Identity.
    pub const WHO_AM_I: u8 = 0x0F;
    /// Gyro ODR, full scale, bandwidth.
    pub const CTRL_REG1_G: u8 = 0x10;
    /// Temperature, low byte.
    pub const OUT_TEMP_L: u8 = 0x15;
    /// Status.
    pub const STATUS_REG: u8 = 0x17;
    /// Gyro X, low byte (6 bytes: X, Y, Z little-endian).
    pub const OUT_X_L_G: u8 = 0x18;
    /// Accelerometer ODR and full scale.
    pub const CTRL_REG6_XL: u8 = 0x20;
    /// BOOT, BDU, IF_ADD_INC, SW_RESET.
    pub const CTRL_REG8: u8 = 0x22;
    /// FIFO_EN.
    pub const CTRL_REG9: u8 = 0x23;
    /// Accelerometer X, low byte (6 bytes).
    pub const OUT_X_L_XL: u8 = 0x28;
    /// FIFO mode and threshold.
    pub const FIFO_CTRL: u8 = 0x2E;
    /// FIFO threshold, overrun, unread samples.
    pub const FIFO_SRC: u8 = 0x2F;
    /// BMI270 chip id register.
    pub const BMI270_CHIP_ID: u8 = 0x00;
}

/// CTRL_REG8 bits.
pub const CTRL8_BDU: u8 = 1 << 6;
/// CTRL_REG8 register address auto-increment.
pub const CTRL8_IF_ADD_INC: u8 = 1 << 2;
/// CTRL_REG8 software reset.
pub const CTRL8_SW_RESET: u8 = 1 << 0;
/// CTRL_REG9 FIFO enable.
pub const CTRL9_FIFO_EN: u8 = 1 << 1;
/// FIFO_CTRL continuous mode (FMODE = 110): the newest 32 slots, oldest overwritten.
pub const FIFO_MODE_CONTINUOUS: u8 = 0b110 << 5;
/// FIFO_CTRL: bypass mode (FMODE 000: "FIFO turned off", LSM9DS1 datasheet DocID025715, FIFO
/// modes; it holds no sample, so it cannot overrun).
pub const FIFO_MODE_BYPASS: u8 = 0;
/// FIFO_SRC overrun flag.
pub const FIFO_SRC_OVRN: u8 = 1 << 6;

/// Output data rate of gyro and accelerometer together.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Odr {
    /// 119 Hz.
    Hz119,
    /// 238 Hz.
    Hz238,
    /// 476 Hz.
    Hz476,
    /// 952 Hz.
    Hz952,
}

impl Odr {
    /// Nominal rate (Hz); the real one differs by several percent.
    pub const fn hz(self) -> f32 {
        match self {
            Odr::Hz119 => 119.0,
            Odr::Hz238 => 238.0,
            Odr::Hz476 => 476.0,
            Odr::Hz952 => 952.0,
        }
    }

    /// ODR_G / ODR_XL field value (bits 7:5).
    pub fn code(self) -> u8 {
        match self {
            Odr::Hz119 => 0b011,
            Odr::Hz238 => 0b100,
            Odr::Hz476 => 0b101,
            Odr::Hz952 => 0b110,
        }
    }
}

/// Gyro full scale.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum GyroScale {
    /// ±245 °/s, 8.75 m°/s per LSB.
    Dps245,
    /// ±500 °/s, 17.5 m°/s per LSB.
    Dps500,
    /// ±2000 °/s, 70 m°/s per LSB.
    Dps2000,
}

impl GyroScale {
    /// FS_G field value (bits 4:3).
    pub fn code(self) -> u8 {
        match self {
            GyroScale::Dps245 => 0b00,
            GyroScale::Dps500 => 0b01,
            GyroScale::Dps2000 => 0b11,
        }
    }

    /// Sensitivity (°/s per LSB).
    pub fn dps_per_lsb(self) -> f32 {
        match self {
            GyroScale::Dps245 => 0.00875,
            GyroScale::Dps500 => 0.0175,
            GyroScale::Dps2000 => 0.070,
        }
    }

    /// Nominal full scale (°/s).
    pub const fn range_dps(self) -> f32 {
        match self {
            GyroScale::Dps245 => 245.0,
            GyroScale::Dps500 => 500.0,
            GyroScale::Dps2000 => 2000.0,
        }
    }
}

/// Accelerometer full scale.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AccelScale {
    /// ±2 g, 0.061 mg per LSB.
    G2,
    /// ±4 g, 0.122 mg per LSB.
    G4,
    /// ±8 g, 0.244 mg per LSB.
    G8,
    /// ±16 g, 0.732 mg per LSB.
    G16,
}

impl AccelScale {
    /// FS_XL field value (bits 4:3).
    pub fn code(self) -> u8 {
        match self {
            AccelScale::G2 => 0b00,
            AccelScale::G16 => 0b01,
            AccelScale::G4 => 0b10,
            AccelScale::G8 => 0b11,
        }
    }

    /// Sensitivity (g per LSB).
    pub fn g_per_lsb(self) -> f32 {
        match self {
            AccelScale::G2 => 0.000061,
            AccelScale::G4 => 0.000122,
            AccelScale::G8 => 0.000244,
            AccelScale::G16 => 0.000732,
        }
    }

    /// Nominal full scale (g).
    pub const fn range_g(self) -> f32 {
        match self {
            AccelScale::G2 => 2.0,
            AccelScale::G4 => 4.0,
            AccelScale::G8 => 8.0,
            AccelScale::G16 => 16.0,
        }
    }
}

/// Sensor settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SensorConfig {
    /// Output data rate.
    pub odr: Odr,
    /// Gyro range.
    pub gyro: GyroScale,
    /// Accelerometer range.
    pub accel: AccelScale,
}

impl Default for SensorConfig {
    /// [`SensorConfig::DEFAULT`].
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl SensorConfig {
    /// 119 Hz, ±500 °/s, ±2 g: the firmware's default.
    pub const DEFAULT: SensorConfig = SensorConfig { odr: Odr::Hz119, gyro: GyroScale::Dps500, accel: AccelScale::G2 };
    /// What Arduino's Arduino_LSM9DS1 library sets in `IMU.begin()`: CTRL_REG1_G 0x78 (119 Hz,
    /// ±2000 °/s, BW_G 00) and CTRL_REG6_XL 0x70 (119 Hz, ±4 g, bandwidth from the ODR).
    pub const ARDUINO_LSM9DS1: SensorConfig = SensorConfig { odr: Odr::Hz119, gyro: GyroScale::Dps2000, accel: AccelScale::G4 };

    /// The settings of a record's setup, if this driver can run them (its ODRs and full scales).
    pub fn of(s: &SensorSetup) -> Option<SensorConfig> {
        let odr = [Odr::Hz119, Odr::Hz238, Odr::Hz476, Odr::Hz952].into_iter().find(|o| o.hz() == s.odr_hz)?;
        let gyro = [GyroScale::Dps245, GyroScale::Dps500, GyroScale::Dps2000].into_iter().find(|g| g.range_dps() == s.gyro_range_dps)?;
        let accel =
            [AccelScale::G2, AccelScale::G4, AccelScale::G8, AccelScale::G16].into_iter().find(|a| a.range_g() == s.accel_range_g)?;
        Some(SensorConfig { odr, gyro, accel })
    }

    /// The setup a record states.
    pub const fn setup(&self) -> SensorSetup {
        SensorSetup {
            odr_hz: self.odr.hz(),
            gyro_range_dps: self.gyro.range_dps(),
            accel_range_g: self.accel.range_g(),
            sensor: Sensor::Lsm9ds1,
        }
    }

    /// CTRL_REG1_G value (gyro bandwidth BW_G = 00).
    pub fn ctrl_reg1_g(&self) -> u8 {
        (self.odr.code() << 5) | (self.gyro.code() << 3)
    }

    /// CTRL_REG6_XL value (bandwidth from the ODR).
    pub fn ctrl_reg6_xl(&self) -> u8 {
        (self.odr.code() << 5) | (self.accel.code() << 3)
    }
}

/// What went wrong on the I2C bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BusFault {
    /// The address or a data byte was not acknowledged.
    Nack,
    /// Bus error or lost arbitration (SDA/SCL disturbed).
    Bus,
    /// Data overrun.
    Overrun,
    /// Any other driver error.
    Other,
}

impl BusFault {
    pub(crate) fn of<E: embedded_hal::i2c::Error>(e: E) -> Self {
        match e.kind() {
            ErrorKind::NoAcknowledge(_) => BusFault::Nack,
            ErrorKind::Bus | ErrorKind::ArbitrationLoss => BusFault::Bus,
            ErrorKind::Overrun => BusFault::Overrun,
            _ => BusFault::Other,
        }
    }
}

/// Why the sensor could not be used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SensorError {
    /// An I2C transfer failed.
    Bus(BusFault),
    /// Nothing answers at 0x6B: sensor unpowered, not fitted, or I2C wiring.
    Missing,
    /// A BMI270 answers at 0x68: this is a Nano 33 BLE Rev2, not supported.
    Rev2Bmi270,
    /// Something answers at 0x6B with another WHO_AM_I.
    WrongId(u8),
    /// A register did not keep the value written.
    ConfigMismatch {
        /// Register address.
        reg: u8,
        /// Value written.
        wrote: u8,
        /// Value read back.
        read: u8,
    },
    /// The part did not come back from its software reset within [`RESET_TIMEOUT_MS`]
    /// (NACKs, or SW_RESET never cleared).
    ResetTimeout,
}

impl core::fmt::Display for SensorError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            SensorError::Bus(b) => f.write_str(match b {
                BusFault::Nack => "I2C: not acknowledged",
                BusFault::Bus => "I2C: bus error or lost arbitration",
                BusFault::Overrun => "I2C: data overrun",
                BusFault::Other => "I2C: driver error",
            }),
            SensorError::Missing => f.write_str("LSM9DS1 missing"),
            SensorError::Rev2Bmi270 => f.write_str("Nano 33 BLE Rev2"),
            SensorError::WrongId(id) => write!(f, "WHO_AM_I 0x{} at 0x6B is not an LSM9DS1", Hex(id.into(), 2)),
            SensorError::ConfigMismatch { reg, wrote, read } => {
                write!(f, "register 0x{} reads 0x{} after writing 0x{}", Hex(reg.into(), 2), Hex(read.into(), 2), Hex(wrote.into(), 2))
            }
            SensorError::ResetTimeout => f.write_str("no answer after the software reset"),
        }
    }
}

/// One FIFO slot: raw gyro and accelerometer counts, the part's axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RawSample {
    /// Gyro X, Y, Z (LSB).
    pub gyro: [i16; 3],
    /// Accelerometer X, Y, Z (LSB).
    pub accel: [i16; 3],
}

/// FIFO state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FifoStatus {
    /// Unread slots (0..=32).
    pub level: u8,
    /// Slots were overwritten since the last read (samples lost).
    pub overrun: bool,
    /// Every slot unread (FSS = 32): a sample that lands before the first slot is read
    /// overwrites the oldest, and that read clears the overrun flag (a loss no status read
    /// shows). ST DocID025715, FIFO_SRC (2Fh): OVRN is 1 while the FIFO is completely filled
    /// and at least one sample has been overwritten.
    pub full: bool,
}

/// The accelerometer/gyroscope part of an LSM9DS1.
pub struct Lsm9ds1<I> {
    i2c: I,
    cfg: SensorConfig,
    /// FIFO slots still to throw away: ST, "the first sample acquired must be discarded"
    /// after the FIFO is (re)enabled.
    discard: u8,
}

fn le3(b: &[u8; 6]) -> [i16; 3] {
    [i16::from_le_bytes([b[0], b[1]]), i16::from_le_bytes([b[2], b[3]]), i16::from_le_bytes([b[4], b[5]])]
}

impl<I: I2c> Lsm9ds1<I> {
    /// Checks the identity (telling a Rev2 board's BMI270 apart), resets and configures the
    /// sensor: ODR and ranges, block data update, FIFO in continuous mode. Bounded: at most
    /// [`RESET_TIMEOUT_MS`] of waiting for the reset, a fixed number of transfers otherwise.
    pub fn init(mut i2c: I, cfg: SensorConfig, delay: &mut impl DelayNs) -> Result<Self, (SensorError, I)> {
        match read_reg(&mut i2c, ADDR_AG, reg::WHO_AM_I) {
            Ok(WHO_AM_I_AG) => {}
            Ok(id) => return Err((SensorError::WrongId(id), i2c)),
            Err(_) => {
                let e = match read_reg(&mut i2c, ADDR_BMI270, reg::BMI270_CHIP_ID) {
                    Ok(BMI270_CHIP_ID) => SensorError::Rev2Bmi270,
                    _ => SensorError::Missing,
                };
                return Err((e, i2c));
            }
        }
        let mut s = Self { i2c, cfg, discard: 0 };
        match s.configure(delay) {
            Ok(()) => Ok(s),
            Err(e) => Err((e, s.i2c)),
        }
    }

    /// Software reset: the part does not answer for a while (NACK = not ready yet), then
    /// SW_RESET reads back 0. Polled every millisecond after [`RESET_WAIT_MS`], up to
    /// [`RESET_TIMEOUT_MS`].
    fn reset(&mut self, delay: &mut impl DelayNs) -> Result<(), SensorError> {
        self.write(reg::CTRL_REG8, CTRL8_IF_ADD_INC | CTRL8_SW_RESET)?;
        delay.delay_ms(RESET_WAIT_MS);
        for _ in RESET_WAIT_MS..=RESET_TIMEOUT_MS {
            match self.read(reg::CTRL_REG8) {
                Ok(v) if v & CTRL8_SW_RESET == 0 => return Ok(()),
                Ok(_) | Err(SensorError::Bus(BusFault::Nack)) => delay.delay_ms(1),
                Err(e) => return Err(e),
            }
        }
        Err(SensorError::ResetTimeout)
    }

    fn configure(&mut self, delay: &mut impl DelayNs) -> Result<(), SensorError> {
        self.reset(delay)?;
        let c = self.cfg;
        for (r, v) in [
            (reg::CTRL_REG8, CTRL8_BDU | CTRL8_IF_ADD_INC),
            (reg::CTRL_REG1_G, c.ctrl_reg1_g()),
            (reg::CTRL_REG6_XL, c.ctrl_reg6_xl()),
            (reg::CTRL_REG9, CTRL9_FIFO_EN),
            (reg::FIFO_CTRL, FIFO_MODE_CONTINUOUS),
        ] {
            self.write(r, v)?;
            let read = self.read(r)?;
            if read != v {
                return Err(SensorError::ConfigMismatch { reg: r, wrote: v, read });
            }
        }
        // The FIFO was just enabled: its first slot is junk.
        self.discard = 1;
        Ok(())
    }

    /// The settings in use.
    pub fn config(&self) -> &SensorConfig {
        &self.cfg
    }

    /// The bus back.
    pub fn release(self) -> I {
        self.i2c
    }

    /// The bus, borrowed (e.g. to recover it after an error).
    pub fn bus_mut(&mut self) -> &mut I {
        &mut self.i2c
    }

    fn read(&mut self, r: u8) -> Result<u8, SensorError> {
        read_reg(&mut self.i2c, ADDR_AG, r).map_err(|e| SensorError::Bus(BusFault::of(e)))
    }

    fn write(&mut self, r: u8, v: u8) -> Result<(), SensorError> {
        self.i2c.write(ADDR_AG, &[r, v]).map_err(|e| SensorError::Bus(BusFault::of(e)))
    }

    fn read6(&mut self, r: u8) -> Result<[u8; 6], SensorError> {
        let mut b = [0u8; 6];
        self.i2c.write_read(ADDR_AG, &[r], &mut b).map_err(|e| SensorError::Bus(BusFault::of(e)))?;
        Ok(b)
    }

    /// The FIFO off (bypass mode: empty, it cannot overrun) for a stretch whose samples are not
    /// wanted and that outlasts it (a flash page erase stalls the CPU for up to 85 ms; at 952 Hz
    /// the FIFO holds 34 ms).
    pub fn pause_fifo(&mut self) -> Result<(), SensorError> {
        self.write(reg::FIFO_CTRL, FIFO_MODE_BYPASS)
    }

    /// The FIFO on again after [`Self::pause_fifo`]: it starts empty and its first slot is junk,
    /// as after [`Self::init`].
    pub fn resume_fifo(&mut self) -> Result<(), SensorError> {
        self.write(reg::FIFO_CTRL, FIFO_MODE_CONTINUOUS)?;
        self.discard = 1;
        Ok(())
    }

    /// Unread FIFO slots (not counting a slot still to be discarded) and the overrun flag.
    pub fn fifo_status(&mut self) -> Result<FifoStatus, SensorError> {
        let src = self.read(reg::FIFO_SRC)?;
        let level = (src & 0x3F).min(FIFO_DEPTH);
        Ok(FifoStatus { level: level.saturating_sub(self.discard), overrun: src & FIFO_SRC_OVRN != 0, full: level == FIFO_DEPTH })
    }

    /// Pops one FIFO slot (after throwing away the junk first slot, if still due): the gyro
    /// registers, then the accelerometer registers.
    pub fn read_slot(&mut self) -> Result<RawSample, SensorError> {
        while self.discard > 0 {
            self.pop()?;
            self.discard -= 1;
        }
        self.pop()
    }

    fn pop(&mut self) -> Result<RawSample, SensorError> {
        let g = self.read6(reg::OUT_X_L_G)?;
        let a = self.read6(reg::OUT_X_L_XL)?;
        Ok(RawSample { gyro: le3(&g), accel: le3(&a) })
    }

    /// Temperature (°C): 16 LSB/°C, 0 at 25 °C.
    pub fn temperature_c(&mut self) -> Result<f32, SensorError> {
        let mut b = [0u8; 2];
        self.i2c.write_read(ADDR_AG, &[reg::OUT_TEMP_L], &mut b).map_err(|e| SensorError::Bus(BusFault::of(e)))?;
        Ok(25.0 + i16::from_le_bytes(b) as f32 / 16.0)
    }

    /// Converts counts to accelerometer (g) and gyro (°/s) in the board frame, datasheet
    /// sensitivity only.
    pub fn convert(&self, raw: &RawSample) -> ([f32; 3], [f32; 3]) {
        convert(&self.cfg, raw)
    }
}

/// Converts counts to accelerometer (g) and gyro (°/s) for `cfg`, in the board frame: the raw
/// axes form a left-handed triad, `(−x, y, z)` of both is the board's ([`calib_core::board::LSM9DS1_AG`]).
pub fn convert(cfg: &SensorConfig, raw: &RawSample) -> ([f32; 3], [f32; 3]) {
    let (ga, gg) = (cfg.accel.g_per_lsb(), cfg.gyro.dps_per_lsb());
    let ([ax, ay, az], [gx, gy, gz]) = (raw.accel.map(|c| c as f32 * ga), raw.gyro.map(|c| c as f32 * gg));
    ([-ax, ay, az], [-gx, gy, gz])
}

fn read_reg<I: I2c>(i2c: &mut I, addr: u8, r: u8) -> Result<u8, I::Error> {
    let mut b = [0u8; 1];
    i2c.write_read(addr, &[r], &mut b)?;
    Ok(b[0])
}
