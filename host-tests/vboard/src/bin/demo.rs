//! `cargo demo [--seed N] [--quiet]`: builds the firmware, boots the very ELF that gets flashed
//! on the emulated Nano 33 BLE with a simulated rig (random but seeded sensor and servo errors),
//! presses the button, plays the operator (who watches the LEDs, never the log), prints the
//! firmware's own defmt log, resets the board,
//! reads the stored record back from the emulated flash and compares it with the simulator's
//! truth. The last stdout line is `RESULT max_scale_error_pct=<number> stored=<true|false>
//! board=rev1`, after `SPEED board_s=<virtual s> wall_s=<s> x=<virtual s per wall s>`; for a
//! full `K` (every run that stores one) over `E = Qᵀ K̂ K⁻¹ − I` (the calibrated accelerometer
//! frame aligned to the simulator's), with `max_cross_axis_error_pct=<max |E_ij|, i ≠ j, %>
//! max_abs_e=<max |E_ij|>` after the scale error (`max |E_ii|`, %) in every mode.
//!
//! `--rev2` (with any of the modes below): the same firmware on a Nano 33 BLE Rev2, its BMI270 at
//! 0x68 (Bosch's configuration upload, the FIFO in header mode); `board=rev2`.
//!
//! `--odr952`: the `odr952` firmware, the LSM9DS1's gyro and accelerometer at 952 Hz (8× the
//! samples through the same procedure; issue 50's per-sample budget holds there too).
//!
//! `--raw-log OUT.csv`: the firmware's raw-log mode (a long press before the calibration, another
//! after it) and the message text of every line from the header on written to OUT.csv, exactly
//! what `probe-rs run --log-format "{s}" > OUT.csv` would write; `calib OUT.csv` calibrates it.
//!
//! `--tilt`: the `tilt-servo` firmware (the pan/tilt plan) on a pan/tilt bracket (shaft 30–50°
//! from vertical, gyro cross-axis ±1 %, accelerometer misalignment ±0.3 %). The stored full `K`
//! is compared with the truth over `E = Qᵀ K̂ K⁻¹ − I` (the calibrated accelerometer frame
//! aligned to the simulator's): the RESULT line comes after the rig time (press to stored).
//!
//! `--no-probe`: nobody reads RTT until the end (no probe attached). The operator then cannot
//! read the log and goes by the LEDs (as always: `Testbed::calibrate`);
//! the result comes from the emulated flash and from what the RTT buffer holds at the end. The
//! last line is `RESULT max_scale_error_pct=<x> … stored=<bool> probe=none`, and the exit code is
//! non-zero if the watchdog reset the board.
//!
//! `--usb`: no button and no probe. The board's USB port (VBUS plugged, the virtual host
//! enumerates it) is a pseudo-terminal, and `calib --port <pty>` (calib's own session code, on a
//! thread) does everything: starts the calibration, shows the phases, gets Enter from the
//! operator after the re-clamp, saves the raw log to `OUT/demo-usb.csv` (`--out`, default
//! `target/demo`), prints
//! the board's JSON result and cross-checks it on the PC. The last line is
//! `RESULT max_scale_error_pct=<x> … stored=<bool> via=usb`, `x` from the board's JSON line.

use clap::Parser;
use rig_sim::lsm_model::Board;
use rig_sim::nor::NorSim;
use rig_sim::pan_tilt;
use rig_sim::variant::Variant;
use std::process::ExitCode;
use vboard::mcu::Calls;
use vboard::testbed::{build_firmware, message, Outcome, Testbed};

