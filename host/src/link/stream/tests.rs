//! The plan stream fed events by hand, no transport: credit, a lost credit recovered from status,
//! refusals, duplicate and missing measurements, resends.

use super::*;

const CHUNK: u32 = CHUNK_DIRECTIONS as u32;

fn plan(n: usize) -> Vec<Direction> {
    vec![
        Direction {
            theta_i: 0.5,
            phi_i: 0.0,
            theta_o: 0.5,
            phi_o: 3.0,
        };
        n
    ]
}

fn reading(seq: u32) -> Measurement {
    Measurement {
        seq,
        index: seq,
        steps: [0; 4],
        counts: heapless::Vec::new(),
        exposure_us: 100,
        timestamp_us: 1000 + u64::from(seq),
    }
}

fn status(state: ControllerState, plan_next: u32, plan_free: u16, plan_done: u32) -> Status {
    Status {
        state,
        homed: true,
        plan_next,
        plan_done,
        plan_free,
        unacked: 0,
        bad_frames: 0,
        steps: [0; 4],
        last_fault: None,
    }
}

/// Take every frame due, numbering them from `seq` like the reliability layer would; returns the
/// frames and the next sequence number.
fn drain(s: &mut PlanStream, mut seq: u16) -> (Vec<HostMsg>, u16) {
    let mut out = Vec::new();
    while let Some(msg) = s.next_frame().unwrap() {
        s.sent(&msg, seq);
        seq = seq.wrapping_add(1);
        out.push(msg);
    }
    (out, seq)
}

/// First plan indices of the chunks among `frames`.
fn chunk_starts(frames: &[HostMsg]) -> Vec<u32> {
    frames
        .iter()
        .filter_map(|m| match m {
            HostMsg::Plan(c) => Some(c.first_index),
            _ => None,
        })
        .collect()
}

