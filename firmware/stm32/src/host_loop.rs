//! The controller loop, the same in both builds: bytes from the host link go into
//! `Device::receive`, `QueuedHal::run` runs the controller ahead of real time (its steps queued for
//! the step interrupt), and the outbox goes to the TX pipe, which a writer task moves to the link.
//! The link itself (USB CDC-ACM on the board, USART1 under QEMU) is behind [`HostRx`] and
//! [`TX_PIPE`]; the watchdog behind [`Watchdog`].

use defmt::{info, warn};
use embassy_futures::select::{select3, Either3};
use embassy_futures::yield_now;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::pipe::Pipe;
use embassy_time::{Instant, Timer};
use gonio_firmware::timed::{QueuedHal, SharedQueue};
use gonio_firmware::{watchdog, Clock, Detector, Device, Switches};
use gonio_shared::msg::{ControllerState, Fault};

/// Bytes taken from the link per read: a full-speed USB bulk packet.
pub const RX_CHUNK: usize = 64;
/// Bytes between the controller and the link's writer. The controller's own outbox (2 KiB) is the
/// real buffer; this only decouples write latency from the controller loop.
pub const TX_PIPE_BYTES: usize = 256;

/// Outgoing bytes, controller -> link writer task.
pub static TX_PIPE: Pipe<CriticalSectionRawMutex, TX_PIPE_BYTES> = Pipe::new();

/// What the link side of the controller loop saw.
pub enum RxEvent {
    /// A host is there (the link decoder starts afresh).
    Connected,
    Data(usize),
    #[cfg_attr(feature = "qemu", allow(dead_code, reason = "a UART has no detach event"))]
    Disconnected,
    /// A packet larger than the buffer was lost.
    #[cfg_attr(feature = "qemu", allow(dead_code, reason = "a UART delivers bytes, not packets"))]
    Overflow,
}

/// The host -> device byte stream.
pub trait HostRx {
    /// The next event: `Connected` first while `connected` is false, then received bytes in `buf`.
    async fn next(&mut self, buf: &mut [u8; RX_CHUNK], connected: bool) -> RxEvent;
}

/// The board's independent watchdog (none under QEMU, which does not emulate it).
pub trait Watchdog {
    fn pet(&mut self);
}

/// The watchdog, fed by the controller loop by the rule of `gonio_firmware::watchdog` (at most every
/// `FEED_US`, only while the step queue never overran).
pub struct Feeder<W> {
    wdg: W,
    rule: watchdog::Feed,
}

impl<W: Watchdog> Feeder<W> {
    pub fn new(wdg: W) -> Self {
        Self {
            wdg,
            rule: watchdog::Feed::new(Instant::now().as_micros()),
        }
    }

    /// Feed it if due and healthy; returns when the loop must come back to feed it again (`None`:
    /// it stopped feeding, the watchdog resets the board).
    fn feed<B, Q: SharedQueue>(&mut self, hal: &QueuedHal<B, Q>) -> Option<u64> {
        let (pet, next) = self.rule.poll(Instant::now().as_micros(), || {
            hal.queue.with(|q| watchdog::healthy(&q.stats()))
        });
        if pet {
            self.wdg.pet();
        }
        next
    }
}

/// Bytes on their way from the controller's outbox to the TX pipe.
struct Staged {
    buf: [u8; RX_CHUNK],
    start: usize,
    end: usize,
}

impl Staged {
    fn pending(&self) -> &[u8] {
        self.buf.get(self.start..self.end).unwrap_or(&[])
    }

    fn consume(&mut self, n: usize) {
        self.start = self.start.saturating_add(n).min(self.end);
    }

    /// Move as much of the outbox into the TX pipe as it takes without waiting.
    fn pump(&mut self, device: &mut Device) {
        loop {
            if self.pending().is_empty() {
                self.start = 0;
                self.end = device.drain_outbox(&mut self.buf);
                if self.end == 0 {
                    return;
                }
            }
            match TX_PIPE.try_write(self.pending()) {
                Ok(n) => self.consume(n),
                Err(_) => return, // full: the writer task makes room
            }
        }
    }
}