/// The firmware on the emulated Nano 33 BLE, calibrating on a simulated rig.
#[derive(Parser, Debug)]
#[command(name = "demo")]
struct Args {
    /// Seed of the simulated rig (sensor and servo errors).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Do not print the firmware's log.
    #[arg(long)]
    quiet: bool,
    /// Nobody reads RTT until the end; the operator watches the LEDs.
    #[arg(long, conflicts_with = "raw_log")]
    no_probe: bool,
    /// Raw-log mode: write the log lines from the header on to this file, as probe-rs would.
    #[arg(long, value_name = "OUT.csv")]
    raw_log: Option<String>,
    /// The pan/tilt bracket and the `tilt-servo` firmware: the full 3×3 K.
    #[arg(long)]
    tilt: bool,
    /// Everything over USB serial with `calib --port` on a pseudo-terminal (no button, no RTT).
    #[arg(long, conflicts_with_all = ["raw_log", "no_probe"])]
    usb: bool,
    /// With --usb: after the calibration, the 1200-baud touch (gyrocal-flash's own code) and
    /// 60 s of board time in the bootloader the touch enters. Last line `RESULT
    /// touch=<bootloader|app|off> held_s=<s> resets=<n>` (resets while held).
    #[arg(long, requires = "usb")]
    touch: bool,
    /// A Nano 33 BLE Rev2 (BMI270 at 0x68) instead of a Rev1 (LSM9DS1): the same firmware.
    #[arg(long)]
    rev2: bool,
    /// The `odr952` firmware: the LSM9DS1 at 952 Hz (the rig's sensor model follows it).
    #[arg(long, conflicts_with = "rev2")]
    odr952: bool,
    /// Where the demo writes its files (`--usb`: the raw log `demo-usb.csv`); default
    /// `target/demo` in the workspace.
    #[arg(long, value_name = "DIR")]
    out: Option<std::path::PathBuf>,
    /// Print where `Procedure::handle_sample`'s instructions go: its N costliest functions
    /// (callees apart) over the whole run, in its calls of a sample and in its long calls apart
    /// (issue 50).
    #[arg(long, value_name = "N")]
    profile: Option<usize>,
}

