//! The virtual gonio: the real firmware (`gonio_firmware::Device`) behind a simulated HAL, on a
//! Linux pseudo-terminal, so the host talks to it through the same serial code as to a board.
//!
//! ## Time
//! The simulation clock is instrument time (what the firmware's `now_us` reads and what its
//! measurement timestamps carry). While the firmware has something scheduled (steps, a settle, an
//! exposure) its clock runs `speedup` times faster than the wall clock; while it only waits for the
//! host, it runs at the wall clock's rate, as it would on the bench (host latency costs the real
//! instrument real time). `gonio sim --speedup X` sets the factor (default [`DEFAULT_SPEEDUP`]).
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
/// Firmware polls between two looks at the pty (bounds the latency of host input).
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
    let mut hal = SimHal::new(model);
    // The firmware's Device is ~20 KiB: on the heap, not on this thread's stack.
    let mut dev = Box::new(Device::new());
    let mut inbuf: Vec<u8> = Vec::new();
    let mut outbuf: Vec<u8> = Vec::new();
    let mut tmp = [0u8; 4096];
    let mut report = SimReport::default();
    let mut last_wall = Instant::now();
    // Instrument microseconds the wall clock has granted but the firmware has not used yet.
    let mut budget_us = 0.0f64;
    let mut stopping_since: Option<Instant> = None;
    loop {
        match control.load(Ordering::SeqCst) {
            KILL => break,
            STOP => {
                let since = *stopping_since.get_or_insert_with(Instant::now);
                // Keep the master open until the host has read what the device sent (or a second
                // passed: a host that stopped reading is not waited for).
                let sent = outbuf.is_empty() && dev.link().pending_bytes() == 0 && unread(fds.slave) == 0;
                if sent || since.elapsed() > Duration::from_secs(1) {
                    break;
                }
            }
            _ => {}
        }
        // Host -> device.
        if inbuf.len() < 4096 {
            match nix::unistd::read(fds.master, &mut tmp) {
                Ok(n) => {
                    inbuf.extend_from_slice(tmp.get(..n).unwrap_or(&[]));
                    report.bytes_in += n as u64;
                }
                Err(nix::errno::Errno::EAGAIN | nix::errno::Errno::EIO | nix::errno::Errno::EINTR) => {}
                Err(_) => break,
            }
        }
        if !inbuf.is_empty() {
            let n = dev.receive(&mut hal, &inbuf);
            inbuf.drain(..n.min(inbuf.len()));
            dev.poll(&mut hal);
            drain(&mut dev, &mut outbuf, &mut tmp);
        }
        // Time.
        let now = Instant::now();
        let dt_us = now.duration_since(last_wall).as_secs_f64() * 1e6;
        last_wall = now;
        if dev.next_deadline_us().is_some() {
            budget_us = (budget_us + dt_us * speedup).min(3.6e9);
        } else {
            hal.now_us = hal.now_us.saturating_add(dt_us as u64);
            budget_us = 0.0;
        }
        for _ in 0..POLLS_PER_SLICE {
            let Some(due) = dev.next_deadline_us() else { break };
            let wait = due.saturating_sub(hal.now_us) as f64;
            if wait > budget_us || outbuf.len() >= OUT_BACKLOG {
                break;
            }
            budget_us -= wait;
            hal.now_us = hal.now_us.max(due);
            dev.poll(&mut hal);
            drain(&mut dev, &mut outbuf, &mut tmp);
        }
        counters.readings.store(hal.readings, Ordering::Relaxed);
        counters.instrument_us.store(hal.now_us, Ordering::Relaxed);
        // Device -> host.
        if !outbuf.is_empty() {
            match nix::unistd::write(fds.master, &outbuf) {
                Ok(n) => {
                    outbuf.drain(..n.min(outbuf.len()));
                    report.bytes_out += n as u64;
                }
                Err(nix::errno::Errno::EAGAIN | nix::errno::Errno::EIO | nix::errno::Errno::EINTR) => {}
                Err(_) => break,
            }
        }
        // Sleep until the pty has something, or the next deadline's wall instant (at most 2 ms,
        // so stop requests and clock drift are looked at often).
        let busy = !inbuf.is_empty()
            || dev
                .next_deadline_us()
                .is_some_and(|d| (d.saturating_sub(hal.now_us) as f64) <= budget_us);
        let timeout_ms = if busy {
            0
        } else {
            match dev.next_deadline_us() {
                Some(d) => {
                    (((d.saturating_sub(hal.now_us) as f64 - budget_us) / speedup / 1000.0).ceil() as i32).clamp(0, 2)
                }
                None => 2,
            }
        };
        let mut flags = PollFlags::POLLIN;
        if !outbuf.is_empty() {
            flags |= PollFlags::POLLOUT;
        }
        let mut pfd = [PollFd::new(fds.master, flags)];
        if timeout_ms > 0 || !outbuf.is_empty() {
            let _ = poll(&mut pfd, timeout_ms);
        }
    }
    report.instrument_us = hal.now_us;
    report.readings = hal.readings;
    report.steps = hal.steps_taken;
    report
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

fn drain(dev: &mut Device, outbuf: &mut Vec<u8>, tmp: &mut [u8]) {
    loop {
        let n = dev.drain_outbox(tmp);
        if n == 0 {
            break;
        }
        outbuf.extend_from_slice(tmp.get(..n).unwrap_or(&[]));
    }
}
