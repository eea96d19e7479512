//! Instructions per step of the firmware's step path, counted on the real thumbv7em code under
//! QEMU (`qemu-system-arm -machine netduinoplus2 -icount shift=0`: TIM2 with PSC = 0 then counts
//! one per guest instruction). Run by `.ci/step-cost`.
//!
//! What runs is the shipped logic (`gonio_firmware`: `QueuedHal::run` -> `Device::poll` -> the
//! segment generator; `StepQueue::on_compare` in the compare interrupt), built with the firmware's
//! release profile, around the same register work as `firmware/stm32/src/board.rs` (the critical
//! section, the channel sync after each queue access, GPIOB's BSRR, the CCR write and the late
//! check). QEMU's STM32 timer model has no compare interrupts, so this harness keeps a virtual
//! microsecond clock and calls the interrupt body itself at each channel's compare tick, with the
//! flags the hardware would raise; each call, and each turn of the controller loop, is bracketed
//! by two reads of TIM2's counter. The scan: the reference instrument homes, then makes the eight
//! four-axis moves the README's reference scan figures were taken on.
#![no_std]
#![no_main]

use core::fmt::Write;
use cortex_m_rt::entry;
use gonio_firmware::step_queue::{reached, Edge, Pins, StepQueue, PULSE_TICKS};
use gonio_firmware::timed::{tick, QueuedHal, SharedQueue};
use gonio_firmware::{Clock, Detector, Device, Readout, Switches};
use gonio_shared::frame::{encode, MAX_WIRE_FRAME};
use gonio_shared::instrument::{InstrumentConfig, AXES};
use gonio_shared::msg::{Direction, Hello, HostMsg, PlanChunk};
use gonio_shared::Axis;

const TIM2: u32 = 0x4000_0000;
const TIM_DIER: u32 = TIM2 + 0x0C;
const TIM_SR: u32 = TIM2 + 0x10;
const TIM_EGR: u32 = TIM2 + 0x14;
const TIM_CNT: u32 = TIM2 + 0x24;
const TIM_PSC: u32 = TIM2 + 0x28;
const TIM_ARR: u32 = TIM2 + 0x2C;
const TIM_CCR1: u32 = TIM2 + 0x34;
const GPIOB_BSRR: u32 = 0x4002_0418;
const CC_BITS: u32 = 0b1_1110;

/// Cycles per instruction assumed for the CPU share (flash wait states behind the ART
/// accelerator), and cycles of exception entry plus exit per interrupt.
const CPI: f32 = 1.3;
const EXCEPTION_CYCLES: f32 = 24.0;
/// The board's core clock.
const SYSCLK_HZ: f32 = 96.0e6;
/// The window the peak step rate is taken over.
const PEAK_WINDOW_US: u64 = 10_000;

fn rd(a: u32) -> u32 {
    // SAFETY: a memory-mapped register of the emulated STM32F405.
    unsafe { core::ptr::read_volatile(a as *const u32) }
}

fn wr(a: u32, v: u32) {
    // SAFETY: as `rd`.
    unsafe { core::ptr::write_volatile(a as *mut u32, v) }
}

/// The virtual microsecond clock the interrupt body reads instead of the counter (which counts
/// instructions here): one load, as the board's counter read.
static mut NOW: u32 = 0;

#[inline(always)]
fn now_tick() -> u32 {
    // SAFETY: single-threaded harness; a volatile load so it costs what a register read costs.
    unsafe { core::ptr::read_volatile(core::ptr::addr_of!(NOW)) }
}

static mut STEP_QUEUE: StepQueue = StepQueue::new();

/// The queue, exclusively (as on the board: from the "interrupt", or with interrupts masked).
#[inline(always)]
fn step_queue() -> &'static mut StepQueue {
    // SAFETY: single-threaded harness; every caller finishes with it before the next.
    unsafe { &mut *core::ptr::addr_of_mut!(STEP_QUEUE) }
}

// ---- The board's step code (firmware/stm32/src/board.rs), on raw registers. ----

fn step_pins(axes: u8) -> u32 {
    let a = u32::from(axes);
    (a & 0b0011) | ((a & 0b1100) << 4)
}

fn dir_pins(axes: u8) -> u32 {
    u32::from(axes & 0b1111) << 12
}

fn bsrr(p: Pins) -> u32 {
    (step_pins(p.step_high) | dir_pins(p.dir_increasing)) | ((step_pins(p.step_low) | dir_pins(p.dir_decreasing)) << 16)
}

fn apply(p: Pins) {
    if !p.is_empty() {
        wr(GPIOB_BSRR, bsrr(p));
    }
}

