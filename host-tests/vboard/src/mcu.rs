//! The emulated nRF52840: Unicorn's Cortex-M4 with the peripheral models, exception entry and
//! return done by the host (Unicorn has no NVIC), virtual time from the instruction count at
//! 64 MHz, `wfi` skipping to the next event, and the defmt log read from the RTT buffer.

use crate::elf::Firmware;
use crate::periph::bootloader::{self, Decision, Stage, StockBootloader};
use crate::periph::{mpu, Dma, Periph, ResetKind, Wake, CPU_HZ, STORAGE};
use std::cell::{Cell, RefCell};
use std::collections::HashSet;
use std::rc::Rc;
use unicorn_engine::{Arch, MemType, Mode, Prot, RegisterARM, Unicorn};

const FLASH_END: u64 = STORAGE.0;
const RAM: (u64, u64) = (0x2000_0000, 0x2004_0000);
/// The application's start (its vector table), after the Arduino bootloader.
const APP: u64 = 0x1_0000;
/// Instructions per emulation slice (1 ms at 64 MHz).
const SLICE: u64 = 64_000;
/// Unicorn interrupt number of a v7-M exception return.
const EXCP_EXCEPTION_EXIT: u32 = 8;
/// Unicorn interrupt number of a prefetch abort.
const EXCP_PREFETCH_ABORT: u32 = 3;

/// FPSCR's cumulative exception flags: set at a `wfi`, they pend the FPU interrupt, which keeps
/// the CPU awake (erratum 87; counted in `Scs::wfi_with_fpu_flags`).
const FPSCR_EXCEPTIONS: u64 = 0x9F;
/// xPSR's IT/ICI bits (EPSR[26:25] and [15:10]).
const XPSR_IT: u32 = 0x0600_FC00;

/// Why a run stopped.
#[derive(Debug, Clone, PartialEq)]
pub enum Stop {
    /// The requested time was reached.
    Time,
    /// The firmware faulted (undefined instruction, e.g. a panic) or touched an unmodelled address.
    Fault(String),
    /// The injected power cut happened.
    PowerCut,
}

#[derive(Clone)]
struct Exception {
    fp: Vec<u64>,
    irq: u32,
}

/// SEGGER RTT up-buffer flags: mode bits 1:0; 2 = BLOCK_IF_FULL (the target waits for room).
const RTT_MODE_MASK: u32 = 0b11;
/// SEGGER RTT BLOCK_IF_FULL.
const RTT_BLOCK_IF_FULL: u32 = 2;

/// The debug host on the other end of RTT.
///
/// By default an ideal reader drains up-channel 0 after every slice and never touches its
/// flags. [`Mcu::rtt_attach`] models `probe-rs run`: on attach it sets the channel's mode to
/// BLOCK_IF_FULL (SEGGER RTT flags bits 1:0 = 2; defmt-rtt then waits for room instead of
/// overwriting) and reads; [`Mcu::rtt_detach`] stops reading (the probe is unplugged or
/// `probe-rs` is killed) and leaves the flags as they are, as a real host does.
#[derive(Debug, Clone, Default)]
pub struct RttHost {
    /// The host reads the buffer.
    pub reading: bool,
    /// An attach is waiting for the control block to be initialised to write the mode.
    mode_pending: bool,
    /// Bytes the firmware wrote to the up buffer (from its write-offset updates).
    pub written: u64,
    /// Bytes the host read.
    pub read: u64,
}

/// A saved state of the whole board (CPU, RAM, peripherals, sensor, rig, flash).
pub struct Snapshot {
    context: unicorn_engine::Context,
    ram: Vec<u8>,
    periph: Periph,
    instructions: u64,
    exception: Option<Exception>,
}

/// The longest `Procedure::handle_sample` call that [`Mcu::profile`] files as a sample's
/// (instructions); longer ones are fits and the solve.
pub const SHORT_CALL: u64 = 200_000;

/// Which calls into the procedure a profile ([`Mcu::profile`]) is of.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Calls {
    /// `Procedure::handle_sample` calls of up to [`SHORT_CALL`] instructions: the samples.
    Samples = 0,
    /// The longer `handle_sample` calls: the pose ends and the fits made in them.
    LongSamples = 1,
    /// `Procedure::handle_tick` calls: the fits and the solve's steps.
    Ticks = 2,
}

/// The board.
pub struct Mcu {
    uc: Unicorn<'static, ()>,
    /// The peripherals, shared with the MMIO callbacks.
    pub periph: Rc<RefCell<Periph>>,
    instructions: Rc<Cell<u64>>,
    wfi_hit: Rc<Cell<bool>>,
    fault: Rc<RefCell<Option<String>>>,
    firmware: Firmware,
    table: Option<&'static defmt_decoder::Table>,
    decoder: Option<Box<dyn defmt_decoder::StreamDecoder>>,
    /// Decoded defmt log lines, in order.
    pub log: Vec<String>,
    exception: Option<Exception>,
    wfi_addrs: HashSet<u64>,
    /// The instruction count at which the running slice ends.
    stop_at: Rc<Cell<u64>>,
    /// The CPU has fetched from SRAM: it is mapped executable from then on.
    sram_exec: Rc<Cell<bool>>,
    /// Resets so far (watchdog, software).
    pub resets: u32,
    /// Watchdog resets so far.
    pub watchdog_resets: u32,
    /// The RTT host.
    pub rtt: RttHost,
    rtt_write_seen: Rc<Cell<(u64, u64)>>,
    /// Instructions spent in `Procedure::handle_sample` and its calls, and calls counted.
    pub handle_sample: Rc<Cell<(u64, u64)>>,
    /// Instructions of the longest single `Procedure::handle_sample` call.
    pub handle_sample_max: Rc<Cell<u64>>,
    /// Instructions of the longest single `Procedure::handle_tick` call (a fit or a step of the solve).
    pub handle_tick_max: Rc<Cell<u64>>,
    /// Instructions spent inside `Procedure::handle_sample` and `handle_tick` (callees
    /// included) per function's start, while `profiling` is set: their flat profiles
    /// ([`Mcu::profile`]), indexed by [`Calls`].
    pub blocks: Rc<RefCell<[std::collections::HashMap<u64, u64>; 3]>>,
    /// Whether `blocks` is kept (off by default: it costs emulation time).
    pub profiling: Rc<Cell<bool>>,
}

struct UcDma<'a, 'b>(&'a mut Unicorn<'b, ()>);

