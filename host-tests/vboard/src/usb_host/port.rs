//! The port and the host's clock: connect / disconnect, debounce, bus reset, SOFs, the script
//! run step by step ([`Host::advance`], [`Host::next_time`] for a CPU asleep), what is due next
//! handed to the control or bulk pipes, and how errors are kept.

use super::control::{describe, Op, Tag};
use super::{Host, Next, CONTROL_TIMEOUT_S, DEBOUNCE_S, RECOVERY_S, RESET_S};
use crate::periph::usbd::{Phy, Usbd};

/// Where the port is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PortState {
    /// Nothing connected.
    NoDevice,
    /// Connected, debouncing until this time (s).
    Debounce(f64),
    /// Enumerating (or running requests).
    Active,
    /// The enumeration failed: the port is disabled until a disconnect.
    Failed,
}

/// A timed bus step of the script under way.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Running {
    Idle,
    Reset(f64),
    Wait(f64),
}

impl Host {
    /// Whether control requests are still queued or running.
    pub fn busy(&self) -> bool {
        self.ctrl.is_some() || !self.script.is_empty() || self.running != Running::Idle
    }

    /// A time-stamped line in the log.
    pub(super) fn note(&mut self, s: String) {
        self.log.push(format!("{:.6} {s}", self.now));
    }

    /// An error: kept; during the enumeration it also disables the port.
    pub(super) fn fail(&mut self, e: String) {
        self.note(format!("error: {e}"));
        self.errors.push(e.clone());
        if !self.enumerated {
            self.error = Some(e);
            self.port = PortState::Failed;
            self.script.clear();
            self.ctrl = None;
            self.running = Running::Idle;
            self.next_sof = None;
        }
    }

    /// The device left: the port empty, the enumeration's requests dropped (the API's kept).
    fn disconnect(&mut self) {
        if self.port != PortState::NoDevice {
            self.note("device disconnected".into());
        }
        self.port = PortState::NoDevice;
        self.enumerated = false;
        self.script.retain(|op| matches!(op, Op::User(_)));
        self.ctrl = None;
        self.running = Running::Idle;
        self.next_sof = None;
        self.addr = 0;
        // The read URB is killed with the device: its bytes never reach the reader.
        self.urb.clear();
        self.urb_since = None;
    }

    /// The debounce is over: forget the last device and enumerate from the bus reset.
    fn start_enumeration(&mut self) {
        self.note("device connected: reset".into());
        self.error = None;
        self.device = None;
        self.configuration = None;
        self.bos = None;
        self.cdc = None;
        self.langid = None;
        self.strings.clear();
        self.mps0 = 64;
        self.addr = 0;
        self.port = PortState::Active;
        let user: Vec<Op> = self.script.drain(..).collect();
        self.script = [Op::Reset, Op::Wait(RECOVERY_S), Op::Control(Tag::Device64)].into_iter().collect();
        self.script.extend(user);
    }

    /// The next time the host does something by itself (s), for a CPU asleep in `wfi`.
    pub fn next_time(&self, dev: &Usbd) -> Option<f64> {
        let mut t: Option<f64> = None;
        let mut add = |x: f64| t = Some(t.map_or(x, |y: f64| y.min(x)));
        if let PortState::Debounce(d) = self.port {
            add(d);
        }
        if let Some(s) = self.next_sof {
            add(s);
        }
        match self.running {
            Running::Reset(e) | Running::Wait(e) => add(e),
            Running::Idle => {}
        }
        let when = |n: Next| match n {
            Next::At(x) => Some(x),
            Next::AfterChange(g) => (g != dev.generation).then(|| dev.changed_at.max(self.now)),
        };
        if let Some(c) = &self.ctrl {
            if let Some(x) = when(c.next) {
                add(x);
            }
            add(c.deadline);
        }
        if self.enumerated {
            if self.reading {
                if let Some(x) = when(self.in_next) {
                    add(x);
                }
            }
            if !self.tx.is_empty() {
                if let Some(x) = when(self.out_next) {
                    add(x);
                }
            }
        }
        t
    }

