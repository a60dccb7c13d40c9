//! The firmware's BMI270 driver against the register model (Bosch's rules: the soft reset's
//! absence, the power-save access gap, the configuration upload and its check, invalid
//! configurations), and the configuration file against Bosch's published array.

use calib_core::formats::record::{Sensor, SensorSetup};
use gyrocal_fw::bmi270::{self, Bmi270, Bmi270Error, Config, CONFIG};
use rig_sim::bmi_model::{Bmi270Model, Loaded, BOSCH_CONFIG, BOSCH_MAX_FIFO_CONFIG, GYR_START_S};
use rig_sim::harness::at;
use sha2::{Digest, Sha256};
use std::cell::RefCell;
use std::rc::Rc;

#[derive(Clone)]
struct Bus(Rc<RefCell<Bmi270Model>>);

impl embedded_hal::i2c::ErrorType for Bus {
    type Error = rig_sim::lsm_model::BusError;
}

impl embedded_hal::i2c::I2c for Bus {
    fn transaction(&mut self, address: u8, operations: &mut [embedded_hal::i2c::Operation<'_>]) -> Result<(), Self::Error> {
        self.0.borrow_mut().transaction(address, operations)
    }
}

/// A delay that advances the model's clock; `scale` 0 never waits.
struct ModelDelay(Bus, f64);

impl embedded_hal::delay::DelayNs for ModelDelay {
    fn delay_ns(&mut self, ns: u32) {
        let m = &self.0 .0;
        let t = m.borrow().now_s() + ns as f64 * 1e-9 * self.1;
        m.borrow_mut().advance_to(t);
    }
}

/// The BMI270 on its own (its clock advanced by its bus time at 400 kHz), holding a sample at
/// rest: 1 g along z, a 0.3 °/s gyro bias on x.
fn bus() -> Bus {
    let mut m = Bmi270Model::new(0.0);
    m.bus_hz = Some(400e3);
    // Frames in the FIFO at their tick (the sensortime test sets a latency).
    m.fifo_latency_s = 0.0;
    m.set_sample(0.0, [0.0, 0.0, 1.0], [0.3, 0.0, 0.0]);
    Bus(Rc::new(RefCell::new(m)))
}

#[test]
fn the_configuration_files_are_boschs() {
    // SHA-256 of BMI270_SensorAPI's (v2.86.1, docs/rev2-sources.md) `bmi270_config_file[]`
    // (bmi270.c) and `bmi270_maximum_fifo_config_file[]` (bmi270_maximum_fifo.c): the model's
    // two (the second is the firmware's copy, which the firmware uploads).
    let hash = |b: &[u8]| -> String { Sha256::digest(b).iter().map(|b| format!("{b:02x}")).collect() };
    assert_eq!(hash(BOSCH_CONFIG), "2d75e68e343a13ff99be98261dfbd99d9e8c6f267da9e3c5aeb883276ad178db");
    assert_eq!(hash(BOSCH_MAX_FIFO_CONFIG), "e17bf316de8139afa8f9b27cd3520845c7809fb418cdd3f8439dcdcdea683ffe");
    assert_eq!(CONFIG.as_slice(), BOSCH_MAX_FIFO_CONFIG.as_slice());
}

/// The model runs either of Bosch's files, each with its own GYR_CAS place and FIFO size, and
/// nothing else: a firmware reading GYR_CAS where its configuration does not put it reads 0.
#[test]
fn the_model_runs_boschs_two_configurations_and_puts_gyr_cas_where_each_does() {
    use embedded_hal::i2c::I2c;
    for (file, loaded) in
        [(&BOSCH_CONFIG[..], Some(Loaded::Full)), (&BOSCH_MAX_FIFO_CONFIG[..], Some(Loaded::MaxFifo)), (&BOSCH_CONFIG[..328], None)]
    {
        let b = bus();
        let mut m = b.0.borrow_mut();
        // Each access 1 ms after the previous one's end (the power-save gap is 450 µs).
        let put = |m: &mut Bmi270Model, bytes: &[u8]| {
            let t = m.now_s() + 0.001;
            m.advance_to(t);
            m.write(bmi270::ADDR, bytes).unwrap();
        };
        put(&mut m, &[bmi270::reg::PWR_CONF, 0]);
        put(&mut m, &[bmi270::reg::INIT_CTRL, 0]);
        for (i, chunk) in file.chunks(64).enumerate() {
            let word = (i * 32) as u16;
            put(&mut m, &[bmi270::reg::INIT_ADDR_0, (word & 0x0F) as u8, (word >> 4) as u8]);
            put(&mut m, &[[bmi270::reg::INIT_DATA].as_slice(), chunk].concat());
        }
        put(&mut m, &[bmi270::reg::INIT_CTRL, 1]);
        let t = m.now_s() + 0.02;
        m.advance_to(t);
        assert_eq!(m.loaded(), loaded);
        let mut status = [0u8];
        m.write_read(bmi270::ADDR, &[bmi270::reg::INTERNAL_STATUS], &mut status).unwrap();
        assert_eq!(status[0], if loaded.is_some() { 1 } else { 2 });
        let (mut page, mut gpio0) = ([0u8; 16], [0u8]);
        m.write_read(bmi270::ADDR, &[0x30], &mut page).unwrap();
        m.write_read(bmi270::ADDR, &[bmi270::reg::GYR_CAS], &mut gpio0).unwrap();
        let cas = rig_sim::bmi_model::GYR_CAS as u8 & 0x7F;
        let want = match loaded {
            Some(Loaded::Full) => (cas, 0),
            Some(Loaded::MaxFifo) => (0, cas),
            None => (0, 0),
        };
        assert_eq!((page[0x0C], gpio0[0]), want, "{loaded:?}");
    }
}

#[test]
fn the_driver_brings_the_bmi270_up_as_boschs_api_does_and_reads_the_rig() {
    let b = bus();
    let mut s = Bmi270::init(b.clone(), Config::DEFAULT, &mut ModelDelay(b.clone(), 1.0)).unwrap_or_else(|(e, _)| panic!("{e}"));
    {
        let m = b.0.borrow();
        assert_eq!((m.resets, m.lost_accesses), (1, 0), "one soft reset; no access inside a power-save gap");
        // The 328-byte upload at 400 kHz (9 bit times a byte: 7.4 ms), the soft reset's and the
        // initialisation's waits (2 + 15 ms, the latter polled every 5 ms) and the power-save
        // gaps: well inside the 2 s watchdog (the 8 KiB file took 240 ms).
        println!("init took {:.1} ms of model time", m.now_s() * 1e3);
        assert!(m.now_s() > 0.0074 + 0.002 + 0.015 && m.now_s() < 0.06);
    }
    // In counts at ±2 g and ±500 °/s, back in g and °/s.
    let (accel, gyro) = s.read_sample().unwrap();
    assert_eq!(accel, [0.0, 0.0, 1.0]);
    assert!((gyro[0] - 0.3).abs() <= 0.5 / 65.536 && gyro[1] == 0.0, "{gyro:?}");
    assert_eq!(s.config(), Config::DEFAULT);
    // The part's GYR_CAS and user gain, as the record states them.
    let sensor = Sensor::Bmi270 { gyr_cas: rig_sim::bmi_model::GYR_CAS, user_gain: false };
    assert_eq!(s.setup(), SensorSetup { odr_hz: 100.0, gyro_range_dps: 500.0, accel_range_g: 2.0, sensor });
}

#[test]
fn gyr_cas_is_read_from_gpio0_as_seven_bit_twos_complement() {
    assert_eq!([bmi270::gyr_cas(0x3F), bmi270::gyr_cas(0x40), bmi270::gyr_cas(0x7F), bmi270::gyr_cas(0xC1)], [63, -64, -1, -63]);
    for (cas, gain) in [(-64, true), (63, false), (0, true)] {
        let b = bus();
        b.0.borrow_mut().gyr_cas = cas;
        b.0.borrow_mut().user_gain_after_reset = gain;
        let s = Bmi270::init(b.clone(), Config::DEFAULT, &mut ModelDelay(b.clone(), 1.0)).unwrap_or_else(|(e, _)| panic!("{e}"));
        assert_eq!(s.setup().sensor, Sensor::Bmi270 { gyr_cas: cas, user_gain: gain }, "{cas}");
    }
}

#[test]
fn what_the_part_rejects_the_driver_names() {
    // A driver that never waits: its accesses inside the power-save gaps are lost (the reset
    // among them; a lost read gives 0), so the identity read after the reset fails.
    let b = bus();
    let e = Bmi270::init(b.clone(), Config::DEFAULT, &mut ModelDelay(b.clone(), 0.0)).err().map(|e| e.0);
    assert_eq!(e, Some(Bmi270Error::WrongId(0)));
    assert!(b.0.borrow().lost_accesses > 0);
    // A part slower out of its soft reset than Bosch's 2 ms (issue 32 point 6: the driver had
    // no margin) comes up; one that never answers is named, after a bounded wait.
    for (reset_s, ok) in [(0.002, true), (0.005, true), (0.011, true), (0.05, false)] {
        let b = bus();
        b.0.borrow_mut().reset_s = reset_s;
        let r = Bmi270::init(b.clone(), Config::DEFAULT, &mut ModelDelay(b.clone(), 1.0)).map(|_| ()).map_err(|e| e.0);
        assert_eq!(r.is_ok(), ok, "reset {reset_s} s: {r:?}");
        if !ok {
            assert!(matches!(r, Err(Bmi270Error::Bus(_))), "{r:?}");
        }
    }
    // A byte of the upload disturbed on the bus: INTERNAL_STATUS says init error (2).
    let b = bus();
    b.0.borrow_mut().flip_upload_byte = Some(200);
    let e = Bmi270::init(b.clone(), Config::DEFAULT, &mut ModelDelay(b.clone(), 1.0)).err().map(|e| e.0);
    assert_eq!(e, Some(Bmi270Error::Init(2)));
    // A full scale the part does not have: refused before any transfer.
    let b = bus();
    let e = Bmi270::init(b.clone(), Config { gyro_range_dps: 300, ..Config::DEFAULT }, &mut ModelDelay(b.clone(), 1.0)).err().map(|e| e.0);
    assert_eq!(e, Some(Bmi270Error::BadConfig));
    assert_eq!(b.0.borrow().resets, 0);
}

#[test]
fn the_model_keeps_boschs_rules() {
    use embedded_hal::i2c::I2c;
    let b = bus();
    let mut m = b.0.borrow_mut();
    // After a reset power save is on: a second access within 450 µs is lost.
    m.write(bmi270::ADDR, &[bmi270::reg::CMD, 0xB6]).unwrap();
    let mut id = [0u8];
    assert!(m.write_read(bmi270::ADDR, &[bmi270::reg::CHIP_ID], &mut id).is_err(), "away for 2 ms after the soft reset");
    m.advance_to(0.003);
    m.write_read(bmi270::ADDR, &[bmi270::reg::CHIP_ID], &mut id).unwrap();
    assert_eq!(id[0], bmi270::CHIP_ID);
    m.advance_to(0.004);
    m.write(bmi270::ADDR, &[bmi270::reg::INIT_CTRL, 0x00]).unwrap();
    m.write(bmi270::ADDR, &[bmi270::reg::PWR_CONF, 0x00]).unwrap();
    assert_eq!(m.lost_accesses, 1);
    let mut pc = [0u8];
    m.advance_to(0.005);
    m.write_read(bmi270::ADDR, &[bmi270::reg::PWR_CONF], &mut pc).unwrap();
    assert_eq!(pc[0] & 1, 1, "the write inside the gap did nothing");
    // Initialisation without an upload: init error.
    m.advance_to(0.006);
    m.write(bmi270::ADDR, &[bmi270::reg::PWR_CONF, 0x00]).unwrap();
    // Power save off: an access right after a register write (< 2 µs) is lost, one 2 µs
    // later is not.
    let lost = m.lost_accesses;
    m.write(bmi270::ADDR, &[bmi270::reg::INIT_CTRL, 0x01]).unwrap();
    assert_eq!(m.lost_accesses, lost + 1);
    let t = m.now_s();
    m.advance_to(t + 2e-6);
    m.write(bmi270::ADDR, &[bmi270::reg::INIT_CTRL, 0x01]).unwrap();
    assert_eq!(m.lost_accesses, lost + 1);
    let t = m.now_s();
    m.advance_to(t + 2e-6);
    let mut st = [0u8];
    m.write_read(bmi270::ADDR, &[bmi270::reg::INTERNAL_STATUS], &mut st).unwrap();
    assert_eq!(st[0], 0, "not done yet");
    m.advance_to(0.03);
    m.write_read(bmi270::ADDR, &[bmi270::reg::INTERNAL_STATUS], &mut st).unwrap();
    assert_eq!(st[0], 2);
    // Another address: not acknowledged.
    assert!(m.write(0x69, &[0x00]).is_err());
}

#[test]
fn the_fifo_gives_every_sample_and_names_the_lost_ones() {
    let b = bus();
    let mut s = Bmi270::init(b.clone(), Config::DEFAULT, &mut ModelDelay(b.clone(), 1.0)).unwrap_or_else(|(e, _)| panic!("{e}"));
    // Three samples in, 10 ms apart once the gyro has started, three out, in order, in g and °/s.
    let t0 = b.0.borrow().now_s() + GYR_START_S;
    for k in 0..3 {
        b.0.borrow_mut().set_sample(t0 + 0.01 * k as f64, [0.0, 0.0, 1.0], [k as f32, 0.0, 0.0]);
    }
    // Read 4 ms after the newest (plus the bus time of the reads).
    b.0.borrow_mut().advance_to(t0 + 0.024);
    let mut got = vec![];
    let r = s.read_fifo(|a, g| got.push((a, g))).unwrap();
    assert_eq!((r.samples, r.lost), (3, 0));
    // The sensortime frame after the data, the newest sample's count; no date yet (the first
    // reads find the sample grid: the sensortime test).
    assert_eq!(r.newest_age_us, None);
    assert_eq!(r.sensortime.map(|t| t / 256), Some(b.0.borrow().sensortime() / 256), "the newest sample's count");
    assert!(got.iter().enumerate().all(|(k, (a, g))| *a == [0.0, 0.0, 1.0] && (g[0] - k as f32).abs() < 0.01), "{got:?}");
    // Empty: nothing (the over-read header ends the data).
    assert_eq!(s.read_fifo(|_, _| {}).unwrap(), bmi270::FifoRead::default());
    // 6 KB hold 472 frames: 600 samples lose 128, said by a skip frame at the head. A read
    // takes at most FIFO_BYTES (158 frames and the skip frame), the next ones the rest.
    for k in 0..600 {
        b.0.borrow_mut().set_sample(t0 + 0.03 + 0.01 * k as f64, [0.0, 0.0, 1.0], [0.0; 3]);
    }
    let reads: Vec<_> = (0..4).map(|_| s.read_fifo(|_, _| {}).map(|r| (r.samples, r.lost)).unwrap()).collect();
    assert_eq!(reads, [(158, 128), (158, 0), (156, 0), (0, 0)]);
    // The parser on its own: tag bits ignored, a sensortime frame read, a cut frame left for the
    // next burst (issue 32 point 3: it was counted lost).
    let mut bytes = vec![0x44, 1, 2, 3, 0x8D];
    bytes.extend_from_slice(&[0; 12]);
    bytes.extend_from_slice(&[0x8C, 0, 0]);
    let r = bmi270::parse_fifo(&bytes, Config::DEFAULT.per_lsb(), |_, _| {});
    assert_eq!((r.samples, r.lost, r.sensortime), (1, 0, Some(0x030201)));
    // One sensor's frames (6 bytes) are read past, each a missing pair (issue 32 point 2: the
    // parse ended at them and dropped the rest of the burst, counted nowhere).
    let mut bytes = vec![0x84, 0, 0, 0, 0, 0, 0];
    for _ in 0..2 {
        bytes.push(0x8C);
        bytes.extend_from_slice(&[0; 12]);
    }
    bytes.extend_from_slice(&[0x88, 0, 0, 0, 0, 0, 0, 0x44, 9, 0, 0, 0x80]);
    let r = bmi270::parse_fifo(&bytes, Config::DEFAULT.per_lsb(), |_, _| {});
    assert_eq!((r.samples, r.lost, r.partial, r.sensortime), (2, 0, 2, Some(9)));
    // A burst that stops at FIFO_LENGTH gets no sensortime frame; one that reads on gets one,
    // once, then the over-read pattern.
    use embedded_hal::i2c::I2c;
    let mut m = b.0.borrow_mut();
    let t = m.now_s();
    m.set_sample(t, [0.0, 0.0, 1.0], [0.0; 3]);
    let mut exact = [0u8; 13];
    m.write_read(bmi270::ADDR, &[bmi270::reg::FIFO_DATA], &mut exact).unwrap();
    assert_eq!(exact[0], 0x8C);
    let mut over = [0u8; 8];
    m.write_read(bmi270::ADDR, &[bmi270::reg::FIFO_DATA], &mut over).unwrap();
    assert_eq!((over[0], over[4], over[7]), (0x44, 0x80, 0x80), "{over:?}");
}

/// A burst that ends inside a frame (FIFO_LENGTH read, then frames arrive before the data
/// burst: a stalled loop) leaves the frame whole for the next burst: nothing is lost, nothing
/// misaligned (issue 32 point 3).
#[test]
fn a_frame_a_burst_cuts_is_read_whole_by_the_next() {
    let b = bus();
    let mut s = Bmi270::init(b.clone(), Config::DEFAULT, &mut ModelDelay(b.clone(), 1.0)).unwrap_or_else(|(e, _)| panic!("{e}"));
    b.0.borrow_mut().bus_hz = None;
    let t0 = b.0.borrow().now_s() + GYR_START_S;
    let mut gyro_x = vec![];
    let mut k = 0;
    // 50 samples queued (a 0.5 s stall), FIFO_LENGTH read, then 2 more arrive before the burst:
    // FIFO_LENGTH + 17 bytes read the 50, the 51st whole and 4 bytes of the 52nd.
    for _ in 0..50 {
        b.0.borrow_mut().set_sample(t0 + 0.01 * k as f64, [0.0, 0.0, 1.0], [k as f32, 0.0, 0.0]);
        k += 1;
    }
    use embedded_hal::i2c::I2c;
    let mut len = [0u8; 2];
    b.0.borrow_mut().write_read(bmi270::ADDR, &[bmi270::reg::FIFO_LENGTH_0], &mut len).unwrap();
    let n = u16::from_le_bytes(len) as usize;
    assert_eq!(n, 650);
    for _ in 0..2 {
        b.0.borrow_mut().set_sample(t0 + 0.01 * k as f64, [0.0, 0.0, 1.0], [k as f32, 0.0, 0.0]);
        k += 1;
    }
    let mut buf = vec![0u8; n + bmi270::FIFO_OVER_READ];
    b.0.borrow_mut().write_read(bmi270::ADDR, &[bmi270::reg::FIFO_DATA], &mut buf).unwrap();
    let r = bmi270::parse_fifo(&buf, Config::DEFAULT.per_lsb(), |_, g| gyro_x.push(g[0]));
    assert_eq!((r.samples, r.lost, r.partial), (51, 0, 0));
    let r = s.read_fifo(|_, g| gyro_x.push(g[0])).unwrap();
    assert_eq!((r.samples, r.lost), (1, 0));
    assert!(gyro_x.iter().enumerate().all(|(i, g)| (g - i as f32).abs() < 0.02), "{gyro_x:?}");
}

/// The gyro starts GYR_START_S after PWR_CTRL: the FIFO holds the accelerometer's frames alone
/// until then (0x84), which the driver counts as missing pairs, then both (issue 32 point 2).
#[test]
fn the_gyros_start_up_fills_the_fifo_with_accelerometer_frames_the_driver_names() {
    use embedded_hal::i2c::I2c;
    let b = bus();
    let mut s = Bmi270::init(b.clone(), Config::DEFAULT, &mut ModelDelay(b.clone(), 1.0)).unwrap_or_else(|(e, _)| panic!("{e}"));
    let t0 = b.0.borrow().now_s();
    for k in 0..10 {
        b.0.borrow_mut().set_sample(t0 + 0.01 * k as f64, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]);
    }
    let mut got = vec![];
    let r = s.read_fifo(|a, g| got.push((a, g))).unwrap();
    let alone = r.gyro_started_after.expect("the gyro's first sample in this read");
    println!("MEASURED start-up frames: {alone} accelerometer alone, then {} pairs", r.samples);
    assert_eq!(alone + r.samples, 10, "{r:?}");
    assert!((4..=5).contains(&alone) && r.lost == 0 && r.partial == 0, "the start-up is no loss: {r:?}");
    assert!(got.iter().all(|(_, g)| (g[0] - 1.0).abs() < 0.01), "only pairs with the gyro's reading: {got:?}");
    // Once started, a frame of one sensor is a missing pair.
    let t = t0 + 0.1;
    b.0.borrow_mut().write(bmi270::ADDR, &[bmi270::reg::FIFO_CONFIG_1, 0x50]).unwrap();
    b.0.borrow_mut().set_sample(t, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]);
    b.0.borrow_mut().write(bmi270::ADDR, &[bmi270::reg::FIFO_CONFIG_1, 0xD0]).unwrap();
    b.0.borrow_mut().set_sample(t + 0.01, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]);
    let r = s.read_fifo(|_, _| {}).unwrap();
    assert_eq!((r.samples, r.partial, r.gyro_started_after), (1, 1, None), "{r:?}");
}

