//! Bosch BMI270 (the Nano 33 BLE Rev2's IMU at 0x68) over embedded-hal I2C: identity, soft reset,
//! the configuration file upload, the sensor configuration and its checks, as Bosch's
//! BMI270_SensorAPI does them (v2.86.1; every step and its source: `docs/rev2-sources.md`).
//!
//! The configuration file [`CONFIG`] is Bosch's `bmi270_maximum_fifo_config_file[]`, under this
//! licence:
//!
//! Copyright (c) 2023 Bosch Sensortec GmbH. All rights reserved. BSD-3-Clause.
//! Redistribution and use in source and binary forms, with or without modification, are
//! permitted provided that the following conditions are met: 1. Redistributions of source code
//! must retain the above copyright notice, this list of conditions and the following disclaimer.
//! 2. Redistributions in binary form must reproduce the above copyright notice, this list of
//! conditions and the following disclaimer in the documentation and/or other materials provided
//! with the distribution. 3. Neither the name of the copyright holder nor the names of its
//! contributors may be used to endorse or promote products derived from this software without
//! specific prior written permission. THIS SOFTWARE IS PROVIDED BY THE COPYRIGHT HOLDERS AND
//! CONTRIBUTORS "AS IS" AND ANY EXPRESS OR IMPLIED WARRANTIES, INCLUDING, BUT NOT LIMITED TO,
//! THE IMPLIED WARRANTIES OF MERCHANTABILITY AND FITNESS FOR A PARTICULAR PURPOSE ARE
//! DISCLAIMED. IN NO EVENT SHALL THE COPYRIGHT HOLDER OR CONTRIBUTORS BE LIABLE FOR ANY DIRECT,
//! INDIRECT, INCIDENTAL, SPECIAL, EXEMPLARY, OR CONSEQUENTIAL DAMAGES (INCLUDING, BUT NOT LIMITED
//! TO, PROCUREMENT OF SUBSTITUTE GOODS OR SERVICES; LOSS OF USE, DATA, OR PROFITS; OR BUSINESS
//! INTERRUPTION) HOWEVER CAUSED AND ON ANY THEORY OF LIABILITY, WHETHER IN CONTRACT, STRICT
//! LIABILITY, OR TORT (INCLUDING NEGLIGENCE OR OTHERWISE) ARISING IN ANY WAY OUT OF THE USE OF
//! THIS SOFTWARE, EVEN IF ADVISED OF THE POSSIBILITY OF SUCH DAMAGE.

use crate::lsm9ds1::BusFault;
use calib_core::formats::record::{Sensor, SensorSetup};
use calib_core::formats::text::{Hex, Int};
use embedded_hal::delay::DelayNs;
use embedded_hal::i2c::I2c;

