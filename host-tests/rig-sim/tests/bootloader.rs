//! Bootloader detection and the record-page guard: the stock and the updated Arduino bootloader
//! leave the records alone; a bootloader or MBR page that could cover them forbids writing.

use gyrocal_fw::bootloader::{Bootloader, Conflict, FlashMap};

const ERASED: u32 = 0xFFFF_FFFF;

fn map(nrffw0: u32, nrffw1: u32, reset_vector_0: u32, bootloader_entry: Option<u32>) -> FlashMap {
    FlashMap { nrffw0, nrffw1, reset_vector_0, bootloader_entry }
}

#[test]
fn the_stock_bootloader_is_recognised_and_safe() {
    // Stock build: UICR.NRFFW erased, reset vector 0x3EF9 (its ELF's vector table).
    let m = map(ERASED, ERASED, 0x3EF9, None);
    assert_eq!(m.bootloader(), Bootloader::Stock);
    assert_eq!(m.records_safe(), Ok(()));
}

#[test]
fn the_updated_bootloader_is_recognised_and_safe() {
    // MBR at 0 (reset vector 0xA81), bootloader at 0xE0000, MBR parameters at 0xFE000.
    let m = map(0xE0000, 0xFE000, 0xA81, Some(0xE0E61));
    assert_eq!(m.bootloader(), Bootloader::Updated);
    assert_eq!(m.records_safe(), Ok(()));
}

#[test]
fn anything_that_could_cover_the_records_forbids_writing() {
    // Adafruit's nRF52840 bootloader at 0xF4000 spans 0xF4000..0xFE000.
    let adafruit = map(0xF4000, 0xFF000, 0xA81, Some(0xF4E61));
    assert_eq!(adafruit.bootloader(), Bootloader::Other(0xF4000));
    assert_eq!(adafruit.records_safe(), Err(Conflict::UnknownBootloader(0xF4000)));
    // An MBR parameter page inside the record pages.
    assert_eq!(map(0xE0000, 0xF9000, 0xA81, None).records_safe(), Err(Conflict::InRecordPages(0xF9000)));
    // A bootloader entry point inside them.
    assert_eq!(map(0xFC000, ERASED, 0xA81, Some(0xF8101)).records_safe(), Err(Conflict::InRecordPages(0xF8100)));
    // A bootloader above the records with its parameters elsewhere is fine.
    assert_eq!(map(0xFC000, 0xFE000, 0xA81, Some(0xFC101)).records_safe(), Ok(()));
}
