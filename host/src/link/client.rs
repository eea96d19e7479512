//! The typed client (Klipper's serialhdl + mcu): the handshake, status, bringing the device to
//! rest, configure and home (each matched to its answer by sequence number), and the scan: the
//! plan stream's state machine ([`PlanStream`]) driven over the reliability layer, with every
//! measurement handed to a [`MeasurementSink`] and acknowledged once the sink has it on disk.

use super::error::LinkError;
use super::reliable::{LinkStats, LinkTiming, Reliable};
use super::stream::{PlanStream, Reading, Stop};
use super::transport::Transport;
use gonio_shared::instrument::InstrumentConfig;
use gonio_shared::kinematics::Kinematics;
use gonio_shared::msg::{
    check_handshake, ControllerState, DeviceMsg, Direction, Fault, Hello, HostMsg, RefuseReason, Status,
};
use std::time::{Duration, Instant};

/// Where measurements go: `record` each as it arrives (in sequence order, exactly once), `sync`
/// before they are acknowledged to the device (after which it forgets them).
pub trait MeasurementSink {
    fn record(&mut self, m: &gonio_shared::msg::Measurement) -> Result<(), String>;
    fn sync(&mut self) -> Result<(), String>;
}

/// One connection to a gonio.
pub struct Link<T: Transport> {
    r: Reliable<T>,
    /// The configured instrument, to report fault poses in degrees.
    kin: Option<Kinematics<f32>>,
}

impl<T: Transport> Link<T> {
    /// Handshake on a fresh transport: our Hello, until the device's Hello (or a clear refusal).
    ///
    /// The Hello carries a fresh session id and always goes as sequence number 0, the same frame
    /// on every try: the device opens a new session for it once and treats its copies as
    /// duplicates (see `msg::Hello`), so a late copy can never restart its count mid-session.
    pub fn connect(t: T, timing: LinkTiming) -> Result<Self, LinkError> {
        let hello = Hello::ours(new_session_id());
        let mut r = Reliable::new(t, timing);
        let start = Instant::now();
        let mut tries = 0u32;
        while start.elapsed() < timing.hello_timeout {
            r.restart_numbering();
            r.send(&HostMsg::Hello(hello))?;
            tries += 1;
            let until = Instant::now() + timing.rto.max(Duration::from_millis(200)) * tries.min(4);
            while Instant::now() < until {
                r.pump(Duration::from_millis(20))?;
                while let Some(m) = r.take_queued() {
                    if let DeviceMsg::Hello(theirs) = m {
                        check_handshake(theirs)?;
                        if theirs.session != hello.session {
                            // A stale answer (to an earlier connection's Hello).
                            continue;
                        }
                        r.clear_queued();
                        // The device answered, so it has our Hello: no need to resend it (a resent
                        // copy would be harmless, only acknowledged and answered again).
                        r.forget_inflight();
                        return Ok(Self { r, kin: None });
                    }
                }
            }
        }
        Err(LinkError::NoHello(timing.hello_timeout.as_secs_f64()))
    }

    pub fn into_inner(self) -> T {
        self.r.into_inner()
    }

    /// What this connection's link did so far.
    pub fn stats(&self) -> LinkStats {
        self.r.stats
    }

    /// Send `msg`, counting status and resend requests.
    fn send_counted(&mut self, msg: &HostMsg) -> Result<u16, LinkError> {
        match msg {
            HostMsg::GetStatus => self.r.stats.status_requests += 1,
            HostMsg::ResendMeasurements { .. } => self.r.stats.resend_requests += 1,
            _ => {}
        }
        self.r.send(msg)
    }

    /// Ask for status until one arrives; other messages on the way are dropped (the callers
    /// use this only outside a scan's streaming).
    pub fn status(&mut self) -> Result<Status, LinkError> {
        for _ in 0..20 {
            self.send_counted(&HostMsg::GetStatus)?;
            let until = Instant::now() + self.r.timing.rto * 3;
            while Instant::now() < until {
                if let Some(DeviceMsg::Status(s)) = self.r.next_msg(Duration::from_millis(20))? {
                    return Ok(s);
                }
            }
        }
        Err(LinkError::Silent("no status reply".into()))
    }

    /// Reconnected after a connection loss: take the readings the device kept from our last
    /// session (which had taken `from` of them in order) before `prepare` resets it. Only a device
    /// still in that scan has them (homed, readings unacknowledged); a running scan is paused
    /// first, so it finishes its direction and the collection ends.
    pub fn collect_kept(&mut self, from: u32, sink: &mut dyn MeasurementSink) -> Result<(), LinkError> {
        let s = self.status()?;
        let in_scan = matches!(
            s.state,
            ControllerState::Running | ControllerState::Paused | ControllerState::Done | ControllerState::Fault
        );
        if s.unacked == 0 || !s.homed || !in_scan {
            return Ok(());
        }
        if s.state == ControllerState::Running {
            self.r.send(&HostMsg::Pause)?;
        }
        self.send_counted(&HostMsg::ResendMeasurements { from })?;
        let mut next = from;
        let mut last = Instant::now();
        while last.elapsed() < self.r.timing.rto * 4 {
            if let Some(DeviceMsg::Measurement(m)) = self.r.next_msg(Duration::from_millis(20))? {
                last = Instant::now();
                if m.seq == next {
                    sink.record(&m).map_err(LinkError::Sink)?;
                    next += 1;
                }
            }
        }
        if next > from {
            sink.sync().map_err(LinkError::Sink)?;
            self.r.send(&HostMsg::AckMeasurements { through: next - 1 })?;
            self.r.flush()?;
        }
        Ok(())
    }

