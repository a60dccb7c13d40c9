//! Power-fail-safe storage of the calibration record: two slots (A/B), one flash page each.
//!
//! A new record always goes to the slot that does *not* hold the newest valid record: that slot
//! is erased, written and read back. A power cut at any instant of the erase or the write leaves
//! the other slot, with the previous record, untouched; at boot the valid record with the
//! highest sequence number wins, and a torn or corrupt slot is never applied (CRC-32, version,
//! magic and field checks of `calib_core::formats::record`).

pub use calib_core::formats::record::StoreError;
use calib_core::formats::record::{DecodeError, Record, LEN};
pub use calib_core::formats::region::{Slot, SLOTS};
use embedded_storage::nor_flash::NorFlash;

/// The two record slots in a flash region (offsets relative to the driver's region).
pub struct Storage<F> {
    flash: F,
}

impl<F: NorFlash> Storage<F> {
    /// Uses the first two erase pages of `flash`.
    pub fn new(flash: F) -> Result<Self, StoreError> {
        if flash.capacity() < SLOTS * F::ERASE_SIZE || F::ERASE_SIZE < LEN {
            return Err(StoreError::RegionTooSmall);
        }
        Ok(Self { flash })
    }

    /// The driver back.
    pub fn release(self) -> F {
        self.flash
    }

    fn offset(slot: usize) -> u32 {
        (slot * F::ERASE_SIZE) as u32
    }

    /// Reads and classifies one slot.
    pub fn slot(&mut self, slot: usize) -> Result<Slot, StoreError> {
        let mut buf = [0u8; LEN];
        self.flash.read(Self::offset(slot), &mut buf).map_err(|_| StoreError::Flash)?;
        Ok(Slot::of(&buf))
    }

    /// Both slots.
    pub fn slots(&mut self) -> Result<[Slot; SLOTS], StoreError> {
        Ok([self.slot(0)?, self.slot(1)?])
    }

    /// The newest valid record and its slot, if any ([`calib_core::formats::region::newest`]).
    pub fn load(&mut self) -> Result<Option<(usize, Record)>, StoreError> {
        Ok(calib_core::formats::region::newest(&self.slots()?))
    }

    /// The version of a record in a slot that this build does not read (one made before the
    /// board frame, without calib-core's `older-records`), if any.
    pub fn unsupported_version(&mut self) -> Option<u8> {
        self.slots().ok()?.into_iter().find_map(|s| match s {
            Slot::Invalid(DecodeError::UnsupportedVersion(v)) => Some(v),
            _ => None,
        })
    }

    /// Stores `rec` in the slot not holding the newest valid record; returns that slot.
    pub fn store(&mut self, rec: &Record) -> Result<usize, StoreError> {
        let target = match self.load()? {
            Some((slot, _)) => 1 - slot,
            None => 0,
        };
        // Refused before anything is erased.
        let bytes = rec.encode().map_err(|_| StoreError::NotFinite)?;
        let at = Self::offset(target);
        self.flash.erase(at, at + F::ERASE_SIZE as u32).map_err(|_| StoreError::Flash)?;
        self.flash.write(at, &bytes).map_err(|_| StoreError::Flash)?;
        // Read back: the very bytes written (a valid record, since `encode` made them).
        let mut back = [0u8; LEN];
        self.flash.read(at, &mut back).map_err(|_| StoreError::Flash)?;
        if back != bytes {
            return Err(StoreError::Verify);
        }
        Ok(target)
    }
}
