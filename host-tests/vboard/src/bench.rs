//! A bench around the emulated board: the simulated rig, an operator who presses the button and
//! does what the firmware's log asks (hand-held poses, re-clamping), and readers of the result.

use crate::elf::Firmware;
use crate::mcu::{Mcu, Stop};
use crate::periph::Periph;
use calib_core::record::Record;
use rig_sim::harness::handheld_attitudes;
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

/// The workspace root.
fn root() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The release firmware ELF of this workspace.
pub fn firmware_path() -> std::path::PathBuf {
    root().join("target/thumbv7em-none-eabihf/release/gyrocal-fw")
}

/// Builds the release firmware with `features` (its own target directory per feature set, so
/// that it never waits on the lock of a running cargo) and returns the ELF bytes.
pub fn build_firmware(features: &[&str]) -> Result<Vec<u8>, String> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut cmd = std::process::Command::new(cargo);
    cmd.args(["build", "--release", "-p", "gyrocal-fw"]).current_dir(root());
    let path = if features.is_empty() {
        firmware_path()
    } else {
        let dir = root().join("target").join(format!("fw-{}", features.join("-")));
        cmd.arg("--features").arg(features.join(",")).arg("--target-dir").arg(&dir);
        dir.join("thumbv7em-none-eabihf/release/gyrocal-fw")
    };
    let status = cmd.status().map_err(|e| format!("cargo: {e}"))?;
    if !status.success() {
        return Err(format!("firmware build failed: {status}"));
    }
    std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))
}

/// How a calibration attempt ended.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    /// "calibration done" logged.
    Done,
    /// "calibration failed" logged, with the line.
    Failed(String),
    /// The emulation stopped.
    Stopped(Stop),
    /// Neither within the time limit.
    Timeout,
}

/// The emulated board on the simulated rig, with an operator.
pub struct Bench {
    /// The board.
    pub mcu: Mcu,
    printed: usize,
    /// Print log lines as they come.
    pub echo: bool,
}

