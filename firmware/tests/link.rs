//! The link under abuse: garbage, truncated, corrupted, duplicated and reordered frames never
//! panic, are NAKed with the sequence number the link expects, and never cause motion.

mod common;

use common::*;
use gonio_firmware::link::BAD_FRAME_FAULT_RUN;
use gonio_shared::msg::{ControllerState, DeviceMsg, Fault, Hello, HostMsg, NakReason};
use proptest::prelude::*;

fn fixed(cases: u32) -> proptest::test_runner::Config {
    common::fixed_seed_config(cases, 0x11_4c)
}

fn naks(msgs: &[DeviceMsg]) -> Vec<(u16, NakReason)> {
    msgs.iter()
        .filter_map(|m| match m {
            DeviceMsg::Nak { expected, reason } => Some((*expected, *reason)),
            _ => None,
        })
        .collect()
}

fn acks(msgs: &[DeviceMsg]) -> Vec<u16> {
    msgs.iter()
        .filter_map(|m| match m {
            DeviceMsg::Ack { seq } => Some(*seq),
            _ => None,
        })
        .collect()
}

/// Homed, a plan loaded and ended: one valid `Start` away from moving.
fn armed() -> Bench {
    let mut b = Bench::new(coarse_config());
    b.handshake_and_configure();
    b.home();
    b.send_plan(0, &[dir_deg(60.0, 0.0, 20.0, 180.0), dir_deg(10.0, 0.0, 70.0, 180.0)]);
    b.send(HostMsg::PlanEnd { total: 2 });
    assert_eq!(b.dev.controller().state(), ControllerState::Ready);
    b.hal.steps.clear();
    b.hal.step_count = 0;
    b
}

/// Runs the device for a while and checks it did not move or measure.
fn assert_still(b: &mut Bench) {
    b.run_idle(10_000_000);
    assert_eq!(b.hal.step_count, 0, "motion from a bad frame");
    assert_eq!(b.hal.exposure_count(), 0);
    assert_eq!(b.dev.controller().state(), ControllerState::Ready);
}

proptest! {
    #![proptest_config(fixed(256))]

    /// Arbitrary bytes: no panic, one NAK per dropped candidate frame, no motion.
    #[test]
    fn garbage_is_naked_and_never_moves(garbage in prop::collection::vec(any::<u8>(), 0..1500)) {
        let mut b = armed();
        let bad_before = b.dev.link().decoder_stats().bad();
        let r = b.send_raw(&garbage);
        let dropped = b.dev.link().decoder_stats().bad() - bad_before;
        prop_assert_eq!(naks(&r).len() as u32, dropped);
        prop_assert!(acks(&r).is_empty(), "garbage was acknowledged: {:?}", r);
        if dropped >= BAD_FRAME_FAULT_RUN {
            // That many bad frames in a row: the link is not trusted (and still nothing moves).
            prop_assert!(r.contains(&DeviceMsg::Fault(Fault::BadFrame)), "{:?}", r);
            b.run_idle(10_000_000);
            prop_assert_eq!(b.hal.step_count, 0);
            prop_assert_eq!(b.dev.controller().state(), ControllerState::Fault);
        } else {
            assert_still(&mut b);
        }
        // The link still works afterwards (a delimiter flushes any partial frame first).
        b.send_raw(&[0]);
        let r = b.send(HostMsg::GetStatus);
        prop_assert!(r.iter().any(|m| matches!(m, DeviceMsg::Status(_))));
    }

    /// A `Start` frame cut short or with one bit flipped is NAKed, and the device stays still.
    #[test]
    fn truncated_or_corrupted_start_is_naked_and_never_moves(
        cut in any::<prop::sample::Index>(),
        flip in any::<prop::sample::Index>(),
        bit in 0u8..8,
        truncate in any::<bool>(),
    ) {
        let mut b = armed();
        let seq = b.host_seq;
        let f = frame(seq, &HostMsg::Start);
        let bad = if truncate {
            let mut t = f[..cut.index(f.len() - 1)].to_vec();
            t.push(0);
            t
        } else {
            let mut t = f.clone();
            t[flip.index(f.len() - 1)] ^= 1 << bit;
            t
        };
        let r = b.send_raw(&bad);
        prop_assert!(acks(&r).is_empty(), "{:?}", r);
        for (expected, _) in naks(&r) {
            prop_assert_eq!(expected, seq);
        }
        assert_still(&mut b);
        // The intact frame, resent with the same sequence number, is executed.
        let r = b.send_raw(&f);
        prop_assert_eq!(acks(&r), vec![seq]);
        prop_assert_eq!(b.dev.controller().state(), ControllerState::Running);
    }
}

