//! A mission's metrics.

use super::*;

#[test]
fn metrics_come_from_frame_stamps_and_ground_truth() {
    let mut m = MetricsAcc::default();
    let truth = |x: f64, len: f64, soft: u32| Truth {
        pose: Some(Pose2::new(x, 0.0, 0.0)),
        path_length_m: len,
        hard_collisions: 0,
        soft_collisions: soft,
        odom_origin: Some(Pose2::default()),
    };
    m.observe(10.0, &Pose2::new(0.0, 0.0, 0.0), Some(&truth(0.0, 5.0, 1)));
    m.observe(10.1, &Pose2::new(0.3, 0.4, 0.0), Some(&truth(0.5, 5.5, 1)));
    m.observe(12.0, &Pose2::new(0.3, 1.4, 0.0), Some(&truth(0.6, 6.6, 2)));
    let p = m.metrics(2, 3, 1, Some(&Pose2::new(1.0, 0.0, 0.0)));
    assert!((p.duration_s - 2.0).abs() < 1e-9);
    assert!((p.odom_path_length_m - 1.5).abs() < 1e-9);
    assert_eq!(p.frames, 3);
    assert!(p.has_ground_truth);
    assert!((p.true_path_length_m - 1.6).abs() < 1e-9);
    assert_eq!(p.soft_collisions, 1);
    assert!((p.final_error_m - 0.4).abs() < 1e-9);
}
