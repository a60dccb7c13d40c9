//! Small `memcpy`, `memclr` and `memcmp` for the run-time ABI names LLVM calls on the
//! Cortex-M4F (ARM's RTABI §4.3.4), in place of compiler_builtins' weak, speed-unrolled ones:
//! 96 B instead of 1 396 B of flash (the trade newlib-nano makes).
//!
//! A word (4 B, 5 instructions) at a time when both addresses are word-aligned, else a byte at a
//! time. The copies on the firmware's paths are short (a sample, a pose, a 320-byte record);
//! `cargo demo` measures the instructions a sample and the longest call with these in place.
//! Written in assembly: a Rust loop inside a function named like these may be turned back into a
//! call to itself (compiler_builtins builds with `#![no_builtins]` for that reason).

use core::arch::naked_asm;

/// Copies `n` bytes from `src` to `dst` (regions not overlapping; any alignment).
///
/// # Safety
/// As `core::ptr::copy_nonoverlapping(src, dst, n)`.
#[unsafe(naked)]
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memcpy(dst: *mut u8, src: *const u8, n: usize) {
    naked_asm!(
        "orr r3, r0, r1",
        "lsls r3, r3, #30", // Z: both word-aligned
        "bne 2f",
        "1:",
        "subs r2, #4",
        "itt hs",
        "ldrhs r3, [r1], #4",
        "strhs r3, [r0], #4",
        "bhs 1b",
        "adds r2, #4",
        "2:",
        "cbz r2, 4f",
        "3:",
        "ldrb r3, [r1], #1",
        "strb r3, [r0], #1",
        "subs r2, #1",
        "bne 3b",
        "4:",
        "bx lr",
    )
}

/// [`__aeabi_memcpy`] with both addresses word-aligned.
///
/// # Safety
/// As [`__aeabi_memcpy`].
#[unsafe(naked)]
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memcpy4(dst: *mut u8, src: *const u8, n: usize) {
    naked_asm!("b {copy}", copy = sym __aeabi_memcpy)
}

/// [`__aeabi_memcpy`] with both addresses 8-byte aligned.
///
/// # Safety
/// As [`__aeabi_memcpy`].
#[unsafe(naked)]
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memcpy8(dst: *mut u8, src: *const u8, n: usize) {
    naked_asm!("b {copy}", copy = sym __aeabi_memcpy)
}

/// Zeroes `n` bytes at `dst` (any alignment; the RTABI's argument order: address, length).
///
/// # Safety
/// As `core::ptr::write_bytes(dst, 0, n)`.
#[unsafe(naked)]
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memclr(dst: *mut u8, n: usize) {
    naked_asm!(
        "movs r2, #0",
        "lsls r3, r0, #30", // Z: word-aligned
        "bne 2f",
        "1:",
        "subs r1, #4",
        "it hs",
        "strhs r2, [r0], #4",
        "bhs 1b",
        "adds r1, #4",
        "2:",
        "cbz r1, 4f",
        "3:",
        "strb r2, [r0], #1",
        "subs r1, #1",
        "bne 3b",
        "4:",
        "bx lr",
    )
}

/// [`__aeabi_memclr`] with `dst` word-aligned.
///
/// # Safety
/// As [`__aeabi_memclr`].
#[unsafe(naked)]
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memclr4(dst: *mut u8, n: usize) {
    naked_asm!("b {clear}", clear = sym __aeabi_memclr)
}

/// [`__aeabi_memclr`] with `dst` 8-byte aligned.
///
/// # Safety
/// As [`__aeabi_memclr`].
#[unsafe(naked)]
#[unsafe(no_mangle)]
pub unsafe extern "C" fn __aeabi_memclr8(dst: *mut u8, n: usize) {
    naked_asm!("b {clear}", clear = sym __aeabi_memclr)
}

/// C's `memcmp`: the difference of the first unequal bytes of `a` and `b` (as `u8`), or 0
/// when their first `n` bytes are equal.
///
/// # Safety
/// `a` and `b` readable for `n` bytes.
#[unsafe(naked)]
#[unsafe(no_mangle)]
pub unsafe extern "C" fn memcmp(a: *const u8, b: *const u8, n: usize) -> i32 {
    naked_asm!(
        "movs r3, #0",
        "cbz r2, 2f",
        "1:",
        "ldrb r3, [r0], #1",
        "ldrb r12, [r1], #1",
        "subs r3, r3, r12",
        "bne 2f",
        "subs r2, #1",
        "bne 1b",
        "2:",
        "mov r0, r3",
        "bx lr",
    )
}