#[test]
fn an_empty_truncation_still_gets_a_nak_when_bytes_preceded_it() {
    let mut b = armed();
    let r = b.send_raw(&[0x42, 0x00]);
    assert_eq!(naks(&r), vec![(b.host_seq, NakReason::Cobs)]);
}

#[test]
fn duplicates_are_reacknowledged_but_not_executed() {
    let mut b = armed();
    // Home once, then the same frame again (the host missed our Ack).
    let seq = b.host_seq;
    b.host_seq += 1;
    let home = frame(seq, &HostMsg::Home);
    let r = b.send_raw(&home);
    assert_eq!(acks(&r), vec![seq]);
    assert_eq!(b.dev.controller().state(), ControllerState::Homing);
    let r = b.send_raw(&home);
    assert_eq!(acks(&r), vec![seq], "a duplicate is acknowledged again");
    assert!(
        !r.iter().any(|m| matches!(m, DeviceMsg::Refused { .. })),
        "not executed again: {r:?}"
    );
    b.run_idle(600_000_000);
    // A duplicated plan chunk is not taken twice.
    let plan_next = b.status().plan_next;
    let seq = b.host_seq;
    let r = b.send_plan(0, &[dir_deg(30.0, 0.0, 50.0, 180.0)]);
    assert!(!r.iter().any(|m| matches!(m, DeviceMsg::Refused { .. })), "{r:?}");
    let chunk = {
        let mut directions = heapless::Vec::new();
        directions.push(dir_deg(30.0, 0.0, 50.0, 180.0)).unwrap();
        HostMsg::Plan(gonio_shared::msg::PlanChunk {
            first_index: 0,
            directions,
        })
    };
    let r = b.send_raw(&frame(seq, &chunk));
    assert_eq!(acks(&r), vec![seq]);
    assert!(!r.iter().any(|m| matches!(m, DeviceMsg::Refused { .. })), "{r:?}");
    assert_eq!(b.status().plan_next, plan_next + 1);
}

#[test]
fn reordered_frames_are_naked_until_the_gap_is_filled() {
    let mut b = armed();
    let s = b.host_seq;
    let start = frame(s, &HostMsg::Start);
    let pause = frame(s + 1, &HostMsg::Pause);
    // Pause overtakes Start: NAKed, not executed, and no motion.
    let r = b.send_raw(&pause);
    assert_eq!(naks(&r), vec![(s, NakReason::Sequence)]);
    assert_still(&mut b);
    // A frame from far in the past or the future is a gap too.
    let r = b.send_raw(&frame(s.wrapping_add(1000), &HostMsg::Start));
    assert_eq!(naks(&r), vec![(s, NakReason::Sequence)]);
    assert_still(&mut b);
    // Then in order.
    assert_eq!(acks(&b.send_raw(&start)), vec![s]);
    assert_eq!(acks(&b.send_raw(&pause)), vec![s + 1]);
    assert_eq!(b.dev.controller().state(), ControllerState::Paused);
}

fn hellos(msgs: &[DeviceMsg]) -> Vec<Hello> {
    msgs.iter()
        .filter_map(|m| match m {
            DeviceMsg::Hello(h) => Some(*h),
            _ => None,
        })
        .collect()
}

