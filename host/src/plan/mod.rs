//! Step 2 of the pipeline: from estimated BRDF parameters to an ordered, timed direction list.

pub mod file;
