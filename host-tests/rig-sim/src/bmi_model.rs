//! A register model of the Bosch BMI270 at 0x68 (the Nano 33 BLE Rev2), as strict as the part is
//! with what Bosch's BMI270_SensorAPI does (every rule and its source: `docs/rev2-sources.md`):
//!
//! - CHIP_ID 0x24; CMD 0xB6 resets every register and the part does not answer for 2 ms.
//! - Advanced power save (PWR_CONF bit 0, on after a reset): an access that comes less than
//!   450 µs after the previous one is lost (a write does nothing, a read returns 0), and a burst
//!   write keeps only its first byte. With it off, an access less than 2 µs after a register
//!   write ([`WRITE_GAP_S`]) is lost the same way.
//! - The configuration upload: INIT_DATA (0x5E, the address does not increment) takes a burst at
//!   the word address in INIT_ADDR_0/1, only while INIT_CTRL = 0 and power save is off. INIT_CTRL
//!   = 1 starts the initialisation: 15 ms later INTERNAL_STATUS reads 0x01 if the bytes uploaded
//!   since the reset are one of Bosch's BMI270 configuration files ([`Loaded`]: the full 8192
//!   bytes, or the 328 of the maximum-FIFO one), else 0x02 (init error); 0x00 until then.
//! - ACC_CONF/GYR_CONF checked once initialised: an ODR or bandwidth the part does not have sets
//!   EVENT's error code (1 accelerometer, 2 gyro, 3 both).
//! - The data registers hold the latest sample handed in ([`Bmi270Model::set_sample`]: the
//!   rig's, by the board model that owns the rig) in counts at the configured full scales while
//!   PWR_CTRL enables that sensor (0 otherwise).
//! - The FIFO (2048 bytes with the full configuration, 6144 with the maximum-FIFO one: Bosch's
//!   README, "supports a 6kB FIFO") in header mode (FIFO_CONFIG_1 bit 4) with the sensors its acc_en and
//!   gyr_en bits (6, 7) take: each sample enters as a 0x8C frame (gyro then accelerometer, 6
//!   bytes each) while both produce, as 0x84 (accelerometer, 6 bytes) or 0x88 (gyro) while only
//!   one does (`bmi2_defs.h` headers and payload lengths). The gyro produces nothing for
//!   [`GYR_START_S`] after PWR_CTRL turns it on (its start-up), the accelerometer from its
//!   first sample: a FIFO that takes both holds accelerometer-only frames first. FIFO_LENGTH 0x24/0x25 its
//!   byte count (14 bits), FIFO_DATA 0x26 its bytes in one burst (a read past the data gives
//!   0x80, "over-read"). Full, it drops its oldest frames and the next read starts with a skip
//!   frame (0x40 and the frames lost, at most 255). A burst that ends inside a frame leaves it
//!   whole: the next burst reads it again (Bosch's parser skips a partially read frame, "the
//!   part repeats it": `bmi2.c` unpack functions). Each transaction's samples enter before its
//!   bytes are read (the board model advances to the transaction's end first), so a burst of
//!   FIFO_LENGTH + 17 bytes read after a stall runs into frames that arrived while it ran.
//! - A frame lands in the FIFO [`Bmi270Model::fifo_latency_s`] after its sample's tick (the data
//!   path from the tick into the FIFO; its value is not in the documents read here: 2 ms by
//!   default, the tests run 0 to 9 ms, anything below a period).
//! - Sensortime (SENSORTIME 0x18–0x1A, 24 bit, 39.0625 µs a count) runs on the part's own
//!   oscillator, the one its ODR divides: sample n of the rig is produced at count
//!   n · 25 600 / ODR (BMI160 datasheet Table 11: sensor_time bit 8 updates at 100 Hz; the
//!   BMI270 keeps the family's hardware-synchronised sensortime); between samples the count
//!   runs at the rate of the last two. With FIFO_CONFIG_0 bit 1 (fifo_time_en), a burst that has
//!   read the FIFO empty gets one sensortime frame (0x44 and the count when it starts), then 0x80
//!   (Bosch's FIFO over-read rule, as the BMA400 datasheet states it; a burst that stops at
//!   FIFO_LENGTH gets none).
//! - GYR_CAS (7-bit two's complement), where the loaded configuration puts it (0 before): with
//!   the full one on the feature pages (FEAT_PAGE 0x2F selects one, 0x30–0x3F is its 16-byte
//!   window, read in one burst as Bosch's `bmi2_get_feat_config` does), page 0 offset 0x0C;
//!   with the maximum-FIFO one, which has no feature pages, in 0x1E (`BMI2_GYR_CAS_GPIO0_ADDR`,
//!   Bosch's `get_gyro_cross_sense`; the full one's step counter SC_OUT_0 there reads 0). The part's raw data are the rig's
//!   readings; a rig made for it (`RigConfig::on_bmi270`) has the raw z→x coupling GYR_CAS/512
//!   on top of its cross-axis draw, as the part whose factory trim GYR_CAS measures it.
//! - TEMPERATURE_0/1 (0x22/0x23): int16 little-endian, °C = raw / 512 + 23 (Bosch's
//!   `bmi2_get_temperature_data` and the temperature example; 0x8000 is invalid), the
//!   temperature handed in ([`Bmi270Model::set_temperature`]) as of the latest sample while
//!   PWR_CTRL's temp_en (bit 3) is set (the part converts every 10 ms with the gyro on); 0x8000
//!   after a reset until then.
//! - FIFO_DOWNS 0x45 ([`Bmi270Model::fifo_downs_after_reset`] after a reset, 0x88 by default:
//!   the datasheet's register map was not read here, so the tests run 0x00 too): with
//!   gyr_fifo_filt_data (bit 3) clear the FIFO's gyro frames carry pre-filter data, reported on
//!   Bosch's forum with a 2× gyro scale at ±500 °/s (the model doubles them); a down-sampling
//!   field (6:4 accelerometer, 2:0 gyro) n ≠ 0 puts only every 2ⁿ-th sample into the FIFO.
//! - Reserved bits of ACC_RANGE (7:2), GYR_RANGE (7:4) and FIFO_CONFIG_0 (7:2) read 0, or 1
//!   with [`Bmi270Model::reserved_bits_read_one`] (unknown: the tests run both).
//! - GYR_OFF_COMP_6 0x77 bit 7 (user gain enable) after a reset: [`Bmi270Model::user_gain_after_reset`]
//!   (the datasheet's reset value was not available; a part whose NVM holds a CRT result may
//!   come up with it on); writable.

