//! The QEMU build's board: what QEMU's netduinoplus2 (STM32F405) emulates stands in for the Black
//! Pill's timers, pins and sensors; every decision is still the logic crate's.
//!
//! - **Time**: an embassy-time driver (QEMU has no RCC model, so `embassy_stm32::init` cannot run,
//!   and its timers raise no compare interrupts): `now` is TIM2's free-running microsecond
//!   counter, and SysTick interrupts every `TICK_US` to fire the alarms.
//! - **Steps**: the same SysTick interrupt plays the `StepQueue` with `StepQueue::service`, every
//!   edge due by then (the board's TIM2 compare channels play each at its own microsecond; here
//!   an edge is up to `TICK_US` late, which the queue counts in `stats().late`).
//! - **Motors and switches**: a stand-in instrument follows the played STEP/DIR edges; its switches
//!   close at fixed step positions (`SWITCHES`), and a switch that closes trips the queue in the
//!   same interrupt, as the board's EXTI handler does.
//! - **Detector**: a stand-in sample whose counts are a fixed function of the axis positions and
//!   the exposure (`stand_in_counts`): the same readings every run.

use crate::exposure::ExposureTimer;
use core::cell::{Cell, RefCell};
use core::task::Waker;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embassy_time_queue_utils::Queue;
use gonio_firmware::step_queue::StepQueue;
use gonio_firmware::timed::{tick, SharedQueue};
use gonio_firmware::{Clock, Detector, Readout, Switches};

use gonio_shared::Axis;

/// The core clock of QEMU's netduinoplus2 model (its SYSCLK; nothing to set up, the RCC is not
/// emulated). SysTick counts it.
pub const SYSCLK_HZ: u32 = 168_000_000;
/// SysTick period: how often the time driver checks its alarms and the step queue is played.
pub const TICK_US: u32 = 20;
const SYST_RELOAD: u32 = TICK_US * (SYSCLK_HZ / 1_000_000) - 1;
/// QEMU's STM32 timers count a 1 GHz clock (virtual nanoseconds): /1000 = microseconds.
const TIM2_PSC: u32 = 999;

const SYST_CSR: usize = 0xE000_E010;
const SYST_RVR: usize = 0xE000_E014;
const SYST_CVR: usize = 0xE000_E018;
/// SysTick control: counter on, interrupt on, core clock.
const SYST_ENABLE_TICKINT_CORECLK: u32 = 0b111;
const TIM2: usize = 0x4000_0000;
const TIM2_CR1: usize = TIM2;
const TIM2_EGR: usize = TIM2 + 0x14;
const TIM2_CNT: usize = TIM2 + 0x24;
const TIM2_PSC_REG: usize = TIM2 + 0x28;
const TIM2_ARR: usize = TIM2 + 0x2C;

fn rd(addr: usize) -> u32 {
    // SAFETY: a memory-mapped register of the emulated Cortex-M4 / STM32F405, 32-bit access.
    unsafe { core::ptr::read_volatile(addr as *const u32) }
}

fn wr(addr: usize, v: u32) {
    // SAFETY: as `rd`.
    unsafe { core::ptr::write_volatile(addr as *mut u32, v) }
}

/// The embassy-time driver: TIM2's free-running 32-bit microsecond counter, widened to 64 bits
/// (QEMU derives the counter from its virtual clock, so no time is lost when the host is too busy
/// to deliver every SysTick; counting SysTick periods lost up to two thirds of them).
struct SysTickDriver {
    /// The counter when last read, and the wraps seen.
    counter: Mutex<CriticalSectionRawMutex, Cell<(u32, u32)>>,
    /// The next alarm (embassy-time ticks = microseconds); `u64::MAX` = none.
    alarm: Mutex<CriticalSectionRawMutex, Cell<u64>>,
    queue: Mutex<CriticalSectionRawMutex, RefCell<Queue>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: SysTickDriver = SysTickDriver {
    counter: Mutex::new(Cell::new((0, 0))),
    alarm: Mutex::new(Cell::new(u64::MAX)),
    queue: Mutex::new(RefCell::new(Queue::new())),
});

