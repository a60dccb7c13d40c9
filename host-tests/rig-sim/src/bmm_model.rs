//! A register model of the Bosch BMM150 magnetometer at 0x10 (the Nano 33 BLE Rev2's), as strict
//! as the part is about its power modes. Sources: the datasheet BST-BMM150-DS001-01 rev. 1.0
//! (DS: §4.2.3 sleep mode, §5.1 general remarks, §5.2 register map, §5.3 chip ID) and Bosch's
//! BMM150_SensorAPI v2.0.0 (API: `bmm150.c`, `bmm150.h`, `bmm150_defs.h`); `docs/rev2-sources.md`
//! §6 has the line numbers.
//!
//! - Power-on: suspend mode, POWER_CONTROL (0x4B) = 0x00. API: `bmm150_init` starts by setting
//!   the power bit to bring the part "from suspend to sleep mode" (see the caveats below).
//! - Suspend (0x4B bit 0 = 0): only 0x4B answers; every other register reads 0x00 and writes to
//!   them are ignored ([`Bmm150Model::blocked_reads`], [`Bmm150Model::ignored_writes`]). DS §5.3:
//!   CHIP_ID "can only be read if the power control bit (register 0x4B bit0) is enabled"; DS
//!   §4.2.3: in sleep mode (and not before) "the user has full access to the device registers".
//! - Setting bit 0 leaves suspend for sleep mode (DS §4.2.3), after [`START_UP_S`] (API:
//!   `BMM150_START_UP_TIME`, 3000 µs, waited after setting the bit in `bmm150_init` and
//!   `suspend_to_sleep_mode`). Until then the part still behaves as in suspend: it acknowledges
//!   its address, 0x4B answers, everything else reads 0x00 and ignores writes. Neither source says
//!   what the part does inside the start-up time; this reading fails a driver that does not wait
//!   with the same error as one that never set the bit (CHIP_ID 0x00). The other reading, no
//!   acknowledge at all until the start-up has passed, is [`Bmm150Model::nack_while_starting`].
//! - Clearing bit 0 returns to suspend (DS §4.2.3; API: `bmm150_set_op_mode(SUSPEND)` clears it by
//!   read-modify-write). The other registers do not keep their contents through suspend: after
//!   the next wake they hold their defaults (stricter than a part that keeps them; no source read
//!   says either way).
//! - Sleep and active modes: CHIP_ID 0x40 = 0x32 (DS §5.3; API `BMM150_CHIP_ID`). 0x40-0x4A are
//!   read-only, writes to them are ignored (DS §5.1). Defaults (DS §5.2): 0x4C 0x06 (op mode 11,
//!   sleep), 0x4D 0x3F, 0x4E 0x07, 0x4F-0x52 0x00. OP_MODE 0x4C bits 2:1: 00 normal, 01 forced,
//!   11 sleep (API: `BMM150_OP_MODE_MSK` 0x06, `BMM150_POWERMODE_*`); 10 is reported as
//!   [`Mode::Reserved`].
//! - Measurements (DS §4.2.4, §5.2 and Tables 6–13; API `bmm150_read_mag_data` and the
//!   floating-point `compensate_x/y/z`): in normal mode one per data-rate period (OP_MODE bits
//!   5:3: 10, 2, 6, 8, 15, 20, 25, 30 Hz), never faster than the repetitions allow
//!   (1 / (145 µs nXY + 500 µs nZ + 980 µs), nXY = 1 + 2 REP_XY, nZ = 1 + REP_Z: Zephyr's and
//!   Linux's drivers, citing DS §4.2.4); in forced mode one, then back to sleep (OP_MODE reads
//!   11). Each is the rig's field (µT, board frame, in the part's axes: [`raw_axes`], UNVERIFIED)
//!   turned into the counts Bosch's compensation maps back onto it with this part's
//!   trim ([`TRIM`]) and hall resistance ([`RHALL`]): x, y 13-bit (bits 7:3 of the LSB), z 15-bit
//!   (bits 7:1), RHALL 14-bit (bits 7:2) with data ready in 0x48 bit 0, which a read of the data
//!   registers clears when its burst ends (DS §4.6.6); beyond the ADC's range x, y read −4096 and
//!   z −16384 (Bosch's overflow values). Before the first measurement the data registers read 0.
//!   The noise is the rig's (the high-accuracy preset's 0.3 µT) whatever the repetitions: a
//!   lower preset is noisier on the part (DS Table 3), not in the model.
//! - Trim registers 0x5D–0x71 (API `read_trim_registers`): read-only, [`TRIM`]'s values, DIG_XYZ1
//!   with bit 15 clear.
//! - Soft reset: writing 0x4B with bits 7 and 1 set (API `BMM150_SET_SOFT_RESET` 0x82, ORed into
//!   0x4B) resets every register except 0x4B (API `bmm150.h`: "all the registers are reset to
//!   their default values except 0x4B"); the part is away for [`SOFT_RESET_S`] (API
//!   `BMM150_DELAY_SOFT_RESET`, 1000 µs: treated like the start-up). The two bits read back 0. In
//!   suspend a soft reset does nothing (DFRobot_BMM150's header: "soft reset can't be
//!   implemented under suspend mode"; not in the sources above).
//! - Multi-byte accesses auto-increment the register address (API: the trim registers are read
//!   in bursts).
//!
//! Caveats: DS §4.2.1/§4.2.2 (power-off and suspend mode) and the electrical table with the
//! start-up time were not among the pages read. "Suspend at power-on" and the 3 ms come from
//! Bosch's API; "only 0x4B in suspend" from DS §5.3 (CHIP_ID) and secondary sources
//! (DFRobot_BMM150: in suspend "users can only visit the content of the control register");
//! the value 0x00 for the other registers is the model's choice, found in no source read. DS
//! §5.2 lists 0x4B's default as 0x01, which reads as the value in sleep mode, where the table's
//! defaults can be read; the model powers up with 0x00, as Bosch's `bmm150_init` assumes.