/// The sensortime frame dates each batch's newest sample to a count (39 µs), where the read's own
/// time is up to a sample period late: the Stamper's line through those times is then as good
/// after 2 s as through the read times after a minute.
#[test]
fn sensortime_dates_the_newest_sample_to_a_count_and_the_stamper_converges_sooner() {
    use gyrocal_fw::stamp::Stamper;
    use rand::{Rng, SeedableRng};
    // Whatever the part's latency from a tick to its frame in the FIFO, below a period (issue 32
    // point 4: dated by the latest tick alone, a batch whose newest tick had not landed was a
    // period late).
    for latency_s in [0.0, 0.003, 0.009] {
        let b = bus();
        let mut s = Bmi270::init(b.clone(), Config::DEFAULT, &mut ModelDelay(b.clone(), 1.0)).unwrap_or_else(|(e, _)| panic!("{e}"));
        // The reads take no bus time here: the samples below are all the part produces.
        b.0.borrow_mut().bus_hz = None;
        b.0.borrow_mut().fifo_latency_s = latency_s;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        // The part's oscillator 1.7 % fast: a sample every 9.833 ms of true time.
        let period = 0.01 / 1.017;
        let t0 = b.0.borrow().now_s() + GYR_START_S;
        let mut next = t0;
        let mut produced = vec![];
        let (mut by_sensortime, mut by_read) = (Stamper::new(100.0), Stamper::new(100.0));
        let (mut worst_st, mut worst_read) = (0.0f64, 0.0f64);
        let mut read_at = t0;
        for batch in 0..300 {
            // Reads every 10 ms with up to 3 ms of jitter (the loop's other work).
            read_at += 0.01 + rng.random_range(0.0..0.003);
            while next <= read_at {
                b.0.borrow_mut().set_sample(next, [0.0, 0.0, 1.0], [0.0; 3]);
                produced.push(next);
                next += period;
            }
            b.0.borrow_mut().advance_to(read_at);
            let r = s.read_fifo(|_, _| {}).unwrap();
            let t_read = b.0.borrow().now_s();
            // The newest sample in the FIFO: produced at least the latency before the read.
            let Some(&newest) = produced.iter().rev().find(|&&t| t + latency_s <= t_read) else { continue };
            // The first reads find the grid: undated, counted only.
            let Some(age) = r.newest_age_us else {
                assert!(batch < 8, "read {batch} undated");
                by_sensortime.undated(at(t_read), r.samples);
                by_read.batch(at(t_read), r.samples);
                continue;
            };
            let t_st = t_read - f64::from(age) * 1e-6;
            worst_st = worst_st.max((t_st - newest).abs());
            worst_read = worst_read.max(t_read - newest);
            by_sensortime.batch(at(t_st), r.samples);
            by_read.batch(at(t_read), r.samples);
            if batch == 200 {
                let err = |p: f32| (f64::from(p) / period - 1.0).abs();
                println!(
                    "latency {latency_s} s: period error after 2 s: sensortime {:.2e}, read times {:.2e}",
                    err(by_sensortime.period_s()),
                    err(by_read.period_s())
                );
                assert!(err(by_sensortime.period_s()) < 1e-4, "{}", err(by_sensortime.period_s()));
                assert!(err(by_sensortime.period_s()) < err(by_read.period_s()) / 5.0);
            }
        }
        println!(
            "MEASURED latency {:.0} ms: newest sample's time by sensortime off by <= {:.3} ms, by the read <= {:.3} ms",
            latency_s * 1e3,
            worst_st * 1e3,
            worst_read * 1e3
        );
        // The nominal count rate's 1.7 % error over at most one period plus the latency, and
        // one count.
        assert!(
            worst_st < 0.02 * (period + latency_s) + f64::from(bmi270::SENSORTIME_US.0) / f64::from(bmi270::SENSORTIME_US.1) * 1e-6,
            "latency {latency_s}: {worst_st}"
        );
        assert!(worst_read > 0.5 * period, "the read time alone is up to a period late: {worst_read}");
    }
}