use crate::lsm_model::{bus_time_s, BusError};
use embedded_hal::i2c::{ErrorKind, ErrorType, I2c, NoAcknowledgeSource, Operation};

/// Bosch's full configuration file (`bmi270_config_file[]`, the `bmi2` crate's copy; its SHA-256
/// is checked against Bosch's source in the tests).
pub static BOSCH_CONFIG: &[u8; 8192] = &bmi2::config::BMI270_CONFIG_FILE;

/// Bosch's maximum-FIFO configuration file (`bmi270_maximum_fifo_config_file[]`, BMI270_SensorAPI
/// v2.86.1): the firmware's copy, whose SHA-256 the tests pin to Bosch's source, so that the model
/// runs Bosch's bytes, not whatever the firmware holds.
pub static BOSCH_MAX_FIFO_CONFIG: &[u8; 328] = &gyrocal_fw::bmi270::CONFIG;

/// The configuration file the part runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Loaded {
    /// [`BOSCH_CONFIG`]: the features, a 2 KB FIFO.
    Full,
    /// [`BOSCH_MAX_FIFO_CONFIG`]: no features, a 6 KB FIFO.
    MaxFifo,
}

/// I2C address.
pub const ADDR: u8 = 0x68;
/// How long the part is away after a soft reset (s).
pub const RESET_S: f64 = 0.002;
/// The access gap advanced power save needs (s).
pub const APS_GAP_S: f64 = 450e-6;
/// With power save off, the gap a register write needs before the next access (s): Bosch's
/// `BMI2_NORMAL_MODE_DELAY_IN_US`, Zephyr's `BMI270_TRANSC_DELAY_NORMAL`.
pub const WRITE_GAP_S: f64 = 2e-6;
/// From INIT_CTRL = 1 to the initialisation's result (s).
pub const INIT_S: f64 = 0.015;
/// The gyro's start-up from suspend to its first sample (s): Zephyr's `bmi270.h`
/// `BMI270_GYR_SUS_TO_NOR_START_UP_TIME` (45 ms; 2 ms in the fast start-up mode this firmware
/// does not use; the datasheet's table was not read here).
pub const GYR_START_S: f64 = 0.045;
/// The default [`Bmi270Model::fifo_latency_s`] (s).
pub const FIFO_LATENCY_S: f64 = 0.002;

