//! A 10,000-direction plan streams through the 512-slot plan ring and the 128-slot measurement
//! buffer: the host sends chunks only as `Credit` allows, acknowledges late and in bursts, loses
//! some measurement frames and asks for them again; every measurement comes out exactly once and in
//! order, and the controller pauses (never drops) when the host falls behind with its acks.

mod common;

use common::*;
use gonio_firmware::capacity::{MEASUREMENT_CAPACITY, PLAN_CAPACITY};
use gonio_shared::msg::caps::CHUNK_DIRECTIONS;
use gonio_shared::msg::{ControllerState, DeviceMsg, Direction, HostMsg, Measurement};

const PLAN_LEN: u32 = 10_000;
// The plan is much larger than both buffers it streams through.
const _: () = assert!(PLAN_CAPACITY * 10 < PLAN_LEN as usize);
const _: () = assert!(MEASUREMENT_CAPACITY * 50 < PLAN_LEN as usize);

/// A serpentine over outgoing theta, stepping the incoming theta every 100 directions: small moves
/// (fast to simulate), an arm jump now and then.
fn direction(i: u32) -> Direction {
    let row = i / 100;
    let col = i % 100;
    let col = if row % 2 == 0 { col } else { 99 - col };
    dir_deg(20.0 + (row % 5) as f32 * 10.0, 0.0, 10.0 + 0.6 * col as f32, 180.0)
}

/// A tiny deterministic generator for the host's burstiness.
struct Lcg(u64);
impl Lcg {
    fn next(&mut self, n: u64) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 33) % n
    }
}

#[test]
fn ten_thousand_directions_stream_through_small_buffers_exactly_once_in_order() {
    let mut b = Bench::new(coarse_config());
    b.hal.record_steps = false;
    b.handshake_and_configure();
    b.home();
    let mut rng = Lcg(7);

    let mut processed = 0usize; // messages of b.log handled
    let mut credit_limit = 0u32; // plan index the host may send up to (exclusive)
    let mut next_plan = 0u32;
    let mut plan_end_sent = false;
    let mut started = false;
    let mut in_order: Vec<Measurement> = Vec::new(); // what the host accepted, by seq
    let mut acked_through: Option<u32> = None;
    let mut ack_hold = 0u32; // iterations to sit on received measurements
    let mut resend_pending = false;
    let mut lost_once = std::collections::HashSet::new();
    let mut duplicates = 0usize;
    let mut resends = 0usize;
    let mut paused_by_buffer = 0usize;
    let mut iterations = 0u64;

    loop {
        iterations += 1;
        assert!(
            iterations < 5_000_000,
            "stream stalled at {} measurements",
            in_order.len()
        );
        // The host reads what the device sent.
        while processed < b.log.len() {
            let msg = b.log[processed].clone();
            processed += 1;
            match msg {
                DeviceMsg::Credit { next_index, free } => credit_limit = next_index + u32::from(free),
                DeviceMsg::Measurement(m) => {
                    let expected = in_order.len() as u32;
                    // The link "loses" one frame in 97 (each at most once).
                    if m.seq % 97 == 13 && lost_once.insert(m.seq) {
                        continue;
                    }
                    if m.seq == expected {
                        in_order.push(m);
                        resend_pending = false;
                    } else if m.seq < expected {
                        duplicates += 1;
                        assert_eq!(in_order[m.seq as usize], m, "a resend differs from the original");
                    } else if !resend_pending {
                        // A gap: ask for everything from the first missing one.
                        resend_pending = true;
                        resends += 1;
                        let r = b.send(HostMsg::ResendMeasurements { from: expected });
                        assert!(b.refusals().is_empty(), "{r:?}");
                    }
                }
                DeviceMsg::Status(s) if s.state == ControllerState::Paused => paused_by_buffer += 1,
                DeviceMsg::Refused { .. } | DeviceMsg::Fault(_) | DeviceMsg::Nak { .. } => panic!("{msg:?}"),
                _ => {}
            }
        }
        // Plan chunks, as far as the credit goes.
        while next_plan < PLAN_LEN && next_plan < credit_limit {
            let n = (credit_limit - next_plan)
                .min(CHUNK_DIRECTIONS as u32)
                .min(PLAN_LEN - next_plan);
            let dirs: Vec<_> = (next_plan..next_plan + n).map(direction).collect();
            b.send_plan(next_plan, &dirs);
            next_plan += n;
        }
        if next_plan == PLAN_LEN && !plan_end_sent {
            b.send(HostMsg::PlanEnd { total: PLAN_LEN });
            plan_end_sent = true;
        }
        if !started {
            b.send(HostMsg::Start);
            started = true;
        }
        // Late, bursty acknowledgements: sit on them for a random while, then ack all at once.
        let have = in_order.len() as u32;
        let unacked = have - acked_through.map_or(0, |a| a + 1);
        if unacked > 0 {
            if ack_hold == 0 {
                let through = have - 1;
                b.send(HostMsg::AckMeasurements { through });
                acked_through = Some(through);
                // Sometimes long enough for the buffer to fill up.
                ack_hold = if rng.next(10) == 0 { 3_000 } else { rng.next(40) as u32 };
            } else {
                ack_hold -= 1;
            }
        }
        if b.dev.controller().state() == ControllerState::Done && in_order.len() as u32 == PLAN_LEN {
            break;
        }
        if !b.tick() && unacked == 0 && processed == b.log.len() {
            // Nothing to do on either side: the host must be holding something; ack now.
            ack_hold = 0;
            if b.dev.controller().state() == ControllerState::Paused {
                // Held after `HOST_SILENT_US` without a frame from us: we are back.
                b.send(HostMsg::Resume);
            }
        }
    }
    if let Some(a) = acked_through {
        if a + 1 < PLAN_LEN {
            b.send(HostMsg::AckMeasurements { through: PLAN_LEN - 1 });
        }
    }

    for (k, m) in in_order.iter().enumerate() {
        assert_eq!(m.seq, k as u32);
        assert_eq!(m.index, k as u32, "measurements in plan order");
    }
    assert_eq!(
        b.hal.exposure_count(),
        PLAN_LEN as usize,
        "every direction measured once"
    );
    let s = b.status();
    assert_eq!(s.state, ControllerState::Done);
    assert_eq!((s.plan_next, s.plan_done, s.unacked), (PLAN_LEN, PLAN_LEN, 0));
    assert!(!lost_once.is_empty() && resends > 0, "the resend path was exercised");
    assert!(
        paused_by_buffer > 0,
        "the host never let the measurement buffer fill up"
    );
    assert_eq!(b.dev.outbox().lost_replies(), 0);
    eprintln!(
        "streamed {PLAN_LEN} directions: {} frames lost, {resends} resend requests, {duplicates} duplicates dropped by the host, \
         {paused_by_buffer} buffer-full pauses, {} steps, {:.1} s simulated",
        lost_once.len(),
        b.hal.step_count,
        b.hal.now as f64 / 1e6
    );
}