const STEP_PIN: [u32; 4] = [1 << 0, 1 << 1, 1 << 6, 1 << 7];
const DIR_PIN: [u32; 4] = [1 << 12, 1 << 13, 1 << 14, 1 << 15];

#[inline(always)]
fn compare_at(i: usize, t: u32) -> bool {
    wr(TIM_CCR1 + 4 * i as u32, t);
    let late = reached(t, now_tick());
    if late {
        wr(TIM_EGR, 1 << (i + 1));
    }
    late
}

fn sync_channels(q: &mut StepQueue) {
    let (lowered, kicked, disarmed) = (q.take_lowered(), q.take_kicked(), q.take_disarmed());
    if (lowered | kicked | disarmed) == 0 {
        return;
    }
    let dir = q.dir_levels();
    apply(Pins {
        step_low: lowered,
        dir_increasing: kicked & dir,
        dir_decreasing: kicked & !dir,
        step_high: 0,
    });
    wr(TIM_DIER, rd(TIM_DIER) & !(u32::from(disarmed) << 1));
    wr(TIM_SR, !(u32::from(kicked) << 1));
    for i in 0..4 {
        if kicked & (1 << i) != 0 && compare_at(i, q.compare_tick(i)) {
            q.note_late();
        }
    }
    wr(TIM_DIER, rd(TIM_DIER) | (u32::from(kicked) << 1));
}

struct CsQueue;

impl SharedQueue for CsQueue {
    fn with<R>(&self, f: impl FnOnce(&mut StepQueue) -> R) -> R {
        cortex_m::interrupt::free(|_| {
            let q = step_queue();
            let r = f(q);
            sync_channels(q);
            r
        })
    }
}

/// The TIM2 handler's body; `flags` are the compare flags the hardware would have raised (QEMU's
/// timer raises none).
#[inline(never)]
fn tim2_isr(flags: u32) {
    // As many instructions as the board's `SR & DIER & CC_BITS` (QEMU raises no compare flag).
    let flags = flags | (rd(TIM_SR) & rd(TIM_DIER));
    wr(TIM_SR, !flags);
    let q = step_queue();
    let mut pending = flags >> 1;
    while pending != 0 {
        let i = pending.trailing_zeros() as usize & 3;
        pending &= pending - 1;
        let step = STEP_PIN[i];
        match q.on_compare(i) {
            Edge::Rise(_) => {
                wr(GPIOB_BSRR, step);
                wr(TIM_CCR1 + 4 * i as u32, now_tick().wrapping_add(PULSE_TICKS));
            }
            Edge::Fall(t) => {
                wr(GPIOB_BSRR, step << 16);
                if compare_at(i, t) {
                    q.note_late();
                }
            }
            Edge::FallDir(t) => {
                let dir = if q.dir_levels() & (1 << i) != 0 {
                    DIR_PIN[i]
                } else {
                    DIR_PIN[i] << 16
                };
                wr(GPIOB_BSRR, step << 16 | dir);
                if compare_at(i, t) {
                    q.note_late();
                }
            }
            Edge::Ended => {
                wr(GPIOB_BSRR, step << 16);
                wr(TIM_DIER, rd(TIM_DIER) & !(1 << (i + 1)));
            }
        }
    }
}

// ---- The simulated instrument. ----

/// Virtual real time; motors move on played steps; switches close at the home positions.
struct SimBoard {
    real: u64,
    pos: [i64; 4],
    dir: [bool; 4],
    /// Home position and side per axis (`None`: a continuous axis's index at 0).
    homes: [(i64, Option<gonio_shared::HomeSide>); 4],
}

impl SimBoard {
    /// A switch level, as cheap as the board's pin read: the home positions are worked out once.
    fn closed(&self, axis: Axis) -> bool {
        let i = axis.index();
        let (home, side) = self.homes[i];
        match side {
            None => self.pos[i] == 0,
            Some(gonio_shared::HomeSide::Max) => self.pos[i] >= home,
            Some(gonio_shared::HomeSide::Min) => self.pos[i] <= home,
        }
    }
}

impl Clock for SimBoard {
    fn now_us(&self) -> u64 {
        self.real
    }
}

impl Switches for SimBoard {
    fn limit_closed(&self, axis: Axis) -> bool {
        self.closed(axis)
    }
}

impl Detector for SimBoard {
    fn start_exposure(&mut self, _: u32) {}
    fn poll_readout(&mut self) -> Option<Readout> {
        Some(Readout::new())
    }
}

#[derive(Default)]
struct Costs {
    isr: u64,
    interrupts: u64,
    loop_: u64,
    polls: u64,
    /// Steps in the current and the busiest `PEAK_WINDOW_US` window.
    window: (u64, u32),
    peak: u32,
}

