//! The `vlnav` command's library: what the command line and the end-to-end
//! tests share.
//!
//! - [`up`]: every stage service and the gateway in one process, each on its
//!   own loopback port and talking real gRPC to the others, plus a simulated
//!   Husky attached through the edge agent (`vlnav up`, `vlnav demo`, the
//!   evaluation's stack);
//! - [`credentials`]: the certificates and tokens of a Kubernetes
//!   deployment (`vlnav credentials k8s`);
//! - [`mission`]: the mission client (`vlnav mission`): submit an
//!   instruction, follow the mission's events, print a summary;
//! - [`replay`]: a mission recording fed through a fresh stack, its commands
//!   compared with the recorded ones (`vlnav replay`).

//! - [`bench`]: many simulated robots in real time on one gateway
//!   (`vlnav bench fleet`).

pub mod bench;
pub mod credentials;
pub mod mission;
pub mod replay;
pub mod up;

/// The paper's Case 2 instruction (docs/design.md §2).
pub const CASE_2: &str = "Buddy take left turn, move 4 m ahead, then find the standing person to reach close to it, \
In your right you may see the visitor chair follow it. Finally go at spot where bicycle is standing.";
