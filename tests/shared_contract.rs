//! The contracts host and firmware share, checked across the crates that use them: the host's
//! instrument file reaches the firmware side intact over the wire, and both sides' kinematics
//! (host f64, firmware f32) agree on integer step targets.

use gonio::instrument::{self, survey};
use gonio_shared::frame::{Frame, FrameDecoder};
use gonio_shared::kinematics::Kinematics;
use gonio_shared::msg::{check_handshake, DeviceMsg, Hello, HostMsg};
use gonio_shared::InstrumentConfig;
use gonio_tests::frame_bytes;
use std::path::Path;

fn decode_one<M: serde::de::DeserializeOwned>(bytes: &[u8]) -> Frame<M> {
    let mut dec = FrameDecoder::new();
    let mut got = bytes.iter().filter_map(|&b| dec.push::<M>(b));
    let first = got.next().expect("one frame").expect("a valid frame");
    assert!(got.next().is_none());
    first
}

#[test]
fn instrument_file_reaches_the_firmware_intact() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/gonio.toml");
    let host_cfg = instrument::load(&path).expect("shipped instrument file");
    let wire = frame_bytes(1, &HostMsg::Configure(host_cfg.cast::<f32>()));
    let Frame { seq, msg } = decode_one::<HostMsg>(&wire);
    assert_eq!(seq, 1);
    let HostMsg::Configure(fw_cfg) = msg else {
        panic!("wrong message {msg:?}")
    };
    // The firmware validates what it receives with the same rules as the host.
    fw_cfg.validate().expect("valid on the firmware side");
    assert_eq!(fw_cfg, host_cfg.cast::<f32>());
    // And builds the same kinematics from it.
    Kinematics::new(fw_cfg).expect("firmware kinematics");
}

#[test]
fn handshake_round_trips_and_mismatches_refuse() {
    let Frame { msg, .. } = decode_one::<DeviceMsg>(&frame_bytes(0, &DeviceMsg::Hello(Hello::OURS)));
    let DeviceMsg::Hello(theirs) = msg else {
        panic!("wrong message")
    };
    check_handshake(theirs).expect("same build agrees");
    let other = Hello {
        schema: theirs.schema.wrapping_add(1),
        ..theirs
    };
    let err = check_handshake(other).expect_err("different schema refused");
    assert!(err.to_string().contains("protocol mismatch"));
}

/// Host (f64) and firmware (f32) inverse kinematics from the same wire angles give the same
/// integer step targets, or differ by one step where rounding falls on a boundary.
#[test]
fn host_and_firmware_step_targets_agree() {
    let s = survey::survey(&InstrumentConfig::<f64>::reference(), 50_000, 7).expect("valid instrument");
    println!("{s}");
    // The survey must have compared real poses, not a vacuous set.
    assert!(s.reachable() > 45_000, "{s}");
    assert_eq!(s.compared(), s.reachable() - s.outcome_disagreements, "{s}");
    assert_eq!(s.step_targets_off_by_more, 0, "{s}");
    // Off-by-one only where an f32 rounding error meets a half-step boundary: rare.
    assert!(s.step_targets_off_by_one * 100 < s.compared(), "{s}");
    assert!(s.outcome_disagreements * 1000 < s.pairs, "{s}");
    assert!(s.max_fk_error_f64 < 1e-9, "{s}");
    // f32 on the firmware path: a few ulps of the angles (f32 eps ~ 1.2e-7 rad at 1 rad).
    assert!(s.max_fk_error_f32 < 2e-6, "{s}");
}
