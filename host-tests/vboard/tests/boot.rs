//! The firmware ELF from the state the Arduino bootloader leaves (and from a cold power-on), a
//! soft reset with the watchdog running, and an RTT host that detaches. Short runs (seconds of
//! board time, no calibration).

use rig_sim::lsm_model::Board;
use rig_sim::nor::NorSim;
use rig_sim::variant::Variant;
use vboard::mcu::Stop;
use vboard::periph::NoDma;
use vboard::testbed::{build_firmware, Testbed};

fn testbed(seed: u64, bootloader: bool) -> Testbed {
    let elf = build_firmware(&[]).unwrap();
    let mut b = Testbed::new(elf, Variant::Hobby.config(seed, 0), seed, Board::Rev1, NorSim::new(8, seed), false).unwrap();
    if !bootloader {
        b.mcu.periph.borrow_mut().bootloader = false;
        b.mcu.reset().unwrap();
    }
    b
}

#[test]
fn boots_from_the_bootloader_state_and_from_cold() {
    for bootloader in [true, false] {
        let mut b = testbed(11, bootloader);
        assert_eq!(b.run_for(3.0), Stop::Time, "{:?}", b.mcu.log);
        let p = b.mcu.periph.borrow();
        let what = if bootloader { "bootloader" } else { "cold" };
        assert_eq!(b.mcu.resets, 0, "{what}: {:?}", b.mcu.log);
        assert_eq!(b.mcu.periph.borrow().sensor.sw_resets(), 1, "{what}: {:?}", b.mcu.log);
        // The sensor supply is driven with high drive; no voltage drop.
        assert!(p.sensor_powered() && !p.vdd_env_drop, "{what}: P0.22 PIN_CNF 0x{:08X}", p.gpio.cnf(0, 22));
        // UARTE0 (the bootloader's, receiving): stopped (RXTO) and then disabled.
        assert!(
            !p.uarte.receiving() && p.uarte.enable == 0 && !p.uarte.disabled_while_receiving,
            "{what}: UARTE0 {:?} ENABLE {}, disabled while receiving {}",
            p.uarte.rx,
            p.uarte.enable,
            p.uarte.disabled_while_receiving
        );
        // The HFXO start waited for a fresh EVENTS_HFCLKSTARTED, not the bootloader's.
        assert_eq!(p.clock.stale_event_reads, 0, "{what}: stale HFCLKSTARTED read");
        assert!(p.clock.hfxo_running);
        // The tick interrupt's event clear is complete before the handler returns.
        let spurious: u32 = p.timers.iter().map(|t| t.spurious).sum();
        assert_eq!(spurious, 0, "{what}: spurious timer interrupts (event clear not read back)");
        // No STOP issued to an idle TWIM; the watchdog is fed.
        assert_eq!((p.twim.idle_stops, p.twim.broken_transfers), (0, 0), "{what}");
        assert!(p.wdt.running && p.wdt.reloads > 100, "{what}");
        // Erratum 87: no `wfi` with FPU exception flags pending.
        assert_eq!(p.scs.wfi_with_fpu_flags, 0, "{what}");
    }
}

/// Erratum 136: after a pin reset RESETREAS also shows SREQ; the firmware reports RESETPIN
/// alone.
#[test]
fn a_pin_reset_is_reported_as_one_despite_erratum_136() {
    let mut b = testbed(15, true);
    b.run_for(1.0);
    b.mcu.reset_pin().unwrap();
    b.run_for(1.5);
    let line = b.mcu.log.iter().rev().find(|l| l.contains("reset reason")).cloned().unwrap_or_default();
    assert!(line.ends_with("reset reason 0x00000001"), "{line}");
    assert_eq!(b.mcu.periph.borrow().power.resetreas_read, Some(0b101), "the part said RESETPIN | SREQ");
}

#[test]
fn a_soft_reset_with_the_watchdog_running_recovers_it() {
    let mut b = testbed(12, true);
    b.run_for(1.0);
    assert!(b.mcu.periph.borrow().wdt.running);
    // AIRCR.SYSRESETREQ: the WDT keeps running (PS: a soft reset does not reset it); the
    // firmware must find it running (Watchdog::try_recover) and keep feeding it.
    b.mcu.periph.borrow_mut().scs.reset_request = true;
    let reloads = b.mcu.periph.borrow().wdt.reloads;
    assert_eq!(b.run_for(6.0), Stop::Time);
    let p = b.mcu.periph.borrow();
    assert_eq!((b.mcu.resets, b.mcu.watchdog_resets), (1, 0), "{:?}", b.mcu.log);
    assert!(p.wdt.running && p.wdt.reloads > reloads + 100);
    assert_eq!(b.mcu.periph.borrow().power.resetreas_read, Some(1 << 2), "RESETREAS.SREQ read after the soft reset");
    assert_eq!(b.mcu.periph.borrow().sensor.sw_resets(), 2, "{:?}", b.mcu.log);
}

