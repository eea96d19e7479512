//! The virtual gonio: the real firmware (`gonio_firmware::Device`) behind a simulated board, on a
//! Linux pseudo-terminal, so the host talks to it through the same serial code as to a board.
//!
//! ## Step path
//! As on the STM32: the controller loop is `QueuedHal::run` (the controller ahead of real time,
//! segments queued), and simulated compare channels play the `StepQueue` back at their ticks
//! ([`hal::service_timer`]); the motors move only on played steps.
//!
//! ## Time
//! The simulation clock is instrument time (the board's real time, what measurement timestamps
//! carry). While the firmware has something scheduled (steps, a settle, an exposure) or steps are
//! queued, it runs `speedup` times faster than the wall clock; while it only waits for the host, it
//! runs at the wall clock's rate, as it would on the bench (host latency costs the real instrument
//! real time). `gonio sim --speedup X` sets the factor (default [`DEFAULT_SPEEDUP`]).
//!
//! ## Pseudo-terminal
//! `openpty` + raw mode on the slave; the simulation keeps its own slave descriptor open so that
//! a host closing and reopening the port (a resume) never makes the master fail, and keeps the
//! master open until it is stopped. With a `link` path, the slave is published under that fixed
//! name (a symlink re-pointed on restart), so a host can find the device again after it "replugs".

pub mod hal;
pub mod model;

use gonio_firmware::Device;
use hal::SimHal;
use model::SimModel;
use nix::poll::{poll, PollFd, PollFlags};
use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};
use std::os::unix::io::RawFd;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, AtomicU8, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Instrument seconds per wall second while the firmware is busy, unless told otherwise.
pub const DEFAULT_SPEEDUP: f64 = 100.0;

/// Bytes of device output held for a host that does not read, before the device is throttled.
const OUT_BACKLOG: usize = 64 * 1024;
/// Controller loop turns and timer interrupts between two looks at the pty (bounds the latency of host input).
const POLLS_PER_SLICE: usize = 2_000;

#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("virtual gonio: cannot create a pseudo-terminal: {0}")]
    Pty(nix::Error),
    #[error("virtual gonio: cannot publish the port as {path}: {source}")]
    Link { path: String, source: std::io::Error },
    #[error("virtual gonio: speedup must be finite and > 0, got {0}")]
    Speedup(f64),
}

const RUN: u8 = 0;
const STOP: u8 = 1;
const KILL: u8 = 2;

/// What a stopped simulation did.
#[derive(Clone, Debug, Default)]
pub struct SimReport {
    pub instrument_us: u64,
    pub readings: u64,
    pub steps: u64,
    pub bytes_in: u64,
    pub bytes_out: u64,
}

/// Counters readable while the simulation runs.
#[derive(Debug, Default)]
pub struct SimCounters {
    pub readings: AtomicU64,
    pub instrument_us: AtomicU64,
}

/// A running virtual gonio. Dropping it stops it.
pub struct SimHandle {
    model: Arc<SimModel>,
    speedup: f64,
    link: Option<PathBuf>,
    slave_path: PathBuf,
    control: Arc<AtomicU8>,
    counters: Arc<SimCounters>,
    thread: Option<JoinHandle<SimReport>>,
}

