//! The board's step path on the host: the controller loop (`QueuedHal::run` -> `Device::poll`,
//! queueing events) and the timer interrupt's work (`StepQueue::service`), for one long 4-axis
//! move of the reference instrument, separated so each side can be costed on its own.
//!
//! Prints steps, timer wake-ups per step (each wake-up is one interrupt on the board), and host
//! ns per step of each side. For instruction counts (the proxy behind the Cortex-M4 estimate in
//! `firmware/stm32/README.md`), run it under callgrind and read the inclusive counts of
//! `QueuedHal::run` and `StepQueue::service`:
//!
//! ```sh
//! cargo build --release -p gonio-firmware --example step_path_costs
//! valgrind --tool=callgrind --callgrind-out-file=/tmp/cg.out $CARGO_TARGET_DIR/release/examples/step_path_costs
//! callgrind_annotate --inclusive=yes /tmp/cg.out | grep -E 'QueuedHal.*run|StepQueue::service'
//! ```

use gonio_firmware::step_queue::StepQueue;
use gonio_firmware::timed::{tick, QueuedHal, SharedQueue};
use gonio_firmware::{Clock, Detector, Device, Readout, Switches};
use gonio_shared::frame::{encode, MAX_WIRE_FRAME};
use gonio_shared::instrument::InstrumentConfig;
use gonio_shared::msg::{Direction, Hello, HostMsg, PlanChunk};
use gonio_shared::Axis;
use std::cell::RefCell;
use std::time::{Duration, Instant};

/// Simulated real time; switches close at the configured home positions (so homing completes).
struct SimBoard {
    real: u64,
    pos: [i64; 4],
    dir: [bool; 4],
    cfg: InstrumentConfig<f32>,
}

impl Clock for SimBoard {
    fn now_us(&self) -> u64 {
        self.real
    }
}

impl Switches for SimBoard {
    fn limit_closed(&self, axis: Axis) -> bool {
        let i = axis.index();
        let home = gonio_firmware::homing::home_position(&self.cfg, axis) as i64;
        match (self.cfg.axis(axis).continuous, self.cfg.axis(axis).home) {
            (true, _) => self.pos[i] == 0,
            (false, gonio_shared::HomeSide::Max) => self.pos[i] >= home,
            (false, gonio_shared::HomeSide::Min) => self.pos[i] <= home,
        }
    }
}

impl Detector for SimBoard {
    fn start_exposure(&mut self, _: u32) {}
    fn poll_readout(&mut self) -> Option<Readout> {
        Some(Readout::new())
    }
}

struct Shared(RefCell<StepQueue>);

impl SharedQueue for Shared {
    fn with<R>(&self, f: impl FnOnce(&mut StepQueue) -> R) -> R {
        f(&mut self.0.borrow_mut())
    }
}

#[derive(Default)]
struct Costs {
    loop_time: Duration,
    isr_time: Duration,
    wakes: u64,
}

/// Run loop and timer until idle; the timer's work and the loop's are timed separately.
fn run(dev: &mut Device, hal: &mut QueuedHal<SimBoard, Shared>, costs: &mut Costs) {
    let mut run_at = Some(hal.board.real);
    loop {
        let now = hal.board.real;
        let isr_at = hal.queue.with(|q| q.next_wake(tick(now))).map(|w| {
            let ahead = w.wrapping_sub(tick(now));
            if ahead >= 1 << 31 {
                now
            } else {
                now + u64::from(ahead)
            }
        });
        let Some(t) = [isr_at, run_at].into_iter().flatten().min() else {
            return;
        };
        hal.board.real = hal.board.real.max(t);
        if isr_at.is_some_and(|w| w <= t) {
            let t0 = Instant::now();
            let (pins, _) = hal.queue.with(|q| q.service(tick(t)));
            costs.isr_time += t0.elapsed();
            costs.wakes += 1;
            for i in 0..4 {
                let b = 1u8 << i;
                if pins.dir_increasing & b != 0 {
                    hal.board.dir[i] = true;
                }
                if pins.dir_decreasing & b != 0 {
                    hal.board.dir[i] = false;
                }
                if pins.step_high & b != 0 {
                    hal.board.pos[i] += if hal.board.dir[i] { 1 } else { -1 };
                    // A home switch closing is the EXTI trip.
                    if hal.board.limit_closed(gonio_shared::instrument::AXES[i]) {
                        hal.queue.with(|q| q.trip(b, tick(t)));
                    }
                }
            }
        }
        if run_at.is_some_and(|r| r <= t) {
            let t0 = Instant::now();
            run_at = hal.run(dev);
            costs.loop_time += t0.elapsed();
            let mut sink = [0u8; 4096];
            while dev.drain_outbox(&mut sink) > 0 {}
        }
    }
}

