//! The System Control Space registers the firmware uses (ARMv7-M, ARM DDI 0403): NVIC
//! ISER/ICER/ISPR/ICPR/IPR, SysTick (stopped), CPUID, ICSR, VTOR, AIRCR (SYSRESETREQ), SCR, CCR,
//! SHPR, SHCSR, fault status, CPACR, the MPU, DEMCR and the FPU's FPCCR/FPCAR. Unicorn has no
//! NVIC: pending interrupts are delivered by the board (`Mcu`). One priority level is modelled.

use super::mpu::{self, Mpu};
use super::Access;

/// SCS state.
#[derive(Debug, Clone, Default)]
pub struct Scs {
    /// Interrupts enabled (bit n = IRQ n).
    pub nvic_enabled: u64,
    /// Interrupts pending.
    pub nvic_pending: u64,
    /// SCB VTOR.
    pub vtor: u32,
    /// AIRCR SYSRESETREQ written.
    pub reset_request: bool,
    /// The MPU.
    pub mpu: Mpu,
    /// `wfi`s executed with FPSCR exception flags set (erratum 87: on the part the pending FPU
    /// interrupt keeps the CPU from sleeping; the model only counts them).
    pub wfi_with_fpu_flags: u32,
    scr: u32,
    ccr: u32,
    shpr: [u32; 3],
    shcsr: u32,
    cpacr: u32,
    demcr: u32,
    fpccr: u32,
    fpcar: u32,
    fpdscr: u32,
    systick: [u32; 3],
    ipr: [u32; 16],
}

impl Scs {
    /// After a reset; `bootloader`: VTOR at the application, the MPU as the bootloader left it.
    pub fn new(bootloader: bool) -> Self {
        Self {
            vtor: if bootloader { 0x1_0000 } else { 0 },
            mpu: Mpu::new(bootloader),
            ccr: 0x200,         // STKALIGN
            fpccr: 0xC000_0000, // ASPEN, LSPEN
            cpacr: if bootloader { 0x00F0_0000 } else { 0 },
            ..Self::default()
        }
    }

    /// An access at offset `o` of 0xE000E000.
    pub fn access(&mut self, o: u32, a: Access) -> Result<u32, String> {
        let word = |v: u64, o: u32, base: u32| (v >> (32 * ((o - base) / 4))) as u32;
        let sh = |o: u32, base: u32| 32 * ((o - base) / 4);
        Ok(match (o, a) {
            (0x004, Access::Read) => 1, // ICTR: 64 interrupt lines
            (0x010..=0x018, a) => a.rw(&mut self.systick[((o - 0x010) / 4) as usize]),
            (0x01C, _) => 0, // SYST_CALIB
            (0x100 | 0x104, Access::Write(v)) => {
                self.nvic_enabled |= (v as u64) << sh(o, 0x100);
                word(self.nvic_enabled, o, 0x100)
            }
            (0x100 | 0x104, Access::Read) => word(self.nvic_enabled, o, 0x100),
            (0x180 | 0x184, Access::Write(v)) => {
                self.nvic_enabled &= !((v as u64) << sh(o, 0x180));
                word(self.nvic_enabled, o, 0x180)
            }
            (0x180 | 0x184, Access::Read) => word(self.nvic_enabled, o, 0x180),
            (0x200 | 0x204, Access::Write(v)) => {
                self.nvic_pending |= (v as u64) << sh(o, 0x200);
                word(self.nvic_pending, o, 0x200)
            }
            (0x200 | 0x204, Access::Read) => word(self.nvic_pending, o, 0x200),
            (0x280 | 0x284, Access::Write(v)) => {
                self.nvic_pending &= !((v as u64) << sh(o, 0x280));
                word(self.nvic_pending, o, 0x280)
            }
            (0x280 | 0x284, Access::Read) => word(self.nvic_pending, o, 0x280),
            (0x400..=0x43F, a) => {
                a.rw(&mut self.ipr[((o - 0x400) / 4) as usize]) // byte writes arrive as words here
            }
            (0xD00, Access::Read) => 0x410F_C241, // CPUID: Cortex-M4 r0p1
            (0xD04, _) => 0,                      // ICSR
            (0xD08, a) => a.rw(&mut self.vtor),
            (0xD0C, Access::Write(v)) => {
                if v >> 16 == 0x05FA && v & (1 << 2) != 0 {
                    self.reset_request = true;
                }
                0
            }
            (0xD0C, Access::Read) => 0xFA05_0000,
            (0xD10, a) => a.rw(&mut self.scr),
            (0xD14, a) => a.rw(&mut self.ccr),
            (0xD18..=0xD20, a) => a.rw(&mut self.shpr[((o - 0xD18) / 4) as usize]),
            (0xD24, a) => a.rw(&mut self.shcsr),
            (0xD28 | 0xD2C | 0xD30 | 0xD34 | 0xD38 | 0xD3C, _) => 0, // fault status and address
            (0xD88, a) => a.rw(&mut self.cpacr),
            (mpu::TYPE..=mpu::LAST, Access::Read) => self.mpu.read(o),
            (mpu::TYPE..=mpu::LAST, Access::Write(v)) => {
                self.mpu.write(o, v);
                v
            }
            (0xDFC, a) => a.rw(&mut self.demcr),
            (0xF34, a) => a.rw(&mut self.fpccr),
            (0xF38, a) => a.rw(&mut self.fpcar),
            (0xF3C, a) => a.rw(&mut self.fpdscr),
            _ => return Err(format!("SCS register 0x{o:03X}")),
        })
    }
}
