//! The controller state machine (Idle, Homing, Ready, Running, Paused, Done, Fault): one host command
//! at a time, and the per-direction scan sequence; states and rules in `docs/firmware.md`.

use crate::hal::Hal;
use crate::homing::{self, Homing, Stage};
use crate::measurements::MeasurementBuffer;
use crate::outbox::Outbox;
use crate::plan::{Intake, PlanQueue};
use crate::stepper::{StepError, Stepper};
use gonio_shared::instrument::{InstrumentConfig, AXES};
use gonio_shared::kinematics::{Kinematics, Steps, Unreachable};
use gonio_shared::msg::{
    check_handshake, Command, ControllerState, DeviceMsg, Fault, Hello, HostMsg, Measurement, RefuseReason,
};
use gonio_shared::separation::SeparationGuard;
use heapless::{Deque, Vec};

mod report;

/// A running scan with no valid host frame for this long holds (`docs/firmware.md`, "Host
/// liveness"): it finishes the direction in flight, keeps its readings and waits in Paused for the
/// host's `Resume`. The host sends something at least every `LinkTiming::idle` (0.4 s).
pub const HOST_SILENT_US: u64 = 10_000_000;
/// Time the detector gets beyond its exposure before `Fault::DetectorTimeout`.
pub const DETECTOR_MARGIN_US: u64 = 100_000;
/// Once an exposure should be over, look for its readout this often.
const READOUT_POLL_US: u64 = 100;
/// State transitions taken in one `poll` when nothing needs waiting for (e.g. homing: park done ->
/// next axis's seek; scan: readout -> next move). Bounded so a poll's cost is bounded.
pub const TRANSITIONS_PER_POLL: usize = 4;

/// Where the current plan direction stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    /// No direction in progress.
    Idle,
    Moving {
        index: u32,
    },
    Settling {
        index: u32,
        until_us: u64,
    },
    Exposing {
        index: u32,
        done_us: u64,
        deadline_us: u64,
    },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum PauseCause {
    NotPaused,
    Host,
    /// Resumes by itself once acknowledgements free a slot.
    MeasurementsFull,
    /// No host frame for `HOST_SILENT_US`: waits for the host's `Resume`.
    HostSilent,
}

/// `Option`-like fields are `heapless::Vec<_, 1>` (empty when all-zero), so `Controller::new()` is
/// all zero bytes and a `static` Device lands in `.bss`, not in `.data`.
pub struct Controller {
    state: ControllerState,
    handshake: bool,
    kin: Vec<Kinematics<f32>, 1>,
    guard: Option<SeparationGuard>,
    homed: bool,
    homing: Homing,
    stepper: Stepper,
    plan: PlanQueue,
    plan_done: u32,
    measurements: MeasurementBuffer,
    phase: Phase,
    pause: PauseCause,
    last_fault: Vec<Fault, 1>,
    /// Faults not yet sent to the host, oldest first, sent as soon as the outbox has room.
    faults_unreported: Deque<Fault, 4>,
    /// A state change the host was not told about (homing done, buffer-full pause, done).
    status_unreported: bool,
    /// The `free` of the last `Credit` sent; `None` forces one.
    credit_reported: Option<u16>,
    last_now_us: u64,
    /// When the last valid host frame arrived.
    last_host_us: u64,
    /// `HOST_SILENT_US` for a board whose clock runs faster than the host's (the virtual gonio);
    /// 0 = `HOST_SILENT_US` (so `new()` stays all zero bytes).
    host_silent_us: u64,
    /// Poll again at once: the last poll ran out of its transition budget with work left, or a
    /// command arrived since.
    more_work: bool,
}

impl Default for Controller {
    fn default() -> Self {
        Self::new()
    }
}

