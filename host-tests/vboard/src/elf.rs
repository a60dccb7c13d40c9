//! The firmware ELF: loadable segments, symbols and the defmt table.

use object::{Object, ObjectSegment, ObjectSymbol};

/// What the board needs from the ELF.
pub struct Firmware {
    /// Raw ELF bytes (for the defmt table).
    pub bytes: Vec<u8>,
    /// (physical address, bytes) of every loadable segment.
    pub segments: Vec<(u64, Vec<u8>)>,
    /// Address of the RTT control block `_SEGGER_RTT`.
    pub rtt: Option<u64>,
    /// Address of the logger's count of dropped bytes (`gyrocal_fw::rtt`'s `DROPPED`, a u32).
    pub rtt_dropped: Option<u64>,
    /// Address range of `Procedure::handle_sample` (instruction counting).
    pub handle_sample: Option<(u64, u64)>,
    /// Address range of the stack (RAM start to the initial stack pointer; flip-link puts it
    /// below .data/.bss).
    pub stack: Option<(u64, u64)>,
}

impl Firmware {
    /// Parses an ELF file.
    pub fn load(bytes: Vec<u8>) -> Result<Self, String> {
        let file = object::File::parse(&*bytes).map_err(|e| format!("not an ELF: {e}"))?;
        let mut segments = vec![];
        for seg in file.segments() {
            let data = seg.data().map_err(|e| e.to_string())?;
            if !data.is_empty() {
                // The load (physical) address: .data is copied from flash by the reset handler.
                let (offset, _) = seg.file_range();
                let paddr = physical_address(&bytes, offset).unwrap_or(seg.address());
                segments.push((paddr, data.to_vec()));
            }
        }
        let (mut rtt, mut rtt_dropped) = (None, None);
        let mut handle_sample = None;
        let mut stack_top = None;
        for sym in file.symbols() {
            let name = sym.name().unwrap_or("");
            if name == "_SEGGER_RTT" {
                rtt = Some(sym.address());
            } else if name.contains("rtt") && name.contains("DROPPED") && sym.size() == 4 {
                rtt_dropped = Some(sym.address());
            } else if name == "_stack_start" {
                stack_top = Some(sym.address());
            } else if name.contains("Procedure") && name.contains("handle_sample") && sym.size() > 0 {
                let a = sym.address() & !1;
                handle_sample = Some((a, a + sym.size()));
            }
        }
        let stack = stack_top.map(|t| (0x2000_0000, t));
        Ok(Self { bytes, segments, rtt, rtt_dropped, handle_sample, stack })
    }
}

/// The physical address of the program header whose file offset is `offset` (ELF32 LE).
fn physical_address(elf: &[u8], offset: u64) -> Option<u64> {
    let u32_at = |o: usize| -> Option<u32> { Some(u32::from_le_bytes(elf.get(o..o + 4)?.try_into().ok()?)) };
    let u16_at = |o: usize| -> Option<u16> { Some(u16::from_le_bytes(elf.get(o..o + 2)?.try_into().ok()?)) };
    let phoff = u32_at(0x1C)? as usize;
    let phentsize = u16_at(0x2A)? as usize;
    let phnum = u16_at(0x2C)? as usize;
    (0..phnum).find_map(|i| {
        let ph = phoff + i * phentsize;
        (u32_at(ph)? == 1 && u32_at(ph + 4)? as u64 == offset && u32_at(ph + 16)? > 0).then(|| u32_at(ph + 12).map(u64::from))?
    })
}
