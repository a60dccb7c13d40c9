//! The image's own run-time routines (`src/mem.rs`: the `memcpy`, `memclr` and `memcmp` LLVM
//! calls, in assembly), called on the emulated core and checked against Rust's at every length
//! and alignment a word loop and its byte tail can meet.

use rig_sim::lsm_model::Board;
use rig_sim::nor::NorSim;
use rig_sim::variant::Variant;
use vboard::mcu::Mcu;
use vboard::testbed::{build_firmware, Testbed};

/// Scratch RAM at the bottom of the stack's region (the firmware does not run here).
const DST: u64 = 0x2000_0100;
const SRC: u64 = 0x2000_0300;
const SPAN: usize = 96;
/// Longest length tried: several words and every tail.
const MAX_N: usize = 40;
const GUARD: u8 = 0xA5;

fn board() -> Mcu {
    let elf = build_firmware(&[]).unwrap();
    Testbed::new(elf, Variant::Hobby.config(1, 0), 1, Board::Rev1, NorSim::new(8, 1), false).unwrap().mcu
}

fn pattern(seed: u8) -> Vec<u8> {
    (0..SPAN).map(|i| (i as u8).wrapping_mul(37).wrapping_add(seed) | 0x01).collect()
}

/// Offsets a routine may be given: any for the byte-aligned names, multiples of 4 or 8 for
/// the `4` and `8` ones (the run-time ABI's promise).
fn offsets(name: &str) -> Vec<usize> {
    let step = if name.ends_with('8') {
        8
    } else if name.ends_with('4') {
        4
    } else {
        1
    };
    (0..8).step_by(step).collect()
}

#[test]
fn the_images_memcpy_memclr_and_memcmp_match_rusts_at_every_length_and_alignment() {
    let mut mcu = board();
    for name in ["__aeabi_memcpy", "__aeabi_memcpy4", "__aeabi_memcpy8", "__aeabi_memclr", "__aeabi_memclr4", "__aeabi_memclr8", "memcmp"] {
        let f = mcu.firmware().functions.iter().find(|f| f.2 == name).unwrap_or_else(|| panic!("{name} not in the image"));
        // compiler_builtins' are 156–730 B: the image must have taken src/mem.rs's.
        assert!(f.1 - f.0 <= 64, "{name} is {} B: not the image's own", f.1 - f.0);
    }
    let (src, guard) = (pattern(11), vec![GUARD; SPAN]);
    for name in ["__aeabi_memcpy", "__aeabi_memcpy4", "__aeabi_memcpy8"] {
        for (n, s, d) in
            (0..=MAX_N).flat_map(|n| offsets(name).into_iter().flat_map(move |s| offsets(name).into_iter().map(move |d| (n, s, d))))
        {
            mcu.mem_write(DST, &guard).unwrap();
            mcu.mem_write(SRC, &src).unwrap();
            mcu.call(name, &[(DST as usize + d) as u32, (SRC as usize + s) as u32, n as u32], 1_000).unwrap();
            let mut want = guard.clone();
            want[d..d + n].copy_from_slice(&src[s..s + n]);
            assert_eq!(mcu.mem_read(DST, SPAN).unwrap(), want, "{name}(dst + {d}, src + {s}, {n})");
            assert_eq!(mcu.mem_read(SRC, SPAN).unwrap(), src, "{name} wrote its source");
        }
    }
    for name in ["__aeabi_memclr", "__aeabi_memclr4", "__aeabi_memclr8"] {
        for (n, d) in (0..=MAX_N).flat_map(|n| offsets(name).into_iter().map(move |d| (n, d))) {
            mcu.mem_write(DST, &src).unwrap();
            mcu.call(name, &[(DST as usize + d) as u32, n as u32], 1_000).unwrap();
            let mut want = src.clone();
            want[d..d + n].fill(0);
            assert_eq!(mcu.mem_read(DST, SPAN).unwrap(), want, "{name}(dst + {d}, {n})");
        }
    }
    // memcmp: equal prefixes, and one byte changed up or down (across 0x80: the bytes compare
    // unsigned) at every place; C promises the sign alone.
    for n in 0..=MAX_N {
        for (at, to) in
            std::iter::once((None, 0u8)).chain((0..n).flat_map(|i| [(Some(i), 0x00), (Some(i), 0xFF), (Some(i), 0x7F), (Some(i), 0x80)]))
        {
            let mut b = src.clone();
            if let Some(i) = at {
                b[i] = to;
            }
            mcu.mem_write(SRC, &src).unwrap();
            mcu.mem_write(DST, &b).unwrap();
            let got = mcu.call("memcmp", &[SRC as u32, DST as u32, n as u32], 1_000).unwrap() as i32;
            let want = src[..n].cmp(&b[..n]);
            assert_eq!(got.cmp(&0), want, "memcmp(.., .., {n}) with byte {at:?} set to {to:#04X}: {got}");
        }
    }
}
