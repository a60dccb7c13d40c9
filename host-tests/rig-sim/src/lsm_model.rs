//! A register-level model of the LSM9DS1 accelerometer/gyroscope behind the embedded-hal 1.0
//! `I2c` trait, fed by the rig simulator: what the firmware's driver talks to on the host.
//!
//! Modelled from the datasheet (ST DocID025715): WHO_AM_I 0x68 at address 0x6B; register
//! auto-increment (IF_ADD_INC, CTRL_REG8 bit 2); software reset (CTRL_REG8 bit 0) back to the
//! defaults; ODR and ranges from CTRL_REG1_G / CTRL_REG6_XL; a 32-slot FIFO (CTRL_REG9 FIFO_EN,
//! FIFO_CTRL mode) of gyro + accelerometer slots, popped once the gyro registers and then the
//! accelerometer registers (OUT_Z_H_XL, 0x2D) have been read; FIFO_SRC with the unread count
//! (FSS), overrun (OVRN, cleared by the next read of a slot) and threshold flags; in continuous
//! mode a full FIFO drops its oldest slot; the temperature output (16 LSB/°C, 0 at 25 °C).
//! Samples enter the FIFO at the ODR configured in CTRL_REG1_G times the rig's ODR error, in
//! true time.
//!
//! Strict where the part is: while it boots (power-up, SW_RESET, BOOT) it does not acknowledge
//! its address (the datasheet's I2C section: a slave that "is performing some real-time
//! function" leaves the acknowledge out) for [`BOOT_S`]; unpowered it NACKs everything and loses
//! its registers; with the FIFO enabled, a burst read auto-incremented past OUT_Z_H_XL (0x2D)
//! wraps back to OUT_X_L_G (0x18), so one transaction can pull many slots; the first slot after
//! the FIFO is (re)enabled is junk (ST: "the first sample acquired must be discarded"): zeros,
//! which no driver that keeps it can mistake for a real pose (|a| = 0 g). That slot is not a
//! sample of the rig ([`Lsm9ds1Model::history`] does not list it; [`Lsm9ds1Model::junk`] counts
//! it).

use crate::bmi_model::Bmi270Model;
use crate::bmm_model::{self, Bmm150Model};
use crate::lsm_mag_model::{self, LsmMagModel};
use crate::sim::{AccelRange, GyroRange, Rig, RigConfig};
use embedded_hal::i2c::{ErrorKind, ErrorType, I2c, NoAcknowledgeSource, Operation};
use gyrocal_fw::lsm9ds1::{reg, ADDR_AG, ADDR_BMI270, FIFO_DEPTH, WHO_AM_I_AG};
use std::collections::VecDeque;

/// A bus failure of the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BusError(pub ErrorKind);

impl embedded_hal::i2c::Error for BusError {
    fn kind(&self) -> ErrorKind {
        self.0
    }
}

/// What answers on the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Board {
    /// Nano 33 BLE Rev1: LSM9DS1.
    Rev1,
    /// Nano 33 BLE Rev2: BMI270 at 0x68, BMM150 at 0x10, nothing at 0x6B.
    Rev2,
    /// No sensor (unpowered or not fitted).
    Missing,
    /// A chip at 0x6B with this WHO_AM_I.
    OtherChip(u8),
}

impl Board {
    /// `cfg` with the physics of this board's sensor: a Rev2's BMI270 (`RigConfig::on_bmi270`,
    /// its ODR error drawn from `seed`; the full scales follow the registers), else as it is.
    pub fn physics(self, cfg: RigConfig, seed: u64) -> RigConfig {
        match self {
            Board::Rev2 => cfg.on_bmi270(500, 2, &mut <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(seed)),
            _ => cfg,
        }
    }
}

/// A produced sample waiting for its time: true time, FIFO slot, temperature, rig readings.
/// (true time, the LSM9DS1's slot, its temperature reading (1/16 °C), accelerometer, gyro, the
/// true temperature for the BMI270's finer register, a new magnetometer reading).
type Pending = (f64, Slot, f32, [f32; 3], [f32; 3], f64, Option<[f32; 3]>);

#[derive(Debug, Clone, Copy)]
struct Slot {
    gyro: [u8; 6],
    accel: [u8; 6],
}