impl SimHandle {
    /// Start the device on a fresh pseudo-terminal (published at `link` if given).
    pub fn spawn(model: Arc<SimModel>, speedup: f64, link: Option<PathBuf>) -> Result<Self, SimError> {
        if !(speedup.is_finite() && speedup > 0.0) {
            return Err(SimError::Speedup(speedup));
        }
        let pty = nix::pty::openpty(None, None).map_err(SimError::Pty)?;
        let fds = Fds {
            master: pty.master,
            slave: pty.slave,
        };
        let setup = || -> nix::Result<PathBuf> {
            // openpty does not set close-on-exec: without it a child process (a host started by
            // the same program) would keep the master open and never see the device go away.
            for fd in [fds.master, fds.slave] {
                nix::fcntl::fcntl(fd, nix::fcntl::FcntlArg::F_SETFD(nix::fcntl::FdFlag::FD_CLOEXEC))?;
            }
            let mut t = tcgetattr(fds.slave)?;
            cfmakeraw(&mut t);
            tcsetattr(fds.slave, SetArg::TCSANOW, &t)?;
            nix::fcntl::fcntl(fds.master, nix::fcntl::FcntlArg::F_SETFL(nix::fcntl::OFlag::O_NONBLOCK))?;
            nix::unistd::ttyname(fds.slave)
        };
        let slave_path = setup().map_err(SimError::Pty)?;
        if let Some(l) = &link {
            publish(l, &slave_path).map_err(|source| SimError::Link {
                path: l.display().to_string(),
                source,
            })?;
        }
        let control = Arc::new(AtomicU8::new(RUN));
        let counters = Arc::new(SimCounters::default());
        let thread = {
            let (model, control, counters) = (model.clone(), control.clone(), counters.clone());
            std::thread::Builder::new()
                .name("virtual-gonio".into())
                .spawn(move || run(fds, model, speedup, &control, &counters))
                .map_err(|e| SimError::Pty(nix::Error::from_i32(e.raw_os_error().unwrap_or(0))))?
        };
        Ok(Self {
            model,
            speedup,
            link,
            slave_path,
            control,
            counters,
            thread: Some(thread),
        })
    }

    /// The port a host opens: the published link if any, else the pty slave.
    pub fn path(&self) -> &Path {
        self.link.as_deref().unwrap_or(&self.slave_path)
    }

    pub fn counters(&self) -> &SimCounters {
        &self.counters
    }

    /// Stop after sending what the device still has for the host.
    pub fn stop(mut self) -> SimReport {
        self.finish(STOP)
    }

    /// Pull the plug: the device and everything it held are gone at once.
    pub fn kill(mut self) -> SimReport {
        self.finish(KILL)
    }

    /// Pull the plug and plug a freshly booted device back in (same published link, if any).
    pub fn restart(&mut self) -> Result<SimReport, SimError> {
        let report = self.finish(KILL);
        let fresh = Self::spawn(self.model.clone(), self.speedup, self.link.clone())?;
        let old = std::mem::replace(self, fresh);
        drop(old);
        Ok(report)
    }

    fn finish(&mut self, how: u8) -> SimReport {
        self.control.store(how, Ordering::SeqCst);
        self.thread.take().and_then(|t| t.join().ok()).unwrap_or_default()
    }
}

impl Drop for SimHandle {
    fn drop(&mut self) {
        if self.thread.is_some() {
            self.finish(STOP);
        }
    }
}

/// Point `link` at `target` atomically (a symlink renamed into place).
fn publish(link: &Path, target: &Path) -> std::io::Result<()> {
    let tmp = crate::fsio::temp_name(link);
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp)?;
    std::fs::rename(&tmp, link)
}

struct Fds {
    master: RawFd,
    slave: RawFd,
}

impl Drop for Fds {
    fn drop(&mut self) {
        let _ = nix::unistd::close(self.master);
        let _ = nix::unistd::close(self.slave);
    }
}