/// The die temperature (issue 32 point 1): TEMPERATURE_0/1 read 0x8000 (invalid: `None`) until
/// the part, with temp_en set by the driver's PWR_CTRL, converts with a sample; then raw / 512 +
/// 23 °C (Bosch's `bmi2_get_temperature_data`), to the register's 1/512 °C.
#[test]
fn the_driver_reads_the_die_temperature_and_none_before_the_first_conversion() {
    assert_eq!(bmi270::temperature_c(i16::MIN), None);
    assert_eq!(bmi270::temperature_c(0), Some(23.0));
    assert_eq!(bmi270::temperature_c(-512), Some(22.0));
    let b = bus();
    let mut s = Bmi270::init(b.clone(), Config::DEFAULT, &mut ModelDelay(b.clone(), 1.0)).unwrap_or_else(|(e, _)| panic!("{e}"));
    assert_eq!(s.temperature_c().unwrap(), None, "no conversion since the reset");
    let t = b.0.borrow().now_s() + 0.01;
    b.0.borrow_mut().set_temperature(31.337);
    b.0.borrow_mut().set_sample(t, [0.0, 0.0, 1.0], [0.0; 3]);
    let got = s.temperature_c().unwrap().expect("a conversion");
    assert!((got - 31.337).abs() <= 0.5 / 512.0 + 1e-5, "{got}");
}

