//! The serial link to a gonio, in layers (after Klipper's serialqueue / serialhdl / mcu split):
//!
//! - [`transport`]: the byte pipe (a serial port; a seeded fault injector around any pipe);
//! - [`reliable`]: frames with sequence numbers, the send window, ACK/NAK and retransmission;
//! - [`client`]: the typed requests (handshake, status, configure, home) and the scan driver;
//! - [`stream`]: plan streaming as a state machine without a transport;
//! - [`run`]: [`run_plan`], the one call a scan makes (journal, reconnects, progress);
//! - [`connection`]: the body `gonio measure` and `gonio scan` share; [`write_csv`].

pub mod client;
pub mod connection;
pub mod error;
mod measurements_csv;
pub mod reliable;
pub mod run;
pub mod stream;
pub mod transport;

use gonio_shared::kinematics::Kinematics;
use gonio_shared::msg::Direction;

pub use client::{Link, MeasurementSink};
pub use connection::{check_journal_state, run_options, Connection, MeasureError, Measured};
pub use error::LinkError;
pub use measurements_csv::write_csv;
pub use reliable::{LinkStats, LinkTiming};
pub use run::{
    run_plan, run_plan_below, Progress, Quiet, Reconnect, ReopenFaulty, ReopenPath, RunError, RunOptions, RunSummary,
};
pub use transport::{FaultConfig, FaultCounts, FaultyTransport, SerialTransport, SharedFaultCounts, Transport};

/// The journal's key for a plan: FNV-1a 64 of its canonical plan-file encoding, so `gonio measure`
/// (from a file) and a scan (from directions in memory) journal the same plan the same way.
pub fn plan_hash(directions: &[Direction]) -> Result<u64, crate::plan::file::PlanFileError> {
    Ok(crate::journal::fnv64(&crate::plan::file::encode_plan(directions)?))
}

/// The direction pair a reading was really taken at: forward kinematics of its step positions,
/// `(theta_i, phi_i, theta_o, phi_o)` in radians. On an isotropic instrument the azimuth stage
/// stays put, so both phis may differ from the requested ones by a common rotation; their
/// difference is what was measured.
pub fn reached(kin: &Kinematics<f64>, steps: &[i32; 4]) -> [f64; 4] {
    let (wi, wo) = kin.forward(&kin.from_steps(steps));
    let (ti, pi) = angles(wi);
    let (to, po) = angles(wo);
    [ti, pi, to, po]
}

/// (theta, phi) in radians of a local direction.
fn angles(v: gonio_shared::vec3::Vec3<f64>) -> (f64, f64) {
    (v.z.clamp(-1.0, 1.0).acos(), v.y.atan2(v.x))
}
