//! A seeded regression subset of generated worlds (`vlnav worlds generate`):
//! three development worlds of different families, one hybrid trial each,
//! through the real services. Checks that generated worlds run end to end
//! and that the report gains its per-family section; the figures themselves
//! are measured on the test set (docs/eval/generated/).

use vlnav_e2e::TestStack;
use vlnav_eval::worlds::{Family, dev_set, generate_set};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn generated_worlds_run_through_the_real_services() {
    let worlds = tempfile::tempdir().unwrap();
    let mut which = Vec::new();
    for f in [Family::Corridor, Family::Home, Family::Warehouse] {
        which.extend(dev_set(f, 1, 7).unwrap());
    }
    let rep = generate_set(&which, worlds.path(), "regression subset").unwrap();
    assert!(rep.worlds_written >= 2, "{rep:?}");

    let t = TestStack::start(|a| {
        a.no_robot = true;
        a.perception = vlnav_eval::PerceptionMode::Realistic;
    })
    .await;
    let out = tempfile::tempdir().unwrap();
    let args = vlnav_eval::EvalArgs {
        suite: rep.suite.clone(),
        trials: Some(1),
        seed: 3,
        modes: vec![vlnav_eval::metrics::Mode::Hybrid],
        out: out.path().to_path_buf(),
        jobs: 3,
        plots: 0,
        stall_timeout_s: 120.0,
        no_progress: true,
        ..vlnav_eval::EvalArgs::default()
    };
    let report = vlnav_eval::run_eval(args, t.eval_target()).await.expect("the evaluation runs");
    assert_eq!(report.records.len(), rep.worlds_written, "one hybrid trial per world");
    for r in &report.records {
        assert!(r.frames > 0, "{}: the robot ran", r.scenario);
        assert_ne!(r.outcome, vlnav_eval::metrics::Outcome::Error, "{}: {}", r.scenario, r.reason);
    }
    assert!(report.markdown.contains("## Generated worlds — per family"), "{}", report.markdown);
    assert!(report.markdown.contains("| **overall** | all |"), "{}", report.markdown);
    t.stack.shutdown().await.unwrap();
}
