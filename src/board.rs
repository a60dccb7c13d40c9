//! The Nano 33 BLE around the firmware (target only): the LEDs, the microsecond clock, the
//! watchdog, the sensor's rail and I2C bus, and the boot-time clean-up of what the Arduino
//! bootloader leaves running. Shared by the calibration firmware and the example that loads its
//! record (`src/bin/calibrated-rates.rs`).

use crate::bootloader::FlashMap;
use crate::led::Lights;
use calib_core::Time;
use embedded_hal::delay::DelayNs;
use embedded_hal::digital::OutputPin;
use embedded_hal::i2c::{ErrorType, I2c, Operation};
use hal::gpio::{p0, p1, Disconnected, DriveConfig, Level, Output, Pin, PushPull};
use hal::pac;
use hal::timer::Periodic;
use hal::{twim, wdt, Timer, Twim};
use nrf52840_hal as hal;

/// Polls of EVENTS_HFCLKSTARTED before giving up on the crystal (≥ 10 ms at 64 MHz; the
/// crystal starts in ≈ 0.36 ms).
pub const HFXO_POLLS: u32 = 200_000;
/// Polls of UARTE0's EVENTS_RXTO after STOPRX (≥ 1 ms at 64 MHz; one character at 115 200 Bd
/// is 87 µs).
pub const UARTE_STOP_POLLS: u32 = 20_000;
/// TWIM0 FREQUENCY: nRF52840 erratum 219 (at the 400 kHz setting the SCL low time is below the
/// I2C minimum); Nordic's fix is this 390 kHz value.
pub const TWIM_FREQUENCY_390K: u32 = 0x0620_0000;

/// The four LEDs (RGB active low).
pub struct Leds {
    /// The yellow LED on D13 (P0.13), active high.
    pub d13: Pin<Output<PushPull>>,
    /// The RGB LED's red (P0.24).
    pub red: Pin<Output<PushPull>>,
    /// Its green (P0.16).
    pub green: Pin<Output<PushPull>>,
    /// Its blue (P0.06).
    pub blue: Pin<Output<PushPull>>,
}

impl Leds {
    /// Shows a pattern's state.
    pub fn show(&mut self, l: Lights) {
        let set = |p: &mut Pin<Output<PushPull>>, on: bool| {
            let _ = if on { p.set_high() } else { p.set_low() };
        };
        set(&mut self.d13, l.d13);
        set(&mut self.red, !l.red);
        set(&mut self.green, !l.green);
        set(&mut self.blue, !l.blue);
    }
}

/// Microseconds since boot from TIMER1, free-running at 1 MHz in 32-bit mode with no shortcut,
/// so that it wraps at exactly 2³² µs (71.6 min); extended to 64 bits (read more often than
/// that: the loop runs every 2 ms).
pub struct Clock {
    timer: pac::TIMER1,
    last: u32,
    high: u64,
}

impl Clock {
    /// Starts TIMER1 from 0.
    pub fn start(timer: pac::TIMER1) -> Self {
        // SAFETY (all writes): TIMER1 is ours; values from the PS (PRESCALER 4: 16 MHz / 2⁴).
        timer.tasks_stop.write(|w| unsafe { w.bits(1) });
        timer.shorts.reset();
        timer.intenclr.write(|w| unsafe { w.bits(u32::MAX) });
        timer.mode.write(|w| w.mode().timer());
        timer.bitmode.write(|w| w.bitmode()._32bit());
        timer.prescaler.write(|w| unsafe { w.prescaler().bits(4) });
        timer.tasks_clear.write(|w| unsafe { w.bits(1) });
        timer.tasks_start.write(|w| unsafe { w.bits(1) });
        Self { timer, last: 0, high: 0 }
    }

    /// Microseconds since [`Clock::start`]. (Out of line: inlined at its calls it cost 0.3 KiB.)
    #[inline(never)]
    pub fn now_us(&mut self) -> u64 {
        // SAFETY: CAPTURE[0] copies the counter into CC[0].
        self.timer.tasks_capture[0].write(|w| unsafe { w.bits(1) });
        let v = self.timer.cc[0].read().bits();
        if v < self.last {
            self.high += 1 << 32;
        }
        self.last = v;
        self.high + v as u64
    }

    /// Milliseconds since [`Clock::start`], wrapping at 2³² ms (49.7 days), by 32-bit division
    /// (`2³² µs = 4 294 967 ms + 296 µs`; no 64-bit division linked).
    pub fn now_ms(&mut self) -> u32 {
        let us = self.now_us();
        let (h, l) = ((us >> 32) as u32, us as u32);
        h.wrapping_mul(4_294_967).wrapping_add(l / 1000).wrapping_add(h.wrapping_mul(296).wrapping_add(l % 1000) / 1000)
    }

    /// The time since [`Clock::start`].
    pub fn now(&mut self) -> Time {
        Time::from_us(self.now_us() as i64)
    }
}

/// Busy waits on [`Clock`] (the sensor's reset; at most tens of ms, below the watchdog's 2 s).
pub struct Wait<'a>(pub &'a mut Clock);