/// The model.
#[derive(Clone)]
pub struct Lsm9ds1Model {
    rig: Rig,
    board: Board,
    regs: [u8; 0x80],
    fifo: VecDeque<Slot>,
    overrun: bool,
    /// Bytes of the current slot read (gyro 0..6, accel 6..12).
    slot_read: u8,
    now_s: f64,
    pending: Option<Pending>,
    /// Every transaction from this count on is NACKed (bus fault injection).
    pub nack_from: Option<usize>,
    transactions: usize,
    produced: usize,
    sw_resets: usize,
    dropped: usize,
    /// Overruns: runs of drops, each from a FIFO that was not flagged overrun yet.
    overruns: usize,
    history: Vec<([f32; 3], [f32; 3])>,
    /// The part does not answer before this time (booting).
    busy_until: f64,
    powered: bool,
    /// The next slot entering the FIFO is the junk first sample after enabling it.
    junk_next: bool,
    junk: usize,
    /// Each transaction advances true time by its bus time at this rate (Hz), if set.
    pub bus_hz: Option<f64>,
    /// External clock (s): every transaction first advances true time to it.
    pub clock: Option<std::rc::Rc<std::cell::Cell<f64>>>,
    /// On a Rev2 board: the BMI270 that answers at 0x68, fed the rig's samples.
    bmi: Option<Bmi270Model>,
    /// On a Rev2 board: the BMM150 magnetometer that answers at 0x10.
    bmm: Option<Bmm150Model>,
    /// On a Rev1 board whose rig simulates the field: the LSM9DS1's magnetometer at 0x1E.
    mag: Option<LsmMagModel>,
}

const DEFAULT_CTRL_REG8: u8 = 0x04;

/// How long the part does not answer after power-up, SW_RESET or BOOT (s). DocID025715 gives no
/// figure for it; 10 ms is what Arduino's LSM9DS1 library waits after its reset on this very
/// board (Zephyr waits 50 ms after BOOT), so a driver that waits that long, or polls with NACK
/// as "not ready" under a timeout, works, and one that polls at once does not.
pub const BOOT_S: f64 = 0.010;

impl Lsm9ds1Model {
    /// A model on `board`, sampling `rig` (its full scales and ODR follow CTRL_REG1_G and
    /// CTRL_REG6_XL from the first write on).
    pub fn new(mut rig: Rig, board: Board) -> Self {
        // A BMI270 quantises at its own full scales.
        if board == Board::Rev2 {
            rig.set_quantized(false);
        }
        let mut m = Self {
            rig,
            board,
            regs: [0; 0x80],
            fifo: VecDeque::new(),
            overrun: false,
            slot_read: 0,
            now_s: 0.0,
            pending: None,
            nack_from: None,
            transactions: 0,
            produced: 0,
            sw_resets: 0,
            dropped: 0,
            overruns: 0,
            history: Vec::new(),
            busy_until: 0.0,
            powered: true,
            junk_next: false,
            junk: 0,
            bus_hz: None,
            clock: None,
            bmi: (board == Board::Rev2).then(|| Bmi270Model::new(0.0)),
            bmm: (board == Board::Rev2).then(|| Bmm150Model::new(0.0)),
            mag: None,
        };
        m.mag = m.has_lsm_mag().then(|| LsmMagModel::new(0.0));
        m.reset_registers();
        m
    }

    /// Powers the part on or off (the board's VDD_ENV). Off: it NACKs and loses its registers;
    /// on: it boots for [`BOOT_S`] first.
    pub fn set_powered(&mut self, on: bool) {
        if on == self.powered {
            return;
        }
        self.powered = on;
        self.reset_registers();
        if on {
            self.busy_until = self.now_s + BOOT_S;
            if self.board == Board::Rev2 {
                self.bmi = Some(Bmi270Model::new(self.now_s));
                self.bmm = Some(Bmm150Model::new(self.now_s));
            }
            if self.has_lsm_mag() {
                self.mag = Some(LsmMagModel::new(self.now_s));
            }
        }
    }

    /// Powered.
    pub fn powered(&self) -> bool {
        self.powered
    }

    /// On a Rev2 board: the BMI270 at 0x68.
    pub fn bmi(&self) -> Option<&Bmi270Model> {
        self.bmi.as_ref()
    }

    /// On a Rev2 board: the BMM150 at 0x10 (to check the power mode the firmware left it in).
    pub fn bmm(&self) -> Option<&Bmm150Model> {
        self.bmm.as_ref()
    }

    /// Whether the LSM9DS1's magnetometer answers at 0x1E: on a Rev1 board whose rig simulates
    /// the field (a rig without one models a board whose magnetometer is missing).
    fn has_lsm_mag(&self) -> bool {
        self.board == Board::Rev1 && self.rig.config().mag.is_some()
    }

