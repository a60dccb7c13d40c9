//! `cargo flash-usb --port PORT`: flashes the release firmware over the USB cable through the
//! stock Arduino (SAM-BA) bootloader with Arduino's bossac, no SWD probe needed. `--help` tells
//! everything; the reasons behind each check are in the comments below.
//!
//! Exit codes: 0 done, 1 build, image check, missing tool or upload failed (bossac's own
//! non-zero exit code is forwarded: 1 error, 2 verify failed), 2 usage.

use calib::firmware::{self, root};
use clap::{ArgGroup, Parser};
use object::elf::{FileHeader32, EM_ARM, PT_LOAD};
use object::read::elf::{FileHeader, ProgramHeader};
use object::Endianness;
use std::io::{BufRead, IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};
use std::time::{Duration, Instant};

/// What `--help` says after the options.
const ABOUT: &str = "\
What it does:
  1. builds the release firmware: cargo build --release -p gyrocal-fw [--features F]
     (ELF target/thumbv7em-none-eabihf/release/gyrocal-fw)
  2. makes the flat binary with the toolchain's llvm-objcopy -O binary (the llvm-tools
     component): target/gyrocal-fw.bin, or OUT.bin with --bin-only
  3. checks the image before anything reaches the board: the loadable segments (by load
     address) start at exactly 0x10000, where the bootloader writes every upload, and end at
     or below 0xE0000 (the updated Arduino bootloader lives there, the calibration records at
     0xF8000/0xF9000 must never be in the image); the first word is an initial stack pointer
     in RAM (0x20000000..=0x20040000), the reset vector a Thumb address inside the image, the
     .bin as long as the image
  4. finds bossac (Arduino's 1.9.1-arduino2): --bossac PATH, else $BOSSAC, else bossac on
     PATH, else the Arduino15 data directory ($ARDUINO_DIRECTORIES_DATA, Linux ~/.arduino15,
     macOS ~/Library/Arduino15, Windows %LOCALAPPDATA%\\Arduino15) under
     packages/arduino/tools/bossac/1.9.1-arduino2/. To install it:
         arduino-cli core install arduino:mbed_nano
     (or the IDE's Boards Manager: \"Arduino Mbed OS Nano Boards\"). A bossac built from
     upstream BOSSA (e.g. Debian's bossa-cli) may not know the nRF52840: use Arduino's.
  5. puts the board in its bootloader as the Arduino IDE does for it (use_1200bps_touch,
     wait_for_upload_port): opens PORT at 1200 baud and drops DTR, which makes the gyrocal
     firmware reset into the bootloader's serial mode, then waits (up to --wait) for the
     bootloader's port (a new one, or PORT back). If PORT cannot be opened as a serial port, or does not go away within
     3 s (another firmware, or the bootloader already runs), it asks you to double-tap the
     board's RESET button instead: the orange LED (L) fades in and out while the bootloader
     runs. Then it runs, as the Arduino IDE does, plus -v (verify):
         bossac -d --port=PORT -U -i -e -w -v target/gyrocal-fw.bin -R
     PORT is the bootloader's serial port (Linux /dev/ttyACM0, macOS /dev/cu.usbmodemXXXX,
     Windows COM9); it is passed bare like the IDE does (ttyACM0, cu.usbmodemXXXX, COM9).
     It may differ from the port the board had before the reset. -R resets the board
     into the new firmware.

The upload never touches the calibration records: the bootloader writes (and erases) only
the 4 KiB pages of the image, from 0x10000 on; its erase command (-e) erases nothing.";

/// Where the stock bootloader puts byte 0 of every upload: it adds 0x10000 to each write
/// address (bossac is run without --offset), and jumps to the vector table there.
const APP_START: u64 = 0x1_0000;
/// Highest end of the image: the updated Arduino bootloader starts at 0xE0000 (and refuses
/// writes reaching past it); the calibration records at 0xF8000/0xF9000 are above.
const APP_END: u64 = 0xE_0000;
/// The calibration record pages (0xF8000, 0xF9000) and the rest of the storage region.
const RECORDS: std::ops::Range<u64> = 0xF_8000..0x10_0000;
/// Plausible initial stack pointers: the nRF52840's 256 KiB of RAM (the top included).
const STACK: std::ops::RangeInclusive<u32> = 0x2000_0000..=0x2004_0000;
/// The bossac version Arduino's mbed_nano platform pins.
const BOSSAC_VERSION: &str = "1.9.1-arduino2";

/// A loadable part of the image: load (physical) address and file size.
#[derive(Debug, Clone, Copy)]
struct Segment {
    paddr: u64,
    vaddr: u64,
    size: u64,
}

/// The image's extent in flash, from the ELF: `start..end`.
#[derive(Debug, Clone, Copy)]
struct Extent {
    start: u64,
    end: u64,
}

fn loadable_segments(elf: &[u8]) -> Result<Vec<Segment>, String> {
    let h = FileHeader32::<Endianness>::parse(elf).map_err(|e| format!("not a 32-bit ELF file: {e}"))?;
    let e = h.endian().map_err(|e| format!("bad ELF header: {e}"))?;
    if e != Endianness::Little || h.e_machine(e) != EM_ARM {
        return Err(format!("not a little-endian ARM ELF (e_machine {}): not a firmware for the nRF52840", h.e_machine(e)));
    }
    let phs = h.program_headers(e, elf).map_err(|e| format!("bad ELF program headers: {e}"))?;
    Ok(phs
        .iter()
        .filter(|p| p.p_type(e) == PT_LOAD && p.p_filesz(e) > 0)
        .map(|p| Segment { paddr: p.p_paddr(e).into(), vaddr: p.p_vaddr(e).into(), size: p.p_filesz(e).into() })
        .collect())
}

/// The checks on the ELF: where its bytes will be loaded, by physical address (LMA: `.data`'s
/// initial values are stored in flash, their RAM address does not matter here).
fn check_elf(elf: &[u8]) -> Result<Extent, String> {
    let segs = loadable_segments(elf)?;
    if segs.is_empty() {
        return Err("the ELF has no loadable segment with contents".into());
    }
    let show = |s: &Segment| format!("0x{:X}..0x{:X} (0x{:X} bytes, run address 0x{:X})", s.paddr, s.paddr + s.size, s.size, s.vaddr);
    if let Some(s) = segs.iter().find(|s| s.paddr < RECORDS.end && s.paddr + s.size > RECORDS.start) {
        return Err(format!(
            "a loadable segment lies in the calibration record storage 0xF8000..0x100000: {}; uploading it would \
             overwrite the calibration records. Nothing may be linked there (memory.x)",
            show(s)
        ));
    }
    let start = segs.iter().map(|s| s.paddr).min().unwrap_or(0);
    let end = segs.iter().map(|s| s.paddr + s.size).max().unwrap_or(0);
    if start != APP_START {
        let s = segs.iter().find(|s| s.paddr == start).map(show).unwrap_or_default();
        return Err(format!(
            "the image starts at 0x{start:X}, not 0x10000 (segment {s}): the Arduino bootloader writes an upload \
             at 0x10000 + its offset (bossac runs without --offset) and starts the application at 0x10000. \
             memory.x must put FLASH at ORIGIN = 0x10000"
        ));
    }
    if end > APP_END {
        let s = segs.iter().find(|s| s.paddr + s.size == end).map(show).unwrap_or_default();
        return Err(format!(
            "the image ends at 0x{end:X}, above 0xE0000 (segment {s}): the updated Arduino bootloader lives at \
             0xE0000 (and refuses such writes), the calibration records at 0xF8000. memory.x must end FLASH at or \
             below 0xE0000 (LENGTH <= 0xD0000) and every loadable section must be in it"
        ));
    }
    Ok(Extent { start, end })
}

fn word(bin: &[u8], i: usize) -> u32 {
    u32::from_le_bytes([bin[i], bin[i + 1], bin[i + 2], bin[i + 3]])
}

/// The checks on the flat binary, which is byte 0 = address 0x10000.
fn check_bin(bin: &[u8], x: Extent) -> Result<(), String> {
    let want = x.end - x.start;
    if bin.len() as u64 != want {
        return Err(format!(
            "the .bin is {} bytes, but the ELF's image 0x{:X}..0x{:X} is {want} bytes: llvm-objcopy left something \
             out or added something",
            bin.len(),
            x.start,
            x.end
        ));
    }
    if bin.len() < 8 {
        return Err(format!("the image is only {} bytes: no vector table", bin.len()));
    }
    let sp = word(bin, 0);
    if !STACK.contains(&sp) {
        return Err(format!(
            "the first word (initial stack pointer) is 0x{sp:08X}, not in RAM 0x20000000..=0x20040000: the image \
             does not start with a Cortex-M vector table"
        ));
    }
    let reset = word(bin, 4);
    if reset & 1 == 0 {
        return Err(format!("the reset vector 0x{reset:08X} is not a Thumb address (bit 0 clear): not a Cortex-M vector table"));
    }
    let pc = u64::from(reset & !1);
    if !(x.start..x.end).contains(&pc) {
        return Err(format!("the reset vector 0x{reset:08X} points outside the image 0x{:X}..0x{:X}", x.start, x.end));
    }
    Ok(())
}

/// Builds the release firmware with `features` (comma-separated) and returns its ELF's path.
fn build_firmware(features: Option<&str>) -> Result<PathBuf, String> {
    eprintln!(
        "flash-usb: building the firmware: cargo build --release -p gyrocal-fw{}",
        features.map(|f| format!(" --features {f}")).unwrap_or_default()
    );
    let features: Vec<&str> = features.map(|f| f.split(',').map(str::trim).filter(|f| !f.is_empty()).collect()).unwrap_or_default();
    firmware::build(&features)
}

/// Runs `rustc ARGS` (the workspace's pinned toolchain) and returns its stdout.
fn rustc(args: &[&str]) -> Result<String, String> {
    let rustc = std::env::var_os("RUSTC").unwrap_or_else(|| "rustc".into());
    let out = Command::new(&rustc).args(args).current_dir(root()).output().map_err(|e| format!("cannot run rustc: {e}"))?;
    if !out.status.success() {
        return Err(format!("rustc {} failed: {}", args.join(" "), String::from_utf8_lossy(&out.stderr).trim()));
    }
    Ok(String::from_utf8_lossy(&out.stdout).trim().to_string())
}

/// `$(rustc --print sysroot)/lib/rustlib/<host>/bin/llvm-objcopy`, as `.ci/firmware-check`
/// finds llvm-size (what `cargo objcopy` runs).
fn llvm_objcopy() -> Result<PathBuf, String> {
    let sysroot = rustc(&["--print", "sysroot"])?;
    let vv = rustc(&["-vV"])?;
    let host = vv.lines().find_map(|l| l.strip_prefix("host: ")).ok_or("rustc -vV printed no host line")?;
    let p = Path::new(&sysroot).join("lib/rustlib").join(host).join("bin").join(format!("llvm-objcopy{}", std::env::consts::EXE_SUFFIX));
    if p.is_file() {
        Ok(p)
    } else {
        Err(format!("{} not found: install the llvm-tools component (rustup component add llvm-tools)", p.display()))
    }
}

/// ELF -> checks -> `llvm-objcopy -O binary` into a temporary file -> checks -> `out`. A
/// failed check leaves no .bin behind.
fn make_bin(elf_path: &Path, out: &Path) -> Result<(), String> {
    let elf = std::fs::read(elf_path).map_err(|e| format!("{}: {e}", elf_path.display()))?;
    let x = check_elf(&elf).map_err(|e| format!("{}: {e}", elf_path.display()))?;
    if let Some(d) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(d).map_err(|e| format!("{}: {e}", d.display()))?;
    }
    let mut tmp = out.as_os_str().to_owned();
    tmp.push(format!(".{}.tmp", std::process::id()));
    let tmp = PathBuf::from(tmp);
    let objcopy = llvm_objcopy()?;
    let o = Command::new(&objcopy)
        .args(["-O", "binary"])
        .arg(elf_path)
        .arg(&tmp)
        .output()
        .map_err(|e| format!("cannot run {}: {e}", objcopy.display()))?;
    if !o.status.success() {
        let _ = std::fs::remove_file(&tmp);
        return Err(format!("llvm-objcopy failed ({}): {}", o.status, String::from_utf8_lossy(&o.stderr).trim()));
    }
    let bin = std::fs::read(&tmp).map_err(|e| format!("{}: {e}", tmp.display()))?;
    if let Err(e) = check_bin(&bin, x) {
        let _ = std::fs::remove_file(&tmp);
        return Err(format!("{}: {e}", elf_path.display()));
    }
    std::fs::rename(&tmp, out).map_err(|e| format!("{}: {e}", out.display()))?;
    eprintln!(
        "flash-usb: image OK: 0x{:X}..0x{:X} ({} bytes, {} pages of 4 KiB), SP 0x{:08X}, reset 0x{:08X}; wrote {}",
        x.start,
        x.end,
        bin.len(),
        bin.len().div_ceil(4096),
        word(&bin, 0),
        word(&bin, 4),
        out.display()
    );
    Ok(())
}

fn on_path(name: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path).map(|d| d.join(format!("{name}{}", std::env::consts::EXE_SUFFIX))).find(|p| p.is_file())
}