impl DelayNs for Wait<'_> {
    fn delay_ns(&mut self, ns: u32) {
        let end = self.0.now_us() + ns.div_ceil(1000) as u64;
        while self.0.now_us() < end {}
    }
}

/// TWIM0 as the sensor's bus. After a failed transfer (e.g. an address NACK) the TWIM is
/// disabled and enabled again before the next one: a TWIM that received a STOP task while idle
/// fails the transfers that follow (embassy-rs/embassy #6722), which would spoil the Rev2 probe
/// at 0x68 that follows a NACK at 0x6B.
pub struct Bus(pub Twim<pac::TWIM0>);

impl ErrorType for Bus {
    type Error = twim::Error;
}

impl I2c for Bus {
    fn transaction(&mut self, address: u8, operations: &mut [Operation<'_>]) -> Result<(), Self::Error> {
        let r = self.0.transaction(address, operations);
        if r.is_err() {
            self.0.disable();
            // Let the bus go idle: 30 µs at 64 MHz, more than one byte time at 390 kHz (23 µs).
            cortex_m::asm::delay(64 * 30);
            self.0.enable();
        }
        r
    }
}

/// Puts what the stock Arduino bootloader leaves running into a known state: it jumps here
/// with the MPU on (flash read/execute only: a store to the record pages would fault), UARTE0
/// receiving, PWM0 driving P0.13, RTC1 running with its interrupt enabled, and interrupts
/// enabled in the NVIC whose handlers this firmware does not have. Nothing here relies on a
/// reset value.
pub fn quiesce(p: &pac::Peripherals, core: &mut cortex_m::Peripherals) {
    // SAFETY (whole function): writes to peripherals this firmware owns, values from the PS and
    // the ARMv7-M ARM; no other code runs yet.
    unsafe {
        core.MPU.ctrl.write(0);
        core.SYST.csr.write(0);
        for i in 0..2 {
            core.NVIC.icer[i].write(u32::MAX);
            core.NVIC.icpr[i].write(u32::MAX);
        }
        // ICSR.PENDSTCLR: no stale SysTick.
        core.SCB.icsr.write(1 << 25);
    }
    cortex_m::asm::dsb();
    cortex_m::asm::isb();

    let u = &p.UARTE0;
    if u.enable.read().bits() != 0 {
        u.events_rxto.write(|w| unsafe { w.bits(0) });
        u.tasks_stoprx.write(|w| unsafe { w.bits(1) });
        u.tasks_stoptx.write(|w| unsafe { w.bits(1) });
        for _ in 0..UARTE_STOP_POLLS {
            if u.events_rxto.read().bits() != 0 {
                break;
            }
        }
    }
    u.intenclr.write(|w| unsafe { w.bits(u32::MAX) });
    u.enable.write(|w| w.enable().disabled());
    // Pins disconnected (PSEL.CONNECT = 1).
    u.psel.txd.write(|w| unsafe { w.bits(u32::MAX) });
    u.psel.rxd.write(|w| unsafe { w.bits(u32::MAX) });
    u.psel.rts.write(|w| unsafe { w.bits(u32::MAX) });
    u.psel.cts.write(|w| unsafe { w.bits(u32::MAX) });

    let r = &p.RTC1;
    r.tasks_stop.write(|w| unsafe { w.bits(1) });
    r.intenclr.write(|w| unsafe { w.bits(u32::MAX) });
    r.evtenclr.write(|w| unsafe { w.bits(u32::MAX) });

    let pwm = &p.PWM0;
    pwm.tasks_stop.write(|w| unsafe { w.bits(1) });
    pwm.enable.write(|w| w.enable().disabled());
    for out in pwm.psel.out.iter() {
        out.write(|w| unsafe { w.bits(u32::MAX) });
    }

    // P1.00 (the I2C pull-ups' enable) is also TRACEDATA0: no trace on the pins.
    p.CLOCK.traceconfig.write(|w| unsafe { w.bits(0) });
}

/// What the UICR and the start of the flash say about the bootloader.
pub fn flash_map(uicr: &pac::UICR) -> FlashMap {
    let nrffw0 = uicr.nrffw[0].read().bits();
    // SAFETY: aligned reads of mapped flash (0x4: the vector table at 0x0; a bootloader's
    // vector table only where UICR says one starts, inside the 1 MiB flash).
    let word = |a: u32| unsafe { core::ptr::read_volatile(a as *const u32) };
    let bootloader_entry = (nrffw0 < 0x10_0000 && nrffw0.is_multiple_of(4)).then(|| word(nrffw0 + 4));
    FlashMap { nrffw0, nrffw1: uicr.nrffw[1].read().bits(), reset_vector_0: word(4), bootloader_entry }
}

/// Starts the 32 MHz crystal, the time base of every gyro integral, clearing a stale
/// HFCLKSTARTED first. Bounded. A crystal that already runs (the stock bootloader starts it) is
/// taken as it is (HFCLKSTAT: source Xtal, running), without relying on a start task raising
/// HFCLKSTARTED again.
pub fn start_hfxo(clock: &pac::CLOCK) -> bool {
    let stat = clock.hfclkstat.read();
    if stat.src().is_xtal() && stat.state().is_running() {
        return true;
    }
    // SAFETY: CLOCK is ours; event and task registers take 0 / 1.
    clock.events_hfclkstarted.write(|w| unsafe { w.bits(0) });
    clock.tasks_hfclkstart.write(|w| unsafe { w.bits(1) });
    for _ in 0..HFXO_POLLS {
        if clock.events_hfclkstarted.read().bits() != 0 {
            clock.events_hfclkstarted.write(|w| unsafe { w.bits(0) });
            let stat = clock.hfclkstat.read();
            return stat.src().is_xtal() && stat.state().is_running();
        }
    }
    false
}

/// TIMER2 interrupting every `period_us` to wake the loop from [`sleep`] (its handler calls
/// [`tick_handled`]); light sleep (SLEEPDEEP off).
pub fn start_tick(timer2: pac::TIMER2, period_us: u32, core: &mut cortex_m::Peripherals) -> Timer<pac::TIMER2, Periodic> {
    let mut tick = Timer::periodic(timer2);
    tick.enable_interrupt();
    tick.start(period_us);
    // SAFETY: the handler only clears its event; no shared state.
    unsafe { cortex_m::peripheral::NVIC::unmask(pac::Interrupt::TIMER2) };
    core.SCB.clear_sleepdeep();
    tick
}

/// The TIMER2 handler's work: it only wakes the loop. Clears the compare event and reads it
/// back, so that the write has reached the peripheral before the handler returns (else the
/// interrupt fires again).
pub fn tick_handled() {
    // SAFETY: this timer's own event register.
    let t = unsafe { &*pac::TIMER2::ptr() };
    t.events_compare[0].write(|w| unsafe { w.bits(0) });
    let _ = t.events_compare[0].read().bits();
}

/// FPSCR's cumulative exception flags (IOC, DZC, OFC, UFC, IXC, IDC).
const FPSCR_EXCEPTIONS: u32 = 0x9F;

/// Sleeps until the next interrupt. Erratum 87: an FPU exception flag left in FPSCR pends the
/// FPU interrupt, which keeps the CPU from sleeping; the flags and the pending bit are cleared
/// first, as Nordic's workaround does.
pub fn sleep() {
    let fpscr = cortex_m::register::fpscr::read().bits();
    if fpscr & FPSCR_EXCEPTIONS != 0 {
        // SAFETY: only the sticky exception flags change; rounding and modes stay.
        unsafe { cortex_m::register::fpscr::write(cortex_m::register::fpscr::Fpscr::from_bits(fpscr & !FPSCR_EXCEPTIONS)) };
    }
    cortex_m::peripheral::NVIC::unpend(pac::Interrupt::FPU);
    cortex_m::asm::wfi();
}

/// The watchdog, started with `timeout_s`, or recovered when it already runs (after a soft reset,
/// or left running by the firmware before an upload: it cannot be stopped); `None` when it is in
/// a state neither way handles (the caller resets).
pub fn watchdog(w: pac::WDT, timeout_s: u32) -> Option<wdt::WatchdogHandle<wdt::handles::Hdl0>> {
    match wdt::Watchdog::try_new(w) {
        Ok(mut w) => {
            w.set_lfosc_ticks(timeout_s * 32_768);
            Some(w.activate::<wdt::count::One>().handles.0)
        }
        Err(w) => wdt::Watchdog::try_recover::<wdt::count::One>(w).ok().map(|parts| parts.handles.0),
    }
}

/// The sensor rail and its bus, as Arduino's core brings them up: VDD_ENV (P0.22) in high drive
/// (against a voltage drop on the sensor rail), after ~10 ms the I2C pull-ups (P1.00), 5 ms,
/// then TWIM0 on SCL P0.15 / SDA P0.14 at 390 kHz (erratum 219). The IMU answers only after
/// both.
pub fn sensor_bus(
    vdd_env: p0::P0_22<Disconnected>,
    pullups: p1::P1_00<Disconnected>,
    scl: p0::P0_15<Disconnected>,
    sda: p0::P0_14<Disconnected>,
    twim0: pac::TWIM0,
    clock: &mut Clock,
) -> Bus {
    let _vdd_env = vdd_env.into_push_pull_output_drive(Level::High, DriveConfig::HighDrive0HighDrive1);
    let t0 = clock.now_us();
    while clock.now_us() - t0 < 10_000 {}
    let _pullups = pullups.into_push_pull_output(Level::High);
    let t0 = clock.now_us();
    while clock.now_us() - t0 < 5_000 {}
    let pins = twim::Pins { scl: scl.into_floating_input().degrade(), sda: sda.into_floating_input().degrade() };
    let bus = Bus(Twim::new(twim0, pins, twim::Frequency::K400));
    // SAFETY: a plain register write to the TWIM we own, before any transfer.
    unsafe { (*pac::TWIM0::ptr()).frequency.write(|w| w.bits(TWIM_FREQUENCY_390K)) };
    bus
}