    /// On a Rev1 board: the LSM9DS1's magnetometer at 0x1E.
    pub fn lsm_mag(&self) -> Option<&LsmMagModel> {
        self.mag.as_ref()
    }

    /// Junk first slots produced (after each FIFO enable).
    pub fn junk(&self) -> usize {
        self.junk
    }

    /// Whether the part acknowledges `address` now.
    pub fn acks(&self, address: u8) -> bool {
        let present = match self.board {
            Board::Rev1 => address == ADDR_AG || (address == lsm_mag_model::ADDR && self.mag.is_some()),
            Board::OtherChip(_) => address == ADDR_AG,
            Board::Rev2 => address == ADDR_BMI270 || address == bmm_model::ADDR,
            Board::Missing => false,
        };
        let bmm_answers = address != bmm_model::ADDR || self.bmm.as_ref().is_some_and(|m| m.acks_at(self.now_s));
        let mag_answers = address != lsm_mag_model::ADDR || self.mag.as_ref().is_some_and(|m| m.acks_at(self.now_s));
        present
            && bmm_answers
            && mag_answers
            && self.powered
            && self.now_s >= self.busy_until
            && self.nack_from.is_none_or(|n| self.transactions < n)
    }

    fn fifo_on(&self) -> bool {
        self.reg(reg::CTRL_REG9) & 0x02 != 0 && self.reg(reg::FIFO_CTRL) >> 5 != 0
    }

    fn reset_registers(&mut self) {
        self.regs = [0; 0x80];
        self.regs[reg::WHO_AM_I as usize] = match self.board {
            Board::OtherChip(id) => id,
            _ => WHO_AM_I_AG,
        };
        self.regs[reg::CTRL_REG8 as usize] = DEFAULT_CTRL_REG8;
        self.fifo.clear();
        self.overrun = false;
        self.slot_read = 0;
        self.junk_next = false;
    }

    /// A register value.
    pub fn reg(&self, r: u8) -> u8 {
        self.regs[r as usize & 0x7F]
    }

    /// The rig.
    pub fn rig(&self) -> &Rig {
        &self.rig
    }

    /// The rig, to command the servo.
    pub fn rig_mut(&mut self) -> &mut Rig {
        &mut self.rig
    }

    /// Software resets (CTRL_REG8 SW_RESET) received: each initialisation of a driver does one.
    pub fn sw_resets(&self) -> usize {
        self.sw_resets
    }

    /// Samples the sensor produced since configuration, and how many were lost to overrun.
    pub fn counts(&self) -> (usize, usize) {
        (self.produced, self.dropped)
    }

    /// Overruns since configuration: runs of lost samples, each ended by a slot read (which
    /// clears the flag, FIFO_SRC's OVRN).
    pub fn overruns(&self) -> usize {
        self.overruns
    }

    /// The rig readings (accel g, gyro °/s) of every sample produced, in order.
    pub fn history(&self) -> &[([f32; 3], [f32; 3])] {
        &self.history
    }

    /// True time (s).
    pub fn now_s(&self) -> f64 {
        self.now_s
    }

    fn running(&self) -> bool {
        self.reg(reg::CTRL_REG1_G) >> 5 != 0
    }

    /// FS_G (CTRL_REG1_G bits 4:3; 10 is "not available" in the datasheet, read as ±2000 °/s).
    fn gyro_range(&self) -> GyroRange {
        match (self.reg(reg::CTRL_REG1_G) >> 3) & 3 {
            0 => GyroRange::Dps245,
            1 => GyroRange::Dps500,
            _ => GyroRange::Dps2000,
        }
    }

    /// FS_XL (CTRL_REG6_XL bits 4:3).
    fn accel_range(&self) -> AccelRange {
        match (self.reg(reg::CTRL_REG6_XL) >> 3) & 3 {
            0 => AccelRange::G2,
            1 => AccelRange::G16,
            2 => AccelRange::G4,
            _ => AccelRange::G8,
        }
    }

    /// The board frame's vector in the part's raw accelerometer and gyro axes: `(−x, y, z)`. The
    /// raw triad is left-handed (the gyro follows the accelerometer with the left-hand rule):
    /// recordings of real Nano 33 BLE boards (`host-tests/calib/tests/real_boards.rs`), ArduPilot's
    /// AP_InertialSensor_LSM9DS1 and PX4's lsm9ds1 driver (both flip one axis of both sensors).
    pub fn raw_axes(b: [f32; 3]) -> [f32; 3] {
        [-b[0], b[1], b[2]]
    }