fn run(fds: Fds, model: Arc<SimModel>, speedup: f64, control: &AtomicU8, counters: &SimCounters) -> SimReport {
    let mut sim = Instrument::new(model);
    // The firmware's host-silence hold counts instrument time, which runs `speedup` times faster.
    let silent = gonio_firmware::controller::HOST_SILENT_US as f64 * speedup.max(1.0);
    sim.dev.set_host_silent_us(silent.min(u64::MAX as f64) as u64);
    let mut io = PtyIo::default();
    let mut last_wall = Instant::now();
    let mut stopping_since: Option<Instant> = None;
    loop {
        match control.load(Ordering::SeqCst) {
            KILL => break,
            STOP => {
                let since = *stopping_since.get_or_insert_with(Instant::now);
                // Keep the master open until the host has read what the device sent (or a second
                // passed: a host that stopped reading is not waited for).
                let sent = io.outbuf.is_empty() && sim.dev.outbox().pending_bytes() == 0 && unread(fds.slave) == 0;
                if sent || since.elapsed() > Duration::from_secs(1) {
                    break;
                }
            }
            _ => {}
        }
        if io.read(fds.master).is_err() {
            break;
        }
        sim.receive(&mut io);
        let now = Instant::now();
        let wall_us = now.duration_since(last_wall).as_secs_f64() * 1e6;
        last_wall = now;
        sim.advance(wall_us, speedup, &mut io);
        counters.readings.store(sim.hal.board.readings, Ordering::Relaxed);
        counters.instrument_us.store(sim.hal.board.now_us, Ordering::Relaxed);
        if io.write(fds.master).is_err() {
            break;
        }
        io.wait(fds.master, sim.idle_wall_ms(speedup, !io.inbuf.is_empty()));
    }
    SimReport {
        instrument_us: sim.hal.board.now_us,
        readings: sim.hal.board.readings,
        steps: sim.hal.board.steps_taken,
        bytes_in: io.bytes_in,
        bytes_out: io.bytes_out,
    }
}

/// The device and its board, on instrument time.
struct Instrument {
    hal: SimHal,
    /// The firmware's Device is ~20 KiB: on the heap, not on this thread's stack.
    dev: Box<Device>,
    /// Board time the controller loop asked to run again at (`QueuedHal::run`'s answer).
    run_at: Option<u64>,
    /// Instrument microseconds the wall clock has granted but the instrument has not used yet.
    budget_us: f64,
}

impl Instrument {
    fn new(model: Arc<SimModel>) -> Self {
        Self {
            hal: hal::sim_hal(model),
            dev: Box::new(Device::new()),
            run_at: Some(0),
            budget_us: 0.0,
        }
    }

    /// Host bytes into the device, then a turn of the controller loop.
    fn receive(&mut self, io: &mut PtyIo) {
        if io.inbuf.is_empty() {
            return;
        }
        let n = self.dev.receive(&mut self.hal, &io.inbuf);
        io.inbuf.drain(..n.min(io.inbuf.len()));
        self.run_at = self.hal.run(&mut self.dev);
        io.take_output(&mut self.dev);
    }

    /// The board time of the next thing the instrument does on its own: a step timer interrupt or
    /// a turn of the controller loop; `None` when only the host can make progress.
    fn next_event(&self) -> Option<u64> {
        [hal::timer_wake(&self.hal), self.run_at].into_iter().flatten().min()
    }

    /// Let `wall_us` of wall time pass: `speedup` times as much instrument time while busy, as much
    /// while waiting for the host. Runs timer interrupts and the controller loop as they fall due.
    fn advance(&mut self, wall_us: f64, speedup: f64, io: &mut PtyIo) {
        if self.next_event().is_some() {
            self.budget_us = (self.budget_us + wall_us * speedup).min(3.6e9);
        } else {
            self.hal.board.now_us = self.hal.board.now_us.saturating_add(wall_us as u64);
            self.budget_us = 0.0;
        }
        for _ in 0..POLLS_PER_SLICE {
            let Some(due) = self.next_event() else { break };
            let wait = due.saturating_sub(self.hal.board.now_us) as f64;
            if wait > self.budget_us || io.outbuf.len() >= OUT_BACKLOG {
                break;
            }
            self.budget_us -= wait;
            self.hal.board.now_us = self.hal.board.now_us.max(due);
            if hal::timer_wake(&self.hal).is_some_and(|w| w <= self.hal.board.now_us) {
                hal::service_timer(&mut self.hal);
            }
            if self.run_at.is_some_and(|t| t <= self.hal.board.now_us) {
                self.run_at = self.hal.run(&mut self.dev);
                io.take_output(&mut self.dev);
            }
        }
    }