use crate::lsm_model::{bus_time_s, BusError};
use embedded_hal::i2c::{ErrorKind, ErrorType, I2c, NoAcknowledgeSource, Operation};

/// The board frame's field in the BMM150's axes: `(−y, −x, −z)`, a turn of 180° about the
/// BMI270's x from its axes ([`crate::bmi_model::Bmi270Model::raw_axes`]): Bosch's note for the
/// two parts side by side, M5Stack's BMI270 + BMM150 boards and an Arduino forum thread on the
/// Rev2's layout. UNVERIFIED on a Nano 33 BLE: turns cannot tell the field from its negative,
/// only the dip's sign can (docs/frames.md).
pub fn raw_axes(b: [f32; 3]) -> [f32; 3] {
    let bmi = crate::bmi_model::Bmi270Model::raw_axes(b);
    [bmi[0], -bmi[1], -bmi[2]]
}

/// I2C address (API `BMM150_DEFAULT_I2C_ADDRESS`).
pub const ADDR: u8 = 0x10;
/// CHIP_ID of a BMM150.
pub const CHIP_ID: u8 = 0x32;
/// From setting the power bit to sleep mode (s).
pub const START_UP_S: f64 = 0.003;
/// How long a soft reset keeps the part away (s).
pub const SOFT_RESET_S: f64 = 0.001;

const REG_CHIP_ID: u8 = 0x40;
const DATA: u8 = 0x42;
const REP_XY: u8 = 0x51;
const REP_Z: u8 = 0x52;

/// This part's trim (Bosch's names), as the registers at 0x5D–0x71 hold it: values in the range
/// real parts report (the x/y sensitivity terms near 26 and 29, DIG_Z1 ~24700, DIG_XYZ1 ~6600),
/// with the small offsets non-zero so that a driver that leaves a term out is off.
pub const TRIM: gyrocal_fw::bmm150::Trim =
    gyrocal_fw::bmm150::Trim { x1: 2, y1: -3, x2: 26, y2: 27, z1: 24747, z2: 763, z3: -45, z4: 12, xy1: 29, xy2: -3, xyz1: 6615 };
