//! gonio firmware for the STM32F411CE "Black Pill" (embassy).
//!
//! Glue only: the controller (link, plan streaming, homing, stepping, measurement) is
//! `gonio_firmware::Device`, driven here exactly as the host test bench drives it
//! (`firmware/tests/common/mod.rs`): bytes from USB go into `Device::receive`, `Device::poll` runs
//! through `QueuedHal::run` (the controller ahead of real time, its steps queued for the TIM2
//! interrupt: `gonio_firmware::timed`), and the outbox goes back to USB. The board's pins,
//! interrupts and detector are in `board`.
//!
//! Tasks:
//! - `usb_task` runs the USB device stack;
//! - `controller_task` owns the `Device` and the HAL: it waits on a USB packet, the controller's next
//!   deadline (`Timer::at`) or room in the TX pipe, whichever comes first;
//! - `usb_tx_task` moves the TX pipe to USB in 64-byte packets (with a zero-length packet after a
//!   full one), so a host that is slow to read never holds up step timing;
//! - `blink` is the PC13 heartbeat.
#![no_std]
#![no_main]

mod board;

use board::{AdcDetector, AxisPins, BoardIo, CsQueue, SYSCLK_HZ};
use defmt::{info, warn};
use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_futures::select::{select3, Either3};
use embassy_futures::yield_now;
use embassy_stm32::adc::{Adc, AdcChannel};
use embassy_stm32::exti::{ExtiInput, TriggerEdge};
use embassy_stm32::gpio::{Level, Output, Pull, Speed};
use embassy_stm32::time::Hertz;
use embassy_stm32::usb::{self, Driver};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, peripherals, Config};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::pipe::Pipe;
use embassy_time::{Instant, Timer};
use embassy_usb::class::cdc_acm::{CdcAcmClass, Receiver, Sender, State};
use embassy_usb::driver::EndpointError;
use embassy_usb::{Builder, UsbDevice};
use gonio_firmware::timed::{QueuedHal, SharedQueue};
use gonio_firmware::Device;
use gonio_shared::msg::{ControllerState, Fault};
use static_cell::{ConstStaticCell, StaticCell};

/// Drivers off (STEP low, ENABLE released), log where, reset. The panic *message* is not
/// printed: formatting it would link `core::fmt` (docs/firmware.md, "Flash and RAM"); no panic can
/// come from wire data (the logic crate's rule), only from start-up `expect`s.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    board::drivers_off();
    match info.location() {
        Some(l) => defmt::error!("panic at {=str}:{=u32}", l.file(), l.line()),
        None => defmt::error!("panic"),
    }
    cortex_m::peripheral::SCB::sys_reset()
}

/// A bus or usage fault: drivers off at once, then reset (nothing is logged: the stack may be
/// what failed).
#[cortex_m_rt::exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    board::drivers_off();
    cortex_m::peripheral::SCB::sys_reset()
}

bind_interrupts!(struct Irqs {
    OTG_FS => usb::InterruptHandler<peripherals::USB_OTG_FS>;
});

type UsbDriver = Driver<'static, peripherals::USB_OTG_FS>;

/// Bulk endpoint size of a full-speed CDC-ACM device.
const USB_PACKET: usize = 64;
/// Bytes between the controller and the USB writer. The controller's own outbox (2 KiB) is the
/// real buffer; this only decouples USB write latency from the controller loop.
const TX_PIPE_BYTES: usize = 256;
/// pid.codes test VID/PID: fine on the bench, to be replaced by an allocated PID before shipping.
const USB_VID: u16 = 0x1209;
const USB_PID: u16 = 0x0001;

/// The independent watchdog's timeout, and how often the healthy controller loop feeds it.
const WATCHDOG_US: u32 = 500_000;
const WATCHDOG_FEED_US: u64 = 100_000;

/// Outgoing bytes, controller -> USB writer.
static TX_PIPE: Pipe<CriticalSectionRawMutex, TX_PIPE_BYTES> = Pipe::new();