const CHIP_ID: u8 = 0x00;
const ACC_X_LSB: u8 = 0x0C;
const EVENT: u8 = 0x1B;
const INTERNAL_STATUS: u8 = 0x21;
const GPIO0: u8 = 0x1E;
const FEAT_PAGE: u8 = 0x2F;
const FEATURES: u8 = 0x30;
const ACC_CONF: u8 = 0x40;
const ACC_RANGE: u8 = 0x41;
const GYR_CONF: u8 = 0x42;
const GYR_RANGE: u8 = 0x43;
const INIT_CTRL: u8 = 0x59;
const INIT_ADDR_0: u8 = 0x5B;
const INIT_ADDR_1: u8 = 0x5C;
const INIT_DATA: u8 = 0x5E;
const PWR_CONF: u8 = 0x7C;
const PWR_CTRL: u8 = 0x7D;
const CMD: u8 = 0x7E;
const FIFO_LENGTH_0: u8 = 0x24;
const FIFO_DATA: u8 = 0x26;
const FIFO_CONFIG_0: u8 = 0x48;
const FIFO_DOWNS: u8 = 0x45;
const FIFO_CONFIG_1: u8 = 0x49;
const SENSORTIME_0: u8 = 0x18;
const TEMPERATURE_0: u8 = 0x22;
/// FIFO size with [`Loaded::Full`] (bytes).
pub const FIFO_BYTES: usize = 2048;
/// FIFO size with [`Loaded::MaxFifo`] (bytes).
pub const MAX_FIFO_BYTES: usize = 6144;

/// The BMI270.
#[derive(Clone)]
pub struct Bmi270Model {
    /// The latest sample: (accelerometer g, gyro °/s), exact (the model quantises).
    last: ([f32; 3], [f32; 3]),
    fifo: std::collections::VecDeque<u8>,
    /// Frames dropped since the last read (a full FIFO).
    skipped: usize,
    /// Frames dropped since power-on, and the runs of them (each ended by a read).
    dropped: (usize, usize),
    regs: [u8; 0x80],
    upload: Vec<u8>,
    /// Bytes of the upload area written since the reset (its highest offset + 1).
    uploaded: usize,
    now_s: f64,
    /// The part does not answer before this time (s).
    away_until: f64,
    /// End of the last access (s), for the power-save gap.
    last_access_s: f64,
    /// End of the last register write (s), for the normal mode's gap.
    last_write_s: f64,
    /// INIT_CTRL = 1 was written at this time (s).
    init_started: Option<f64>,
    /// Accesses lost to the power-save rule.
    pub lost_accesses: u32,
    /// Soft resets seen.
    pub resets: u32,
    /// Fault injection: the upload byte at this offset arrives with a bit flipped (a disturbed
    /// bus), so that the initialisation fails.
    pub flip_upload_byte: Option<usize>,
    /// Each transaction advances true time by its bus time at this rate (Hz), if set (a model
    /// that owns the clock; the board model advances it itself).
    pub bus_hz: Option<f64>,
    /// The part's GYR_CAS (−64..63), reported where the loaded configuration puts it.
    pub gyr_cas: i8,
    /// Samples produced since power-on, the true time of the last one and the interval before it
    /// (s): the sensortime clock.
    produced: u64,
    last_sample_s: Option<f64>,
    /// The die temperature handed in (°C), and the one the part last converted.
    temp_c: Option<f64>,
    converted_temp_c: Option<f64>,
    /// When PWR_CTRL last turned the gyro on (s).
    gyro_on_s: Option<f64>,
    /// From a sample's tick to its frame in the FIFO (s).
    pub fifo_latency_s: f64,
    /// Frames produced, not yet in the FIFO: (when they land, s; bytes).
    landing: std::collections::VecDeque<(f64, Vec<u8>)>,
    /// The data frame a FIFO_DATA burst is in: its bytes still to come, and those read.
    frame_left: usize,
    frame_read: Vec<u8>,
    sample_interval_s: f64,
    /// The sensortime frame's bytes still to send in this burst; whether this burst sent one.
    time_frame: std::collections::VecDeque<u8>,
    time_sent: bool,
    /// GYR_OFF_COMP_6 bit 7 (user gain on) after a reset.
    pub user_gain_after_reset: bool,
    /// How long a soft reset keeps the part away (s; [`RESET_S`] by default).
    pub reset_s: f64,
    /// FIFO_DOWNS after a reset.
    pub fifo_downs_after_reset: u8,
    /// Reserved bits read 1.
    pub reserved_bits_read_one: bool,
}