#[test]
fn a_scan_holds_when_the_host_falls_silent_and_resumes_when_it_returns() {
    use gonio_firmware::controller::HOST_SILENT_US;
    let mut b = Bench::new(coarse_config());
    b.hal.record_steps = false;
    b.handshake_and_configure();
    b.home();
    // Big arm moves (about a second each), so the buffer never fills before the host falls silent.
    let n = 40u32;
    let dirs: Vec<Direction> = (0..n)
        .map(|i| dir_deg(if i % 2 == 0 { 20.0 } else { 60.0 }, 0.0, 30.0, 180.0))
        .collect();
    b.send_plan(0, &dirs);
    b.send(HostMsg::PlanEnd { total: n });
    b.send(HostMsg::Start);
    let last_frame_us = b.hal.now;
    // The host falls silent: the scan runs on, then holds.
    while b.dev.controller().state() == ControllerState::Running && b.tick() {}
    assert_eq!(b.dev.controller().state(), ControllerState::Paused);
    // The direction in flight finishes.
    b.run_idle(600_000_000);
    assert!(!b.dev.controller().is_moving(), "held mid-move");
    assert!(b.hal.now >= last_frame_us + HOST_SILENT_US);
    let held = b.log.iter().filter(|m| matches!(m, DeviceMsg::Measurement(_))).count();
    assert!(held > 0 && (held as u32) < n, "{held} readings before the hold");
    let exposures = b.hal.exposure_count();
    assert_eq!(exposures, held, "the direction in flight was finished and measured");
    // Held: nothing moves or measures however long the host stays away.
    let (steps, t_hold) = (b.hal.step_count, b.hal.now);
    b.hal.now += 600_000_000;
    b.run_idle(600_000_000);
    assert_eq!((b.hal.step_count, b.hal.exposure_count()), (steps, exposures));
    assert!(b.hal.now > t_hold);
    let s = b.status();
    assert_eq!(s.state, ControllerState::Paused);
    assert_eq!(usize::from(s.unacked), held, "the readings are kept");
    // The host returns and resumes: the scan finishes with every direction measured once.
    assert!(b
        .send(HostMsg::Resume)
        .iter()
        .all(|m| !matches!(m, DeviceMsg::Refused { .. })));
    let mut last_ack = b.hal.now;
    while b.dev.controller().state() != ControllerState::Done {
        assert!(b.tick(), "stalled in {:?}", b.dev.controller().state());
        // A present host: something at least every second of instrument time.
        if b.hal.now > last_ack + 1_000_000 {
            b.send(HostMsg::GetStatus);
            last_ack = b.hal.now;
        }
        let taken = b.log.iter().filter(|m| matches!(m, DeviceMsg::Measurement(_))).count() as u32;
        if b.dev.controller().state() == ControllerState::Paused && taken > 0 {
            b.send(HostMsg::AckMeasurements { through: taken - 1 });
        }
    }
    let mut seqs: Vec<u32> = b
        .log
        .iter()
        .filter_map(|m| match m {
            DeviceMsg::Measurement(m) => Some(m.index),
            _ => None,
        })
        .collect();
    seqs.dedup();
    assert_eq!(seqs, (0..n).collect::<Vec<_>>());
}
