//! The gonio lab: research on top of the `gonio` library (which never depends on it): the
//! trade-off and planner reports, encoder datasets, training and reports, and charts. Its binary
//! is `gonio-lab`.

pub mod encoder;
pub mod plan;
pub mod plot;
