//! `gonio plan`.