#[test]
fn an_rtt_host_that_detaches_does_not_stall_the_firmware() {
    let mut b = testbed(13, true);
    // probe-rs run: attaches at boot (BLOCK_IF_FULL) and reads.
    b.mcu.rtt_attach();
    b.run_for(1.0);
    assert_eq!(b.mcu.rtt_flags().map(|f| f & 3), Some(2), "the host set BLOCK_IF_FULL");
    assert_eq!(b.mcu.periph.borrow().sensor.sw_resets(), 1);
    // The probe is unplugged; the user holds the button 2 s (raw-log mode: a CSV line per
    // sample, far more than the 1 KiB buffer holds) and leaves the board alone for 8 s.
    b.mcu.rtt_detach();
    let written0 = b.mcu.rtt_written();
    b.press(2.3);
    b.run_for(8.0);
    let written = b.mcu.rtt_written() - written0;
    let tail = b.mcu.rtt_tail();
    println!("MEASURED rtt_detached_bytes_written={written} watchdog_resets={} tail_lines={}", b.mcu.watchdog_resets, tail.len());
    assert_eq!(
        b.mcu.watchdog_resets,
        0,
        "the firmware stalled on a full RTT buffer: {:?}",
        b.mcu.log.iter().rev().take(3).collect::<Vec<_>>()
    );
    assert!(written > 4096, "only {written} bytes written while detached");
    // The frames that did not fit were dropped and counted by the firmware, not waited for.
    assert!(b.mcu.rtt_dropped().is_some_and(|d| d > 0), "{:?}", b.mcu.rtt_dropped());
    // Read at the end: the buffer holds whole defmt frames (raw CSV lines).
    assert!(tail.iter().any(|l| l.matches(',').count() >= 6), "{tail:?}");
}

#[test]
fn raw_log_at_952_hz_fits_the_rtt_buffer_and_is_a_log_calib_reads() {
    // probe-rs run, reading all along (the vboard drains the buffer every millisecond).
    let (mut b, before) = raw_log_at_952_hz(14, 1.0);
    let (w0, t0) = (b.mcu.rtt_written(), b.mcu.now());
    b.run_for(5.0);
    let bytes_per_s = (b.mcu.rtt_written() - w0) as f64 / (b.mcu.now() - t0);
    // The lines as `probe-rs run --log-format "{s}"` prints them: the message text.
    let text: String = b.mcu.log[before..].iter().map(|l| format!("{}\n", vboard::testbed::message(l))).collect();
    let log = calib::csvlog::parse(&text).expect("the raw log parses");
    let rate = (log.rows.len() - 1) as f64 / (log.rows.last().unwrap().t.s() - log.rows[0].t.s());
    let buffer_s = gyrocal_fw::rtt::BUF_SIZE as f64 / bytes_per_s;
    println!("MEASURED raw_log_bytes_per_s={bytes_per_s:.0} rows={} sample_rate_hz={rate:.1} rtt_buffer_s={buffer_s:.3}", log.rows.len());
    assert!(rate > 900.0, "{rate} Hz");
    assert!(log.rows.len() as f64 > 4.5 * rate, "rows lost: {}", log.rows.len());
    assert_eq!(b.mcu.rtt_dropped(), Some(0), "bytes dropped with a host reading");
    // The buffer holds at least 0.1 s of raw log: several of probe-rs' polls.
    assert!(buffer_s >= 0.1, "{buffer_s} s");
}

/// The `odr952` firmware on a one-servo rig (`seed`), a probe reading RTT all along, booted for
/// `boot_s` and put into raw-log mode (the button held 2.3 s); and where its log then starts.
pub(crate) fn raw_log_at_952_hz(seed: u64, boot_s: f64) -> (Testbed, usize) {
    let elf = build_firmware(&["odr952"]).unwrap();
    let mut b = Testbed::new(elf, Variant::Hobby.config(seed, 0), seed, Board::Rev1, NorSim::new(8, seed), false).unwrap();
    b.mcu.rtt_attach();
    b.run_for(boot_s);
    let from = b.mcu.log.len();
    b.press(2.3);
    (b, from)
}

#[test]
fn the_microsecond_clock_wraps_at_2_pow_32_without_a_gap() {
    let mut b = testbed(15, true);
    b.run_for(2.0);
    // TIMER1 (the 1 MHz clock) 0.5 s before its 32-bit wrap.
    {
        let mut p = b.mcu.periph.borrow_mut();
        let now = p.now();
        let t = &mut p.timers[1];
        let counter = t.counter_at(now);
        t.advance((1u64 << 32) - 500_000 - counter);
    }
    let (_, calls0) = b.mcu.handle_sample.get();
    b.run_for(3.0);
    let (_, calls) = b.mcu.handle_sample.get();
    let handled = calls - calls0;
    println!("MEASURED samples_handled_across_the_wrap={handled}");
    // 3 s at 119 Hz (−4 %): every sample still read and handed on, nothing lost or stalled.
    assert!(handled >= 330, "{handled} samples in 3 s across the wrap");
    assert_eq!(b.mcu.watchdog_resets, 0);
    assert_eq!(b.mcu.periph.borrow().sensor.counts().1, 0, "samples lost to a FIFO overrun");
}