/// The GYR_CAS of the model's part unless a test sets another: −1.4 % z→x, an example trim.
pub const GYR_CAS: i8 = -7;

impl Bmi270Model {
    /// A part just powered, at time `now_s`.
    pub fn new(now_s: f64) -> Self {
        let mut m = Self {
            last: ([0.0; 3], [0.0; 3]),
            fifo: std::collections::VecDeque::new(),
            skipped: 0,
            dropped: (0, 0),
            regs: [0; 0x80],
            upload: vec![0; 8192],
            uploaded: 0,
            now_s,
            away_until: 0.0,
            last_access_s: f64::NEG_INFINITY,
            last_write_s: f64::NEG_INFINITY,
            init_started: None,
            lost_accesses: 0,
            resets: 0,
            flip_upload_byte: None,
            bus_hz: None,
            gyr_cas: GYR_CAS,
            user_gain_after_reset: false,
            fifo_downs_after_reset: 0x88,
            reset_s: RESET_S,
            reserved_bits_read_one: false,
            produced: 0,
            last_sample_s: None,
            temp_c: None,
            converted_temp_c: None,
            gyro_on_s: None,
            fifo_latency_s: FIFO_LATENCY_S,
            landing: std::collections::VecDeque::new(),
            frame_left: 0,
            frame_read: vec![],
            sample_interval_s: 0.01,
            time_frame: std::collections::VecDeque::new(),
            time_sent: false,
        };
        m.reset();
        m
    }

    fn reset(&mut self) {
        self.regs = [0; 0x80];
        self.regs[CHIP_ID as usize] = 0x24;
        self.regs[PWR_CONF as usize] = 0x03;
        // Reset values: ChromiumOS EC's BMI260 emulator (same register map), emul_bmi260.c
        // bmi260_emul_reset(); the datasheet's register map was not read here.
        self.regs[ACC_CONF as usize] = 0xA8;
        self.regs[ACC_RANGE as usize] = 0x02;
        self.regs[GYR_CONF as usize] = 0xA9;
        self.regs[FIFO_CONFIG_0 as usize] = 0x02;
        self.regs[FIFO_CONFIG_1 as usize] = 0x10;
        self.regs[0x77] = if self.user_gain_after_reset { 0x80 } else { 0 };
        self.regs[FIFO_DOWNS as usize] = self.fifo_downs_after_reset;
        self.upload.fill(0);
        self.uploaded = 0;
        self.init_started = None;
        self.fifo.clear();
        self.skipped = 0;
        (self.frame_left, self.frame_read) = (0, vec![]);
        self.landing.clear();
        self.converted_temp_c = None;
        self.gyro_on_s = None;
    }

