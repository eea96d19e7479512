//! gonio firmware for the STM32F411CE "Black Pill" (embassy).
//!
//! Today's bring-up binary: clocks, USB CDC-ACM, the shared frame decoder on every received byte,
//! one STEP pulse on the light axis per good host frame, and the PC13 LED blinking. The controller
//! itself (planning, homing, measurement) lives in the `gonio-firmware` logic crate and is wired in
//! here with the firmware issue; this crate stays glue only.
#![no_std]
#![no_main]

use defmt::{info, warn};
use embassy_executor::Spawner;
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::time::Hertz;
use embassy_stm32::usb::{self, Driver};
use embassy_stm32::{bind_interrupts, peripherals, Config};
use embassy_time::Timer;
use embassy_usb::class::cdc_acm::{CdcAcmClass, State};
use embassy_usb::driver::EndpointError;
use embassy_usb::{Builder, UsbDevice};
use gonio_shared::frame::{Frame, FrameDecoder, FrameError};
use gonio_shared::msg::HostMsg;
use static_cell::StaticCell;
use {defmt_rtt as _, panic_probe as _};

bind_interrupts!(struct Irqs {
    OTG_FS => usb::InterruptHandler<peripherals::USB_OTG_FS>;
});

type UsbDriver = Driver<'static, peripherals::USB_OTG_FS>;

/// SYSCLK; the step pulse width below is counted in its cycles.
const SYSCLK_HZ: u32 = 96_000_000;
/// STEP high time: 5 us, above every common driver's minimum (DRV8825 1.9 us, A4988 1 us, TMC 100 ns).
const STEP_PULSE_CYCLES: u32 = SYSCLK_HZ / 1_000_000 * 5;
/// Bulk endpoint size of a full-speed CDC-ACM device.
const USB_PACKET: u16 = 64;
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

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_stm32::init(clocks());
    info!("gonio-stm32 up: SYSCLK {=u32} Hz", SYSCLK_HZ);

    // Black Pill user LED, active low: start off.
    let led = Output::new(p.PC13, Level::High, Speed::Low);
    // Light axis STEP (see README for the full pin table); idle low, pulses high.
    let light_step = Output::new(p.PB0, Level::Low, Speed::Medium);

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
    let class = CdcAcmClass::new(&mut builder, CDC_STATE.init(State::new()), USB_PACKET);
    let usb = builder.build();

    spawner.spawn(usb_task(usb).expect("spawn usb_task"));
    spawner.spawn(host_link(class, light_step).expect("spawn host_link"));
    spawner.spawn(blink(led).expect("spawn blink"));
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

/// Reads USB packets and feeds every byte to the frame decoder; one light STEP pulse per good frame.
#[embassy_executor::task]
async fn host_link(mut class: CdcAcmClass<'static, UsbDriver>, mut step: Output<'static>) -> ! {
    let mut decoder = FrameDecoder::new();
    let mut packet = [0u8; USB_PACKET as usize];
    loop {
        class.wait_connection().await;
        info!("host connected");
        // A partial frame from the previous session must not prefix the next one.
        decoder.reset();
        loop {
            let n = match class.read_packet(&mut packet).await {
                Ok(n) => n,
                Err(EndpointError::Disabled) => break,
                // Cannot happen with a buffer of the endpoint's size; drop the packet if it does.
                Err(EndpointError::BufferOverflow) => {
                    warn!("USB packet larger than {=u16} bytes dropped", USB_PACKET);
                    continue;
                }
            };
            for &byte in packet.get(..n).unwrap_or(&[]) {
                match decoder.push::<HostMsg>(byte) {
                    None => {}
                    Some(Ok(Frame { seq, msg })) => {
                        info!("host frame seq={=u16} {=str}", seq, host_msg_name(&msg));
                        pulse(&mut step);
                    }
                    Some(Err(e)) => {
                        let stats = decoder.stats();
                        warn!(
                            "bad frame dropped: {=str} (ok {=u32}, bad {=u32})",
                            frame_error_name(e),
                            stats.ok,
                            stats.bad()
                        );
                    }
                }
            }
        }
        info!("host disconnected");
    }
}

/// One STEP pulse. Busy-waits a few microseconds: shorter than any await would be.
fn pulse(step: &mut Output<'static>) {
    step.set_high();
    cortex_m::asm::delay(STEP_PULSE_CYCLES);
    step.set_low();
}

/// The variant's name, for defmt (the shared crate stays free of defmt; `Debug2Format` would pull
/// `core::fmt` into flash).
fn host_msg_name(msg: &HostMsg) -> &'static str {
    match msg {
        HostMsg::Hello(_) => "Hello",
        HostMsg::Configure(_) => "Configure",
        HostMsg::Plan(_) => "Plan",
        HostMsg::PlanEnd { .. } => "PlanEnd",
        HostMsg::Home => "Home",
        HostMsg::Start => "Start",
        HostMsg::Pause => "Pause",
        HostMsg::Resume => "Resume",
        HostMsg::Abort => "Abort",
        HostMsg::GetStatus => "GetStatus",
        HostMsg::AckMeasurements { .. } => "AckMeasurements",
        HostMsg::ResendMeasurements { .. } => "ResendMeasurements",
    }
}

fn frame_error_name(e: FrameError) -> &'static str {
    match e {
        FrameError::Crc => "CRC mismatch",
        FrameError::Cobs => "invalid COBS",
        FrameError::TooLong => "too long",
        FrameError::TooShort => "too short",
        FrameError::Payload => "payload is not a HostMsg",
        FrameError::Encode => "encode",
    }
}
