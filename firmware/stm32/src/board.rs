//! The Black Pill's side of the step path and the board I/O; every decision (when to step, which
//! way, what a closed switch means) is the logic crate's (`gonio_firmware::timed`,
//! `gonio_firmware::step_queue`).
//!
//! - STEP/DIR/ENABLE per axis on GPIOB (`gonio_firmware::pin_map`), so one write of GPIOB's BSRR
//!   applies everything the step timer decided at an instant; ENABLE driven active (low) from boot.
//! - TIM2 (32-bit, 1 MHz, counting the same microseconds as embassy-time) plays the `StepQueue`:
//!   one compare channel per axis (CC1..CC4), whose interrupt makes that axis's STEP rise or fall
//!   and schedules its next edge (`StepQueue::on_compare`).
//! - Home/limit switches on EXTI lines 1, 2, 3 and 5 (falling edge = closing, pull-ups): the EXTI
//!   interrupt calls `StepQueue::trip`, which stops every channel at once (compares disarmed, STEP
//!   pins forced low) if the controller armed that switch. Levels are read with `ExtiInput::is_low` for the controller's own checks.
//! - The detector is the **simple internal-ADC driver**: ADC1 on PA4..PA7, read with blocking
//!   conversions once the exposure time has elapsed (see [`BoardIo::poll_readout`]). The ADS131M04
//!   on SPI1 is the planned precision option (README).

use crate::exposure::ExposureTimer;
use embassy_stm32::adc::{Adc, AnyAdcChannel, SampleTime};
use embassy_stm32::exti::ExtiInput;
use embassy_stm32::gpio::Output;
use embassy_stm32::interrupt;
use embassy_stm32::mode::Blocking;
use embassy_stm32::pac;
use embassy_stm32::peripherals::ADC1;
use embassy_time::Instant;
use gonio_firmware::pin_map::{dir_bits, step_bits, DIR_BIT, STEP_BIT};
use gonio_firmware::step_queue::{reached, Edge, Pins, StepQueue, PULSE_TICKS};
use gonio_firmware::timed::{tick, SharedQueue};
use gonio_firmware::{Clock, Detector, Readout, Switches};
use gonio_shared::Axis;

/// SYSCLK; TIM2's clock is the APB1 timer clock, also 96 MHz (APB1 /2, timers x2).
pub const SYSCLK_HZ: u32 = 96_000_000;
/// TIM2 prescaler to 1 MHz: one tick per microsecond, the unit of `Hal::now_us`.
const TIM2_PSC: u16 = (SYSCLK_HZ / 1_000_000 - 1) as u16;

/// Conversions summed per channel at the end of an exposure.
pub const ADC_OVERSAMPLE: u32 = 8;
/// 144 ADC cycles + 12 = 6.5 us per conversion at the 24 MHz ADC clock (PCLK2 96 MHz / 4): ample for
/// a low-impedance source such as a transimpedance amplifier's output.
const ADC_SAMPLE_TIME: SampleTime = SampleTime::CYCLES144;

/// The queue the controller loop fills and the TIM2 / EXTI interrupts play and stop. Touched only
/// by priority-0 handlers (TIM2, EXTI), which nothing preempts, and by the loop inside a critical
/// section ([`CsQueue`]), so every access is exclusive without a lock in the step interrupt
/// (a lock and a `RefCell` there cost ~12 instructions per compare event).
static mut STEP_QUEUE: StepQueue = StepQueue::new();

/// The step queue, exclusively.
///
/// # Safety
/// Only from a priority-0 handler, or with interrupts masked.
#[inline(always)]
unsafe fn step_queue() -> &'static mut StepQueue {
    // SAFETY: exclusive by the caller's contract (see `STEP_QUEUE`).
    unsafe { &mut *core::ptr::addr_of_mut!(STEP_QUEUE) }
}

/// `Pins` as one GPIOB BSRR word (set bits low half, reset bits high half). Bit arithmetic rather
/// than a loop over a pin table: this runs in every step interrupt.
fn bsrr(p: Pins) -> u32 {
    (step_bits(p.step_high) | dir_bits(p.dir_increasing)) | ((step_bits(p.step_low) | dir_bits(p.dir_decreasing)) << 16)
}

fn apply(p: Pins) {
    if !p.is_empty() {
        pac::GPIOB.bsrr().write_value(pac::gpio::regs::Bsrr(bsrr(p)));
    }
}

/// TIM2's compare-interrupt enable and flag bits of the four channels (CC1..CC4 = bits 1..4).
const CC_BITS: u32 = 0b1_1110;

#[inline(always)]
fn write_bsrr(word: u32) {
    pac::GPIOB.bsrr().write_value(pac::gpio::regs::Bsrr(word));
}

/// Point channel `i`'s compare at `tick`. A tick already due (or due before the write lands) is
/// forced with a software compare event, so none is missed until the counter wraps; returns
/// whether it was.
#[inline(always)]
fn compare_at(i: usize, tick: u32) -> bool {
    let t = pac::TIM2;
    t.ccr(i).write_value(tick);
    let late = reached(tick, t.cnt().read());
    if late {
        t.egr().write(|e| e.set_ccg(i, true));
    }
    late
}

