//! The vlnav gateway: the public `MissionService`, the `FleetService` edge
//! agents attach to, and one mission-executor actor per robot that runs a
//! validated plan step by step through the pipeline services.
//!
//! Other crates see only [`api::Gateway`], the settings ([`config`]), the
//! token file ([`auth`]) and the frame checks ([`frames`]); every other
//! module is the gateway's own (docs/architecture.md, "The gateway's modules").
//!
//! - [`frames`]: pure checks of what edge agents send (sizes, finiteness, time order),
//!   and the checked frame the rest of the gateway takes;
//! - [`executor`]: the step state machine (MOVE, FIND, FOLLOW, RETURN, exploration,
//!   clarification) driven by sensor frames and their timestamps;
//! - [`pipeline`]: the gRPC clients of the stage services;
//! - [`hub`]: mission records, event logs and watchers, persisted in [`store`];
//! - `link`: a robot's inbound stream, where each frame is checked once;
//! - [`robot`]: the per-robot actor that owns the attach stream and the executor;
//! - [`auth`]: bearer tokens, roles and the tower layer that checks them;
//! - [`limit`]: the per-caller rate limit of mission submissions;
//! - [`viz`]: the live view (Foxglove WebSocket) and every mission's MCAP recording;
//! - [`api`]: the thin tonic layer of MissionService and FleetService.

pub mod api;
pub mod auth;
pub mod config;
pub mod frames;

mod executor;
mod hub;
mod limit;
mod link;
mod pipeline;
mod robot;
mod store;
mod viz;

pub use config::GatewayOptions;
