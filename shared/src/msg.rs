//! The messages on the wire. postcard-encoded, framed by [`crate::frame`].
//!
//! Every collection is a `heapless` one with its capacity named in [`caps`], so both sides know the
//! largest possible message at compile time and the firmware never allocates.

use crate::frame::FrameError;
use crate::instrument::{Axis, ConfigError, InstrumentConfig, AXIS_COUNT};
use crate::kinematics::Unreachable;
use heapless::Vec;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Capacities of the wire, in one place.
pub mod caps {
    /// Directions per `Plan` chunk: 8 x 16 bytes keeps a chunk well under one USB-FS bulk packet pair.
    pub const CHUNK_DIRECTIONS: usize = 8;
    /// Detector channels per measurement (RGB + one spare, e.g. a reference photodiode).
    pub const MAX_CHANNELS: usize = 4;
}

/// Bumped by hand on any change of meaning that keeps the same shape (a unit, an index origin).
/// Shape changes are caught by [`SCHEMA_HASH`] without anyone remembering to bump anything.
pub const PROTOCOL_VERSION: u16 = 1;

/// The postcard-schema key of both message enums, computed at compile time.
pub const SCHEMA_HASH: u32 = crate::schema_hash::schema_hash32::<HostMsg, DeviceMsg>();

/// One measurement direction pair, f32 radians in the sample's local frame
/// (+z normal, +x tangent; wi toward the light, wo toward the detector).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub struct Direction {
    pub theta_i: f32,
    pub phi_i: f32,
    pub theta_o: f32,
    pub phi_o: f32,
}

/// Consecutive plan directions starting at `first_index`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub struct PlanChunk {
    pub first_index: u32,
    pub directions: Vec<Direction, { caps::CHUNK_DIRECTIONS }>,
}

/// The version handshake, sent by both sides: each checks the other's with [`check_handshake`].
///
/// Sessions: the host picks a `session` id per connection (random, so two connections differ) and
/// sends its `Hello` with sequence number 0, resending that same frame until answered. The
/// firmware's link opens a new session, restarting its sequence count at 1, only for a `Hello` with
/// sequence number 0 whose `session` differs from the current session's. Any other `Hello` (a
/// duplicate of the opening one, a late or reordered copy) follows the ordinary sequence rules and
/// never restarts the count: a duplicate of the opening `Hello` is acknowledged and answered again,
/// one in sequence re-checks the versions, anything else is NAKed. The firmware answers with its
/// own `Hello` echoing the session id of the `Hello` it answers, so the host can tell its answer
/// from a stale one.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct Hello {
    pub protocol: u16,
    pub schema: u32,
    pub session: u32,
}

impl Hello {
    /// What this build speaks, in session 0.
    pub const OURS: Hello = Hello::ours(0);

    /// What this build speaks, in `session`.
    pub const fn ours(session: u32) -> Hello {
        Hello {
            protocol: PROTOCOL_VERSION,
            schema: SCHEMA_HASH,
            session,
        }
    }
}

/// A host and firmware that disagree on the protocol refuse each other.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error(
    "protocol mismatch: this side speaks v{} (schema {:#010x}), the other v{} (schema {:#010x}); \
     flash firmware built from the same gonio version as the host",
    ours.protocol, ours.schema, theirs.protocol, theirs.schema
)]
pub struct HandshakeError {
    pub ours: Hello,
    pub theirs: Hello,
}

/// Compares versions only (not the session id).
pub fn check_handshake(theirs: Hello) -> Result<(), HandshakeError> {
    if theirs.protocol == PROTOCOL_VERSION && theirs.schema == SCHEMA_HASH {
        Ok(())
    } else {
        Err(HandshakeError {
            ours: Hello::ours(theirs.session),
            theirs,
        })
    }
}

/// Host -> firmware.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub enum HostMsg {
    Hello(Hello),
    /// The instrument description; the firmware validates it before use.
    Configure(InstrumentConfig<f32>),
    Plan(PlanChunk),
    /// No directions after `total - 1`.
    PlanEnd {
        total: u32,
    },
    Home,
    Start,
    Pause,
    Resume,
    Abort,
    GetStatus,
    /// Cumulative: every measurement with `seq <= through` has arrived and may be forgotten.
    AckMeasurements {
        through: u32,
    },
    /// Send every kept measurement from `from` on again.
    ResendMeasurements {
        from: u32,
    },
}

/// The firmware's controller states.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum ControllerState {
    Idle,
    Homing,
    Ready,
    Running,
    Paused,
    Done,
    Fault,
}