fn main() -> ExitCode {
    let Args { seed, quiet, no_probe, raw_log, tilt, usb, touch, rev2, odr952, out, profile } = Args::parse_from(calib::cli_args());
    let (board, board_name) = if rev2 { (Board::Rev2, "rev2") } else { (Board::Rev1, "rev1") };
    let out = out.unwrap_or_else(|| calib::firmware::target_dir().join("demo"));
    if let Err(e) = std::fs::create_dir_all(&out) {
        eprintln!("[demo] {}: {e}", out.display());
        return ExitCode::from(2);
    }

    let features: Vec<&str> = [(tilt, "tilt-servo"), (odr952, "odr952")].into_iter().filter(|f| f.0).map(|f| f.1).collect();
    let shown = if features.is_empty() { String::new() } else { format!(" --features {}", features.join(",")) };
    println!("[demo] building the firmware (cargo build --release{shown})");
    let elf = match build_firmware(&features) {
        Ok(e) => e,
        Err(e) => {
            eprintln!("[demo] {e}");
            return ExitCode::from(2);
        }
    };
    let rig = if tilt { pan_tilt::rig_config(seed, 0) } else { Variant::Hobby.config(seed, 0) };
    let mut testbed = match Testbed::new(elf, rig, seed, board, NorSim::new(8, seed), !quiet) {
        Ok(b) => b,
        Err(e) => {
            eprintln!("[demo] {e}");
            return ExitCode::from(2);
        }
    };
    if no_probe || usb {
        testbed.mcu.rtt_detach();
    }
    let wall = std::time::Instant::now();
    testbed.mcu.paint_stack();
    testbed.mcu.profiling.set(profile.is_some());
    if usb {
        return demo_usb(&mut testbed, &out.join("demo-usb.csv"), quiet, touch, wall, board_name);
    }
    println!(
        "[demo] power on (seed {seed}); the button is pressed at 2 s{}",
        if no_probe { "; no probe: the operator watches the LEDs" } else { "" }
    );
    testbed.run_for(2.0);
    let mut raw_text = None;
    let raw_from = raw_log.as_ref().map(|_| {
        println!("[demo] the button held 2.3 s: raw-log mode");
        let at = testbed.mcu.log.len();
        testbed.press(2.3);
        testbed.run_for(1.0);
        at
    });
    let pressed_at = testbed.mcu.now();
    let outcome = testbed.calibrate(600.0);
    let rig_time_s = testbed.mcu.now() - pressed_at;
    if let (Some(path), Some(from)) = (&raw_log, raw_from) {
        testbed.press(2.3);
        testbed.run_for(0.5);
        let text: String = testbed.mcu.log[from..].iter().map(|l| format!("{}\n", message(l))).collect();
        let Some(start) = text.find(calib_core::formats::log::HEADER) else {
            eprintln!("[demo] raw-log mode printed no header");
            return ExitCode::from(1);
        };
        if let Err(e) = std::fs::write(path, &text[start..]) {
            eprintln!("[demo] {path}: {e}");
            return ExitCode::from(2);
        }
        println!("[demo] raw log written to {path} ({} lines)", text[start..].lines().count());
        raw_text = Some(text[start..].to_string());
    }
    println!("[demo] calibration: {outcome:?} at {:.1} s virtual, {:.1} s wall", testbed.mcu.now(), wall.elapsed().as_secs_f64());
    println!("[demo] rig time: {rig_time_s:.1} s from the press to the LEDs showing the result");
    testbed.run_for(2.0);
    println!("[demo] reset: the firmware must load and apply the stored record");
    if let Err(e) = testbed.reset() {
        eprintln!("[demo] reset failed: {e}");
    }
    testbed.run_for(3.0);
    let (calls, instr) = {
        let (i, n) = testbed.mcu.handle_sample.get();
        (n, i)
    };
    println!(
        "[demo] {} instructions in {:.1} s virtual; Procedure::handle_sample: {} calls, {:.0} instructions per sample",
        testbed.mcu.instructions(),
        testbed.mcu.now(),
        calls,
        if calls > 0 { instr as f64 / calls as f64 } else { 0.0 }
    );
    println!("[demo] peak stack: {} bytes (from power-on)", testbed.mcu.peak_stack().unwrap_or(0));
    let (dropped, overruns) = {
        let p = testbed.mcu.periph.borrow();
        p.sensor.bmi().map_or((p.sensor.counts().1, p.sensor.overruns()), |b| b.dropped())
    };
    println!("[demo] FIFO overruns: {overruns}, samples dropped: {dropped} (the whole run, the solve and the store included)");
    if let Some(n) = profile {
        for (calls, what) in [
            (Calls::Samples, "Procedure::handle_sample, its calls of a sample"),
            (Calls::LongSamples, "Procedure::handle_sample, its long calls (pose ends, fits)"),
            (Calls::Ticks, "Procedure::handle_tick (fits, the solve's steps)"),
        ] {
            let profile = testbed.mcu.profile(calls);
            let total: u64 = profile.iter().map(|p| p.1).sum();
            println!("[demo] profile of {what}: {total} instructions; the {n} costliest functions (callees apart, builtins charged to their caller):");
            for (name, i) in profile.iter().take(n) {
                println!("[demo] {:>6.2} % {i:>12} {name}", 100.0 * *i as f64 / total.max(1) as f64);
            }
        }
    }
    let longest = testbed.mcu.handle_sample_max.get();
    println!("[demo] the longest handle_sample call: {longest} instructions, {:.0} ms at 64 MHz", longest as f64 / 64e3);
    let longest = testbed.mcu.handle_tick_max.get();
    println!(
        "[demo] the longest handle_tick call (a fit or a step of the solve): {longest} instructions, {:.0} ms at 64 MHz",
        longest as f64 / 64e3
    );
    let stored = testbed.stored();
    let truth = testbed.mcu.periph.borrow().sensor.rig().truth().gyro_k;
    println!("[demo] true K diagonal   {:.6} {:.6} {:.6}", truth[(0, 0)], truth[(1, 1)], truth[(2, 2)]);
    let err = match &stored {
        Some(r) => {
            println!(
                "[demo] stored record {}: K diagonal {:.6} {:.6} {:.6} ({:?})",
                r.seq, r.gyro_k[0][0], r.gyro_k[1][1], r.gyro_k[2][2], r.method
            );
            testbed.max_scale_error_pct(r)
        }
        None => f64::NAN,
    };
    // A full K against the truth: scale (diagonal) and cross-axis (off-diagonal) of E.
    let full_err = stored.as_ref().filter(|r| r.method == calib_core::estimators::gyro::Method::Full).map(|r| testbed.k_errors_pct(r));
    let ok = stored.is_some() && outcome == Outcome::Done;
    let mag = mag_fields(stored.as_ref(), testbed.mcu.periph.borrow().sensor.rig(), seed);
    // The raw log through the offline path of `calib` (the same code): the same K as the
    // firmware's record within 0.005 % (the log's six decimals leave ~1e-4 % between them; a
    // replay that drifts from the firmware's code breaks this), and within 0.1 % of the truth (of
    // a full K every element against the record, E's diagonal against the truth; the firmware's
    // full K reaches 0.075 % on the worst of rotation-bench's 20 rigs).
    if let (Some(text), Some(rec)) = (&raw_text, &stored) {
        // calib's full K when it gives one (the record is then a full K too), else its diagonal.
        let k = calib::csvlog::parse(text)
            .map_err(|e| e.to_string())
            .and_then(|l| calib::offline::calibrate(&l.rows, None).map_err(|e| e.to_string()))
            .and_then(|c| match c.full {
                Some(f) => f.map(|f| (f.k, c.accel.m, true)).map_err(|e| e.to_string()),
                None => c.gyro.map(|g| (g.k, c.accel.m, false)).map_err(|e| e.to_string()),
            });
        match k {
            Ok((k, m, full)) => {
                let cells = if full { 9 } else { 3 };
                let at = |i: usize| if full { (i / 3, i % 3) } else { (i, i) };
                let vs_fw = (0..cells)
                    .map(|i| ((k[at(i).0][at(i).1] - rec.gyro_k[at(i).0][at(i).1]) / rec.gyro_k[at(i).0][at(i).0]).abs() as f64 * 100.0)
                    .fold(0.0, f64::max);
                let (vs_truth, cross) = if full {
                    pan_tilt::k_error_matrix(k, m, testbed.mcu.periph.borrow().sensor.rig()).map_or((f64::NAN, f64::NAN), |e| {
                        let off = (0..9).filter(|i| i / 3 != i % 3).map(|i| e[(i / 3, i % 3)].abs()).fold(0.0, f64::max);
                        (e.diagonal().amax() * 100.0, off * 100.0)
                    })
                } else {
                    ((0..3).map(|i| (k[i][i] as f64 / truth[(i, i)] - 1.0).abs() * 100.0).fold(0.0, f64::max), f64::NAN)
                };
                println!("ROUNDTRIP calib_vs_firmware_max_pct={vs_fw:.4} calib_scale_error_pct={vs_truth:.4} calib_cross_axis_error_pct={cross:.4}");
                if vs_fw > 0.005 || vs_truth > 0.1 {
                    return ExitCode::from(1);
                }
            }
            Err(e) => {
                println!("ROUNDTRIP failed: {e}");
                return ExitCode::from(1);
            }
        }
    }
    print_speed(&testbed, wall);
    if no_probe {
        let tail = testbed.mcu.rtt_tail();
        println!("[demo] RTT buffer at the end ({} bytes written in all, {} lines held):", testbed.mcu.rtt_written(), tail.len());
        for l in tail.iter().rev().take(12).rev() {
            println!("[demo]   {l}");
        }
        println!("[demo] watchdog resets: {}", testbed.mcu.watchdog_resets);
        println!("RESULT max_scale_error_pct={err:.4}{}{mag} stored={ok} probe=none board={board_name}", full_fields(full_err));
        if testbed.mcu.watchdog_resets > 0 {
            return ExitCode::from(1);
        }
    } else if let Some((scale, _)) = full_err {
        println!("RESULT max_scale_error_pct={scale:.4}{}{mag} stored={ok} board={board_name}", full_fields(full_err));
    } else if tilt {
        println!("RESULT max_scale_error_pct=NaN max_cross_axis_error_pct=NaN stored=false board={board_name}");
    } else {
        println!("RESULT max_scale_error_pct={err:.4}{mag} stored={ok} board={board_name}");
    }
    ExitCode::SUCCESS
}

