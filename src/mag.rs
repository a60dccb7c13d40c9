//! The board's magnetometer, whichever it is: the LSM9DS1's on a Rev1
//! ([`gyrocal_fw::lsm9ds1_mag`]), the BMM150 on a Rev2 ([`gyrocal_fw::bmm150`]). Brought up once
//! the IMU answers, read every FIFO poll, brought up again every 2 s after a failure; a failure is
//! said once with its cause and is never fatal to the gyro's calibration (the procedure says what
//! the missing readings cost).

use crate::console::Console;
use calib_core::formats::text::Level as Log;
use calib_core::Time;
use core::fmt;
use embedded_hal::i2c::I2c;
use gyrocal_fw::bmm150::{self, Bmm150};
use gyrocal_fw::board::{Clock, Wait};
use gyrocal_fw::lsm9ds1_mag::{self, LsmMag};

/// How long after a failure the part is brought up again (s).
const RETRY_S: f32 = 2.0;

/// A configured part.
enum Part {
    Lsm(LsmMag),
    Bmm(Bmm150),
}

/// Either part's failure.
#[derive(Clone, Copy, PartialEq)]
enum Error {
    Lsm(lsm9ds1_mag::Error),
    Bmm(bmm150::ReadError),
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Lsm(e) => e.fmt(f),
            Error::Bmm(e) => e.fmt(f),
        }
    }
}

/// The magnetometer and its bring-up state.
pub(crate) struct Magnetometer {
    part: Option<Part>,
    next_try: Time,
    last_error: Option<Error>,
}

impl Magnetometer {
    pub(crate) const fn new() -> Self {
        Self { part: None, next_try: Time::ZERO, last_error: None }
    }

    /// Forgets the part (the IMU is being brought up again; so is the magnetometer, at once).
    pub(crate) fn reset(&mut self) {
        (self.part, self.next_try) = (None, Time::ZERO);
    }

    /// One poll at `now` on the IMU's bus: brings the part up (a Rev2's BMM150, else the
    /// LSM9DS1's) or reads it; a new reading (µT, the accelerometer's axes).
    pub(crate) fn poll<I: I2c>(
        &mut self,
        bus: &mut I,
        rev2: bool,
        now: Time,
        clock: &mut Clock,
        console: &mut Console,
    ) -> Option<[f32; 3]> {
        let t_us = clock.now_us();
        let result = match self.part.as_mut() {
            Some(Part::Lsm(m)) => m.read(bus, t_us).map_err(Error::Lsm),
            Some(Part::Bmm(m)) => m.read(bus, t_us).map_err(Error::Bmm),
            None if now >= self.next_try => {
                let up = if rev2 {
                    Bmm150::init(bus, bmm150::Config::HIGH_ACCURACY, &mut Wait(clock), t_us).map(Part::Bmm).map_err(Error::Bmm)
                } else {
                    LsmMag::init(bus, lsm9ds1_mag::Config::DEFAULT, &mut Wait(clock), t_us).map(Part::Lsm).map_err(Error::Lsm)
                };
                up.map(|p| {
                    console.send(
                        Log::Info,
                        match p {
                            Part::Lsm(_) => "LSM9DS1 magnetometer ready: 40 Hz, +-4 gauss, ultra-high performance",
                            Part::Bmm(_) => "BMM150 ready: trim read, high-accuracy preset (nXY 47, nZ 83), 20 Hz",
                        },
                    );
                    self.part = Some(p);
                    self.last_error = None;
                    None
                })
            }
            None => Ok(None),
        };
        result.unwrap_or_else(|e| {
            if self.last_error != Some(e) {
                console.say(Log::Warn, format_args!("{e}; calibrating without it, retrying every 2 s"));
            }
            (self.last_error, self.part, self.next_try) = (Some(e), None, now.plus_s(RETRY_S));
            None
        })
    }
}
