//! What keeping the seen grid and searching the frontier
//! (`--local-planner-frontier`, `control/frontier.rs`) adds to one robot's
//! planning step: the same turn in place in a 20 m hall with 8 pillars,
//! one 87° frame of 1° rays every 0.1 s of sensor time, with it off and on.
//!
//! `cargo bench -p vlnav-local-planner --bench frontier`

use std::f64::consts::PI;
use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::Vector2;
use vlnav_geometry::{GoalSpec, Pose2};
use vlnav_local_planner::cloud::{ObstacleCloud, SeenRange};
use vlnav_local_planner::control::{FollowParams, RobotState, StepInput, View};
use vlnav_local_planner::planner::{Planner, PlannerParams};

/// What a camera at the origin facing `yaw` (`odom`) sees of a square hall
/// of half-side 10 m with round pillars (0.3 m) on a 6 m grid, in the
/// robot's `base_link` (the robot at the origin facing `yaw`).
fn frame(yaw: f64) -> SeenRange {
    let pillars: Vec<Vector2<f64>> = [-6.0, 0.0, 6.0]
        .iter()
        .flat_map(|&x| [-6.0, 6.0].map(move |y| Vector2::new(x, y)))
        .chain([Vector2::new(6.0, 0.0), Vector2::new(-6.0, 0.0)])
        .collect();
    let mut s = SeenRange::new(Vector2::zeros());
    for i in -43..=43 {
        let b = f64::from(i) * PI / 180.0;
        let dir = Vector2::new((yaw + b).cos(), (yaw + b).sin());
        let mut reach = 10.0 / dir.x.abs().max(dir.y.abs());
        for c in &pillars {
            let along = dir.dot(c);
            let disc = along * along - c.norm_squared() + 0.09;
            if disc >= 0.0 && along - disc.sqrt() > 0.0 {
                reach = reach.min(along - disc.sqrt());
            }
        }
        let p = Vector2::new(b.cos(), b.sin()) * reach;
        s.record_obstacle(p.x, p.y);
    }
    s
}

fn step(c: &mut Criterion) {
    let planner = Planner::new(PlannerParams::default());
    let view = View { yaw: 0.0, half_fov: 0.76, floor_from_m: 0.5, camera_x_m: 0.0, camera_z_m: 0.0 };
    let mut group = c.benchmark_group("robot_step_turning");
    group.sample_size(20);
    for (name, frontier) in [("frontier_off", false), ("frontier_on", true)] {
        let p = FollowParams { frontier, ..FollowParams::default() };
        let mut state = RobotState::default();
        let mut k = 0u32;
        group.bench_function(name, |b| {
            b.iter(|| {
                // A frame every 0.1 s, the robot turning 0.05 rad a frame.
                k += 1;
                let yaw = f64::from(k % 126) * 0.05;
                let cloud = ObstacleCloud { seen: Some(frame(yaw)), ..ObstacleCloud::default() };
                let input = StepInput {
                    stamp: f64::from(k) * 0.1,
                    pose: Pose2::new(0.0, 0.0, yaw),
                    goal: GoalSpec {
                        pose: Pose2::new(0.0, 0.0, yaw + 1.0),
                        position_tolerance: 0.3,
                        yaw_tolerance: 0.2,
                        rotation_only: true,
                        landmark: None,
                    },
                    cloud: &cloud,
                    max_speed: 0.0,
                    view,
                };
                black_box(state.step(&planner, &p, input))
            })
        });
    }
    group.finish();
}

criterion_group!(benches, step);
criterion_main!(benches);
