//! An example of your own firmware using the calibration: it finds the record the calibration
//! firmware stored at 0xF8000 (the pages survive the upload of this program), runs the LSM9DS1
//! at the setup the record was made at, and logs over RTT once a second the calibrated rate
//! `K (g − b)` (°/s, 1 s mean) and the angle turned since boot (°, the calibrated rate
//! integrated), and with the record's magnetometer calibration the tilt-compensated heading
//! (°, clockwise from magnetic north: the calibrated accelerometer's 1 s mean and the
//! calibrated field, `calib_core::estimators::mag::heading_deg`). Without a valid record, or one
//! made at a setup this driver cannot run, it says so and logs the raw rate instead.
//!
//! `cargo run --release --bin calibrated-rates` (probe), or its .bin through the bootloader.
#![no_std]
#![no_main]

use calib_core::estimators::mag::heading_deg;
use calib_core::formats::record::{Record, SensorSetup};
use calib_core::formats::region::{self, ADDRESS, PAGE, SLOTS};
use calib_core::math::stats::Moments3;
use calib_core::math::vec3::to_real;
use calib_core::Time;
use gyrocal_fw::board::{self, quiesce, start_hfxo, Clock, Wait};
use gyrocal_fw::lsm9ds1::{Lsm9ds1, SensorConfig, FIFO_DEPTH};
use gyrocal_fw::lsm9ds1_mag::{self, LsmMag};
use gyrocal_fw::stamp::Stamper;
use hal::pac::{self, interrupt};
use nrf52840_hal as hal;
use panic_probe as _;

/// Watchdog timeout (s).
const WATCHDOG_S: u32 = 2;
/// FIFO read period (µs): the loop sleeps between reads.
const POLL_US: u32 = 10_000;

/// The newest valid record in the two pages at 0xF8000.
fn stored() -> Option<Record> {
    // SAFETY: the record pages are memory-mapped flash, read only.
    let pages = unsafe { core::slice::from_raw_parts(ADDRESS as *const u8, SLOTS * PAGE) };
    region::load(pages, PAGE).map(|(_, r)| r)
}

#[interrupt]
fn TIMER2() {
    board::tick_handled();
}