impl Dma for UcDma<'_, '_> {
    fn read(&mut self, addr: u64, buf: &mut [u8]) {
        let _ = self.0.mem_read(addr, buf);
    }
    fn write(&mut self, addr: u64, data: &[u8]) {
        let _ = self.0.mem_write(addr, data);
    }
}

fn err<E: std::fmt::Debug>(what: &str) -> impl Fn(E) -> String + '_ {
    move |e| format!("{what}: {e:?}")
}

impl Mcu {
    /// Powers the board on with `firmware`.
    pub fn new(firmware: Firmware, periph: Periph) -> Result<Self, String> {
        let instructions = periph.instructions.clone();
        let mut uc = Unicorn::new_with_data(Arch::ARM, Mode::THUMB | Mode::MCLASS, ()).map_err(err("unicorn"))?;
        uc.ctl_set_cpu_model(unicorn_engine::ArmCpuModel::CORTEX_M4 as i32).map_err(err("cpu model"))?;
        // Flash is read/execute for the CPU: it is written only through the NVMC (storage).
        uc.mem_map(0, FLASH_END, Prot::READ | Prot::EXEC).map_err(err("map flash"))?;
        // SRAM is not executable until the CPU first fetches from it (`sram_exec`), in its
        // mapping and in the TLB (identity-mapped by our fill hook): Unicorn sends every store to
        // an executable page through its self-modifying-code check, the slow path.
        uc.mem_map(RAM.0, RAM.1 - RAM.0, Prot::READ | Prot::WRITE).map_err(err("map RAM"))?;
        uc.ctl_set_tlb_type(unicorn_engine::TlbType::VIRTUAL).map_err(err("TLB type"))?;
        let sram_exec = Rc::new(Cell::new(false));
        let exec = sram_exec.clone();
        uc.add_tlb_hook(1, 0, move |uc, addr, access| {
            // Unicorn restores the CPU state of the access's instruction before this hook
            // (unicorn_vtlb.c), EPSR.IT included, and nothing clears it again: a load or store
            // inside an IT block would leave its IT state to the next translation block looked
            // up, which then runs under a stale condition (seen: memcpy's epilogue skipping
            // `add sp` and popping garbage into PC). Between blocks the IT state is only ever
            // held in the translated code, so clearing it after a data access's fill (Thumb
            // kept) is exact. An instruction fetch's fill restores nothing: it comes when the
            // next block is looked up or translated, and if that block starts inside an IT block
            // (one that crosses into a page not fetched before) the IT state held then is the
            // block's own: it must stay (seen: a `-` in the USB serial number from core::fmt).
            if access != MemType::FETCH {
                let _ = uc.reg_write(RegisterARM::EPSR, 1 << 24);
            }
            let ram = (RAM.0..RAM.1).contains(&addr);
            let perms = if ram && !exec.get() { Prot::READ | Prot::WRITE } else { Prot::ALL };
            Some(unicorn_engine::TlbEntry { paddr: addr, perms })
        })
        .map_err(err("TLB hook"))?;
        let periph = Rc::new(RefCell::new(periph));
        let fault = Rc::new(RefCell::new(None));
        // Storage flash and peripherals: MMIO into the models.
        let p = periph.clone();
        let p2 = periph.clone();
        uc.mmio_map(
            STORAGE.0,
            STORAGE.1 - STORAGE.0,
            Some(move |_: &mut Unicorn<()>, off: u64, size: usize| p.borrow_mut().flash_read(STORAGE.0 + off, size)),
            Some(move |_: &mut Unicorn<()>, off: u64, size: usize, v: u64| p2.borrow_mut().flash_write(STORAGE.0 + off, size, v)),
        )
        .map_err(err("map storage"))?;
        for (base, size) in [(0x4000_0000u64, 0x8_0000u64), (0x5000_0000, 0x1000), (0x1000_0000, 0x2000), (0xE000_E000, 0x1000)] {
            let (pr, pw) = (periph.clone(), periph.clone());
            uc.mmio_map(
                base,
                size,
                Some(move |_: &mut Unicorn<()>, off: u64, _size: usize| pr.borrow_mut().read(base + off)),
                Some(move |uc: &mut Unicorn<()>, off: u64, _size: usize, v: u64| {
                    let mut dma = UcDma(uc);
                    pw.borrow_mut().write(base + off, v, &mut dma);
                    let p = pw.borrow();
                    if p.power.system_off && !p.debug_interface {
                        let _ = uc.emu_stop();
                    }
                }),
            )
            .map_err(err("map peripherals"))?;
        }
        for (addr, data) in &firmware.segments {
            if *addr < FLASH_END {
                uc.mem_write(*addr, data).map_err(err("load"))?;
            }
        }
        // The clock counts instructions per translated block, at the block's entry (a block hook,
        // not a hook on every instruction); the block that reaches the slice's budget ends it.
        let code = Thumb::new(&firmware);
        let (count, stop_at) = (instructions.clone(), Rc::new(Cell::new(u64::MAX)));
        let (budget, block_pc) = (stop_at.clone(), periph.borrow().pc.clone());
        // Instructions inside `Procedure::handle_sample` (callees included): from its entry block
        // to the block at the return address found in LR at the entry.
        let handle_sample = Rc::new(Cell::new((0u64, 0u64)));
        let handle_sample_max = Rc::new(Cell::new(0u64));
        let (hs, hs_max, entry) = (handle_sample.clone(), handle_sample_max.clone(), firmware.handle_sample.map(|r| r.0));
        let handle_tick_max = Rc::new(Cell::new(0u64));
        let (ht_max, tick_entry) = (handle_tick_max.clone(), firmware.handle_tick.map(|r| r.0));
        // The open `handle_tick` call: its first instruction count and return address.
        let tick_open: Cell<Option<(u64, u64)>> = Cell::new(None);
        let blocks = Rc::new(RefCell::new([(); 3].map(|_| std::collections::HashMap::new())));
        let (profile, profiling) = (blocks.clone(), Rc::new(Cell::new(false)));
        let profile_on = profiling.clone();
        // The open call's instructions per function (by its start), filed as short or long when
        // it returns; a builtin's (software floating point, memcpy: leaves) go to the function
        // that ran before it, its caller.
        let mut call: std::collections::HashMap<u64, u64> = std::collections::HashMap::new();
        let fns: Vec<(u64, u64, bool)> = firmware
            .functions
            .iter()
            .map(|(a, b, name)| (*a, *b, name.starts_with("compiler_builtins") || name.starts_with("__aeabi")))
            .collect();
        let mut caller = 0u64;
        let open: Cell<Option<(u64, u64)>> = Cell::new(None);
        uc.add_block_hook(0x1_0000, FLASH_END - 1, move |uc, addr, size| {
            let n0 = count.get();
            let n = n0 + code.instructions(addr, size);
            count.set(n);
            block_pc.set(addr);
            if Some(addr) == entry {
                let lr = uc.reg_read(RegisterARM::LR).unwrap_or(0) & !1;
                open.set(Some((n0, lr)));
            } else if Some(addr) == tick_entry {
                let lr = uc.reg_read(RegisterARM::LR).unwrap_or(0) & !1;
                tick_open.set(Some((n0, lr)));
            } else if let Some((t0, _)) = tick_open.get().filter(|t| t.1 == addr) {
                ht_max.set(ht_max.get().max(n0 - t0));
                tick_open.set(None);
                for (a, k) in call.drain() {
                    *profile.borrow_mut()[Calls::Ticks as usize].entry(a).or_insert(0) += k;
                }
            }
            // The two never nest: the main loop calls each.
            let inside = open.get().or(tick_open.get());
            if profile_on.get() && inside.is_some_and(|o| o.1 != addr) {
                let f = fns.partition_point(|f| f.0 <= addr).checked_sub(1).map(|i| fns[i]).filter(|f| addr < f.1);
                let key = match f {
                    Some((_, _, true)) => caller,
                    Some((start, _, false)) => {
                        caller = start;
                        start
                    }
                    None => addr,
                };
                *call.entry(key).or_insert(0) += n - n0;
            }
            if let Some((e0, _)) = open.get().filter(|o| o.1 == addr) {
                let long = if n0 - e0 > SHORT_CALL { Calls::LongSamples } else { Calls::Samples };
                for (a, k) in call.drain() {
                    *profile.borrow_mut()[long as usize].entry(a).or_insert(0) += k;
                }
                let (i, calls) = hs.get();
                hs.set((i + n0 - e0, calls + 1));
                hs_max.set(hs_max.get().max(n0 - e0));
                open.set(None);
            }
            if n >= budget.get() {
                let _ = uc.emu_stop();
            }
        })
        .map_err(err("block hook"))?;
        // Code below the application (the bootloader's pages, not emulated) or past it: a jump
        // there (a corrupt function pointer or return address) is a fault, not a silent spin.
        let f = fault.clone();
        uc.add_block_hook(0, 0xFFFF, move |uc, addr, _| {
            let lr = uc.reg_read(RegisterARM::LR).unwrap_or(0);
            *f.borrow_mut() = Some(format!("execution at 0x{addr:08X}, outside the application (LR 0x{lr:08X})"));
            let _ = uc.emu_stop();
        })
        .map_err(err("low code hook"))?;
        // A `wfi` ends the slice before it executes: one code hook on each (Unicorn instruments
        // only the instructions inside a hook's range).
        let wfi_hit = Rc::new(Cell::new(false));
        let wfi_addrs = wfi_addresses(&firmware);
        for &a in &wfi_addrs {
            let hit = wfi_hit.clone();
            uc.add_code_hook(a, a, move |uc, _, _| {
                hit.set(true);
                let _ = uc.emu_stop();
            })
            .map_err(err("wfi hook"))?;
        }
        // The MPU (ours, not Unicorn's): an instruction fetch from SRAM it marks XN faults.
        let (mp, mf) = (periph.clone(), fault.clone());
        uc.add_code_hook(RAM.0, RAM.1, move |uc, addr, _size| {
            let denied = mp.try_borrow().ok().and_then(|p| p.scs.mpu.check(addr, mpu::Check::Exec).err());
            if let Some(e) = denied {
                *mf.borrow_mut() = Some(e);
                let _ = uc.emu_stop();
            }
        })
        .map_err(err("RAM code hook"))?;
        // RTT: the bytes written are counted from the up channel's write offset after every
        // slice (`note_rtt_writes`): a memory hook, even on 4 bytes, would send every load and
        // store of the emulated CPU through Unicorn's slow path.
        let rtt_write_seen = Rc::new(Cell::new((0u64, 0u64)));
        let f = fault.clone();
        uc.add_intr_hook(move |uc, intno| {
            let pc = uc.reg_read(RegisterARM::PC).unwrap_or(0);
            // A branch to EXC_RETURN arrives as an exception exit (or a prefetch abort at
            // 0xFFFFFFFx): the run loop unstacks the frame.
            let exception_return = intno == EXCP_EXCEPTION_EXIT || (intno == EXCP_PREFETCH_ABORT && pc >= 0xFFFF_FF00);
            if !exception_return {
                *f.borrow_mut() = Some(format!("CPU exception {intno} at PC 0x{pc:08X} (1 = undefined instruction: a firmware panic)"));
            }
            let _ = uc.emu_stop();
        })
        .map_err(err("intr hook"))?;
        // `wfe`, `yield` and `sev` are hints Unicorn may not decode: executed as no-ops.
        uc.add_insn_invalid_hook(|uc| {
            let pc = uc.reg_read(RegisterARM::PC).unwrap_or(0);
            let mut op = [0u8; 2];
            let hint = uc.mem_read(pc, &mut op).is_ok() && matches!(u16::from_le_bytes(op), 0xBF10 | 0xBF20 | 0xBF40);
            if hint {
                let _ = uc.reg_write(RegisterARM::PC, pc + 2);
            }
            hint
        })
        .map_err(err("invalid-instruction hook"))?;
        // The defmt table lives as long as the process (a test bench); a fresh stream decoder
        // per power-on, so that a frame cut by a reset does not garble the next ones.
        let table: Option<&'static defmt_decoder::Table> =
            defmt_decoder::Table::parse(&firmware.bytes).ok().flatten().map(|t| &*Box::leak(Box::new(t)));
        let mut mcu = Self {
            uc,
            periph,
            instructions,
            wfi_hit,
            fault,
            firmware,
            table,
            decoder: None,
            log: vec![],
            exception: None,
            wfi_addrs,
            stop_at,
            sram_exec,
            resets: 0,
            watchdog_resets: 0,
            rtt: RttHost { reading: true, ..RttHost::default() },
            rtt_write_seen,
            handle_sample,
            handle_sample_max,
            handle_tick_max,
            blocks,
            profiling,
        };
        mcu.reset()?;
        Ok(mcu)
    }