#[test]
fn nothing_goes_before_credit_and_a_grant_sends_chunks_then_start() {
    let p = plan(20);
    let t0 = Instant::now();
    let mut s = PlanStream::new(&p, 5, LinkTiming::default(), t0).unwrap();
    assert_eq!(drain(&mut s, 5).0, vec![]);
    s.on_credit(0, 2 * CHUNK as u16, t0);
    let (frames, _) = drain(&mut s, 5);
    assert_eq!(chunk_starts(&frames), vec![0, CHUNK]);
    assert_eq!(frames.last(), Some(&HostMsg::Start));
    assert_eq!(frames.len(), 3, "{frames:?}");
    // The rest of the plan (a short last chunk), then its end.
    s.on_credit(2 * CHUNK, 64, t0);
    let (frames, _) = drain(&mut s, 8);
    assert_eq!(chunk_starts(&frames), vec![2 * CHUNK]);
    assert_eq!(frames.last(), Some(&HostMsg::PlanEnd { total: 20 }));
    match &frames[0] {
        HostMsg::Plan(c) => assert_eq!(c.directions.len(), 20 - 2 * CHUNK as usize),
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_lost_credit_is_asked_for_and_recovered_from_status() {
    let p = plan(40);
    let timing = LinkTiming::default();
    let t0 = Instant::now();
    let mut s = PlanStream::new(&p, 0, timing, t0).unwrap();
    // Starved from the start: the configuration's grant went elsewhere, so ask at once.
    assert_eq!(s.status_due(t0), Some(HostMsg::GetStatus));
    assert_eq!(s.status_due(t0 + timing.idle / 2), None, "asked again too soon");
    s.on_credit(0, CHUNK as u16, t0);
    let (frames, seq) = drain(&mut s, 0);
    assert_eq!(chunk_starts(&frames), vec![0]);
    // The Credit for the next chunk is lost; after `idle` without a grant the stream asks.
    assert_eq!(s.status_due(t0 + timing.idle / 2), None);
    let later = t0 + timing.idle;
    assert_eq!(s.status_due(later), Some(HostMsg::GetStatus));
    // The status carries the same grant.
    let replies = s
        .on_status(&status(ControllerState::Running, CHUNK, CHUNK as u16, 0), later)
        .unwrap();
    assert_eq!(replies, vec![]);
    assert_eq!(chunk_starts(&drain(&mut s, seq).0), vec![CHUNK]);
}

#[test]
fn measurements_are_taken_once_in_order_and_acknowledged() {
    let p = plan(3);
    let t0 = Instant::now();
    let mut s = PlanStream::new(&p, 0, LinkTiming::default(), t0).unwrap();
    assert_eq!(s.on_measurement(&reading(0), t0).unwrap(), Reading::Record);
    assert_eq!(s.on_measurement(&reading(0), t0).unwrap(), Reading::Duplicate);
    assert_eq!(s.ack_due(false), None, "busy, and fewer than ACK_EVERY");
    assert_eq!(s.ack_due(true), Some(HostMsg::AckMeasurements { through: 0 }));
    assert_eq!(s.ack_due(true), None, "nothing new to acknowledge");
    assert_eq!(s.on_measurement(&reading(1), t0).unwrap(), Reading::Record);
    assert_eq!(s.on_measurement(&reading(2), t0).unwrap(), Reading::Record);
    assert!(s.is_complete());
    assert_eq!(s.ack_due(false), Some(HostMsg::AckMeasurements { through: 2 }));
    let bad = Measurement { index: 3, ..reading(0) };
    let mut s = PlanStream::new(&p, 0, LinkTiming::default(), t0).unwrap();
    assert!(matches!(
        s.on_measurement(&bad, t0),
        Err(LinkError::OutOfPlan { index: 3, total: 3 })
    ));
}

#[test]
fn a_gap_asks_for_a_resend_once_per_two_timeouts() {
    let p = plan(10);
    let timing = LinkTiming::default();
    let t0 = Instant::now();
    let mut s = PlanStream::new(&p, 0, timing, t0).unwrap();
    assert_eq!(s.on_measurement(&reading(0), t0).unwrap(), Reading::Record);
    assert_eq!(s.on_measurement(&reading(2), t0).unwrap(), Reading::Resend { from: 1 });
    assert_eq!(s.on_measurement(&reading(3), t0 + timing.rto).unwrap(), Reading::Early);
    assert_eq!(
        s.on_measurement(&reading(3), t0 + timing.rto * 2).unwrap(),
        Reading::Resend { from: 1 }
    );
    // The resend arrives: in order again, and a later gap may ask at once.
    for k in 1..=3 {
        assert_eq!(
            s.on_measurement(&reading(k), t0 + timing.rto * 2).unwrap(),
            Reading::Record
        );
    }
    assert_eq!(
        s.on_measurement(&reading(5), t0 + timing.rto * 2).unwrap(),
        Reading::Resend { from: 4 }
    );
}

#[test]
fn only_a_probed_status_reveals_lost_measurements() {
    let p = plan(10);
    let timing = LinkTiming::default();
    let t0 = Instant::now();
    let mut s = PlanStream::new(&p, 0, timing, t0).unwrap();
    s.on_credit(0, 16, t0);
    let _ = drain(&mut s, 0);
    let running = status(ControllerState::Running, 10, 0, 4);
    // An unsolicited status may overtake readings still on their way: no resend.
    assert_eq!(s.on_status(&running, t0).unwrap(), vec![]);
    assert_eq!(s.probe_due(t0 + timing.idle / 2), None);
    let quiet = t0 + timing.idle;
    assert_eq!(s.probe_due(quiet), Some(HostMsg::GetStatus));
    assert_eq!(
        s.on_status(&running, quiet).unwrap(),
        vec![HostMsg::ResendMeasurements { from: 0 }]
    );
    assert_eq!(s.on_status(&running, quiet).unwrap(), vec![], "one answer per probe");
}

#[test]
fn a_ready_device_is_started_again() {
    let p = plan(4);
    let t0 = Instant::now();
    let mut s = PlanStream::new(&p, 0, LinkTiming::default(), t0).unwrap();
    let ready = status(ControllerState::Ready, 0, 512, 0);
    assert_eq!(s.on_status(&ready, t0).unwrap(), vec![], "not started yet");
    let _ = drain(&mut s, 0);
    assert_eq!(s.on_status(&ready, t0).unwrap(), vec![HostMsg::Start]);
}

#[test]
fn refused_chunks_rewind_the_stream_once() {
    let p = plan(40);
    let t0 = Instant::now();
    let mut s = PlanStream::new(&p, 0, LinkTiming::default(), t0).unwrap();
    s.on_credit(0, 40, t0);
    let (frames, seq) = drain(&mut s, 10);
    assert_eq!(chunk_starts(&frames), vec![0, 8, 16, 24, 32]);
    // Chunk 8 (seq 11) is lost; 16 (seq 12) and the ones after it are refused out of order.
    let out_of_order = RefuseReason::OutOfOrder { expected: 8 };
    assert_eq!(s.on_refused(12, Command::Plan, out_of_order, seq).unwrap(), None);
    assert_eq!(s.on_refused(13, Command::Plan, out_of_order, seq).unwrap(), None);
    let (again, seq2) = drain(&mut s, seq);
    assert_eq!(chunk_starts(&again), vec![8, 16, 24, 32]);
    // A refusal of a frame from before the rewind is stale.
    assert_eq!(s.on_refused(14, Command::Plan, out_of_order, seq2).unwrap(), None);
    assert_eq!(drain(&mut s, seq2).0, vec![]);
    // No credit for the chunk at 24 (seq2 - 2): back to it, and wait for a fresh grant.
    let seq_24 = seq2 - 2;
    assert_eq!(
        s.on_refused(seq_24, Command::Plan, RefuseReason::NoCredit, seq2)
            .unwrap(),
        None
    );
    assert_eq!(drain(&mut s, seq2).0, vec![]);
    s.on_credit(24, 16, t0);
    assert_eq!(chunk_starts(&drain(&mut s, seq2).0), vec![24, 32]);
}

#[test]
fn refusals_of_start_and_of_the_configuration() {
    let p = plan(4);
    let t0 = Instant::now();
    let mut s = PlanStream::new(&p, 0, LinkTiming::default(), t0).unwrap();
    s.on_credit(0, 8, t0);
    let (frames, seq) = drain(&mut s, 0);
    assert_eq!(
        frames,
        vec![frames[0].clone(), HostMsg::PlanEnd { total: 4 }, HostMsg::Start]
    );
    let start_seq = seq - 1;
    let busy = RefuseReason::WrongState(ControllerState::Running);
    assert_eq!(
        s.on_refused(start_seq, Command::Start, busy, seq).unwrap(),
        Some(HostMsg::GetStatus)
    );
    assert_eq!(
        s.on_refused(start_seq - 1, Command::Start, busy, seq).unwrap(),
        None,
        "not our Start"
    );
    assert!(matches!(
        s.on_refused(start_seq, Command::Start, RefuseReason::NotHomed, seq),
        Err(LinkError::Refused {
            what: "the scan's Start",
            ..
        })
    ));
    assert!(matches!(
        s.on_refused(0, Command::Plan, RefuseReason::NotConfigured, seq),
        Err(LinkError::Refused {
            what: "a scan command",
            ..
        })
    ));
}

#[test]
fn statuses_that_end_the_stream() {
    let p = plan(40);
    let t0 = Instant::now();
    let mut s = PlanStream::new(&p, 0, LinkTiming::default(), t0).unwrap();
    let mut fault = status(ControllerState::Fault, 0, 0, 0);
    fault.last_fault = Some(Fault::BufferOverflow);
    assert!(matches!(
        s.on_status(&fault, t0),
        Err(Stop::Fault(Some(Fault::BufferOverflow)))
    ));
    let mut restarted = status(ControllerState::Idle, 0, 0, 0);
    restarted.homed = false;
    assert!(matches!(
        s.on_status(&restarted, t0),
        Err(Stop::Error(LinkError::Disconnected(_)))
    ));
    // A device out of plan that grants nothing: a bounded number of such answers, then an error.
    s.on_credit(0, 8, t0);
    let _ = drain(&mut s, 0);
    let starved = status(ControllerState::Running, 8, 0, 8);
    for _ in 0..STARVED_STATUS_LIMIT {
        assert!(s.on_status(&starved, t0).is_ok());
    }
    assert!(matches!(
        s.on_status(&starved, t0),
        Err(Stop::Error(LinkError::Stalled(_)))
    ));
}

#[test]
fn an_empty_plan_is_complete_at_once() {
    let s = PlanStream::new(&[], 0, LinkTiming::default(), Instant::now()).unwrap();
    assert!(s.is_complete());
}

/// On a lossy link the `Refused` of the last chunk is lost: everything is acknowledged, the
/// device's status keeps showing it starved before that chunk. Without a rewind the scan would
/// wait forever (statuses keep flowing, so the link never counts as silent).
#[test]
fn a_lost_refusal_of_the_last_chunk_rewinds_once_everything_is_acked() {
    let p = plan(24);
    let t0 = Instant::now();
    let mut s = PlanStream::new(&p, 0, LinkTiming::default(), t0).unwrap();
    s.on_credit(0, 24, t0);
    let (frames, seq) = drain(&mut s, 0);
    assert_eq!(chunk_starts(&frames), vec![0, 8, 16]);
    // The chunk at 16 was refused and its refusal lost; the device measured all it took.
    let starved = status(ControllerState::Running, 16, 8, 16);
    s.on_settled_status(&starved, seq);
    assert_eq!(s.on_status(&starved, t0).unwrap(), vec![]);
    let (again, _) = drain(&mut s, seq);
    assert_eq!(chunk_starts(&again), vec![16]);
    // A status that overtook the Acks of chunks the device still works through: no rewind.
    let mut s = PlanStream::new(&p, 0, LinkTiming::default(), t0).unwrap();
    s.on_credit(0, 24, t0);
    let (_, seq) = drain(&mut s, 0);
    s.on_settled_status(&status(ControllerState::Running, 8, 16, 3), seq);
    assert_eq!(drain(&mut s, seq).0, vec![]);
}

/// A device that heard nothing from us for `HOST_SILENT_US` holds the scan in Paused; once we
/// hear it again we resume it (we never pause a scan ourselves). A buffer-full pause resumes by
/// itself as our acknowledgements free it, so it gets no Resume.
#[test]
fn a_scan_held_for_host_silence_is_resumed_when_we_hear_it() {
    let p = plan(24);
    let t0 = Instant::now();
    let mut s = PlanStream::new(&p, 0, LinkTiming::default(), t0).unwrap();
    // Before our Start, a paused device is not ours to resume.
    assert_eq!(
        s.on_status(&status(ControllerState::Paused, 0, 24, 0), t0).unwrap(),
        vec![]
    );
    s.on_credit(0, 24, t0);
    drain(&mut s, 0);
    let held = status(ControllerState::Paused, 24, 0, 5);
    assert_eq!(s.on_status(&held, t0).unwrap(), vec![HostMsg::Resume]);
    let full = Status {
        unacked: gonio_firmware::capacity::MEASUREMENT_CAPACITY as u16,
        ..held
    };
    assert_eq!(s.on_status(&full, t0).unwrap(), vec![]);
}