/// The hall resistance the part reads (counts; near DIG_XYZ1 at room temperature).
pub const RHALL: u16 = 6780;
const POWER_CONTROL: u8 = 0x4B;
const OP_MODE: u8 = 0x4C;
/// Bits of 0x4B that are stored: power control (0) and SPI 3-wire (2).
const POWER_CONTROL_STORED: u8 = 0x05;

/// The part's power mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Power bit 0: only 0x4B answers.
    Suspend,
    /// Power bit 1, inside the start-up (or soft-reset) time: still as in suspend.
    StartingUp,
    /// OP_MODE 11: every register accessible, no measurement.
    Sleep,
    /// OP_MODE 00.
    Normal,
    /// OP_MODE 01.
    Forced,
    /// OP_MODE 10 (not used by Bosch's API).
    Reserved,
}

/// The BMM150.
#[derive(Clone)]
pub struct Bmm150Model {
    regs: [u8; 0x80],
    now_s: f64,
    /// With the power bit set: registers accessible from this time on (s).
    ready_at: f64,
    /// Fault injection: the part at 0x10 reports this CHIP_ID (another part).
    pub chip_id: u8,
    /// The other reading of the start-up: the part does not acknowledge its address at all until
    /// [`START_UP_S`] after the power bit was set (or [`SOFT_RESET_S`] after a soft reset).
    pub nack_while_starting: bool,
    /// Each transaction advances true time by its bus time at this rate (Hz), if set (a model that
    /// owns the clock; the board model advances it itself).
    pub bus_hz: Option<f64>,
    /// Transactions addressed to 0x10 (answered or not).
    pub transactions: u32,
    /// Suspend to sleep transitions (power bit 0 → 1).
    pub wakes: u32,
    /// Returns to suspend (power bit 1 → 0).
    pub suspends: u32,
    /// Soft resets done.
    pub soft_resets: u32,
    /// Bytes read from a register other than 0x4B while suspended or starting up (they read 0x00).
    pub blocked_reads: u32,
    /// Bytes written and ignored: to a register other than 0x4B while suspended or starting up, to
    /// a read-only register, or past 0x52.
    pub ignored_writes: u32,
    /// Transactions not acknowledged because of [`Self::nack_while_starting`].
    pub startup_nacks: u32,
    /// Measurements made.
    pub measurements: u32,
    /// No measurement before this time (s): the last one's period.
    next_measurement_s: f64,
}

impl Bmm150Model {
    /// A part just powered (suspend mode), at time `now_s`.
    pub fn new(now_s: f64) -> Self {
        let mut m = Self {
            regs: [0; 0x80],
            now_s,
            ready_at: now_s,
            chip_id: CHIP_ID,
            nack_while_starting: false,
            bus_hz: None,
            transactions: 0,
            wakes: 0,
            suspends: 0,
            soft_resets: 0,
            blocked_reads: 0,
            ignored_writes: 0,
            startup_nacks: 0,
            measurements: 0,
            next_measurement_s: 0.0,
        };
        m.defaults();
        m
    }

    /// Every register but 0x4B to its default (DS §5.2).
    fn defaults(&mut self) {
        let power = self.regs[POWER_CONTROL as usize];
        self.regs = [0; 0x80];
        self.regs[POWER_CONTROL as usize] = power;
        self.regs[OP_MODE as usize] = 0x06;
        self.regs[0x4D] = 0x3F;
        self.regs[0x4E] = 0x07;
        let t = TRIM;
        let z = |v: u16| v.to_le_bytes();
        self.regs[0x5D..0x5F].copy_from_slice(&[t.x1 as u8, t.y1 as u8]);
        self.regs[0x62..0x66].copy_from_slice(&[z(t.z4 as u16)[0], z(t.z4 as u16)[1], t.x2 as u8, t.y2 as u8]);
        let [z2, z1, xyz1, z3] = [t.z2 as u16, t.z1, t.xyz1, t.z3 as u16].map(z);
        self.regs[0x68..0x72].copy_from_slice(&[z2[0], z2[1], z1[0], z1[1], xyz1[0], xyz1[1], z3[0], z3[1], t.xy2 as u8, t.xy1]);
    }

