//! Every buffer capacity of the firmware, in one place, sized for the STM32F411 (128 KiB RAM; the
//! goal is <= 48 KiB of static RAM for the whole binary, stacks and USB buffers included).
//!
//! | buffer | entry | entries | bytes |
//! |---|---|---|---|
//! | plan ring ([`crate::plan::PlanQueue`]) | 20 B (index + 4 step targets) | 512 | ~10 KiB |
//! | measurements ([`crate::measurements::MeasurementBuffer`]) | 56 B | 128 | ~7 KiB |
//! | outbox ([`crate::link::Link`]) | bytes | 2048 | 2 KiB |

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