/// FIFO_DOWNS is written (0x88: filtered data at the full rate) and read back, and reserved
/// bits are not compared, whatever the part comes up with (issue 32 point 5: the driver assumed
/// 0x88, so a part at 0x00 gave twice the gyro rate from its FIFO; a part whose reserved bits
/// read 1 failed the bring-up with ConfigMismatch). Reset values not read from the datasheet
/// here: both are run.
#[test]
fn fifo_downs_is_written_and_reserved_bits_are_not_compared() {
    for (downs, ones) in [(0x88, false), (0x00, false), (0x88, true), (0x00, true)] {
        let b = bus();
        b.0.borrow_mut().fifo_downs_after_reset = downs;
        b.0.borrow_mut().reserved_bits_read_one = ones;
        let mut s = Bmi270::init(b.clone(), Config::DEFAULT, &mut ModelDelay(b.clone(), 1.0))
            .unwrap_or_else(|(e, _)| panic!("FIFO_DOWNS {downs:#04x}, reserved ones {ones}: {e}"));
        assert_eq!(b.0.borrow().reg(bmi270::reg::FIFO_DOWNS), bmi270::FIFO_DOWNS_FILTERED);
        let t0 = b.0.borrow().now_s() + GYR_START_S;
        for k in 0..4 {
            b.0.borrow_mut().set_sample(t0 + 0.01 * k as f64, [0.0, 0.0, 1.0], [10.0, -20.0, 5.0]);
        }
        let mut got = vec![];
        let r = s.read_fifo(|_, g| got.push(g)).unwrap();
        assert_eq!(r.samples, 4, "every sample, none down-sampled: {r:?}");
        assert!(got.iter().all(|g| (g[0] - 10.0).abs() < 0.02 && (g[1] + 20.0).abs() < 0.02), "FIFO_DOWNS {downs:#04x}: {got:?}");
    }
}

