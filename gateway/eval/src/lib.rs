//! vlnav-eval: the evaluation harness. It runs the paper's scenarios as
//! missions through the real services (lockstep simulation, gRPC end to end)
//! and reports the paper's metrics beside the paper's numbers.
//!
//! - [`metrics`]: per-trial definitions (success, drift, collisions);
//! - [`aggregate`]: one summary per (scenario, mode);
//! - [`report`]: Markdown and CSV tables with the paper's figures;
//! - [`plot`]: top-down SVG trajectory plots;
//! - [`suite`]: the scenario suite manifest and the trial plan;
//! - [`seed`]: reproducible per-trial seeds;
//! - [`paper`]: the paper's Tables IV and V.

pub mod aggregate;
pub mod metrics;
pub mod paper;
pub mod plot;
pub mod report;
pub mod seed;
pub mod suite;
