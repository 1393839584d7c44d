//! The robot link's depth codecs on rendered 640×480 depth (the D455's
//! noise) of the `demo` and `lab` scenarios: RVL, lossless
//! (`vlnav_geometry::rvl`), and quantised disparity with a bounded error
//! (`vlnav_geometry::disparity`) at the D455's own noise step and twice it.
//! Encode and decode time, and the compressed size against the raw 614,400
//! bytes (printed once per scenario).

use criterion::{Criterion, criterion_group, criterion_main};
use vlnav_geometry::{disparity, rvl};
use vlnav_sim::{Frame, Simulator, Twist, load_scenario};

fn bench(c: &mut Criterion) {
    for scenario in ["demo", "lab"] {
        let world = load_scenario(scenario).expect("shipped scenario");
        let mut sim = Simulator::new(world, 1);
        let mut frame = Frame::default();
        // A few frames along a drive, so holes and edges vary.
        let steps = [disparity::D455_STEP_PER_M, 2.0 * disparity::D455_STEP_PER_M];
        let mut sizes = Vec::new();
        let mut quantised = vec![Vec::new(); steps.len()];
        for k in 0..20 {
            sim.step(Twist::new(0.4, if k < 10 { 0.3 } else { -0.3 }), 0.1);
            sim.render_into(&mut frame);
            sizes.push(rvl::encode(&frame.depth_mm).len());
            for (s, step) in steps.iter().enumerate() {
                let w = frame.width as usize;
                quantised[s].push(disparity::encode(&frame.depth_mm, w, *step).expect("valid step").len());
            }
        }
        let raw = frame.depth_mm.len() * 2;
        let mean = |sizes: &[usize]| sizes.iter().sum::<usize>() as f64 / sizes.len() as f64;
        let mbit = |bytes: f64| bytes * 8.0 * 10.0 / 1e6;
        println!(
            "{scenario}: {}x{}, raw {raw} bytes; RVL {:.0} bytes a frame on average ({:.1} %, {:.1} Mbit/s at 10 Hz)",
            frame.width,
            frame.height,
            mean(&sizes),
            100.0 * mean(&sizes) / raw as f64,
            mbit(mean(&sizes)),
        );
        for (step, sizes) in steps.iter().zip(&quantised) {
            println!(
                "{scenario}: disparity step {step} m⁻¹: {:.0} bytes ({:.1} %, {:.1} Mbit/s at 10 Hz)",
                mean(sizes),
                100.0 * mean(sizes) / raw as f64,
                mbit(mean(sizes)),
            );
        }
        let packed = rvl::encode(&frame.depth_mm);
        let pixels = frame.depth_mm.len();
        c.bench_function(&format!("{scenario}/rvl-encode/640x480"), |b| b.iter(|| rvl::encode(&frame.depth_mm).len()));
        c.bench_function(&format!("{scenario}/rvl-decode/640x480"), |b| {
            b.iter(|| rvl::decode_le_bytes(&packed, pixels).expect("own stream").len())
        });
        let (w, h, step) = (frame.width as usize, frame.height as usize, disparity::D455_STEP_PER_M);
        let packed = disparity::encode(&frame.depth_mm, w, step).expect("valid step");
        c.bench_function(&format!("{scenario}/disparity-encode/640x480"), |b| {
            b.iter(|| disparity::encode(&frame.depth_mm, w, step).expect("valid step").len())
        });
        c.bench_function(&format!("{scenario}/disparity-decode/640x480"), |b| {
            b.iter(|| disparity::decode_le_bytes(&packed, w, h, step).expect("own stream").len())
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