    /// A register as written (no read side effects).
    pub fn reg(&self, r: u8) -> u8 {
        self.regs[r as usize & 0x7F]
    }

    /// True time (s).
    pub fn now_s(&self) -> f64 {
        self.now_s
    }

    /// Advances true time to `t_s`.
    pub fn advance_to(&mut self, t_s: f64) {
        if t_s > self.now_s {
            self.now_s = t_s;
        }
        self.land();
    }

    /// The board frame's vector in Bosch's axes of the part: `(−y, x, z)`. Arduino_BMI270_BMM150
    /// (1.1.0 on, `BMI270.cpp`, TARGET_ARDUINO_NANO33BLE) remaps them with `x = −y, y = −x` to
    /// read as the Rev1's raw LSM9DS1 axes, whose `(−x, y, z)` is the board frame; HeadTracker's
    /// `sense.cpp` takes `(y, −x, z)` of the BMI270 where it flips the LSM9DS1's x.
    pub fn raw_axes(b: [f32; 3]) -> [f32; 3] {
        [-b[1], b[0], b[2]]
    }

    /// The sensor's reading produced at true time `t_s`: specific force (g) and rate (°/s), board
    /// frame, in the part's axes ([`Self::raw_axes`]); into the FIFO when it takes both sensors in
    /// header mode and they are on.
    pub fn set_sample(&mut self, t_s: f64, accel_g: [f32; 3], gyro_dps: [f32; 3]) {
        let (accel_g, gyro_dps) = (Self::raw_axes(accel_g), Self::raw_axes(gyro_dps));
        if let Some(t0) = self.last_sample_s.filter(|&t0| t_s > t0) {
            self.sample_interval_s = t_s - t0;
        }
        self.last_sample_s = Some(t_s);
        // A sample produced at t_s: the part's time is at least that.
        self.advance_to(t_s);
        self.produced += 1;
        self.last = (accel_g, gyro_dps);
        if self.regs[PWR_CTRL as usize] & 0x08 != 0 {
            self.converted_temp_c = self.temp_c.or(self.converted_temp_c);
        }
        let (pwr, fifo) = (self.regs[PWR_CTRL as usize], self.regs[FIFO_CONFIG_1 as usize]);
        let acc = pwr & 0x04 != 0 && fifo & 0x40 != 0;
        let gyr = pwr & 0x02 != 0 && fifo & 0x80 != 0 && self.gyro_on_s.is_some_and(|t0| t_s >= t0 + GYR_START_S);
        if !(self.initialised() && fifo & 0x10 != 0 && (acc || gyr)) {
            return;
        }
        // FIFO_DOWNS: every 2ⁿ-th sample of each sensor; pre-filter gyro data at twice the scale.
        let downs = self.regs[FIFO_DOWNS as usize];
        let every = |n: u8| self.produced.is_multiple_of(1u64 << n);
        let (acc, gyr) = (acc && every((downs >> 4) & 0x07), gyr && every(downs & 0x07));
        if !(acc || gyr) {
            return;
        }
        let mut frame = vec![0x80 | if acc { 0x04 } else { 0 } | if gyr { 0x08 } else { 0 }];
        let regs = gyr.then_some(0x12..0x18u8).into_iter().chain(acc.then_some(ACC_X_LSB..0x12));
        for r in regs.flatten() {
            frame.push(self.read_byte(r));
        }
        if gyr && downs & 0x08 == 0 {
            for k in 0..3 {
                let v = i16::from_le_bytes([frame[1 + 2 * k], frame[2 + 2 * k]]).saturating_mul(2).to_le_bytes();
                frame[1 + 2 * k..3 + 2 * k].copy_from_slice(&v);
            }
        }
        self.landing.push_back((t_s + self.fifo_latency_s, frame));
        self.land();
    }

