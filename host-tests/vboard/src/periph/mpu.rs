//! The Cortex-M4 MPU (ARMv7-M PMSAv7, ARM DDI 0403 §B3.5): MPU_TYPE (8 regions), MPU_CTRL,
//! MPU_RNR, MPU_RBAR, MPU_RASR and their aliases, at 0xE000ED90–0xE000EDB8. Unicorn does not
//! enforce it (the SCS is ours), so the board does: instruction fetches from a region marked XN
//! and writes to a region without privileged write access are MemManage faults (the firmware
//! runs privileged; with PRIVDEFENA the default memory map applies where no region matches).
//!
//! The state the bootloader leaves (as the lead describes it; mbed OS's `mbed_mpu_init` sets up
//! the same shape): region 0 = flash 0x0, 1 MB, privileged read-only and executable; region 1 =
//! SRAM 0x2000_0000, 256 KB, read/write, execute-never; CTRL = ENABLE | PRIVDEFENA.

/// MPU register offsets in the SCS block (0xE000E000).
pub const TYPE: u32 = 0xD90;
/// MPU_CTRL.
pub const CTRL: u32 = 0xD94;
/// MPU_RNR.
pub const RNR: u32 = 0xD98;
/// MPU_RBAR.
pub const RBAR: u32 = 0xD9C;
/// MPU_RASR.
pub const RASR: u32 = 0xDA0;
/// The last alias (MPU_RASR_A3).
pub const LAST: u32 = 0xDB8;

/// MPU state.
#[derive(Debug, Clone, Default)]
pub struct Mpu {
    /// MPU_CTRL (bit 0 ENABLE, bit 1 HFNMIENA, bit 2 PRIVDEFENA).
    pub ctrl: u32,
    rnr: u32,
    rbar: [u32; 8],
    rasr: [u32; 8],
}

/// Kind of access checked against the MPU.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Check {
    /// Instruction fetch.
    Exec,
    /// Data write.
    Write,
}

impl Mpu {
    /// After a reset; `bootloader`: enabled with the bootloader's regions.
    pub fn new(bootloader: bool) -> Self {
        let mut m = Self::default();
        if bootloader {
            // RASR: XN bit 28, AP bits 26:24, SIZE bits 5:1 (2^(SIZE+1) bytes), ENABLE bit 0.
            m.rbar[0] = 0x0000_0000;
            m.rasr[0] = (0b101 << 24) | (19 << 1) | 1; // 1 MB, privileged RO, executable
            m.rbar[1] = 0x2000_0000;
            m.rasr[1] = (1 << 28) | (0b011 << 24) | (17 << 1) | 1; // 256 KB, RW, XN
            m.ctrl = 0b101;
        }
        m
    }

    /// The MPU is enabled.
    pub fn enabled(&self) -> bool {
        self.ctrl & 1 != 0
    }

    /// Checks an access at `addr`: `Err` describes the MemManage fault.
    pub fn check(&self, addr: u64, what: Check) -> Result<(), String> {
        if !self.enabled() {
            return Ok(());
        }
        let a = addr as u32;
        // The highest-numbered matching region wins.
        let region = (0..8).rev().find(|&n| {
            let rasr = self.rasr[n];
            if rasr & 1 == 0 {
                return false;
            }
            let size_log2 = ((rasr >> 1) & 0x1F) + 1;
            if size_log2 < 5 {
                return false;
            }
            let size = 1u64 << size_log2;
            let base = (self.rbar[n] as u64) & !(size - 1);
            let a64 = a as u64;
            if a64 < base || a64 >= base + size {
                return false;
            }
            // Sub-region disable (regions of 256 bytes or more).
            if size_log2 >= 8 {
                let sub = ((a64 - base) / (size / 8)) as u32;
                if (rasr >> 8) & (1 << sub) != 0 {
                    return false;
                }
            }
            true
        });
        match region {
            Some(n) => {
                let rasr = self.rasr[n];
                let ap = (rasr >> 24) & 7;
                match what {
                    Check::Exec if rasr & (1 << 28) != 0 => {
                        Err(format!("MemManage: instruction fetch at 0x{a:08X} from MPU region {n} (XN)"))
                    }
                    Check::Write if !matches!(ap, 1..=3) => {
                        Err(format!("MemManage: write to 0x{a:08X} in MPU region {n} (AP {ap:03b}: no privileged write)"))
                    }
                    _ => Ok(()),
                }
            }
            None if self.ctrl & 4 != 0 => Ok(()), // PRIVDEFENA: default map
            None => Err(format!("MemManage: access at 0x{a:08X} outside every MPU region, PRIVDEFENA = 0")),
        }
    }

    /// A read at SCS offset `o` (TYPE..=LAST).
    pub fn read(&self, o: u32) -> u32 {
        let n = (self.rnr & 7) as usize;
        match o {
            TYPE => 8 << 8, // DREGION = 8, unified
            CTRL => self.ctrl,
            RNR => self.rnr,
            o if (o - RBAR).is_multiple_of(8) => (self.rbar[n] & !0x1F) | n as u32,
            _ => self.rasr[n],
        }
    }

    /// A write at SCS offset `o`.
    pub fn write(&mut self, o: u32, v: u32) {
        match o {
            TYPE => {}
            CTRL => self.ctrl = v & 7,
            RNR => self.rnr = v & 0xFF,
            o if (o - RBAR).is_multiple_of(8) => {
                if v & (1 << 4) != 0 {
                    self.rnr = v & 0xF; // VALID: the REGION field selects the region
                }
                self.rbar[(self.rnr & 7) as usize] = v & !0x1F;
            }
            _ => self.rasr[(self.rnr & 7) as usize] = v,
        }
    }
}
