//! The firmware's LSM9DS1 driver, FIFO reading, conversion and timestamps against the register
//! model fed by the rig simulator; and the button and LED logic.

use calib_core::procedure::{ErrorClass, Led, Phase};
use calib_core::Time;
use gyrocal_fw::button::{Button, Press};
use gyrocal_fw::led::render;
use gyrocal_fw::lsm9ds1::{reg, AccelScale, BusFault, GyroScale, Lsm9ds1, Odr, SensorConfig, SensorError};
use gyrocal_fw::stamp::Stamper;
use rig_sim::harness::at;
use rig_sim::lsm_model::{Board, Lsm9ds1Model};
use rig_sim::sim::{AccelRange, GyroRange, Rig};
use rig_sim::variant::Variant;
use std::cell::RefCell;
use std::rc::Rc;

/// The register model on a bus shared with [`ModelDelay`], so that the driver's waits pass
/// the model's time.
#[derive(Clone)]
struct Bus(Rc<RefCell<Lsm9ds1Model>>);

impl embedded_hal::i2c::ErrorType for Bus {
    type Error = <Lsm9ds1Model as embedded_hal::i2c::ErrorType>::Error;
}

impl embedded_hal::i2c::I2c for Bus {
    fn transaction(&mut self, address: u8, operations: &mut [embedded_hal::i2c::Operation<'_>]) -> Result<(), Self::Error> {
        self.0.borrow_mut().transaction(address, operations)
    }
}

impl Bus {
    fn advance_to(&self, t: f64) {
        self.0.borrow_mut().advance_to(t);
    }
}

/// A delay that advances the model's clock.
struct ModelDelay(Bus);

impl embedded_hal::delay::DelayNs for ModelDelay {
    fn delay_ns(&mut self, ns: u32) {
        let m = &self.0 .0;
        let t = m.borrow().now_s() + ns as f64 * 1e-9;
        m.borrow_mut().advance_to(t);
    }
}

fn model(odr: f64, board: Board) -> Bus {
    let mut cfg = Variant::Hobby.config(31, 0);
    cfg.odr_hz = odr;
    cfg.gyro.range = GyroRange::Dps500;
    cfg.accel.range = AccelRange::G2;
    Bus(Rc::new(RefCell::new(Lsm9ds1Model::new(Rig::new(cfg, 9), board))))
}

/// The driver initialised on `bus`, its waits passing the model's time.
fn init(bus: &Bus, c: SensorConfig) -> Result<Lsm9ds1<Bus>, SensorError> {
    Lsm9ds1::init(bus.clone(), c, &mut ModelDelay(bus.clone())).map_err(|e| e.0)
}

fn cfg(odr: Odr) -> SensorConfig {
    SensorConfig { odr, gyro: GyroScale::Dps500, accel: AccelScale::G2 }
}

#[test]
fn init_writes_the_datasheet_configuration() {
    for (odr, code) in [(Odr::Hz119, 0x60), (Odr::Hz238, 0x80), (Odr::Hz476, 0xA0), (Odr::Hz952, 0xC0)] {
        let bus = model(odr.hz() as f64, Board::Rev1);
        init(&bus, cfg(odr)).unwrap();
        let m = bus.0.borrow();
        assert_eq!(m.reg(reg::CTRL_REG1_G), code | 0x08, "{odr:?}"); // FS_G = 500 °/s
        assert_eq!(m.reg(reg::CTRL_REG6_XL), code, "{odr:?}"); // FS_XL = ±2 g
        assert_eq!(m.reg(reg::CTRL_REG8), 0x44); // BDU, IF_ADD_INC
        assert_eq!(m.reg(reg::CTRL_REG9), 0x02); // FIFO_EN
        assert_eq!(m.reg(reg::FIFO_CTRL), 0xC0); // continuous mode
    }
}

#[test]
fn missing_rev2_and_foreign_chips_are_named() {
    let err = |b| init(&model(119.0, b), cfg(Odr::Hz119)).err();
    assert!(matches!(err(Board::Missing), Some(SensorError::Missing)));
    assert!(matches!(err(Board::Rev2), Some(SensorError::Rev2Bmi270)));
    assert!(matches!(err(Board::OtherChip(0x3D)), Some(SensorError::WrongId(0x3D))));
}

/// A sample as read: accel (g), gyro (°/s), MCU timestamp (s).
type Read = ([f32; 3], [f32; 3], Time);

/// Polls the FIFO every `poll_s` of true time for `secs`; returns samples read and overruns seen.
fn stream(odr: Odr, poll_s: f64, secs: f64) -> (Vec<Read>, usize, Lsm9ds1Model) {
    let bus = model(odr.hz() as f64, Board::Rev1);
    bus.0.borrow_mut().rig_mut().set_pulse_us(1500.0); // the servo turns while we read
    let mut s = init(&bus, cfg(odr)).unwrap();
    let (mut out, mut overruns) = (vec![], 0);
    let mut stamper = Stamper::new(odr.hz());
    let mut t = bus.0.borrow().now_s();
    let end = t + secs;
    while t < end {
        t += poll_s;
        bus.advance_to(t);
        let st = s.fifo_status().unwrap();
        overruns += usize::from(st.overrun);
        let batch = stamper.batch(at(t), st.level as usize);
        for i in 0..st.level as usize {
            let raw = s.read_slot().unwrap();
            let (a, g) = s.convert(&raw);
            out.push((a, g, batch.stamp(i)));
        }
    }
    drop(s);
    let m = Rc::try_unwrap(bus.0).ok().expect("one owner").into_inner();
    (out, overruns, m)
}

/// A FIFO found full: the status says so before any overrun, and a sample that lands before
/// the first slot read is lost with its flag (that read clears it): what the firmware names as
/// a loss that may have happened.
#[test]
fn a_full_fifo_is_said_before_the_loss_its_first_read_hides() {
    let bus = model(952.0, Board::Rev1);
    let mut s = init(&bus, cfg(Odr::Hz952)).unwrap();
    let mut t = bus.0.borrow().now_s();
    let mut st = s.fifo_status().unwrap();
    for _ in 0..200 {
        if st.full {
            break;
        }
        t += 2e-4;
        bus.advance_to(t);
        st = s.fifo_status().unwrap();
    }
    // 32 slots, the first the junk slot a start discards.
    assert!(st.level == 31 && st.full && !st.overrun, "{st:?}");
    // One more sample lands before the first slot is read: overwritten, then the flag cleared.
    t += 1.1e-3;
    bus.advance_to(t);
    s.read_slot().unwrap();
    let after = s.fifo_status().unwrap();
    assert!(!after.overrun && !after.full, "{after:?}");
    assert_eq!(bus.0.borrow().counts().1, 1, "one sample dropped");
}

#[test]
fn no_sample_lost_at_952_hz_and_values_exact() {
    let (samples, overruns, m) = stream(Odr::Hz952, 0.02, 10.0);
    let (produced, dropped) = m.counts();
    assert_eq!((overruns, dropped), (0, 0));
    // Everything produced was read, except what arrived after the last poll.
    assert!(produced - samples.len() <= 1, "produced {produced}, read {}", samples.len());
    // Values: the rig's own readings, in order, reproduced through counts and sensitivity.
    for (k, ((a, g, _), (ra, rg))) in samples.iter().zip(m.history()).enumerate() {
        for i in 0..3 {
            assert!((a[i] - ra[i]).abs() <= 1e-6 + 1e-6 * ra[i].abs(), "sample {k}: accel {a:?} vs {ra:?}");
            assert!((g[i] - rg[i]).abs() <= 1e-5 + 1e-6 * rg[i].abs(), "sample {k}: gyro {g:?} vs {rg:?}");
        }
    }
    assert!(m.history().iter().any(|(_, g)| g.iter().any(|v| v.abs() > 10.0)), "the servo never turned");
    // Timestamps: measured period, within 0.5 % of the true one (the rig's ODR error), increasing.
    let n = samples.len();
    let period = samples[n - 1].2.since(samples[n / 2].2) / (n - 1 - n / 2) as f64;
    let true_period = 1.0 / m.rig().config().actual_odr_hz();
    assert!((period / true_period - 1.0).abs() < 0.005, "period {period} vs {true_period}");
    assert!(samples.windows(2).all(|w| w[1].2 >= w[0].2));
}

#[test]
fn slow_polling_reports_overrun() {
    let (_, overruns, m) = stream(Odr::Hz952, 0.06, 1.0);
    assert!(overruns > 0 && m.counts().1 > 0);
}

#[test]
fn samples_lost_without_the_overrun_flag_are_seen_by_their_count() {
    // 119 Hz read every 10 ms with ±1 ms jitter: never late. Then a long call inside a batch:
    // 0.5 s of samples overwritten, the flag cleared by the slot reads after it, the next read
    // finds 31 samples: the count is 57 short of the time, so the batch is late.
    let p = 1.0 / 117.0;
    let mut stamper = Stamper::new(119.0);
    let (mut t, mut produced, mut read) = (0.0f64, 0u64, 0u64);
    for k in 0..2000 {
        t += 0.010 + if k % 2 == 0 { 0.001 } else { -0.001 };
        let now = (t / p) as u64;
        let n = (now - read) as usize;
        (read, produced) = (now, now);
        assert!(!stamper.batch(at(t), n).late(at(t), n), "read {k}");
    }
    t += 0.5 + 31.0 * p;
    let n = 31usize;
    let lost = ((t / p) as u64 - produced) as usize - n;
    assert!(lost > 50 && stamper.batch(at(t), n).late(at(t), n), "{lost} samples lost unseen");
}

#[test]
fn a_bus_fault_mid_stream_is_an_error_value() {
    let bus = model(119.0, Board::Rev1);
    let mut s = init(&bus, cfg(Odr::Hz119)).unwrap();
    bus.advance_to(0.5);
    bus.0.borrow_mut().nack_from = Some(0);
    assert!(matches!(s.fifo_status(), Err(SensorError::Bus(BusFault::Nack))));
    assert!(matches!(s.read_slot(), Err(SensorError::Bus(BusFault::Nack))));
    assert!(matches!(s.temperature_c(), Err(SensorError::Bus(BusFault::Nack))));
}

#[test]
fn button_debounces_and_tells_long_presses() {
    let mut b = Button::new();
    let mut events = vec![];
    let mut t = 0.0;
    // Bouncy press: 5 ms toggles, then held 0.5 s, then released.
    for k in 0..6 {
        events.extend(b.update(at(t), k % 2 == 0));
        t += 0.005;
    }
    while t < 0.5 {
        events.extend(b.update(at(t), true));
        t += 0.01;
    }
    while t < 0.6 {
        events.extend(b.update(at(t), false));
        t += 0.01;
    }
    assert_eq!(events, vec![Press::Short]);
    while t < 3.0 {
        events.extend(b.update(at(t), true));
        t += 0.01;
    }
    events.extend(b.update(at(3.1), false));
    events.extend(b.update(at(3.2), false));
    assert_eq!(events, vec![Press::Short, Press::Long]);
}

#[test]
fn led_patterns_encode_phase_and_error_class() {
    let count = |led: Led| -> usize {
        (0..2000).step_by(10).map(|ms| render(led, ms).d13).collect::<Vec<_>>().windows(2).filter(|w| !w[0] && w[1]).count()
            + usize::from(render(led, 0).d13)
    };
    assert_eq!(count(Led::Busy(Phase::RigPoses)), 5);
    assert_eq!(count(Led::Busy(Phase::Store)), 7);
    assert_eq!(count(Led::Error(ErrorClass::Servo)), 3);
    assert_eq!(count(Led::Error(ErrorClass::Storage)), 7);
    assert!(render(Led::Error(ErrorClass::Sensor), 5).red);
    assert!(render(Led::Error(ErrorClass::Storage), 5).red && !render(Led::Error(ErrorClass::Storage), 5).green);
    assert!(render(Led::Done, 777).green);
}