    /// Frames whose latency has passed enter the FIFO (a full one drops its oldest).
    fn land(&mut self) {
        while let Some((at, _)) = self.landing.front() {
            if *at > self.now_s {
                break;
            }
            let Some((_, frame)) = self.landing.pop_front() else { break };
            while self.fifo.len() + frame.len() > self.fifo_bytes() {
                self.drop_oldest_frame();
                self.dropped = (self.dropped.0 + 1, self.dropped.1 + usize::from(self.skipped == 0));
                self.skipped += 1;
            }
            self.fifo.extend(frame);
        }
    }

    /// Drops the oldest frame (its length from its header).
    fn drop_oldest_frame(&mut self) {
        let Some(&header) = self.fifo.front() else { return };
        self.fifo.drain(..(1 + payload_len(header)).min(self.fifo.len()));
    }

    /// The end of a FIFO_DATA burst: a frame it cut is put back whole.
    fn end_burst(&mut self) {
        if self.frame_left > 0 {
            for b in self.frame_read.drain(..).rev() {
                self.fifo.push_front(b);
            }
        }
        (self.frame_left, self.frame_read) = (0, vec![]);
    }

    /// Frames a full FIFO dropped since power-on, and in how many runs (each a skip frame).
    pub fn dropped(&self) -> (usize, usize) {
        self.dropped
    }

    /// The die temperature (°C) the next sample is produced at.
    pub fn set_temperature(&mut self, temp_c: f64) {
        self.temp_c = Some(temp_c);
    }

    /// TEMPERATURE_0/1: the latest conversion, 0x8000 (invalid) before the first.
    fn temperature_raw(&self) -> i16 {
        self.converted_temp_c.map_or(i16::MIN, |t| ((t - 23.0) * 512.0).round().clamp(-32767.0, 32767.0) as i16)
    }

    /// The nominal ODR the accelerometer and gyro are set to (Hz), if they agree and are valid.
    pub fn odr_hz(&self) -> Option<f64> {
        let code = |r: u8| self.regs[r as usize] & 0x0F;
        let (a, g) = (code(ACC_CONF), code(GYR_CONF));
        (a == g && (0x06..=0x0C).contains(&a)).then(|| 25.0 * 2f64.powi(a as i32 - 6))
    }

    /// Sensortime counts per sample at the configured ODR (25 600 / ODR; 256 unconfigured).
    fn ticks_per_sample(&self) -> f64 {
        self.odr_hz().map_or(256.0, |hz| 25_600.0 / hz)
    }

    /// The sensortime count now (24 bit): sample n at n · ticks per sample.
    pub fn sensortime(&self) -> u32 {
        let tps = self.ticks_per_sample();
        let Some(t0) = self.last_sample_s else { return 0 };
        let since = ((self.now_s - t0) / self.sample_interval_s * tps).clamp(0.0, tps - 1.0);
        (((self.produced - 1) as f64 * tps + since.floor()) as u64 % (1 << 24)) as u32
    }

    /// The FIFO's next byte (a skip frame first after frames were dropped; once a burst has read
    /// it empty, a sensortime frame if enabled; 0x80 past the data).
    fn fifo_byte(&mut self) -> u8 {
        if self.skipped > 0 {
            let n = self.skipped.min(255) as u8;
            self.skipped = 0;
            // The skip frame: header, then its count.
            self.fifo.push_front(n);
            self.fifo.push_front(0x40);
        }
        if let Some(b) = self.fifo.pop_front() {
            if self.frame_left == 0 {
                (self.frame_left, self.frame_read) = (payload_len(b), vec![]);
            } else {
                self.frame_left -= 1;
            }
            self.frame_read.push(b);
            return b;
        }
        if let Some(b) = self.time_frame.pop_front() {
            return b;
        }
        if self.regs[FIFO_CONFIG_0 as usize] & 0x02 != 0 && !self.time_sent {
            self.time_sent = true;
            self.time_frame.extend(&self.sensortime().to_le_bytes()[..3]);
            return 0x44;
        }
        0x80
    }

    fn aps(&self) -> bool {
        self.regs[PWR_CONF as usize] & 1 != 0
    }

    fn initialised(&self) -> bool {
        self.loaded().is_some()
    }

