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
    /// Address range of `Procedure::handle_tick` (the solve's steps run in it).
    pub handle_tick: Option<(u64, u64)>,
    /// Address range of the stack (RAM start to the initial stack pointer; flip-link puts it
    /// below .data/.bss).
    pub stack: Option<(u64, u64)>,
    /// Every function with a size: (start, end, demangled name without its hash), by start.
    pub functions: Vec<(u64, u64, String)>,
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
        let (mut handle_sample, mut handle_tick) = (None, None);
        let mut stack_top = None;
        let mut functions = vec![];
        for sym in file.symbols() {
            let name = sym.name().unwrap_or("");
            if sym.kind() == object::SymbolKind::Text && sym.size() > 0 {
                let a = sym.address() & !1;
                functions.push((a, a + sym.size(), demangle(name)));
            }
            if name == "_SEGGER_RTT" {
                rtt = Some(sym.address());
            } else if name.contains("rtt") && name.contains("DROPPED") && sym.size() == 4 {
                rtt_dropped = Some(sym.address());
            } else if name == "_stack_start" {
                stack_top = Some(sym.address());
            } else if name.contains("Procedure") && sym.size() > 0 {
                let a = sym.address() & !1;
                if names(name, "handle_sample") {
                    handle_sample = Some((a, a + sym.size()));
                } else if names(name, "handle_tick") {
                    handle_tick = Some((a, a + sym.size()));
                }
            }
        }
        let stack = stack_top.map(|t| (0x2000_0000, t));
        functions.sort();
        Ok(Self { bytes, segments, rtt, rtt_dropped, handle_sample, handle_tick, stack, functions })
    }
}

/// A Rust-mangled name as `a::b::c`: legacy (`_ZN` length-prefixed parts, `17h…E` hash,
/// its common `$LT$`-style escapes replaced) or v0 (its identifiers); other names as they are.
fn demangle(name: &str) -> String {
    // A v0 name (`_R…`, compiler_builtins'): its identifiers only.
    if let Some(v0) = name.strip_prefix("_R") {
        let mut parts = vec![];
        let mut rest = v0;
        while let Some(start) = rest.find(|c: char| c.is_ascii_digit()) {
            // A crate root's disambiguator (`Cs<base-62>_`) is not a name.
            if rest[..start].ends_with("Cs") {
                rest = rest[start..].split_once('_').map_or("", |(_, r)| r);
                continue;
            }
            rest = &rest[start..];
            let mut digits = rest.find(|c: char| !c.is_ascii_digit()).unwrap_or(rest.len());
            let len = rest[..digits].parse::<usize>().unwrap_or(0);
            // An identifier that starts with `_` or a digit has a `_` before it.
            if rest[digits..].starts_with('_')
                && rest
                    .get(digits + 1..digits + 1 + len)
                    .is_some_and(|p| p.starts_with(['_', '0', '1', '2', '3', '4', '5', '6', '7', '8', '9']))
            {
                digits += 1;
            }
            match rest.get(digits..digits + len) {
                Some(part) if len > 0 && part.starts_with(|c: char| c.is_ascii_alphabetic() || c == '_') => {
                    parts.push(part.to_string());
                    rest = &rest[digits + len..];
                }
                _ => rest = &rest[digits..],
            }
        }
        return if parts.is_empty() { name.to_string() } else { parts.join("::") };
    }
    let Some(mut rest) = name.strip_prefix("_ZN") else { return name.to_string() };
    let mut parts = vec![];
    while let Some(digits) = rest.find(|c: char| !c.is_ascii_digit()).filter(|&d| d > 0) {
        let Ok(len) = rest[..digits].parse::<usize>() else { break };
        let Some(part) = rest.get(digits..digits + len) else { break };
        rest = &rest[digits + len..];
        if !(part.len() == 17 && part.starts_with('h') && rest == "E") {
            parts.push(part.replace("..", "::").replace("$LT$", "<").replace("$GT$", ">").replace("$u20$", " ").replace("$C$", ","));
        }
    }
    parts.join("::")
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

/// Whether symbol `name` (mangled or not) names the function `ident` itself: `ident` not
/// followed by more of an identifier (`handle_sample`, not `handle_samples_lost`; a mangled
/// name's hash length digits may follow).
fn names(name: &str, ident: &str) -> bool {
    name.match_indices(ident).any(|(i, _)| !name[i + ident.len()..].starts_with(|c: char| c.is_ascii_alphabetic() || c == '_'))
}

#[cfg(test)]
mod tests {
    use super::{demangle, names};

    #[test]
    fn names_read_as_paths() {
        assert_eq!(demangle("_ZN10calib_core4math5stats8Moments33add17h0123456789abcdefE"), "calib_core::math::stats::Moments3::add");
        assert_eq!(demangle("_RNvNtNtCs7NhdfSRABLd_17compiler_builtins5float3add8___adddf3"), "compiler_builtins::float::add::__adddf3");
        assert_eq!(demangle("__aeabi_dsub"), "__aeabi_dsub");
    }

    #[test]
    fn a_function_is_named_by_its_whole_identifier() {
        let mangled = "_ZN10calib_core9procedure9Procedure13handle_sample17h5f86772b79c39b4bE";
        assert!(names(mangled, "handle_sample"));
        assert!(!names("_ZN10calib_core9procedure9Procedure19handle_samples_lost17hb21a3cc4d776929aE", "handle_sample"));
        assert!(names("calib_core::procedure::Procedure::handle_tick", "handle_tick"));
    }
}
