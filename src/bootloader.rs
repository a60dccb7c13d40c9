//! Which Arduino bootloader the firmware runs under, and whether its flash map leaves the
//! record pages alone.
//!
//! - Stock (SAM-BA, 0x0..0x10000): UICR.NRFFW[0] erased; it jumps to 0x10000 with VTOR set.
//! - Updated (Nordic MBR at 0x0, bootloader at 0xE0000..0xE8C6F, SoftDevice-update magic at
//!   0xFF000): UICR.NRFFW[0] = 0xE0000; the MBR's reset vector is 0xA81.
//!
//! The record pages (0xF8000..0xFA000) are written only under a bootloader whose extent is
//! known to spare them and if no MBR parameter page or bootloader entry point lies in them. An
//! unknown bootloader that starts below their end (Adafruit's, at 0xF4000, spans them) may
//! cover them: nothing is written.

/// Start of the calibration record pages.
pub const RECORDS_START: u32 = 0xF_8000;
/// End (exclusive) of the calibration record pages: two 4 KiB pages.
pub const RECORDS_END: u32 = 0xF_A000;
/// The updated bootloader's SoftDevice-update magic page.
pub const UPDATED_MAGIC_PAGE: u32 = 0xF_F000;
/// Where the updated bootloader lives (UICR.NRFFW[0]).
pub const UPDATED_BOOTLOADER: u32 = 0xE_0000;
/// Reset vector of Nordic's MBR (the word at 0x4 under the updated bootloader).
pub const MBR_RESET_VECTOR: u32 = 0xA81;

const _: () = assert!(RECORDS_END <= UPDATED_MAGIC_PAGE && RECORDS_START >= UPDATED_BOOTLOADER + 0x9000);

/// What the flash says at boot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FlashMap {
    /// UICR.NRFFW[0] (0x10001014): the bootloader's start, 0xFFFF_FFFF if none.
    pub nrffw0: u32,
    /// UICR.NRFFW[1] (0x10001018): the MBR parameter page, 0xFFFF_FFFF if none.
    pub nrffw1: u32,
    /// The word at 0x4: the reset vector of whatever is at 0x0.
    pub reset_vector_0: u32,
    /// The reset vector of the bootloader at NRFFW[0] (its word at +4), if NRFFW[0] is set.
    pub bootloader_entry: Option<u32>,
}

/// The bootloader found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Bootloader {
    /// The stock Arduino SAM-BA bootloader in 0x0..0x10000.
    Stock,
    /// Nordic's MBR with the updated Arduino bootloader at 0xE0000.
    Updated,
    /// Something else: a bootloader start in UICR.NRFFW[0] (address).
    Other(u32),
}

/// Why the record pages must not be written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Conflict {
    /// This address, used by the bootloader or MBR, lies in the record pages.
    InRecordPages(u32),
    /// An unknown bootloader starts here, below the record pages' end: it may cover them.
    UnknownBootloader(u32),
}

fn in_records(a: u32) -> bool {
    (RECORDS_START..RECORDS_END).contains(&a)
}

impl FlashMap {
    /// The bootloader this map shows.
    pub fn bootloader(&self) -> Bootloader {
        match self.nrffw0 {
            0xFFFF_FFFF => Bootloader::Stock,
            UPDATED_BOOTLOADER if self.reset_vector_0 == MBR_RESET_VECTOR => Bootloader::Updated,
            a => Bootloader::Other(a),
        }
    }

    /// `Ok` if writing the record pages cannot touch a bootloader, its MBR parameters or its
    /// entry point.
    pub fn records_safe(&self) -> Result<(), Conflict> {
        if let Bootloader::Other(a) = self.bootloader() {
            if a < RECORDS_END {
                return Err(Conflict::UnknownBootloader(a));
            }
        }
        let set = |a: u32| a != 0xFFFF_FFFF;
        for a in [Some(self.nrffw0), Some(self.nrffw1), self.bootloader_entry.map(|e| e & !1)].into_iter().flatten() {
            if set(a) && in_records(a) {
                return Err(Conflict::InRecordPages(a));
            }
        }
        Ok(())
    }
}