/// The Arduino15 data directories where `arduino-cli core install arduino:mbed_nano` puts
/// bossac (arduino-cli's defaults; `ARDUINO_DIRECTORIES_DATA` overrides them).
fn arduino15_candidates() -> Vec<PathBuf> {
    let mut dirs = Vec::new();
    if let Some(d) = std::env::var_os("ARDUINO_DIRECTORIES_DATA").filter(|d| !d.is_empty()) {
        dirs.push(PathBuf::from(d));
    }
    if cfg!(windows) {
        if let Some(d) = std::env::var_os("LOCALAPPDATA") {
            dirs.push(Path::new(&d).join("Arduino15"));
        }
    } else if let Some(h) = std::env::var_os("HOME") {
        let h = PathBuf::from(h);
        dirs.push(if cfg!(target_os = "macos") { h.join("Library/Arduino15") } else { h.join(".arduino15") });
    }
    let exe = format!("bossac{}", std::env::consts::EXE_SUFFIX);
    dirs.into_iter().map(|d| d.join("packages/arduino/tools/bossac").join(BOSSAC_VERSION).join(&exe)).collect()
}

/// `--bossac`, else `$BOSSAC`, else `bossac` on PATH, else Arduino15. `Err` lists where it looked.
fn find_bossac(explicit: Option<&Path>) -> Result<PathBuf, String> {
    if let Some(p) = explicit {
        return if p.is_file() { Ok(p.to_path_buf()) } else { Err(format!("--bossac {}: no such file", p.display())) };
    }
    if let Some(b) = std::env::var_os("BOSSAC").filter(|b| !b.is_empty()) {
        let p = PathBuf::from(&b);
        return if p.is_file() { Ok(p) } else { on_path(&p.to_string_lossy()).ok_or(format!("BOSSAC={}: no such file", p.display())) };
    }
    if let Some(p) = on_path("bossac") {
        return Ok(p);
    }
    let cands = arduino15_candidates();
    if let Some(p) = cands.iter().find(|p| p.is_file()) {
        return Ok(p.clone());
    }
    let looked: Vec<String> = cands.iter().map(|p| format!("  {}", p.display())).collect();
    Err(format!("bossac not found (not given by --bossac or $BOSSAC, not on PATH, not in:\n{})", looked.join("\n")))
}

