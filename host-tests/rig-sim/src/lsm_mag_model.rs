//! A register-level model of the LSM9DS1's magnetometer (I2C 0x1E on the Nano 33 BLE Rev1), fed
//! the rig's field readings: what the firmware's `lsm9ds1_mag` driver talks to on the host.
//!
//! Modelled from the datasheet (ST DocID025715 §8, Tables 21–22 and 107–124; the facts and their
//! sources: `docs/mag-sources.md`): WHO_AM_I_M 0x3D; the reset values (CTRL_REG1_M 0x10,
//! CTRL_REG3_M 0x03 = power-down: no conversion until MD is written, INT_CFG_M 0x08);
//! REBOOT/SOFT_RST (CTRL_REG2_M bits 3 and 2) restore them and clear themselves; MD = 00
//! converts continuously at DO (0.625–80 Hz; LP forces 0.625 Hz), 01 once and then powers down,
//! 1x not at all; FS sets the sensitivity (0.14, 0.29, 0.43, 0.58 mgauss/LSB); each conversion
//! sets ZYXDA (STATUS_REG_M bit 3), or ZYXOR (bit 7) as well when the previous set was not read.
//!
//! Strict where the part is, or where the datasheet leaves it open and a driver must not rely
//! on it: a multi-byte read auto-increments only with the sub-address's bit 7 set (§5.1.1;
//! without it every byte is the same register); ZYXDA and ZYXOR clear when OUT_Z_H_M (0x2D),
//! the last output byte, is read; the output registers read 0 until the first conversion; after
//! a reboot or reset the part does not acknowledge for [`BOOT_S`] (no figure in the datasheet:
//! the LSM9DS1 model's, Arduino's library waits 10 ms); read-only registers ignore writes.
//! Readings enter in the accelerometer's axes (the rig's) and are turned into the part's
//! (x = −x_acc, Figure 1) and its counts at the configured full scale, saturated at `i16`.

use crate::lsm_model::BusError;
use embedded_hal::i2c::{ErrorKind, NoAcknowledgeSource, Operation};

/// I2C address.
pub const ADDR: u8 = 0x1E;
/// How long the part does not answer after REBOOT or SOFT_RST (s): the LSM9DS1 model's.
pub const BOOT_S: f64 = crate::lsm_model::BOOT_S;

const WHO_AM_I: u8 = 0x0F;
const CTRL_REG1: u8 = 0x20;
const CTRL_REG2: u8 = 0x21;
const CTRL_REG3: u8 = 0x22;
const STATUS: u8 = 0x27;
const OUT_X_L: u8 = 0x28;
const OUT_Z_H: u8 = 0x2D;
const INT_CFG: u8 = 0x30;
/// Registers that ignore writes: WHO_AM_I, STATUS, the outputs, INT_SRC and the thresholds'
/// read-only neighbours.
const READ_ONLY: [u8; 9] = [WHO_AM_I, STATUS, 0x28, 0x29, 0x2A, 0x2B, 0x2C, 0x2D, 0x31];

/// The model.
#[derive(Debug, Clone)]
pub struct LsmMagModel {
    regs: [u8; 0x40],
    /// Does not acknowledge before this true time (s).
    busy_until: f64,
    /// Conversions made (readings accepted from the rig).
    conversions: usize,
    /// Software resets and reboots received.
    resets: usize,
}

impl LsmMagModel {
    /// Powered up at true time `now_s` (busy for [`BOOT_S`]).
    pub fn new(now_s: f64) -> Self {
        let mut m = Self { regs: [0; 0x40], busy_until: now_s + BOOT_S, conversions: 0, resets: 0 };
        m.reset_registers();
        m
    }

    fn reset_registers(&mut self) {
        self.regs = [0; 0x40];
        self.regs[WHO_AM_I as usize] = 0x3D;
        self.regs[CTRL_REG1 as usize] = 0x10;
        self.regs[CTRL_REG3 as usize] = 0x03;
        self.regs[INT_CFG as usize] = 0x08;
    }

    /// A register value.
    pub fn reg(&self, r: u8) -> u8 {
        self.regs[(r & 0x3F) as usize]
    }

    /// Conversions made since power-up.
    pub fn conversions(&self) -> usize {
        self.conversions
    }

    /// REBOOT/SOFT_RST commands received.
    pub fn resets(&self) -> usize {
        self.resets
    }

