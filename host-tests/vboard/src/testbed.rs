//! A testbed around the emulated board: the simulated rig, an operator who presses the button and
//! does what the firmware's log asks (hand-held poses, re-clamping), and readers of the result.

use crate::elf::Firmware;
use crate::mcu::{Mcu, Stop};
use crate::periph::{Leds, Periph};
use crate::pty::PtyBridge;
use calib_core::formats::record::Record;
use rig_sim::harness::operator_attitudes;
use rig_sim::lsm_model::{Board, Lsm9ds1Model};
use rig_sim::nor::NorSim;
use rig_sim::sim::{Rig, RigConfig};
use std::cell::Cell;
use std::rc::Rc;

/// The message text of a decoded log line, as `probe-rs run --log-format "{s}"` prints it
/// (the level word dropped).
pub fn message(line: &str) -> &str {
    match line.split_once(' ') {
        Some((level, m)) if ["TRACE", "DEBUG", "INFO", "WARN", "ERROR"].contains(&level) => m,
        _ => line,
    }
}

/// Builds the release firmware with `features` ([`calib::firmware::build`]) and returns the ELF
/// bytes.
pub fn build_firmware(features: &[&str]) -> Result<Vec<u8>, String> {
    let path = calib::firmware::build(features)?;
    std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))
}

/// How a calibration attempt ended.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    /// The LEDs show "done: stored and applied" (green, D13 on).
    Done,
    /// The LEDs show an error (red): its class, the number of D13 flashes in a group (1 sensor,
    /// 2 motion, 3 servo, 4 geometry, 5 result, 6 timeout, 7 storage).
    Failed(u8),
    /// The emulation stopped.
    Stopped(Stop),
    /// Neither within the time limit.
    Timeout,
}

/// What the operator did, as fault injection sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Event {
    /// They hold the board still in hand-held orientation `n` (0-based).
    HandHeldPose(usize),
    /// They clamped the board back on the shaft and pressed the button.
    Reattached,
    /// Every 50 ms: seconds since [`Event::Reattached`] (or since the start, before it).
    Tick(f64),
}

/// The emulated board on the simulated rig, with an operator.
pub struct Testbed {
    /// The board.
    pub mcu: Mcu,
    printed: usize,
    /// Print log lines as they come.
    pub echo: bool,
    /// The board's USB port as a pseudo-terminal, pumped as virtual time runs.
    pub usb: Option<PtyBridge>,
    /// How the operator says "go" (start, and continue after re-clamping).
    pub go: Go,
}

/// How the operator says "go".
pub enum Go {
    /// A short press of the button.
    Button,
    /// Enter typed to `calib --port` (which sends `c` to the board): a line on this pipe; the
    /// calibration is started by `calib` itself.
    Enter(std::io::PipeWriter),
}

/// Virtual time between two pumps of the USB pty (s): 5 ms, 2.5 main-loop ticks.
const USB_PUMP_S: f64 = 0.005;

impl Testbed {
    /// Powers up `elf` on a rig, with `board`'s sensor and this flash.
    pub fn new(elf: Vec<u8>, rig: RigConfig, seed: u64, board: Board, flash: NorSim, echo: bool) -> Result<Self, String> {
        let fw = Firmware::load(elf)?;
        let sensor = Lsm9ds1Model::new(Rig::new(board.physics(rig, seed), seed), board);
        let mcu = Mcu::new(fw, Periph::new(sensor, flash, Rc::new(Cell::new(0))))?;
        Ok(Self { mcu, printed: 0, echo, usb: None, go: Go::Button })
    }

    /// New log lines since the last call (echoed when `echo`).
    pub fn new_lines(&mut self) -> Vec<String> {
        let lines = self.mcu.log[self.printed..].to_vec();
        self.printed = self.mcu.log.len();
        if self.echo {
            for l in &lines {
                println!("{l}");
            }
        }
        lines
    }

    /// Runs `secs` of virtual time (pumping the USB pty, if any).
    pub fn run_for(&mut self, secs: f64) -> Stop {
        let t = self.mcu.now() + secs;
        let stop = match self.usb.as_mut() {
            None => self.mcu.run_until(t),
            Some(bridge) => loop {
                let stop = self.mcu.run_until((self.mcu.now() + USB_PUMP_S).min(t));
                if let Err(e) = bridge.pump() {
                    break Stop::Fault(format!("USB pty: {e}"));
                }
                if stop != Stop::Time || self.mcu.now() >= t {
                    break stop;
                }
            },
        };
        self.new_lines();
        stop
    }

    /// The operator says "go": presses the button, or types Enter to `calib --port`.
    fn go(&mut self) -> Stop {
        match &mut self.go {
            Go::Button => self.press(0.2),
            Go::Enter(pipe) => {
                use std::io::Write;
                let _ = pipe.write_all(b"\n");
                self.run_for(0.2)
            }
        }
    }

    /// The LEDs now.
    pub fn leds(&self) -> Leds {
        self.mcu.periph.borrow().leds()
    }

