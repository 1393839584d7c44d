//! The harness's own cost, which must stay negligible beside the stack it
//! measures: ground-truth contact checks per frame, and aggregating and
//! rendering the tables of a full run (1050 trials).

use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use vlnav_eval::metrics::{ContactAccount, Mode, Outcome, Point2, Pose, TrialRecord};
use vlnav_eval::report::ScenarioRef;
use vlnav_eval::runner::{contact_at, load_world};
use vlnav_eval::suite::{Suite, plan_trials};

fn suite() -> Suite {
    Suite::load(&std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/suite.toml")).unwrap()
}

fn contact(c: &mut Criterion) {
    let s = suite();
    let lab = load_world(&s.scenario("lab").unwrap().world_path(&s)).unwrap();
    let mut t = 0.0;
    c.bench_function("contact_at lab (one frame)", |b| {
        b.iter(|| {
            t += 0.2;
            let x = 1.0 + (t * 0.37) % 8.0;
            black_box(contact_at(&lab.world, Pose::new(x, 2.75, 0.3), t))
        })
    });
}

fn tables(c: &mut Criterion) {
    let s = suite();
    let specs = plan_trials(&s, 50, 1, &[]);
    let records: Vec<TrialRecord> = specs
        .iter()
        .map(|t| {
            let sc = &s.scenarios[t.scenario];
            let ins = &sc.instructions[t.instruction];
            let k = (t.seed % 1000) as f64 / 1000.0;
            TrialRecord {
                scenario: sc.name.clone(),
                mode: t.mode,
                instruction: ins.id.clone(),
                trial: t.trial,
                seed: t.seed,
                outcome: if k < 0.9 { Outcome::Succeeded } else { Outcome::Failed },
                reason: String::new(),
                steps_completed: 3,
                steps_total: 3,
                destination: ins.destination(),
                success_radius_m: ins.radius,
                stop_distance_m: ins.stop_m.unwrap_or(0.0),
                final_position: Point2::new(ins.destination().x + k, ins.destination().y),
                path_length_m: 10.0 + k,
                odom_path_length_m: 10.0,
                duration_s: 30.0,
                frames: 150,
                replans: 0,
                contact: ContactAccount { soft_events: u32::from(k > 0.8), soft_s: k, ..Default::default() },
            }
        })
        .collect();
    let refs = ScenarioRef::from_suite(&s);
    assert_eq!(records.len(), 1050);
    assert!(records.iter().any(|r| r.mode == Mode::Visual));
    c.bench_function("summarise + markdown + csv (1050 trials)", |b| {
        b.iter(|| {
            let sums = vlnav_eval::aggregate::summarise(black_box(&records));
            let md = vlnav_eval::report::markdown(&refs, &sums, 1, 50, "realistic", None);
            let csv = vlnav_eval::report::trials_csv(&records).unwrap();
            black_box((md, csv))
        })
    });
}

criterion_group!(benches, contact, tables);
criterion_main!(benches);