    /// Bring the device to Ready with `cfg` and homed, whatever it was doing (a previous host's
    /// scan, a fault).
    pub fn prepare(&mut self, cfg: &InstrumentConfig<f32>) -> Result<Status, LinkError> {
        self.kin = Kinematics::new(*cfg).ok();
        self.settle()?;
        self.configure(cfg)?;
        let s = self.status()?;
        if s.homed && s.state == ControllerState::Ready {
            return Ok(s);
        }
        self.home()
    }

    /// Stop whatever the device is doing (abort a move or a scan; home away a fault that lost the
    /// position) until it is Idle, Ready or Done.
    fn settle(&mut self) -> Result<(), LinkError> {
        let mut homing_sent = false;
        for _ in 0..200 {
            let s = self.status()?;
            match s.state {
                ControllerState::Idle | ControllerState::Ready | ControllerState::Done => break,
                ControllerState::Fault
                    if matches!(s.last_fault, Some(Fault::LimitSwitch(_) | Fault::HomeNotFound(_))) =>
                {
                    // Only homing clears a fault that lost the position.
                    if !homing_sent {
                        self.r.send(&HostMsg::Home)?;
                        homing_sent = true;
                    }
                }
                ControllerState::Homing if homing_sent => {}
                _ => {
                    self.r.send(&HostMsg::Abort)?;
                }
            }
            self.r.flush()?;
            std::thread::sleep(Duration::from_millis(20));
        }
        Ok(())
    }

