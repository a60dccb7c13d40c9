//! The hardware-independent half of the Nano 33 BLE firmware: everything between the raw
//! peripherals and `calib_core::procedure`, testable on the host.
//!
//! - [`bootloader`]: which Arduino bootloader, and whether the record pages are safe to write.
//! - [`lsm9ds1`]: sensor identity, configuration, FIFO and conversion over embedded-hal I2C;
//!   [`lsm9ds1_mag`]: its magnetometer; [`bmi270`]: the Rev2 board's IMU brought up as Bosch's
//!   API does it; [`bmm150`]: its magnetometer, with Bosch's trim compensation.
//! - [`watch`]: the magnetometers' stopped and stuck checks.
//! - [`stamp`]: MCU timestamps for FIFO batches from the measured sample period.
//! - [`storage`]: the power-fail-safe A/B record slots over embedded-storage NOR flash.
//! - [`button`]: debouncing; [`led`]: the LED patterns.
//! - `mem` (target only): the small `memcpy`, `memclr` and `memcmp` the linker takes.
//! - [`rtt`]: the never-blocking defmt RTT logger.
//! - [`serial`]: the USB serial console's outbox, commands and 1200-baud touch; `usb` (target
//!   only): the CDC-ACM port over the USBD.
//! - `board` (target only): the Nano 33 BLE's bring-up (bootloader clean-up, crystal, clock,
//!   watchdog, sensor rail and bus, LEDs).
#![no_std]
#![deny(missing_docs)]

pub mod bmi270;
pub mod bmm150;
#[cfg(target_os = "none")]
pub mod board;
pub mod bootloader;
pub mod button;
pub mod led;
pub mod lsm9ds1;
pub mod lsm9ds1_mag;
#[cfg(target_os = "none")]
pub mod mem;
pub mod rtt;
pub mod serial;
pub mod stamp;
pub mod storage;
#[cfg(target_os = "none")]
pub mod usb;
pub mod watch;