/// The port as Arduino's platform.txt passes it: `--port={serial.port.file}`, the port's bare
/// file name (the IDE log in the research shows `--port=ttyACM0`; macOS `cu.usbmodem14201`,
/// Windows `COM9`). bossac itself opens the name as given and, if that fails, `"/dev/" + name`
/// (BOSSA PosixSerialPort.cpp), and on Windows always prepends `\\.\` (WinSerialPort.cpp), so
/// `/dev/ttyACM0` → `ttyACM0` and `\\.\COM9` → `COM9` is what the IDE does and what bossac
/// expects. Other paths (`/dev/serial/by-id/...`, `./x`) are passed unchanged: bossac opens
/// them as given.
fn bossac_port(port: &str) -> String {
    for prefix in ["/dev/", r"\\.\"] {
        if let Some(name) = port.strip_prefix(prefix) {
            if !name.is_empty() && !name.contains(['/', '\\']) {
                return name.to_string();
            }
        }
    }
    port.to_string()
}

/// Arduino's `tools.bossac.upload.pattern` with `-d` (upload.verbose) and `-v` (verify) added.
/// No `--offset`: offset 0 is 0x10000 on this bootloader (0x16000 is for SoftDevice sketches).
fn bossac_args(port: &str, bin: &Path) -> Vec<String> {
    let mut a: Vec<String> = vec!["-d".into(), format!("--port={}", bossac_port(port))];
    a.extend(["-U", "-i", "-e", "-w", "-v"].map(String::from));
    a.push(bin.display().to_string());
    a.push("-R".into());
    a
}

