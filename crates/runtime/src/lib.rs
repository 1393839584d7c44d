//! What every vlnav gRPC server shares, and nothing more:
//!
//! - [`server`]: bootstrap — health (`grpc.health.v1`), reflection v1 and
//!   v1alpha, tonic's request timeout, message size limits, per-method
//!   telemetry and graceful shutdown;
//! - [`telemetry`]: tracing + OpenTelemetry (OTLP, W3C trace context);
//! - [`client`]: channels whose requests carry the caller's trace context;
//! - [`transport`]: the HTTP/2 keepalive and flow-control settings the
//!   client and the server share;
//! - [`security`]: TLS settings, certificate identities, bearer tokens and
//!   the development PKI (docs/security.md);
//! - [`authz`]: which certificate identities may call which methods, as a
//!   tower layer every server runs;
//! - [`revocation`]: revoked identities and certificates, refused at the
//!   handshake and their running calls ended;
//! - [`tls`]: rustls settings whose certificates and revocation list are
//!   read again when their files change;
//! - [`actor`]: the request/reply helper every service actor uses;
//! - [`testing`]: a service set served on an ephemeral loopback port, for
//!   integration tests;
//! - [`perception`]: the measured perception error model the simulation
//!   detector and ReID backends draw from.

pub mod actor;
pub mod authz;
pub mod client;
pub mod perception;
pub mod revocation;
pub mod security;
pub mod server;
pub mod telemetry;
pub mod testing;
pub mod tls;
pub mod transport;

pub use authz::CallerPolicy;
pub use server::{ServerConfig, ServiceSet, ports, serve, serve_main, shutdown_signal};
pub use tokio_util::sync::CancellationToken;
