//! What can go wrong on the link, for every layer of it.

use gonio_shared::msg::{Fault, HandshakeError, RefuseReason};

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
    /// The measurement sink (the journal) could not take or sync a reading.
    #[error("{0}")]
    Sink(String),
    /// More directions than the wire's `u32` plan indices can number.
    #[error("the plan has {0} directions, more than the wire can number")]
    PlanTooLong(usize),
    /// A message that does not fit a frame (a host bug, never the device's).
    #[error("{0}")]
    Encode(String),
    /// The device measured a direction the plan does not have.
    #[error("device measured index {index} of a {total}-direction plan")]
    OutOfPlan { index: u32, total: u32 },
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
