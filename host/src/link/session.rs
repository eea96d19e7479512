//! The host side of the wire: frames with sequence numbers, acknowledged one by one; a window of
//! frames in flight, resent from the one the device expects on a NAK (go-back-N) or when the
//! oldest waited longer than the retransmit timeout; the handshake; and the scan conversation:
//! configure, home, stream the plan under `Credit`, start, collect measurements in sequence order,
//! acknowledge them once the caller has them on disk, ask for resends on gaps and silences.

use super::transport::Transport;
use gonio_shared::frame::{encode, FrameDecoder, MAX_WIRE_FRAME};
use gonio_shared::instrument::InstrumentConfig;
use gonio_shared::msg::caps::CHUNK_DIRECTIONS;
use gonio_shared::msg::{
    check_handshake, Command, ControllerState, DeviceMsg, Direction, Fault, HandshakeError, Hello, HostMsg,
    Measurement, PlanChunk, RefuseReason, Status,
};
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Status answers in a row showing a device out of plan that grants no credit, before the scan
/// gives up (about 10 s at the idle poll interval).
const STARVED_STATUS_LIMIT: u32 = 25;

/// Frames sent and not yet acknowledged, at most.
const WINDOW: usize = 16;
/// Acknowledge measurements at least every this many. Each acknowledgement costs a journal sync
/// (fsync); 32 keeps the firmware's 128-slot buffer at most a quarter full in steady streaming.
const ACK_EVERY: u32 = 32;

#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// The port went away (unplugged, device killed) or stopped answering.
    #[error("lost the device: {0}")]
    Disconnected(String),
    #[error("no gonio answered on this port (no Hello within {0:.1} s)")]
    NoHello(f64),
    #[error(transparent)]
    Handshake(#[from] HandshakeError),
    #[error("lost the device: it stopped answering ({0})")]
    Silent(String),
    #[error("the device refused {what}: {reason:?}")]
    Refused { what: &'static str, reason: RefuseReason },
    #[error("device fault {fault:?} at pose {pose}")]
    Fault {
        fault: Fault,
        pose: String,
        steps: Option<[i32; 4]>,
    },
    #[error("the device is in its fault state without naming the fault, at pose {pose}")]
    UnnamedFault { pose: String },
    #[error("{0}")]
    Sink(String),
    /// The protocol deadlocked (a device that ran out of plan and grants no credit).
    #[error("the scan stalled: {0}")]
    Stalled(String),
}

impl LinkError {
    /// Errors after which the same scan can go on once the device is back.
    pub fn is_connection_loss(&self) -> bool {
        matches!(self, LinkError::Disconnected(_) | LinkError::Silent(_))
    }
}

/// Timing of the link, wall time.
#[derive(Clone, Copy, Debug)]
pub struct LinkTiming {
    pub hello_timeout: Duration,
    /// Resend the oldest unacknowledged frame after this.
    pub rto: Duration,
    /// Ask for status after this long without any message from the device.
    pub idle: Duration,
    /// Give up (connection lost) after this long without any frame from the device.
    pub silence: Duration,
    /// Longest homing, wall time.
    pub homing: Duration,
}

impl Default for LinkTiming {
    fn default() -> Self {
        Self {
            hello_timeout: Duration::from_secs(2),
            rto: Duration::from_millis(150),
            idle: Duration::from_millis(400),
            silence: Duration::from_secs(5),
            homing: Duration::from_secs(600),
        }
    }
}

/// What the link did, for reports and tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkStats {
    pub frames_sent: u64,
    pub retransmits: u64,
    pub naks: u64,
    pub timeouts: u64,
    pub bad_frames_in: u64,
    pub duplicate_measurements: u64,
    pub resend_requests: u64,
    pub status_requests: u64,
}

/// Where measurements go: `record` each as it arrives (in sequence order, exactly once), `sync`
/// before they are acknowledged to the device (after which it forgets them).
pub trait MeasurementSink {
    fn record(&mut self, m: &Measurement) -> Result<(), String>;
    fn sync(&mut self) -> Result<(), String>;
}