    /// Runs the host up to time `t` (s) against `dev`. An `Err` is a modelling fault raised by
    /// the device model (the run stops).
    pub fn advance(&mut self, t: f64, dev: &mut Usbd, phy: Phy) -> Result<(), String> {
        for _ in 0..1_000_000 {
            let connected = dev.connected(phy);
            if !connected && self.port != PortState::NoDevice {
                self.now = self.now.max(dev.changed_at.min(t));
                self.disconnect();
            }
            if connected && self.port == PortState::NoDevice {
                self.now = self.now.max(t);
                self.port = PortState::Debounce(self.now + DEBOUNCE_S);
                self.note("device seen (pull-up): debounce".into());
            }
            // Start the next step of the script when nothing runs.
            if self.port == PortState::Active && self.running == Running::Idle && self.ctrl.is_none() {
                if let Some(op) = self.script.front().copied() {
                    let user = matches!(op, Op::User(_));
                    if !user || self.enumerated {
                        self.script.pop_front();
                        self.begin(op, dev, phy);
                        continue;
                    }
                }
            }
            let Some(next) = self.next_time(dev) else { break };
            if next > t {
                break;
            }
            self.now = self.now.max(next);
            self.step(dev, phy)?;
        }
        self.now = self.now.max(t);
        Ok(())
    }

    /// Starts the script's step `op`.
    fn begin(&mut self, op: Op, dev: &mut Usbd, phy: Phy) {
        match op {
            Op::Reset => {
                self.note("bus reset".into());
                self.running = Running::Reset(self.now + RESET_S);
                self.next_sof = None;
                dev.bus_reset(phy);
                self.addr = 0;
            }
            Op::Wait(s) => self.running = Running::Wait(self.now + s),
            Op::Configured => {
                self.enumerated = true;
                self.enumerations += 1;
                self.in_next = Next::At(self.now);
                self.out_next = Next::At(self.now);
                self.note("enumerated".into());
            }
            Op::Control(tag) | Op::User(tag) => self.start_control(tag),
        }
    }

    /// Does what is due at `self.now`.
    fn step(&mut self, dev: &mut Usbd, phy: Phy) -> Result<(), String> {
        let now = self.now;
        if let PortState::Debounce(d) = self.port {
            if now >= d {
                self.start_enumeration();
                return Ok(());
            }
        }
        if let Running::Reset(e) = self.running {
            if now >= e {
                self.running = Running::Idle;
                self.next_sof = Some(now);
            }
            return Ok(());
        }
        if let Running::Wait(e) = self.running {
            if now >= e {
                self.running = Running::Idle;
            }
        }
        if self.next_sof.is_some_and(|s| now >= s) {
            dev.sof(self.frame, phy);
            self.frame = (self.frame + 1) & 0x7FF;
            self.next_sof = self.next_sof.map(|s| s + 1e-3);
            return Ok(());
        }
        let due = |n: Next, dev: &Usbd| match n {
            Next::At(x) => now >= x,
            Next::AfterChange(g) => g != dev.generation && now >= dev.changed_at,
        };
        if let Some(c) = &self.ctrl {
            if now >= c.deadline {
                let stage = c.stage;
                let tag = c.tag;
                self.ctrl = None;
                self.control_done(
                    tag,
                    Err(format!(
                        "timeout: {} not completed within {CONTROL_TIMEOUT_S} s (stage {stage:?}, the device NAKs)",
                        describe(tag)
                    )),
                );
                return Ok(());
            }
            if due(c.next, dev) {
                return self.control_step(dev, phy);
            }
        }
        if self.enumerated && self.reading && due(self.in_next, dev) {
            return self.bulk_in(dev, phy);
        }
        if self.enumerated && !self.tx.is_empty() && due(self.out_next, dev) {
            return self.bulk_out(dev, phy);
        }
        Ok(())
    }

    /// No handshake: the device left (a disconnect) or does not answer (an error).
    pub(super) fn silent(&mut self, what: &str, dev: &Usbd, phy: Phy) {
        if dev.connected(phy) {
            self.fail(format!("no response from the device to {what}"));
        } else {
            self.disconnect();
        }
    }
}