impl SysTickDriver {
    /// Microseconds since boot. Read at least every SysTick, far more often than the counter
    /// wraps (71 minutes).
    fn now_us(&self) -> u64 {
        self.counter.lock(|c| {
            let (last, mut wraps) = c.get();
            let now = rd(TIM2_CNT);
            if now < last {
                wraps = wraps.wrapping_add(1);
            }
            c.set((now, wraps));
            (u64::from(wraps) << 32) | u64::from(now)
        })
    }

    /// A SysTick: wake the timers that are due.
    fn on_tick(&self) -> u64 {
        let now = self.now_us();
        if now >= self.alarm.lock(Cell::get) {
            let next = self.queue.lock(|q| q.borrow_mut().next_expiration(now));
            self.alarm.lock(|a| a.set(next));
        }
        now
    }
}

impl embassy_time_driver::Driver for SysTickDriver {
    fn now(&self) -> u64 {
        self.now_us()
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        self.queue.lock(|q| {
            let mut q = q.borrow_mut();
            if q.schedule_wake(at, waker) {
                // Wakes at once what is already due, and gives the next alarm.
                let next = q.next_expiration(self.now_us());
                self.alarm.lock(|a| a.set(next));
            }
        });
    }
}

/// Start TIM2 (the microsecond counter) and SysTick (alarms and step playback, at the highest
/// priority, as the board's TIM2).
pub fn start_time() {
    wr(TIM2_PSC_REG, TIM2_PSC);
    wr(TIM2_ARR, u32::MAX);
    wr(TIM2_EGR, 1); // UG: load the prescaler
    wr(TIM2_CNT, 0);
    wr(TIM2_CR1, 1); // CEN
    wr(SYST_RVR, SYST_RELOAD);
    wr(SYST_CVR, 0);
    wr(SYST_CSR, SYST_ENABLE_TICKINT_CORECLK);
}

/// The queue the controller loop fills and the SysTick interrupt plays. Touched only by SysTick
/// (nothing preempts it: priority 0) and by the loop inside a critical section ([`CsQueue`]).
static mut STEP_QUEUE: StepQueue = StepQueue::new();

/// The stand-in instrument's axis positions (steps), moved by the played edges. Same access rule
/// as `STEP_QUEUE`.
static mut POSITIONS: [i32; 4] = [0; 4];

/// The step queue, exclusively.
///
/// # Safety
/// Only from the SysTick handler, or with interrupts masked.
unsafe fn step_queue() -> &'static mut StepQueue {
    // SAFETY: exclusive by the caller's contract (see `STEP_QUEUE`).
    unsafe { &mut *core::ptr::addr_of_mut!(STEP_QUEUE) }
}

/// The stand-in's positions, exclusively.
///
/// # Safety
/// As [`step_queue`].
unsafe fn positions_mut() -> &'static mut [i32; 4] {
    // SAFETY: as `step_queue`.
    unsafe { &mut *core::ptr::addr_of_mut!(POSITIONS) }
}

fn positions() -> [i32; 4] {
    // SAFETY: interrupts are masked.
    cortex_m::interrupt::free(|_| unsafe { *positions_mut() })
}

/// The queue inside a critical section. Playback follows `StepQueue::running` (nothing to arm);
/// the board's channel bookkeeping (lowered, disarmed) is taken and has nothing to act on here.
pub struct CsQueue;

impl SharedQueue for CsQueue {
    fn with<R>(&self, f: impl FnOnce(&mut StepQueue) -> R) -> R {
        cortex_m::interrupt::free(|_| {
            // SAFETY: interrupts are masked.
            let q = unsafe { step_queue() };
            let r = f(q);
            q.take_lowered();
            q.take_disarmed();
            r
        })
    }
}

/// Where a stand-in switch closes.
#[derive(Clone, Copy)]
enum Switch {
    AtOrAbove(i32),
    AtOrBelow(i32),
    /// A continuous axis's index mark, at step 0.
    Index,
}