/// 25 MHz HSE -> PLL: /25 = 1 MHz, x192 = 192 MHz VCO; P /2 = 96 MHz SYSCLK, Q /4 = 48 MHz USB.
/// APB1 is capped at 50 MHz on the F411, hence /2 (48 MHz, timers 96 MHz); APB2 runs at 96 MHz.
fn clocks() -> Config {
    use embassy_stm32::rcc::{
        mux, AHBPrescaler, APBPrescaler, Hse, HseMode, Pll, PllMul, PllPDiv, PllPreDiv, PllQDiv, PllSource, Sysclk,
    };
    let mut config = Config::default();
    config.rcc.hse = Some(Hse {
        freq: Hertz(25_000_000),
        mode: HseMode::Oscillator,
    });
    config.rcc.pll_src = PllSource::HSE;
    config.rcc.pll = Some(Pll {
        prediv: PllPreDiv::DIV25,
        mul: PllMul::MUL192,
        divp: Some(PllPDiv::DIV2),
        divq: Some(PllQDiv::DIV4),
        divr: None,
    });
    config.rcc.ahb_pre = AHBPrescaler::DIV1;
    config.rcc.apb1_pre = APBPrescaler::DIV2;
    config.rcc.apb2_pre = APBPrescaler::DIV1;
    config.rcc.sys = Sysclk::PLL1_P;
    config.rcc.mux.clk48sel = mux::Clk48sel::PLL1_Q;
    config
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_stm32::init(clocks());
    info!("gonio-stm32 up: SYSCLK {=u32} Hz", SYSCLK_HZ);

    // Black Pill user LED, active low: start off.
    let led = Output::new(p.PC13, Level::High, Speed::Low);

    // Steppers (README pin table), indexed by `Axis::index`: light, detector, tilt, azimuth.
    // STEP idles low and pulses high (driven by the TIM2 interrupt); ENABLE is active low and
    // driven active from here on.
    let pins = AxisPins {
        step: [
            Output::new(p.PB0, Level::Low, Speed::Medium),
            Output::new(p.PB1, Level::Low, Speed::Medium),
            Output::new(p.PB6, Level::Low, Speed::Medium),
            Output::new(p.PB7, Level::Low, Speed::Medium),
        ],
        dir: [
            Output::new(p.PB12, Level::Low, Speed::Medium),
            Output::new(p.PB13, Level::Low, Speed::Medium),
            Output::new(p.PB14, Level::Low, Speed::Medium),
            Output::new(p.PB15, Level::Low, Speed::Medium),
        ],
        enable: [
            Output::new(p.PB8, Level::Low, Speed::Low),
            Output::new(p.PB9, Level::Low, Speed::Low),
            Output::new(p.PB4, Level::Low, Speed::Low),
            Output::new(p.PA15, Level::Low, Speed::Low),
        ],
    };
    // Switches to GND, closed = low: a falling edge is a switch closing. Our own EXTI handlers
    // (board.rs) stop the step timer; embassy's async EXTI would only wake a task.
    let limit = [
        ExtiInput::new_blocking(p.PA1, p.EXTI1, Pull::Up, TriggerEdge::Falling),
        ExtiInput::new_blocking(p.PA2, p.EXTI2, Pull::Up, TriggerEdge::Falling),
        ExtiInput::new_blocking(p.PA3, p.EXTI3, Pull::Up, TriggerEdge::Falling),
        ExtiInput::new_blocking(p.PB5, p.EXTI5, Pull::Up, TriggerEdge::Falling),
    ];
    // Internal-ADC detector: ADC1_IN4..IN7 on PA4..PA7, channel order = readout order.
    let detector = AdcDetector {
        adc: Adc::new(p.ADC1),
        channels: [
            p.PA4.degrade_adc(),
            p.PA5.degrade_adc(),
            p.PA6.degrade_adc(),
            p.PA7.degrade_adc(),
        ],
    };
    board::start_step_timer(p.TIM2);
    let hal = QueuedHal::new(BoardIo::new(pins, limit, detector), CsQueue);

    // `Device::new()` is const and all-zero, so this static lands in .bss (zeroed by the runtime, no
    // flash image, no copy through the stack). Check `data` in `arm-none-eabi-size` stays small if
    // `Device::new` ever changes.
    static DEVICE: ConstStaticCell<Device> = ConstStaticCell::new(Device::new());
    let device = DEVICE.take();

    // USB OTG FS on PA12 (D+) / PA11 (D-). VBUS sensing (PA9) stays off: the board is bus-powered
    // today; a self-powered build must wire PA9 and enable it (USB spec).
    static EP_OUT_BUFFER: StaticCell<[u8; 256]> = StaticCell::new();
    let mut usb_config = usb::Config::default();
    usb_config.vbus_detection = false;
    let driver = Driver::new_fs(
        p.USB_OTG_FS,
        Irqs,
        p.PA12,
        p.PA11,
        EP_OUT_BUFFER.init([0; 256]),
        usb_config,
    );

    let mut config = embassy_usb::Config::new(USB_VID, USB_PID);
    config.manufacturer = Some("gonio");
    config.product = Some("gonio controller (STM32F411)");
    config.serial_number = Some(embassy_stm32::uid::uid_hex());
    config.max_power = 100;

    static CONFIG_DESCRIPTOR: StaticCell<[u8; 256]> = StaticCell::new();
    static BOS_DESCRIPTOR: StaticCell<[u8; 256]> = StaticCell::new();
    static CONTROL_BUF: StaticCell<[u8; 64]> = StaticCell::new();
    static CDC_STATE: StaticCell<State<'static>> = StaticCell::new();
    let mut builder = Builder::new(
        driver,
        config,
        CONFIG_DESCRIPTOR.init([0; 256]),
        BOS_DESCRIPTOR.init([0; 256]),
        &mut [], // no MS OS descriptors
        CONTROL_BUF.init([0; 64]),
    );
    let class = CdcAcmClass::new(&mut builder, CDC_STATE.init(State::new()), USB_PACKET as u16);
    let (sender, receiver) = class.split();
    let usb = builder.build();

    spawner.spawn(spawned(usb_task(usb), "usb_task"));
    spawner.spawn(spawned(usb_tx_task(sender), "usb_tx_task"));
    // The independent watchdog: a hung executor, or a controller loop that stops feeding it
    // (`Watchdog::feed`), resets the board within WATCHDOG_US.
    let mut wdg = IndependentWatchdog::new(p.IWDG, WATCHDOG_US);
    wdg.unleash();
    let watchdog = Watchdog {
        wdg,
        fed: Instant::now(),
    };
    spawner.spawn(spawned(
        controller_task(device, hal, receiver, watchdog),
        "controller_task",
    ));
    spawner.spawn(spawned(blink(led), "blink"));
}