/// Instructions spent between two counter reads with nothing in between.
fn counter_overhead() -> u32 {
    let a = rd(TIM_CNT);
    let b = rd(TIM_CNT);
    b.wrapping_sub(a)
}

type Hal = QueuedHal<SimBoard, CsQueue>;

fn run(dev: &mut Device, hal: &mut Hal, costs: &mut Costs, overhead: u32, seq: &mut u16) {
    let mut run_at = Some(hal.board.real);
    let mut host_at = hal.board.real;
    loop {
        let now = hal.board.real;
        // A present host: a frame every 5 s, or the device holds the scan (`HOST_SILENT_US`).
        if now >= host_at + 5_000_000 {
            host_at = now;
            send(dev, hal, seq, HostMsg::GetStatus);
            run_at = Some(now);
        }
        let isr_at = step_queue().next_wake(tick(now)).map(|w| {
            // A compare "behind" the counter is one already due.
            let ahead = w.wrapping_sub(tick(now));
            if reached(w, tick(now)) {
                now
            } else {
                now + u64::from(ahead)
            }
        });
        let Some(t) = [isr_at, run_at].into_iter().flatten().min() else {
            return;
        };
        hal.board.real = hal.board.real.max(t);
        // SAFETY: single-threaded harness.
        unsafe { core::ptr::write_volatile(core::ptr::addr_of_mut!(NOW), tick(hal.board.real)) };
        if isr_at.is_some_and(|w| w <= t) {
            let q = step_queue();
            let flags = (0..4)
                .filter(|&i| q.running() & (1 << i) != 0 && reached(q.compare_tick(i), tick(t)))
                .fold(0u32, |f, i| f | 1 << (i + 1));
            let high = q.high();
            let c0 = rd(TIM_CNT);
            tim2_isr(flags);
            let c1 = rd(TIM_CNT);
            let rose = step_queue().high() & !high;
            costs.isr += u64::from(c1.wrapping_sub(c0).wrapping_sub(overhead));
            costs.interrupts += 1;
            step_motors(hal, rose, t, costs);
        }
        if run_at.is_some_and(|r| r <= t) {
            let c0 = rd(TIM_CNT);
            run_at = loop_turn(dev, hal);
            let c1 = rd(TIM_CNT);
            costs.loop_ += u64::from(c1.wrapping_sub(c0).wrapping_sub(overhead));
            costs.polls += 1;
            let mut sink = [0u8; 256];
            while dev.drain_outbox(&mut sink) > 0 {}
        }
    }
}

/// One turn of the board's controller loop (a function of its own, so profiles can tell it apart).
#[inline(never)]
fn loop_turn(dev: &mut Device, hal: &mut Hal) -> Option<u64> {
    hal.run(dev)
}

/// The motors follow the played edges; a home switch that closes raises the EXTI trip.
fn step_motors(hal: &mut Hal, rose: u8, t: u64, costs: &mut Costs) {
    // DIR pins as the queue last set them (from the interrupt, or when the loop started a channel).
    let levels = step_queue().dir_levels();
    let b = &mut hal.board;
    let mut closed = 0u8;
    for axis in AXES {
        let (i, bit) = (axis.index(), 1u8 << axis.index());
        if rose & bit != 0 {
            b.dir[i] = levels & bit != 0;
            let was = b.closed(axis);
            b.pos[i] += if b.dir[i] { 1 } else { -1 };
            if !was && b.closed(axis) {
                closed |= bit;
            }
            let w = t / PEAK_WINDOW_US;
            costs.window = if costs.window.0 == w {
                (w, costs.window.1 + 1)
            } else {
                (w, 1)
            };
            costs.peak = costs.peak.max(costs.window.1);
        }
    }
    if closed != 0 {
        let q = step_queue();
        let p = q.trip(closed);
        if q.tripped() != 0 {
            wr(TIM_DIER, rd(TIM_DIER) & !CC_BITS);
        }
        apply(p);
    }
}

fn send(dev: &mut Device, hal: &mut Hal, seq: &mut u16, msg: HostMsg) {
    let mut f = [0u8; MAX_WIRE_FRAME];
    let Ok(n) = encode(*seq, &msg, &mut f) else {
        panic!("frame does not fit")
    };
    *seq = seq.wrapping_add(1);
    dev.receive(hal, f.get(..n).unwrap_or(&[]));
    let mut sink = [0u8; 256];
    while dev.drain_outbox(&mut sink) > 0 {}
}

fn d(ti: f32, to: f32, po: f32) -> Direction {
    Direction {
        theta_i: ti.to_radians(),
        phi_i: 0.0,
        theta_o: to.to_radians(),
        phi_o: po.to_radians(),
    }
}

