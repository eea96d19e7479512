//! The board build's start-up and host link: `embassy_stm32::init` with the Black Pill's clocks,
//! the board I/O (`board`), USB CDC-ACM as the host link, the IWDG.
//!
//! Tasks:
//! - `usb_task` runs the USB device stack;
//! - `controller_task` runs the controller loop (`host_loop::run`) on the USB receiver;
//! - `usb_tx_task` moves the TX pipe to USB in 64-byte packets (with a zero-length packet after a
//!   full one), so a host that is slow to read never holds up step timing;
//! - `blink` is the PC13 heartbeat.

use crate::board::{self, AdcDetector, AxisPins, BoardIo, CsQueue, SYSCLK_HZ};
use crate::host_loop::{self, Feeder, HostRx, RxEvent, Watchdog, RX_CHUNK, TX_PIPE};
use crate::spawned;
use defmt::info;
use embassy_executor::Spawner;
use embassy_stm32::adc::{Adc, AdcChannel};
use embassy_stm32::exti::{ExtiInput, TriggerEdge};
use embassy_stm32::gpio::{Level, Output, Pin, Pull, Speed};
use embassy_stm32::time::Hertz;
use embassy_stm32::usb::{self, Driver};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, peripherals, Config, Peri};
use embassy_time::Timer;
use embassy_usb::class::cdc_acm::{CdcAcmClass, Receiver, Sender, State};
use embassy_usb::driver::EndpointError;
use embassy_usb::{Builder, UsbDevice};
use gonio_firmware::timed::QueuedHal;
use gonio_firmware::{pin_map, watchdog, Device};
use static_cell::{ConstStaticCell, StaticCell};

bind_interrupts!(struct Irqs {
    OTG_FS => usb::InterruptHandler<peripherals::USB_OTG_FS>;
});

type UsbDriver = Driver<'static, peripherals::USB_OTG_FS>;

/// Bulk endpoint size of a full-speed CDC-ACM device.
const USB_PACKET: usize = RX_CHUNK;
/// pid.codes test VID/PID: fine on the bench, to be replaced by an allocated PID before shipping.
const USB_VID: u16 = 0x1209;
const USB_PID: u16 = 0x0001;

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

pub fn start(spawner: Spawner) {
    let p = embassy_stm32::init(clocks());
    info!("gonio-stm32 up: SYSCLK {=u32} Hz", SYSCLK_HZ);

    // Black Pill user LED, active low: start off.
    let led = Output::new(p.PC13, Level::High, Speed::Low);

    // Steppers (README pin table, `gonio_firmware::pin_map`), indexed by `Axis::index`: light,
    // detector, tilt, azimuth. STEP idles low and pulses high (driven by the TIM2 interrupt);
    // ENABLE is driven active from here on.
    let map = &pin_map::DRIVER_PINS;
    let (step, dir, enable) = (Speed::Medium, Speed::Medium, Speed::Low);
    let on = Level::from(!pin_map::ENABLE_ACTIVE_LOW);
    let pins = AxisPins {
        step: [
            driver_output(p.PB0, map[0].step, Level::Low, step),
            driver_output(p.PB1, map[1].step, Level::Low, step),
            driver_output(p.PB6, map[2].step, Level::Low, step),
            driver_output(p.PB7, map[3].step, Level::Low, step),
        ],
        dir: [
            driver_output(p.PB12, map[0].dir, Level::Low, dir),
            driver_output(p.PB13, map[1].dir, Level::Low, dir),
            driver_output(p.PB14, map[2].dir, Level::Low, dir),
            driver_output(p.PB15, map[3].dir, Level::Low, dir),
        ],
        enable: [
            driver_output(p.PB8, map[0].enable, on, enable),
            driver_output(p.PB9, map[1].enable, on, enable),
            driver_output(p.PB4, map[2].enable, on, enable),
            driver_output(p.PB10, map[3].enable, on, enable),
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
    // (`Feeder::feed`), resets the board within `watchdog::TIMEOUT_US`.
    let mut wdg = IndependentWatchdog::new(p.IWDG, watchdog::TIMEOUT_US);
    wdg.unleash();
    spawner.spawn(spawned(
        controller_task(device, hal, UsbRx(receiver), Feeder::new(Iwdg(wdg))),
        "controller_task",
    ));
    spawner.spawn(spawned(blink(led), "blink"));
}

/// `pin` as an output, if it is the map's `want` (the pin the step and fault paths write): the typed
/// pins above and `gonio_firmware::pin_map` cannot disagree unnoticed. The check folds to nothing
/// when they agree.
fn driver_output<P: Pin>(pin: Peri<'static, P>, want: pin_map::Pin, level: Level, speed: Speed) -> Output<'static> {
    if pin.port() != want.port as u8 || pin.pin() != want.bit {
        defmt::panic!("pin P{=u8}.{=u8} is not the pin map's", pin.port(), pin.pin());
    }
    Output::new(pin, level, speed)
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

/// The USB CDC-ACM receiver as the loop's host link.
struct UsbRx(Receiver<'static, UsbDriver>);

impl HostRx for UsbRx {
    async fn next(&mut self, buf: &mut [u8; RX_CHUNK], connected: bool) -> RxEvent {
        if !connected {
            self.0.wait_connection().await;
            return RxEvent::Connected;
        }
        match self.0.read_packet(buf).await {
            Ok(n) => RxEvent::Data(n),
            Err(EndpointError::Disabled) => RxEvent::Disconnected,
            Err(EndpointError::BufferOverflow) => RxEvent::Overflow,
        }
    }
}

struct Iwdg(IndependentWatchdog<'static, peripherals::IWDG>);

impl Watchdog for Iwdg {
    fn pet(&mut self) {
        self.0.pet();
    }
}

#[embassy_executor::task]
async fn controller_task(
    device: &'static mut Device,
    hal: QueuedHal<BoardIo, CsQueue>,
    link: UsbRx,
    watchdog: Feeder<Iwdg>,
) -> ! {
    host_loop::run(device, hal, link, watchdog).await
}