impl Controller {
    pub const fn new() -> Self {
        Self {
            state: ControllerState::Idle,
            handshake: false,
            kin: Vec::new(),
            guard: None,
            homed: false,
            homing: Homing::new(),
            stepper: Stepper::new(),
            plan: PlanQueue::new(),
            plan_done: 0,
            measurements: MeasurementBuffer::new(),
            phase: Phase::Idle,
            pause: PauseCause::NotPaused,
            last_fault: Vec::new(),
            faults_unreported: Deque::new(),
            status_unreported: false,
            credit_reported: None,
            last_now_us: 0,
            last_host_us: 0,
            host_silent_us: 0,
            more_work: false,
        }
    }

    pub fn state(&self) -> ControllerState {
        self.state
    }

    pub fn homed(&self) -> bool {
        self.homed
    }

    pub fn position(&self) -> Steps {
        self.stepper.position()
    }

    pub fn is_moving(&self) -> bool {
        self.stepper.is_moving()
    }

    pub fn last_fault(&self) -> Option<Fault> {
        self.last_fault.first().copied()
    }

    /// Taking plan chunks (and granting credit for them): configured, not every direction up to
    /// the plan's end received yet, no fault, not done.
    fn streaming(&self) -> bool {
        !self.kin.is_empty()
            && self.plan.end().is_none_or(|end| self.plan.next_index() < end)
            && !matches!(self.state, ControllerState::Fault | ControllerState::Done)
    }