    /// How long the thread may sleep on the pty: until the next event's wall instant, at most
    /// 2 ms (so stop requests and clock drift are looked at often), 0 when work is due now.
    fn idle_wall_ms(&self, speedup: f64, input_waiting: bool) -> i32 {
        let next = self.next_event();
        let ahead = |d: u64| d.saturating_sub(self.hal.board.now_us) as f64;
        if input_waiting || next.is_some_and(|d| ahead(d) <= self.budget_us) {
            return 0;
        }
        match next {
            Some(d) => (((ahead(d) - self.budget_us) / speedup / 1000.0).ceil() as i32).clamp(0, 2),
            None => 2,
        }
    }
}

/// Bytes between the pty and the device, with their counts.
#[derive(Default)]
struct PtyIo {
    inbuf: Vec<u8>,
    outbuf: Vec<u8>,
    bytes_in: u64,
    bytes_out: u64,
}

impl PtyIo {
    /// Host -> device buffer, up to 4 KiB held; `Err` when the pty is gone.
    fn read(&mut self, master: RawFd) -> Result<(), nix::Error> {
        if self.inbuf.len() >= 4096 {
            return Ok(());
        }
        let mut tmp = [0u8; 4096];
        match nix::unistd::read(master, &mut tmp) {
            Ok(n) => {
                self.inbuf.extend_from_slice(tmp.get(..n).unwrap_or(&[]));
                self.bytes_in += n as u64;
                Ok(())
            }
            Err(nix::errno::Errno::EAGAIN | nix::errno::Errno::EIO | nix::errno::Errno::EINTR) => Ok(()),
            Err(e) => Err(e),
        }
    }

    /// Device -> host, as much as the pty takes; `Err` when the pty is gone.
    fn write(&mut self, master: RawFd) -> Result<(), nix::Error> {
        if self.outbuf.is_empty() {
            return Ok(());
        }
        match nix::unistd::write(master, &self.outbuf) {
            Ok(n) => {
                self.outbuf.drain(..n.min(self.outbuf.len()));
                self.bytes_out += n as u64;
                Ok(())
            }
            Err(nix::errno::Errno::EAGAIN | nix::errno::Errno::EIO | nix::errno::Errno::EINTR) => Ok(()),
            Err(e) => Err(e),
        }
    }

    /// Everything in the device's outbox, into `outbuf`.
    fn take_output(&mut self, dev: &mut Device) {
        let mut tmp = [0u8; 4096];
        loop {
            let n = dev.drain_outbox(&mut tmp);
            if n == 0 {
                break;
            }
            self.outbuf.extend_from_slice(tmp.get(..n).unwrap_or(&[]));
        }
    }

    /// Sleep until the pty is readable (or writable, with output pending) or `timeout_ms` passed.
    fn wait(&self, master: RawFd, timeout_ms: i32) {
        let mut flags = PollFlags::POLLIN;
        if !self.outbuf.is_empty() {
            flags |= PollFlags::POLLOUT;
        }
        let mut pfd = [PollFd::new(master, flags)];
        if timeout_ms > 0 || !self.outbuf.is_empty() {
            let _ = poll(&mut pfd, timeout_ms);
        }
    }
}

/// Bytes waiting in the slave's input queue, i.e. sent by the device and not yet read by the host.
fn unread(slave: RawFd) -> usize {
    let mut n: libc::c_int = 0;
    // SAFETY: FIONREAD writes one c_int through the pointer, which points at `n` for the whole
    // call; `slave` is a descriptor this thread owns and keeps open.
    let r = unsafe { libc::ioctl(slave, libc::FIONREAD, &mut n as *mut libc::c_int) };
    if r == 0 {
        usize::try_from(n).unwrap_or(0)
    } else {
        0
    }
}
