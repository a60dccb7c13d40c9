//! Bosch BMM150 magnetometer (the Nano 33 BLE Rev2's, at 0x10 on the same internal bus as the
//! BMI270): found and left in suspend, its lowest-power mode, as Bosch's BMM150_SensorAPI v2.0.0
//! does it (every step and its source: `docs/rev2-sources.md` §6).
//!
//! The part powers up in suspend mode, where only POWER_CONTROL (0x4B) answers: CHIP_ID can only
//! be read once 0x4B bit 0 is set (datasheet BST-BMM150-DS001 §5.3), which takes the part to
//! sleep mode after a start-up time (`BMM150_START_UP_TIME`, 3 ms, in Bosch's `bmm150_init`).
//! Clearing the bit brings it back to suspend (datasheet §4.2.3; Bosch's
//! `bmm150_set_op_mode(BMM150_POWERMODE_SUSPEND)`). The firmware never measures the magnetic
//! field: [`detect_and_suspend`] is all it does with the part.

use crate::lsm9ds1::BusFault;
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
    /// OP_MODE: bits 2:1 the operation mode (00 normal, 01 forced, 11 sleep).
    pub const OP_MODE: u8 = 0x4C;
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

/// Why the BMM150 was not found suspended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Bmm150Error {
    /// An I2C transfer failed: `Bus(BusFault::Nack)` at the first transfer is no BMM150 at 0x10.
    Bus(BusFault),
    /// Another CHIP_ID at 0x10, read 3 ms after setting the power bit (0x00: the part did not
    /// leave suspend). POWER_CONTROL was written back as it was read.
    WrongId(u8),
    /// POWER_CONTROL, read back after clearing the power bit: bit 0 still set.
    NotSuspended(u8),
}

impl core::fmt::Display for Bmm150Error {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            Bmm150Error::Bus(BusFault::Nack) => f.write_str("no BMM150: nothing acknowledges 0x10"),
            Bmm150Error::Bus(b) => write!(f, "BMM150 I2C: {b:?}"),
            Bmm150Error::WrongId(id) => write!(f, "CHIP_ID 0x{id:02X} at 0x10 is not a BMM150 (0x32)"),
            Bmm150Error::NotSuspended(v) => write!(f, "BMM150 POWER_CONTROL reads 0x{v:02X} after suspend (bit 0 set)"),
        }
    }
}

fn read1<I: I2c>(i2c: &mut I, r: u8) -> Result<u8, Bmm150Error> {
    let mut b = [0u8];
    i2c.write_read(ADDR, &[r], &mut b).map_err(|e| Bmm150Error::Bus(BusFault::of(e)))?;
    Ok(b[0])
}

fn write1<I: I2c>(i2c: &mut I, r: u8, v: u8) -> Result<(), Bmm150Error> {
    i2c.write(ADDR, &[r, v]).map_err(|e| Bmm150Error::Bus(BusFault::of(e)))
}

/// Finds the BMM150 at 0x10 and leaves it in suspend mode, as Bosch's API does: sets the power
/// bit (read-modify-write of POWER_CONTROL, as `set_power_control_bit`), waits [`START_UP_MS`],
/// checks CHIP_ID, clears the power bit (read-modify-write) and reads POWER_CONTROL back.
///
/// Bounded: six transfers (seven on [`Bmm150Error::WrongId`], which writes POWER_CONTROL back as
/// it was found) and one 3 ms wait; no loop. A bus fault ends it at once.
pub fn detect_and_suspend<I: I2c>(i2c: &mut I, delay: &mut impl DelayNs) -> Result<(), Bmm150Error> {
    let found = read1(i2c, reg::POWER_CONTROL)? & !SOFT_RESET_BITS;
    write1(i2c, reg::POWER_CONTROL, found | POWER_BIT)?;
    delay.delay_ms(START_UP_MS);
    match read1(i2c, reg::CHIP_ID)? {
        CHIP_ID => {}
        id => {
            // Not a BMM150 (or it did not wake): leave its register as it was, best effort.
            let _ = write1(i2c, reg::POWER_CONTROL, found);
            return Err(Bmm150Error::WrongId(id));
        }
    }
    let awake = read1(i2c, reg::POWER_CONTROL)? & !SOFT_RESET_BITS;
    write1(i2c, reg::POWER_CONTROL, awake & !POWER_BIT)?;
    match read1(i2c, reg::POWER_CONTROL)? {
        v if v & POWER_BIT != 0 => Err(Bmm150Error::NotSuspended(v)),
        _ => Ok(()),
    }
}