/// After the loop touched the queue: lower the STEP pins a stop left high, disarm the channels it
/// stopped, set the DIR pins of the channels it started and arm their compares.
fn sync_channels(q: &mut StepQueue) {
    let (lowered, kicked, disarmed) = (q.take_lowered(), q.take_kicked(), q.take_disarmed());
    if (lowered | kicked | disarmed) == 0 {
        return;
    }
    let t = pac::TIM2;
    let dir = q.dir_levels();
    apply(Pins {
        step_low: lowered,
        dir_increasing: kicked & dir,
        dir_decreasing: kicked & !dir,
        step_high: 0,
    });
    t.dier().modify(|d| d.0 &= !(u32::from(disarmed) << 1));
    // rc_w0: clear stale compare flags of the started channels only.
    t.sr().write_value(pac::timer::regs::SrGp16(!(u32::from(kicked) << 1)));
    for i in 0..4 {
        if kicked & (1 << i) != 0 && compare_at(i, q.compare_tick(i)) {
            q.note_late();
        }
    }
    t.dier().modify(|d| d.0 |= u32::from(kicked) << 1);
}

/// The queue inside a critical section; every access re-synchronises the channels, so a segment
/// the loop queued for an idle axis starts it.
pub struct CsQueue;

impl SharedQueue for CsQueue {
    fn with<R>(&self, f: impl FnOnce(&mut StepQueue) -> R) -> R {
        cortex_m::interrupt::free(|_| {
            // SAFETY: interrupts are masked.
            let q = unsafe { step_queue() };
            let r = f(q);
            sync_channels(q);
            r
        })
    }
}

/// Start TIM2 at 1 MHz with its counter on embassy-time's microseconds, and unmask the step and
/// switch interrupts (the step timer above everything else: its edges are the product).
pub fn start_step_timer(tim2: embassy_stm32::Peri<'static, embassy_stm32::peripherals::TIM2>) {
    use embassy_stm32::interrupt::{InterruptExt, Priority};
    let timer = embassy_stm32::timer::low_level::Timer::new(tim2);
    let t = pac::TIM2;
    t.psc().write_value(TIM2_PSC);
    t.arr().write_value(u32::MAX);
    // Load the prescaler, then set the counter (the update event clears it).
    t.egr().write(|e| e.set_ug(true));
    t.sr().write_value(pac::timer::regs::SrGp16(0));
    t.cnt().write_value(tick(Instant::now().as_micros()));
    timer.start();
    core::mem::forget(timer); // keep TIM2 clocked and running for good
    interrupt::TIM2.set_priority(Priority::P0);
    // USB's handler (embassy's default priority is also P0) must not hold up a step edge, nor
    // embassy-time's driver (TIM9 with `time-driver-any` on the F411, which shares its vector).
    interrupt::OTG_FS.set_priority(Priority::P1);
    interrupt::TIM1_BRK_TIM9.set_priority(Priority::P1);
    for irq in [interrupt::EXTI1, interrupt::EXTI2, interrupt::EXTI3, interrupt::EXTI9_5] {
        irq.set_priority(Priority::P0);
    }
    // SAFETY: the handlers below only touch TIM2, GPIOB's BSRR, the EXTI pending register and the
    // queue behind its critical-section mutex.
    unsafe {
        interrupt::TIM2.enable();
        for irq in [interrupt::EXTI1, interrupt::EXTI2, interrupt::EXTI3, interrupt::EXTI9_5] {
            irq.enable();
        }
    }
}

/// One compare channel per axis (CC1..CC4 = light, detector, tilt, azimuth): each event is a
/// rise or a fall of that axis's STEP pin (`StepQueue::on_compare`), then the channel's next
/// compare, or the channel is disarmed when its ring ran out. One BSRR write per event.
#[interrupt]
fn TIM2() {
    let t = pac::TIM2;
    let flags = t.sr().read().0 & t.dier().read().0 & CC_BITS;
    // rc_w0: writing 0 clears only the flags being served.
    t.sr().write_value(pac::timer::regs::SrGp16(!flags));
    // SAFETY: a priority-0 handler.
    let q = unsafe { step_queue() };
    let mut pending = flags >> 1;
    while pending != 0 {
        let i = pending.trailing_zeros() as usize & 3;
        pending &= pending - 1;
        let step = STEP_BIT[i];
        match q.on_compare(i) {
            Edge::Rise(_) => {
                write_bsrr(step);
                // The fall from the counter, not the scheduled tick: the pulse is PULSE_TICKS long
                // even when the interrupt was held up, and the compare cannot be missed (nothing
                // preempts this handler for 3 us between the read and the write).
                t.ccr(i).write_value(t.cnt().read().wrapping_add(PULSE_TICKS));
            }
            Edge::Fall(tick) => {
                write_bsrr(step << 16);
                if compare_at(i, tick) {
                    q.note_late();
                }
            }
            Edge::FallDir(tick) => {
                let dir = if q.dir_levels() & (1 << i) != 0 {
                    DIR_BIT[i]
                } else {
                    DIR_BIT[i] << 16
                };
                write_bsrr(step << 16 | dir);
                if compare_at(i, tick) {
                    q.note_late();
                }
            }
            Edge::Ended => {
                write_bsrr(step << 16);
                t.dier().modify(|d| d.set_ccie(i, false));
            }
        }
    }
}