    /// Uploads `firmware` as the Arduino bootloader does (bossac's erase and write of the image):
    /// the 4 KiB flash pages its image covers are erased and written; every other page keeps
    /// what it held (the old program's tail, and the calibration records at 0xF8000, which live in
    /// the storage flash model). Then the board powers on with it; the peripherals' models, the
    /// flash, the sensor and the rig carry over.
    pub fn upload(self, firmware: Firmware) -> Result<Mcu, String> {
        const PAGE: u64 = 4096;
        let mut flash = vec![0u8; (FLASH_END - APP) as usize];
        self.uc.mem_read(APP, &mut flash).map_err(err("flash read"))?;
        let image: Vec<&(u64, Vec<u8>)> = firmware.segments.iter().filter(|(a, _)| *a < FLASH_END).collect();
        if let Some((a, d)) = image.iter().find(|(a, d)| *a < APP || a + d.len() as u64 > FLASH_END) {
            return Err(format!("a segment at 0x{a:X} ({} bytes) lies outside the application flash 0x{APP:X}..0x{FLASH_END:X}", d.len()));
        }
        for (addr, data) in &image {
            let (first, last) = ((addr - APP) / PAGE, (addr - APP + data.len().max(1) as u64 - 1) / PAGE);
            flash[(first * PAGE) as usize..((last + 1) * PAGE).min(FLASH_END - APP) as usize].fill(0xFF);
        }
        for (addr, data) in &image {
            flash[(addr - APP) as usize..(addr - APP) as usize + data.len()].copy_from_slice(data);
        }
        let Mcu { uc, periph, .. } = self;
        drop(uc);
        let periph = Rc::try_unwrap(periph).map_err(|_| "the peripherals are still shared".to_string())?.into_inner();
        Mcu::new(Firmware { segments: vec![(APP, flash)], ..firmware }, periph)
    }