/// A task's spawn token, or a logged halt at boot. Not `expect`: its `Debug` formatting of the
/// error would link `core::fmt`.
fn spawned<T, E>(token: Result<T, E>, name: &str) -> T {
    match token {
        Ok(t) => t,
        Err(_) => defmt::panic!("cannot spawn {=str}", name),
    }
}

#[embassy_executor::task]
async fn usb_task(mut usb: UsbDevice<'static, UsbDriver>) -> ! {
    usb.run().await
}

#[embassy_executor::task]
async fn blink(mut led: Output<'static>) -> ! {
    loop {
        led.toggle();
        Timer::after_millis(500).await;
    }
}

/// TX pipe -> USB, one packet at a time. A full 64-byte packet with nothing behind it is followed
/// by a zero-length packet so the host's read completes instead of waiting for more.
#[embassy_executor::task]
async fn usb_tx_task(mut sender: Sender<'static, UsbDriver>) -> ! {
    let mut packet = [0u8; USB_PACKET];
    loop {
        sender.wait_connection().await;
        loop {
            let n = TX_PIPE.read(&mut packet).await;
            let Some(bytes) = packet.get(..n) else { continue };
            if sender.write_packet(bytes).await.is_err() {
                break;
            }
            if n == USB_PACKET && TX_PIPE.is_empty() && sender.write_packet(&[]).await.is_err() {
                break;
            }
        }
        // Bytes still in the pipe go to the next host session (old replies its decoder and sequence
        // checks discard); only the packet that failed at the disconnect is lost, a truncated frame
        // the host's decoder drops.
    }
}