/// Owns the `Device` and the HAL; the loop of the host test bench, with real time. It waits on
/// the link, the controller's next deadline (`Timer::at`) or room in the TX pipe, whichever comes
/// first.
pub async fn run<B, Q, R, W>(
    device: &'static mut Device,
    mut hal: QueuedHal<B, Q>,
    mut link: R,
    mut watchdog: Feeder<W>,
) -> !
where
    B: Clock + Switches + Detector,
    Q: SharedQueue,
    R: HostRx,
    W: Watchdog,
{
    let mut rx = [0u8; RX_CHUNK];
    let (mut rx_start, mut rx_end) = (0usize, 0usize);
    let mut staged = Staged {
        buf: [0; RX_CHUNK],
        start: 0,
        end: 0,
    };
    let mut connected = false;
    let mut seen = Seen::new(device);
    loop {
        // Received bytes first: `receive` takes fewer than offered only while the outbox is too full
        // to answer, and the rest is offered again once the pipe has taken some of it.
        if let Some(bytes) = rx.get(rx_start..rx_end).filter(|b| !b.is_empty()) {
            let n = device.receive(&mut hal, bytes);
            rx_start = rx_start.saturating_add(n);
        }
        // Everything due (and, while moving, the next `LOOKAHEAD_US` of steps into the queue).
        let wake = hal.run(device);
        seen.log_changes(device, &hal);
        staged.pump(device);
        let wake = [wake, watchdog.feed(&hal)].into_iter().flatten().min();

        let rx_idle = rx_start >= rx_end;
        if !rx_idle && staged.pending().is_empty() {
            // `receive` stopped on a full outbox, and the pump has since emptied it: offer the rest
            // again right away (waiting here would wait for nothing).
            yield_now().await;
            continue;
        }
        let deadline = wake.map_or(Instant::MAX, Instant::from_micros);
        let event = select3(
            async {
                if rx_idle {
                    link.next(&mut rx, connected).await
                } else {
                    core::future::pending().await
                }
            },
            Timer::at(deadline),
            async {
                if staged.pending().is_empty() {
                    core::future::pending().await
                } else {
                    TX_PIPE.write(staged.pending()).await
                }
            },
        )
        .await;
        match event {
            Either3::First(RxEvent::Data(n)) => (rx_start, rx_end) = (0, n.min(RX_CHUNK)),
            Either3::First(RxEvent::Connected) => {
                connected = true;
                device.reset_link_decoder();
                info!("host connected");
            }
            Either3::First(RxEvent::Disconnected) => {
                connected = false;
                (rx_start, rx_end) = (0, 0);
                info!("host disconnected");
            }
            // Cannot happen with a buffer of the endpoint's size; the packet is lost and the link
            // NAKs the damaged frame.
            Either3::First(RxEvent::Overflow) => warn!("packet larger than {=usize} bytes dropped", RX_CHUNK),
            // Due work runs at the top of the loop. Let the other tasks run first: a deadline already
            // in the past resolves without the executor ever getting control back.
            Either3::Second(()) => yield_now().await,
            Either3::Third(n) => staged.consume(n),
        }
    }
}

/// Controller state and fault as last logged, so only changes go to defmt.
struct Seen {
    state: ControllerState,
    fault: Option<Fault>,
    overruns: u32,
}

impl Seen {
    fn new(device: &Device) -> Self {
        Self {
            state: device.controller().state(),
            fault: device.controller().last_fault(),
            overruns: 0,
        }
    }

    /// State changes, faults, and a step queue overrun (a bug: the loop keeps room for a poll's
    /// events) or late steps (the loop fell behind the lookahead), once per change of the count
    /// at a state change, so nothing is logged per step.
    fn log_changes<B, Q: SharedQueue>(&mut self, device: &Device, hal: &QueuedHal<B, Q>) {
        let state = device.controller().state();
        if state != self.state {
            info!("state {=str} -> {=str}", state_name(self.state), state_name(state));
            self.state = state;
            let stats = hal.queue.with(|q| q.stats());
            if stats.overruns.wrapping_add(stats.late) != self.overruns {
                warn!(
                    "step queue: {=u32} overruns, {=u32} late steps",
                    stats.overruns, stats.late
                );
                self.overruns = stats.overruns.wrapping_add(stats.late);
            }
        }
        let fault = device.controller().last_fault();
        if fault != self.fault {
            if let Some(f) = fault {
                warn!("fault: {=str}", fault_name(f));
            }
            self.fault = fault;
        }
    }
}

/// Names for defmt (the shared crate stays free of defmt; `Debug2Format` would pull `core::fmt`
/// into flash).
fn state_name(s: ControllerState) -> &'static str {
    match s {
        ControllerState::Idle => "Idle",
        ControllerState::Homing => "Homing",
        ControllerState::Ready => "Ready",
        ControllerState::Running => "Running",
        ControllerState::Paused => "Paused",
        ControllerState::Done => "Done",
        ControllerState::Fault => "Fault",
    }
}

fn fault_name(f: Fault) -> &'static str {
    match f {
        Fault::LimitSwitch(_) => "limit switch",
        Fault::Unreachable { .. } => "unreachable direction",
        Fault::BufferOverflow => "buffer overflow",
        Fault::BadFrame => "too many bad frames",
        Fault::DetectorTimeout => "detector timeout",
        Fault::HomeNotFound(_) => "home not found",
        Fault::StepsLate => "steps late",
    }
}