/// Commands the firmware can refuse (names the refused request in [`DeviceMsg::Refused`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum Command {
    Configure,
    Plan,
    PlanEnd,
    Home,
    Start,
    Pause,
    Resume,
    Abort,
    Ack,
    Resend,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum RefuseReason {
    /// No compatible `Hello` yet.
    NoHandshake,
    NotConfigured,
    BadConfig(ConfigError),
    WrongState(ControllerState),
    /// A plan chunk that does not continue the plan where it stands.
    OutOfOrder {
        expected: u32,
    },
    /// More directions than the free space the last `Credit` granted.
    NoCredit,
    /// A resend from a measurement the firmware has already forgotten (acknowledged).
    Forgotten {
        oldest_kept: u32,
    },
    /// `Start` before homing has completed (positions are not known).
    NotHomed,
}

/// Why a frame was not accepted.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum NakReason {
    Crc,
    Cobs,
    TooLong,
    /// CRC was right but the payload is not a message of this schema.
    Payload,
    /// A sequence number other than the one expected next.
    Sequence,
}

impl From<FrameError> for NakReason {
    fn from(e: FrameError) -> Self {
        match e {
            FrameError::Crc => NakReason::Crc,
            FrameError::Cobs => NakReason::Cobs,
            FrameError::TooLong => NakReason::TooLong,
            FrameError::TooShort | FrameError::Payload | FrameError::Encode => NakReason::Payload,
        }
    }
}

/// Faults stop motion; only the listed recovery clears them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum Fault {
    /// A limit switch closed during a move; cleared by homing.
    LimitSwitch(Axis),
    /// A direction of the plan cannot be reached on this instrument.
    Unreachable { index: u32, reason: Unreachable },
    /// A receive or measurement buffer would have overflowed.
    BufferOverflow,
    /// Too many bad frames in a row for the link to be trusted.
    BadFrame,
    /// The detector did not answer within its exposure plus margin.
    DetectorTimeout,
    /// Homing travelled the axis's whole range without its switch closing (or could not back off a
    /// switch that was closed at the start); cleared by homing again once the switch is fixed.
    HomeNotFound(Axis),
    /// The step generator fell behind its own schedule during a move (a step would have come
    /// late): motion stops, positions stay counted.
    StepsLate,
}

/// One reading at one plan direction.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub struct Measurement {
    /// Sequence number of measurements, from 0, gap-free: the unit of acknowledgement.
    pub seq: u32,
    /// Index of the plan direction measured.
    pub index: u32,
    /// Step positions actually reached, indexed by `Axis::index`.
    pub steps: [i32; AXIS_COUNT],
    /// Detector counts per channel.
    pub counts: Vec<u32, { caps::MAX_CHANNELS }>,
    pub exposure_us: u32,
    /// Microseconds since the firmware started, at the end of the exposure.
    pub timestamp_us: u64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub struct Status {
    pub state: ControllerState,
    pub homed: bool,
    /// Next plan index the firmware expects.
    pub plan_next: u32,
    /// Plan directions measured so far.
    pub plan_done: u32,
    /// Free plan directions from `plan_next` on: the same grant as a [`DeviceMsg::Credit`]
    /// `{ next_index: plan_next, free: plan_free }` (0 when not streaming: no configuration, every
    /// direction up to the plan's end received, fault, done).
    pub plan_free: u16,
    /// Measurements kept until acknowledged.
    pub unacked: u16,
    /// Frames dropped by the decoder since start.
    pub bad_frames: u32,
    pub steps: [i32; AXIS_COUNT],
    pub last_fault: Option<Fault>,
}

