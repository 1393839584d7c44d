//! Cost of one simulated frame: physics step (0.1 s at 10 Hz) plus render, at
//! 640×480 and 320×240, in the `demo` and `lab` scenarios.

use criterion::{Criterion, criterion_group, criterion_main};
use vlnav_sim::{Frame, Simulator, Twist, load_scenario};

fn bench(c: &mut Criterion) {
    for scenario in ["demo", "lab"] {
        for (w, h) in [(640u32, 480u32), (320, 240)] {
            let world = load_scenario(scenario).expect("shipped scenario");
            let mut sim = Simulator::new(world, 1);
            sim.set_camera(sim.camera().clone().with_resolution(w, h).expect("resolution"));
            let mut frame = Frame::default();
            let mut k = 0u64;
            c.bench_function(&format!("{scenario}/step+render/{w}x{h}"), |b| {
                b.iter(|| {
                    // Drive in a slow circle so the view changes every frame.
                    k += 1;
                    let cmd = if (k / 50).is_multiple_of(2) { Twist::new(0.3, 0.4) } else { Twist::new(-0.3, -0.4) };
                    sim.step(cmd, 0.1);
                    sim.render_into(&mut frame);
                    frame.depth_mm[0]
                })
            });
            c.bench_function(&format!("{scenario}/step/{w}x{h}"), |b| {
                b.iter(|| {
                    sim.step(Twist::new(0.2, 0.3), 0.1);
                    sim.truth().pose.x
                })
            });
        }
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