/// One connection to a gonio.
pub struct Link<T: Transport> {
    t: T,
    dec: FrameDecoder,
    tx_seq: u16,
    inflight: VecDeque<(u16, Vec<u8>)>,
    oldest_sent: Instant,
    last_nak: Option<(u16, Instant)>,
    rx: VecDeque<DeviceMsg>,
    last_rx: Instant,
    pub timing: LinkTiming,
    pub stats: LinkStats,
    /// The configured instrument, to report fault poses in degrees.
    kin: Option<gonio_shared::kinematics::Kinematics<f32>>,
}

impl<T: Transport> Link<T> {
    /// Handshake on a fresh transport: our Hello, until the device's Hello (or a clear refusal).
    ///
    /// The Hello carries a fresh session id and always goes as sequence number 0, the same frame
    /// on every try: the device opens a new session for it once and treats its copies as
    /// duplicates (see `msg::Hello`), so a late copy can never restart its count mid-session.
    pub fn connect(t: T, timing: LinkTiming) -> Result<Self, LinkError> {
        let hello = Hello::ours(new_session_id());
        let mut link = Self {
            t,
            dec: FrameDecoder::new(),
            tx_seq: 0,
            inflight: VecDeque::new(),
            oldest_sent: Instant::now(),
            last_nak: None,
            rx: VecDeque::new(),
            last_rx: Instant::now(),
            timing,
            stats: LinkStats::default(),
            kin: None,
        };
        let start = Instant::now();
        let mut tries = 0u32;
        while start.elapsed() < timing.hello_timeout {
            link.inflight.clear();
            link.tx_seq = 0;
            link.send(&HostMsg::Hello(hello))?;
            tries += 1;
            let until = Instant::now() + timing.rto.max(Duration::from_millis(200)) * tries.min(4);
            while Instant::now() < until {
                link.pump(Duration::from_millis(20))?;
                while let Some(m) = link.rx.pop_front() {
                    if let DeviceMsg::Hello(theirs) = m {
                        check_handshake(theirs)?;
                        if theirs.session != hello.session {
                            // A stale answer (to an earlier connection's Hello).
                            continue;
                        }
                        link.rx.clear();
                        // The device answered, so it has our Hello: no need to resend it (a resent
                        // copy would be harmless, only acknowledged and answered again).
                        link.inflight.clear();
                        return Ok(link);
                    }
                }
            }
        }
        Err(LinkError::NoHello(timing.hello_timeout.as_secs_f64()))
    }

    pub fn into_inner(self) -> T {
        self.t
    }

    pub fn transport(&self) -> &T {
        &self.t
    }

    fn io(e: std::io::Error) -> LinkError {
        LinkError::Disconnected(e.to_string())
    }

    /// Queue `msg` with the next sequence number (waits while the window is full); returns the
    /// sequence number it went with (named by a `Refused` answering it).
    pub fn send(&mut self, msg: &HostMsg) -> Result<u16, LinkError> {
        while self.inflight.len() >= WINDOW {
            self.pump(Duration::from_millis(10))?;
        }
        let mut buf = [0u8; MAX_WIRE_FRAME];
        let n =
            encode(self.tx_seq, msg, &mut buf).map_err(|e| LinkError::Sink(format!("cannot encode {msg:?}: {e}")))?;
        let frame = buf.get(..n).unwrap_or(&[]).to_vec();
        self.t.write_all(&frame).map_err(Self::io)?;
        self.stats.frames_sent += 1;
        if self.inflight.is_empty() {
            self.oldest_sent = Instant::now();
        }
        let seq = self.tx_seq;
        self.inflight.push_back((seq, frame));
        self.tx_seq = seq.wrapping_add(1);
        Ok(seq)
    }

    /// The sequence number the next frame will go with.
    pub fn next_seq(&self) -> u16 {
        self.tx_seq
    }

    pub fn window_free(&self) -> bool {
        self.inflight.len() < WINDOW
    }

    pub fn all_acked(&self) -> bool {
        self.inflight.is_empty()
    }

