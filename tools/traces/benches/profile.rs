//! Cost of profiling a long mission's trace: stage statistics and the
//! critical path of every control cycle.

use criterion::{Criterion, criterion_group, criterion_main};
use vlnav_traces::{CONTROL_CYCLE, Span, SpanKind, SpanStatus, profile};

/// A mission of `cycles` control cycles, each with the stage calls the
/// gateway makes per frame (detect, segment and reid in parallel, then
/// subgoal and local-plan), client and server span per call.
fn mission(cycles: u64) -> Vec<Span> {
    let mut spans = Vec::new();
    let mut next = 1u64;
    let mut span = |parent: Option<u64>, name: &str, service: &str, start: u64, end: u64| {
        let id = next;
        next += 1;
        spans.push(Span {
            trace_id: "4bf92f3577b34da6a3ce929d0e0e4736".into(),
            span_id: format!("{id:016x}"),
            parent_id: parent.map(|p| format!("{p:016x}")),
            name: name.into(),
            service: service.into(),
            kind: SpanKind::Internal,
            start_ns: start,
            end_ns: end,
            attributes: Default::default(),
            status: SpanStatus::Unset,
        });
        id
    };
    const MS: u64 = 1_000_000;
    let root = span(None, "mission", "vlnav-gateway", 0, cycles * 200 * MS);
    for c in 0..cycles {
        let t = c * 200 * MS;
        let jitter = (c * 7919 % 13) * MS / 4;
        let cycle = span(Some(root), CONTROL_CYCLE, "vlnav-gateway", t, t + 120 * MS + jitter);
        for (name, svc, a, b) in [
            ("detect", "vlnav-detector", 2, 40),
            ("segment", "vlnav-segmenter", 2, 45),
            ("reid", "vlnav-reid", 2, 30),
            ("subgoal", "vlnav-subgoal", 46, 50),
            ("local-plan", "vlnav-local-planner", 51, 110),
        ] {
            let client = span(Some(cycle), name, "vlnav-gateway", t + a * MS, t + b * MS + jitter);
            span(Some(client), name, svc, t + a * MS + MS / 10, t + b * MS + jitter - MS / 10);
        }
    }
    spans
}

fn bench(c: &mut Criterion) {
    for cycles in [100u64, 1000] {
        let spans = mission(cycles);
        c.bench_function(&format!("profile {} spans ({cycles} cycles)", spans.len()), |b| {
            b.iter(|| profile("4bf92f3577b34da6a3ce929d0e0e4736", std::hint::black_box(&spans), CONTROL_CYCLE))
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
