//! PWM0 (nRF52840 PS v1.7 §6.17): ENABLE, MODE, COUNTERTOP, PRESCALER, DECODER, LOOP, SEQ[n],
//! PSEL.OUT[n], SHORTS, events. TASKS_SEQSTART[n] loads the sequence's compare values from RAM
//! (EasyDMA) at once; the output keeps the last value until the next sequence or STOP (as the
//! PS describes). Each value's bit 15 is the polarity: set = falling edge first, i.e. HIGH for
//! `value` ticks from the start of the period. The outputs reach a pin only when ENABLE = 1 and
//! PSEL.OUT[n] connects them: the servo sees the channel routed to P0.27, the tilt servo the one
//! routed to P1.02, and the channel routed to P0.13 overrides the D13 LED.
//!
//! TASKS_SEQSTART while a sequence plays restarts the PWM period at once (PS v1.7 §6.17.2
//! "Sequences": a started sequence begins from its first value; nrf-hal-common 0.19 `pwm.rs`'s
//! `set_duty_*` triggers it on every call): the period in progress is cut, and if a channel's output was still
//! HIGH its pulse runs on into the new one. What a servo then sees is flagged: a period shorter
//! than [`SERVO_MIN_PERIOD_US`] ([`Pwm::short_periods`]) or a pulse stretched by a restart
//! during it ([`Pwm::stretched_pulses`]), on channels routed to a servo pin.

use super::{off, Access, Dma};

/// Shortest frame a hobby servo is made for (µs): they expect 50 Hz (20 ms); many analog servos
/// misbehave well below it.
pub const SERVO_MIN_PERIOD_US: f64 = 15_000.0;
/// The servo pins (port, pin): the rotation servo on P0.27, the tilt servo on P1.02.
pub const SERVO_PINS: [(u32, u32); 2] = [(0, 27), (1, 2)];

/// PWM0 state.
#[derive(Debug, Clone)]
pub struct Pwm {
    /// ENABLE.
    pub enable: u32,
    mode: u32,
    /// COUNTERTOP.
    pub countertop: u32,
    /// PRESCALER.
    pub prescaler: u32,
    decoder: u32,
    loop_: u32,
    seq: [[u32; 4]; 2],
    /// PSEL.OUT[n] (bit 31 = disconnected).
    pub psel_out: [u32; 4],
    shorts: u32,
    inten: u32,
    events_stopped: bool,
    events_seqstarted: [bool; 2],
    events_seqend: [bool; 2],
    events_pwmperiodend: bool,
    events_loopsdone: bool,
    /// The generator runs (a sequence was started and no STOP since).
    pub running: bool,
    /// Output HIGH time per channel (µs, 0 = no pulse).
    pub pulse_us: [u16; 4],
    /// Duty (HIGH fraction) per channel, for LEDs.
    pub duty: [f64; 4],
    /// When the current PWM period began (s).
    period_start: f64,
    /// Servo-channel periods cut short of [`SERVO_MIN_PERIOD_US`] by a restart.
    pub short_periods: u32,
    /// Servo-channel pulses still HIGH when a restart began a new one.
    pub stretched_pulses: u32,
}

impl Default for Pwm {
    fn default() -> Self {
        Self::new(false)
    }
}

/// A pin as PSEL encodes it (port * 32 + pin).
pub fn psel(port: u32, pin: u32) -> u32 {
    port << 5 | pin
}

impl Pwm {
    /// After a reset; `bootloader`: enabled and breathing the D13 LED on OUT[0] = P0.13.
    pub fn new(bootloader: bool) -> Self {
        let mut p = Self {
            enable: 0,
            mode: 0,
            countertop: 0x3FF,
            prescaler: 0,
            decoder: 0,
            loop_: 0,
            seq: [[0; 4]; 2],
            psel_out: [0xFFFF_FFFF; 4],
            shorts: 0,
            inten: 0,
            events_stopped: false,
            events_seqstarted: [false; 2],
            events_seqend: [false; 2],
            events_pwmperiodend: false,
            events_loopsdone: false,
            running: false,
            pulse_us: [0; 4],
            duty: [0.0; 4],
            period_start: 0.0,
            short_periods: 0,
            stretched_pulses: 0,
        };
        if bootloader {
            p.enable = 1;
            p.psel_out[0] = psel(0, 13);
            p.running = true;
            p.duty[0] = 0.5;
        }
        p
    }

    /// The channel whose output is routed to `port`.`pin` (when enabled).
    pub fn channel_on(&self, port: u32, pin: u32) -> Option<usize> {
        if self.enable & 1 == 0 {
            return None;
        }
        self.psel_out.iter().position(|&s| s & (1 << 31) == 0 && s & 0x3F == psel(port, pin))
    }

    /// Servo pulse (µs) on `port`.`pin`: 0 when no running channel drives it.
    pub fn pulse_on(&self, port: u32, pin: u32) -> u16 {
        match self.channel_on(port, pin) {
            Some(ch) if self.running => self.pulse_us[ch],
            _ => 0,
        }
    }

