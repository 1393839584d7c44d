//! Trace-based latency profiling for vlnav.
//!
//! - [`receiver`]: an OTLP/gRPC trace receiver (the official
//!   `opentelemetry-proto` service definitions) that keeps spans in a
//!   [`SpanStore`] — in memory and appended to one JSON-lines file per trace
//!   under a data directory, readable by another process;
//! - [`jaeger`]: the same spans from Jaeger's query API (in a cluster);
//! - [`profile`]: pure analysis — per-stage count and p50/p95/p99, and the
//!   critical path of every control cycle (frame in → command out);
//! - [`cli`]: `vlnav profile <mission-id>` ([`ProfileArgs`], [`run_profile`]).

pub mod cli;
pub mod jaeger;
pub mod otlp;
pub mod profile;
pub mod receiver;
pub mod span;
pub mod store;

pub use cli::{DEFAULT_SPANS_DIR, ProfileArgs, SpanSource, run_profile};
pub use profile::{CONTROL_CYCLE, ControlLoopProfile, Profile, StageStats, control_loop_of, profile};
pub use receiver::{OtlpReceiver, serve_receiver, serve_receiver_with};
pub use span::{AttrValue, Span, SpanKind, SpanStatus};
pub use store::{SpanStore, StoreError};
