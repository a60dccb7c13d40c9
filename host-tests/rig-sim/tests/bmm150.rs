//! The firmware's BMM150 driver (wake it, read its trim, run the high-accuracy preset, compensate
//! as Bosch does) against the register model, which is as strict as the part about suspend mode;
//! and the Rev2 board model answering at 0x10.

use embedded_hal::i2c::I2c;
use gyrocal_fw::bmm150::{self, Bmm150, Config, ReadError};
use gyrocal_fw::lsm9ds1::{BusFault, ADDR_BMI270};
use rig_sim::bmm_model::{counts, Bmm150Model, Mode, RHALL, START_UP_S, TRIM};
use rig_sim::lsm_model::{Board, BusError, Lsm9ds1Model};
use rig_sim::sim::Rig;
use rig_sim::variant::Variant;
use std::cell::RefCell;
use std::rc::Rc;

/// A model on a bus shared with [`ModelDelay`], so that the driver's wait passes its time.
struct Bus<M>(Rc<RefCell<M>>);

impl<M> Clone for Bus<M> {
    fn clone(&self) -> Self {
        Bus(self.0.clone())
    }
}

impl<M: I2c<Error = BusError>> embedded_hal::i2c::ErrorType for Bus<M> {
    type Error = BusError;
}

impl<M: I2c<Error = BusError>> I2c for Bus<M> {
    fn transaction(&mut self, address: u8, operations: &mut [embedded_hal::i2c::Operation<'_>]) -> Result<(), BusError> {
        self.0.borrow_mut().transaction(address, operations)
    }
}

/// What a delay needs of a model: its clock.
trait Clock {
    fn now(&self) -> f64;
    fn set(&mut self, t_s: f64);
}

impl Clock for Bmm150Model {
    fn now(&self) -> f64 {
        self.now_s()
    }
    fn set(&mut self, t_s: f64) {
        self.advance_to(t_s);
    }
}

impl Clock for Lsm9ds1Model {
    fn now(&self) -> f64 {
        self.now_s()
    }
    fn set(&mut self, t_s: f64) {
        self.advance_to(t_s);
    }
}

/// A delay that advances the model's clock; `scale` 0 never waits.
struct ModelDelay<M>(Bus<M>, f64);

impl<M: Clock> embedded_hal::delay::DelayNs for ModelDelay<M> {
    fn delay_ns(&mut self, ns: u32) {
        let m = &self.0 .0;
        let t = m.borrow().now() + ns as f64 * 1e-9 * self.1;
        m.borrow_mut().set(t);
    }
}

/// The BMM150 on its own, just powered, its clock advanced by its bus time at 400 kHz.
fn bmm() -> Bus<Bmm150Model> {
    let mut m = Bmm150Model::new(0.0);
    m.bus_hz = Some(400e3);
    Bus(Rc::new(RefCell::new(m)))
}

fn board(b: Board) -> Bus<Lsm9ds1Model> {
    Bus(Rc::new(RefCell::new(Lsm9ds1Model::new(Rig::new(Variant::Hobby.config(31, 0), 9), b))))
}

/// [`Bmm150::init`] on `bus`, waiting `scale` times what it asks.
fn run<M: I2c<Error = BusError> + Clock>(bus: &Bus<M>, scale: f64) -> Result<Bmm150, ReadError> {
    Bmm150::init(&mut bus.clone(), Config::HIGH_ACCURACY, &mut ModelDelay(bus.clone(), scale), 0)
}

fn read(bus: &mut impl I2c<Error = BusError>, r: u8) -> Result<u8, BusError> {
    let mut b = [0u8];
    bus.write_read(bmm150::ADDR, &[r], &mut b).map(|()| b[0])
}

#[test]
fn the_driver_wakes_it_reads_its_trim_and_runs_the_high_accuracy_preset() {
    let bus = bmm();
    assert_eq!(bus.0.borrow().mode(), Mode::Suspend, "power-on is suspend");
    let d = run(&bus, 1.0).unwrap();
    assert_eq!(*d.trim(), TRIM);
    let m = bus.0.borrow();
    assert_eq!(m.mode(), Mode::Normal);
    assert_eq!([m.reg(0x51), m.reg(0x52), m.reg(0x4C)], [0x17, 0x52, 0x28], "nXY 47, nZ 83, 20 Hz, normal");
    // nXY 47 and nZ 83 take 49.3 ms: 20.3 Hz at most, so the 20 Hz data rate holds.
    assert_eq!(m.odr_hz(), Some(20.0));
    // Every access beyond 0x4B came after the start-up: none answered as in suspend.
    assert_eq!((m.blocked_reads, m.ignored_writes, m.wakes, m.suspends), (0, 0, 1, 0));
    // 0x4B read and written, CHIP_ID, three trim bursts, three registers written and read back.
    assert_eq!(m.transactions, 12);
    assert!(m.now_s() >= START_UP_S && m.now_s() < START_UP_S + 3e-3, "{} s", m.now_s());
}

#[test]
fn bosch_s_compensation_inverts_the_model_s_counts_to_a_count() {
    // Over the ADC's range the driver's compensation of the model's counts gives back the field
    // within half a count (0.18 µT for x and y, 0.18 µT for z with this trim).
    for k in -120..=120 {
        let f = [k as f32 * 8.3, -(k as f32) * 5.1 + 3.0, k as f32 * 10.7 - 7.0];
        let [x, y, z] = counts(&TRIM, f, RHALL);
        let back = TRIM.compensate(x, y, z, RHALL).expect("in range");
        for a in 0..3 {
            assert!((back[a] - f[a]).abs() <= 0.19, "axis {a}: {f:?} -> {back:?}");
        }
    }
    // Beyond the ADC (a magnet on the chip): Bosch's overflow, no reading.
    let [x, y, z] = counts(&TRIM, [2000.0, 0.0, 0.0], RHALL);
    assert_eq!(x, -4096);
    assert_eq!(TRIM.compensate(x, y, z, RHALL), None);
    assert_eq!(TRIM.compensate(10, 10, 10, 0), None, "a zero hall resistance");
}

#[test]
fn readings_come_at_the_data_rate_and_data_ready_clears_after_the_burst() {
    let bus = bmm();
    let mut d = run(&bus, 1.0).unwrap();
    let t0 = bus.0.borrow().now_s();
    let field = [21.5, -13.25, -40.0];
    bus.0.borrow_mut().measure(t0, field);
    let m = d.read(&mut bus.clone(), 10_000).unwrap().expect("a reading");
    for a in 0..3 {
        assert!((m[a] - field[a]).abs() <= 0.19, "{m:?}");
    }
    // Data ready cleared by that burst: nothing new until the next period (50 ms).
    assert_eq!(d.read(&mut bus.clone(), 20_000), Ok(None));
    bus.0.borrow_mut().measure(t0 + 0.01, field);
    assert_eq!(d.read(&mut bus.clone(), 30_000), Ok(None), "inside the period: no measurement");
    bus.0.borrow_mut().measure(t0 + 0.05, field);
    assert!(d.read(&mut bus.clone(), 60_000).unwrap().is_some());
    // No reading for longer than 500 ms: stopped, named.
    assert_eq!(d.read(&mut bus.clone(), 600_000), Err(ReadError::Stalled { ms: 540, limit_ms: 500 }));
    assert_eq!(ReadError::Stalled { ms: 540, limit_ms: 500 }.to_string(), "BMM150: no new reading for 540 ms (limit 500 ms): stopped");
    // The same counts 40 times in a row: stuck.
    let mut stuck = None;
    for k in 0..40 {
        bus.0.borrow_mut().measure(t0 + 1.0 + k as f64 * 0.051, field);
        if let Err(e) = d.read(&mut bus.clone(), 1_000_000 + k * 50_000) {
            stuck = Some(e);
            break;
        }
    }
    assert_eq!(stuck, Some(ReadError::Stuck { readings: 40 }));
}

#[test]
fn in_suspend_only_0x4b_answers_and_chip_id_reads_0() {
    let mut bus = bmm();
    // Straight after power-on: CHIP_ID reads 0x00, 0x4B reads 0x00 (power bit clear).
    assert_eq!(read(&mut bus, bmm150::reg::CHIP_ID), Ok(0x00));
    assert_eq!(read(&mut bus, bmm150::reg::POWER_CONTROL), Ok(0x00));
    // A write to OP_MODE in suspend is ignored: normal mode (00) never happens.
    bus.write(bmm150::ADDR, &[bmm150::reg::OP_MODE, 0x00]).unwrap();
    assert_eq!(bus.0.borrow().ignored_writes, 1);
    // The power bit set: still 0x00 inside the 3 ms start-up, 0x32 after it.
    bus.write(bmm150::ADDR, &[bmm150::reg::POWER_CONTROL, 0x01]).unwrap();
    assert_eq!(bus.0.borrow().mode(), Mode::StartingUp);
    assert_eq!(read(&mut bus, bmm150::reg::CHIP_ID), Ok(0x00));
    let t = bus.0.borrow().now_s() + START_UP_S;
    bus.0.borrow_mut().advance_to(t);
    assert_eq!(read(&mut bus, bmm150::reg::CHIP_ID), Ok(bmm150::CHIP_ID));
    // OP_MODE holds its default (sleep, 0x06), not the write made in suspend.
    assert_eq!(read(&mut bus, bmm150::reg::OP_MODE), Ok(0x06));
    assert_eq!(bus.0.borrow().mode(), Mode::Sleep);
    assert_eq!(bus.0.borrow().blocked_reads, 2);
}

#[test]
fn a_driver_that_does_not_wait_reads_chip_id_0_and_leaves_the_part_suspended() {
    let bus = bmm();
    assert_eq!(run(&bus, 0.0).err(), Some(ReadError::WrongId(0x00)));
    let m = bus.0.borrow();
    assert_eq!(m.blocked_reads, 1);
    // WrongId writes 0x4B back as it was found: power bit clear again.
    assert!(m.suspended());
    assert_eq!((m.wakes, m.suspends), (1, 1));
}

#[test]
fn registers_are_lost_in_suspend_and_a_soft_reset_keeps_0x4b() {
    let mut bus = bmm();
    let wake = |bus: &mut Bus<Bmm150Model>| {
        bus.write(bmm150::ADDR, &[bmm150::reg::POWER_CONTROL, 0x01]).unwrap();
        let t = bus.0.borrow().now_s() + START_UP_S;
        bus.0.borrow_mut().advance_to(t);
    };
    wake(&mut bus);
    // Normal mode, then a soft reset (0x82 ORed into 0x4B): OP_MODE back to sleep, power bit kept.
    bus.write(bmm150::ADDR, &[bmm150::reg::OP_MODE, 0x00]).unwrap();
    assert_eq!(bus.0.borrow().mode(), Mode::Normal);
    bus.write(bmm150::ADDR, &[bmm150::reg::POWER_CONTROL, 0x83]).unwrap();
    let t = bus.0.borrow().now_s() + 1e-3;
    bus.0.borrow_mut().advance_to(t);
    assert_eq!(read(&mut bus, bmm150::reg::OP_MODE), Ok(0x06));
    assert_eq!(read(&mut bus, bmm150::reg::POWER_CONTROL), Ok(0x01), "soft-reset bits read back 0");
    assert_eq!(bus.0.borrow().soft_resets, 1);
    // Through suspend and back: a register written in sleep mode holds its default again.
    bus.write(bmm150::ADDR, &[0x4E, 0x3F]).unwrap();
    assert_eq!(read(&mut bus, 0x4E), Ok(0x3F));
    bus.write(bmm150::ADDR, &[bmm150::reg::POWER_CONTROL, 0x00]).unwrap();
    wake(&mut bus);
    assert_eq!(read(&mut bus, 0x4E), Ok(0x07));
}

#[test]
fn the_drivers_wait_also_covers_a_part_that_does_not_answer_while_starting() {
    let bus = bmm();
    bus.0.borrow_mut().nack_while_starting = true;
    run(&bus, 1.0).unwrap();
    assert_eq!(bus.0.borrow().mode(), Mode::Normal);
    assert_eq!(bus.0.borrow().startup_nacks, 0);
    // Without the wait, the CHIP_ID read is not acknowledged.
    let bus = bmm();
    bus.0.borrow_mut().nack_while_starting = true;
    assert_eq!(run(&bus, 0.0).err(), Some(ReadError::Bus(BusFault::Nack)));
    assert_eq!(bus.0.borrow().startup_nacks, 1);
}

#[test]
fn nothing_at_0x10_is_a_nack() {
    // A Rev1 board (LSM9DS1 only): nothing acknowledges 0x10.
    let bus = board(Board::Rev1);
    assert_eq!(run(&bus, 1.0).err(), Some(ReadError::Bus(BusFault::Nack)));
    assert_eq!(ReadError::Bus(BusFault::Nack).to_string(), "BMM150: nothing acknowledges 0x10");
    // A lone BMM150 model does not answer another address either.
    let mut m = Bmm150Model::new(0.0);
    assert!(m.write(0x11, &[bmm150::reg::POWER_CONTROL, 0x01]).is_err());
    assert!(m.suspended());
}

#[test]
fn another_chip_id_is_named_and_0x4b_restored() {
    let bus = bmm();
    bus.0.borrow_mut().chip_id = 0x33;
    let e = run(&bus, 1.0).err();
    assert_eq!(e, Some(ReadError::WrongId(0x33)));
    assert_eq!(e.map(|e| e.to_string()).unwrap_or_default(), "BMM150: CHIP_ID 0x33 at 0x10 (expected 0x32)");
    assert_eq!(bus.0.borrow().power_control(), 0x00);
}

#[test]
fn a_rev2_board_acks_0x10_and_the_driver_runs_its_bmm150() {
    let rev1 = board(Board::Rev1);
    assert!(!rev1.0.borrow().acks(bmm150::ADDR));
    assert!(rev1.0.borrow().bmm().is_none());
    let rev2 = board(Board::Rev2);
    {
        let b = rev2.0.borrow();
        assert!(b.acks(bmm150::ADDR) && b.acks(ADDR_BMI270) && !b.acks(0x6B));
        assert!(b.bmm().is_some_and(|m| m.suspended()));
    }
    run(&rev2, 1.0).unwrap();
    {
        let b = rev2.0.borrow();
        let m = b.bmm().unwrap();
        assert_eq!(m.mode(), Mode::Normal);
        assert_eq!((m.wakes, m.suspends, m.transactions, m.blocked_reads), (1, 0, 12, 0));
    }
    // The BMI270 still answers at 0x68 with its CHIP_ID.
    let mut b = [0u8];
    rev2.clone().write_read(ADDR_BMI270, &[0x00], &mut b).unwrap();
    assert_eq!(b[0], 0x24);
    // Woken and then power-cycled: the new part is suspended with fresh counters, and the board
    // does not answer while its rail boots.
    rev2.clone().write(bmm150::ADDR, &[bmm150::reg::POWER_CONTROL, 0x01]).unwrap();
    assert!(!rev2.0.borrow().bmm().unwrap().suspended());
    rev2.0.borrow_mut().set_powered(false);
    assert!(!rev2.0.borrow().acks(bmm150::ADDR));
    rev2.0.borrow_mut().set_powered(true);
    let b = rev2.0.borrow();
    let m = b.bmm().unwrap();
    assert!(m.suspended());
    assert_eq!((m.wakes, m.transactions), (0, 0));
}

#[test]
fn both_magnetometers_name_their_shared_failures_with_their_part_and_address() {
    use gyrocal_fw::lsm9ds1_mag::Error as Lsm;
    let cases: [(String, &str); 10] = [
        (ReadError::Bus(BusFault::Nack).to_string(), "BMM150: nothing acknowledges 0x10"),
        (ReadError::Bus(BusFault::Overrun).to_string(), "BMM150 I2C: Overrun"),
        (
            ReadError::ConfigMismatch { reg: 0x4C, wrote: 0x28, read: 0x00 }.to_string(),
            "BMM150: register 0x4C reads 0x00 after writing 0x28",
        ),
        (ReadError::Stuck { readings: 40 }.to_string(), "BMM150: 40 readings in a row with the same counts: stuck"),
        (ReadError::WrongId(0x00).to_string(), "BMM150: CHIP_ID 0x00 at 0x10 (expected 0x32)"),
        (Lsm::Bus(BusFault::Nack).to_string(), "LSM9DS1 magnetometer: nothing acknowledges 0x1E"),
        (Lsm::Bus(BusFault::Bus).to_string(), "LSM9DS1 magnetometer I2C: Bus"),
        (
            Lsm::ConfigMismatch { reg: 0x20, wrote: 0xFC, read: 0x7C }.to_string(),
            "LSM9DS1 magnetometer: register 0x20 reads 0x7C after writing 0xFC",
        ),
        (Lsm::Stalled { ms: 260, limit_ms: 250 }.to_string(), "LSM9DS1 magnetometer: no new reading for 260 ms (limit 250 ms): stopped"),
        (Lsm::Stuck { readings: 80 }.to_string(), "LSM9DS1 magnetometer: 80 readings in a row with the same counts: stuck"),
    ];
    for (got, want) in cases {
        assert_eq!(got, want);
    }
}
