//! vlnav-geometry: the geometry and sensor types every service shares, so
//! that no service crate depends on another.
//!
//! - [`pose`]: the planar pose [`Pose2`] and its composition, the one angle
//!   wrap [`wrap_angle`], the goal [`GoalSpec`], the body velocity [`Twist`];
//! - [`camera`]: the RGB-D camera model (pinhole, mount) and the
//!   [`Projector`](camera::Projector) from pixels with depth to `base_link`
//!   and back;
//! - [`depth`]: depth images on the wire ([`DepthView`](depth::DepthView));
//! - [`rgb`]: the one RGB decoder (RGB8, PNG, JPEG; size-capped; run off the
//!   async threads);
//! - [`convert`]: proto ↔ domain for all of the above, field by field, with
//!   errors that name the field (the only module that knows `vlnav-proto`).
//!
//! Frames and units follow REP-103/105 (x forward, y left, z up; `odom`,
//! `base_link`), SI throughout.

pub mod camera;
pub mod convert;
pub mod depth;
pub mod disparity;
pub mod pose;
pub mod rgb;
pub mod rvl;

pub use pose::{GoalSpec, Pose2, Twist, wrap_angle};