/// I2C address on the Nano 33 BLE Rev2 (SDO low).
pub const ADDR: u8 = 0x68;
/// CHIP_ID of a BMI270.
pub const CHIP_ID: u8 = 0x24;
/// Bosch's "maximum FIFO" configuration file (`bmi270_maximum_fifo.c`, v2.86.1; 328 bytes,
/// SHA-256 e17bf316…83ffe, pinned by rig-sim's tests; `docs/rev2-sources.md`): the accelerometer,
/// gyro and a 6 KB FIFO, none of the 8 KiB file's features (which this firmware does not use).
/// GYR_CAS is then at [`reg::GYR_CAS`].
pub static CONFIG: [u8; 328] = [
    0xc8, 0x2e, 0x00, 0x2e, 0x80, 0x2e, 0x1a, 0x00, 0xc8, 0x2e, 0x00, 0x2e, 0xc8, 0x2e, 0x00, 0x2e, 0xc8, 0x2e, 0x00, 0x2e, 0xc8, 0x2e,
    0x00, 0x2e, 0xc8, 0x2e, 0x00, 0x2e, 0xc8, 0x2e, 0x00, 0x2e, 0x90, 0x32, 0x21, 0x2e, 0x59, 0xf5, 0x10, 0x30, 0x21, 0x2e, 0x6a, 0xf5,
    0x1a, 0x24, 0x22, 0x00, 0x80, 0x2e, 0x3b, 0x00, 0xc8, 0x2e, 0x44, 0x47, 0x22, 0x00, 0x37, 0x00, 0xa4, 0x00, 0xff, 0x0f, 0xd1, 0x00,
    0x07, 0xad, 0x80, 0x2e, 0x00, 0xc1, 0x80, 0x2e, 0x00, 0xc1, 0x80, 0x2e, 0x00, 0xc1, 0x80, 0x2e, 0x00, 0xc1, 0x80, 0x2e, 0x00, 0xc1,
    0x80, 0x2e, 0x00, 0xc1, 0x80, 0x2e, 0x00, 0xc1, 0x80, 0x2e, 0x00, 0xc1, 0x80, 0x2e, 0x00, 0xc1, 0x80, 0x2e, 0x00, 0xc1, 0x80, 0x2e,
    0x00, 0xc1, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x11, 0x24, 0xfc, 0xf5, 0x80, 0x30, 0x40, 0x42, 0x50, 0x50, 0x00, 0x30, 0x12, 0x24,
    0xeb, 0x00, 0x03, 0x30, 0x00, 0x2e, 0xc1, 0x86, 0x5a, 0x0e, 0xfb, 0x2f, 0x21, 0x2e, 0xfc, 0xf5, 0x13, 0x24, 0x63, 0xf5, 0xe0, 0x3c,
    0x48, 0x00, 0x22, 0x30, 0xf7, 0x80, 0xc2, 0x42, 0xe1, 0x7f, 0x3a, 0x25, 0xfc, 0x86, 0xf0, 0x7f, 0x41, 0x33, 0x98, 0x2e, 0xc2, 0xc4,
    0xd6, 0x6f, 0xf1, 0x30, 0xf1, 0x08, 0xc4, 0x6f, 0x11, 0x24, 0xff, 0x03, 0x12, 0x24, 0x00, 0xfc, 0x61, 0x09, 0xa2, 0x08, 0x36, 0xbe,
    0x2a, 0xb9, 0x13, 0x24, 0x38, 0x00, 0x64, 0xbb, 0xd1, 0xbe, 0x94, 0x0a, 0x71, 0x08, 0xd5, 0x42, 0x21, 0xbd, 0x91, 0xbc, 0xd2, 0x42,
    0xc1, 0x42, 0x00, 0xb2, 0xfe, 0x82, 0x05, 0x2f, 0x50, 0x30, 0x21, 0x2e, 0x21, 0xf2, 0x00, 0x2e, 0x00, 0x2e, 0xd0, 0x2e, 0xf0, 0x6f,
    0x02, 0x30, 0x02, 0x42, 0x20, 0x26, 0xe0, 0x6f, 0x02, 0x31, 0x03, 0x40, 0x9a, 0x0a, 0x02, 0x42, 0xf0, 0x37, 0x05, 0x2e, 0x5e, 0xf7,
    0x10, 0x08, 0x12, 0x24, 0x1e, 0xf2, 0x80, 0x42, 0x83, 0x84, 0xf1, 0x7f, 0x0a, 0x25, 0x13, 0x30, 0x83, 0x42, 0x3b, 0x82, 0xf0, 0x6f,
    0x00, 0x2e, 0x00, 0x2e, 0xd0, 0x2e, 0x12, 0x40, 0x52, 0x42, 0x00, 0x2e, 0x12, 0x40, 0x52, 0x42, 0x3e, 0x84, 0x00, 0x40, 0x40, 0x42,
    0x7e, 0x82, 0xe1, 0x7f, 0xf2, 0x7f, 0x98, 0x2e, 0x6a, 0xd6, 0x21, 0x30, 0x23, 0x2e, 0x61, 0xf5, 0xeb, 0x2c, 0xe1, 0x6f,
];

/// Register addresses (Bosch's `bmi2_defs.h`; the two RANGE registers and ERR_REG as Zephyr
/// names them).
pub mod reg {
    /// CHIP_ID.
    pub const CHIP_ID: u8 = 0x00;
    /// ERR_REG.
    pub const ERR_REG: u8 = 0x02;
    /// First accelerometer data byte (ACC_X_LSB); the gyro follows at 0x12.
    pub const ACC_X_LSB: u8 = 0x0C;
    /// EVENT: bits 4:2 the configuration error code.
    pub const EVENT: u8 = 0x1B;
    /// INTERNAL_STATUS: bits 3:0 the initialisation's message.
    pub const INTERNAL_STATUS: u8 = 0x21;
    /// GYR_CAS with the maximum-FIFO configuration (Bosch's `BMI2_GYR_CAS_GPIO0_ADDR`; the
    /// step counter's SC_OUT_0 with the full one).
    pub const GYR_CAS: u8 = 0x1E;
    /// GYR_OFF_COMP_6: bit 7 the gyro user gain (GYR_USR_GAIN 0x78–0x7A) is applied.
    pub const GYR_OFF_COMP_6: u8 = 0x77;
    /// FIFO_LENGTH_0 (byte count bits 7:0); FIFO_LENGTH_1 (bits 13:8) follows.
    pub const FIFO_LENGTH_0: u8 = 0x24;
    /// Die temperature, LSB then MSB.
    pub const TEMPERATURE_0: u8 = 0x22;
    /// FIFO_DATA (the address does not increment: one burst reads the bytes in order).
    pub const FIFO_DATA: u8 = 0x26;
    /// FIFO_CONFIG_0 (bit 0 stop on full, bit 1 sensortime frames).
    pub const FIFO_CONFIG_0: u8 = 0x48;
    /// FIFO_CONFIG_1 (bit 4 header mode, 6 accelerometer, 7 gyro).
    pub const FIFO_CONFIG_1: u8 = 0x49;
    /// FIFO_DOWNS (bit 7 acc_fifo_filt_data, 6:4 acc_fifo_downs, bit 3 gyr_fifo_filt_data,
    /// 2:0 gyr_fifo_downs).
    pub const FIFO_DOWNS: u8 = 0x45;
    /// ACC_CONF (ODR bits 3:0, bandwidth 6:4, filter_perf 7); ACC_RANGE follows.
    pub const ACC_CONF: u8 = 0x40;
    /// ACC_RANGE (bits 1:0).
    pub const ACC_RANGE: u8 = 0x41;
    /// GYR_CONF (ODR 3:0, bandwidth 5:4, noise_perf 6, filter_perf 7); GYR_RANGE follows.
    pub const GYR_CONF: u8 = 0x42;
    /// GYR_RANGE (bits 2:0).
    pub const GYR_RANGE: u8 = 0x43;
    /// INIT_CTRL: 0 before the upload, 1 to start the initialisation.
    pub const INIT_CTRL: u8 = 0x59;
    /// INIT_ADDR_0 (word address bits 3:0); INIT_ADDR_1 (bits 11:4) follows.
    pub const INIT_ADDR_0: u8 = 0x5B;
    /// INIT_DATA: the upload's bytes (the address does not increment).
    pub const INIT_DATA: u8 = 0x5E;
    /// PWR_CONF: bit 0 advanced power save.
    pub const PWR_CONF: u8 = 0x7C;
    /// PWR_CTRL: bit 1 gyro, 2 accelerometer, 3 temperature.
    pub const PWR_CTRL: u8 = 0x7D;
    /// CMD.
    pub const CMD: u8 = 0x7E;
}