/// Only a `Hello` at sequence number 0 with a new session id restarts the count; copies of the
/// opening one are acknowledged and answered again, others obey the sequence rules.
#[test]
fn only_a_new_sessions_hello_restarts_the_sequence_numbers() {
    let mut b = armed();
    let plan_next = b.status().plan_next;
    let next = b.host_seq;
    // The opening Hello again (session 0, seq 0): acknowledged and answered, count unchanged.
    let r = b.send_raw(&frame(0, &HostMsg::Hello(Hello::OURS)));
    assert_eq!(acks(&r), vec![0]);
    assert_eq!(hellos(&r), vec![Hello::OURS]);
    assert_eq!(b.dev.link().expected_seq(), next);
    // The frame before `next` (a GetStatus) resent: re-ACKed, not executed.
    let r = b.send_raw(&frame(next - 1, &HostMsg::GetStatus));
    assert_eq!(acks(&r), vec![next - 1]);
    assert!(!r.iter().any(|m| matches!(m, DeviceMsg::Status(_))), "{r:?}");
    // A Hello far from the expected number (even of a new session) is a gap: NAKed, no reset.
    for seq in [40_000, next + 1, next + 100] {
        let r = b.send_raw(&frame(seq, &HostMsg::Hello(Hello::ours(9))));
        assert_eq!(naks(&r), vec![(next, NakReason::Sequence)], "seq {seq}");
        assert!(hellos(&r).is_empty());
    }
    // A Hello in sequence is executed once (versions re-checked), without restarting the count.
    let r = b.send_raw(&frame(next, &HostMsg::Hello(Hello::OURS)));
    assert_eq!(acks(&r), vec![next]);
    assert_eq!(hellos(&r), vec![Hello::OURS]);
    assert_eq!(b.dev.link().expected_seq(), next + 1);
    assert_eq!(b.status_at(next + 1).plan_next, plan_next);
    // A new session (seq 0, another id): the count restarts at 1; the plan stays.
    let r = b.send_raw(&frame(0, &HostMsg::Hello(Hello::ours(7))));
    assert_eq!(acks(&r), vec![0]);
    assert_eq!(hellos(&r), vec![Hello::ours(7)]);
    assert_eq!(b.dev.link().expected_seq(), 1);
    assert_eq!(b.status_at(1).plan_next, plan_next);
    // Its copy is a duplicate now, and the previous session's opening Hello is a new session.
    let r = b.send_raw(&frame(0, &HostMsg::Hello(Hello::ours(7))));
    assert_eq!((acks(&r), hellos(&r)), (vec![0], vec![Hello::ours(7)]));
    assert_eq!(b.dev.link().expected_seq(), 2);
    let r = b.send_raw(&frame(0, &HostMsg::Hello(Hello::OURS)));
    assert_eq!((acks(&r), hellos(&r)), (vec![0], vec![Hello::OURS]));
    assert_eq!(b.dev.link().expected_seq(), 1);
}

/// The host's resend after a late copy of its opening `Hello`: with the old rule (`Hello` at any
/// sequence number restarts the count) the resent `Start` ran again and the instrument moved.
#[test]
fn a_late_hello_then_a_resend_never_runs_a_command_twice() {
    let mut b = armed();
    let start = b.host_seq;
    b.send(HostMsg::Start);
    b.send(HostMsg::Abort);
    b.run_idle(600_000_000);
    assert_eq!(b.dev.controller().state(), ControllerState::Ready);
    b.hal.steps.clear();
    b.hal.step_count = 0;
    let exposures = b.hal.exposure_count();
    // The opening Hello arrives late, then go-back-N resends every frame from the first.
    let mut replay = frame(0, &HostMsg::Hello(Hello::OURS));
    for (_, f) in b.sent.clone().iter().skip(1) {
        replay.extend_from_slice(f);
    }
    let r = b.send_raw(&replay);
    assert!(
        r.iter()
            .all(|m| matches!(m, DeviceMsg::Ack { .. } | DeviceMsg::Hello(_))),
        "{r:?}"
    );
    assert_eq!(acks(&r), (0..=start + 1).collect::<Vec<_>>());
    b.run_idle(600_000_000);
    assert_eq!(b.hal.step_count, 0, "a resent command moved the instrument");
    assert_eq!(b.hal.exposure_count(), exposures);
    assert_eq!(b.dev.controller().state(), ControllerState::Ready);
    assert_eq!(b.dev.link().expected_seq(), start + 2);
}