#[entry]
fn main() -> ! {
    wr(TIM_PSC, 0);
    wr(TIM_ARR, u32::MAX);
    wr(TIM2, 1); // CEN
    let overhead = counter_overhead();
    let cfg = InstrumentConfig::<f32>::reference();
    let mut dev = Device::new();
    let board = SimBoard {
        real: 0,
        pos: [0; 4],
        dir: [true; 4],
        homes: AXES.map(|a| {
            let c = cfg.axis(a);
            let home = i64::from(gonio_firmware::homing::home_position(&cfg, a));
            (home, (!c.continuous).then_some(c.home))
        }),
    };
    let mut hal = QueuedHal::new(board, CsQueue);
    let mut seq = 0;
    let mut costs = Costs::default();
    send(&mut dev, &mut hal, &mut seq, HostMsg::Hello(Hello::OURS));
    send(&mut dev, &mut hal, &mut seq, HostMsg::Configure(cfg));
    send(&mut dev, &mut hal, &mut seq, HostMsg::Home);
    run(&mut dev, &mut hal, &mut costs, overhead, &mut seq);
    let mut directions = heapless::Vec::new();
    for k in 0..8 {
        let dir = if k % 2 == 0 {
            d(70.0, 10.0, 90.0)
        } else {
            d(10.0, 70.0, -90.0)
        };
        let _ = directions.push(dir);
    }
    let chunk = PlanChunk {
        first_index: 0,
        directions,
    };
    send(&mut dev, &mut hal, &mut seq, HostMsg::Plan(chunk));
    send(&mut dev, &mut hal, &mut seq, HostMsg::PlanEnd { total: 8 });
    send(&mut dev, &mut hal, &mut seq, HostMsg::Start);
    run(&mut dev, &mut hal, &mut costs, overhead, &mut seq);

    let stats = hal.queue.with(|q| q.stats());
    let steps = u64::from(stats.steps).max(1);
    let per = |x: u64| x as f32 / steps as f32;
    let (isr, gen) = (per(costs.isr), per(costs.loop_));
    let total = isr + gen;
    let irq_per_step = per(costs.interrupts);
    let cycles = total * CPI + irq_per_step * EXCEPTION_CYCLES;
    let peak_rate = costs.peak as f32 * (1e6 / PEAK_WINDOW_US as f32);
    let cpu = cycles * peak_rate / SYSCLK_HZ * 100.0;
    let state = dev.controller().state();
    let mut out: heapless::String<512> = heapless::String::new();
    let _ = write!(
        out,
        "step path: {:.0} instructions per step (interrupt {:.0}, segment generation {:.0}), reference scan CPU {:.1} %\n\
         detail: {} steps, {} interrupts ({:.2} per step), {} loop turns, peak {} steps in {} ms, \
         CPI {:.1} + {:.0} cycles per interrupt at {:.0} MHz, late {}, overruns {}, final state {:?} {:?}, counter overhead {}\n",
        total,
        isr,
        gen,
        cpu,
        stats.steps,
        costs.interrupts,
        irq_per_step,
        costs.polls,
        costs.peak,
        PEAK_WINDOW_US / 1000,
        CPI,
        EXCEPTION_CYCLES,
        SYSCLK_HZ / 1e6,
        stats.late,
        stats.overruns,
        state,
        dev.controller().last_fault(),
        overhead,
    );
    print(&out);
    let done = state == gonio_shared::msg::ControllerState::Done && stats.overruns == 0;
    exit(done)
}

// ---- Semihosting: print and exit. ----

fn semihost(op: u32, arg: u32) -> u32 {
    let r;
    // SAFETY: the semihosting call convention (QEMU -semihosting): r0 = operation, r1 = argument.
    unsafe { core::arch::asm!("bkpt 0xAB", inout("r0") op => r, in("r1") arg) };
    r
}

fn print(s: &str) {
    let mut buf = [0u8; 513];
    let n = s.len().min(512);
    buf[..n].copy_from_slice(&s.as_bytes()[..n]);
    semihost(0x04, buf.as_ptr() as u32); // SYS_WRITE0
}

fn exit(ok: bool) -> ! {
    // SYS_EXIT with ADP_Stopped_ApplicationExit (QEMU exits 0) or RunTimeErrorUnknown (exits 1).
    semihost(0x18, if ok { 0x20026 } else { 0x20023 });
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    let mut out: heapless::String<256> = heapless::String::new();
    let _ = writeln!(out, "step-cost harness panicked: {info}");
    print(&out);
    exit(false)
}