/// CMD: soft reset.
pub const CMD_SOFT_RESET: u8 = 0xB6;
/// After the soft reset (ms; Bosch waits 2), then CHIP_ID is polled every
/// [`RESET_POLL_MS`] until the part answers, at most [`RESET_POLLS`] times: a part slower
/// than Bosch's 2 ms still comes up, a missing one is named.
pub const RESET_WAIT_MS: u32 = 2;
/// See [`RESET_WAIT_MS`].
pub const RESET_POLL_MS: u32 = 1;
/// See [`RESET_WAIT_MS`]: up to 10 ms more, five times Bosch's wait.
pub const RESET_POLLS: u32 = 10;
/// While advanced power save is on, every access needs a gap of 450 µs (Bosch's API waits
/// exactly that); the driver waits twice it, so a part's slower oscillator cannot eat it (µs).
pub const APS_GAP_US: u32 = 900;
/// Bytes of the upload per I2C write (even: the address is in 16-bit words; Arduino's library
/// writes 30, Bosch's examples 46, Zephyr 256).
pub const UPLOAD_CHUNK: usize = 32;
/// After a register write with power save off, before the next access (µs): Bosch's API waits
/// 2 (`BMI2_NORMAL_MODE_DELAY_IN_US`, Zephyr the same), Zephyr's upload 1000 after each chunk;
/// five times Bosch's keeps back-to-back TWIM transfers (a few µs apart) off the limit.
pub const WRITE_GAP_US: u32 = 10;
/// Bosch reads INTERNAL_STATUS once, 20 ms after INIT_CTRL = 1 (an older API waited 140 ms):
/// polled every [`STATUS_POLL_MS`] up to this (ms).
pub const INIT_TIMEOUT_MS: u32 = 150;
/// See [`INIT_TIMEOUT_MS`].
pub const STATUS_POLL_MS: u32 = 5;
/// INTERNAL_STATUS message: initialised.
pub const INIT_OK: u8 = 0x01;
/// PWR_CTRL: gyro, accelerometer and temperature on.
pub const PWR_CTRL_ON: u8 = 0x0E;
/// FIFO_CONFIG_1: header mode, accelerometer and gyro frames.
pub const FIFO_HEADER_ACC_GYR: u8 = 0xD0;
/// FIFO header: a gyro + accelerometer frame (12 bytes, gyro first).
pub const FRAME_ACC_GYR: u8 = 0x8C;
/// Header of an accelerometer-only frame (6 bytes): the gyro not yet started.
pub const FRAME_ACC: u8 = 0x84;
/// Header of a gyro-only frame (6 bytes).
pub const FRAME_GYR: u8 = 0x88;
/// FIFO header: frames were dropped (1 byte: how many).
pub const FRAME_SKIP: u8 = 0x40;
/// FIFO header: sensortime (3 bytes).
pub const FRAME_SENSORTIME: u8 = 0x44;
/// FIFO header: a configuration change (4 bytes).
pub const FRAME_CONFIG: u8 = 0x48;
/// FIFO header: read past the data.
pub const FRAME_OVER_READ: u8 = 0x80;
/// Bytes a FIFO read takes at most (the part's FIFO holds 6 KB with [`CONFIG`]): more waiting
/// are read by the next read (a frame the burst cuts is repeated whole, [`parse_fifo`]); at
/// 100 Hz this is 1.5 s of frames, and no call into the procedure is a tenth of it.
pub const FIFO_BYTES: usize = 2048;
/// What a FIFO read takes beyond FIFO_LENGTH: a frame that arrives during the burst (13 bytes)
/// and the sensortime frame (4), which the part sends only once a burst has read the FIFO empty
/// (Bosch's FIFO over-read; its BMI160 application note reads watermark + two frames + 4 bytes).
pub const FIFO_OVER_READ: usize = 13 + 4;
/// FIFO_CONFIG_0: sensortime frames on (fifo_time_en, bit 1).
pub const FIFO_TIME_EN: u8 = 0x02;
/// FIFO_DOWNS: both sensors' filtered data, not down-sampled (the FIFO then carries what the
/// data registers do; with 0x00 it carries pre-filter data, reported with a 2× gyro scale at
/// ±500 °/s).
pub const FIFO_DOWNS_FILTERED: u8 = 0x88;

