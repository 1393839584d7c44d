//! RVL, the robot link's lossless depth codec (`vlnav_geometry::rvl`), on
//! rendered 640×480 depth of the `demo` and `lab` scenarios: encode and
//! decode time, and the compressed size against the raw 614,400 bytes
//! (printed once per scenario).

use criterion::{Criterion, criterion_group, criterion_main};
use vlnav_geometry::rvl;
use vlnav_sim::{Frame, Simulator, Twist, load_scenario};

fn bench(c: &mut Criterion) {
    for scenario in ["demo", "lab"] {
        let world = load_scenario(scenario).expect("shipped scenario");
        let mut sim = Simulator::new(world, 1);
        let mut frame = Frame::default();
        // A few frames along a drive, so holes and edges vary.
        let mut sizes = Vec::new();
        for k in 0..20 {
            sim.step(Twist::new(0.4, if k < 10 { 0.3 } else { -0.3 }), 0.1);
            sim.render_into(&mut frame);
            sizes.push(rvl::encode(&frame.depth_mm).len());
        }
        let raw = frame.depth_mm.len() * 2;
        let mean = sizes.iter().sum::<usize>() as f64 / sizes.len() as f64;
        println!(
            "{scenario}: RVL {:.0} bytes a frame on average against {raw} raw ({:.1} %), {}x{}",
            mean,
            100.0 * mean / raw as f64,
            frame.width,
            frame.height
        );
        let packed = rvl::encode(&frame.depth_mm);
        let pixels = frame.depth_mm.len();
        c.bench_function(&format!("{scenario}/rvl-encode/640x480"), |b| b.iter(|| rvl::encode(&frame.depth_mm).len()));
        c.bench_function(&format!("{scenario}/rvl-decode/640x480"), |b| {
            b.iter(|| rvl::decode_le_bytes(&packed, pixels).expect("own stream").len())
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
