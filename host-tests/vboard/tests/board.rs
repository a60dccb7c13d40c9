//! The real firmware ELF on the emulated board: calibration end to end, reboot, and faults.

use rig_sim::lsm_model::Board;
use rig_sim::nor::NorSim;
use rig_sim::sim::RigConfig;
use rig_sim::variant::Variant;
use vboard::bench::{build_firmware, Bench, Outcome};
use vboard::mcu::Stop;

fn bench(board: Board, rig: RigConfig, seed: u64) -> Bench {
    let elf = build_firmware(&[]).unwrap();
    Bench::new(elf, rig, seed, board, NorSim::new(8, seed), false).unwrap()
}

fn has(b: &Bench, text: &str) -> bool {
    b.mcu.log.iter().any(|l| l.contains(text))
}

#[test]
fn calibrates_stores_and_reloads_after_reset() {
    let mut b = bench(Board::Rev1, Variant::Hobby.config(3, 0), 3);
    b.mcu.paint_stack();
    assert_eq!(b.run_for(2.0), Stop::Time);
    let boot_stack = b.mcu.peak_stack();
    b.mcu.paint_stack();
    assert!(has(&b, "no calibration stored"));
    assert_eq!(b.calibrate(600.0), Outcome::Done, "{:?}", b.mcu.log.iter().rev().take(5).collect::<Vec<_>>());
    let rec = b.stored().expect("a record in flash");
    let err = b.max_scale_error_pct(&rec);
    assert!(err <= 0.1, "max scale error {err:.4} %");
    let (instr, calls) = b.mcu.handle_sample.get();
    println!(
        "MEASURED instructions_per_sample={:.0} peak_stack_bytes_boot={boot_stack:?} peak_stack_bytes_calibration={:?} max_scale_error_pct={err:.4}",
        instr as f64 / calls.max(1) as f64,
        b.mcu.peak_stack()
    );
    // Reboot: the record is loaded and applied.
    b.reset().unwrap();
    b.run_for(3.0);
    assert!(has(&b, "loaded calibration record 1 from slot 0"), "{:?}", b.mcu.log.iter().rev().take(5).collect::<Vec<_>>());
    assert!(b.mcu.log.iter().rev().take(4).any(|l| l.contains("rate [")));
}

#[test]
fn missing_foreign_and_rev2_sensors_are_reported_without_hanging() {
    for (board, text) in
        [(Board::Missing, "no LSM9DS1 at 0x6B"), (Board::OtherChip(0x3D), "WrongId(61)"), (Board::Rev2, "Nano 33 BLE Rev2")]
    {
        let mut b = bench(board, Variant::Hobby.config(4, 0), 4);
        assert_eq!(b.run_for(5.0), Stop::Time);
        assert!(has(&b, text), "{board:?}: {:?}", b.mcu.log);
        // Retried every 2 s, and the firmware keeps running (the watchdog is fed).
        assert!(b.mcu.log.iter().filter(|l| l.contains(text)).count() >= 2);
        assert_eq!(b.mcu.resets, 0);
        // The red LED (P0.24, active low) is lit.
        assert_eq!(b.mcu.periph.borrow().gpio.port[0].out & (1 << 24), 0);
    }
}

#[test]
fn i2c_nack_mid_run_fails_and_stores_nothing() {
    let mut b = bench(Board::Rev1, Variant::Hobby.config(5, 0), 5);
    b.run_for(2.0);
    let out = b.calibrate_with(600.0, |line, p| {
        if line.contains("hand-held pose 2") {
            p.sensor.nack_from = Some(0);
        }
    });
    assert!(matches!(out, Outcome::Failed(ref l) if l.contains("SensorTimeout")), "{out:?}");
    assert!(has(&b, "LSM9DS1 read failed"));
    assert!(b.stored().is_none());
}

#[test]
fn disconnected_servo_fails_and_stores_nothing() {
    let mut b = bench(Board::Rev1, Variant::Hobby.config(6, 0), 6);
    b.run_for(2.0);
    let out = b.calibrate_with(600.0, |line, p| {
        if line.contains("rig pose 0") {
            p.sensor.rig_mut().stall(true);
        }
    });
    assert!(matches!(out, Outcome::Failed(ref l) if l.contains("ServoNotTurning")), "{out:?}");
    assert!(b.stored().is_none());
}

#[test]
fn a_hung_bus_ends_in_a_watchdog_reset() {
    let mut b = bench(Board::Rev1, Variant::Hobby.config(7, 0), 7);
    b.run_for(2.0);
    b.mcu.periph.borrow_mut().twim.hang = true;
    b.run_for(3.0);
    assert_eq!(b.mcu.resets, 1, "{:?}", b.mcu.log);
    assert!(has(&b, "watchdog reset"));
    b.mcu.periph.borrow_mut().twim.hang = false;
    b.run_for(3.0);
    assert_eq!(b.mcu.log.iter().filter(|l| l.contains("LSM9DS1 ready")).count(), 2);
}