#[cortex_m_rt::entry]
fn main() -> ! {
    let (Some(p), Some(mut core)) = (pac::Peripherals::take(), cortex_m::Peripherals::take()) else {
        cortex_m::peripheral::SCB::sys_reset();
    };
    quiesce(&p, &mut core);
    if !start_hfxo(&p.CLOCK) {
        defmt::error!("the 32 MHz crystal did not start; resetting");
        cortex_m::peripheral::SCB::sys_reset();
    }
    let Some(mut wd) = board::watchdog(p.WDT, WATCHDOG_S) else {
        cortex_m::peripheral::SCB::sys_reset();
    };
    let mut clock = Clock::start(p.TIMER1);
    let _tick = board::start_tick(p.TIMER2, POLL_US, &mut core);
    let (p0, p1) = (hal::gpio::p0::Parts::new(p.P0), hal::gpio::p1::Parts::new(p.P1));
    let mut bus = board::sensor_bus(p0.p0_22, p1.p1_00, p0.p0_15, p0.p0_14, p.TWIM0, &mut clock);

    let rec = stored();
    let config = match rec {
        Some(r) => match SensorConfig::of(&r.setup) {
            Some(c) => {
                defmt::info!(
                    "record {=u32} loaded: K made at {=f32} Hz, +-{=f32} dps, +-{=f32} g",
                    r.seq,
                    r.setup.odr_hz,
                    r.setup.gyro_range_dps,
                    r.setup.accel_range_g
                );
                c
            }
            None => {
                defmt::warn!("record {=u32} was made at a setup this driver cannot run: raw rates", r.seq);
                SensorConfig::DEFAULT
            }
        },
        None => {
            defmt::warn!("no valid calibration record at 0xF8000: raw rates");
            SensorConfig::DEFAULT
        }
    };
    // Applied only at the setup it was made at.
    let rec = rec.filter(|r| SensorConfig::of(&r.setup) == Some(config));
    let apply = |g| rec.as_ref().map_or(g, |r| r.apply_gyro(g));

    let mut sensor = loop {
        match Lsm9ds1::init(bus, config, &mut Wait(&mut clock)) {
            Ok(s) => break s,
            Err((e, b)) => {
                defmt::error!("LSM9DS1: {}; retrying", e);
                bus = b;
                let t0 = clock.now_us();
                while clock.now_us() - t0 < 500_000 {}
                wd.pet();
            }
        }
    };
    let setup: SensorSetup = config.setup();
    let mut stamper = Stamper::new(setup.odr_hz);
    let (mut rate, mut turned_deg, mut last_t) = (Moments3::new(), [0.0f64; 3], None::<Time>);
    // The heading needs the record's magnetometer calibration and the part.
    let mag_cal = rec.and_then(|r| r.mag);
    let t_us = clock.now_us();
    let mut mag = mag_cal.and_then(|_| match LsmMag::init(sensor.bus_mut(), lsm9ds1_mag::Config::DEFAULT, &mut Wait(&mut clock), t_us) {
        Ok(m) => Some(m),
        Err(e) => {
            defmt::warn!("{}: no heading", e);
            None
        }
    });
    let (mut gravity, mut field) = (Moments3::new(), None::<[f32; 3]>);
    let mut next_line = clock.now_us() + 1_000_000;
    loop {
        board::sleep();
        wd.pet();
        let now = clock.now_us();
        let status = match sensor.fifo_status() {
            Ok(s) => s,
            Err(e) => {
                defmt::error!("LSM9DS1 read failed: {}", e);
                continue;
            }
        };
        if status.overrun {
            stamper.restart();
            last_t = None;
        }
        if let Some(m) = mag.as_mut() {
            match m.read(sensor.bus_mut(), now) {
                Ok(Some(r)) => field = Some(r),
                Ok(None) => {}
                Err(e) => {
                    defmt::warn!("{}: no heading from now on", e);
                    mag = None;
                }
            }
        }
        let n = status.level.min(FIFO_DEPTH) as usize;
        let batch = stamper.batch(clock.now(), n);
        for i in 0..n {
            let Ok(slot) = sensor.read_slot() else {
                // The samples left in the FIFO would be stamped as the next batch's: start over.
                defmt::error!("LSM9DS1 read failed");
                stamper.restart();
                last_t = None;
                break;
            };
            let (accel_g, gyro_dps) = sensor.convert(&slot);
            let w = apply(gyro_dps);
            if let Some(r) = rec.as_ref() {
                gravity.add(r.accel().apply(accel_g));
            }
            let t = batch.stamp(i);
            if let Some(t0) = last_t {
                for k in 0..3 {
                    turned_deg[k] += w[k] as f64 * t.since(t0) as f64;
                }
            }
            last_t = Some(t);
            rate.add(w);
        }
        if now >= next_line && rate.count() > 0 {
            next_line += 1_000_000;
            let m = rate.mean();
            let cal = if rec.is_some() { "calibrated" } else { "raw" };
            defmt::info!(
                "rate [{} {} {}] dps ({=str}, 1 s mean); turned [{} {} {}] deg since boot",
                m[0],
                m[1],
                m[2],
                cal,
                turned_deg[0],
                turned_deg[1],
                turned_deg[2]
            );
            rate = Moments3::new();
            if let (Some(c), Some(m), true) = (mag_cal, field, gravity.count() > 0) {
                let f = gravity.mean();
                if let Some(h) = heading_deg(to_real(f), to_real(c.apply(m))) {
                    defmt::info!("heading {} deg (tilt-compensated, clockwise from magnetic north)", h);
                }
            }
            gravity = Moments3::new();
        }
    }
}
