//! gonio firmware for the STM32F411CE "Black Pill" (embassy), and its QEMU build.
//!
//! Glue only: the controller (link, plan streaming, homing, stepping, measurement) is
//! `gonio_firmware::Device`, driven by `host_loop` exactly as the host test bench drives it
//! (`firmware/tests/common/mod.rs`): bytes from the host link go into `Device::receive`,
//! `Device::poll` runs through `QueuedHal::run` (the controller ahead of real time, its steps
//! queued for the step interrupt: `gonio_firmware::timed`), and the outbox goes back to the link.
//!
//! Two builds (cargo features, exactly one):
//! - `board` (default): the Black Pill. `usb` starts it (USB CDC-ACM link, IWDG), `board` has its
//!   pins, TIM2 compare-channel step playback, EXTI switches and ADC detector.
//! - `qemu`: QEMU's netduinoplus2 (STM32F405), for CI. `qemu` starts it (USART1 link), `qemu_board`
//!   has its SysTick time driver, SysTick step playback and the stand-in switches and detector.
#![no_std]
#![no_main]

#[cfg(all(feature = "board", feature = "qemu"))]
compile_error!("build either the board (default) or `--no-default-features --features qemu`, not both");
#[cfg(not(any(feature = "board", feature = "qemu")))]
compile_error!("build the board (default features) or `--no-default-features --features qemu`");

#[cfg(feature = "board")]
mod board;
mod exposure;
mod host_loop;
#[cfg(feature = "qemu")]
mod qemu;
#[cfg(feature = "qemu")]
mod qemu_board;
#[cfg(feature = "board")]
mod usb;

use defmt_rtt as _;
#[cfg(feature = "board")]
use embassy_executor::Spawner;
use embassy_stm32::pac;
use gonio_firmware::pin_map;

/// Drivers off (STEP low, ENABLE released), log where, reset. The panic *message* is not
/// printed: formatting it would link `core::fmt` (docs/firmware.md, "Flash and RAM"); no panic can
/// come from wire data (the logic crate's rule), only from start-up `expect`s.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    drivers_off();
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
    drivers_off();
    cortex_m::peripheral::SCB::sys_reset()
}

/// Every STEP pin low and every driver disabled in one GPIOB BSRR write, the word computed from the
/// pin map and host-tested there (`gonio_firmware::pin_map::DRIVERS_OFF_BSRR`): what a panic or a
/// HardFault does before the reset. (QEMU has no GPIO model: there the write goes nowhere.)
pub fn drivers_off() {
    const _: () = assert!(matches!(pin_map::DRIVER_PORT, pin_map::Port::B));
    pac::GPIOB
        .bsrr()
        .write_value(pac::gpio::regs::Bsrr(pin_map::DRIVERS_OFF_BSRR));
}

#[cfg(feature = "board")]
#[embassy_executor::main]
async fn main(spawner: Spawner) {
    usb::start(spawner);
}

/// A task's spawn token, or a logged halt at boot. Not `expect`: its `Debug` formatting of the
/// error would link `core::fmt`.
fn spawned<T, E>(token: Result<T, E>, name: &str) -> T {
    match token {
        Ok(t) => t,
        Err(_) => defmt::panic!("cannot spawn {=str}", name),
    }
}