/// What the benchmarks hand the procedure for a Rev2 is what the firmware reads: the rig's
/// temperature at the BMI270's register resolution, equal to the driver's reading of the
/// model's TEMPERATURE_0/1 for the same die temperature (issue 32 point 1: the harness gave
/// every part the LSM9DS1's 1/16 °C, and a Rev2 temperature the firmware did not read).
#[test]
fn the_harness_gives_a_rev2_rig_the_temperature_the_driver_reads() {
    use rand::SeedableRng;
    use rig_sim::sim::{Rig, RigConfig};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let cfg = RigConfig::realistic(&mut rng).on_bmi270(500, 2, &mut rng);
    let mut rig = Rig::new(cfg, 3);
    let b = bus();
    let mut s = Bmi270::init(b.clone(), Config::DEFAULT, &mut ModelDelay(b.clone(), 1.0)).unwrap_or_else(|(e, _)| panic!("{e}"));
    for _ in 0..500 {
        let reading = rig.next_sample();
        let truth = rig.truth();
        let t = b.0.borrow().now_s() + 0.01;
        b.0.borrow_mut().set_temperature(truth.temp_c);
        b.0.borrow_mut().set_sample(t, reading.accel_g, reading.gyro_dps);
        let read = s.temperature_c().unwrap().expect("a conversion");
        assert_eq!(read, reading.temp_c, "truth {} C", truth.temp_c);
    }
    // The LSM9DS1's rig keeps its 16 LSB/°C.
    let lsm = RigConfig::realistic(&mut rng);
    assert_eq!(lsm.temp_reading_c(25.03), 25.0);
    assert_eq!(cfg.temp_reading_c(25.03), (25.03f64 * 512.0).round() as f32 / 512.0);
}
