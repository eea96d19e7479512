//! Golden wire test: pins `SCHEMA_HASH` and the exact postcard bytes of one instance of every
//! `HostMsg` and `DeviceMsg` variant (and one whole frame), so an accidental wire change fails CI.
//!
//! A deliberate change updates the hex strings here in the same commit (and, for a change of
//! meaning with the same shape, bumps `PROTOCOL_VERSION`). `GOLDEN_PRINT=1 cargo test -p
//! gonio-shared --test wire_golden -- --nocapture` prints the current values.

use gonio_shared::frame::{encode, MAX_WIRE_FRAME};
use gonio_shared::instrument::{AxisConfig, ConfigError, HomeSide, InstrumentConfig};
use gonio_shared::kinematics::Unreachable;
use gonio_shared::msg::{
    Command, ControllerState, DeviceMsg, Direction, Fault, Hello, HostMsg, Measurement, NakReason, PlanChunk,
    RefuseReason, Status, PROTOCOL_VERSION, SCHEMA_HASH,
};
use gonio_shared::Axis;

const GOLDEN_SCHEMA_HASH: u32 = 0x2871_6e46;

/// `Configure(config())`: four axes, then blocking angle, settle, exposure, isotropic.
const CONFIGURE: &str = concat!(
    "01",
    "c80110000090400000003f000000400000c0bf0000c03f0001",
    "c80110000090400000003f000000400000c0bf0000c03f0000",
    "c80110000040400000003f00000040000080bf0000803f0001",
    "c80110000000400000003f00000040000000000000000001",
    "000000803e14904e01",
);

/// Every `HostMsg` variant's index; exhaustive, so a new variant does not compile until it has a
/// golden instance below.
fn host_variant(m: &HostMsg) -> usize {
    match m {
        HostMsg::Hello(_) => 0,
        HostMsg::Configure(_) => 1,
        HostMsg::Plan(_) => 2,
        HostMsg::PlanEnd { .. } => 3,
        HostMsg::Home => 4,
        HostMsg::Start => 5,
        HostMsg::Pause => 6,
        HostMsg::Resume => 7,
        HostMsg::Abort => 8,
        HostMsg::GetStatus => 9,
        HostMsg::AckMeasurements { .. } => 10,
        HostMsg::ResendMeasurements { .. } => 11,
    }
}

fn device_variant(m: &DeviceMsg) -> usize {
    match m {
        DeviceMsg::Hello(_) => 0,
        DeviceMsg::Ack { .. } => 1,
        DeviceMsg::Nak { .. } => 2,
        DeviceMsg::Credit { .. } => 3,
        DeviceMsg::Status(_) => 4,
        DeviceMsg::Measurement(_) => 5,
        DeviceMsg::Fault(_) => 6,
        DeviceMsg::Refused { .. } => 7,
    }
}

fn axis(gear_ratio: f32, min: f32, max: f32, continuous: bool, home: HomeSide) -> AxisConfig<f32> {
    AxisConfig {
        steps_per_rev: 200,
        microsteps: 16,
        gear_ratio,
        max_speed: 0.5,
        max_accel: 2.0,
        min,
        max,
        continuous,
        home,
    }
}

/// A fixed instrument (not `reference()`, so a change of the reference is not a wire change).
fn config() -> InstrumentConfig<f32> {
    InstrumentConfig {
        axes: [
            axis(4.5, -1.5, 1.5, false, HomeSide::Max),
            axis(4.5, -1.5, 1.5, false, HomeSide::Min),
            axis(3.0, -1.0, 1.0, false, HomeSide::Max),
            axis(2.0, 0.0, 0.0, true, HomeSide::Min),
        ],
        blocking_angle: 0.25,
        settle_ms: 20,
        exposure_us: 10_000,
        isotropic: true,
    }
}

fn hello() -> Hello {
    Hello {
        protocol: 1,
        schema: 0xdead_beef,
        session: 0x0102_0304,
    }
}