/// The stand-in instrument's switches, in `Axis::index` order: the home-side limits of
/// `.ci/qemu-instrument.toml` (2000 steps per turn: light +175 deg max, detector -175 deg min,
/// tilt -85 deg min; the azimuth's index at 0). An instrument file that says otherwise does not
/// home on it (`Fault::HomeNotFound`), as on a real instrument.
const SWITCHES: [Switch; 4] = [
    Switch::AtOrAbove(972),
    Switch::AtOrBelow(-972),
    Switch::AtOrBelow(-472),
    Switch::Index,
];

fn switch_closed(i: usize, pos: i32) -> bool {
    match SWITCHES.get(i) {
        Some(Switch::AtOrAbove(s)) => pos >= *s,
        Some(Switch::AtOrBelow(s)) => pos <= *s,
        Some(Switch::Index) => pos == 0,
        None => false,
    }
}

#[cortex_m_rt::exception]
fn SysTick() {
    let now = DRIVER.on_tick();
    // SAFETY: the SysTick handler.
    let (q, pos) = unsafe { (step_queue(), positions_mut()) };
    let (pins, _) = q.service(tick(now));
    if pins.step_high == 0 {
        return;
    }
    // The motors follow the rising edges in the DIR levels the queue set; a switch that closes
    // trips playback, as its EXTI interrupt does on the board.
    let dir = q.dir_levels();
    let mut closed = 0u8;
    for (i, p) in pos.iter_mut().enumerate() {
        let bit = 1u8 << i;
        if pins.step_high & bit == 0 {
            continue;
        }
        let was = switch_closed(i, *p);
        *p = p.wrapping_add(if dir & bit != 0 { 1 } else { -1 });
        if !was && switch_closed(i, *p) {
            closed |= bit;
        }
    }
    if closed != 0 {
        q.trip(closed);
    }
}

/// Counts per millisecond of exposure: a dark floor, a lobe, and a channel-to-channel tint.
const DARK_PER_MS: f32 = 200.0;
const LOBE_PER_MS: f32 = 4000.0;
/// Steps per radian of every stand-in axis (2000 steps per turn).
const STEPS_PER_RAD: f32 = 2000.0 / core::f32::consts::TAU;

/// The stand-in sample: brightest where light + detector = 2 x tilt (in angle), a Lorentzian lobe
/// of ~0.2 rad half width around it. Not physics: a fixed, smooth function of the pose.
fn stand_in_counts(pos: [i32; 4], exposure_us: u32) -> Readout {
    let [light, detector, tilt, _] = pos;
    let off = (light + detector - 2 * tilt) as f32 / STEPS_PER_RAD;
    let lobe = 1.0 / (1.0 + 25.0 * off * off);
    let ms = exposure_us as f32 / 1000.0;
    let mut readout = Readout::new();
    for tint in [1.0, 0.9, 0.8, 0.7] {
        // Cannot fail: four channels, `MAX_CHANNELS` = 4.
        let _ = readout.push(((DARK_PER_MS + LOBE_PER_MS * lobe) * tint * ms) as u32);
    }
    readout
}

/// The board I/O besides STEP/DIR (which `QueuedHal` queues for SysTick): the stand-in switches
/// and detector, the clock.
pub struct StandIn {
    exposure: ExposureTimer,
}

impl StandIn {
    pub const fn new() -> Self {
        Self {
            exposure: ExposureTimer::new(),
        }
    }
}

impl Clock for StandIn {
    fn now_us(&self) -> u64 {
        DRIVER.now_us()
    }
}

impl Switches for StandIn {
    fn limit_closed(&self, axis: Axis) -> bool {
        let i = axis.index();
        positions().get(i).is_some_and(|p| switch_closed(i, *p))
    }
}

impl Detector for StandIn {
    fn start_exposure(&mut self, exposure_us: u32) {
        let now = self.now_us();
        self.exposure.start(now, exposure_us);
    }

    /// `None` until the exposure time has passed; then the stand-in's readout at the pose reached.
    fn poll_readout(&mut self) -> Option<Readout> {
        let now = self.now_us();
        let exposure_us = self.exposure.take_done(now)?;
        Some(stand_in_counts(positions(), exposure_us))
    }
}