/// An EXTI line fired: stop playback if the switch is armed.
fn switch_closed_irq(lines: u32) {
    let pending = pac::EXTI.pr(0).read().0 & lines;
    pac::EXTI.pr(0).write_value(pac::exti::regs::Lines(pending));
    // EXTI line -> axis bit: lines 1, 2, 3 (PA1 light, PA2 detector, PA3 tilt) -> bits 0, 1, 2;
    // line 5 (PB5 azimuth) -> bit 3.
    let closed = ((pending >> 1) & 0b0111) as u8 | ((pending >> 2) & 0b1000) as u8;
    // SAFETY: a priority-0 handler.
    let q = unsafe { step_queue() };
    let pins = q.trip(closed);
    if q.tripped() != 0 {
        // Every channel stops at once; its STEP pin is forced low below.
        pac::TIM2.dier().modify(|d| d.0 &= !CC_BITS);
    }
    apply(pins);
}

#[interrupt]
fn EXTI1() {
    switch_closed_irq(1 << 1);
}

#[interrupt]
fn EXTI2() {
    switch_closed_irq(1 << 2);
}

#[interrupt]
fn EXTI3() {
    switch_closed_irq(1 << 3);
}

#[interrupt]
fn EXTI9_5() {
    switch_closed_irq(1 << 5);
}

/// The four axes' output pins, indexed by `Axis::index`; owned so they stay configured. The step
/// interrupt writes them through GPIOB's BSRR.
#[allow(dead_code, reason = "kept only so the pins stay configured and driven")]
pub struct AxisPins {
    pub step: [Output<'static>; 4],
    pub dir: [Output<'static>; 4],
    /// Held low (driver enabled) for as long as the binary runs.
    pub enable: [Output<'static>; 4],
}

pub struct AdcDetector {
    pub adc: Adc<'static, ADC1>,
    /// One per reported channel (`gonio_shared::msg::caps::MAX_CHANNELS` = 4).
    pub channels: [AnyAdcChannel<'static, ADC1>; 4],
}

/// The board I/O besides STEP/DIR (which `QueuedHal` queues for TIM2): switch levels, the detector, the clock.
pub struct BoardIo {
    /// Home / limit switch per axis, closed = low, each on its own EXTI line.
    limit: [ExtiInput<'static, Blocking>; 4],
    detector: AdcDetector,
    exposure: ExposureTimer,
    #[allow(dead_code, reason = "kept only so the pins stay configured and driven")]
    pins: AxisPins,
}

impl BoardIo {
    pub fn new(pins: AxisPins, limit: [ExtiInput<'static, Blocking>; 4], detector: AdcDetector) -> Self {
        Self {
            limit,
            detector,
            exposure: ExposureTimer::new(),
            pins,
        }
    }

    /// One conversion pass over every channel, `ADC_OVERSAMPLE` times, summed per channel, then
    /// scaled by the exposure so the counts grow with exposure time like an integrating detector's:
    /// `counts = sum * exposure_us / 1000` = mean 12-bit code x 8 x exposure in ms (saturating).
    fn read_detector(&mut self, exposure_us: u32) -> Readout {
        let mut sums = [0u32; 4];
        for _ in 0..ADC_OVERSAMPLE {
            for (sum, channel) in sums.iter_mut().zip(self.detector.channels.iter_mut()) {
                *sum += u32::from(self.detector.adc.blocking_read(channel, ADC_SAMPLE_TIME));
            }
        }
        let mut readout = Readout::new();
        for sum in sums {
            let scaled = u64::from(sum) * u64::from(exposure_us) / 1000;
            // Cannot fail: `sums` has exactly MAX_CHANNELS entries.
            let _ = readout.push(u32::try_from(scaled).unwrap_or(u32::MAX));
        }
        readout
    }
}

impl Clock for BoardIo {
    fn now_us(&self) -> u64 {
        Instant::now().as_micros()
    }
}

impl Switches for BoardIo {
    fn limit_closed(&self, axis: Axis) -> bool {
        self.limit.get(axis.index()).is_some_and(ExtiInput::is_low)
    }
}

impl Detector for BoardIo {
    fn start_exposure(&mut self, exposure_us: u32) {
        let now = self.now_us();
        self.exposure.start(now, exposure_us);
    }

    /// `None` until the exposure time has passed; then the blocking ADC reads (4 channels x
    /// `ADC_OVERSAMPLE` conversions, about 0.3 ms) and the readout.
    fn poll_readout(&mut self) -> Option<Readout> {
        let now = self.now_us();
        let exposure_us = self.exposure.take_done(now)?;
        Some(self.read_detector(exposure_us))
    }
}
