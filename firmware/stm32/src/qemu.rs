//! The QEMU build's start-up and host link: SysTick time (`qemu_board`), the stand-in board I/O,
//! and USART1 as the host link (QEMU's `-serial pty`), in place of `embassy_stm32::init`, the
//! Black Pill's pins and USB (QEMU emulates neither its RCC nor USB). The controller loop, the
//! `Device`, `QueuedHal` and `StepQueue` are the board's.
//!
//! USART1 is driven through 32-bit register accesses only (QEMU's model bus-faults 8-bit ones):
//! its receive interrupt moves each byte into `RX_PIPE`; when the pipe is full it masks itself in
//! the NVIC and leaves the byte in DR (QEMU holds the rest in the pty: the host is held back,
//! nothing is dropped) until the loop has read from the pipe and unmasked it. `uart_tx_task`
//! writes the TX pipe to DR.

use crate::host_loop::{self, Feeder, HostRx, RxEvent, Watchdog, RX_CHUNK, TX_PIPE};
use crate::qemu_board::{self, CsQueue, StandIn, SYSCLK_HZ, TICK_US};
use crate::spawned;
use defmt::info;
use embassy_executor::Spawner;
use embassy_stm32::interrupt::{self, InterruptExt, Priority};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::pipe::Pipe;
use gonio_firmware::timed::QueuedHal;
use gonio_firmware::Device;
use static_cell::{ConstStaticCell, StaticCell};

const USART1: usize = 0x4001_1000;
const USART_SR: usize = USART1;
const USART_DR: usize = USART1 + 0x04;
const USART_CR1: usize = USART1 + 0x0C;
const SR_RXNE: u32 = 1 << 5;
const SR_TXE: u32 = 1 << 7;
const CR1_UE: u32 = 1 << 13;
const CR1_RXNEIE: u32 = 1 << 5;
const CR1_TE: u32 = 1 << 3;
const CR1_RE: u32 = 1 << 2;

/// Received bytes, USART1 interrupt -> controller loop.
const RX_PIPE_BYTES: usize = 256;
static RX_PIPE: Pipe<CriticalSectionRawMutex, RX_PIPE_BYTES> = Pipe::new();

fn rd(addr: usize) -> u32 {
    // SAFETY: a memory-mapped USART1 register of the emulated STM32F405, 32-bit access.
    unsafe { core::ptr::read_volatile(addr as *const u32) }
}

fn wr(addr: usize, v: u32) {
    // SAFETY: as `rd`.
    unsafe { core::ptr::write_volatile(addr as *mut u32, v) }
}

/// The board's executor (embassy's thread-mode `raw::Executor`), idling in WFI instead of WFE: QEMU
/// 7.2 runs WFE as a busy yield, which under `-icount` spends the guest's time spinning. A wake
/// from thread mode (embassy's pender is `sev`) waits for the next interrupt, at most a SysTick.
#[cortex_m_rt::entry]
fn main() -> ! {
    static EXECUTOR: StaticCell<embassy_executor::raw::Executor> = StaticCell::new();
    // The thread-mode pender's context (embassy-executor's `THREAD_PENDER`): `sev`.
    let executor = EXECUTOR.init(embassy_executor::raw::Executor::new(usize::MAX as *mut ()));
    start(executor.spawner());
    loop {
        // SAFETY: polled from this one thread-mode loop only.
        unsafe { executor.poll() };
        cortex_m::asm::wfi();
    }
}

fn start(spawner: Spawner) {
    qemu_board::start_time();
    info!(
        "gonio-stm32 (QEMU netduinoplus2) up: SYSCLK {=u32} Hz, SysTick every {=u32} us",
        SYSCLK_HZ, TICK_US
    );
    // No baud rate: QEMU's USART moves bytes at once.
    wr(USART_CR1, CR1_UE | CR1_TE | CR1_RE | CR1_RXNEIE);
    interrupt::USART1.set_priority(Priority::P1);
    // SAFETY: the handler only touches USART1 and the RX pipe.
    unsafe { interrupt::USART1.enable() };

    // As on the board: all-zero, so in .bss.
    static DEVICE: ConstStaticCell<Device> = ConstStaticCell::new(Device::new());
    let device = DEVICE.take();
    let hal = QueuedHal::new(StandIn::new(), CsQueue);
    spawner.spawn(spawned(uart_tx_task(), "uart_tx_task"));
    spawner.spawn(spawned(
        controller_task(device, hal, UartRx, Feeder::new(NoWatchdog)),
        "controller_task",
    ));
}

#[embassy_stm32::interrupt]
fn USART1() {
    if rd(USART_SR) & SR_RXNE == 0 {
        return;
    }
    if RX_PIPE.is_full() {
        // Leave the byte in DR (QEMU delivers no more until it is read) and stay out until
        // `UartRx` has made room. Masked in the NVIC, not by clearing RXNEIE: QEMU 7.2's USART
        // lowers its interrupt line only when DR is read, and the NVIC re-enters a handler whose
        // line is still high, so this handler ran back to back and starved every task.
        interrupt::USART1.disable();
        return;
    }
    let byte = rd(USART_DR) as u8;
    // Cannot fail: not full, and this handler is the only writer.
    let _ = RX_PIPE.try_write(&[byte]);
}

/// USART1 as the loop's host link: always connected (a UART has no attach event).
struct UartRx;

impl HostRx for UartRx {
    async fn next(&mut self, buf: &mut [u8; RX_CHUNK], connected: bool) -> RxEvent {
        if !connected {
            return RxEvent::Connected;
        }
        let n = RX_PIPE.read(buf).await;
        // Room again: a byte the interrupt left in DR still holds its line high, so it is pending
        // and taken as soon as it is unmasked.
        // SAFETY: the handler only touches USART1 and the RX pipe.
        unsafe { interrupt::USART1.enable() };
        RxEvent::Data(n)
    }
}

/// QEMU 7.2 does not emulate the IWDG.
struct NoWatchdog;

impl Watchdog for NoWatchdog {
    fn pet(&mut self) {}
}

/// TX pipe -> USART1, a byte at a time (QEMU's transmitter is always ready; the wait is for a
/// real UART).
#[embassy_executor::task]
async fn uart_tx_task() -> ! {
    let mut chunk = [0u8; RX_CHUNK];
    loop {
        let n = TX_PIPE.read(&mut chunk).await;
        for &byte in chunk.get(..n).unwrap_or(&[]) {
            while rd(USART_SR) & SR_TXE == 0 {}
            wr(USART_DR, u32::from(byte));
        }
    }
}

#[embassy_executor::task]
async fn controller_task(
    device: &'static mut Device,
    hal: QueuedHal<StandIn, CsQueue>,
    link: UartRx,
    watchdog: Feeder<NoWatchdog>,
) -> ! {
    host_loop::run(device, hal, link, watchdog).await
}