/// The bits of a register the driver writes and reads back that are defined (`bmi2_defs.h`
/// masks); the others are reserved, and what they read is not checked.
pub const fn defined_bits(r: u8) -> u8 {
    match r {
        // acc_range 1:0.
        reg::ACC_RANGE => 0x03,
        // gyr_range 2:0, ois_range 3.
        reg::GYR_RANGE => 0x0F,
        // stop_on_full 0, fifo_time_en 1.
        reg::FIFO_CONFIG_0 => 0x03,
        // ACC_CONF, GYR_CONF, FIFO_CONFIG_1, FIFO_DOWNS: every bit defined.
        _ => 0xFF,
    }
}
/// Sensortime resolution: 39.0625 µs per count (Bosch's `BMI2_SENSORTIME_RESOLUTION`), as
/// µs per [`SENSORTIME_PER`] counts.
pub const SENSORTIME_US: (u32, u32) = (625, 16);

/// Output data rate of both sensors.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Odr {
    /// 100 Hz (code 0x08).
    Hz100,
    /// 200 Hz (code 0x09).
    Hz200,
}

impl Odr {
    /// Sensortime counts per sample: a sample is produced each time the count crosses a
    /// multiple of this (BMI160 datasheet Table 11: sensor_time bit 8 updates at 100 Hz, bit 7 at
    /// 200 Hz; the BMI270 keeps the family's hardware-synchronised sensortime).
    pub const fn ticks_per_sample(self) -> u32 {
        match self {
            Odr::Hz100 => 256,
            Odr::Hz200 => 128,
        }
    }

    /// Nominal rate (Hz).
    pub const fn hz(self) -> f32 {
        match self {
            Odr::Hz100 => 100.0,
            Odr::Hz200 => 200.0,
        }
    }

    /// The ODR field of ACC_CONF and GYR_CONF.
    pub const fn code(self) -> u8 {
        match self {
            Odr::Hz100 => 0x08,
            Odr::Hz200 => 0x09,
        }
    }
}

/// Sensor settings: ODR and full scales.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config {
    /// Both sensors' ODR.
    pub odr: Odr,
    /// Gyro full scale (°/s): 125, 250, 500, 1000 or 2000.
    pub gyro_range_dps: u16,
    /// Accelerometer full scale (g): 2, 4, 8 or 16.
    pub accel_range_g: u8,
    /// Arduino_BMI270_BMM150's filter settings (bwp OSR2 for both sensors, gyro noise_perf
    /// off, ois_range 2000) instead of the normal bandwidth with both performance modes.
    pub arduino_filters: bool,
}

impl Config {
    /// 100 Hz, ±500 °/s, ±2 g: as close to the LSM9DS1 default as the BMI270 goes.
    pub const DEFAULT: Config = Config { odr: Odr::Hz100, gyro_range_dps: 500, accel_range_g: 2, arduino_filters: false };
    /// What Arduino_BMI270_BMM150 1.2.3's `IMU.begin()` sets (its `configure_sensor`): 100 Hz,
    /// ±2000 °/s, ±4 g, ACC_CONF 0x98, GYR_CONF 0x98 (its noise_perf is an uninitialised field;
    /// 0 taken), GYR_RANGE 0x08.
    pub const ARDUINO: Config = Config { odr: Odr::Hz100, gyro_range_dps: 2000, accel_range_g: 4, arduino_filters: true };

    /// ACC_CONF: the ODR, performance mode, the normal bandwidth (bwp 2, NORMAL_AVG4) or
    /// Arduino's (bwp 1, OSR2_AVG2).
    pub const fn acc_conf(&self) -> u8 {
        let bwp = if self.arduino_filters { 1 } else { 2 };
        0x80 | (bwp << 4) | self.odr.code()
    }

    /// GYR_CONF: the ODR, filter performance mode, and the normal bandwidth (code 2) with noise
    /// performance mode, or Arduino's OSR2 (code 1) without.
    pub const fn gyr_conf(&self) -> u8 {
        if self.arduino_filters {
            0x80 | (1 << 4) | self.odr.code()
        } else {
            0x80 | 0x40 | (2 << 4) | self.odr.code()
        }
    }