proptest! {
    #![proptest_config(fixed(128))]

    /// Copies of the session's frames (its opening `Hello` among them) and `Hello`s at arbitrary
    /// sequence numbers, in any order, mid-plan: nothing runs twice, nothing moves, and the frame
    /// the host sends next is executed.
    #[test]
    fn duplicated_and_reordered_hellos_mid_plan_never_rerun_or_move(
        picks in prop::collection::vec((any::<prop::sample::Index>(), any::<u16>(), 0u8..4), 1..40),
    ) {
        let mut b = armed();
        let plan_next = b.status().plan_next;
        let next = b.host_seq;
        b.hal.steps.clear();
        b.hal.step_count = 0;
        let log_start = b.log.len();
        let sent = b.sent.clone();
        for (pick, seq, kind) in picks {
            let bytes = match kind {
                // A copy of any frame of the session (index 0: the opening Hello).
                0 | 1 => sent[pick.index(sent.len())].1.clone(),
                2 => frame(0, &HostMsg::Hello(Hello::OURS)),
                // A Hello of this session at an arbitrary number (the expected one excepted).
                _ if seq == next => continue,
                _ => frame(seq, &HostMsg::Hello(Hello::OURS)),
            };
            b.send_raw(&bytes);
            b.run_idle(1_000_000);
        }
        let r = b.log[log_start..].to_vec();
        prop_assert!(!r.iter().any(|m| matches!(m, DeviceMsg::Refused { .. } | DeviceMsg::Credit { .. } | DeviceMsg::Status(_))), "re-executed: {:?}", r);
        prop_assert_eq!(b.hal.step_count, 0);
        prop_assert_eq!(b.dev.link().expected_seq(), next);
        let s = b.status();
        prop_assert_eq!(s.plan_next, plan_next);
        prop_assert_eq!(s.state, ControllerState::Ready);
    }
}

#[test]
fn a_host_that_never_reads_is_throttled_not_answered_with_lost_replies() {
    let mut b = armed();
    // 500 status requests in one go, without draining the outbox in between.
    let mut bytes = Vec::new();
    for k in 0..500u16 {
        bytes.extend(frame(b.host_seq + k, &HostMsg::GetStatus));
    }
    let log_start = b.log.len();
    let consumed = b.dev.receive(&mut b.hal, &bytes);
    assert!(
        consumed < bytes.len(),
        "the device must stop reading when it cannot answer"
    );
    assert_eq!(b.dev.outbox().lost_replies(), 0);
    // Draining lets the rest through, and every request is answered.
    b.host_seq += 500;
    b.collect();
    let before = b.log.len();
    b.send_raw(&bytes[consumed..]);
    let statuses = b.log[log_start..]
        .iter()
        .filter(|m| matches!(m, DeviceMsg::Status(_)))
        .count();
    assert_eq!(statuses, 500, "{} messages after the drain", b.log.len() - before);
    assert_eq!(b.dev.outbox().lost_replies(), 0);
}