    /// The rate it measures at now (Hz): the data rate in normal mode, capped by the
    /// repetitions' time; `None` when it does not measure on its own (suspend, sleep, forced).
    pub fn odr_hz(&self) -> Option<f64> {
        (self.mode() == Mode::Normal).then(|| {
            let odr = [10.0, 2.0, 6.0, 8.0, 15.0, 20.0, 25.0, 30.0][((self.regs[OP_MODE as usize] >> 3) & 7) as usize];
            let (nxy, nz) = (1.0 + 2.0 * self.regs[REP_XY as usize] as f64, 1.0 + self.regs[REP_Z as usize] as f64);
            f64::min(odr, 1.0 / (145e-6 * nxy + 500e-6 * nz + 980e-6))
        })
    }

    /// A reading of the rig (µT, board frame) at true time `t_s`: measured when the part is due
    /// to (normal mode, a period after the last; forced mode, once).
    pub fn measure(&mut self, t_s: f64, field_ut: [f32; 3]) {
        let field_ut = raw_axes(field_ut);
        let forced = self.mode() == Mode::Forced;
        let due = match self.odr_hz() {
            Some(hz) if t_s >= self.next_measurement_s => {
                self.next_measurement_s = t_s + 1.0 / hz;
                true
            }
            _ => forced,
        };
        if !due {
            return;
        }
        let [x, y, z] = counts(&TRIM, field_ut, RHALL);
        let [xl, xh] = ((x as u16) << 3).to_le_bytes();
        let [yl, yh] = ((y as u16) << 3).to_le_bytes();
        let [zl, zh] = ((z as u16) << 1).to_le_bytes();
        let [rl, rh] = (RHALL << 2).to_le_bytes();
        self.regs[DATA as usize..DATA as usize + 8].copy_from_slice(&[xl, xh, yl, yh, zl, zh, rl | 0x01, rh]);
        self.measurements += 1;
        if forced {
            self.regs[OP_MODE as usize] |= 0x06;
        }
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
    }

    /// The power bit (0x4B bit 0) is clear: the part is in suspend mode, its lowest-power state.
    pub fn suspended(&self) -> bool {
        self.regs[POWER_CONTROL as usize] & 0x01 == 0
    }

    /// POWER_CONTROL as stored (whatever the mode).
    pub fn power_control(&self) -> u8 {
        self.regs[POWER_CONTROL as usize]
    }

    /// A register as stored (whatever the mode; CHIP_ID is [`Self::chip_id`]).
    pub fn reg(&self, r: u8) -> u8 {
        if r == REG_CHIP_ID {
            self.chip_id
        } else {
            self.regs[r as usize & 0x7F]
        }
    }

    /// Registers beyond 0x4B are accessible: power bit set and the start-up passed.
    fn accessible(&self) -> bool {
        !self.suspended() && self.now_s >= self.ready_at
    }

    /// The power mode now.
    pub fn mode(&self) -> Mode {
        if self.suspended() {
            return Mode::Suspend;
        }
        if !self.accessible() {
            return Mode::StartingUp;
        }
        match (self.regs[OP_MODE as usize] >> 1) & 0x03 {
            0b00 => Mode::Normal,
            0b01 => Mode::Forced,
            0b10 => Mode::Reserved,
            _ => Mode::Sleep,
        }
    }

    /// Whether the part acknowledges its address at `t_s` (only [`Self::nack_while_starting`]
    /// makes it not).
    pub fn acks_at(&self, t_s: f64) -> bool {
        !(self.nack_while_starting && !self.suspended() && t_s < self.ready_at)
    }

    fn read_byte(&mut self, r: u8) -> u8 {
        if r == POWER_CONTROL {
            return self.regs[POWER_CONTROL as usize];
        }
        if !self.accessible() {
            self.blocked_reads += 1;
            return 0x00;
        }
        match r {
            REG_CHIP_ID => self.chip_id,
            r => self.regs[r as usize & 0x7F],
        }
    }