    /// Current PC (diagnostics).
    pub fn pc(&self) -> u64 {
        self.uc.reg_read(RegisterARM::PC).unwrap_or(0)
    }

    /// Virtual time (s).
    pub fn now(&self) -> f64 {
        self.periph.borrow().now()
    }

    /// Instructions executed.
    pub fn instructions(&self) -> u64 {
        self.instructions.get()
    }

    /// The firmware.
    pub fn firmware(&self) -> &Firmware {
        &self.firmware
    }

    /// Reads `len` bytes of RAM or flash at `addr`.
    pub fn mem_read(&self, addr: u64, len: usize) -> Result<Vec<u8>, String> {
        self.uc.mem_read_as_vec(addr, len).map_err(err("read"))
    }

    /// Writes `data` into RAM at `addr`.
    pub fn mem_write(&mut self, addr: u64, data: &[u8]) -> Result<(), String> {
        self.uc.mem_write(addr, data).map_err(err("write"))
    }

    /// Calls the image's function `name` (AAPCS: `args` in r0–r3) on the emulated core and
    /// returns r0: checks a leaf routine of the image itself (the run-time's `memcpy`) where it
    /// runs. At most `limit` instructions; the registers are restored after it, memory is left
    /// as the call leaves it.
    pub fn call(&mut self, name: &str, args: &[u32], limit: u64) -> Result<u32, String> {
        const REGS: [RegisterARM; 4] = [RegisterARM::R0, RegisterARM::R1, RegisterARM::R2, RegisterARM::R3];
        let start = self.firmware.functions.iter().find(|f| f.2 == name).map(|f| f.0).ok_or(format!("no function {name} in the image"))?;
        if args.len() > REGS.len() {
            return Err(format!("{} arguments: at most 4 go in registers", args.len()));
        }
        let mut saved = self.uc.context_init().map_err(err("context"))?;
        self.uc.context_save(&mut saved).map_err(err("context save"))?;
        // Returning to the vector table's first word, which is never executed, ends the call.
        let ret = APP;
        for (r, a) in REGS.iter().zip(args) {
            self.uc.reg_write(*r, u64::from(*a)).map_err(err("argument"))?;
        }
        self.uc.reg_write(RegisterARM::LR, ret | 1).map_err(err("LR"))?;
        let n0 = self.instructions.get();
        self.stop_at.set(n0 + limit);
        let run = self.uc.emu_start(start | 1, ret, 0, 0);
        let (pc, r0) = (self.pc(), self.uc.reg_read(RegisterARM::R0).unwrap_or(0));
        let fault = self.fault.borrow_mut().take();
        self.uc.context_restore(&saved).map_err(err("context restore"))?;
        run.map_err(|e| format!("{name}: emulation error {e:?} at PC 0x{pc:08X}"))?;
        if let Some(f) = fault {
            return Err(format!("{name}: {f}"));
        }
        if pc != ret {
            return Err(format!("{name} did not return within {limit} instructions (PC 0x{pc:08X})"));
        }
        Ok(r0 as u32)
    }

    /// A power-on reset (see [`Mcu::reset_with`]).
    pub fn reset(&mut self) -> Result<(), String> {
        self.reset_with(ResetKind::PowerOn)
    }

    /// A reset of `kind`: peripherals to their reset state (the watchdog survives a soft
    /// reset), then, when `periph.bootloader` is set, the stock bootloader's stand-in
    /// ([`crate::periph::bootloader`]: its wait, then SAM-BA mode or the jump), else the CPU at
    /// once from the application's vector table at 0x10000. A wake-up from System OFF loses the
    /// RAM not retained (all of it at the RAMn.POWER reset values): it reads as noise.
    pub fn reset_with(&mut self, kind: ResetKind) -> Result<(), String> {
        let bootloader = {
            let mut p = self.periph.borrow_mut();
            p.reset(kind);
            let t = p.now();
            if p.bootloader {
                p.stock.reset(t, kind == ResetKind::Pin);
            }
            p.bootloader
        };
        self.exception = None;
        self.rtt_write_seen.set((0, self.rtt_write_seen.get().1));
        self.decoder = self.table.map(|t| t.new_stream_decoder() as Box<dyn defmt_decoder::StreamDecoder>);
        if let ResetKind::OffWake(_) = kind {
            let noise: Vec<u8> = (0..RAM.1 - RAM.0).map(|i| (i.wrapping_mul(0x9E37_79B9) >> 13) as u8).collect();
            self.uc.mem_write(RAM.0, &noise).map_err(err("RAM"))?;
        }
        if bootloader {
            Ok(())
        } else {
            self.start_app()
        }
    }