    fn counts_le(v: [f32; 3], lsb: f64) -> [u8; 6] {
        let mut out = [0u8; 6];
        for (k, x) in v.iter().enumerate() {
            let c = (*x as f64 / lsb).round().clamp(i16::MIN as f64, i16::MAX as f64) as i16;
            out[2 * k..2 * k + 2].copy_from_slice(&c.to_le_bytes());
        }
        out
    }

    /// Advances true time to `t_s`: every sample the rig produces by then enters the FIFO (or the
    /// output registers when the FIFO is off).
    pub fn advance_to(&mut self, t_s: f64) {
        loop {
            let (t, slot, temp, accel, gyro, true_temp, mag_ut) = match self.pending {
                Some(p) => p,
                None => {
                    let s = self.rig.next_sample();
                    let slot = Slot {
                        gyro: Self::counts_le(Self::raw_axes(s.gyro_dps), self.gyro_range().lsb_dps()),
                        accel: Self::counts_le(Self::raw_axes(s.accel_g), self.accel_range().lsb_g()),
                    };
                    let truth = self.rig.truth();
                    let p = (truth.t_s, slot, s.temp_c, s.accel_g, s.gyro_dps, truth.temp_c, s.mag_ut);
                    self.pending = Some(p);
                    p
                }
            };
            if t > t_s {
                break;
            }
            self.pending = None;
            if let Some(b) = self.bmi.as_mut() {
                b.set_temperature(true_temp);
                b.set_sample(t, accel, gyro);
            }
            if let (Some(m), Some(reading), true) = (self.mag.as_mut(), mag_ut, self.powered) {
                m.convert(reading);
            }
            if let (Some(m), Some(reading), true) = (self.bmm.as_mut(), mag_ut, self.powered) {
                m.advance_to(t);
                m.measure(t, reading);
            }
            if !self.running() || !self.powered {
                continue;
            }
            let fifo_on = self.fifo_on();
            if fifo_on && self.junk_next {
                // The first acquisition after enabling the FIFO: junk, not a sample.
                self.junk_next = false;
                self.junk += 1;
                if self.fifo.len() == FIFO_DEPTH as usize {
                    self.fifo.pop_front();
                    self.overrun = true;
                }
                self.fifo.push_back(Slot { gyro: [0; 6], accel: [0; 6] });
                continue;
            }
            self.produced += 1;
            self.history.push((accel, gyro));
            let t16 = (((temp - 25.0) * 16.0).round() as i16).to_le_bytes();
            self.regs[reg::OUT_TEMP_L as usize..reg::OUT_TEMP_L as usize + 2].copy_from_slice(&t16);
            if fifo_on {
                if self.fifo.len() == FIFO_DEPTH as usize {
                    self.fifo.pop_front();
                    self.overruns += usize::from(!self.overrun);
                    self.overrun = true;
                    self.dropped += 1;
                }
                self.fifo.push_back(slot);
            } else {
                self.fifo.clear();
                self.fifo.push_back(slot);
            }
        }
        self.now_s = self.now_s.max(t_s);
    }

    fn read_byte(&mut self, r: u8) -> u8 {
        let r = r & 0x7F;
        match r {
            0x18..=0x1D | 0x28..=0x2D => {
                let head = self.fifo.front().copied();
                let v = match (head, r) {
                    (Some(s), 0x18..=0x1D) => s.gyro[(r - 0x18) as usize],
                    (Some(s), _) => s.accel[(r - 0x28) as usize],
                    (None, _) => self.regs[r as usize],
                };
                self.regs[r as usize] = v;
                if r == 0x2D && head.is_some() {
                    self.fifo.pop_front();
                    self.overrun = false;
                }
                v
            }
            reg::FIFO_SRC => {
                let fss = self.fifo.len() as u8;
                let fth = self.reg(reg::FIFO_CTRL) & 0x1F;
                fss | (u8::from(self.overrun) << 6) | (u8::from(fth > 0 && fss >= fth) << 7)
            }
            reg::STATUS_REG => u8::from(!self.fifo.is_empty()) * 0x03,
            _ => self.regs[r as usize],
        }
    }