    fn resend_from(&mut self, from: Option<u16>) -> Result<(), LinkError> {
        let mut bytes = Vec::new();
        for (seq, f) in &self.inflight {
            // Frames before `from` were executed; only the rest go again.
            if from.is_none_or(|s| seq.wrapping_sub(s) < 0x8000) {
                bytes.extend_from_slice(f);
                self.stats.retransmits += 1;
            }
        }
        if !bytes.is_empty() {
            // A leading delimiter ends any partial frame the device holds.
            let mut out = vec![0u8];
            out.extend_from_slice(&bytes);
            self.t.write_all(&out).map_err(Self::io)?;
        }
        self.oldest_sent = Instant::now();
        Ok(())
    }

    /// Read what arrived within `timeout`, handle Acks and NAKs, queue the rest; retransmit on
    /// timeout. Fails when the device has been silent for `timing.silence`.
    pub fn pump(&mut self, timeout: Duration) -> Result<(), LinkError> {
        let mut buf = [0u8; 1024];
        let n = self.t.read(&mut buf, timeout).map_err(Self::io)?;
        for &b in buf.get(..n).unwrap_or(&[]) {
            match self.dec.push::<DeviceMsg>(b) {
                None => {}
                Some(Err(_)) => self.stats.bad_frames_in += 1,
                Some(Ok(frame)) => {
                    self.last_rx = Instant::now();
                    self.on_msg(frame.msg)?;
                }
            }
        }
        if !self.inflight.is_empty() && self.oldest_sent.elapsed() >= self.timing.rto {
            self.stats.timeouts += 1;
            self.resend_from(None)?;
        }
        if self.last_rx.elapsed() >= self.timing.silence {
            return Err(LinkError::Silent(format!(
                "nothing received for {:.1} s",
                self.timing.silence.as_secs_f64()
            )));
        }
        Ok(())
    }

    fn on_msg(&mut self, msg: DeviceMsg) -> Result<(), LinkError> {
        match msg {
            DeviceMsg::Ack { seq } => {
                let before = self.inflight.len();
                // The device executes in order: an Ack covers every frame up to it.
                while self
                    .inflight
                    .front()
                    .is_some_and(|(s, _)| seq.wrapping_sub(*s) < 0x8000)
                {
                    self.inflight.pop_front();
                }
                if self.inflight.len() != before {
                    self.oldest_sent = Instant::now();
                }
            }
            DeviceMsg::Nak { expected, .. } => {
                self.stats.naks += 1;
                // Every frame after a lost one is NAKed with the same `expected`: go back once
                // per retransmit timeout, not once per NAK.
                let recent = self
                    .last_nak
                    .is_some_and(|(e, t)| e == expected && t.elapsed() < self.timing.rto);
                if !recent {
                    self.last_nak = Some((expected, Instant::now()));
                    self.resend_from(Some(expected))?;
                }
            }
            other => self.rx.push_back(other),
        }
        Ok(())
    }

    /// The next queued device message, reading for up to `timeout`.
    pub fn next_msg(&mut self, timeout: Duration) -> Result<Option<DeviceMsg>, LinkError> {
        if let Some(m) = self.rx.pop_front() {
            return Ok(Some(m));
        }
        let deadline = Instant::now() + timeout;
        loop {
            self.pump(
                deadline
                    .saturating_duration_since(Instant::now())
                    .min(Duration::from_millis(20)),
            )?;
            if let Some(m) = self.rx.pop_front() {
                return Ok(Some(m));
            }
            if Instant::now() >= deadline {
                return Ok(None);
            }
        }
    }

    /// Ask for status until one arrives; other messages on the way are dropped (the callers
    /// use this only outside a scan's streaming).
    pub fn status(&mut self) -> Result<Status, LinkError> {
        for _ in 0..20 {
            self.send(&HostMsg::GetStatus)?;
            self.stats.status_requests += 1;
            let until = Instant::now() + self.timing.rto * 3;
            while Instant::now() < until {
                if let Some(DeviceMsg::Status(s)) = self.next_msg(Duration::from_millis(20))? {
                    return Ok(s);
                }
            }
        }
        Err(LinkError::Silent("no status reply".into()))
    }

    /// Wait until every frame sent has been acknowledged.
    pub fn flush(&mut self) -> Result<(), LinkError> {
        while !self.inflight.is_empty() {
            self.pump(Duration::from_millis(10))?;
        }
        Ok(())
    }