/// The stock bootloader's stand-in as the PS reset table and its disassembly say: a soft reset
/// keeps the watchdog, which the bootloader never feeds; a wake from System OFF resets it.
#[test]
fn the_stock_bootloader_is_cut_off_by_a_watchdog_a_soft_reset_kept_but_not_after_system_off() {
    use vboard::periph::bootloader::{DFU_MAGIC_SERIAL_ONLY, DOUBLE_TAP_S};
    const GPREGRET: u64 = 0x4000_051C;
    // Soft reset with the magic: SAM-BA mode, then the firmware's 2 s watchdog fires; the magic
    // is gone by then, so the bootloader jumps into the application.
    let mut b = testbed(12, true);
    b.run_for(1.0);
    assert!(b.mcu.in_app() && b.mcu.periph.borrow().wdt.running);
    {
        let mut p = b.mcu.periph.borrow_mut();
        p.power.gpregret = DFU_MAGIC_SERIAL_ONLY;
        p.scs.reset_request = true;
    }
    b.run_for(1.0);
    assert!(b.mcu.stock_bootloader().in_samba(), "{:#?}", b.mcu.log);
    b.run_for(3.0);
    assert_eq!((b.mcu.resets, b.mcu.watchdog_resets), (2, 1), "{:#?}", b.mcu.log);
    assert!(b.mcu.in_app(), "after the watchdog reset GPREGRET is clear: the application again");

    // GPREGRET = 0xB0, P1.11 sensing high (it reads high: pull-up, button up), SYSTEMOFF: an
    // immediate wake that resets the watchdog and keeps GPREGRET: SAM-BA mode for good.
    let mut b = testbed(12, true);
    b.run_for(1.0);
    {
        let mut p = b.mcu.periph.borrow_mut();
        p.power.gpregret = DFU_MAGIC_SERIAL_ONLY;
        let mut ram = NoDma;
        p.write(0x5000_0300 + 0x700 + 4 * 11, (3 << 2) | (2 << 16), &mut ram);
        p.write(0x4000_0500, 1, &mut ram); // SYSTEMOFF
    }
    b.run_for(61.0);
    let bl = b.mcu.stock_bootloader();
    assert!(bl.in_samba() && bl.held_s(b.mcu.now()) >= 60.0, "{bl:?} {:#?}", b.mcu.log);
    assert_eq!((b.mcu.resets, b.mcu.watchdog_resets), (1, 0), "{:#?}", b.mcu.log);
    assert_eq!(b.mcu.periph.borrow().power.resetreas & (1 << 16), 1 << 16, "RESETREAS.OFF");
    assert_eq!(b.mcu.periph.borrow_mut().read(GPREGRET), 0, "cleared by the bootloader");

    // System OFF with nothing sensing: off until the button (DETECT) wakes it.
    let mut b = testbed(13, true);
    b.run_for(1.0);
    b.mcu.periph.borrow_mut().write(0x4000_0500, 1, &mut NoDma);
    b.run_for(5.0);
    assert!(!b.mcu.in_app() && b.mcu.resets == 0, "{:#?}", b.mcu.log);

    // The double tap: two pin resets within the wait.
    let mut b = testbed(14, true);
    b.run_for(1.0);
    b.mcu.reset_pin().unwrap();
    b.run_for(DOUBLE_TAP_S / 2.0);
    b.mcu.reset_pin().unwrap();
    b.run_for(2.0);
    assert!(b.mcu.stock_bootloader().in_samba());
}

/// The firmware reads only this version's records (it is built without calib-core's
/// `older-records`): one of version 5 (the part's raw axes, before the board frame) in flash is
/// named, kept and not applied, the same record as version 6 is loaded and applied.
#[test]
fn a_record_of_an_older_version_is_not_applied_and_one_of_this_version_is() {
    use calib_core::formats::record::{crc32, LEN, VERSION};
    use embedded_storage::nor_flash::NorFlash;
    let rec = rig_sim::harness::record(7);
    for (version, loaded) in [(VERSION - 1, false), (VERSION, true)] {
        let mut bytes = rec.encode().unwrap();
        bytes[4] = version;
        let crc = crc32(&bytes[..LEN - 4]);
        bytes[LEN - 4..].copy_from_slice(&crc.to_le_bytes());
        let mut nor = NorSim::new(8, 12);
        nor.write(0, &bytes).unwrap();
        let elf = build_firmware(&[]).unwrap();
        let mut b = Testbed::new(elf, Variant::Hobby.config(12, 0), 12, Board::Rev1, nor, false).unwrap();
        assert_eq!(b.run_for(3.0), Stop::Time, "{:?}", b.mcu.log);
        let said = |m: &str| b.mcu.log.iter().any(|l| vboard::testbed::message(l).contains(m));
        assert_eq!(said("loaded record 7"), loaded, "version {version}: {:?}", b.mcu.log);
        assert_eq!(said(&format!("unsupported record version {version} in flash")), !loaded, "version {version}: {:?}", b.mcu.log);
        assert!(!said("no calibration stored"), "version {version}: {:?}", b.mcu.log);
        // Kept: the flash still holds it.
        assert_eq!(b.mcu.periph.borrow().flash.bytes()[..LEN], bytes[..], "version {version}");
    }
}
