//! vlnav's simulated world and Clearpath Husky A200 with a RealSense D455.
//!
//! - [`scenario`]: TOML scenario files, validated into a [`World`] (errors name the field);
//! - [`robot`]: skid-steer kinematics, velocity/acceleration limits, wheel slip;
//! - [`camera_config`]: the D455's intrinsics, mount and depth errors;
//! - [`camera`]: the D455 model and an exact column ray caster for the 2.5-D
//!   world — RGB, depth (u16 mm) and instance labels;
//! - [`crowd`]: walking people (social force), who step aside for the robot;
//! - [`sim`]: the [`Simulator`] — steps physics, renders, keeps ground truth
//!   (pose, path length, hard/soft collision events) apart from odometry.
//!
//! Pure Rust, no gRPC: the edge agent's `sim` driver wraps it.

pub mod camera;
pub mod camera_config;
pub mod crowd;
pub mod geometry;
pub mod robot;
pub mod scenario;
pub mod sim;
pub mod world;

pub use camera::{CameraConfig, Frame};
pub use geometry::{Pose2, Vec2};
pub use robot::{HuskyParams, SlipModel, Twist};
pub use scenario::ScenarioError;
pub use sim::{Odometry, Simulator, Truth};
pub use world::{Entity, Semantic, World};

/// The scenarios shipped with the crate (`scenarios/<name>.toml`).
pub const SHIPPED: &[(&str, &str)] =
    &[("demo", include_str!("../scenarios/demo.toml")), ("lab", include_str!("../scenarios/lab.toml"))];

/// Loads a shipped scenario by name (`demo`, `lab`) or, if the argument names
/// an existing file or ends in `.toml`, a scenario file.
pub fn load_scenario(name_or_path: &str) -> Result<World, ScenarioError> {
    if let Some((_, text)) = SHIPPED.iter().find(|(n, _)| *n == name_or_path) {
        return scenario::parse(text);
    }
    let path = std::path::Path::new(name_or_path);
    if path.exists() || name_or_path.ends_with(".toml") {
        let text = std::fs::read_to_string(path)
            .map_err(|e| ScenarioError::Io { path: name_or_path.to_string(), message: e.to_string() })?;
        return scenario::parse(&text);
    }
    Err(ScenarioError::UnknownName {
        name: name_or_path.to_string(),
        known: SHIPPED.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", "),
    })
}