    /// Bring the device to Ready with `cfg` and homed, whatever it was doing (a previous host's
    /// scan, a fault).
    pub fn prepare(&mut self, cfg: &InstrumentConfig<f32>) -> Result<Status, LinkError> {
        self.kin = gonio_shared::kinematics::Kinematics::new(*cfg).ok();
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
                        self.send(&HostMsg::Home)?;
                        homing_sent = true;
                    }
                }
                ControllerState::Homing if homing_sent => {}
                _ => {
                    self.send(&HostMsg::Abort)?;
                }
            }
            self.flush()?;
            std::thread::sleep(Duration::from_millis(20));
        }
        // Configure: refused while a move winds down; try again until it takes.
        let mut configured = false;
        for _ in 0..200 {
            let cfg_seq = self.send(&HostMsg::Configure(*cfg))?;
            let until = Instant::now() + self.timing.rto * 4;
            let mut refused = None;
            while Instant::now() < until && !configured && refused.is_none() {
                match self.next_msg(Duration::from_millis(20))? {
                    Some(DeviceMsg::Credit { next_index: 0, .. }) => configured = true,
                    // Only the answer to this Configure (not to an earlier Abort or Home).
                    Some(DeviceMsg::Refused { seq, reason, .. }) if seq == cfg_seq => refused = Some(reason),
                    _ => {}
                }
            }
            if configured {
                break;
            }
            if let Some(reason @ (RefuseReason::BadConfig(_) | RefuseReason::NoHandshake)) = refused {
                return Err(LinkError::Refused {
                    what: "the instrument configuration",
                    reason,
                });
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        if !configured {
            return Err(LinkError::Silent("the device never accepted the configuration".into()));
        }
        let s = self.status()?;
        if s.homed && s.state == ControllerState::Ready {
            return Ok(s);
        }
        self.send(&HostMsg::Home)?;
        let start = Instant::now();
        while start.elapsed() < self.timing.homing {
            std::thread::sleep(Duration::from_millis(10));
            let s = self.status()?;
            match s.state {
                ControllerState::Ready if s.homed => return Ok(s),
                ControllerState::Fault => return Err(self.fault_error(s.last_fault, Some(s.steps))),
                ControllerState::Idle => {
                    self.send(&HostMsg::Home)?;
                }
                _ => {}
            }
        }
        Err(LinkError::Silent("homing did not finish".into()))
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

    /// Stream `plan` (indices 0..len on the wire), start, and hand every measurement to `sink`
    /// exactly once in order. Returns when all have arrived and are acknowledged.
    pub fn scan(&mut self, plan: &[Direction], sink: &mut dyn MeasurementSink) -> Result<(), LinkError> {
        let total = u32::try_from(plan.len()).map_err(|_| LinkError::Sink("plan too long".into()))?;
        if total == 0 {
            return Ok(());
        }
        let mut credit_limit = 0u32;
        let mut next_send = 0u32;
        let mut end_sent = false;
        let mut started = false;
        let mut next_seq = 0u32;
        let mut acked = 0u32; // measurements acknowledged (count)
        let mut resend_at: Option<(u32, Instant)> = None;
        let mut last_activity = Instant::now();
        let mut dirty = false; // recorded but not synced
                               // A status asked for after a silence: only its answer can reveal lost measurements (an
                               // unsolicited status may overtake readings that are merely still on their way).
        let mut probing = false;
        // Sequence numbers of our Start and of the plan chunks in flight (with their first index),
        // to match a `Refused` to the frame it answers.
        let mut start_seq: Option<u16> = None;
        let mut chunk_seqs: VecDeque<(u16, u32)> = VecDeque::new();
        // Refusals of frames sent before this sequence number are stale: the plan was rewound since.
        let mut epoch = self.next_seq();
        // When the plan credit last grew (or was last asked for). The configuration's grant went to
        // `prepare`: ask for the current one at once.
        let mut last_grant = Instant::now()
            .checked_sub(self.timing.idle)
            .unwrap_or_else(Instant::now);
        let mut starved_statuses = 0u32;
        loop {
            while next_send < total && self.window_free() {
                let len = (total - next_send).min(CHUNK_DIRECTIONS as u32);
                if next_send + len > credit_limit {
                    break;
                }
                let lo = next_send as usize;
                let dirs = plan.get(lo..lo + len as usize).unwrap_or(&[]);
                let directions =
                    heapless::Vec::from_slice(dirs).map_err(|_| LinkError::Sink("chunk too long".into()))?;
                let seq = self.send(&HostMsg::Plan(PlanChunk {
                    first_index: next_send,
                    directions,
                }))?;
                if chunk_seqs.len() >= 2 * WINDOW {
                    chunk_seqs.pop_front();
                }
                chunk_seqs.push_back((seq, next_send));
                next_send += len;
            }
            if next_send == total && !end_sent && self.window_free() {
                self.send(&HostMsg::PlanEnd { total })?;
                end_sent = true;
            }
            if !started && next_send > 0 && self.window_free() {
                start_seq = Some(self.send(&HostMsg::Start)?);
                started = true;
            }
            let msg = self.next_msg(Duration::from_millis(20))?;
            let got_msg = msg.is_some();
            match msg {
                Some(DeviceMsg::Credit { next_index, free }) => {
                    let limit = next_index.saturating_add(u32::from(free));
                    if limit > credit_limit {
                        credit_limit = limit;
                        last_grant = Instant::now();
                    }
                }
                Some(DeviceMsg::Measurement(m)) => {
                    if m.seq == next_seq {
                        if m.index >= total {
                            return Err(LinkError::Sink(format!(
                                "device measured index {} of a {total}-direction plan",
                                m.index
                            )));
                        }
                        sink.record(&m).map_err(LinkError::Sink)?;
                        dirty = true;
                        next_seq += 1;
                        if resend_at.is_some_and(|(from, _)| next_seq > from) {
                            resend_at = None;
                        }
                    } else if m.seq < next_seq {
                        self.stats.duplicate_measurements += 1;
                    } else if resend_at.is_none_or(|(_, t)| t.elapsed() >= self.timing.rto * 2) {
                        // A gap: the device keeps everything unacknowledged; ask from the hole.
                        self.send(&HostMsg::ResendMeasurements { from: next_seq })?;
                        self.stats.resend_requests += 1;
                        resend_at = Some((next_seq, Instant::now()));
                    }
                }
                Some(DeviceMsg::Fault(f)) => return Err(self.stop_on_fault(Some(f), next_seq, sink)),
                Some(DeviceMsg::Status(s)) => {
                    // The same grant as a Credit: recovers from a lost one (see `DeviceMsg::Credit`).
                    let limit = s.plan_next.saturating_add(u32::from(s.plan_free));
                    if limit > credit_limit {
                        credit_limit = limit;
                        last_grant = Instant::now();
                    }
                    // Deadlock watch: the device has run out of plan (everything it took is
                    // measured), we have sent everything it granted, and its status grants nothing
                    // more. Never so with a working device; a bounded number of such answers in a
                    // row is an error rather than a scan that hangs.
                    let len = (total - next_send).min(CHUNK_DIRECTIONS as u32);
                    let starved = len > 0
                        && next_send + len > credit_limit
                        && s.plan_next == next_send
                        && s.plan_done >= s.plan_next
                        && matches!(s.state, ControllerState::Running | ControllerState::Ready);
                    starved_statuses = if starved { starved_statuses + 1 } else { 0 };
                    if starved_statuses > STARVED_STATUS_LIMIT {
                        return Err(LinkError::Stalled(format!(
                            "the device ran out of plan at direction {next_send} of {total} and grants no credit"
                        )));
                    }
                    if s.state == ControllerState::Fault {
                        return Err(self.stop_on_fault(s.last_fault, next_seq, sink));
                    }
                    if s.state == ControllerState::Idle && !s.homed {
                        return Err(LinkError::Disconnected("the device restarted mid-scan".into()));
                    }
                    if s.state == ControllerState::Ready && started && next_seq < total {
                        // Our Start was refused or lost (e.g. sent before the plan reached it).
                        self.send(&HostMsg::Start)?;
                    }
                    if std::mem::take(&mut probing)
                        && s.plan_done > next_seq
                        && resend_at.is_none_or(|(_, t)| t.elapsed() >= self.timing.rto * 2)
                    {
                        self.send(&HostMsg::ResendMeasurements { from: next_seq })?;
                        self.stats.resend_requests += 1;
                        resend_at = Some((next_seq, Instant::now()));
                    }
                }
                Some(DeviceMsg::Refused { seq, command, reason }) => {
                    if let RefuseReason::BadConfig(_) | RefuseReason::NotConfigured | RefuseReason::NoHandshake = reason
                    {
                        return Err(LinkError::Refused {
                            what: "a scan command",
                            reason,
                        });
                    }
                    let since_epoch = seq.wrapping_sub(epoch) < 0x8000;
                    let chunk_first = chunk_seqs.iter().find(|(s, _)| *s == seq).map(|&(_, first)| first);
                    match (command, reason, chunk_first) {
                        // A chunk the device did not take: every later chunk in flight is refused
                        // too (out of order). Go back to where the device stands, once.
                        (Command::Plan, RefuseReason::OutOfOrder { expected }, Some(_))
                            if since_epoch && expected < next_send =>
                        {
                            next_send = expected;
                            epoch = self.next_seq();
                        }
                        (Command::Plan, RefuseReason::NoCredit, Some(first)) if since_epoch && first < next_send => {
                            // Our idea of the credit was wrong: wait for a fresh grant.
                            next_send = first;
                            credit_limit = first;
                            epoch = self.next_seq();
                        }
                        (Command::Start, RefuseReason::NotHomed, _) if start_seq == Some(seq) => {
                            return Err(LinkError::Refused {
                                what: "the scan's Start",
                                reason,
                            });
                        }
                        (Command::Start, _, _) if start_seq == Some(seq) && self.window_free() => {
                            // E.g. a move still winding down: the status answer says when Ready
                            // (and the Status arm above starts again).
                            self.send(&HostMsg::GetStatus)?;
                            self.stats.status_requests += 1;
                        }
                        _ => {}
                    }
                }
                Some(DeviceMsg::Hello(_) | DeviceMsg::Ack { .. } | DeviceMsg::Nak { .. }) | None => {}
            }
            if got_msg {
                last_activity = Instant::now();
            }
            let unacked = next_seq - acked;
            let idle = !got_msg;
            if unacked > 0 && (unacked >= ACK_EVERY || idle || next_seq == total) && self.window_free() {
                if dirty {
                    sink.sync().map_err(LinkError::Sink)?;
                    dirty = false;
                }
                self.send(&HostMsg::AckMeasurements { through: next_seq - 1 })?;
                acked = next_seq;
            }
            if next_seq == total {
                self.flush()?;
                return Ok(());
            }
            let next_len = (total - next_send).min(CHUNK_DIRECTIONS as u32);
            let credit_starved = next_len > 0 && next_send + next_len > credit_limit;
            if credit_starved && last_grant.elapsed() >= self.timing.idle && self.window_free() {
                // Waiting for room while measurements still flow (so never quiet): a `Credit` may
                // have been lost; the status answer carries the same grant.
                self.send(&HostMsg::GetStatus)?;
                self.stats.status_requests += 1;
                last_grant = Instant::now();
            }
            if last_activity.elapsed() >= self.timing.idle && self.window_free() {
                // Quiet: a lost Credit, Measurement or Status; ask where the device stands. The
                // answer carries the plan credit too (`Status::plan_free`).
                self.send(&HostMsg::GetStatus)?;
                self.stats.status_requests += 1;
                probing = true;
                last_activity = Instant::now();
            }
        }
    }

    /// A fault stops the scan: collect what was measured before it, then report where it stopped.
    fn stop_on_fault(&mut self, fault: Option<Fault>, mut next_seq: u32, sink: &mut dyn MeasurementSink) -> LinkError {
        let status = self.status().ok();
        if let Some(s) = &status {
            if s.plan_done > next_seq && self.send(&HostMsg::ResendMeasurements { from: next_seq }).is_ok() {
                let until = Instant::now() + self.timing.rto * 10;
                while Instant::now() < until && next_seq < s.plan_done {
                    match self.next_msg(Duration::from_millis(20)) {
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
                    let _ = self.send(&HostMsg::AckMeasurements { through: next_seq - 1 });
                    let _ = self.flush();
                }
            }
        }
        self.fault_error(fault, status.map(|s| s.steps))
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
