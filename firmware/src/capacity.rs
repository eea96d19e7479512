//! Every buffer capacity of the firmware, in one place (sizes in `docs/firmware.md`).

/// Plan directions accepted ahead of the one being measured. At ~1 s per direction this is minutes
/// of work, so the host's refills are never on the critical path; a plan of any length streams
/// through it under `Credit` flow control.
pub const PLAN_CAPACITY: usize = 512;

/// Measurements kept until the host acknowledges them. When full, the controller pauses before the
/// next direction (it never drops one); 128 readings is two minutes of scanning at ~1 s each, far
/// more than any sane acknowledgement latency.
pub const MEASUREMENT_CAPACITY: usize = 128;

/// Encoded frames waiting for the binary to write them to USB/UART. Holds ten worst-case frames.
pub const OUTBOX_BYTES: usize = 2048;

/// Segments queued per axis between the controller loop and the axis's compare channel. A ramp
/// segment covers ~1 ms or more and a cruise is one segment, so 16 keep a channel fed well past
/// the loop's lookahead (`timed::LOOKAHEAD_US`).
pub const SEGMENT_RING: usize = 16;