/// The RESULT fields of the stored magnetometer calibration: ` mag_heading_rms_deg=<RMS>
/// mag_heading_max_deg=<largest>`, the tilt-compensated heading error (°) over 500 random
/// attitudes against the simulator's truth (`rig_sim::heading`); NaN without one.
fn mag_fields(stored: Option<&calib_core::formats::record::Record>, rig: &rig_sim::sim::Rig, seed: u64) -> String {
    let err = stored.and_then(|r| {
        let m = r.mag?;
        let applied = rig_sim::heading::Applied { accel_m: r.accel_m, accel_o: r.accel_offset_g, mag_a: m.a, mag_o: m.offset_ut };
        rig_sim::heading::heading_error(&applied, rig, 500, seed)
    });
    let (rms, max) = err.unwrap_or((f64::NAN, f64::NAN));
    format!(" mag_heading_rms_deg={rms:.3} mag_heading_max_deg={max:.3}")
}

/// The RESULT fields of a full `K` beside its scale error: ` max_cross_axis_error_pct=<largest
/// off-diagonal |E_ij|, %> max_abs_e=<largest |E_ij|>` (empty for a one-axis record).
fn full_fields(full_err: Option<(f64, f64)>) -> String {
    full_err
        .map_or(String::new(), |(scale, cross)| format!(" max_cross_axis_error_pct={cross:.4} max_abs_e={:.2e}", scale.max(cross) / 100.0))
}

/// `SPEED board_s=<virtual s> wall_s=<s> x=<board s per wall s>`: how fast the virtual board ran
/// (from power-on; the firmware build not counted).
fn print_speed(testbed: &Testbed, wall: std::time::Instant) {
    let (board, wall) = (testbed.mcu.now(), wall.elapsed().as_secs_f64());
    println!("SPEED board_s={board:.1} wall_s={wall:.1} x={:.1}", board / wall.max(1e-9));
}