    /// The next instant `poll` has work, `None` when only the host can make progress.
    pub fn next_deadline_us(&self) -> Option<u64> {
        if self.more_work {
            return Some(self.last_now_us);
        }
        // A move polls at least at each ring refill and at its end, and the host-silence check
        // in `poll` runs then: only a scan standing still needs the silence deadline.
        if let Some(t) = self.stepper.next_due_us() {
            return Some(t);
        }
        let own = self.phase_deadline_us();
        let silence = (self.state == ControllerState::Running).then(|| self.host_silent_at());
        match (own, silence) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    fn host_silent_at(&self) -> u64 {
        let silent = if self.host_silent_us == 0 {
            HOST_SILENT_US
        } else {
            self.host_silent_us
        };
        self.last_host_us.saturating_add(silent)
    }

    /// How long a running scan goes on without a host frame, in this board's clock (a simulation
    /// sped up against the host's wall clock scales `HOST_SILENT_US`).
    pub fn set_host_silent_us(&mut self, us: u64) {
        self.host_silent_us = us.max(1);
    }

    /// The scan phase's next deadline while no move runs.
    fn phase_deadline_us(&self) -> Option<u64> {
        match self.phase {
            Phase::Settling { until_us, .. } => Some(until_us),
            Phase::Exposing {
                done_us, deadline_us, ..
            } => {
                if self.last_now_us < done_us {
                    Some(done_us)
                } else {
                    Some(self.last_now_us.saturating_add(READOUT_POLL_US).min(deadline_us))
                }
            }
            Phase::Idle | Phase::Moving { .. } => None,
        }
    }

    /// Switches whose closing stops all motion (bit per `Axis::index`): during a homing seek the
    /// seeking axis's; during a scan or any other move every non-continuous axis's (a continuous
    /// axis's index sensor closes once a turn); none while nothing moves or homing moves away from
    /// a switch (a bouncing contact must not stop a back-off or park).
    pub fn stop_mask(&self) -> u8 {
        let Some(cfg) = self.kin.first().map(Kinematics::config) else {
            return 0;
        };
        if self.state == ControllerState::Homing {
            return match (self.homing.axis(), self.homing.stage) {
                (Some(axis), Stage::Seek) => 1 << axis.index(),
                _ => 0,
            };
        }
        let active =
            self.stepper.is_moving() || matches!(self.state, ControllerState::Running | ControllerState::Paused);
        if !active {
            return 0;
        }
        AXES.iter()
            .filter(|&&a| !cfg.axis(a).continuous)
            .fold(0, |m, a| m | 1 << a.index())
    }

    /// Would a board-side stop on these switches halt a move this controller has not stopped?
    pub fn halts_on(&self, closed: u8) -> bool {
        let Some(cfg) = self.kin.first().map(Kinematics::config) else {
            return false;
        };
        if self.state == ControllerState::Homing {
            return matches!((self.homing.axis(), self.homing.stage), (Some(a), Stage::Seek) if closed & (1 << a.index()) != 0);
        }
        let already = matches!(self.last_fault(), Some(Fault::LimitSwitch(_) | Fault::HomeNotFound(_)))
            && self.state == ControllerState::Fault;
        !already
            && AXES
                .iter()
                .any(|&a| !cfg.axis(a).continuous && closed & (1 << a.index()) != 0)
    }

    /// The board stopped every axis on these switches (see [`Controller::halts_on`]).
    pub fn limit_tripped<H: Hal>(&mut self, hal: &mut H, closed: u8) {
        if !self.halts_on(closed) {
            return;
        }
        let now = hal.now_us();
        self.last_now_us = self.last_now_us.max(now);
        self.more_work = true;
        self.stepper.stop(hal);
        if self.state == ControllerState::Homing {
            if let Some(axis) = self.homing.axis() {
                self.found_home(hal, now, axis);
            }
            return;
        }
        let Some(cfg) = self.kin.first().map(|k| *k.config()) else {
            return;
        };
        if let Some(&axis) = AXES
            .iter()
            .find(|&&a| !cfg.axis(a).continuous && closed & (1 << a.index()) != 0)
        {
            self.enter_fault(hal, Fault::LimitSwitch(axis));
        }
    }

    /// The board's loop came back at real time `real_us`: past the instant a ring of the move in
    /// progress ran dry, steps that were due were not played: `Fault::StepsLate` (motion stops).
    /// Host frames handled meanwhile do not count: only the step generator's deadline does.
    pub fn check_steps_on_time<H: Hal>(&mut self, hal: &mut H, real_us: u64) {
        if self.stepper.dry_us().is_some_and(|dry| real_us > dry) {
            self.more_work = true;
            self.enter_fault(hal, Fault::StepsLate);
        }
    }

    /// Act on one host command (already sequence-checked by the link); `seq` is its frame's
    /// sequence number, named in a `Refused`.
    ///
    /// Not inlined: it keeps the board's controller task small (`docs/firmware.md`, flash).
    #[inline(never)]
    pub fn handle<H: Hal>(&mut self, seq: u16, msg: HostMsg, hal: &mut H, out: &mut Outbox, bad_frames: u32) {
        self.last_now_us = self.last_now_us.max(hal.now_us());
        self.last_host_us = self.last_now_us;
        // Any command may have created work (a start, a plan, an ack that frees the buffer).
        self.more_work = true;
        let command = match &msg {
            HostMsg::Hello(theirs) => {
                self.handshake = check_handshake(*theirs).is_ok();
                // Answer either way: the host reports a mismatch from our Hello.
                out.reply(&DeviceMsg::Hello(Hello::ours(theirs.session)));
                return;
            }
            HostMsg::GetStatus => {
                out.reply(&DeviceMsg::Status(self.status(bad_frames)));
                return;
            }
            HostMsg::Configure(_) => Command::Configure,
            HostMsg::Plan(_) => Command::Plan,
            HostMsg::PlanEnd { .. } => Command::PlanEnd,
            HostMsg::Home => Command::Home,
            HostMsg::Start => Command::Start,
            HostMsg::Pause => Command::Pause,
            HostMsg::Resume => Command::Resume,
            HostMsg::Abort => Command::Abort,
            HostMsg::AckMeasurements { .. } => Command::Ack,
            HostMsg::ResendMeasurements { .. } => Command::Resend,
        };
        if !self.handshake {
            out.reply(&DeviceMsg::Refused {
                seq,
                command,
                reason: RefuseReason::NoHandshake,
            });
            return;
        }
        let result = match msg {
            HostMsg::Configure(cfg) => self.configure(cfg, out),
            HostMsg::Plan(chunk) => self.take_plan(&chunk, hal, out),
            HostMsg::PlanEnd { total } => self.end_plan(total),
            HostMsg::Home => self.home(),
            HostMsg::Start => self.start(),
            HostMsg::Pause => self.pause(),
            HostMsg::Resume => self.resume(),
            HostMsg::Abort => self.abort(hal),
            HostMsg::AckMeasurements { through } => self.measurements.ack(through),
            HostMsg::ResendMeasurements { from } => self.measurements.resend(from),
            HostMsg::Hello(_) | HostMsg::GetStatus => Ok(()),
        };
        if let Err(reason) = result {
            out.reply(&DeviceMsg::Refused { seq, command, reason });
        }
    }

    fn wrong_state(&self) -> RefuseReason {
        RefuseReason::WrongState(self.state)
    }

    fn configure(&mut self, cfg: InstrumentConfig<f32>, out: &mut Outbox) -> Result<(), RefuseReason> {
        use ControllerState::*;
        if !matches!(self.state, Idle | Ready | Done) || self.stepper.is_moving() {
            return Err(self.wrong_state());
        }
        let kin = Kinematics::new(cfg).map_err(RefuseReason::BadConfig)?;
        // The same instrument again keeps its homing; another one may count steps differently.
        let same = self.kin.first().is_some_and(|k| *k.config() == cfg);
        if !same {
            self.homed = false;
        }
        self.state = if self.homed { Ready } else { Idle };
        self.guard = Some(SeparationGuard::new(&kin));
        self.kin.clear();
        // Cannot fail: cleared just above.
        let _ = self.kin.push(kin);
        self.plan.reset(self.stepper.position());
        self.plan_done = 0;
        self.measurements.reset();
        self.phase = Phase::Idle;
        self.pause = PauseCause::NotPaused;
        self.grant_credit(out);
        Ok(())
    }

    fn take_plan<H: Hal>(
        &mut self,
        chunk: &gonio_shared::msg::PlanChunk,
        hal: &mut H,
        out: &mut Outbox,
    ) -> Result<(), RefuseReason> {
        let (Some(kin), Some(guard)) = (self.kin.first(), self.guard.as_ref()) else {
            return Err(RefuseReason::NotConfigured);
        };
        if matches!(self.state, ControllerState::Fault | ControllerState::Done) {
            return Err(self.wrong_state());
        }
        match self.plan.intake(chunk, kin, guard)? {
            Intake::Accepted => self.grant_credit(out),
            Intake::Rejected { index, reason } => {
                let fault = Fault::Unreachable { index, reason };
                self.enter_fault(hal, fault);
                // Answered right away (the link reserved room), so not queued for `report`.
                self.faults_unreported.pop_back();
                out.reply(&DeviceMsg::Fault(fault));
            }
        }
        Ok(())
    }

    fn end_plan(&mut self, total: u32) -> Result<(), RefuseReason> {
        if self.kin.is_empty() {
            return Err(RefuseReason::NotConfigured);
        }
        if matches!(self.state, ControllerState::Fault | ControllerState::Done) {
            return Err(self.wrong_state());
        }
        self.plan.set_end(total)
    }

    fn home(&mut self) -> Result<(), RefuseReason> {
        use ControllerState::*;
        let Some(kin) = self.kin.first() else {
            return Err(RefuseReason::NotConfigured);
        };
        if !matches!(self.state, Idle | Ready | Done | Fault) || self.stepper.is_moving() {
            return Err(self.wrong_state());
        }
        let rest = AXES.map(|a| homing::rest_position(kin, a));
        self.state = Homing;
        self.homed = false;
        self.homing = homing::Homing::new();
        self.phase = Phase::Idle;
        self.pause = PauseCause::NotPaused;
        // Homing ends at the rest pose: a plan streamed meanwhile is planned from there.
        self.plan.reset(rest);
        self.plan_done = 0;
        self.credit_reported = None;
        Ok(())
    }

    fn start(&mut self) -> Result<(), RefuseReason> {
        if self.kin.is_empty() {
            return Err(RefuseReason::NotConfigured);
        }
        // Before `WrongState`: "home first" is the useful answer in Idle, Homing and after a fault
        // that needs re-homing.
        if !self.homed {
            return Err(RefuseReason::NotHomed);
        }
        if self.state != ControllerState::Ready || self.stepper.is_moving() {
            return Err(self.wrong_state());
        }
        self.state = ControllerState::Running;
        self.phase = Phase::Idle;
        Ok(())
    }

    fn pause(&mut self) -> Result<(), RefuseReason> {
        match self.state {
            ControllerState::Running | ControllerState::Paused => {
                self.state = ControllerState::Paused;
                self.pause = PauseCause::Host;
                Ok(())
            }
            _ => Err(self.wrong_state()),
        }
    }

    fn resume(&mut self) -> Result<(), RefuseReason> {
        if self.state != ControllerState::Paused {
            return Err(self.wrong_state());
        }
        // A buffer that is still full pauses again before the next direction.
        self.state = ControllerState::Running;
        self.pause = PauseCause::NotPaused;
        Ok(())
    }

    fn abort<H: Hal>(&mut self, hal: &mut H) -> Result<(), RefuseReason> {
        use ControllerState::*;
        match self.state {
            Homing => {
                self.stepper.stop(hal);
                self.homed = false;
            }
            Fault => {
                let needs_homing = matches!(
                    self.last_fault(),
                    Some(gonio_shared::msg::Fault::LimitSwitch(_) | gonio_shared::msg::Fault::HomeNotFound(_))
                );
                if needs_homing || self.stepper.is_moving() {
                    return Err(self.wrong_state());
                }
            }
            // A move in progress finishes its deceleration; Start is refused until it has.
            Idle | Ready | Running | Paused | Done => {}
        }
        self.state = if self.homed { Ready } else { Idle };
        self.phase = Phase::Idle;
        self.pause = PauseCause::NotPaused;
        self.plan.reset(self.stepper.position());
        self.plan_done = 0;
        self.credit_reported = None;
        Ok(())
    }

    /// The link dropped `link::BAD_FRAME_FAULT_RUN` frames in a row: the host cannot be
    /// heard (it could not even stop us), so motion stops like on any fault. Cleared by `Abort` or
    /// `Home` once frames get through again.
    pub(crate) fn link_untrusted<H: Hal>(&mut self, hal: &mut H) {
        if self.state != ControllerState::Fault {
            self.enter_fault(hal, Fault::BadFrame);
            self.more_work = true;
        }
    }

    /// Every fault stops motion at once: a seek or move in progress must not run on unsupervised
    /// (on a segment board its queued steps are dropped).
    fn enter_fault<H: Hal>(&mut self, hal: &mut H, fault: Fault) {
        self.stepper.stop(hal);
        self.state = ControllerState::Fault;
        self.last_fault.clear();
        let _ = self.last_fault.push(fault);
        // With four unreported faults the host is not reading: the first ones say what went wrong
        // and `Status::last_fault` says where it ended, so a fifth is not queued.
        let _queued = self.faults_unreported.push_back(fault).is_ok();
        self.phase = Phase::Idle;
        self.pause = PauseCause::NotPaused;
        if matches!(fault, Fault::LimitSwitch(_) | Fault::HomeNotFound(_)) {
            self.homed = false;
        }
    }

    /// Run everything that is due: steps, homing, the scan, then tell the host what changed.
    pub fn poll<H: Hal>(&mut self, hal: &mut H, out: &mut Outbox, bad_frames: u32) {
        let now = hal.now_us();
        self.last_now_us = self.last_now_us.max(now);
        if self.stepper.is_moving() {
            self.drive_motion(hal, now);
        }
        self.more_work = true;
        if self.state == ControllerState::Running && now >= self.host_silent_at() {
            // The host is gone (unplugged, crashed): hold after the direction in flight.
            self.state = ControllerState::Paused;
            self.pause = PauseCause::HostSilent;
            self.status_unreported = true;
        }
        for _ in 0..TRANSITIONS_PER_POLL {
            let progressed = match self.state {
                ControllerState::Homing if !self.stepper.is_moving() => self.advance_homing(hal, now),
                ControllerState::Running | ControllerState::Paused => self.advance_scan(hal, now),
                _ => false,
            };
            if !progressed {
                self.more_work = false;
                break;
            }
        }
        self.report(out, bad_frames);
    }

    /// Switches first (a closed switch stops everything before another step), then due steps.
    fn drive_motion<H: Hal>(&mut self, hal: &mut H, now: u64) {
        let Some(cfg) = self.kin.first().map(Kinematics::config) else {
            self.stepper.stop(hal);
            return;
        };
        if self.state == ControllerState::Homing {
            // Only the seek looks at a switch: the others stand still, or move away from theirs.
            if let (Some(axis), Stage::Seek) = (self.homing.axis(), self.homing.stage) {
                if hal.limit_closed(axis) {
                    self.stepper.stop(hal);
                    self.found_home(hal, now, axis);
                    return;
                }
            }
        } else {
            for axis in AXES {
                // A continuous axis's index sensor closes once a turn: not a limit.
                if !cfg.axis(axis).continuous && hal.limit_closed(axis) {
                    self.enter_fault(hal, Fault::LimitSwitch(axis));
                    return;
                }
            }
        }
        let guard = if self.state == ControllerState::Homing && !self.homing.arms_homed() {
            None
        } else {
            self.guard
        };
        if let Err(e) = self.stepper.poll(hal, now, guard.as_ref()) {
            self.motion_failed(hal, e);
        }
    }

    fn motion_failed<H: Hal>(&mut self, hal: &mut H, e: StepError) {
        let index = match self.phase {
            Phase::Moving { index } | Phase::Settling { index, .. } | Phase::Exposing { index, .. } => index,
            Phase::Idle => self.plan.next_index(),
        };
        let reason = match e {
            StepError::Blocked => Unreachable::Blocked,
            StepError::BadProfile => Unreachable::NotFinite,
        };
        self.enter_fault(hal, Fault::Unreachable { index, reason });
    }

    fn start_move<H: Hal>(&mut self, hal: &mut H, now: u64, target: Steps, speed_scale: f32) -> bool {
        let Some(kin) = self.kin.first() else { return false };
        let guard = self
            .guard
            .filter(|_| self.state != ControllerState::Homing || self.homing.arms_homed());
        match self
            .stepper
            .start(hal, now, target, kin.config(), speed_scale, guard.as_ref())
        {
            Ok(()) => true,
            Err(e) => {
                self.motion_failed(hal, e);
                false
            }
        }
    }

    /// The seek met the switch: that is the axis's home position; park it at its rest angle.
    fn found_home<H: Hal>(&mut self, hal: &mut H, now: u64, axis: gonio_shared::Axis) {
        let Some(kin) = self.kin.first() else { return };
        let home = homing::home_position(kin.config(), axis);
        let rest = homing::rest_position(kin, axis);
        self.stepper.set_position(axis, home);
        match axis {
            gonio_shared::Axis::Light => self.homing.light_homed = true,
            gonio_shared::Axis::Detector => self.homing.detector_homed = true,
            _ => {}
        }
        let mut target = self.stepper.position();
        if let Some(t) = target.get_mut(axis.index()) {
            *t = rest;
        }
        self.homing.stage = Stage::Park;
        self.start_move(hal, now, target, 1.0);
    }

    /// The stepper is idle during homing: start the next sub-move. `true` if something changed.
    fn advance_homing<H: Hal>(&mut self, hal: &mut H, now: u64) -> bool {
        let Some(cfg) = self.kin.first().map(|k| *k.config()) else {
            return false;
        };
        let Some(axis) = self.homing.axis() else {
            self.homed = true;
            self.state = ControllerState::Ready;
            self.status_unreported = true;
            return false;
        };
        let here = self.stepper.position();
        let i = axis.index();
        let at = here.get(i).copied().unwrap_or(0);
        let toward = homing::toward_switch(&cfg, axis);
        let mut target: Steps = here;
        match self.homing.stage {
            Stage::Begin | Stage::BackOff => {
                let closed = hal.limit_closed(axis);
                if closed && self.homing.stage == Stage::BackOff {
                    self.enter_fault(hal, Fault::HomeNotFound(axis));
                    return false;
                }
                let (distance, stage) = if closed {
                    (-homing::backoff_steps(&cfg, axis), Stage::BackOff)
                } else {
                    (homing::seek_steps(&cfg, axis), Stage::Seek)
                };
                if let Some(t) = target.get_mut(i) {
                    *t = at.saturating_add(toward.saturating_mul(distance));
                }
                self.homing.stage = stage;
                self.start_move(hal, now, target, homing::SPEED_SCALE);
                // A zero-length move (cannot happen with a validated config) still progresses.
                true
            }
            Stage::Seek => {
                // The whole travel went by without the switch closing.
                self.enter_fault(hal, Fault::HomeNotFound(axis));
                false
            }
            Stage::Park => {
                self.homing.position_in_order += 1;
                self.homing.stage = Stage::Begin;
                true
            }
        }
    }

    /// One step of the per-direction sequence. `true` if it moved on without waiting.
    fn advance_scan<H: Hal>(&mut self, hal: &mut H, now: u64) -> bool {
        let Some(cfg) = self.kin.first().map(Kinematics::config) else {
            return false;
        };
        match self.phase {
            Phase::Idle => {
                if self.state == ControllerState::Paused {
                    if self.pause == PauseCause::MeasurementsFull && !self.measurements.is_full() {
                        self.state = ControllerState::Running;
                        self.pause = PauseCause::NotPaused;
                        self.status_unreported = true;
                        return true;
                    }
                    return false;
                }
                if self.stepper.is_moving() {
                    return false;
                }
                if self.measurements.is_full() {
                    self.state = ControllerState::Paused;
                    self.pause = PauseCause::MeasurementsFull;
                    self.status_unreported = true;
                    return false;
                }
                if self.plan.end().is_some_and(|end| self.plan_done >= end) {
                    self.state = ControllerState::Done;
                    self.status_unreported = true;
                    return false;
                }
                let Some(next) = self.plan.pop() else {
                    return false; // starved: waiting for the host's next chunk
                };
                if self.start_move(hal, now, next.steps, 1.0) {
                    self.phase = Phase::Moving { index: next.index };
                    true
                } else {
                    false
                }
            }
            Phase::Moving { index } => {
                if self.stepper.is_moving() {
                    return false;
                }
                let settle_us = u64::from(cfg.settle_ms).saturating_mul(1000);
                self.phase = Phase::Settling {
                    index,
                    until_us: now.saturating_add(settle_us),
                };
                true
            }
            Phase::Settling { index, until_us } => {
                if now < until_us {
                    return false;
                }
                hal.start_exposure(cfg.exposure_us);
                let done_us = now.saturating_add(u64::from(cfg.exposure_us));
                self.phase = Phase::Exposing {
                    index,
                    done_us,
                    deadline_us: done_us.saturating_add(DETECTOR_MARGIN_US),
                };
                true
            }
            Phase::Exposing { index, deadline_us, .. } => {
                if let Some(counts) = hal.poll_readout() {
                    let m = Measurement {
                        seq: 0,
                        index,
                        steps: self.stepper.position(),
                        counts,
                        exposure_us: cfg.exposure_us,
                        timestamp_us: now,
                    };
                    if self.measurements.push(m).is_err() {
                        self.enter_fault(hal, Fault::BufferOverflow);
                        return false;
                    }
                    self.plan_done = self.plan_done.saturating_add(1);
                    self.phase = Phase::Idle;
                    true
                } else if now >= deadline_us {
                    self.enter_fault(hal, Fault::DetectorTimeout);
                    false
                } else {
                    false
                }
            }
        }
    }
}