    /// ACC_RANGE, or `None` for a full scale the part does not have.
    pub const fn acc_range(&self) -> Option<u8> {
        match self.accel_range_g {
            2 => Some(0),
            4 => Some(1),
            8 => Some(2),
            16 => Some(3),
            _ => None,
        }
    }

    /// GYR_RANGE (with Arduino's filters its ois_range bit 3, ±2000 °/s, as it writes it), or
    /// `None` for a full scale the part does not have.
    pub const fn gyr_range(&self) -> Option<u8> {
        let ois = if self.arduino_filters { 0x08 } else { 0 };
        match self.gyro_range_dps {
            2000 => Some(ois),
            1000 => Some(1 | ois),
            500 => Some(2 | ois),
            250 => Some(3 | ois),
            125 => Some(4 | ois),
            _ => None,
        }
    }

    /// The setup a record states for these settings on the part `sensor`.
    pub fn setup(&self, sensor: Sensor) -> SensorSetup {
        SensorSetup { odr_hz: self.odr.hz(), gyro_range_dps: self.gyro_range_dps as f32, accel_range_g: self.accel_range_g as f32, sensor }
    }

    /// Sensitivities: (°/s per LSB, g per LSB) = range / 32768.
    pub fn per_lsb(&self) -> (f32, f32) {
        (self.gyro_range_dps as f32 / 32768.0, self.accel_range_g as f32 / 32768.0)
    }
}

/// Why the BMI270 could not be used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Bmi270Error {
    /// An I2C transfer failed.
    Bus(BusFault),
    /// Another CHIP_ID at 0x68.
    WrongId(u8),
    /// INTERNAL_STATUS did not read "initialised" after the upload: its message (0 not yet
    /// within the timeout, 2 init error: a wrong upload, 3 driver error, …).
    Init(u8),
    /// A full scale the part does not have.
    BadConfig,
    /// EVENT reports the configuration invalid (1 accelerometer, 2 gyro, 3 both).
    ConfigRejected(u8),
    /// A register did not keep the value written.
    ConfigMismatch {
        /// Register address.
        reg: u8,
        /// Value written.
        wrote: u8,
        /// Value read back.
        read: u8,
    },
}

impl core::fmt::Display for Bmi270Error {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            Bmi270Error::Bus(b) => write!(f, "BMI270 I2C: {b:?}"),
            Bmi270Error::WrongId(id) => write!(f, "CHIP_ID 0x{} at 0x68 is not a BMI270", Hex(id.into(), 2)),
            Bmi270Error::Init(s) => write!(f, "BMI270 not initialised: INTERNAL_STATUS message 0x{} (1 expected)", Hex(s.into(), 1)),
            Bmi270Error::BadConfig => f.write_str("a full scale the BMI270 does not have"),
            Bmi270Error::ConfigRejected(e) => write!(f, "BMI270 rejected its configuration (EVENT error code {})", Int(e.into())),
            Bmi270Error::ConfigMismatch { reg, wrote, read } => {
                write!(f, "BMI270 register 0x{} reads 0x{} after 0x{}", Hex(reg.into(), 2), Hex(read.into(), 2), Hex(wrote.into(), 2))
            }
        }
    }
}

/// GYR_CAS from its byte: 7-bit two's complement, bit 7 not part of it (Bosch's
/// `get_gyro_cross_sense`).
pub const fn gyr_cas(byte: u8) -> i8 {
    let v = byte & 0x7F;
    if v & 0x40 != 0 {
        (v as i16 - 128) as i8
    } else {
        v as i8
    }
}

/// An initialised BMI270.
pub struct Bmi270<I> {
    i2c: I,
    cfg: Config,
    /// The part's factory z→x trim (read once after the configuration load, as Bosch does).
    gyr_cas: i8,
    /// Its gyro user gain was enabled.
    user_gain: bool,
    /// Accelerometer-only frames since PWR_CTRL, until the gyro's first sample; `None` once it
    /// has started.
    starting: Option<usize>,
    /// Sample dating by index: [`SampleIndex`].
    index: SampleIndex,
}

/// Dates the newest frame read by its index on the sensortime's sample grid, robust to the
/// part's data-ready latency (a frame lands in the FIFO some time `L` after its tick): the
/// frames received (samples, lost, one-sensor) are counted modulo the 24-bit count's grid, and
/// the offset `d` = (latest tick at the read) − (frames received) is either `lag` (the newest
/// frame landed) or `lag + 1` (its tick passed, its frame not yet there). Dating each batch by
/// the latest tick alone put a fraction `L / period` of them a period late.
#[derive(Debug, Clone, Copy, Default)]
struct SampleIndex {
    received: u32,
    lag: Option<u32>,
    /// Reads with a sensortime frame since the offset was (re)started.
    reads: u32,
}

/// Reads whose smallest offset is taken before dates are given: all of them miss their
/// newest tick with the probability `(L / period)⁸` (7e-5 for a latency of 3 ms at 100 Hz).
const INDEX_READS: u32 = 8;