    /// Watches D13 for one group of flashes and returns their number (the phase number while
    /// blue, the error class while red; 0 when D13 stays off or on).
    pub fn flashes(&mut self) -> Result<u8, Stop> {
        // One whole group: from a pause (D13 off for 0.5 s: the flashes are 0.15 s apart) to the
        // next, as a person counts them (at most 2 of the longest cycle, 2.9 s, in 25 ms steps).
        let (mut n, mut was, mut off_s, mut started) = (0u8, self.leds().d13, 0.0, false);
        for _ in 0..240 {
            let stop = self.run_for(0.025);
            if stop != Stop::Time {
                return Err(stop);
            }
            let on = self.leds().d13;
            off_s = if on { 0.0 } else { off_s + 0.025 };
            if started && on && !was {
                n += 1;
            }
            if off_s >= 0.5 {
                if started && n > 0 {
                    break;
                }
                started = true;
            }
            was = on;
        }
        Ok(n)
    }

    /// Runs until the LEDs show phase `n` (blue, n flashes) or `max_s` passes.
    pub fn run_until_phase(&mut self, n: u8, max_s: f64) -> bool {
        let t_end = self.mcu.now() + max_s;
        while self.mcu.now() < t_end {
            if self.run_for(0.05) != Stop::Time {
                return false;
            }
            let l = self.leds();
            if l.blue && !l.red && self.flashes() == Ok(n) {
                return true;
            }
        }
        false
    }

    /// Runs until the LEDs show "done" (green and D13 steady) or `max_s` passes.
    pub fn run_until_done(&mut self, max_s: f64) -> bool {
        let t_end = self.mcu.now() + max_s;
        while self.mcu.now() < t_end {
            if self.run_for(0.05) != Stop::Time {
                return false;
            }
            let l = self.leds();
            if l.done() {
                return true;
            }
        }
        false
    }

    /// Holds the button for `secs`.
    pub fn press(&mut self, secs: f64) -> Stop {
        self.mcu.periph.borrow_mut().button = true;
        let s = self.run_for(secs);
        self.mcu.periph.borrow_mut().button = false;
        s
    }

    /// Presses the button and plays the operator until the LEDs say the calibration ended (or
    /// `max_s` of virtual time passes).
    pub fn calibrate(&mut self, max_s: f64) -> Outcome {
        self.calibrate_with(max_s, |_, _| {})
    }

    /// Presses the button and plays an operator who goes by the LEDs only, never by the log:
    /// yellow blinking (red + green together) means "your turn": with D13 dark they hold the
    /// board in the hand-held orientations one after the other (`operator_attitudes`), 4 s each
    /// (a pose is captured after 2 s of stillness); with D13 lit they clamp it back and press
    /// the button until the yellow stops; green with
    /// D13 lit is done, red without green an error, its class the D13 flashes. `inject(event,
    /// periph)` sees what the operator does (fault injection).
    pub fn calibrate_with(&mut self, max_s: f64, mut inject: impl FnMut(Event, &mut Periph)) -> Outcome {
        const HOLD_S: f64 = 4.0;
        let attitudes = operator_attitudes(self.mcu.periph.borrow_mut().sensor.rig_mut().operator_rng());
        let t_end = self.mcu.now() + max_s;
        // With `calib --port`, calib starts the calibration itself.
        if matches!(self.go, Go::Button) {
            if let s @ (Stop::Fault(_) | Stop::PowerCut) = self.press(0.2) {
                return Outcome::Stopped(s);
            }
        }
        let (mut red_since, mut done_since, mut yellow_seen) = (None::<f64>, None::<f64>, false);
        let (mut next, mut next_at, mut reattached_at) = (0usize, 0.0f64, None::<f64>);
        let mut since = self.mcu.now();
        while self.mcu.now() < t_end {
            let stop = self.run_for(0.05);
            if stop != Stop::Time {
                return Outcome::Stopped(stop);
            }
            let now = self.mcu.now();
            inject(Event::Tick(now - since), &mut self.mcu.periph.borrow_mut());
            let l = self.leds();
            yellow_seen |= l.red && l.green;
            red_since = if l.red && !l.green { red_since.or(Some(now)) } else { None };
            done_since = if l.done() { done_since.or(Some(now)) } else { None };
            if red_since.is_some_and(|t| now - t > 0.6) {
                return match self.flashes() {
                    Ok(class) => Outcome::Failed(class),
                    Err(s) => Outcome::Stopped(s),
                };
            }
            if done_since.is_some_and(|t| now - t > 0.6) {
                return Outcome::Done;
            }
            if !yellow_seen {
                continue;
            }
            // The user's turn: hand-held poses on a timeline while D13 is dark, then (D13 lit)
            // re-clamp and press.
            if reattached_at.is_none() && !l.d13 {
                if next < attitudes.len() && now >= next_at {
                    let mut p = self.mcu.periph.borrow_mut();
                    p.sensor.rig_mut().detach_to(attitudes[next], 1.0);
                    inject(Event::HandHeldPose(next), &mut p);
                    next += 1;
                    next_at = now + HOLD_S;
                }
            } else if now >= next_at {
                match reattached_at {
                    None => {
                        let mut p = self.mcu.periph.borrow_mut();
                        let rig = p.sensor.rig_mut();
                        rig.attach();
                        reattached_at = Some(now + rig.config().attach_transition_s + 1.0);
                    }
                    Some(t) if now >= t && l.red && l.green => {
                        if let s @ (Stop::Fault(_) | Stop::PowerCut) = self.go() {
                            return Outcome::Stopped(s);
                        }
                        inject(Event::Reattached, &mut self.mcu.periph.borrow_mut());
                        since = self.mcu.now();
                        reattached_at = Some(self.mcu.now() + 2.0);
                    }
                    _ => {}
                }
            }
        }
        Outcome::Timeout
    }