    /// Whether it acknowledges at true time `t_s`.
    pub fn acks_at(&self, t_s: f64) -> bool {
        t_s >= self.busy_until
    }

    /// The conversion rate the registers ask for (Hz), `None` while powered down.
    pub fn odr_hz(&self) -> Option<f64> {
        let md = self.reg(CTRL_REG3) & 0x03;
        if md >= 2 {
            return None;
        }
        if self.reg(CTRL_REG3) & 0x20 != 0 {
            return Some(0.625);
        }
        Some([0.625, 1.25, 2.5, 5.0, 10.0, 20.0, 40.0, 80.0][((self.reg(CTRL_REG1) >> 2) & 7) as usize])
    }

    /// Sensitivity at the configured full scale (µT per LSB).
    fn ut_per_lsb(&self) -> f64 {
        [0.014, 0.029, 0.043, 0.058][((self.reg(CTRL_REG2) >> 5) & 3) as usize]
    }

    /// A reading of the rig (µT, board frame) at its time: converted if the part is converting
    /// (a single conversion then powers it down).
    pub fn convert(&mut self, m_board_ut: [f32; 3]) {
        let md = self.reg(CTRL_REG3) & 0x03;
        if md >= 2 {
            return;
        }
        let lsb = self.ut_per_lsb();
        // In the accelerometer's raw axes ([`crate::lsm_model::Lsm9ds1Model::raw_axes`]), then the
        // magnetometer's: its x is the accelerometer's −x (DocID025715 Figure 1).
        let acc = crate::lsm_model::Lsm9ds1Model::raw_axes(m_board_ut);
        let part = [-(acc[0] as f64), acc[1] as f64, acc[2] as f64];
        for (k, v) in part.iter().enumerate() {
            let c = (v / lsb).round().clamp(i16::MIN as f64, i16::MAX as f64) as i16;
            let at = OUT_X_L as usize + 2 * k;
            self.regs[at..at + 2].copy_from_slice(&c.to_le_bytes());
        }
        let status = self.regs[STATUS as usize];
        self.regs[STATUS as usize] = if status & 0x08 != 0 { 0x88 | 0x77 & status } else { 0x08 | status };
        self.conversions += 1;
        if md == 1 {
            self.regs[CTRL_REG3 as usize] |= 0x03;
        }
    }

    fn read_byte(&mut self, r: u8) -> u8 {
        let v = self.reg(r);
        if r & 0x3F == OUT_Z_H {
            self.regs[STATUS as usize] = 0;
        }
        v
    }

    fn write_byte(&mut self, r: u8, v: u8, now_s: f64) {
        let r = r & 0x3F;
        if READ_ONLY.contains(&r) {
            return;
        }
        if r == CTRL_REG2 && v & 0x0C != 0 {
            // REBOOT or SOFT_RST: registers back to their reset values, both bits clear
            // themselves; the part is busy meanwhile.
            self.reset_registers();
            self.regs[CTRL_REG2 as usize] = v & !0x0C;
            self.resets += 1;
            self.busy_until = now_s + BOOT_S;
            return;
        }
        self.regs[r as usize] = v;
    }

    /// One I2C transaction at true time `now_s` (the address already acknowledged).
    pub fn transaction(&mut self, operations: &mut [Operation<'_>], now_s: f64) -> Result<(), BusError> {
        if !self.acks_at(now_s) {
            return Err(BusError(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address)));
        }
        let mut ptr: Option<u8> = None;
        for op in operations.iter_mut() {
            match op {
                Operation::Write(bytes) => {
                    let mut it = bytes.iter();
                    if let Some(&r) = it.next() {
                        ptr = Some(r);
                    }
                    for &b in it {
                        let r = ptr.unwrap_or(0);
                        self.write_byte(r, b, now_s);
                        ptr = Some(next(r));
                    }
                }
                Operation::Read(buf) => {
                    for b in buf.iter_mut() {
                        let r = ptr.unwrap_or(0);
                        *b = self.read_byte(r);
                        ptr = Some(next(r));
                    }
                }
            }
        }
        Ok(())
    }
}

/// The next sub-address: incremented only with bit 7 set (which it keeps).
fn next(r: u8) -> u8 {
    if r & 0x80 != 0 {
        0x80 | ((r & 0x7F) + 1) & 0x7F
    } else {
        r
    }
}
