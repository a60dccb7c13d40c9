//! The firmware's A/B record storage on a simulated NOR flash, with the power cut at every
//! erase and word-write step of a store: the previous record always survives, a torn record is
//! never loaded.

use calib_core::formats::record::Record;
use gyrocal_fw::storage::{Slot, Storage, StoreError};
use rig_sim::harness::record;
use rig_sim::nor::{NorError, NorSim};

#[test]
fn empty_flash_has_no_record_then_stores_and_alternates() {
    let mut s = Storage::new(NorSim::new(8, 1)).unwrap();
    assert_eq!(s.load().unwrap(), None);
    assert_eq!(s.slots().unwrap(), [Slot::Empty, Slot::Empty]);
    assert_eq!(s.store(&record(1)).unwrap(), 0);
    assert_eq!(s.store(&record(2)).unwrap(), 1);
    assert_eq!(s.store(&record(3)).unwrap(), 0);
    assert_eq!(s.load().unwrap(), Some((0, record(3))));
    assert!(matches!(s.slots().unwrap()[1], Slot::Valid(r) if r.seq == 2));
}

#[test]
fn sequence_numbers_compare_across_wrap() {
    let mut s = Storage::new(NorSim::new(2, 1)).unwrap();
    s.store(&record(u32::MAX)).unwrap();
    s.store(&record(0)).unwrap();
    assert_eq!(s.load().unwrap().map(|(_, r)| r.seq), Some(0));
}

#[test]
fn power_cut_at_every_step_never_loses_the_previous_record() {
    // Steps of one store: one page erase + 47 word writes.
    let mut probe = Storage::new(NorSim::new(2, 0)).unwrap();
    probe.store(&record(1)).unwrap();
    let mut flash = probe.release();
    let before = flash.steps();
    let mut s = Storage::new(flash).unwrap();
    s.store(&record(2)).unwrap();
    flash = s.release();
    let per_store = flash.steps() - before;
    assert_eq!(per_store, 1 + calib_core::formats::record::LEN / 4);

    for history in [1u32, 2] {
        for cut in 0..per_store {
            let mut s = Storage::new(NorSim::new(2, cut as u64)).unwrap();
            for seq in 1..=history {
                s.store(&record(seq)).unwrap();
            }
            let mut flash = s.release();
            flash.cut_after(cut);
            let mut s = Storage::new(flash).unwrap();
            assert_eq!(s.store(&record(history + 1)), Err(StoreError::Flash), "cut {cut}");
            let mut flash = s.release();
            flash.reboot();
            let mut s = Storage::new(flash).unwrap();
            // The previous record is intact and is what loads; the torn one is never valid.
            assert_eq!(s.load().unwrap(), Some(((history as usize + 1) % 2, record(history))), "cut {cut}");
            let torn = s.slot(history as usize % 2).unwrap();
            assert!(!matches!(torn, Slot::Valid(_)), "cut {cut}: torn slot decoded as {torn:?}");
            // And the next store works again.
            s.store(&record(history + 1)).unwrap();
            assert_eq!(s.load().unwrap().map(|(_, r)| r.seq), Some(history + 1));
        }
    }
}

#[test]
fn a_version_1_record_in_flash_loads_and_the_next_store_is_the_current_version() {
    // A record of the release before the full K (format version 1, 156 bytes), as it sits in
    // flash, laid out field by field: the v2 header, then the diagonal 1σ, six quality fields, CRC.
    use embedded_storage::nor_flash::NorFlash;
    let mut v1 = record(4).encode().unwrap()[..calib_core::formats::record::LEN_V1].to_vec();
    v1[4] = 1;
    v1[14] &= 1; // flags: only "temperature unknown" exists in v1
    let sigma = [1e-4f32; 3];
    let quality = [0.01f32, 0.001, 2.0, 40.0, 180.0, 1e-4];
    for (i, x) in sigma.iter().chain(quality.iter()).enumerate() {
        v1[116 + 4 * i..120 + 4 * i].copy_from_slice(&x.to_le_bytes());
    }
    let crc = calib_core::formats::record::crc32(&v1[..152]);
    v1[152..].copy_from_slice(&crc.to_le_bytes());
    let mut flash = NorSim::new(2, 4);
    flash.write(0, &v1).unwrap();
    let mut s = Storage::new(flash).unwrap();
    let loaded = s.load().unwrap().map(|(slot, r)| (slot, r.seq, r.gyro_k, r.sigma_k));
    assert_eq!(loaded, Some((0, 4, record(4).gyro_k, record(4).sigma_k)));
    s.store(&record(5)).unwrap();
    assert_eq!(s.load().unwrap(), Some((1, record(5))));
    assert_eq!(s.release().bytes()[4096 + 4], calib_core::formats::record::VERSION);
}

#[test]
fn corrupt_slots_are_reported_and_skipped() {
    let mut s = Storage::new(NorSim::new(2, 3)).unwrap();
    s.store(&record(5)).unwrap();
    s.store(&record(6)).unwrap();
    let mut flash = s.release();
    // Flip one bit of the newest record (slot 1): only clearing is possible on NOR.
    use embedded_storage::nor_flash::NorFlash;
    let byte = (4096 + 20..4096 + 150).find(|&i| flash.bytes()[i] != 0).unwrap();
    let at = byte & !3;
    let mut word = [0u8; 4];
    word.copy_from_slice(&flash.bytes()[at..at + 4]);
    let k = byte - at;
    word[k] &= word[k] - 1; // clears the lowest set bit
    flash.write(at as u32, &word).unwrap();
    let mut s = Storage::new(flash).unwrap();
    assert!(matches!(s.slots().unwrap()[1], Slot::Invalid(_)));
    assert_eq!(s.load().unwrap().map(|(_, r)| r.seq), Some(5));
}

#[test]
fn flash_errors_are_values() {
    let mut flash = NorSim::new(2, 4);
    flash.cut_after(0);
    let mut s = Storage::new(flash).unwrap();
    assert_eq!(s.store(&record(1)), Err(StoreError::Flash));
    assert_eq!(s.load(), Err(StoreError::Flash));
    assert!(Storage::new(NorSim::new(1, 0)).is_err());
    let _ = NorError::Off;
}

#[test]
fn a_record_with_a_nan_is_refused_before_anything_is_erased() {
    let mut s = Storage::new(NorSim::new(2, 1)).unwrap();
    s.store(&record(1)).unwrap();
    s.store(&record(2)).unwrap();
    let steps = s.release().steps();
    let mut s = Storage::new(NorSim::new(2, 1)).unwrap();
    s.store(&record(1)).unwrap();
    s.store(&record(2)).unwrap();
    let bad = Record { tilt_deg: f32::INFINITY, ..record(3) };
    assert_eq!(s.store(&bad), Err(StoreError::NotFinite));
    // Both records kept; the flash was not touched.
    assert!(matches!(s.slots().unwrap(), [Slot::Valid(a), Slot::Valid(b)] if a.seq == 1 && b.seq == 2));
    assert_eq!(s.release().steps(), steps);
}