impl SampleIndex {
    /// `frames` more received; with the sensortime count `st` of the read (ticks of `tps`
    /// counts), the newest frame's age at `st` (counts).
    fn update(&mut self, frames: usize, st: Option<u32>, tps: u32) -> Option<u32> {
        let m = (1u32 << 24) / tps;
        self.received = ((self.received as u64 + frames as u64) % m as u64) as u32;
        let st = st?;
        let d = (st / tps + m - self.received) % m;
        // The offset holds while d is lag or lag + 1 and falls to d = lag − 1 (the newest tick
        // had not landed in the reads that set it); anything else (the first read, a count
        // beyond a skip frame's 255) starts it anew.
        let lag = match self.lag {
            Some(lag) if d == lag || d == (lag + 1) % m => lag,
            Some(lag) if (d + 1) % m == lag => d,
            _ => {
                self.reads = 0;
                d
            }
        };
        (self.lag, self.reads) = (Some(lag), self.reads.saturating_add(1));
        let newest = (self.received + lag) % m;
        (self.reads >= INDEX_READS).then(|| st.wrapping_sub(newest * tps) & 0x00FF_FFFF)
    }
}

impl<I: I2c> Bmi270<I> {
    /// Identity, soft reset, configuration upload and check, then `cfg`, with every step's wait
    /// as Bosch's API has it. Bounded: a fixed number of transfers and at most
    /// [`INIT_TIMEOUT_MS`] of polling.
    pub fn init(i2c: I, cfg: Config, delay: &mut impl DelayNs) -> Result<Self, (Bmi270Error, I)> {
        let mut s = Self { i2c, cfg, gyr_cas: 0, user_gain: false, starting: Some(0), index: SampleIndex::default() };
        match s.bring_up(delay) {
            Ok(()) => Ok(s),
            Err(e) => Err((e, s.i2c)),
        }
    }

    /// The bus back.
    pub fn release(self) -> I {
        self.i2c
    }

    /// The bus, for the other parts on it (the BMM150).
    pub fn bus_mut(&mut self) -> &mut I {
        &mut self.i2c
    }

    /// The settings it runs at.
    pub fn config(&self) -> Config {
        self.cfg
    }

    /// The part's GYR_CAS (z→x, per 512), read at the bring-up.
    pub fn gyr_cas(&self) -> i8 {
        self.gyr_cas
    }

    /// The part's gyro user gain was on at the bring-up.
    pub fn user_gain(&self) -> bool {
        self.user_gain
    }

    /// The setup a record states: the settings and the part with its GYR_CAS and user gain.
    pub fn setup(&self) -> SensorSetup {
        self.cfg.setup(Sensor::Bmi270 { gyr_cas: self.gyr_cas, user_gain: self.user_gain })
    }

    fn write(&mut self, reg: u8, data: &[u8]) -> Result<(), Bmi270Error> {
        let mut buf = [0u8; 1 + UPLOAD_CHUNK];
        buf[0] = reg;
        buf[1..=data.len()].copy_from_slice(data);
        self.i2c.write(ADDR, &buf[..=data.len()]).map_err(|e| Bmi270Error::Bus(BusFault::of(e)))
    }

    fn read(&mut self, reg: u8, out: &mut [u8]) -> Result<(), Bmi270Error> {
        self.i2c.write_read(ADDR, &[reg], out).map_err(|e| Bmi270Error::Bus(BusFault::of(e)))
    }

    fn read1(&mut self, reg: u8) -> Result<u8, Bmi270Error> {
        let mut b = [0u8];
        self.read(reg, &mut b)?;
        Ok(b[0])
    }

