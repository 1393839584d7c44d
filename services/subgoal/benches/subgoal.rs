//! Subgoal estimation costs: box median depth on a 640×480 frame, fusion
//! updates, and the MOVE formula.
//!
//! `cargo bench -p vlnav-subgoal --bench subgoal`

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Vector3, vector};
use std::hint::black_box;
use vlnav_geometry::Pose2;
use vlnav_geometry::camera::{Camera, Intrinsics, Mount};
use vlnav_geometry::depth::{DepthView, encode_depth_mm};
use vlnav_subgoal::fusion::{FixedParams, FixedTarget, MovingParams, MovingTarget};
use vlnav_subgoal::geometry::{BoxDepthParams, MoveParams, PixelBox, box_depth, move_goal, target_in_odom};

fn bench(c: &mut Criterion) {
    let cam = Camera {
        width: 640,
        height: 480,
        intrinsics: Intrinsics { fx: 388.6187, fy: 388.6187, cx: 320.6609, cy: 239.7847 },
        mount: Mount { translation: vector![0.3, 0.0, 0.5], ..Mount::default() },
        depth_min_m: 0.5,
        depth_max_m: 10.0,
    };
    let depth: Vec<f64> = (0..640 * 480).map(|i| 2.0 + 0.001 * (i % 97) as f64).collect();
    let bytes = encode_depth_mm(&depth);
    let view = DepthView::new(640, 480, &bytes).unwrap();
    let robot = Pose2::new(1.0, 2.0, 0.3);
    for (name, b) in [
        ("target_box_120px", PixelBox { x_min: 260.0, y_min: 180.0, x_max: 380.0, y_max: 300.0 }),
        ("target_box_full_frame", PixelBox { x_min: 0.0, y_min: 0.0, x_max: 640.0, y_max: 480.0 }),
    ] {
        c.bench_function(name, |bch| {
            bch.iter(|| {
                let z = box_depth(black_box(&view), &b, &cam, &BoxDepthParams::default()).unwrap();
                black_box(target_in_odom(&cam, &b, z.depth_m, &robot))
            })
        });
    }
    c.bench_function("fixed_fusion_add_window30", |bch| {
        let mut f = FixedTarget::new(FixedParams::default());
        let mut i = 0u32;
        bch.iter(|| {
            i = i.wrapping_add(1);
            black_box(f.add(Vector3::new(3.0 + 0.01 * (i % 7) as f64, 1.0, 0.5)))
        })
    });
    c.bench_function("moving_kalman_add", |bch| {
        let mut f = MovingTarget::new(MovingParams::default());
        let mut t = 0.0;
        bch.iter(|| {
            t += 0.2;
            black_box(f.add(Vector3::new(2.0 + 0.1 * t, 1.0, 1.0), t, 3.0))
        })
    });
    c.bench_function("move_goal", |bch| {
        bch.iter(|| black_box(move_goal(black_box(robot), 4.0, 1.57, 1.0, &MoveParams::default())))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