    /// The CPU from the application's vector table at 0x10000 (the bootloader's jump).
    fn start_app(&mut self) -> Result<(), String> {
        let mut v = [0u8; 8];
        self.uc.mem_read(0x1_0000, &mut v).map_err(err("vector table"))?;
        let sp = u32::from_le_bytes([v[0], v[1], v[2], v[3]]) as u64;
        let pc = u32::from_le_bytes([v[4], v[5], v[6], v[7]]) as u64;
        self.uc.reg_write(RegisterARM::MSP, sp).map_err(err("msp"))?;
        self.uc.reg_write(RegisterARM::SP, sp).map_err(err("sp"))?;
        self.uc.reg_write(RegisterARM::CONTROL, 0).map_err(err("control"))?;
        self.uc.reg_write(RegisterARM::PRIMASK, 0).map_err(err("primask"))?;
        self.uc.reg_write(RegisterARM::XPSR, 1 << 24).map_err(err("xpsr"))?;
        self.uc.reg_write(RegisterARM::LR, 0xFFFF_FFFF).map_err(err("lr"))?;
        self.uc.reg_write(RegisterARM::PC, pc & !1).map_err(err("pc"))?;
        Ok(())
    }

    /// A press of the reset button (a pin reset; twice within the bootloader's wait is the
    /// double tap).
    pub fn reset_pin(&mut self) -> Result<(), String> {
        self.log.push(format!("[vboard] reset pin at {:.3} s", self.now()));
        self.resets += 1;
        self.reset_with(ResetKind::Pin)
    }

    /// The stock bootloader's stand-in.
    pub fn stock_bootloader(&self) -> StockBootloader {
        self.periph.borrow().stock.clone()
    }

    /// The application runs (not the bootloader, not System OFF).
    pub fn in_app(&self) -> bool {
        let p = self.periph.borrow();
        p.stock.stage == Stage::App && p.off.is_none()
    }

    /// Outside the application (bootloader or System OFF): time passes without the CPU, up to
    /// `t_end`, the bootloader's next decision or the watchdog. Some(stop) when the run ends.
    fn idle_step(&mut self, t_end: f64) -> Result<bool, String> {
        let mut p = self.periph.borrow_mut();
        let now = p.now();
        if p.power.system_off && p.off.is_none() {
            if p.debug_interface {
                // Emulated System OFF: the CPU runs on.
                p.power.system_off = false;
                return Ok(false);
            }
            let vbus = p.power.vbus();
            p.off = Some(vbus);
            drop(p);
            self.log.push(format!("[vboard] System OFF at {now:.3} s"));
            return Ok(true);
        }
        if let Some(vbus_at_off) = p.off {
            let wake = if p.gpio.detect(p.button) {
                Some(Wake::Detect)
            } else if p.power.vbus() && !vbus_at_off {
                Some(Wake::Vbus)
            } else {
                None
            };
            if let Some(w) = wake {
                drop(p);
                self.log.push(format!("[vboard] wake from System OFF ({w:?}) at {now:.3} s"));
                self.resets += 1;
                self.reset_with(ResetKind::OffWake(w))?;
            } else if t_end > now {
                p.skipped_s += t_end - now;
            }
            return Ok(true);
        }
        if p.stock.stage == Stage::App {
            return Ok(false);
        }
        let app_present = {
            let mut v = [0u8; 4];
            self.uc.mem_read(0x1_0004, &mut v).is_ok() && u32::from_le_bytes(v) != 0xFFFF_FFFF
        };
        let mut gpregret = p.power.gpregret;
        let was_samba = p.stock.in_samba();
        let decision = p.stock.decide(now, &mut gpregret, app_present);
        p.power.gpregret = gpregret;
        match decision {
            Decision::Jump => {
                drop(p);
                self.start_app()?;
                return Ok(true);
            }
            Decision::SamBa => {
                if !was_samba {
                    drop(p);
                    self.log.push(format!("[vboard] stock bootloader: SAM-BA mode at {now:.3} s"));
                    p = self.periph.borrow_mut();
                }
                let (m, pr) = bootloader::STRINGS;
                p.usb_host.stand_in = p.power.vbus().then_some((bootloader::VID_PID, m, pr));
            }
            Decision::Wait => {}
        }
        let mut next = t_end;
        if let Some(u) = p.stock.wait_until() {
            next = next.min(u);
        }
        if let Some(d) = p.wdt.deadline() {
            next = next.min(d + 1e-6);
        }
        if next > now {
            p.skipped_s += next - now;
        }
        Ok(true)
    }

    /// Saves the board's state.
    pub fn snapshot(&self) -> Result<Snapshot, String> {
        let mut context = self.uc.context_init().map_err(err("context"))?;
        self.uc.context_save(&mut context).map_err(err("context save"))?;
        Ok(Snapshot {
            context,
            ram: self.uc.mem_read_as_vec(RAM.0, (RAM.1 - RAM.0) as usize).map_err(err("RAM"))?,
            periph: self.periph.borrow().clone(),
            instructions: self.instructions.get(),
            exception: self.exception.clone(),
        })
    }

    /// Goes back to a saved state (the log keeps growing).
    pub fn restore(&mut self, s: &Snapshot) -> Result<(), String> {
        self.uc.context_restore(&s.context).map_err(err("context restore"))?;
        self.uc.mem_write(RAM.0, &s.ram).map_err(err("RAM"))?;
        *self.periph.borrow_mut() = s.periph.clone();
        self.instructions.set(s.instructions);
        self.exception = s.exception.clone();
        self.decoder = self.table.map(|t| t.new_stream_decoder() as Box<dyn defmt_decoder::StreamDecoder>);
        Ok(())
    }

    /// The flat profile of the procedure's `calls` kept while `profiling` was set: their
    /// instructions per function (callees apart, but a builtin's — software floating point,
    /// memcpy — charged to its caller), most first.
    pub fn profile(&self, calls: Calls) -> Vec<(String, u64)> {
        let mut per: std::collections::HashMap<&str, u64> = std::collections::HashMap::new();
        for (addr, n) in self.blocks.borrow()[calls as usize].iter() {
            let fns = &self.firmware.functions;
            let i = fns.partition_point(|f| f.0 <= *addr);
            let name = i.checked_sub(1).map(|i| &fns[i]).filter(|f| *addr < f.1).map_or("?", |f| f.2.as_str());
            *per.entry(name).or_insert(0) += n;
        }
        let mut out: Vec<(String, u64)> = per.into_iter().map(|(k, v)| (k.to_string(), v)).collect();
        out.sort_by_key(|p| std::cmp::Reverse(p.1));
        out
    }