/// A command line to copy (POSIX shell quoting; fine for cmd.exe unless a path has spaces).
fn shell_line(prog: &Path, args: &[String]) -> String {
    let q = |s: &str| {
        if !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || "-_=./:,+@%\\".contains(c)) {
            s.to_string()
        } else {
            format!("'{}'", s.replace('\'', r"'\''"))
        }
    };
    std::iter::once(q(&prog.display().to_string())).chain(args.iter().map(|a| q(a))).collect::<Vec<_>>().join(" ")
}

const GET_BOSSAC: &str = "Get Arduino's bossac 1.9.1-arduino2 with\n    arduino-cli core install arduino:mbed_nano\n\
     (or the Arduino IDE's Boards Manager: \"Arduino Mbed OS Nano Boards\"), or pass --bossac PATH / set BOSSAC.";

/// The device file to wait for after the reset (POSIX only; Windows COM ports are no files).
fn port_device(port: &str) -> Option<PathBuf> {
    if cfg!(windows) {
        return None;
    }
    let p = Path::new(port);
    Some(if p.is_absolute() || port.contains('/') { p.to_path_buf() } else { Path::new("/dev").join(port) })
}

fn wait_for_port(port: &str, wait: Duration) -> Result<(), String> {
    let Some(dev) = port_device(port) else { return Ok(()) };
    let t0 = Instant::now();
    let mut said = false;
    while !dev.exists() {
        if t0.elapsed() >= wait {
            return Err(format!(
                "{} did not appear within {} s. The board was not changed. Double-tap RESET (the orange LED must fade \
                 in and out), look for the new port (ls /dev/ttyACM* /dev/cu.usbmodem*), and run again with it",
                dev.display(),
                wait.as_secs()
            ));
        }
        if !said {
            eprintln!("flash-usb: waiting up to {} s for {} ...", wait.as_secs(), dev.display());
            said = true;
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    Ok(())
}

/// How long the port may take to go away after the 1200-baud touch (the board resets).
const TOUCH_RESET: Duration = Duration::from_secs(3);
/// How long to let the bootloader's port settle once it is back (udev sets its permissions).
const PORT_SETTLE: Duration = Duration::from_millis(500);

/// The serial ports the system lists (none if it cannot list them).
fn listed_ports() -> Vec<String> {
    serialport::available_ports().map(|v| v.into_iter().map(|p| p.port_name).collect()).unwrap_or_default()
}

/// Whether `port` exists: its device file (POSIX), or listed (Windows).
fn present(port: &str) -> bool {
    match port_device(port) {
        Some(dev) => dev.exists(),
        None => listed_ports().iter().any(|p| p == port),
    }
}

/// After the touch, as Arduino's wait_for_upload_port: the bootloader's port is one not listed
/// `before` the touch, or `port` itself back after going away. Err: `port` did not go away
/// within [`TOUCH_RESET`] (the board did not reset), or no port came within `wait` more.
fn wait_after_touch(port: &str, before: &[String], wait: Duration) -> Result<String, String> {
    let t0 = Instant::now();
    let mut gone = false;
    loop {
        let new = listed_ports().into_iter().find(|p| !before.contains(p));
        let here = present(port);
        gone |= !here;
        if let Some(p) = new.or_else(|| (gone && here).then(|| port.to_string())) {
            std::thread::sleep(PORT_SETTLE);
            return Ok(p);
        }
        if !gone && t0.elapsed() >= TOUCH_RESET {
            return Err(format!(
                "{port} did not go away within {} s of the 1200-baud touch: the board did not reset (another firmware \
                 than gyrocal's, or its bootloader already runs)",
                TOUCH_RESET.as_secs()
            ));
        }
        if t0.elapsed() >= TOUCH_RESET + wait {
            return Err(format!("no bootloader port appeared within {} s of the 1200-baud touch", (TOUCH_RESET + wait).as_secs()));
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The 1200-baud touch and the wait for the bootloader's port: that port, or `None` (the
/// reason said) if the board must be put in its bootloader by hand.
fn reset_into_bootloader(port: &str, wait: Duration) -> Option<String> {
    let before = listed_ports();
    let r = calib::port::touch_1200(port).map_err(|e| format!("{port}: {e}")).and_then(|()| {
        eprintln!("flash-usb: 1200-baud touch on {port}: the board resets into its bootloader ...");
        wait_after_touch(port, &before, wait)
    });
    match r {
        Ok(p) => {
            eprintln!("flash-usb: the bootloader's port: {p}");
            Some(p)
        }
        Err(e) => {
            eprintln!("flash-usb: no reset by the 1200-baud touch: {e}");
            None
        }
    }
}

/// cargo flash-usb: flash the firmware over USB through the Arduino bootloader (no SWD probe).
#[derive(Parser, Debug)]
#[command(name = "gyrocal-flash", after_help = ABOUT)]
#[command(group(ArgGroup::new("target").required(true).multiple(true).args(["port", "bin_only"])))]
struct Args {
    /// The board's serial port (the gyrocal firmware's, or the bootloader's); flash the board.
    #[arg(long)]
    port: Option<String>,
    /// Only build, check and write OUT.bin, and print the bossac command.
    #[arg(long, value_name = "OUT", conflicts_with = "out")]
    bin_only: Option<PathBuf>,
    /// Where to write the .bin when flashing (default target/gyrocal-fw.bin).
    #[arg(long, value_name = "PATH")]
    out: Option<PathBuf>,
    /// Cargo features of the firmware (e.g. tilt-servo,odr952).
    #[arg(long, value_name = "F", conflicts_with = "elf")]
    features: Option<String>,
    /// The bossac binary to use.
    #[arg(long, value_name = "PATH")]
    bossac: Option<PathBuf>,
    /// Skip the build, use this ELF (for tests and prebuilt images).
    #[arg(long, value_name = "PATH")]
    elf: Option<PathBuf>,
    /// Do everything but run bossac: print its command line.
    #[arg(long)]
    dry_run: bool,
    /// How long to wait for PORT to appear after the reset (s).
    #[arg(long = "wait", value_name = "SECS", default_value_t = 30)]
    wait_s: u64,
}

fn fail(msg: impl std::fmt::Display) -> ExitCode {
    eprintln!("flash-usb: error: {msg}");
    ExitCode::from(1)
}

fn main() -> ExitCode {
    let a = Args::parse_from(calib::cli_args());
    let wait = Duration::from_secs(a.wait_s);
    let elf = match &a.elf {
        Some(p) => p.clone(),
        None => match build_firmware(a.features.as_deref()) {
            Ok(p) => p,
            Err(e) => return fail(e),
        },
    };
    let bin = a.bin_only.clone().or(a.out.clone()).unwrap_or_else(|| firmware::target_dir().join("gyrocal-fw.bin"));
    if let Err(e) = make_bin(&elf, &bin) {
        return fail(e);
    }
    // bossac reads the file after the user may have changed directory in between: absolute.
    let bin = bin.canonicalize().unwrap_or(bin);
    let bossac = find_bossac(a.bossac.as_deref());
    let shown_port = a.port.clone().unwrap_or_else(|| "PORT".into());
    let line = |prog: &Path| shell_line(prog, &bossac_args(&shown_port, &bin));

    if a.bin_only.is_some() {
        match &bossac {
            Ok(b) => println!("{}", line(b)),
            Err(e) => {
                eprintln!("flash-usb: {e}\n{GET_BOSSAC}");
                println!("{}", line(Path::new("bossac")));
            }
        }
        eprintln!("flash-usb: to flash: double-tap RESET (the orange LED fades in and out), then run the line above");
        return ExitCode::SUCCESS;
    }
    let port = a.port.clone().unwrap_or_default();
    let bossac = match bossac {
        Ok(b) => b,
        Err(e) => {
            eprintln!("flash-usb: error: {e}\n{GET_BOSSAC}");
            eprintln!("flash-usb: {} is written; with bossac, double-tap RESET and run:\n    {}", bin.display(), line(Path::new("bossac")));
            return ExitCode::from(1);
        }
    };
    let args = bossac_args(&port, &bin);
    if a.dry_run {
        println!("{}", shell_line(&bossac, &args));
        return ExitCode::SUCCESS;
    }

    let args = match reset_into_bootloader(&port, wait) {
        Some(p) => bossac_args(&p, &bin),
        None => {
            eprintln!(
                "flash-usb: put the board in its bootloader: double-tap the RESET button (two presses within half a second).\n\
                 flash-usb: the orange-yellow LED L (D13) then fades in and out, and the bootloader's serial port appears."
            );
            if std::io::stdin().is_terminal() {
                eprint!("flash-usb: press Enter when the LED fades (Ctrl-C to stop) ");
                let _ = std::io::stderr().flush();
                let mut s = String::new();
                let _ = std::io::stdin().lock().read_line(&mut s);
            }
            if let Err(e) = wait_for_port(&port, wait) {
                return fail(e);
            }
            args
        }
    };
    eprintln!("flash-usb: {}", shell_line(&bossac, &args));
    let status = match Command::new(&bossac).args(&args).status() {
        Ok(s) => s,
        Err(e) => return fail(format!("cannot run {}: {e}. The board was not changed", bossac.display())),
    };
    match status.code() {
        Some(0) => {
            eprintln!(
                "flash-usb: done: bossac wrote and verified the firmware at 0x10000 and reset the board into it. \
                 The calibration records (0xF8000) were not touched."
            );
            ExitCode::SUCCESS
        }
        Some(2) => {
            eprintln!(
                "flash-usb: error: bossac's verify failed (exit 2): the application pages (from 0x10000) do not hold this \
                 image. The bootloader and the calibration records were not written; double-tap RESET and run again."
            );
            ExitCode::from(2)
        }
        code => {
            eprintln!(
                "flash-usb: error: bossac failed ({status}). If it stopped before \"Write\" (e.g. \"No device found on ...\"), \
                 the board was not changed: check that the orange LED fades (double-tap RESET again) and that PORT is the \
                 bootloader's port, then run again. If it stopped during the write, the application may be incomplete: \
                 the bootloader is intact, double-tap RESET and run again. An upload never writes the calibration records."
            );
            ExitCode::from(code.and_then(|c| u8::try_from(c).ok()).filter(|&c| c != 0).unwrap_or(1))
        }
    }
}