fn host_messages() -> Vec<(HostMsg, &'static str)> {
    let mut directions = heapless::Vec::new();
    for d in [
        Direction {
            theta_i: 0.5,
            phi_i: 0.0,
            theta_o: 0.25,
            phi_o: 3.0,
        },
        Direction {
            theta_i: 1.0,
            phi_i: -0.5,
            theta_o: 0.125,
            phi_o: -2.0,
        },
    ] {
        directions.push(d).unwrap();
    }
    vec![
        (HostMsg::Hello(hello()), "0001effdb6f50d84868808"),
        (HostMsg::Configure(config()), CONFIGURE),
        (
            HostMsg::Plan(PlanChunk {
                first_index: 300,
                directions,
            }),
            "02ac02020000003f000000000000803e000040400000803f000000bf0000003e000000c0",
        ),
        (HostMsg::PlanEnd { total: 70_000 }, "03f0a204"),
        (HostMsg::Home, "04"),
        (HostMsg::Start, "05"),
        (HostMsg::Pause, "06"),
        (HostMsg::Resume, "07"),
        (HostMsg::Abort, "08"),
        (HostMsg::GetStatus, "09"),
        (HostMsg::AckMeasurements { through: 127 }, "0a7f"),
        (HostMsg::ResendMeasurements { from: 128 }, "0b8001"),
    ]
}

fn device_messages() -> Vec<(DeviceMsg, &'static str)> {
    let mut counts = heapless::Vec::new();
    for c in [0, 6000, 65_535] {
        counts.push(c).unwrap();
    }
    vec![
        (DeviceMsg::Hello(hello()), "0001effdb6f50d84868808"),
        (DeviceMsg::Ack { seq: 513 }, "018104"),
        (
            DeviceMsg::Nak {
                expected: 7,
                reason: NakReason::Crc,
            },
            "020700",
        ),
        (
            DeviceMsg::Credit {
                next_index: 1000,
                free: 512,
            },
            "03e8078004",
        ),
        (
            DeviceMsg::Status(Status {
                state: ControllerState::Running,
                homed: true,
                plan_next: 40,
                plan_done: 17,
                plan_free: 488,
                unacked: 3,
                bad_frames: 2,
                steps: [-12_800, 12_800, 0, 1],
                last_fault: Some(Fault::Unreachable {
                    index: 9,
                    reason: Unreachable::Limit(Axis::Tilt),
                }),
            }),
            "0403012811e8030302ffc70180c80100020101090202",
        ),
        (
            DeviceMsg::Measurement(Measurement {
                seq: 16,
                index: 17,
                steps: [100, -200, 300, -400],
                counts,
                exposure_us: 10_000,
                timestamp_us: 123_456_789,
            }),
            "051011c8018f03d8049f060300f02effff03904e959aef3a",
        ),
        (DeviceMsg::Fault(Fault::LimitSwitch(Axis::Detector)), "060001"),
        (
            DeviceMsg::Refused {
                seq: 4,
                command: Command::Configure,
                reason: RefuseReason::BadConfig(ConfigError::BadLimits(Axis::Light)),
            },
            "070400020200",
        ),
    ]
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn printing() -> bool {
    std::env::var_os("GOLDEN_PRINT").is_some()
}

#[test]
fn the_schema_hash_and_protocol_version_are_pinned() {
    if printing() {
        println!("SCHEMA_HASH = {SCHEMA_HASH:#010x}");
    }
    assert_eq!(SCHEMA_HASH, GOLDEN_SCHEMA_HASH, "the wire schema changed");
    assert_eq!(PROTOCOL_VERSION, 1);
}

/// One instance per variant (`variant` numbers them), each encoding to its golden bytes and back.
fn check_golden<M>(cases: &[(M, &str)], variant: fn(&M) -> usize)
where
    M: serde::Serialize + serde::de::DeserializeOwned + PartialEq + std::fmt::Debug,
{
    let mut seen: Vec<usize> = cases.iter().map(|(m, _)| variant(m)).collect();
    seen.sort_unstable();
    assert_eq!(seen, (0..cases.len()).collect::<Vec<_>>(), "one instance per variant");
    for (m, want) in cases {
        let bytes = postcard::to_allocvec(m).unwrap();
        let got = hex(&bytes);
        if printing() {
            println!("{m:?}: \"{got}\"");
        } else {
            assert_eq!(&got, want, "{m:?}");
        }
        assert_eq!(&postcard::from_bytes::<M>(&bytes).unwrap(), m);
    }
}

#[test]
fn every_host_message_encodes_to_its_golden_bytes() {
    check_golden(&host_messages(), host_variant);
}

#[test]
fn every_device_message_encodes_to_its_golden_bytes() {
    check_golden(&device_messages(), device_variant);
}

#[test]
fn a_whole_frame_is_pinned_too() {
    let mut out = [0u8; MAX_WIRE_FRAME];
    let n = encode(0x0201, &DeviceMsg::Ack { seq: 513 }, &mut out).unwrap();
    let got = hex(&out[..n]);
    if printing() {
        println!("frame: \"{got}\"");
    }
    assert_eq!(got, "0a0102018104f75dbe4800");
}