/// `--usb`: the board on a USB cable only, driven by `calib --port` through a pseudo-terminal.
fn demo_usb(
    testbed: &mut Testbed,
    log: &std::path::Path,
    quiet: bool,
    touch: bool,
    wall: std::time::Instant,
    board_name: &str,
) -> ExitCode {
    println!("[demo] USB cable plugged in (VBUS); no probe, no button: everything through calib --port (log: {})", log.display());
    let ui: Box<dyn std::io::Write + Send> = if quiet { Box::new(std::io::sink()) } else { Box::new(std::io::stdout()) };
    let (outcome, session) = match testbed.calibrate_over_usb(log, ui) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("[demo] {e}");
            println!("RESULT max_scale_error_pct=NaN stored=false via=usb board={board_name}");
            return ExitCode::from(1);
        }
    };
    println!("[demo] calibration: {outcome:?} at {:.1} s virtual, {:.1} s wall", testbed.mcu.now(), wall.elapsed().as_secs_f64());
    let out = match session {
        Ok(o) => o,
        Err(e) => {
            eprintln!("[demo] calib --port: {e}");
            println!("RESULT max_scale_error_pct=NaN stored=false via=usb board={board_name}");
            return ExitCode::from(1);
        }
    };
    println!("[demo] the board's result (JSON over USB): {}", out.json);
    println!(
        "[demo] cross-check: calib on the saved log ({} lines, {} rows) agrees with the board to {:.2e} in K",
        out.lines, out.check.rows, out.check.max_diff
    );
    let same = testbed.stored().is_some_and(|r| {
        r.seq == out.record.seq && (0..9).all(|i| (r.gyro_k[i / 3][i % 3] - out.record.gyro_k[i / 3][i % 3]).abs() < 1e-6)
    });
    let ok = same && outcome == Outcome::Done;
    println!("[demo] the record in flash is the one reported over USB: {same}");
    print_speed(testbed, wall);
    let full = (out.record.method == calib_core::estimators::gyro::Method::Full).then(|| testbed.k_errors_pct(&out.record));
    println!(
        "RESULT max_scale_error_pct={:.4}{} stored={ok} via=usb board={board_name}",
        full.map_or(testbed.max_scale_error_pct(&out.record), |f| f.0),
        full_fields(full)
    );
    let ok = ok && (!touch || demo_touch(testbed));
    if ok {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    }
}

/// Board time the bootloader must stay up after the touch (s): what a slow upload takes.
const HOLD_S: f64 = 60.0;

/// `--touch`: the 1200-baud touch on the pty with `gyrocal-flash`'s code, then [`HOLD_S`] of
/// board time. True if the board is in the bootloader's SAM-BA mode for all of it, with no
/// reset of any kind.
fn demo_touch(testbed: &mut Testbed) -> bool {
    let Some(path) = testbed.usb.as_ref().map(|b| b.slave_path().to_string_lossy().into_owned()) else {
        println!("RESULT touch=none held_s=0.0 resets=0");
        return false;
    };
    println!("[demo] the 1200-baud touch on {path}, as gyrocal-flash does it");
    let t = std::thread::spawn(move || calib::port::touch_1200(&path));
    let t_end = testbed.mcu.now() + 5.0;
    while !testbed.mcu.stock_bootloader().in_samba() && testbed.mcu.now() < t_end {
        testbed.run_for(0.01);
    }
    if let Ok(Err(e)) = t.join() {
        eprintln!("[demo] touch: {e}");
    }
    let resets = testbed.mcu.resets;
    testbed.run_for(HOLD_S);
    let bl = testbed.mcu.stock_bootloader();
    let (held, resets) = (bl.held_s(testbed.mcu.now()), testbed.mcu.resets - resets);
    let state = if bl.in_samba() {
        "bootloader"
    } else if testbed.mcu.in_app() {
        "app"
    } else {
        "off"
    };
    let vid_pid = testbed.usb.as_ref().and_then(|b| b.host().vid_pid());
    println!("[demo] after {HOLD_S} s: {state}, on USB as {vid_pid:04X?}, {} watchdog resets in all", testbed.mcu.watchdog_resets);
    println!("RESULT touch={state} held_s={held:.1} resets={resets}");
    bl.in_samba() && held >= HOLD_S && resets == 0
}