    /// Paints the free stack with a pattern (for the peak-stack measurement).
    pub fn paint_stack(&mut self) {
        if let Some((lo, hi)) = self.firmware.stack {
            // Before the bootloader's jump the CPU's SP is not the application's yet.
            let sp = if self.in_app() { self.uc.reg_read(RegisterARM::SP).unwrap_or(hi) } else { hi };
            let top = sp.min(hi).saturating_sub(64);
            if top > lo {
                let _ = self.uc.mem_write(lo, &vec![0xA5; (top - lo) as usize]);
            }
        }
    }

    /// Peak stack use (bytes): the painted bytes that were overwritten.
    pub fn peak_stack(&self) -> Option<u64> {
        let (lo, hi) = self.firmware.stack?;
        let mem = self.uc.mem_read_as_vec(lo, (hi - lo) as usize).ok()?;
        let untouched = mem.iter().take_while(|&&b| b == 0xA5).count() as u64;
        Some(hi - lo - untouched)
    }

    /// The host attaches like `probe-rs run`: sets the up channel to BLOCK_IF_FULL (once the
    /// control block is initialised) and reads it.
    pub fn rtt_attach(&mut self) {
        self.rtt.reading = true;
        self.rtt.mode_pending = true;
        self.rtt_poll_attach();
    }

    /// The host stops reading (unplugged); the channel's flags stay as they are.
    pub fn rtt_detach(&mut self) {
        self.rtt.reading = false;
    }

    /// Bytes the firmware wrote to the RTT up buffer so far.
    pub fn rtt_written(&self) -> u64 {
        self.rtt_write_seen.get().1
    }

    /// The firmware's own count of log bytes it dropped because the buffer was full (read from
    /// its RAM; `None` if the ELF has no such counter).
    pub fn rtt_dropped(&self) -> Option<u32> {
        let mut b = [0u8; 4];
        self.uc.mem_read(self.firmware.rtt_dropped?, &mut b).ok()?;
        Some(u32::from_le_bytes(b))
    }

    /// The up channel's flags word (None before the control block is initialised).
    pub fn rtt_flags(&self) -> Option<u32> {
        let cb = self.firmware.rtt?;
        let mut h = [0u8; 48];
        self.uc.mem_read(cb, &mut h).ok()?;
        (&h[..10] == b"SEGGER RTT").then(|| u32::from_le_bytes([h[44], h[45], h[46], h[47]]))
    }

    fn rtt_poll_attach(&mut self) {
        if !self.rtt.mode_pending {
            return;
        }
        let (Some(cb), Some(flags)) = (self.firmware.rtt, self.rtt_flags()) else { return };
        let f = (flags & !RTT_MODE_MASK) | RTT_BLOCK_IF_FULL;
        let _ = self.uc.mem_write(cb + 44, &f.to_le_bytes());
        self.rtt.mode_pending = false;
    }

    /// The defmt lines in the RTT up buffer as it is now (oldest to newest, the first partial
    /// frame skipped): what a host that attaches at the end can still read.
    pub fn rtt_tail(&self) -> Vec<String> {
        let (Some(cb), Some(table)) = (self.firmware.rtt, self.table) else { return vec![] };
        let mut h = [0u8; 48];
        if self.uc.mem_read(cb, &mut h).is_err() {
            return vec![];
        }
        let u = |o: usize| u32::from_le_bytes([h[o], h[o + 1], h[o + 2], h[o + 3]]) as u64;
        let (buf, size, write) = (u(28), u(32), u(36));
        let Ok(mem) = self.uc.mem_read_as_vec(buf, size as usize) else { return vec![] };
        // Ring order from the write offset: the oldest byte first.
        let ring: Vec<u8> = mem[write as usize..].iter().chain(&mem[..write as usize]).copied().collect();
        // Frames end with a 0x00 delimiter (rzCOBS): start after the first one.
        let start = ring.iter().position(|&b| b == 0).map_or(ring.len(), |i| i + 1);
        let mut dec = table.new_stream_decoder();
        dec.received(&ring[start..]);
        let mut out = vec![];
        while let Ok(frame) = dec.decode() {
            out.push(frame.display(false).to_string());
        }
        out
    }

    /// Counts the bytes the firmware wrote to the up buffer since the last call, from its write
    /// offset (it cannot move by a buffer's size between two calls: it never passes the read
    /// offset, which only the host moves, between slices).
    fn note_rtt_writes(&mut self) {
        let Some(cb) = self.firmware.rtt else { return };
        let mut h = [0u8; 8];
        if self.uc.mem_read(cb + 32, &mut h).is_err() {
            return;
        }
        let (size, write) = (u32::from_le_bytes([h[0], h[1], h[2], h[3]]) as u64, u32::from_le_bytes([h[4], h[5], h[6], h[7]]) as u64);
        let (last, total) = self.rtt_write_seen.get();
        if size > 0 && write < size && write != last {
            self.rtt_write_seen.set((write, total + (write + size - last % size) % size));
        }
    }

    fn drain_rtt(&mut self) {
        self.note_rtt_writes();
        self.rtt_poll_attach();
        if !self.rtt.reading {
            return;
        }
        let Some(cb) = self.firmware.rtt else { return };
        let mut h = [0u8; 48];
        if self.uc.mem_read(cb, &mut h).is_err() {
            return;
        }
        let u = |o: usize| u32::from_le_bytes([h[o], h[o + 1], h[o + 2], h[o + 3]]) as u64;
        let (buf, size, write, read) = (u(28), u(32), u(36), u(40));
        if size == 0 || write == read || write >= size || read >= size {
            return;
        }
        let take = |from: u64, to: u64, v: &mut Vec<u8>| {
            if let Ok(b) = self.uc.mem_read_as_vec(buf + from, (to - from) as usize) {
                v.extend(b);
            }
        };
        let mut bytes = vec![];
        if write > read {
            take(read, write, &mut bytes);
        } else {
            take(read, size, &mut bytes);
            take(0, write, &mut bytes);
        }
        let _ = self.uc.mem_write(cb + 40, &(write as u32).to_le_bytes());
        self.rtt.read += bytes.len() as u64;
        if let Some(dec) = self.decoder.as_mut() {
            dec.received(&bytes);
            loop {
                match dec.decode() {
                    Ok(frame) => self.log.push(frame.display(false).to_string()),
                    Err(defmt_decoder::DecodeError::UnexpectedEof) => break,
                    Err(defmt_decoder::DecodeError::Malformed) => {
                        self.log.push("[vboard] malformed defmt frame".into());
                        break;
                    }
                }
            }
        }
    }

