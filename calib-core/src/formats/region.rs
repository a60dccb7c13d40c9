//! The two record pages (A/B) as the firmware's storage keeps them, read from bytes: each page
//! holds one record at its start or is erased (0xFF); of the valid records the one with the later
//! sequence number (wrapping) is the newest. The firmware's `storage` driver and a user's own
//! firmware (which finds the pages at 0xF8000 after uploading over ours) decide alike.

use crate::formats::record::{DecodeError, NotFinite, Record, LEN};

/// Record pages.
pub const SLOTS: usize = 2;
/// One record page (bytes): the nRF52840's flash erase page.
pub const PAGE: usize = 4096;
/// Where the two pages are in the Nano 33 BLE's flash (`memory.x`'s `STORAGE`).
pub const ADDRESS: u32 = 0xF_8000;

/// What a page holds.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[allow(clippy::large_enum_variant)] // a value read once per load or store; no heap to box it in
pub enum Slot {
    /// Erased flash.
    Empty,
    /// A valid record.
    Valid(Record),
    /// Not a valid record (torn write, corruption, unknown version, overwritten by other data).
    Invalid(DecodeError),
}

impl Slot {
    /// Classifies the first [`LEN`] bytes of a page.
    pub fn of(bytes: &[u8]) -> Slot {
        let head = &bytes[..bytes.len().min(LEN)];
        if head.len() == LEN && head.iter().all(|&b| b == 0xFF) {
            return Slot::Empty;
        }
        match Record::decode(head) {
            Ok(r) => Slot::Valid(r),
            Err(e) => Slot::Invalid(e),
        }
    }
}

/// `true` when `a` is a later sequence number than `b` (wrapping).
pub fn newer(a: u32, b: u32) -> bool {
    (a.wrapping_sub(b) as i32) > 0
}

/// The newest valid record of `slots` and its index.
pub fn newest(slots: &[Slot; SLOTS]) -> Option<(usize, Record)> {
    let mut best: Option<(usize, Record)> = None;
    for (i, s) in slots.iter().enumerate() {
        if let Slot::Valid(r) = *s {
            if best.is_none_or(|(_, b)| newer(r.seq, b.seq)) {
                best = Some((i, r));
            }
        }
    }
    best
}

/// The newest valid record in `region` (the two pages of `page` bytes each, as in flash) and its
/// page; `None` when neither holds one or `region` is shorter than two pages.
pub fn load(region: &[u8], page: usize) -> Option<(usize, Record)> {
    if page < LEN || region.len() < SLOTS * page {
        return None;
    }
    newest(&[Slot::of(&region[..page]), Slot::of(&region[page..2 * page])])
}

/// The two pages as the firmware's first store into erased flash leaves them: `rec` at the start
/// of page A, every other byte erased (0xFF). A record with a NaN or an infinite field is refused.
pub fn image(rec: &Record) -> Result<[u8; SLOTS * PAGE], NotFinite> {
    let mut region = [0xFF; SLOTS * PAGE];
    region[..LEN].copy_from_slice(&rec.encode()?);
    Ok(region)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::record::tests::sample;

    #[test]
    fn the_newest_valid_page_wins_across_the_sequence_wrap_and_garbage_is_never_loaded() {
        let page = |r: Option<Record>| {
            let mut p = [0xFFu8; PAGE];
            if let Some(r) = r {
                p[..LEN].copy_from_slice(&r.encode().unwrap());
            }
            p
        };
        let region = |a: [u8; PAGE], b: [u8; PAGE]| [a, b].concat();
        let (old, new) = (Record { seq: u32::MAX, ..sample() }, Record { seq: 0, ..sample() });
        assert_eq!(load(&region(page(Some(old)), page(Some(new))), PAGE), Some((1, new)));
        assert_eq!(load(&region(page(Some(new)), page(Some(old))), PAGE), Some((0, new)));
        assert_eq!(load(&region(page(None), page(None)), PAGE), None);
        // A sketch's own data over page B (one byte of the record changed): A is loaded.
        let mut b = page(Some(new));
        b[40] ^= 1;
        assert_eq!(load(&region(page(Some(old)), b), PAGE), Some((0, old)));
        assert!(matches!(Slot::of(&b), Slot::Invalid(DecodeError::BadCrc { .. })));
        // Too short a region: nothing, not a panic.
        assert_eq!(load(&region(page(Some(new)), page(None))[..PAGE + 10], PAGE), None);
        assert_eq!(Slot::of(&[0xFF; 10]), Slot::Invalid(DecodeError::BadMagic));
        // The image of one store: the record in page A, page B erased.
        let img = image(&new).unwrap();
        assert_eq!(load(&img, PAGE), Some((0, new)));
        assert_eq!(Slot::of(&img[PAGE..]), Slot::Empty);
        assert!(image(&Record { condition: f32::NAN, ..new }).is_err());
    }
}