fn send(dev: &mut Device, hal: &mut QueuedHal<SimBoard, Shared>, seq: &mut u16, msg: HostMsg) {
    let mut f = [0u8; MAX_WIRE_FRAME];
    let n = encode(*seq, &msg, &mut f).expect("frame fits");
    *seq = seq.wrapping_add(1);
    dev.receive(hal, &f[..n]);
    let mut sink = [0u8; 4096];
    while dev.drain_outbox(&mut sink) > 0 {}
}

fn main() {
    let cfg = InstrumentConfig::<f32>::reference();
    let mut dev = Box::new(Device::new());
    let board = SimBoard {
        real: 0,
        pos: [0; 4],
        dir: [true; 4],
        cfg,
    };
    let mut hal = QueuedHal::new(board, Shared(RefCell::new(StepQueue::new())));
    let mut seq = 0;
    send(&mut dev, &mut hal, &mut seq, HostMsg::Hello(Hello::OURS));
    send(&mut dev, &mut hal, &mut seq, HostMsg::Configure(cfg));
    send(&mut dev, &mut hal, &mut seq, HostMsg::Home);
    let mut homing = Costs::default();
    run(&mut dev, &mut hal, &mut homing);
    let d = |ti: f32, to: f32, po: f32| Direction {
        theta_i: ti.to_radians(),
        phi_i: 0.0,
        theta_o: to.to_radians(),
        phi_o: po.to_radians(),
    };
    let mut directions = heapless::Vec::new();
    for k in 0..8 {
        let dir = if k % 2 == 0 {
            d(70.0, 10.0, 90.0)
        } else {
            d(10.0, 70.0, -90.0)
        };
        directions.push(dir).expect("chunk capacity");
    }
    send(
        &mut dev,
        &mut hal,
        &mut seq,
        HostMsg::Plan(PlanChunk {
            first_index: 0,
            directions,
        }),
    );
    send(&mut dev, &mut hal, &mut seq, HostMsg::PlanEnd { total: 8 });
    send(&mut dev, &mut hal, &mut seq, HostMsg::Start);
    let before = hal.queue.with(|q| q.stats());
    let mut costs = Costs::default();
    run(&mut dev, &mut hal, &mut costs);
    println!(
        "whole run (homing + scan, the divisors for callgrind's counts): {} steps, {} timer wake-ups",
        hal.queue.with(|q| q.stats()).steps,
        homing.wakes + costs.wakes
    );
    let after = hal.queue.with(|q| q.stats());
    let steps = u64::from(after.steps - before.steps);
    println!(
        "timed step path, reference instrument, 8 plan moves: {steps} steps, {} timer wake-ups ({:.2} per step), late {}, overruns {}",
        costs.wakes,
        costs.wakes as f64 / steps as f64,
        after.late - before.late,
        after.overruns
    );
    println!(
        "host cost per step: controller loop (QueuedHal::run + Device::poll, queueing) {:.1} ns; timer side (StepQueue::service) {:.1} ns per step, {:.1} ns per wake-up",
        costs.loop_time.as_nanos() as f64 / steps as f64,
        costs.isr_time.as_nanos() as f64 / steps as f64,
        costs.isr_time.as_nanos() as f64 / costs.wakes as f64
    );
}