    fn bring_up(&mut self, delay: &mut impl DelayNs) -> Result<(), Bmi270Error> {
        let (Some(acc_range), Some(gyr_range)) = (self.cfg.acc_range(), self.cfg.gyr_range()) else {
            return Err(Bmi270Error::BadConfig);
        };
        // Power save may be on (after power-up, or a probe just before): one access per gap.
        delay.delay_us(APS_GAP_US);
        match self.read1(reg::CHIP_ID)? {
            CHIP_ID => {}
            id => return Err(Bmi270Error::WrongId(id)),
        }
        delay.delay_us(APS_GAP_US);
        self.write(reg::CMD, &[CMD_SOFT_RESET])?;
        delay.delay_ms(RESET_WAIT_MS);
        let mut back = self.read1(reg::CHIP_ID);
        for _ in 0..RESET_POLLS {
            if !matches!(back, Err(Bmi270Error::Bus(_))) {
                break;
            }
            delay.delay_ms(RESET_POLL_MS);
            back = self.read1(reg::CHIP_ID);
        }
        match back? {
            CHIP_ID => {}
            id => return Err(Bmi270Error::WrongId(id)),
        }
        // Advanced power save is on after the reset: one access per 450 µs until it is off.
        delay.delay_us(APS_GAP_US);
        self.write(reg::PWR_CONF, &[0x00])?;
        delay.delay_us(APS_GAP_US);
        self.write(reg::INIT_CTRL, &[0x00])?;
        delay.delay_us(WRITE_GAP_US);
        for (i, chunk) in CONFIG.chunks(UPLOAD_CHUNK).enumerate() {
            let word = (i * UPLOAD_CHUNK / 2) as u16;
            self.write(reg::INIT_ADDR_0, &[(word & 0x0F) as u8, (word >> 4) as u8])?;
            delay.delay_us(WRITE_GAP_US);
            self.write(reg::INIT_DATA, chunk)?;
            delay.delay_us(WRITE_GAP_US);
        }
        self.write(reg::INIT_CTRL, &[0x01])?;
        let mut status = 0;
        for _ in 0..INIT_TIMEOUT_MS / STATUS_POLL_MS {
            delay.delay_ms(STATUS_POLL_MS);
            status = self.read1(reg::INTERNAL_STATUS)? & 0x0F;
            if status != 0 {
                break;
            }
        }
        if status != INIT_OK {
            return Err(Bmi270Error::Init(status));
        }
        // GYR_CAS (as Bosch's API reads it after this configuration's load) and whether the
        // user gain is on: the raw data's terms the record states.
        self.gyr_cas = gyr_cas(self.read1(reg::GYR_CAS)?);
        self.user_gain = self.read1(reg::GYR_OFF_COMP_6)? & 0x80 != 0;
        let c = self.cfg;
        for (r, v) in
            [(reg::ACC_CONF, c.acc_conf()), (reg::ACC_RANGE, acc_range), (reg::GYR_CONF, c.gyr_conf()), (reg::GYR_RANGE, gyr_range)]
        {
            self.write_checked(r, v, delay)?;
        }
        match (self.read1(reg::EVENT)? >> 2) & 0x07 {
            0 => {}
            e => return Err(Bmi270Error::ConfigRejected(e)),
        }
        // Advanced power save stays off (Bosch turns it back on; then every access would need
        // its 450 µs gap).
        self.write(reg::PWR_CTRL, &[PWR_CTRL_ON])?;
        delay.delay_us(WRITE_GAP_US);
        // FIFO_DOWNS is written, not assumed: its reset value is the filtered, full-rate data.
        for (r, v) in
            [(reg::FIFO_DOWNS, FIFO_DOWNS_FILTERED), (reg::FIFO_CONFIG_0, FIFO_TIME_EN), (reg::FIFO_CONFIG_1, FIFO_HEADER_ACC_GYR)]
        {
            self.write_checked(r, v, delay)?;
        }
        Ok(())
    }

    /// Writes `v` to `r` and reads it back ([`WRITE_GAP_US`] after the write), its reserved
    /// bits masked ([`defined_bits`]).
    fn write_checked(&mut self, r: u8, v: u8, delay: &mut impl DelayNs) -> Result<(), Bmi270Error> {
        self.write(r, &[v])?;
        delay.delay_us(WRITE_GAP_US);
        let read = self.read1(r)?;
        let mask = defined_bits(r);
        if read & mask != v & mask {
            return Err(Bmi270Error::ConfigMismatch { reg: r, wrote: v, read });
        }
        Ok(())
    }

    /// Reads the whole FIFO and the sensortime frame after it (one burst, [`FIFO_OVER_READ`]
    /// bytes past FIFO_LENGTH) and hands each sample to `each` as (accelerometer g, gyro °/s),
    /// oldest first: how many, how many were lost (dropped by a full FIFO), and the sensortime.
    pub fn read_fifo(&mut self, each: impl FnMut([f32; 3], [f32; 3])) -> Result<FifoRead, Bmi270Error> {
        let mut len = [0u8; 2];
        self.read(reg::FIFO_LENGTH_0, &mut len)?;
        let n = (u16::from_le_bytes([len[0], len[1] & 0x3F]) as usize).min(FIFO_BYTES);
        let mut buf = [0u8; FIFO_BYTES + FIFO_OVER_READ];
        if n == 0 {
            return Ok(FifoRead::default());
        }
        let n = n + FIFO_OVER_READ;
        self.read(reg::FIFO_DATA, &mut buf[..n])?;
        let mut r = parse_fifo(&buf[..n], self.cfg.per_lsb(), each);
        let tps = self.cfg.odr.ticks_per_sample();
        let age = self.index.update(r.samples + r.lost + r.partial, r.sensortime, tps);
        r.newest_age_us = age.filter(|&a| a < 4 * tps).map(|a| (a * SENSORTIME_US.0 + SENSORTIME_US.1 / 2) / SENSORTIME_US.1);
        // The gyro's start-up: one sensor's frames before its first sample are no loss.
        if let Some(before) = self.starting {
            let (frames, started) = (before + r.partial, r.samples > 0);
            self.starting = (!started).then_some(frames);
            r.gyro_started_after = started.then_some(frames);
            r.partial = 0;
        }
        Ok(r)
    }