/// `BAD_FRAME_FAULT_RUN` bad frames in a row raise `Fault::BadFrame`; one good frame in between
/// resets the count. During a scan the fault lets the move in progress finish and starts nothing
/// new; `Abort` clears it.
#[test]
fn a_run_of_bad_frames_faults_and_a_good_frame_resets_the_run() {
    let mut b = armed();
    let bad = [0x42u8, 0x00];
    for _ in 0..BAD_FRAME_FAULT_RUN - 1 {
        b.send_raw(&bad);
    }
    b.send(HostMsg::GetStatus);
    for _ in 0..BAD_FRAME_FAULT_RUN - 1 {
        b.send_raw(&bad);
    }
    assert_eq!(b.dev.controller().state(), ControllerState::Ready, "the run was reset");
    // Start the scan, let the first move begin, then the run that breaks the link.
    b.send(HostMsg::Start);
    while b.hal.step_count == 0 {
        assert!(b.tick());
    }
    let mut r = Vec::new();
    for _ in 0..BAD_FRAME_FAULT_RUN {
        r.extend(b.send_raw(&bad));
    }
    assert!(r.contains(&DeviceMsg::Fault(Fault::BadFrame)), "{r:?}");
    assert_eq!(b.dev.controller().state(), ControllerState::Fault);
    assert!(!b.dev.controller().is_moving(), "every fault stops motion at once");
    b.run_idle(600_000_000);
    assert!(!b.dev.controller().is_moving());
    assert_eq!(b.hal.exposure_count(), 0, "no measurement after the fault");
    // Not a fault that needs homing: Abort clears it, then Start runs again.
    assert!(b.refusals().is_empty());
    b.send(HostMsg::Abort);
    assert_eq!(b.dev.controller().state(), ControllerState::Ready);
    let r = b.send(HostMsg::Start);
    assert!(!r.iter().any(|m| matches!(m, DeviceMsg::Refused { .. })), "{r:?}");
}

/// `Refused` names the frame it answers, so a host with several frames in flight can match it.
#[test]
fn refused_names_the_sequence_number_of_the_refused_frame() {
    let mut b = Bench::new(coarse_config());
    let r = b.send(HostMsg::Home);
    assert_eq!(
        r,
        vec![
            DeviceMsg::Ack { seq: 0 },
            DeviceMsg::Refused {
                seq: 0,
                command: gonio_shared::msg::Command::Home,
                reason: gonio_shared::msg::RefuseReason::NoHandshake
            }
        ]
    );
    b.handshake_and_configure();
    // Three frames in one go: only the middle one is refused, and says so.
    let s = b.host_seq;
    let mut bytes = frame(s, &HostMsg::GetStatus);
    bytes.extend(frame(s + 1, &HostMsg::Start));
    bytes.extend(frame(s + 2, &HostMsg::GetStatus));
    b.host_seq += 3;
    let r = b.send_raw(&bytes);
    let refused: Vec<_> = r
        .iter()
        .filter_map(|m| match m {
            DeviceMsg::Refused { seq, command, reason } => Some((*seq, *command, *reason)),
            _ => None,
        })
        .collect();
    assert_eq!(
        refused,
        vec![(
            s + 1,
            gonio_shared::msg::Command::Start,
            gonio_shared::msg::RefuseReason::NotHomed
        )]
    );
}

/// `Status` carries the plan credit (`plan_next + plan_free`), the same grant as `Credit`, so a
/// lost `Credit` is recovered by the status the host polls anyway.
#[test]
fn status_carries_the_same_grant_as_credit() {
    let mut b = Bench::new(coarse_config());
    assert_eq!(b.status().plan_free, 0, "no grant before the handshake");
    b.handshake_and_configure();
    let credit = |r: &[DeviceMsg]| {
        r.iter()
            .rev()
            .find_map(|m| match m {
                DeviceMsg::Credit { next_index, free } => Some((*next_index, *free)),
                _ => None,
            })
            .expect("a credit")
    };
    let (next, free) = credit(&b.log);
    let s = b.status();
    assert_eq!((s.plan_next, s.plan_free), (next, free));
    assert_eq!((next, usize::from(free)), (0, gonio_firmware::capacity::PLAN_CAPACITY));
    b.home();
    let dirs = vec![dir_deg(30.0, 0.0, 50.0, 180.0); 8];
    let r = b.send_plan(0, &dirs);
    let (next, free) = credit(&r);
    let s = b.status();
    assert_eq!((s.plan_next, s.plan_free), (next, free));
    assert_eq!(u32::from(free) + next, gonio_firmware::capacity::PLAN_CAPACITY as u32);
    // Ended with directions still missing: those are still granted (a chunk the host had to send
    // again after a refusal may come after its PlanEnd), and no more.
    b.send(HostMsg::PlanEnd { total: 16 });
    assert_eq!(b.status().plan_free, 8);
    b.send_plan(8, &dirs);
    // Every direction up to the end is in: nothing more to grant.
    assert_eq!(b.status().plan_free, 0);
}
