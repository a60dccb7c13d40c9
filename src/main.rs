//! Nano 33 BLE gyroscope self-calibration firmware (I/O shell around `calib-core`).
//!
//! This is the boot skeleton: clocks up, one defmt line, sleep. The I/O shell that feeds the
//! calib-core procedure (sensor, servo, button, flash) is tracked in its own issue.
#![no_std]
#![no_main]

use defmt_rtt as _;
use nrf52840_hal as hal;
use panic_probe as _;

#[cortex_m_rt::entry]
fn main() -> ! {
    let p = hal::pac::Peripherals::take().unwrap();
    // High-frequency crystal: the MCU clock is the time base of every gyro integral.
    let _clocks = hal::Clocks::new(p.CLOCK).enable_ext_hfosc();
    defmt::info!("gyrocal-fw {} booted", env!("CARGO_PKG_VERSION"));
    loop {
        cortex_m::asm::wfi();
    }
}