impl Bench {
    /// Powers up `elf` on a rig, with `board`'s sensor and this flash.
    pub fn new(elf: Vec<u8>, rig: RigConfig, seed: u64, board: Board, flash: NorSim, echo: bool) -> Result<Self, String> {
        let fw = Firmware::load(elf)?;
        let sensor = Lsm9ds1Model::new(Rig::new(rig, seed), board);
        let mcu = Mcu::new(fw, Periph::new(sensor, flash, Rc::new(Cell::new(0))))?;
        Ok(Self { mcu, printed: 0, echo })
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

    /// Runs `secs` of virtual time.
    pub fn run_for(&mut self, secs: f64) -> Stop {
        let t = self.mcu.now() + secs;
        let stop = self.mcu.run_until(t);
        self.new_lines();
        stop
    }

    /// Runs in 50 ms steps until a log line contains `text` (true) or `max_s` passes (false).
    pub fn run_until_line(&mut self, text: &str, max_s: f64) -> bool {
        let t_end = self.mcu.now() + max_s;
        while self.mcu.now() < t_end {
            let t = self.mcu.now() + 0.05;
            if self.mcu.run_until(t) != Stop::Time {
                return false;
            }
            if self.new_lines().iter().any(|l| l.contains(text)) {
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

    /// Presses the button and plays the operator until the firmware logs the end of the
    /// calibration (or `max_s` of virtual time passes).
    pub fn calibrate(&mut self, max_s: f64) -> Outcome {
        self.calibrate_with(max_s, |_, _| {})
    }

    /// As [`Bench::calibrate`], calling `inject(line, periph)` on every log line (fault injection).
    pub fn calibrate_with(&mut self, max_s: f64, mut inject: impl FnMut(&str, &mut Periph)) -> Outcome {
        let attitudes = handheld_attitudes();
        let (mut next, mut handheld) = (0usize, false);
        let mut press_at = Some(self.mcu.now());
        let t_end = self.mcu.now() + max_s;
        while self.mcu.now() < t_end {
            if press_at.is_some_and(|t| self.mcu.now() >= t) {
                press_at = None;
                if let s @ (Stop::Fault(_) | Stop::PowerCut) = self.press(0.2) {
                    return Outcome::Stopped(s);
                }
            }
            let t = self.mcu.now() + 0.05;
            let stop = self.mcu.run_until(t);
            if stop != Stop::Time {
                self.new_lines();
                return Outcome::Stopped(stop);
            }
            for line in self.new_lines() {
                inject(&line, &mut self.mcu.periph.borrow_mut());
                let now = self.mcu.now();
                let rig = self.mcu.periph.borrow_mut();
                let mut rig = std::cell::RefMut::map(rig, |p| p.sensor.rig_mut());
                if line.contains("phase: hand-held") {
                    handheld = true;
                }
                if handheld && (line.contains("phase: hand-held") || line.contains("hand-held pose")) {
                    if let Some(q) = attitudes.get(next) {
                        rig.detach_to(*q, 1.0);
                        next += 1;
                    }
                } else if line.contains("phase: reattach") {
                    handheld = false;
                    rig.attach();
                    press_at = Some(now + rig.config().attach_transition_s + 1.0);
                } else if line.contains("calibration done") {
                    drop(rig);
                    self.run_for(0.5);
                    return Outcome::Done;
                } else if line.contains("calibration failed") {
                    return Outcome::Failed(line);
                }
            }
        }
        Outcome::Timeout
    }

    /// Presses the button and plays an operator who cannot read the log (no probe): they go by
    /// the LEDs and the procedure's timeline only. Yellow blinking (red + green together) means
    /// "your turn": they hold the board in the hand-held orientations one after the other, 3 s
    /// each (a pose is captured after 1 s of stillness), then clamp it back and press the button
    /// until the yellow stops; green with D13 lit is done, red without green is an error (class
    /// = D13 flashes). Returns the outcome as the LEDs tell it.
    pub fn calibrate_by_leds(&mut self, max_s: f64) -> Outcome {
        const HOLD_S: f64 = 3.0;
        let attitudes = handheld_attitudes();
        let t_end = self.mcu.now() + max_s;
        if let s @ (Stop::Fault(_) | Stop::PowerCut) = self.press(0.2) {
            return Outcome::Stopped(s);
        }
        // (time the state was first seen, state) of the last LED observations.
        let (mut red_since, mut done_since, mut yellow_seen) = (None::<f64>, None::<f64>, false);
        let (mut next, mut next_at, mut reattached_at) = (0usize, 0.0f64, None::<f64>);
        while self.mcu.now() < t_end {
            let stop = self.run_for(0.05);
            if stop != Stop::Time {
                return Outcome::Stopped(stop);
            }
            let now = self.mcu.now();
            let l = self.mcu.periph.borrow().leds();
            if l.red && l.green {
                yellow_seen = true;
            }
            red_since = if l.red && !l.green { red_since.or(Some(now)) } else { None };
            done_since = if l.green && l.d13 && !l.red && !l.blue { done_since.or(Some(now)) } else { None };
            if red_since.is_some_and(|t| now - t > 0.6) {
                return Outcome::Failed("red LED".into());
            }
            if done_since.is_some_and(|t| now - t > 0.6) {
                return Outcome::Done;
            }
            if !yellow_seen {
                continue;
            }
            // The user's turn: hand-held poses on a timeline, then re-clamp and press.
            if next < attitudes.len() {
                if now >= next_at {
                    let mut p = self.mcu.periph.borrow_mut();
                    p.sensor.rig_mut().detach_to(attitudes[next], 1.0);
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
                        if let s @ (Stop::Fault(_) | Stop::PowerCut) = self.press(0.2) {
                            return Outcome::Stopped(s);
                        }
                        reattached_at = Some(self.mcu.now() + 2.0);
                    }
                    _ => {}
                }
            }
        }
        Outcome::Timeout
    }

    /// The newest valid record in the emulated flash (the firmware's A/B slots).
    pub fn stored(&self) -> Option<Record> {
        let p = self.mcu.periph.borrow();
        let bytes = p.flash.bytes();
        [0usize, 4096].iter().filter_map(|&o| Record::decode(&bytes[o..o + calib_core::record::LEN]).ok()).max_by_key(|r| r.seq)
    }

    /// Largest |K̂_ii / K_ii − 1| of a record against the simulator's truth (%).
    pub fn max_scale_error_pct(&self, rec: &Record) -> f64 {
        let k = self.mcu.periph.borrow().sensor.rig().truth().gyro_k;
        (0..3).map(|i| (rec.gyro_k[i][i] as f64 / k[(i, i)] - 1.0).abs() * 100.0).fold(0.0, f64::max)
    }

    /// A reset of the MCU (power cycle): flash, sensor and rig keep their state.
    pub fn reset(&mut self) -> Result<(), String> {
        self.mcu.periph.borrow_mut().flash.reboot();
        self.mcu.reset()
    }
}