    fn load(&mut self, n: usize, mem: &mut dyn Dma) {
        let [ptr, cnt, _, _] = self.seq[n];
        let per_period = match self.decoder & 3 {
            0 => 1, // common
            1 => 2, // grouped
            2 => 4, // individual
            _ => 4, // waveform: 3 values + top
        };
        if cnt < per_period {
            return;
        }
        let mut buf = [0u8; 8];
        mem.read(ptr as u64, &mut buf[..2 * per_period as usize]);
        let v = |i: usize| u16::from_le_bytes([buf[2 * i], buf[2 * i + 1]]);
        let mut top = self.countertop & 0x7FFF;
        let vals: [u16; 4] = match self.decoder & 3 {
            0 => [v(0); 4],
            1 => [v(0), v(0), v(1), v(1)],
            2 => [v(0), v(1), v(2), v(3)],
            _ => {
                top = (v(3) & 0x7FFF) as u32;
                [v(0), v(1), v(2), 0]
            }
        };
        let us_per_tick = (1u32 << self.prescaler.min(7)) as f64 / 16.0;
        for (ch, raw) in vals.into_iter().enumerate() {
            let cmp = (raw & 0x7FFF) as u32;
            let high = if raw & 0x8000 != 0 { cmp.min(top) } else { top.saturating_sub(cmp) };
            self.pulse_us[ch] = (high as f64 * us_per_tick).round() as u16;
            self.duty[ch] = if top > 0 { high as f64 / top as f64 } else { 0.0 };
        }
    }

    /// The PWM period (µs).
    fn period_us(&self) -> f64 {
        (self.countertop & 0x7FFF) as f64 * (1u32 << self.prescaler.min(7)) as f64 / 16.0
    }

    /// A restart at `t` (s) of a running generator: flags what the servo channels see of the
    /// period it cuts.
    fn restart(&mut self, t: f64) {
        let period = self.period_us();
        if period <= 0.0 {
            return;
        }
        // The phase of the period in progress: the servo sees a frame of that length.
        let into = ((t - self.period_start) * 1e6) % period;
        for (ch, &pulse) in self.pulse_us.iter().enumerate() {
            let servo = SERVO_PINS.iter().any(|&(port, pin)| self.channel_on(port, pin) == Some(ch));
            if !servo || pulse == 0 {
                continue;
            }
            if into < SERVO_MIN_PERIOD_US.min(period) {
                self.short_periods += 1;
            }
            if into < pulse as f64 {
                self.stretched_pulses += 1;
            }
        }
    }

    /// A register access at offset `o` at time `t` (s).
    pub fn access(&mut self, o: u32, a: Access, t: f64, mem: &mut dyn Dma) -> Result<u32, String> {
        let ev = |e: &mut bool, a: Access| -> u32 {
            if let Access::Write(v) = a {
                *e = v & 1 != 0;
            }
            u32::from(*e)
        };
        let (start, started, end, out) =
            (off!(pwm0, tasks_seqstart), off!(pwm0, events_seqstarted), off!(pwm0, events_seqend), off!(pwm0, psel.out));
        let (seq0, seq1) = (off!(pwm0, seq0), off!(pwm0, seq1));
        Ok(match o {
            o if o == off!(pwm0, tasks_stop) => {
                if a.is_write() && self.enable & 1 != 0 {
                    self.running = false;
                    self.events_stopped = true;
                }
                0
            }
            o if o == start || o == start + 4 => {
                let n = ((o - start) / 4) as usize;
                if a.is_write() && self.enable & 1 != 0 {
                    if self.running {
                        self.restart(t);
                    }
                    self.period_start = t;
                    self.load(n, mem);
                    self.running = true;
                    self.events_seqstarted[n] = true;
                    self.events_seqend[n] = true;
                    self.events_pwmperiodend = true;
                }
                0
            }
            o if o == off!(pwm0, tasks_nextstep) => 0,
            o if o == off!(pwm0, events_stopped) => ev(&mut self.events_stopped, a),
            o if o == started || o == started + 4 => ev(&mut self.events_seqstarted[((o - started) / 4) as usize], a),
            o if o == end || o == end + 4 => ev(&mut self.events_seqend[((o - end) / 4) as usize], a),
            o if o == off!(pwm0, events_pwmperiodend) => ev(&mut self.events_pwmperiodend, a),
            o if o == off!(pwm0, events_loopsdone) => ev(&mut self.events_loopsdone, a),
            o if o == off!(pwm0, shorts) => a.rw(&mut self.shorts),
            o if o == off!(pwm0, inten) => a.rw(&mut self.inten),
            o if o == off!(pwm0, intenset) => {
                if let Access::Write(v) = a {
                    self.inten |= v;
                }
                self.inten
            }
            o if o == off!(pwm0, intenclr) => {
                if let Access::Write(v) = a {
                    self.inten &= !v;
                }
                self.inten
            }
            o if o == off!(pwm0, enable) => {
                let v = a.rw(&mut self.enable);
                if self.enable & 1 == 0 {
                    self.running = false;
                }
                v
            }
            o if o == off!(pwm0, mode) => a.rw(&mut self.mode),
            o if o == off!(pwm0, countertop) => a.rw(&mut self.countertop),
            o if o == off!(pwm0, prescaler) => a.rw(&mut self.prescaler),
            o if o == off!(pwm0, decoder) => a.rw(&mut self.decoder),
            o if o == off!(pwm0, loop_) => a.rw(&mut self.loop_),
            o if (seq0..seq0 + 16).contains(&o) => a.rw(&mut self.seq[0][((o - seq0) / 4) as usize]),
            o if (seq1..seq1 + 16).contains(&o) => a.rw(&mut self.seq[1][((o - seq1) / 4) as usize]),
            o if (out..out + 16).contains(&o) => a.rw(&mut self.psel_out[((o - out) / 4) as usize]),
            _ => return Err(format!("PWM0 register 0x{o:03X}")),
        })
    }
}
