//! NVMC (nRF52840 PS v1.7 §4.3): CONFIG (REN/WEN/EEN), ERASEPAGE, READY/READYNEXT, ICACHECNF,
//! IHIT/IMISS; page erases (85 ms, the CPU stalls) and word writes (41 µs) on the storage
//! region's NOR flash model with injectable power cuts. Erasing or writing anything outside the
//! storage region (the bootloader, the application) stops the run.

use super::{off, Access, STORAGE};

/// ERASEPAGE (a union with the deprecated ERASEPCR1 in the PAC, hence no field to take it from).
const ERASEPAGE: u32 = 0x508;
/// Page erase time (PS: tERASEPAGE, 85 ms max).
pub const ERASE_S: f64 = 0.085;
/// Word write time (PS: tWRITE, 41 µs max).
pub const WRITE_S: f64 = 41e-6;

/// NVMC state.
#[derive(Debug, Clone, Default)]
pub struct Nvmc {
    /// CONFIG.WEN: 0 read-only, 1 write, 2 erase.
    pub config: u32,
    /// ICACHECNF (bit 0 CACHEEN, bit 8 CACHEPROFEN).
    pub icachecnf: u32,
    erasepagepartialcfg: u32,
}

/// What an NVMC register write asks of the flash.
pub enum FlashOp {
    /// Nothing.
    None,
    /// Erase the page at this flash address.
    ErasePage(u64),
}

impl Nvmc {
    /// After a reset.
    pub fn new(bootloader: bool) -> Self {
        Self { config: 0, icachecnf: u32::from(bootloader), erasepagepartialcfg: 0x0A }
    }

    /// A register access at offset `o`.
    pub fn access(&mut self, o: u32, a: Access) -> Result<(u32, FlashOp), String> {
        Ok(match o {
            o if o == off!(nvmc, ready) || o == off!(nvmc, readynext) => (1, FlashOp::None),
            o if o == off!(nvmc, config) => (a.rw(&mut self.config), FlashOp::None),
            ERASEPAGE => match a {
                Access::Write(page) => {
                    let page = page as u64;
                    if self.config != 2 {
                        return Err(format!("NVMC ERASEPAGE 0x{page:X} without CONFIG = EEN"));
                    }
                    if !(STORAGE.0..STORAGE.1).contains(&page) || !page.is_multiple_of(4096) {
                        return Err(format!("NVMC ERASEPAGE 0x{page:X} outside the storage region"));
                    }
                    (0, FlashOp::ErasePage(page))
                }
                Access::Read => (0, FlashOp::None),
            },
            o if o == off!(nvmc, eraseall)
                || o == off!(nvmc, eraseuicr)
                || o == off!(nvmc, erasepcr0)
                || o == off!(nvmc, erasepagepartial) =>
            {
                if a.is_write() {
                    return Err(format!("NVMC erase register 0x{o:03X} written (would erase beyond the storage region)"));
                }
                (0, FlashOp::None)
            }
            o if o == off!(nvmc, erasepagepartialcfg) => (a.rw(&mut self.erasepagepartialcfg), FlashOp::None),
            o if o == off!(nvmc, icachecnf) => (a.rw(&mut self.icachecnf), FlashOp::None),
            o if o == off!(nvmc, ihit) || o == off!(nvmc, imiss) => (0, FlashOp::None),
            _ => return Err(format!("NVMC register 0x{o:03X}")),
        })
    }
}