/// What the USB side of the controller loop saw.
enum RxEvent {
    Connected,
    Data(usize),
    Disconnected,
    Overflow,
}

async fn usb_rx(receiver: &mut Receiver<'static, UsbDriver>, buf: &mut [u8], connected: bool) -> RxEvent {
    if !connected {
        receiver.wait_connection().await;
        return RxEvent::Connected;
    }
    match receiver.read_packet(buf).await {
        Ok(n) => RxEvent::Data(n),
        Err(EndpointError::Disabled) => RxEvent::Disconnected,
        Err(EndpointError::BufferOverflow) => RxEvent::Overflow,
    }
}

/// Bytes on their way from the controller's outbox to the TX pipe.
struct Staged {
    buf: [u8; USB_PACKET],
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
                Err(_) => return, // full: `usb_tx_task` makes room
            }
        }
    }
}

/// Owns the `Device` and the HAL; the loop of the host test bench, with real time.
#[embassy_executor::task]
async fn controller_task(
    device: &'static mut Device,
    mut hal: QueuedHal<BoardIo, CsQueue>,
    mut receiver: Receiver<'static, UsbDriver>,
    mut watchdog: Watchdog,
) -> ! {
    let mut rx = [0u8; USB_PACKET];
    let (mut rx_start, mut rx_end) = (0usize, 0usize);
    let mut staged = Staged {
        buf: [0; USB_PACKET],
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
        let wake = Some(watchdog.feed(&hal).min(wake.unwrap_or(u64::MAX)));

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
                    usb_rx(&mut receiver, &mut rx, connected).await
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
            Either3::First(RxEvent::Data(n)) => (rx_start, rx_end) = (0, n.min(USB_PACKET)),
            Either3::First(RxEvent::Connected) => {
                connected = true;
                device.reset_link_decoder();
                info!("USB host connected");
            }
            Either3::First(RxEvent::Disconnected) => {
                connected = false;
                (rx_start, rx_end) = (0, 0);
                info!("USB host disconnected");
            }
            // Cannot happen with a buffer of the endpoint's size; the packet is lost and the link
            // NAKs the damaged frame.
            Either3::First(RxEvent::Overflow) => warn!("USB packet larger than {=usize} bytes dropped", USB_PACKET),
            // Due work runs at the top of the loop. Let the other tasks run first: a deadline already
            // in the past resolves without the executor ever getting control back.
            Either3::Second(()) => yield_now().await,
            Either3::Third(n) => staged.consume(n),
        }
    }
}

/// The IWDG, fed by the controller loop at most every `WATCHDOG_FEED_US`, and only while the
/// step queue is healthy (no overrun: the loop keeps room for what it queues).
struct Watchdog {
    wdg: IndependentWatchdog<'static, peripherals::IWDG>,
    fed: Instant,
}

impl Watchdog {
    /// Feed it if due and healthy; returns when the loop must come back to feed it again.
    fn feed(&mut self, hal: &QueuedHal<BoardIo, CsQueue>) -> u64 {
        let now = Instant::now();
        if now.as_micros() >= self.fed.as_micros().saturating_add(WATCHDOG_FEED_US)
            && hal.queue.with(|q| q.stats().overruns) == 0
        {
            self.wdg.pet();
            self.fed = now;
        }
        self.fed.as_micros().saturating_add(WATCHDOG_FEED_US)
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
    fn log_changes(&mut self, device: &Device, hal: &QueuedHal<BoardIo, CsQueue>) {
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