    /// Plugs in the USB cable, waits for the virtual host to enumerate the board, exposes its
    /// port as a pseudo-terminal and runs `calib --port` (calib's session, on a thread, its
    /// phases and progress to `ui`, the raw log saved to `log`) while the operator plays by the
    /// LEDs and types Enter to calib after the re-clamp. Returns how the calibration ended on
    /// the LEDs and calib's session result; `Err` if the board never enumerated or the session
    /// thread panicked.
    pub fn calibrate_over_usb(
        &mut self,
        log: &std::path::Path,
        mut ui: Box<dyn std::io::Write + Send>,
    ) -> Result<(Outcome, Result<calib::port::Outcome, calib::port::SessionError>), String> {
        let host = crate::usb_host::UsbHost::new(&self.mcu);
        host.attach();
        host.wait_enumerated(&mut self.mcu, 5.0).map_err(|e| format!("the board did not enumerate: {e}"))?;
        let bridge = PtyBridge::new(host).map_err(|e| format!("pty: {e}"))?;
        let path = bridge.slave_path().to_string_lossy().into_owned();
        self.usb = Some(bridge);
        let (enter_rx, enter_tx) = std::io::pipe().map_err(|e| format!("pipe: {e}"))?;
        self.go = Go::Enter(enter_tx);
        let opts = calib::port::Options::new(log);
        let session = std::thread::spawn(move || {
            let mut port = calib::port::open(&path)?;
            calib::port::run(port.as_mut(), std::io::BufReader::new(enter_rx), ui.as_mut(), &opts)
        });
        let outcome = self.calibrate(600.0);
        // calib switches the raw log off and closes the port: the board runs until it is done.
        let t_end = self.mcu.now() + 60.0;
        while !session.is_finished() && self.mcu.now() < t_end {
            self.run_for(0.05);
        }
        let result = session.join().map_err(|_| "the calib session panicked".to_string())?;
        Ok((outcome, result))
    }

    /// The newest valid record in the emulated flash, as the firmware's storage driver reads it
    /// (its slots, its sequence order with the wrap).
    pub fn stored(&self) -> Option<Record> {
        let flash = self.mcu.periph.borrow().flash.clone();
        gyrocal_fw::storage::Storage::new(flash).ok()?.load().ok().flatten().map(|(_, r)| r)
    }

    /// Largest scale error of a record against the simulator's truth (%): of a full `K` the
    /// largest |E_ii| of `E = Qᵀ K̂ K⁻¹ − I` (the calibrated accelerometer frame aligned to the
    /// simulator's, [`rig_sim::pan_tilt::k_error_matrix`]), of a diagonal one |K̂_ii / K_ii − 1|.
    pub fn max_scale_error_pct(&self, rec: &Record) -> f64 {
        self.k_errors_pct(rec).0
    }

    /// (largest scale error, largest cross-axis error |E_ij|, i ≠ j) of a record (%); the
    /// cross-axis error is NaN for a diagonal `K`.
    pub fn k_errors_pct(&self, rec: &Record) -> (f64, f64) {
        let p = self.mcu.periph.borrow();
        let rig = p.sensor.rig();
        if rec.method != calib_core::estimators::gyro::Method::Full {
            let k = rig.truth().gyro_k;
            return ((0..3).map(|i| (rec.gyro_k[i][i] as f64 / k[(i, i)] - 1.0).abs() * 100.0).fold(0.0, f64::max), f64::NAN);
        }
        match rig_sim::pan_tilt::k_error_matrix(rec.gyro_k, rec.accel_m, rig) {
            Some(e) => {
                let cross = (0..9).filter(|i| i / 3 != i % 3).map(|i| e[(i / 3, i % 3)].abs()).fold(0.0, f64::max);
                (e.diagonal().amax() * 100.0, cross * 100.0)
            }
            None => (f64::NAN, f64::NAN),
        }
    }

    /// Uploads another program (`elf`) as the Arduino bootloader would ([`Mcu::upload`]) and
    /// powers it on: the same board, flash (the calibration records stay), sensor and rig.
    pub fn upload(self, elf: Vec<u8>) -> Result<Testbed, String> {
        let mcu = self.mcu.upload(Firmware::load(elf)?)?;
        Ok(Testbed { mcu, printed: 0, echo: self.echo, usb: None, go: Go::Button })
    }

    /// A reset of the MCU (power cycle): flash, sensor and rig keep their state.
    pub fn reset(&mut self) -> Result<(), String> {
        self.mcu.periph.borrow_mut().flash.reboot();
        self.mcu.reset()
    }
}
