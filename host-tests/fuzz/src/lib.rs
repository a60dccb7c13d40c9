//! The bodies of the fuzz targets (`fuzz_targets/`, run by cargo-fuzz with libFuzzer) and of the
//! replay of their corpora (`tests/corpora.rs`, in `cargo test-host`): every byte-level input of
//! gyrocal, each taking arbitrary bytes. A body must not panic, and checks what its input's
//! contract promises (round trips, finite values within the full scale, counts that add up).

use calib::{csvlog, offline};
use calib_core::formats::{protocol, record, region};
use embedded_hal::delay::DelayNs;
use embedded_hal::i2c::{ErrorKind, ErrorType, I2c, NoAcknowledgeSource, Operation};
use gyrocal_fw::{bmi270, lsm9ds1};

/// A target's body: arbitrary bytes in, a panic on a broken contract.
pub type Body = fn(&[u8]);

/// The targets, by name: the corpus of each is `corpus/<name>/`.
pub const TARGETS: [(&str, Body); 6] = [
    ("log_reader", log_reader),
    ("record", record),
    ("protocol", protocol),
    ("bmi270_fifo", bmi270_fifo),
    ("lsm9ds1_fifo", lsm9ds1_fifo),
    ("offline", offline),
];

/// A log's text, and the `--columns` spec of its first line when the first byte is odd.
fn log_text(data: &[u8]) -> Option<String> {
    let (&mode, rest) = data.split_first()?;
    let text = String::from_utf8_lossy(rest);
    if mode & 1 == 0 {
        return Some(text.into_owned());
    }
    let (spec, log) = text.split_once('\n')?;
    csvlog::remap(log, spec).ok()
}

/// The log reader (`gyrocal-calib LOG [--columns SPEC]`): `--columns` remapping, then parsing.
/// A parsed log's times increase and its rows' values are finite.
pub fn log_reader(data: &[u8]) {
    let Some(text) = log_text(data) else { return };
    if let Ok(log) = csvlog::parse(&text) {
        for w in log.rows.windows(2) {
            assert!(w[1].t > w[0].t, "time does not increase: {:?} then {:?}", w[0].t, w[1].t);
        }
        for r in &log.rows {
            assert!(r.accel_g.iter().chain(&r.gyro_dps).all(|v| v.is_finite()), "{r:?}");
        }
    }
}

/// The record decoder, on the bytes and on both flash pages (`region::load`). With an odd first
/// byte the CRC is made right first, so that the fields' validation is reached. A decoded record
/// encodes to bytes that decode to the same record.
pub fn record(data: &[u8]) {
    let Some((&mode, rest)) = data.split_first() else { return };
    let mut bytes = rest.to_vec();
    if mode & 1 == 1 {
        let len = match bytes.get(4) {
            Some(1) => record::LEN_V1,
            Some(2) => record::LEN_V2,
            Some(3) => record::LEN_V3,
            Some(4) => record::LEN_V4,
            _ => record::LEN,
        };
        if bytes.len() >= len {
            let crc = record::crc32(&bytes[..len - 4]);
            bytes[len - 4..len].copy_from_slice(&crc.to_le_bytes());
        }
    }
    if let Ok(rec) = record::Record::decode(&bytes) {
        let again = rec.encode().expect("a decoded record is finite");
        assert_eq!(record::Record::decode(&again), Ok(rec));
    }
    let mut pages = vec![0xFF; region::SLOTS * region::PAGE];
    let n = bytes.len().min(pages.len());
    pages[..n].copy_from_slice(&bytes[..n]);
    // The second page gets the same bytes: two slots with the same sequence number.
    let m = bytes.len().min(region::PAGE);
    pages[region::PAGE..region::PAGE + m].copy_from_slice(&bytes[..m]);
    let _ = region::load(&pages, region::PAGE);
}