    fn deliver_interrupt(&mut self) -> Result<(), String> {
        if self.exception.is_some() || self.uc.reg_read(RegisterARM::PRIMASK).unwrap_or(0) & 1 != 0 {
            return Ok(());
        }
        let (pending, vtor) = {
            let p = self.periph.borrow();
            (p.scs.nvic_pending & p.scs.nvic_enabled, p.scs.vtor)
        };
        if pending == 0 {
            return Ok(());
        }
        let irq = pending.trailing_zeros() as u64;
        {
            let mut p = self.periph.borrow_mut();
            p.scs.nvic_pending &= !(1 << irq);
            p.active_irq = Some(irq as u32);
        }
        let mut v = [0u8; 4];
        self.uc.mem_read(vtor as u64 + 4 * (16 + irq), &mut v).map_err(err("vector"))?;
        let handler = u32::from_le_bytes(v) as u64;
        let r = |uc: &Unicorn<()>, reg| uc.reg_read(reg).unwrap_or(0) as u32;
        let xpsr = r(&self.uc, RegisterARM::XPSR);
        let frame = [
            r(&self.uc, RegisterARM::R0),
            r(&self.uc, RegisterARM::R1),
            r(&self.uc, RegisterARM::R2),
            r(&self.uc, RegisterARM::R3),
            r(&self.uc, RegisterARM::R12),
            r(&self.uc, RegisterARM::LR),
            r(&self.uc, RegisterARM::PC),
            xpsr,
        ];
        let sp = r(&self.uc, RegisterARM::SP) as u64;
        let mut new_sp = sp - 32;
        let mut frame = frame;
        if new_sp & 4 != 0 {
            new_sp -= 4;
            frame[7] |= 1 << 9;
        }
        let bytes: Vec<u8> = frame.iter().flat_map(|w| w.to_le_bytes()).collect();
        self.uc.mem_write(new_sp, &bytes).map_err(err("stack frame"))?;
        // FP context: kept by the host, restored on return (the handler may use the FPU).
        let fp = (0..16)
            .map(|i| self.uc.reg_read(RegisterARM::S0 as i32 + i).unwrap_or(0))
            .chain([self.uc.reg_read(RegisterARM::FPSCR).unwrap_or(0)])
            .collect();
        self.exception = Some(Exception { fp, irq: irq as u32 });
        self.uc.reg_write(RegisterARM::SP, new_sp).map_err(err("sp"))?;
        self.uc.reg_write(RegisterARM::LR, 0xFFFF_FFF9).map_err(err("lr"))?;
        // Exception entry clears EPSR.IT (ARMv7-M ARM B1.5.6): a handler that interrupts an IT
        // block does not run its first instructions under that block's condition.
        self.uc.reg_write(RegisterARM::XPSR, u64::from((xpsr & !XPSR_IT & !0x1FF) | (16 + irq as u32))).map_err(err("xpsr"))?;
        self.uc.reg_write(RegisterARM::PC, handler & !1).map_err(err("pc"))?;
        Ok(())
    }

    fn exception_return(&mut self) -> Result<(), String> {
        let sp = self.uc.reg_read(RegisterARM::SP).map_err(err("sp"))?;
        let mut b = [0u8; 32];
        self.uc.mem_read(sp, &mut b).map_err(err("unstack"))?;
        let w = |i: usize| u32::from_le_bytes([b[4 * i], b[4 * i + 1], b[4 * i + 2], b[4 * i + 3]]) as u64;
        for (i, reg) in
            [RegisterARM::R0, RegisterARM::R1, RegisterARM::R2, RegisterARM::R3, RegisterARM::R12, RegisterARM::LR].into_iter().enumerate()
        {
            self.uc.reg_write(reg, w(i)).map_err(err("restore"))?;
        }
        let xpsr = w(7);
        let new_sp = sp + 32 + if xpsr & (1 << 9) != 0 { 4 } else { 0 };
        self.uc.reg_write(RegisterARM::SP, new_sp).map_err(err("sp"))?;
        self.uc.reg_write(RegisterARM::XPSR, xpsr & !(1 << 9) & !0x1FF).map_err(err("xpsr"))?;
        if let Some(e) = self.exception.take() {
            for (i, v) in e.fp.iter().take(16).enumerate() {
                let _ = self.uc.reg_write(RegisterARM::S0 as i32 + i as i32, *v);
            }
            let _ = self.uc.reg_write(RegisterARM::FPSCR, e.fp[16]);
            self.periph.borrow_mut().exception_return(e.irq);
        }
        self.uc.reg_write(RegisterARM::PC, w(6) & !1).map_err(err("pc"))?;
        Ok(())
    }

    /// Where the CPU is, for a fault message: PC, LR, SP and the last block entered.
    fn cpu_at(&self) -> String {
        let reg = |r| self.uc.reg_read(r).unwrap_or(0);
        let (pc, lr, sp) = (reg(RegisterARM::PC), reg(RegisterARM::LR), reg(RegisterARM::SP));
        format!("at PC 0x{pc:08X} (LR 0x{lr:08X}, SP 0x{sp:08X}, last block at 0x{:08X})", self.periph.borrow().pc.get())
    }