/// Firmware -> host.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub enum DeviceMsg {
    Hello(Hello),
    /// The host frame with this sequence number was received and acted on.
    Ack {
        seq: u16,
    },
    /// A bad frame was dropped; the host resends from `expected`.
    Nak {
        expected: u16,
        reason: NakReason,
    },
    /// Flow control: the firmware can take `free` more directions from `next_index` on.
    ///
    /// Within one configuration `next_index + free` never decreases (taking k directions moves
    /// `next_index` up by k and `free` down by k; measuring one frees a slot) until `PlanEnd`,
    /// after which it is capped at the plan's end. So every grant, from a `Credit` or from a
    /// `Status` (`plan_next + plan_free`), is a valid limit whenever it arrives (below `total`),
    /// and the host keeps the largest it has seen. A `Credit` is sent after each accepted
    /// chunk and whenever a chunk's worth of room has opened up since the last one; it is not
    /// resent. Recovery from a lost `Credit` is the host's `GetStatus`: the `Status` answer
    /// carries the same grant.
    Credit {
        next_index: u32,
        free: u16,
    },
    Status(Status),
    Measurement(Measurement),
    Fault(Fault),
    /// The host frame with sequence number `seq` (a `command`) was not acted on, for `reason`.
    /// Sent after that frame's `Ack`.
    Refused {
        seq: u16,
        command: Command,
        reason: RefuseReason,
    },
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn handshake_accepts_ours_and_refuses_others_with_a_clear_message() {
        assert!(check_handshake(Hello::OURS).is_ok());
        let theirs = Hello {
            schema: SCHEMA_HASH ^ 1,
            ..Hello::OURS
        };
        let e = check_handshake(theirs).unwrap_err();
        let text = std::format!("{e}");
        assert!(text.contains("protocol mismatch"), "{text}");
        let old = Hello {
            protocol: PROTOCOL_VERSION + 1,
            ..Hello::OURS
        };
        assert!(check_handshake(old).is_err());
        // The session id is not part of the versions.
        assert!(check_handshake(Hello::ours(u32::MAX)).is_ok());
    }

    /// The largest value of each variant that can carry variable-length data, with every varint
    /// at its widest; `MAX_PAYLOAD` must hold all of them.
    fn largest_messages() -> (std::vec::Vec<HostMsg>, std::vec::Vec<DeviceMsg>) {
        let dir = Direction {
            theta_i: f32::MAX,
            phi_i: f32::MAX,
            theta_o: f32::MAX,
            phi_o: f32::MAX,
        };
        let mut directions = Vec::new();
        while directions.push(dir).is_ok() {}
        let mut counts = Vec::new();
        while counts.push(u32::MAX).is_ok() {}
        let host = std::vec![
            HostMsg::Hello(Hello {
                protocol: u16::MAX,
                schema: u32::MAX,
                session: u32::MAX,
            }),
            HostMsg::Configure(InstrumentConfig::<f32>::reference()),
            HostMsg::Plan(PlanChunk {
                first_index: u32::MAX,
                directions
            }),
            HostMsg::AckMeasurements { through: u32::MAX },
        ];
        let device = std::vec![
            DeviceMsg::Measurement(Measurement {
                seq: u32::MAX,
                index: u32::MAX,
                steps: [i32::MIN; AXIS_COUNT],
                counts,
                exposure_us: u32::MAX,
                timestamp_us: u64::MAX,
            }),
            DeviceMsg::Status(Status {
                state: ControllerState::Fault,
                homed: true,
                plan_next: u32::MAX,
                plan_done: u32::MAX,
                plan_free: u16::MAX,
                unacked: u16::MAX,
                bad_frames: u32::MAX,
                steps: [i32::MIN; AXIS_COUNT],
                last_fault: Some(Fault::Unreachable {
                    index: u32::MAX,
                    reason: Unreachable::Limit(Axis::Azimuth)
                }),
            }),
            DeviceMsg::Hello(Hello {
                protocol: u16::MAX,
                schema: u32::MAX,
                session: u32::MAX,
            }),
            DeviceMsg::Refused {
                seq: u16::MAX,
                command: Command::Resend,
                reason: RefuseReason::Forgotten { oldest_kept: u32::MAX }
            },
        ];
        (host, device)
    }

    #[test]
    fn largest_messages_fit_in_one_frame() {
        use crate::frame::MAX_PAYLOAD;
        let (host, device) = largest_messages();
        for m in &host {
            let n = postcard::to_stdvec(m).unwrap().len();
            assert!(n <= MAX_PAYLOAD, "{m:?}: {n} bytes > {MAX_PAYLOAD}");
        }
        for m in &device {
            let n = postcard::to_stdvec(m).unwrap().len();
            assert!(n <= MAX_PAYLOAD, "{m:?}: {n} bytes > {MAX_PAYLOAD}");
        }
    }

    #[test]
    fn largest_messages_round_trip_through_a_frame() {
        use crate::frame::{encode, Frame, FrameDecoder, MAX_WIRE_FRAME};
        let (host, device) = largest_messages();
        for m in host {
            let mut out = [0u8; MAX_WIRE_FRAME];
            let n = encode(7, &m, &mut out).unwrap();
            let mut dec = FrameDecoder::new();
            let got: std::vec::Vec<_> = out[..n].iter().filter_map(|&b| dec.push::<HostMsg>(b)).collect();
            assert_eq!(got, std::vec![Ok(Frame { seq: 7, msg: m })]);
        }
        for m in device {
            let mut out = [0u8; MAX_WIRE_FRAME];
            let n = encode(9, &m, &mut out).unwrap();
            let mut dec = FrameDecoder::new();
            let got: std::vec::Vec<_> = out[..n].iter().filter_map(|&b| dec.push::<DeviceMsg>(b)).collect();
            assert_eq!(got, std::vec![Ok(Frame { seq: 9, msg: m })]);
        }
    }

    #[test]
    fn every_frame_error_maps_to_a_nak_reason() {
        assert_eq!(NakReason::from(FrameError::Crc), NakReason::Crc);
        assert_eq!(NakReason::from(FrameError::Cobs), NakReason::Cobs);
        assert_eq!(NakReason::from(FrameError::TooLong), NakReason::TooLong);
        assert_eq!(NakReason::from(FrameError::TooShort), NakReason::Payload);
    }

    /// Strategies producing every variant of both message enums, with values at their extremes.
    mod arb {
        use super::super::*;
        use crate::instrument::{AxisConfig, HomeSide};
        use proptest::collection::vec as pvec;
        use proptest::prelude::*;

        fn f() -> impl Strategy<Value = f32> {
            // Any bit pattern except NaN (NaN != NaN would fail equality, not the codec).
            any::<f32>().prop_filter("not NaN", |x| !x.is_nan())
        }
        pub fn axis() -> impl Strategy<Value = Axis> {
            prop_oneof![
                Just(Axis::Light),
                Just(Axis::Detector),
                Just(Axis::Tilt),
                Just(Axis::Azimuth)
            ]
        }
        fn unreachable() -> impl Strategy<Value = Unreachable> {
            prop_oneof![
                any::<bool>().prop_map(|incoming| Unreachable::BelowHorizon { incoming }),
                Just(Unreachable::Blocked),
                axis().prop_map(Unreachable::Limit),
                Just(Unreachable::NotFinite),
            ]
        }
        fn fault() -> impl Strategy<Value = Fault> {
            prop_oneof![
                axis().prop_map(Fault::LimitSwitch),
                (any::<u32>(), unreachable()).prop_map(|(index, reason)| Fault::Unreachable { index, reason }),
                Just(Fault::BufferOverflow),
                Just(Fault::BadFrame),
                Just(Fault::DetectorTimeout),
                axis().prop_map(Fault::HomeNotFound),
            ]
        }
        fn state() -> impl Strategy<Value = ControllerState> {
            use ControllerState::*;
            prop_oneof![
                Just(Idle),
                Just(Homing),
                Just(Ready),
                Just(Running),
                Just(Paused),
                Just(Done),
                Just(Fault)
            ]
        }
        fn axis_config() -> impl Strategy<Value = AxisConfig<f32>> {
            (
                any::<u16>(),
                any::<u16>(),
                f(),
                f(),
                f(),
                f(),
                f(),
                any::<bool>(),
                any::<bool>(),
            )
                .prop_map(
                    |(steps_per_rev, microsteps, gear_ratio, max_speed, max_accel, min, max, continuous, h)| {
                        AxisConfig {
                            steps_per_rev,
                            microsteps,
                            gear_ratio,
                            max_speed,
                            max_accel,
                            min,
                            max,
                            continuous,
                            home: if h { HomeSide::Max } else { HomeSide::Min },
                        }
                    },
                )
        }
        fn config() -> impl Strategy<Value = InstrumentConfig<f32>> {
            (
                [axis_config(), axis_config(), axis_config(), axis_config()],
                f(),
                any::<u32>(),
                any::<u32>(),
                any::<bool>(),
            )
                .prop_map(
                    |(axes, blocking_angle, settle_ms, exposure_us, isotropic)| InstrumentConfig {
                        axes,
                        blocking_angle,
                        settle_ms,
                        exposure_us,
                        isotropic,
                    },
                )
        }
        fn direction() -> impl Strategy<Value = Direction> {
            (f(), f(), f(), f()).prop_map(|(theta_i, phi_i, theta_o, phi_o)| Direction {
                theta_i,
                phi_i,
                theta_o,
                phi_o,
            })
        }
        fn hello() -> impl Strategy<Value = Hello> {
            (any::<u16>(), any::<u32>(), any::<u32>()).prop_map(|(protocol, schema, session)| Hello {
                protocol,
                schema,
                session,
            })
        }
        fn command() -> impl Strategy<Value = Command> {
            use Command::*;
            prop_oneof![
                Just(Configure),
                Just(Plan),
                Just(PlanEnd),
                Just(Home),
                Just(Start),
                Just(Pause),
                Just(Resume),
                Just(Abort),
                Just(Ack),
                Just(Resend)
            ]
        }
        fn refuse_reason() -> impl Strategy<Value = RefuseReason> {
            use crate::instrument::ConfigError;
            prop_oneof![
                Just(RefuseReason::NoHandshake),
                Just(RefuseReason::NotConfigured),
                axis().prop_map(|a| RefuseReason::BadConfig(ConfigError::BadLimits(a))),
                Just(RefuseReason::BadConfig(ConfigError::TiltRange)),
                state().prop_map(RefuseReason::WrongState),
                any::<u32>().prop_map(|expected| RefuseReason::OutOfOrder { expected }),
                Just(RefuseReason::NoCredit),
                any::<u32>().prop_map(|oldest_kept| RefuseReason::Forgotten { oldest_kept }),
                Just(RefuseReason::NotHomed),
            ]
        }
        fn nak_reason() -> impl Strategy<Value = NakReason> {
            use NakReason::*;
            prop_oneof![Just(Crc), Just(Cobs), Just(TooLong), Just(Payload), Just(Sequence)]
        }
        fn steps() -> impl Strategy<Value = [i32; AXIS_COUNT]> {
            [any::<i32>(), any::<i32>(), any::<i32>(), any::<i32>()]
        }

        pub fn host_msg() -> impl Strategy<Value = HostMsg> {
            prop_oneof![
                hello().prop_map(HostMsg::Hello),
                config().prop_map(HostMsg::Configure),
                (any::<u32>(), pvec(direction(), 0..=caps::CHUNK_DIRECTIONS)).prop_map(|(first_index, d)| {
                    HostMsg::Plan(PlanChunk {
                        first_index,
                        directions: Vec::from_slice(&d).unwrap(),
                    })
                }),
                any::<u32>().prop_map(|total| HostMsg::PlanEnd { total }),
                Just(HostMsg::Home),
                Just(HostMsg::Start),
                Just(HostMsg::Pause),
                Just(HostMsg::Resume),
                Just(HostMsg::Abort),
                Just(HostMsg::GetStatus),
                any::<u32>().prop_map(|through| HostMsg::AckMeasurements { through }),
                any::<u32>().prop_map(|from| HostMsg::ResendMeasurements { from }),
            ]
        }

        pub fn device_msg() -> impl Strategy<Value = DeviceMsg> {
            let measurement = (
                any::<u32>(),
                any::<u32>(),
                steps(),
                pvec(any::<u32>(), 0..=caps::MAX_CHANNELS),
                any::<u32>(),
                any::<u64>(),
            )
                .prop_map(|(seq, index, steps, c, exposure_us, timestamp_us)| {
                    DeviceMsg::Measurement(Measurement {
                        seq,
                        index,
                        steps,
                        counts: Vec::from_slice(&c).unwrap(),
                        exposure_us,
                        timestamp_us,
                    })
                });
            let status = (
                state(),
                any::<bool>(),
                any::<u32>(),
                any::<u32>(),
                any::<u16>(),
                any::<u16>(),
                any::<u32>(),
                steps(),
                proptest::option::of(fault()),
            )
                .prop_map(
                    |(state, homed, plan_next, plan_done, plan_free, unacked, bad_frames, steps, last_fault)| {
                        DeviceMsg::Status(Status {
                            state,
                            homed,
                            plan_next,
                            plan_done,
                            plan_free,
                            unacked,
                            bad_frames,
                            steps,
                            last_fault,
                        })
                    },
                );
            prop_oneof![
                hello().prop_map(DeviceMsg::Hello),
                any::<u16>().prop_map(|seq| DeviceMsg::Ack { seq }),
                (any::<u16>(), nak_reason()).prop_map(|(expected, reason)| DeviceMsg::Nak { expected, reason }),
                (any::<u32>(), any::<u16>()).prop_map(|(next_index, free)| DeviceMsg::Credit { next_index, free }),
                status,
                measurement,
                fault().prop_map(DeviceMsg::Fault),
                (any::<u16>(), command(), refuse_reason()).prop_map(|(seq, command, reason)| DeviceMsg::Refused {
                    seq,
                    command,
                    reason
                }),
            ]
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(3000))]

        #[test]
        fn every_host_message_round_trips(m in arb::host_msg()) {
            let bytes = postcard::to_stdvec(&m).unwrap();
            proptest::prop_assert!(bytes.len() <= crate::frame::MAX_PAYLOAD);
            proptest::prop_assert_eq!(postcard::from_bytes::<HostMsg>(&bytes).unwrap(), m);
        }

        #[test]
        fn every_device_message_round_trips(m in arb::device_msg()) {
            let bytes = postcard::to_stdvec(&m).unwrap();
            proptest::prop_assert!(bytes.len() <= crate::frame::MAX_PAYLOAD);
            proptest::prop_assert_eq!(postcard::from_bytes::<DeviceMsg>(&bytes).unwrap(), m);
        }
    }
}
