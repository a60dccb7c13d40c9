//! A simulated NOR flash (nRF52840 NVMC-like: 4 KiB pages, 32-bit word writes that can only
//! clear bits, erase to 0xFF) with a power cut injectable at any erase or word-write step.
//!
//! At the cut, the interrupted page erase leaves a mix of erased and old bytes, the interrupted
//! word write leaves a random subset of its bits programmed; the device then refuses every
//! operation until [`NorSim::reboot`].

use embedded_storage::nor_flash::{ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Page size (bytes).
pub const PAGE: usize = 4096;

/// Errors of the simulated flash.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NorError {
    /// Power was cut during this operation.
    PowerCut,
    /// Power is off (after a cut, until reboot).
    Off,
    /// Misaligned offset or length.
    Unaligned,
    /// Beyond the region.
    OutOfBounds,
}

impl NorFlashError for NorError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            NorError::Unaligned => NorFlashErrorKind::NotAligned,
            NorError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            _ => NorFlashErrorKind::Other,
        }
    }
}

/// The simulated flash region.
#[derive(Clone)]
pub struct NorSim {
    mem: Vec<u8>,
    steps: usize,
    cut_at: Option<usize>,
    off: bool,
    rng: ChaCha8Rng,
    /// Fault injection: a worn cell: this byte offset keeps bit 0 set whatever is written
    /// (the write "succeeds", the read-back differs).
    pub stuck_bit: Option<usize>,
}

impl NorSim {
    /// An erased region of `pages` pages.
    pub fn new(pages: usize, seed: u64) -> Self {
        Self { mem: vec![0xFF; pages * PAGE], steps: 0, cut_at: None, off: false, rng: ChaCha8Rng::seed_from_u64(seed), stuck_bit: None }
    }

    /// Cuts the power at step `n` from now (0 = the next erase or word write).
    pub fn cut_after(&mut self, n: usize) {
        self.cut_at = Some(self.steps + n);
    }

    /// Erase and word-write steps performed so far.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// Power back on (the contents stay as the cut left them).
    pub fn reboot(&mut self) {
        self.off = false;
        self.cut_at = None;
    }

    /// The raw contents.
    pub fn bytes(&self) -> &[u8] {
        &self.mem
    }

    /// Counts a step; true when the power is cut at it.
    fn step(&mut self) -> Result<bool, NorError> {
        if self.off {
            return Err(NorError::Off);
        }
        let cut = self.cut_at == Some(self.steps);
        self.steps += 1;
        if cut {
            self.off = true;
        }
        Ok(cut)
    }
}

impl ErrorType for NorSim {
    type Error = NorError;
}

impl ReadNorFlash for NorSim {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), NorError> {
        if self.off {
            return Err(NorError::Off);
        }
        let o = offset as usize;
        let src = self.mem.get(o..o + bytes.len()).ok_or(NorError::OutOfBounds)?;
        bytes.copy_from_slice(src);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.mem.len()
    }
}

impl NorFlash for NorSim {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = PAGE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), NorError> {
        let (from, to) = (from as usize, to as usize);
        if !from.is_multiple_of(PAGE) || !to.is_multiple_of(PAGE) || from > to {
            return Err(NorError::Unaligned);
        }
        if to > self.mem.len() {
            return Err(NorError::OutOfBounds);
        }
        for page in (from..to).step_by(PAGE) {
            if self.step()? {
                for b in &mut self.mem[page..page + PAGE] {
                    if self.rng.random_bool(0.5) {
                        *b = 0xFF;
                    }
                }
                return Err(NorError::PowerCut);
            }
            self.mem[page..page + PAGE].fill(0xFF);
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), NorError> {
        let o = offset as usize;
        if !o.is_multiple_of(4) || !bytes.len().is_multiple_of(4) {
            return Err(NorError::Unaligned);
        }
        if o + bytes.len() > self.mem.len() {
            return Err(NorError::OutOfBounds);
        }
        for (i, word) in bytes.chunks(4).enumerate() {
            let at = o + 4 * i;
            if self.step()? {
                for (k, &b) in word.iter().enumerate() {
                    let partial: u8 = self.rng.random();
                    self.mem[at + k] &= b | partial;
                }
                return Err(NorError::PowerCut);
            }
            for (k, &b) in word.iter().enumerate() {
                self.mem[at + k] &= b;
                if self.stuck_bit == Some(at + k) {
                    self.mem[at + k] |= 1;
                }
            }
        }
        Ok(())
    }
}
