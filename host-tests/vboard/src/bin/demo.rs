//! `cargo demo [--seed N] [--quiet]`: builds the firmware, boots the very ELF that gets flashed
//! on the emulated Nano 33 BLE with a simulated rig (random but seeded sensor and servo errors),
//! presses the button, plays the operator, prints the firmware's own defmt log, resets the board,
//! reads the stored record back from the emulated flash and compares it with the simulator's
//! truth. The last stdout line is `RESULT max_scale_error_pct=<number> stored=<true|false>`.
//!
//! `--no-probe`: nobody reads RTT until the end (no probe attached). The operator then cannot
//! read the log and goes by the LEDs and the procedure's timeline (`Bench::calibrate_by_leds`);
//! the result comes from the emulated flash and from what the RTT buffer holds at the end. The
//! last line is `RESULT max_scale_error_pct=<x> stored=<bool> probe=none`, and the exit code is
//! non-zero if the watchdog reset the board.

use host_tests::lsm_model::Board;
use host_tests::nor::NorSim;
use host_tests::servo_protocol::Variant;
use std::process::ExitCode;
use vboard::bench::{build_firmware, Bench, Outcome};

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let seed: u64 = args.iter().position(|a| a == "--seed").and_then(|i| args.get(i + 1)?.parse().ok()).unwrap_or(1);
    let quiet = args.iter().any(|a| a == "--quiet");
    let no_probe = args.iter().any(|a| a == "--no-probe");

    println!("[demo] building the firmware (cargo build --release)");
    let elf = match build_firmware(&[]) {
        Ok(e) => e,
        Err(e) => {
            eprintln!("[demo] {e}");
            return ExitCode::from(2);
        }
    };
    let rig = Variant::Hobby.config(seed, 0);
    let mut bench = match Bench::new(elf, rig, seed, Board::Rev1, NorSim::new(8, seed), !quiet) {
        Ok(b) => b,
        Err(e) => {
            eprintln!("[demo] {e}");
            return ExitCode::from(2);
        }
    };
    if no_probe {
        bench.mcu.rtt_detach();
    }
    let wall = std::time::Instant::now();
    println!("[demo] power on (seed {seed}); the button is pressed at 2 s{}", if no_probe { "; no probe: the operator watches the LEDs" } else { "" });
    bench.run_for(2.0);
    let outcome = if no_probe { bench.calibrate_by_leds(600.0) } else { bench.calibrate(600.0) };
    println!("[demo] calibration: {outcome:?} at {:.1} s virtual, {:.1} s wall", bench.mcu.now(), wall.elapsed().as_secs_f64());
    bench.run_for(2.0);
    println!("[demo] reset: the firmware must load and apply the stored record");
    if let Err(e) = bench.reset() {
        eprintln!("[demo] reset failed: {e}");
    }
    bench.run_for(3.0);
    let (calls, instr) = { let (i, n) = bench.mcu.handle_sample.get(); (n, i) };
    println!(
        "[demo] {} instructions in {:.1} s virtual; Procedure::handle_sample: {} calls, {:.0} instructions per sample",
        bench.mcu.instructions(),
        bench.mcu.now(),
        calls,
        if calls > 0 { instr as f64 / calls as f64 } else { 0.0 }
    );
    let stored = bench.stored();
    let truth = bench.mcu.periph.borrow().sensor.rig().truth().gyro_k;
    println!("[demo] true K diagonal   {:.6} {:.6} {:.6}", truth[(0, 0)], truth[(1, 1)], truth[(2, 2)]);
    let err = match &stored {
        Some(r) => {
            println!("[demo] stored record {}: K diagonal {:.6} {:.6} {:.6} ({:?})", r.seq, r.gyro_k[0][0], r.gyro_k[1][1], r.gyro_k[2][2], r.method);
            bench.max_scale_error_pct(r)
        }
        None => f64::NAN,
    };
    let ok = stored.is_some() && outcome == Outcome::Done;
    if no_probe {
        let tail = bench.mcu.rtt_tail();
        println!("[demo] RTT buffer at the end ({} bytes written in all, {} lines held):", bench.mcu.rtt_written(), tail.len());
        for l in tail.iter().rev().take(12).rev() {
            println!("[demo]   {l}");
        }
        println!("[demo] watchdog resets: {}", bench.mcu.watchdog_resets);
        println!("RESULT max_scale_error_pct={err:.4} stored={ok} probe=none");
        if bench.mcu.watchdog_resets > 0 {
            return ExitCode::from(1);
        }
    } else {
        println!("RESULT max_scale_error_pct={err:.4} stored={ok}");
    }
    ExitCode::SUCCESS
}