    /// Send the instrument configuration until the device takes it (its first `Credit`): it is
    /// refused while a move winds down; a refusal of the configuration itself is final.
    fn configure(&mut self, cfg: &InstrumentConfig<f32>) -> Result<(), LinkError> {
        for _ in 0..200 {
            let cfg_seq = self.r.send(&HostMsg::Configure(*cfg))?;
            let until = Instant::now() + self.r.timing.rto * 4;
            let mut refused = None;
            while Instant::now() < until && refused.is_none() {
                match self.r.next_msg(Duration::from_millis(20))? {
                    Some(DeviceMsg::Credit { next_index: 0, .. }) => return Ok(()),
                    // Only the answer to this Configure (not to an earlier Abort or Home).
                    Some(DeviceMsg::Refused { seq, reason, .. }) if seq == cfg_seq => refused = Some(reason),
                    _ => {}
                }
            }
            if let Some(reason @ (RefuseReason::BadConfig(_) | RefuseReason::NoHandshake)) = refused {
                return Err(LinkError::Refused {
                    what: "the instrument configuration",
                    reason,
                });
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        Err(LinkError::Silent("the device never accepted the configuration".into()))
    }

    /// Home every axis and wait until the device is Ready and homed.
    fn home(&mut self) -> Result<Status, LinkError> {
        self.r.send(&HostMsg::Home)?;
        let start = Instant::now();
        while start.elapsed() < self.r.timing.homing {
            std::thread::sleep(Duration::from_millis(10));
            let s = self.status()?;
            match s.state {
                ControllerState::Ready if s.homed => return Ok(s),
                ControllerState::Fault => return Err(self.fault_error(s.last_fault, Some(s.steps))),
                ControllerState::Idle => {
                    self.r.send(&HostMsg::Home)?;
                }
                _ => {}
            }
        }
        Err(LinkError::Silent("homing did not finish".into()))
    }

    /// Stream `plan` (indices 0..len on the wire), start, and hand every measurement to `sink`
    /// exactly once in order. Returns when all have arrived and are acknowledged.
    pub fn scan(&mut self, plan: &[Direction], sink: &mut dyn MeasurementSink) -> Result<(), LinkError> {
        let mut stream = PlanStream::new(plan, self.r.next_seq(), self.r.timing, Instant::now())?;
        if stream.is_complete() {
            return Ok(());
        }
        loop {
            while self.r.window_free() {
                let Some(msg) = stream.next_frame()? else { break };
                let seq = self.r.send(&msg)?;
                stream.sent(&msg, seq);
            }
            let msg = self.r.next_msg(Duration::from_millis(20))?;
            let quiet = msg.is_none();
            if let Some(msg) = msg {
                self.on_scan_msg(&mut stream, msg, sink)?;
                stream.on_activity(Instant::now());
            }
            if self.r.window_free() {
                if let Some(ack) = stream.ack_due(quiet) {
                    sink.sync().map_err(LinkError::Sink)?;
                    self.r.send(&ack)?;
                }
            }
            if stream.is_complete() {
                return self.r.flush();
            }
            let now = Instant::now();
            if self.r.window_free() {
                if let Some(ask) = stream.status_due(now) {
                    self.send_counted(&ask)?;
                }
            }
            if self.r.window_free() {
                if let Some(ask) = stream.probe_due(now) {
                    self.send_counted(&ask)?;
                }
            }
        }
    }

    /// One device message during a scan, fed to the stream; sends what it asks for.
    fn on_scan_msg(
        &mut self,
        stream: &mut PlanStream,
        msg: DeviceMsg,
        sink: &mut dyn MeasurementSink,
    ) -> Result<(), LinkError> {
        let now = Instant::now();
        match msg {
            DeviceMsg::Credit { next_index, free } => stream.on_credit(next_index, free, now),
            DeviceMsg::Measurement(m) => match stream.on_measurement(&m, now)? {
                Reading::Record => sink.record(&m).map_err(LinkError::Sink)?,
                Reading::Duplicate => self.r.stats.duplicate_measurements += 1,
                Reading::Resend { from } => {
                    self.send_counted(&HostMsg::ResendMeasurements { from })?;
                }
                Reading::Early => {}
            },
            DeviceMsg::Fault(f) => return Err(self.stop_on_fault(Some(f), stream.received(), sink)),
            DeviceMsg::Status(s) => {
                if self.r.all_acked() {
                    stream.on_settled_status(&s, self.r.next_seq());
                }
                match stream.on_status(&s, now) {
                    Ok(replies) => {
                        for reply in &replies {
                            self.send_counted(reply)?;
                        }
                    }
                    Err(Stop::Fault(fault)) => return Err(self.stop_on_fault(fault, stream.received(), sink)),
                    Err(Stop::Error(e)) => return Err(e),
                }
            }
            DeviceMsg::Refused { seq, command, reason } => {
                if let Some(ask) = stream.on_refused(seq, command, reason, self.r.next_seq())? {
                    if self.r.window_free() {
                        self.send_counted(&ask)?;
                    }
                }
            }
            DeviceMsg::Hello(_) | DeviceMsg::Ack { .. } | DeviceMsg::Nak { .. } => {}
        }
        Ok(())
    }

    /// A fault stops the scan: collect what was measured before it, then report where it stopped.
    fn stop_on_fault(&mut self, fault: Option<Fault>, mut next_seq: u32, sink: &mut dyn MeasurementSink) -> LinkError {
        let status = self.status().ok();
        if let Some(s) = &status {
            if s.plan_done > next_seq && self.r.send(&HostMsg::ResendMeasurements { from: next_seq }).is_ok() {
                let until = Instant::now() + self.r.timing.rto * 10;
                while Instant::now() < until && next_seq < s.plan_done {
                    match self.r.next_msg(Duration::from_millis(20)) {
                        Ok(Some(DeviceMsg::Measurement(m))) if m.seq == next_seq => {
                            if sink.record(&m).is_err() {
                                break;
                            }
                            next_seq += 1;
                        }
                        Ok(_) => {}
                        Err(_) => break,
                    }
                }
                let _ = sink.sync();
                if next_seq > 0 {
                    let _ = self.r.send(&HostMsg::AckMeasurements { through: next_seq - 1 });
                    let _ = self.r.flush();
                }
            }
        }
        self.fault_error(fault, status.map(|s| s.steps))
    }

    /// `fault` is `None` when the device is in its fault state but its status names no fault (it
    /// should always name one; the host reports that rather than inventing a cause).
    fn fault_error(&self, fault: Option<Fault>, steps: Option<[i32; 4]>) -> LinkError {
        let pose = match (steps, &self.kin) {
            (Some(s), Some(k)) => {
                let p = k.from_steps(&s);
                format!(
                    "light {:.2} deg, detector {:.2} deg, tilt {:.2} deg, azimuth {:.2} deg (steps {s:?})",
                    p.light.to_degrees(),
                    p.detector.to_degrees(),
                    p.tilt.to_degrees(),
                    p.azimuth.to_degrees()
                )
            }
            (Some(s), None) => format!("steps {s:?}"),
            _ => "unknown".to_string(),
        };
        match fault {
            Some(fault) => LinkError::Fault { fault, pose, steps },
            None => LinkError::UnnamedFault { pose },
        }
    }
}

/// A session id for one connection: differs between connections (and processes) with
/// overwhelming probability, so the device tells a new session's Hello from a copy of the last.
fn new_session_id() -> u32 {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    h.write_u128(now);
    h.write_u32(std::process::id());
    // Truncation intended: any 32 bits of the hash.
    h.finish() as u32
}
