//! Virtual Nano 33 BLE: the real firmware ELF on an emulated Cortex-M4F (Unicorn) with models
//! of the nRF52840 peripherals it touches and of the LSM9DS1, fed by the rig simulator.
//!
//! GPL-2.0 (Unicorn's licence) applies to this crate only; the firmware and calib-core keep
//! the project's licence.

#![deny(missing_docs)]

pub mod elf;
pub mod mcu;
pub mod periph;
pub mod pty;
pub mod testbed;
pub mod usb_host;