    fn write_power_control(&mut self, v: u8) {
        let was_on = !self.suspended();
        let on = v & 0x01 != 0;
        if v & 0x82 == 0x82 && self.accessible() {
            self.defaults();
            self.soft_resets += 1;
            self.ready_at = self.now_s + SOFT_RESET_S;
        }
        self.regs[POWER_CONTROL as usize] = (v & POWER_CONTROL_STORED & !0x01) | u8::from(on);
        match (was_on, on) {
            (false, true) => {
                self.wakes += 1;
                self.ready_at = self.ready_at.max(self.now_s + START_UP_S);
            }
            (true, false) => {
                self.suspends += 1;
                // The registers lose their contents in suspend.
                self.defaults();
            }
            _ => {}
        }
    }

    fn write_byte(&mut self, r: u8, v: u8) {
        if r == POWER_CONTROL {
            self.write_power_control(v);
        } else if !self.accessible() || !(OP_MODE..=0x52).contains(&r) {
            self.ignored_writes += 1;
        } else {
            self.regs[r as usize] = v;
        }
    }
}

impl ErrorType for Bmm150Model {
    type Error = BusError;
}

impl I2c for Bmm150Model {
    fn transaction(&mut self, address: u8, operations: &mut [Operation<'_>]) -> Result<(), BusError> {
        if address != ADDR {
            return Err(BusError(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address)));
        }
        self.transactions += 1;
        if !self.acks_at(self.now_s) {
            self.startup_nacks += 1;
            return Err(BusError(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address)));
        }
        if let Some(hz) = self.bus_hz {
            self.advance_to(self.now_s + bus_time_s(operations, hz));
        }
        let mut ptr = 0u8;
        let mut data_read = false;
        for op in operations.iter_mut() {
            match op {
                Operation::Write(bytes) => {
                    let Some((&r, data)) = bytes.split_first() else { continue };
                    ptr = r;
                    for &b in data {
                        self.write_byte(ptr, b);
                        ptr = ptr.wrapping_add(1);
                    }
                }
                Operation::Read(buf) => {
                    for b in buf.iter_mut() {
                        *b = self.read_byte(ptr);
                        data_read |= (DATA..DATA + 8).contains(&ptr) && self.accessible();
                        ptr = ptr.wrapping_add(1);
                    }
                }
            }
        }
        // Data ready clears when a burst of the data registers ends.
        if data_read {
            self.regs[DATA as usize + 6] &= !0x01;
        }
        Ok(())
    }
}

/// The raw counts (x, y 13-bit, z 15-bit) that Bosch's floating-point compensation with `trim`
/// and hall resistance `rhall` maps onto `field_ut` (the part's axes, µT): its equations
/// inverted, rounded; beyond the ADC's range the overflow values (−4096, −16384).
pub fn counts(trim: &gyrocal_fw::bmm150::Trim, field_ut: [f32; 3], rhall: u16) -> [i16; 3] {
    let (t, rh) = (trim, rhall as f64);
    let r = t.xyz1 as f64 * 16384.0 / rh - 16384.0;
    let p = t.xy2 as f64 * (r * r / 268_435_456.0) + r * t.xy1 as f64 / 16384.0 + 256.0;
    let xy = |b: f32, d1: i8, d2: i8| {
        let c = ((b as f64 * 16.0 - d1 as f64 * 8.0) * 8192.0 / (p * (d2 as f64 + 160.0))).round();
        if (-4095.0..=4095.0).contains(&c) {
            c as i16
        } else {
            -4096
        }
    };
    let z4 = t.z2 as f64 + t.z1 as f64 * rh / 32768.0;
    let z2 = t.z3 as f64 * (rh - t.xyz1 as f64);
    let cz = ((field_ut[2] as f64 * 16.0 * z4 * 4.0 + z2) / 131072.0 + t.z4 as f64).round();
    let z = if (-16383.0..=16383.0).contains(&cz) { cz as i16 } else { -16384 };
    [xy(field_ut[0], t.x1, t.x2), xy(field_ut[1], t.y1, t.y2), z]
}
