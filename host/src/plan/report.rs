//! The accuracy-vs-time report.