    /// The configuration the part runs: the initialisation has ended, on one of Bosch's files.
    pub fn loaded(&self) -> Option<Loaded> {
        match self.init_started {
            Some(t) if self.now_s >= t + INIT_S => match &self.upload[..self.uploaded] {
                u if u == BOSCH_CONFIG.as_slice() => Some(Loaded::Full),
                u if u == BOSCH_MAX_FIFO_CONFIG.as_slice() => Some(Loaded::MaxFifo),
                _ => None,
            },
            _ => None,
        }
    }

    /// The FIFO's size (bytes) with the loaded configuration.
    fn fifo_bytes(&self) -> usize {
        if self.loaded() == Some(Loaded::MaxFifo) {
            MAX_FIFO_BYTES
        } else {
            FIFO_BYTES
        }
    }

    fn status(&self) -> u8 {
        match self.init_started {
            Some(t) if self.now_s >= t + INIT_S => 2 - u8::from(self.initialised()),
            _ => 0,
        }
    }

    /// EVENT's configuration error code for the current ACC_CONF/GYR_CONF.
    fn config_error(&self) -> u8 {
        if !self.initialised() {
            return 0;
        }
        let (acc, gyr) = (self.regs[ACC_CONF as usize], self.regs[GYR_CONF as usize]);
        let acc_ok = (0x01..=0x0C).contains(&(acc & 0x0F)) && (acc & 0x80 == 0 || (acc >> 4) & 0x07 <= 3);
        let gyr_ok = (0x06..=0x0D).contains(&(gyr & 0x0F)) && (gyr >> 4) & 0x03 <= 2;
        u8::from(!acc_ok) | (u8::from(!gyr_ok) << 1)
    }

    fn read_byte(&mut self, r: u8) -> u8 {
        match r {
            INTERNAL_STATUS => self.status(),
            FIFO_LENGTH_0 => (self.fifo.len() + 2 * usize::from(self.skipped > 0)) as u8,
            0x25 => ((self.fifo.len() + 2 * usize::from(self.skipped > 0)) >> 8) as u8 & 0x3F,
            FIFO_DATA => self.fifo_byte(),
            SENSORTIME_0..=0x1A => self.sensortime().to_le_bytes()[(r - SENSORTIME_0) as usize],
            TEMPERATURE_0 | 0x23 => self.temperature_raw().to_le_bytes()[(r - TEMPERATURE_0) as usize],
            EVENT => self.config_error() << 2,
            // GYR_CAS, 7 bits: feature page 0 offset 0x0C, or GPIO0 without feature pages.
            0x3C if self.regs[FEAT_PAGE as usize] == 0 && self.loaded() == Some(Loaded::Full) => self.gyr_cas as u8 & 0x7F,
            FEATURES..=0x3F => 0,
            GPIO0 if self.loaded() == Some(Loaded::MaxFifo) => self.gyr_cas as u8 & 0x7F,
            GPIO0 => 0,
            ACC_X_LSB..=0x17 => {
                let s = self.last;
                let (dps, g) = (
                    [2000.0, 1000.0, 500.0, 250.0, 125.0][(self.regs[GYR_RANGE as usize] & 0x07).min(4) as usize] / 32768.0,
                    [2.0, 4.0, 8.0, 16.0][(self.regs[ACC_RANGE as usize] & 0x03) as usize] / 32768.0,
                );
                let on = self.regs[PWR_CTRL as usize];
                let i = (r - ACC_X_LSB) as usize;
                let (value, enabled, lsb) = if i < 6 { (s.0[i / 2], on & 0x04 != 0, g) } else { (s.1[(i - 6) / 2], on & 0x02 != 0, dps) };
                let counts = if enabled { (value as f64 / lsb).round().clamp(-32768.0, 32767.0) as i16 } else { 0 };
                counts.to_le_bytes()[i % 2]
            }
            ACC_RANGE | FIFO_CONFIG_0 if self.reserved_bits_read_one => self.regs[r as usize] | 0xFC,
            GYR_RANGE if self.reserved_bits_read_one => self.regs[r as usize] | 0xF0,
            r => self.regs[r as usize & 0x7F],
        }
    }

