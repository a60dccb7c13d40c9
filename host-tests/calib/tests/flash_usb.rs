//! `flash-usb`: the image checks on crafted ELFs, the real firmware's image, and the exact bossac
//! command (a fake bossac that records its arguments).
#![cfg(unix)]

use object::read::elf::{FileHeader, SectionHeader};
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::Mutex;

const EXE: &str = env!("CARGO_BIN_EXE_gyrocal-flash");

/// Writing an executable and forking concurrently can make its exec fail with ETXTBSY (another
/// thread's child holds the write descriptor until its own exec): both happen under this lock.
static SPAWN: Mutex<()> = Mutex::new(());

fn dir(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("flash_usb").join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Runs flash-usb with `args` in a clean environment: no BOSSAC, PATH without bossac, HOME
/// `home` (no Arduino15 there unless the test puts one), stdin not a terminal.
fn run(args: &[&str], home: &Path, env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(EXE);
    cmd.args(args).env_remove("BOSSAC").env_remove("ARDUINO_DIRECTORIES_DATA").env("HOME", home);
    cmd.env("PATH", std::env::var("PATH").unwrap_or_default());
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped());
    let child = {
        let _g = SPAWN.lock().unwrap_or_else(|e| e.into_inner());
        cmd.spawn().unwrap()
    };
    let out = child.wait_with_output().unwrap();
    eprintln!("--- flash-usb {args:?}: {}\n{}{}", out.status, String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    out
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// One loadable segment of a crafted ELF: load address, run address, bytes, and whether a
/// section covers it (llvm-objcopy -O binary copies sections, not segments).
struct Seg {
    paddr: u32,
    vaddr: u32,
    data: Vec<u8>,
    section: bool,
}

fn seg(paddr: u32, data: Vec<u8>) -> Seg {
    Seg { paddr, vaddr: paddr, data, section: true }
}

/// A vector table (SP, reset) padded to `len` bytes.
fn vectors(sp: u32, reset: u32, len: usize) -> Vec<u8> {
    let mut v = [sp.to_le_bytes(), reset.to_le_bytes()].concat();
    v.resize(len, 0xA5);
    v
}

/// A minimal little-endian ARM ELF32 executable: program headers, one PROGBITS section per
/// segment (if `section`), `.shstrtab`.
fn elf(segs: &[Seg]) -> Vec<u8> {
    let mut out = vec![0u8; 52 + 32 * segs.len()];
    let mut offsets = Vec::new();
    for s in segs {
        while !out.len().is_multiple_of(4) {
            out.push(0);
        }
        offsets.push(out.len() as u32);
        out.extend_from_slice(&s.data);
    }
    let mut shstr = b"\0.shstrtab\0".to_vec();
    let mut names = Vec::new();
    for i in 0..segs.len() {
        names.push(shstr.len() as u32);
        shstr.extend_from_slice(format!(".s{i}\0").as_bytes());
    }
    let shstr_off = out.len() as u32;
    out.extend_from_slice(&shstr);
    while !out.len().is_multiple_of(4) {
        out.push(0);
    }
    let shoff = out.len() as u32;
    let sh = |out: &mut Vec<u8>, w: [u32; 10]| w.iter().for_each(|x| out.extend_from_slice(&x.to_le_bytes()));
    sh(&mut out, [0; 10]);
    let mut nsec = 1;
    for (i, s) in segs.iter().enumerate().filter(|(_, s)| s.section) {
        // name, SHT_PROGBITS, SHF_ALLOC|SHF_EXECINSTR, addr, offset, size, link, info, align, entsize
        sh(&mut out, [names[i], 1, 6, s.vaddr, offsets[i], s.data.len() as u32, 0, 0, 4, 0]);
        nsec += 1;
    }
    sh(&mut out, [1, 3, 0, 0, shstr_off, shstr.len() as u32, 0, 0, 1, 0]);
    let shstrndx = nsec;
    nsec += 1;
    let mut h = Vec::new();
    h.extend_from_slice(&[0x7F, b'E', b'L', b'F', 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
    let entry = segs.first().and_then(|s| s.data.get(4..8)).map(|w| u32::from_le_bytes(w.try_into().unwrap())).unwrap_or(0);
    for x in [2u16, 40] {
        h.extend_from_slice(&x.to_le_bytes()); // ET_EXEC, EM_ARM
    }
    for x in [1u32, entry, 52, shoff, 0x0500_0400] {
        h.extend_from_slice(&x.to_le_bytes()); // version, entry, phoff, shoff, flags (EABI5, hard float)
    }
    for x in [52u16, 32, segs.len() as u16, 40, nsec, shstrndx] {
        h.extend_from_slice(&x.to_le_bytes());
    }
    for (i, s) in segs.iter().enumerate() {
        let n = s.data.len() as u32;
        // PT_LOAD, offset, vaddr, paddr, filesz, memsz, flags R+X, align
        for x in [1u32, offsets[i], s.vaddr, s.paddr, n, n, 5, 4] {
            h.extend_from_slice(&x.to_le_bytes());
        }
    }
    out[..h.len()].copy_from_slice(&h);
    out
}

/// Writes the crafted ELF and runs `flash-usb --elf ELF --bin-only OUT`; returns the output
/// and OUT.
fn bin_only(name: &str, segs: &[Seg]) -> (Output, PathBuf) {
    let d = dir(name);
    let e = d.join("fw.elf");
    std::fs::write(&e, elf(segs)).unwrap();
    let out = d.join("fw.bin");
    (run(&["--elf", e.to_str().unwrap(), "--bin-only", out.to_str().unwrap()], &d, &[]), out)
}

fn good() -> Vec<Seg> {
    vec![seg(0x1_0000, vectors(0x2003_F000, 0x1_0009, 0x100)), seg(0x1_0100, vec![0x70, 0x47, 0, 0])]
}

#[test]
fn a_good_crafted_image_passes_and_is_written() {
    let (o, bin) = bin_only("good", &good());
    assert!(o.status.success());
    let b = std::fs::read(&bin).unwrap();
    assert_eq!(b.len(), 0x104);
    assert_eq!(&b[..8], &[0x00, 0xF0, 0x03, 0x20, 0x09, 0x00, 0x01, 0x00]);
    assert!(stderr(&o).contains("image OK: 0x10000..0x10104"));
    // The command to run by hand, without bossac installed: the bin's absolute path, no --offset.
    let line = stdout(&o);
    assert_eq!(line.trim(), format!("bossac -d --port=PORT -U -i -e -w -v {} -R", bin.canonicalize().unwrap().display()));
    assert!(stderr(&o).contains("arduino-cli core install arduino:mbed_nano"));
    assert_eq!(tmp_files(bin.parent().unwrap()), 0);
}

fn tmp_files(d: &Path) -> usize {
    std::fs::read_dir(d).unwrap().filter(|e| e.as_ref().unwrap().file_name().to_string_lossy().ends_with(".tmp")).count()
}

/// Each bad image: exit code 1, a message naming the problem, and no .bin left behind.
fn rejected(name: &str, segs: &[Seg], msg: &str) {
    let (o, bin) = bin_only(name, segs);
    assert_eq!(o.status.code(), Some(1), "{name}");
    assert!(stderr(&o).contains(msg), "{name}: expected {msg:?}");
    assert!(!bin.exists() && tmp_files(bin.parent().unwrap()) == 0, "{name}: a .bin was left");
}

#[test]
fn images_not_at_0x10000_are_rejected() {
    // Linked for a board without bootloader, and for a SoftDevice sketch (--offset 0x16000).
    rejected("at0", &[seg(0, vectors(0x2003_F000, 0x9, 0x100))], "the image starts at 0x0, not 0x10000");
    rejected("at26000", &[seg(0x2_6000, vectors(0x2003_F000, 0x2_6009, 0x100))], "the image starts at 0x26000, not 0x10000");
    // One stray segment below 0x10000 is enough.
    let mut segs = good();
    segs.push(seg(0xF000, vec![1; 16]));
    rejected("stray-low", &segs, "the image starts at 0xF000");
}

#[test]
fn images_past_0xe0000_or_in_the_records_are_rejected() {
    let mut segs = good();
    segs.push(seg(0xD_FF00, vec![1; 0x200]));
    rejected("past-e0000", &segs, "the image ends at 0xE0100, above 0xE0000");
    // Exactly up to 0xE0000 is fine.
    let mut segs = good();
    segs.push(seg(0xD_FF00, vec![1; 0x100]));
    let (o, bin) = bin_only("to-e0000", &segs);
    assert!(o.status.success());
    assert_eq!(std::fs::metadata(&bin).unwrap().len(), 0xE_0000 - 0x1_0000);
    // Anything in the record storage, e.g. a record linked into the image.
    let mut segs = good();
    segs.push(seg(0xF_8000, vec![0; 64]));
    rejected("records", &segs, "lies in the calibration record storage 0xF8000..0x100000");
    let mut segs = good();
    segs.push(seg(0xF_9FF0, vec![0; 64]));
    rejected("records-b", &segs, "calibration record storage");
    // `.data` without a load address in flash (its LMA is its RAM address).
    let mut segs = good();
    segs.push(seg(0x2000_0000, vec![0; 16]));
    rejected("data-in-ram", &segs, "the image ends at 0x20000010, above 0xE0000");
    // Its load address in flash and run address in RAM is normal.
    let mut segs = good();
    segs.push(Seg { paddr: 0x1_0104, vaddr: 0x2000_0000, data: vec![7; 16], section: true });
    let (o, bin) = bin_only("data-lma", &segs);
    assert!(o.status.success());
    let b = std::fs::read(&bin).unwrap();
    assert_eq!((b.len(), &b[0x104..]), (0x114, &[7u8; 16][..]));
}

#[test]
fn a_bad_vector_table_is_rejected() {
    rejected("sp-flash", &[seg(0x1_0000, vectors(0x0001_0000, 0x1_0009, 0x100))], "initial stack pointer) is 0x00010000");
    rejected("sp-erased", &[seg(0x1_0000, vectors(0xFFFF_FFFF, 0x1_0009, 0x100))], "not in RAM 0x20000000..=0x20040000");
    rejected("sp-above", &[seg(0x1_0000, vectors(0x2004_0004, 0x1_0009, 0x100))], "initial stack pointer) is 0x20040004");
    // The top of RAM is the usual initial SP without flip-link.
    let (o, _) = bin_only("sp-top", &[seg(0x1_0000, vectors(0x2004_0000, 0x1_0009, 0x100))]);
    assert!(o.status.success());
    rejected("reset-even", &[seg(0x1_0000, vectors(0x2003_F000, 0x1_0008, 0x100))], "is not a Thumb address");
    rejected("reset-outside", &[seg(0x1_0000, vectors(0x2003_F000, 0x1_0101, 0x100))], "points outside the image 0x10000..0x10100");
    rejected("reset-bootloader", &[seg(0x1_0000, vectors(0x2003_F000, 0x3EF9, 0x100))], "reset vector 0x00003EF9 points outside");
    rejected("tiny", &[seg(0x1_0000, vec![0, 0, 0, 0x20])], "no vector table");
}

#[test]
fn a_bin_that_does_not_match_the_elf_or_no_elf_is_rejected() {
    // A segment without a section: llvm-objcopy leaves it out, the .bin comes out short.
    let mut segs = good();
    segs.push(Seg { paddr: 0x1_0200, vaddr: 0x1_0200, data: vec![1; 16], section: false });
    rejected("short-bin", &segs, "the .bin is 260 bytes, but the ELF's image 0x10000..0x10210 is 528 bytes");
    let d = dir("not-elf");
    let f = d.join("x.elf");
    std::fs::write(&f, b"not an ELF").unwrap();
    let o = run(&["--elf", f.to_str().unwrap(), "--bin-only", d.join("x.bin").to_str().unwrap()], &d, &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("not a 32-bit ELF file"));
    let o = run(&["--elf", d.join("missing.elf").to_str().unwrap(), "--bin-only", d.join("x.bin").to_str().unwrap()], &d, &[]);
    assert_eq!(o.status.code(), Some(1));
}

#[test]
fn usage_errors_exit_2_and_help_explains() {
    let d = dir("usage");
    assert_eq!(run(&[], &d, &[]).status.code(), Some(2));
    assert_eq!(run(&["--bogus"], &d, &[]).status.code(), Some(2));
    assert_eq!(run(&["--port"], &d, &[]).status.code(), Some(2));
    let h = run(&["--help"], &d, &[]);
    assert!(h.status.success());
    for s in [
        "double-tap",
        "bossac -d --port=PORT -U -i -e -w -v",
        "arduino-cli core install arduino:mbed_nano",
        "0xE0000",
        "0xF8000",
        "--dry-run",
    ] {
        assert!(stdout(&h).contains(s), "--help lacks {s:?}");
    }
}

/// The real release firmware, built by the tool itself (the only firmware build of this file).
#[test]
fn the_release_firmware_passes_and_its_bin_starts_with_the_vector_table() {
    let d = dir("firmware");
    let bin = d.join("gyrocal-fw.bin");
    let o = run(&["--bin-only", bin.to_str().unwrap()], &d, &[("CARGO_TERM_COLOR", "never")]);
    assert!(o.status.success(), "flash-usb --bin-only failed");
    let b = std::fs::read(&bin).unwrap();
    let elf_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../target/thumbv7em-none-eabihf/release/gyrocal-fw");
    let data = std::fs::read(elf_path).unwrap();
    let h = object::elf::FileHeader32::<object::LittleEndian>::parse(&*data).unwrap();
    let e = object::LittleEndian;
    let secs = h.sections(e, &*data).unwrap();
    let vt = secs.iter().find(|s| secs.section_name(e, s).unwrap() == b".vector_table").expect(".vector_table");
    assert_eq!(vt.sh_addr(e), 0x1_0000);
    let table = vt.data(e, &*data).unwrap();
    assert!(table.len() >= 16 * 4, "a Cortex-M vector table has at least 16 words");
    assert_eq!(&b[..table.len()], table, "the .bin starts with .vector_table");
    let w = |i: usize| u32::from_le_bytes(b[4 * i..4 * i + 4].try_into().unwrap());
    assert!((0x2000_0000..=0x2004_0000).contains(&w(0)));
    assert_eq!(w(1) & 1, 1);
    assert_eq!(u64::from(w(1) & !1), u64::from(h.e_entry(e) & !1), "reset vector = ELF entry (Reset)");
    assert!(b.len() as u64 <= 0xE_0000 - 0x1_0000);
    // The whole .text is in the bin at its address.
    let text = secs.iter().find(|s| secs.section_name(e, s).unwrap() == b".text").unwrap();
    let off = (text.sh_addr(e) - 0x1_0000) as usize;
    assert_eq!(&b[off..off + text.sh_size(e) as usize], text.data(e, &*data).unwrap());
}

/// A fake bossac in `d`: records its arguments, one a line, in `d/args.txt`, exits `code`.
fn fake_bossac(d: &Path, rel: &str, code: i32) -> PathBuf {
    let p = d.join(rel);
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    let script = format!("#!/bin/sh\nfor a in \"$@\"; do printf '%s\\n' \"$a\"; done > '{}'\nexit {code}\n", d.join("args.txt").display());
    let _g = SPAWN.lock().unwrap_or_else(|e| e.into_inner());
    std::fs::write(&p, script).unwrap();
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
    p
}

fn recorded(d: &Path) -> Vec<String> {
    std::fs::read_to_string(d.join("args.txt")).unwrap().lines().map(String::from).collect()
}

fn crafted(d: &Path) -> PathBuf {
    let e = d.join("fw.elf");
    std::fs::write(&e, elf(&good())).unwrap();
    e
}

fn expected(port: &str, bin: &Path) -> Vec<String> {
    let bin = bin.canonicalize().unwrap().display().to_string();
    ["-d", &format!("--port={port}"), "-U", "-i", "-e", "-w", "-v", &bin, "-R"].map(String::from).to_vec()
}

#[test]
fn bossac_gets_arduinos_arguments_plus_verify() {
    let d = dir("bossac");
    let bossac = fake_bossac(&d, "bin/bossac", 0);
    let e = crafted(&d);
    let bin = d.join("out/fw.bin");
    // A port that is no /dev/ name is passed unchanged (it exists: no waiting).
    let port = d.join("ttyACM7");
    std::fs::write(&port, b"").unwrap();
    let base = ["--elf", e.to_str().unwrap(), "--bossac", bossac.to_str().unwrap()];
    let o = run(&[&base[..], &["--port", port.to_str().unwrap(), "--bin-only", bin.to_str().unwrap()]].concat(), &d, &[]);
    // --bin-only never runs bossac, it prints the command.
    assert!(o.status.success());
    assert!(!d.join("args.txt").exists());
    assert_eq!(stdout(&o).trim(), format!("{} {}", bossac.display(), expected(port.to_str().unwrap(), &bin).join(" ")));
    let base = [&base[..], &["--out", bin.to_str().unwrap()]].concat();
    let o = run(&[&base[..], &["--port", port.to_str().unwrap()]].concat(), &d, &[]);
    assert!(o.status.success());
    assert_eq!(recorded(&d), expected(port.to_str().unwrap(), &bin));
    assert!(stderr(&o).contains("double-tap"));
    // /dev/NAME is passed bare, as the Arduino IDE does ({serial.port.file}); /dev/null exists.
    let o = run(&[&base[..], &["--port", "/dev/null"]].concat(), &d, &[]);
    assert!(o.status.success());
    assert_eq!(recorded(&d), expected("null", &bin));
    // Deeper /dev paths stay whole.
    let o = run(&[&base[..], &["--port", "/dev/serial/by-id/x", "--dry-run"]].concat(), &d, &[]);
    assert!(stdout(&o).contains(" --port=/dev/serial/by-id/x "));
}

#[test]
fn dry_run_prints_and_does_not_run() {
    let d = dir("dry");
    let bossac = fake_bossac(&d, "bossac", 0);
    let e = crafted(&d);
    let bin = d.join("fw.bin");
    let args = ["--elf", e.to_str().unwrap(), "--port", "/dev/ttyACM0", "--dry-run", "--out", bin.to_str().unwrap()];
    let o = run(&args, &d, &[("BOSSAC", bossac.to_str().unwrap())]);
    assert!(o.status.success());
    assert!(!d.join("args.txt").exists(), "--dry-run ran bossac");
    assert_eq!(stdout(&o).trim(), format!("{} {}", bossac.display(), expected("ttyACM0", &bin).join(" ")));
}

#[test]
fn bossac_is_found_via_env_path_and_arduino15() {
    let d = dir("find");
    let e = crafted(&d);
    let bin = d.join("fw.bin");
    let args = ["--elf", e.to_str().unwrap(), "--port", "/dev/null", "--dry-run", "--out", bin.to_str().unwrap()];
    // Arduino15 under HOME (Linux layout).
    let a15 = fake_bossac(&d, ".arduino15/packages/arduino/tools/bossac/1.9.1-arduino2/bossac", 0);
    let first = |o: &Output| stdout(o).split(' ').next().unwrap_or_default().to_string();
    assert_eq!(first(&run(&args, &d, &[])), a15.display().to_string());
    // ARDUINO_DIRECTORIES_DATA before HOME's.
    let data = fake_bossac(&d, "data/packages/arduino/tools/bossac/1.9.1-arduino2/bossac", 0);
    assert_eq!(first(&run(&args, &d, &[("ARDUINO_DIRECTORIES_DATA", d.join("data").to_str().unwrap())])), data.display().to_string());
    // PATH before Arduino15.
    let on_path = fake_bossac(&d, "pathdir/bossac", 0);
    let path = format!("{}:{}", d.join("pathdir").display(), std::env::var("PATH").unwrap_or_default());
    assert_eq!(first(&run(&args, &d, &[("PATH", &path)])), on_path.display().to_string());
    // BOSSAC before PATH, --bossac before BOSSAC.
    let env = fake_bossac(&d, "env/bossac", 0);
    assert_eq!(first(&run(&args, &d, &[("PATH", &path), ("BOSSAC", env.to_str().unwrap())])), env.display().to_string());
    let explicit = fake_bossac(&d, "explicit/bossac", 0);
    let o = run(&[&args[..], &["--bossac", explicit.to_str().unwrap()]].concat(), &d, &[("BOSSAC", env.to_str().unwrap())]);
    assert_eq!(first(&o), explicit.display().to_string());
}

#[test]
fn without_bossac_the_bin_is_written_and_the_way_to_get_it_is_shown() {
    let d = dir("nobossac");
    let e = crafted(&d);
    let bin = d.join("fw.bin");
    let o = run(&["--elf", e.to_str().unwrap(), "--port", "/dev/ttyACM0", "--out", bin.to_str().unwrap()], &d, &[]);
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(std::fs::metadata(&bin).unwrap().len(), 0x104, "the .bin is written for a manual upload");
    let err = stderr(&o);
    assert!(err.contains("bossac not found"));
    assert!(err.contains("arduino-cli core install arduino:mbed_nano"));
    assert!(err.contains(&format!("bossac {} -R", expected("ttyACM0", &bin)[..8].join(" "))), "the command to run by hand");
    assert!(err.contains(".arduino15/packages/arduino/tools/bossac/1.9.1-arduino2/bossac"));
    // A --bossac that does not exist is an error too.
    let o = run(
        &["--elf", e.to_str().unwrap(), "--port", "/dev/ttyACM0", "--out", bin.to_str().unwrap(), "--bossac", "/nonexistent/bossac"],
        &d,
        &[],
    );
    assert_eq!(o.status.code(), Some(1));
}

#[test]
fn bossac_failures_are_forwarded() {
    let d = dir("fail");
    let e = crafted(&d);
    let port = d.join("ttyACM0");
    std::fs::write(&port, b"").unwrap();
    let bin = d.join("fw.bin");
    let e = e.to_str().unwrap();
    let base = ["--elf", e, "--out", bin.to_str().unwrap()];
    for (code, msg) in [(1, "the board was not changed"), (2, "verify failed")] {
        let b = fake_bossac(&d, &format!("b{code}/bossac"), code);
        let o = run(&[&base[..], &["--port", port.to_str().unwrap(), "--bossac", b.to_str().unwrap()]].concat(), &d, &[]);
        assert_eq!(o.status.code(), Some(code));
        assert!(stderr(&o).contains(msg), "exit {code}: expected {msg:?}");
    }
    // A port that never appears: nothing is run, exit 1.
    let b = fake_bossac(&d, "b0/bossac", 0);
    let _ = std::fs::remove_file(d.join("args.txt"));
    let gone = d.join("ttyACM9");
    let o = run(&[&base[..], &["--port", gone.to_str().unwrap(), "--bossac", b.to_str().unwrap(), "--wait", "1"]].concat(), &d, &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("did not appear within 1 s. The board was not changed"));
    assert!(!d.join("args.txt").exists());
}

#[test]
fn the_1200_baud_touch_sets_1200_baud_and_falls_back_to_the_double_tap() {
    let d = dir("touch");
    let bossac = fake_bossac(&d, "bin/bossac", 0);
    let (e, bin) = (crafted(&d), d.join("fw.bin"));
    // A pseudo-terminal takes the touch (its DTR ioctl fails: ignored) but never resets.
    let (_master, slave) = serialport::TTYPort::pair().unwrap();
    let port = serialport::SerialPort::name(&slave).unwrap();
    let args = ["--elf", e.to_str().unwrap(), "--bossac", bossac.to_str().unwrap(), "--out", bin.to_str().unwrap(), "--port", &port];
    let o = run(&args, &d, &[]);
    assert!(o.status.success());
    assert_eq!(serialport::SerialPort::baud_rate(&slave).unwrap(), 1200, "the touch's line coding");
    let err = stderr(&o);
    assert!(err.contains(&format!("1200-baud touch on {port}")), "{err}");
    assert!(err.contains("did not go away within 3 s of the 1200-baud touch") && err.contains("double-tap"), "{err}");
    assert_eq!(recorded(&d), expected(&port, &bin));
}

#[test]
fn after_the_touch_bossac_waits_for_the_port_to_come_back() {
    let d = dir("touch-reset");
    let bossac = fake_bossac(&d, "bin/bossac", 0);
    let (e, bin) = (crafted(&d), d.join("fw.bin"));
    // The board's port: a link to a pseudo-terminal that goes away once touched at 1200 baud
    // and comes back, as the board re-enumerates in its bootloader.
    let (_master, slave) = serialport::TTYPort::pair().unwrap();
    let pts = serialport::SerialPort::name(&slave).unwrap();
    let port = d.join("ttyACM5");
    std::os::unix::fs::symlink(&pts, &port).unwrap();
    let board = {
        let port = port.clone();
        std::thread::spawn(move || {
            let t0 = std::time::Instant::now();
            while serialport::SerialPort::baud_rate(&slave).unwrap() != 1200 {
                assert!(t0.elapsed().as_secs() < 60, "no touch");
                std::thread::sleep(std::time::Duration::from_millis(20));
            }
            std::fs::remove_file(&port).unwrap();
            std::thread::sleep(std::time::Duration::from_millis(400));
            std::os::unix::fs::symlink(&pts, &port).unwrap();
        })
    };
    let port = port.to_str().unwrap();
    let args = ["--elf", e.to_str().unwrap(), "--bossac", bossac.to_str().unwrap(), "--out", bin.to_str().unwrap(), "--port", port];
    let o = run(&args, &d, &[]);
    board.join().unwrap();
    assert!(o.status.success());
    let err = stderr(&o);
    assert!(err.contains(&format!("the bootloader's port: {port}")) && !err.contains("double-tap the RESET"), "{err}");
    assert_eq!(recorded(&d), expected(port, &bin));
}