    /// The die temperature (°C) from TEMPERATURE_0/1 (0x22/0x23: int16 little-endian, 23 °C +
    /// raw / 512; Bosch's `bmi2_get_temperature_data`), `None` while the part reports 0x8000
    /// (invalid: no conversion yet). New every 10 ms with the gyro on.
    pub fn temperature_c(&mut self) -> Result<Option<f32>, Bmi270Error> {
        let mut b = [0u8; 2];
        self.read(reg::TEMPERATURE_0, &mut b)?;
        Ok(temperature_c(i16::from_le_bytes(b)))
    }

    /// The latest sample from the data registers: (accelerometer g, gyro °/s), board frame
    /// ([`calib_core::board::BMI270`]: `(y, −x, z)` of Bosch's axes).
    pub fn read_sample(&mut self) -> Result<([f32; 3], [f32; 3]), Bmi270Error> {
        let mut b = [0u8; 12];
        self.read(reg::ACC_X_LSB, &mut b)?;
        let v = |i: usize| i16::from_le_bytes([b[2 * i], b[2 * i + 1]]) as f32;
        let (dps, g) = self.cfg.per_lsb();
        Ok(([v(1) * g, -v(0) * g, v(2) * g], [v(4) * dps, -v(3) * dps, v(5) * dps]))
    }
}

/// A TEMPERATURE_0/1 value in °C (raw / 512 + 23), `None` for 0x8000 (invalid).
pub fn temperature_c(raw: i16) -> Option<f32> {
    (raw != i16::MIN).then(|| raw as f32 / 512.0 + 23.0)
}

/// What one FIFO read gave.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FifoRead {
    /// Samples handed on.
    pub samples: usize,
    /// Samples lost (skip frames: a full FIFO dropped them).
    pub lost: usize,
    /// The read that brought the gyro's first sample since the bring-up: after how many frames
    /// of the accelerometer alone (its start-up, [`Bmi270::read_fifo`]; not counted as
    /// [`Self::partial`]).
    pub gyro_started_after: Option<usize>,
    /// Frames of one sensor alone (0x84 accelerometer, 0x88 gyro: the other not producing, as
    /// while the gyro starts after PWR_CTRL): no sample pair, a hole in the series.
    pub partial: usize,
    /// The sensortime frame's count (24 bit, [`SENSORTIME_US`] each): the part's time when the
    /// burst had read the FIFO empty; `None` without one.
    pub sensortime: Option<u32>,
    /// How long before the sensortime frame the newest frame read was produced (s, at the
    /// nominal count rate; its ≤ 2 % error is ≤ 0.2 ms of a 10 ms period), dated by its index on
    /// the sample grid ([`Bmi270::read_fifo`]); `None` without a sensortime frame, in the first
    /// reads after the bring-up (the grid not yet known) or from [`parse_fifo`] alone: the
    /// read's time minus this is the newest sample's.
    pub newest_age_us: Option<u32>,
}

/// Parses header-mode FIFO bytes (Bosch's frame layout) with the sensitivities `(°/s, g)` per
/// LSB, each sample to `each` (accelerometer g, gyro °/s, board frame: [`calib_core::board::BMI270`]).
pub fn parse_fifo(bytes: &[u8], (dps, g): (f32, f32), mut each: impl FnMut([f32; 3], [f32; 3])) -> FifoRead {
    let mut r = FifoRead::default();
    let mut i = 0;
    let v = |b: &[u8], k: usize| i16::from_le_bytes([b[2 * k], b[2 * k + 1]]) as f32;
    while i < bytes.len() {
        // Bits 1:0 are interrupt tags.
        let (header, rest) = (bytes[i] & 0xFC, &bytes[i + 1..]);
        let payload = match header {
            FRAME_ACC_GYR => 12,
            FRAME_ACC | FRAME_GYR => 6,
            FRAME_SKIP => 1,
            FRAME_SENSORTIME => 3,
            FRAME_CONFIG => 4,
            // Over-read, or an unknown header: the end of the data.
            _ => break,
        };
        // A frame the burst cut: the part repeats it whole in the next burst (Bosch's parser
        // skips a partially read frame), so it is not lost.
        if rest.len() < payload {
            break;
        }
        match header {
            FRAME_ACC_GYR => {
                // [`calib_core::board::BMI270`]: (y, −x, z); the gyro's bytes come first.
                each([v(rest, 4) * g, -v(rest, 3) * g, v(rest, 5) * g], [v(rest, 1) * dps, -v(rest, 0) * dps, v(rest, 2) * dps]);
                r.samples += 1;
            }
            FRAME_ACC | FRAME_GYR => r.partial += 1,
            FRAME_SKIP => r.lost += rest[0] as usize,
            FRAME_SENSORTIME => r.sensortime = Some(u32::from_le_bytes([rest[0], rest[1], rest[2], 0])),
            _ => {}
        }
        i += 1 + payload;
    }
    r
}