    fn write_bytes(&mut self, r: u8, data: &[u8]) {
        match r {
            INIT_DATA => {
                if self.regs[INIT_CTRL as usize] != 0 || self.aps() {
                    return;
                }
                let word = self.regs[INIT_ADDR_0 as usize] as usize & 0x0F | (self.regs[INIT_ADDR_1 as usize] as usize) << 4;
                for (k, &b) in data.iter().enumerate() {
                    let at = 2 * word + k;
                    if let Some(slot) = self.upload.get_mut(at) {
                        *slot = if self.flip_upload_byte == Some(at) { b ^ 1 } else { b };
                        self.uploaded = self.uploaded.max(at + 1);
                    }
                }
            }
            CMD if data.first() == Some(&0xB6) => {
                self.reset();
                self.resets += 1;
                self.away_until = self.now_s + self.reset_s;
            }
            _ => {
                for (k, &b) in data.iter().enumerate() {
                    let reg = r as usize + k;
                    if reg >= 0x80 || matches!(reg as u8, CHIP_ID | INTERNAL_STATUS | EVENT | CMD) {
                        continue;
                    }
                    if reg as u8 == PWR_CTRL && b & 0x02 != 0 && self.regs[reg] & 0x02 == 0 {
                        self.gyro_on_s = Some(self.now_s);
                    }
                    self.regs[reg] = b;
                    if reg as u8 == INIT_CTRL && b & 1 != 0 && self.init_started.is_none() {
                        self.init_started = Some(self.now_s);
                    }
                }
            }
        }
    }
}

/// The payload bytes after a FIFO frame header (`bmi2_defs.h`): 12 both sensors, 6 one, 1 a
/// skip frame's count.
fn payload_len(header: u8) -> usize {
    match header & 0xFC {
        0x8C => 12,
        0x84 | 0x88 => 6,
        0x40 => 1,
        _ => 0,
    }
}

impl ErrorType for Bmi270Model {
    type Error = BusError;
}

impl I2c for Bmi270Model {
    fn transaction(&mut self, address: u8, operations: &mut [Operation<'_>]) -> Result<(), BusError> {
        if address != ADDR || self.now_s < self.away_until {
            return Err(BusError(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address)));
        }
        self.land();
        let gap = if self.aps() { (self.last_access_s, APS_GAP_S) } else { (self.last_write_s, WRITE_GAP_S) };
        let lost = self.now_s - gap.0 < gap.1;
        let aps = self.aps();
        if let Some(hz) = self.bus_hz {
            self.advance_to(self.now_s + bus_time_s(operations, hz));
        }
        self.last_access_s = self.now_s;
        if operations.iter().any(|op| matches!(op, Operation::Write(b) if b.len() > 1)) {
            self.last_write_s = self.now_s;
        }
        if lost {
            self.lost_accesses += 1;
        }
        // A sensortime frame is sent once per burst, and what a burst left of one is gone.
        (self.time_sent, self.time_frame) = (false, std::collections::VecDeque::new());
        let mut ptr = 0u8;
        for op in operations.iter_mut() {
            match op {
                Operation::Write(bytes) => {
                    let Some((&r, data)) = bytes.split_first() else { continue };
                    ptr = r;
                    if !lost && !data.is_empty() {
                        // Under power save a burst keeps only its first byte.
                        self.write_bytes(r, if aps { &data[..1] } else { data });
                    }
                }
                Operation::Read(buf) => {
                    for (k, b) in buf.iter_mut().enumerate() {
                        // FIFO_DATA (0x26) and INIT_DATA (0x5E) trap the address.
                        let r = if matches!(ptr, 0x26 | INIT_DATA) { ptr } else { ptr.wrapping_add(k as u8) };
                        *b = if lost { 0 } else { self.read_byte(r) };
                    }
                    if ptr == FIFO_DATA {
                        self.end_burst();
                    }
                }
            }
        }
        Ok(())
    }
}
