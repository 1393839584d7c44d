//! The plan cycle against cloud size: downsampling + blocked paths + cost J
//! over all 343 paths × 9 rotations, with the lookup table and with the
//! brute-force reference (direct point-to-path distances) in the same run.
//!
//! `cargo bench -p vlnav-local-planner --bench plan_cycle`

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use nalgebra::Vector2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;
use vlnav_local_planner::cloud::{CloudBuilder, CloudParams};
use vlnav_local_planner::planner::{Method, Planner, PlannerParams, Scratch};

/// A cluttered scene as a depth camera returns it: 40 % floor, the rest on
/// the faces of a few boxes and a wall, all within the camera's view.
fn scene(n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let boxes =
        [([1.8, 0.3], [2.3, 0.9]), ([2.8, -1.4], [3.2, -0.8]), ([3.9, -2.5], [4.0, 0.2]), ([1.2, -0.9], [1.35, -0.75])];
    (0..n)
        .map(|_| {
            if rng.random_bool(0.4) {
                let x = rng.random_range(0.5..4.2);
                let y = rng.random_range(-0.9 * x..0.9 * x);
                [x, y, rng.random_range(-0.02..0.03)]
            } else {
                let (lo, hi) = boxes[rng.random_range(0..boxes.len())];
                let z = rng.random_range(0.0..1.0);
                // A point on the face looking at the robot or on a side face.
                if rng.random_bool(0.6) {
                    [lo[0], rng.random_range(lo[1]..hi[1]), z]
                } else {
                    let y = if rng.random_bool(0.5) { lo[1] } else { hi[1] };
                    [rng.random_range(lo[0]..hi[0]), y, z]
                }
            }
        })
        .collect()
}

fn plan_cycle(c: &mut Criterion) {
    let planner = Planner::new(PlannerParams::default());
    let goal = Vector2::new(6.0, 0.5);
    let mut group = c.benchmark_group("plan_cycle");
    group.sample_size(20);
    for &n in &[1_000usize, 10_000, 100_000] {
        let points = scene(n, n as u64);
        let mut builder = CloudBuilder::new(CloudParams::default());
        let mut scratch = Scratch::default();
        // Both methods must agree on this scene before timing them.
        let cloud = builder.from_points(&points, &[]);
        let table = planner.plan_with(&cloud, goal, 1.0, 0.0, &mut scratch, Method::Table);
        let brute = planner.plan_with(&cloud, goal, 1.0, 0.0, &mut scratch, Method::BruteForce);
        let pick = |p: &vlnav_local_planner::planner::Plan| p.selection.as_ref().map(|s| (s.path, s.rotation));
        eprintln!(
            "{n} points → {} cells ({} blocking); table: {} free, path {:?}; brute force: {} free, path {:?}",
            cloud.cells.len(),
            cloud.blocking_cells(),
            table.free_paths,
            pick(&table),
            brute.free_paths,
            pick(&brute)
        );
        group.bench_with_input(BenchmarkId::new("table", n), &points, |b, pts| {
            b.iter(|| {
                let cloud = builder.from_points(black_box(pts), &[]);
                black_box(planner.plan_with(&cloud, goal, 1.0, 0.0, &mut scratch, Method::Table))
            })
        });
        group.bench_with_input(BenchmarkId::new("brute_force", n), &points, |b, pts| {
            b.iter(|| {
                let cloud = builder.from_points(black_box(pts), &[]);
                black_box(planner.plan_with(&cloud, goal, 1.0, 0.0, &mut scratch, Method::BruteForce))
            })
        });
    }
    group.finish();
}

fn startup(c: &mut Criterion) {
    let mut group = c.benchmark_group("startup");
    group.sample_size(10);
    group.bench_function("library_and_tables", |b| b.iter(|| black_box(Planner::new(PlannerParams::default()))));
    group.finish();
}

criterion_group!(benches, plan_cycle, startup);
criterion_main!(benches);