    fn write_byte(&mut self, r: u8, v: u8) {
        let r = r & 0x7F;
        if r == reg::CTRL_REG8 && v & 0x81 != 0 {
            // SW_RESET (bit 0) or BOOT (bit 7): the part reboots and does not answer meanwhile;
            // both bits clear themselves.
            if v & 0x01 != 0 {
                self.reset_registers();
                self.sw_resets += 1;
            }
            self.busy_until = self.now_s + BOOT_S;
            return;
        }
        if matches!(r, reg::WHO_AM_I | reg::FIFO_SRC | reg::STATUS_REG) {
            return; // read-only
        }
        if r == reg::CTRL_REG1_G {
            // The sensor samples at the configured ODR (with the rig's ODR error).
            let hz = [0.0, 14.9, 59.5, 119.0, 238.0, 476.0, 952.0, 0.0][(v >> 5) as usize];
            self.rig.set_odr_hz(hz);
        }
        let was_on = self.fifo_on();
        self.regs[r as usize] = v;
        if matches!(r, reg::CTRL_REG1_G | reg::CTRL_REG6_XL) {
            // The full scales saturate and quantise the rig's readings as the registers say.
            self.rig.set_ranges(self.gyro_range(), self.accel_range());
        }
        if !was_on && self.fifo_on() {
            self.fifo.clear();
            self.junk_next = true;
        }
    }
}

/// The bus time of a transaction at `hz` (s): 9 bit times per byte, the address byte of each
/// operation included.
pub fn bus_time_s(operations: &[Operation<'_>], hz: f64) -> f64 {
    let bytes: usize = operations
        .iter()
        .map(|op| {
            1 + match op {
                Operation::Write(b) => b.len(),
                Operation::Read(b) => b.len(),
            }
        })
        .sum();
    bytes as f64 * 9.0 / hz
}

impl ErrorType for Lsm9ds1Model {
    type Error = BusError;
}

impl I2c for Lsm9ds1Model {
    fn transaction(&mut self, address: u8, operations: &mut [Operation<'_>]) -> Result<(), BusError> {
        if let Some(c) = self.clock.clone() {
            self.advance_to(c.get());
        }
        if let Some(hz) = self.bus_hz {
            let t = self.now_s + bus_time_s(operations, hz);
            self.advance_to(t);
        }
        let acked = self.acks(address);
        self.transactions += 1;
        if !acked {
            return Err(BusError(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address)));
        }
        if address == lsm_mag_model::ADDR {
            if let Some(m) = self.mag.as_mut() {
                let r = m.transaction(operations, self.now_s);
                // The field is read at the rate the registers ask for.
                if let Some(hz) = m.odr_hz() {
                    self.rig.set_mag_odr_hz(hz);
                }
                return r;
            }
        }
        if address == bmm_model::ADDR {
            if let Some(m) = self.bmm.as_mut() {
                m.advance_to(self.now_s);
                let r = m.transaction(address, operations);
                // The field is read at the rate the part measures at.
                if let Some(hz) = m.odr_hz() {
                    self.rig.set_mag_odr_hz(hz);
                }
                return r;
            }
        }
        if let Some(b) = self.bmi.as_mut() {
            b.advance_to(self.now_s);
            let r = b.transaction(address, operations);
            // The BMI270 samples at its configured ODR (with the rig's ODR error).
            if let Some(hz) = b.odr_hz() {
                self.rig.set_odr_hz(hz);
            }
            return r;
        }
        let mut ptr: Option<u8> = None;
        let inc = self.reg(reg::CTRL_REG8) & 0x04 != 0;
        let next = |m: &Self, r: u8| -> u8 {
            match (inc, r) {
                (false, r) => r,
                // FIFO read pattern: past OUT_Z_H_XL the address wraps to OUT_X_L_G.
                (true, 0x2D) if m.fifo_on() => reg::OUT_X_L_G,
                (true, r) => r.wrapping_add(1),
            }
        };
        for op in operations.iter_mut() {
            match op {
                Operation::Write(bytes) => {
                    let mut it = bytes.iter();
                    if let Some(&r) = it.next() {
                        ptr = Some(r);
                    }
                    for &b in it {
                        let r = ptr.unwrap_or(0);
                        self.write_byte(r, b);
                        ptr = Some(next(self, r));
                    }
                }
                Operation::Read(buf) => {
                    for b in buf.iter_mut() {
                        let r = ptr.unwrap_or(0);
                        *b = self.read_byte(r);
                        ptr = Some(next(self, r));
                    }
                }
            }
        }
        Ok(())
    }
}