    /// Runs until virtual time `t_end` (s), or a fault or power cut.
    pub fn run_until(&mut self, t_end: f64) -> Stop {
        // A CPU that neither executes nor lets time pass (an exception it cannot take, code
        // outside the application) would spin this loop forever: a fault after this many turns.
        const STUCK_TURNS: u32 = 100_000;
        let (mut stuck, mut mark) = (0u32, (u64::MAX, f64::NAN));
        loop {
            let now_mark = (self.instructions.get(), self.now());
            if now_mark == mark {
                stuck += 1;
                if stuck >= STUCK_TURNS {
                    return Stop::Fault(format!("the CPU makes no progress {}", self.cpu_at()));
                }
            } else {
                (stuck, mark) = (0, now_mark);
            }
            self.periph.borrow_mut().update();
            self.drain_rtt();
            {
                let mut p = self.periph.borrow_mut();
                if let Some(f) = p.fault.take() {
                    return Stop::Fault(f);
                }
                if p.power_cut {
                    return Stop::PowerCut;
                }
                if p.watchdog_reset || p.scs.reset_request {
                    let wd = p.watchdog_reset;
                    drop(p);
                    self.log.push(format!("[vboard] {} reset at {:.3} s", if wd { "watchdog" } else { "software" }, self.now()));
                    self.resets += 1;
                    self.watchdog_resets += u32::from(wd);
                    if let Err(e) = self.reset_with(if wd { ResetKind::Watchdog } else { ResetKind::Soft }) {
                        return Stop::Fault(e);
                    }
                    continue;
                }
            }
            if let Some(f) = self.fault.borrow_mut().take() {
                return Stop::Fault(f);
            }
            let now = self.now();
            if now >= t_end {
                return Stop::Time;
            }
            match self.idle_step(t_end) {
                Ok(true) => continue,
                Ok(false) => {}
                Err(e) => return Stop::Fault(e),
            }
            if let Err(e) = self.deliver_interrupt() {
                return Stop::Fault(e);
            }
            let pc = self.uc.reg_read(RegisterARM::PC).unwrap_or(0);
            if pc >= 0xFFFF_FF00 {
                if let Err(e) = self.exception_return() {
                    return Stop::Fault(e);
                }
                continue;
            }
            let budget = (((t_end - now) * CPU_HZ).ceil() as u64).clamp(1, SLICE);
            self.wfi_hit.set(false);
            self.stop_at.set(self.instructions.get() + budget);
            let result = self.uc.emu_start(pc | 1, 0, 0, 0);
            if let Err(e) = result {
                let pc = self.uc.reg_read(RegisterARM::PC).unwrap_or(0);
                if pc >= 0xFFFF_FF00 {
                    // Exception return (EXC_RETURN branch): unstack.
                    if let Err(e) = self.exception_return() {
                        return Stop::Fault(e);
                    }
                    continue;
                }
                let fetch_denied = matches!(e, unicorn_engine::uc_error::FETCH_PROT | unicorn_engine::uc_error::EXCEPTION);
                if fetch_denied && !self.sram_exec.get() && (RAM.0..RAM.1).contains(&pc) {
                    // The first fetch from SRAM: a fault if the MPU marks it execute-never, else
                    // SRAM becomes executable (as it is on the part) and the fetch is retried.
                    let denied = self.periph.borrow().scs.mpu.check(pc, mpu::Check::Exec).err();
                    if let Some(f) = denied {
                        return Stop::Fault(f);
                    }
                    self.sram_exec.set(true);
                    if let Err(e) = self.uc.mem_protect(RAM.0, RAM.1 - RAM.0, Prot::ALL).and_then(|_| self.uc.ctl_flush_tlb()) {
                        return Stop::Fault(format!("SRAM execute: {e:?}"));
                    }
                    continue;
                }
                return Stop::Fault(format!("emulation error {e:?} {}", self.cpu_at()));
            }
            let pc = self.uc.reg_read(RegisterARM::PC).unwrap_or(0);
            if pc >= 0xFFFF_FF00 {
                if let Err(e) = self.exception_return() {
                    return Stop::Fault(e);
                }
                continue;
            }
            if self.wfi_hit.get() {
                // The hook stopped the CPU on the `wfi`: execution resumes after it, once an
                // event has woken the CPU. Asleep until the next event (or the end of the run).
                if self.wfi_addrs.contains(&pc) {
                    let _ = self.uc.reg_write(RegisterARM::PC, pc + 2);
                }
                let fpu_flags = self.uc.reg_read(RegisterARM::FPSCR).unwrap_or(0) & FPSCR_EXCEPTIONS != 0;
                let mut p = self.periph.borrow_mut();
                p.scs.wfi_with_fpu_flags += u32::from(fpu_flags);
                let now = p.now();
                let wake = p.next_event().unwrap_or(t_end).min(t_end);
                if wake > now {
                    p.skipped_s += wake - now;
                }
            }
        }
    }
}

/// Thumb-2 instruction lengths of the loaded flash, to count a block's instructions.
struct Thumb {
    /// Per halfword from 0x10000: 1 if it starts a 32-bit instruction (first halfword
    /// 0b11101…, 0b11110… or 0b11111…).
    wide: Vec<u8>,
    /// Per halfword from 0x10000: (size in bytes, instructions) of the last block counted from
    /// there.
    blocks: Cell<Vec<(u32, u32)>>,
}

impl Thumb {
    fn new(fw: &Firmware) -> Self {
        let mut wide = vec![0u8; ((FLASH_END - 0x1_0000) / 2) as usize];
        for (addr, data) in &fw.segments {
            if *addr >= 0x1_0000 && *addr < FLASH_END {
                let first = ((addr - 0x1_0000) / 2) as usize;
                for (i, h) in data.chunks_exact(2).enumerate() {
                    if let Some(w) = wide.get_mut(first + i) {
                        *w = u8::from(u16::from_le_bytes([h[0], h[1]]) >> 11 >= 0b11101);
                    }
                }
            }
        }
        let blocks = Cell::new(vec![(u32::MAX, 0); wide.len()]);
        Self { wide, blocks }
    }

    /// Instructions in the `size` bytes from `addr`.
    fn instructions(&self, addr: u64, size: u32) -> u64 {
        let start = ((addr - 0x1_0000) / 2) as usize;
        let mut blocks = self.blocks.take();
        let n = match blocks.get(start) {
            Some(&(sz, n)) if sz == size => n,
            _ => {
                let (mut i, end) = (start, start + size as usize / 2);
                let mut n = 0;
                while i < end {
                    i += 1 + usize::from(self.wide.get(i).copied().unwrap_or(0));
                    n += 1;
                }
                if let Some(b) = blocks.get_mut(start) {
                    *b = (size, n);
                }
                n
            }
        };
        self.blocks.set(blocks);
        u64::from(n)
    }
}

/// Addresses of `wfi` (0xBF30) halfwords in the loaded flash segments.
fn wfi_addresses(fw: &Firmware) -> HashSet<u64> {
    let mut set = HashSet::new();
    for (addr, data) in &fw.segments {
        if *addr >= 0x1_0000 && *addr < FLASH_END {
            for (i, h) in data.chunks_exact(2).enumerate() {
                if h == [0x30, 0xBF] {
                    set.insert(addr + 2 * i as u64);
                }
            }
        }
    }
    set
}