/// The line protocol the PC reads from the board (`gyrocal-calib --port`): every line, and every
/// byte as a console command.
pub fn protocol(data: &[u8]) {
    for line in String::from_utf8_lossy(data).lines() {
        let _ = protocol::parse(line);
    }
    for &b in data {
        if let Some(c) = protocol::Command::decode(b) {
            assert_eq!(protocol::Command::decode(c.byte()), Some(c), "{c:?} is not its own byte");
        }
    }
}

/// The BMI270's header-mode FIFO frames at ±2000 °/s and ±16 g: every sample within the full
/// scale, no more samples than the bytes hold.
pub fn bmi270_fifo(data: &[u8]) {
    let (dps, g) = (2000.0 / 32768.0, 16.0 / 32768.0);
    let mut n = 0;
    let r = bmi270::parse_fifo(data, (dps, g), |a, w| {
        n += 1;
        assert!(a.iter().all(|v| v.abs() <= 16.0) && w.iter().all(|v| v.abs() <= 2000.0), "{a:?} {w:?}");
    });
    assert_eq!(r.samples, n);
    assert!(13 * r.samples <= data.len(), "{} samples from {} bytes", r.samples, data.len());
}

/// The LSM9DS1 driver over a bus whose every answer is the fuzzer's: identity, reset and
/// configuration read-back, then FIFO status and slot reads until the bytes run out. Every
/// converted sample is within the full scale.
pub fn lsm9ds1_fifo(data: &[u8]) {
    let cfg = lsm9ds1::SensorConfig::DEFAULT;
    let Ok(mut imu) = lsm9ds1::Lsm9ds1::init(Bus { data, at: 0 }, cfg, &mut NoDelay) else { return };
    let (dps, g) = (cfg.gyro.dps_per_lsb() * 32768.0, cfg.accel.g_per_lsb() * 32768.0);
    while let Ok(status) = imu.fifo_status() {
        assert!(status.level <= 32, "{} slots", status.level);
        for _ in 0..status.level {
            let Ok(raw) = imu.read_slot() else { return };
            let (a, w) = imu.convert(&raw);
            assert!(a.iter().all(|v| v.abs() <= g) && w.iter().all(|v| v.abs() <= dps), "{a:?} {w:?}");
        }
    }
}

/// The whole offline pipeline on an arbitrary log (`gyrocal-calib LOG`, the options from the
/// first byte): reading, calibrating, the JSON and the record. A result's JSON is one object;
/// a record it gives decodes.
pub fn offline(data: &[u8]) {
    let Some(&mode) = data.first() else { return };
    let Some(text) = log_text(data) else { return };
    let Ok(log) = csvlog::parse(&text) else { return };
    let options = offline::Options {
        method: None,
        no_rotations: mode & 2 != 0,
        whole_turns: mode & 4 != 0,
        range_dps: (mode & 8 != 0).then_some(245.0),
    };
    if let Ok(c) = offline::calibrate_log(&log, &options, None) {
        let json = c.json(log.messages);
        assert!(json.starts_with('{') && json.trim_end().ends_with('}'), "{json}");
        if let Some(rec) = c.record() {
            let bytes = rec.encode().expect("a stored record is finite");
            assert!(record::Record::decode(&bytes).is_ok());
        }
    }
}

/// An I2C bus answering every read with the next of `data`'s bytes; a NACK once they run out.
struct Bus<'a> {
    data: &'a [u8],
    at: usize,
}

impl ErrorType for Bus<'_> {
    type Error = ErrorKind;
}

impl I2c for Bus<'_> {
    fn transaction(&mut self, _address: u8, operations: &mut [Operation<'_>]) -> Result<(), ErrorKind> {
        for op in operations {
            if let Operation::Read(buf) = op {
                let end = self.at + buf.len();
                let src = self.data.get(self.at..end).ok_or(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address))?;
                buf.copy_from_slice(src);
                self.at = end;
            }
        }
        Ok(())
    }
}

/// No waiting: the bus answers at once.
struct NoDelay;

impl DelayNs for NoDelay {
    fn delay_ns(&mut self, _ns: u32) {}
}
