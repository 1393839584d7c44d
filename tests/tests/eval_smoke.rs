//! `vlnav eval` in small: one trial of two scenarios through the real
//! services (all-in-one stack, lockstep simulated robots over gRPC). Checks
//! that the metrics are computed and the report written — not that they are
//! good — and that the same seed gives the same table.

use vlnav_e2e::TestStack;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_small_evaluation_runs_through_the_real_services() {
    let t = TestStack::start(|a| {
        a.no_robot = true;
        a.perception = vlnav_eval::PerceptionMode::Realistic;
    })
    .await;
    let out = tempfile::tempdir().unwrap();
    let again = tempfile::tempdir().unwrap();
    let args = vlnav_eval::EvalArgs {
        suite: std::path::PathBuf::from(vlnav_eval::DEFAULT_SUITE),
        trials: Some(1),
        seed: 7,
        only_trials: Vec::new(),
        scenarios: vec!["corridor".into(), "lab".into()],
        modes: vec![vlnav_eval::metrics::Mode::Hybrid],
        out: out.path().to_path_buf(),
        jobs: 2,
        width: None,
        height: None,
        frame_rate: 5.0,
        plots: 1,
        stall_timeout_s: 120.0,
        no_progress: true,
        perception: vlnav_eval::PerceptionMode::Realistic,
        beside: None,
        ..vlnav_eval::EvalArgs::default()
    };
    let rerun = vlnav_eval::EvalArgs { out: again.path().to_path_buf(), jobs: 1, ..args.clone() };
    let report = vlnav_eval::run_eval(args, t.eval_target()).await.expect("the evaluation runs");
    assert_eq!(report.records.len(), 2, "one trial per scenario");
    for r in &report.records {
        assert!(r.frames > 0, "{}: the robot ran", r.scenario);
        assert!(
            r.duration_s > 0.0 && r.path_length_m >= 0.0 && r.stop_error_m() >= 0.0 && r.final_error_m().is_finite()
        );
    }
    for f in ["report.md", "summary.csv", "trials.csv"] {
        let text = std::fs::read_to_string(out.path().join(f)).unwrap();
        assert!(text.contains("corridor") || text.contains("Corridor"), "{f} lists the scenario");
    }
    // Determinism: the same seed, run again (one trial at a time this
    // time), gives the same per-trial records and the same table.
    let second = vlnav_eval::run_eval(rerun, t.eval_target()).await.expect("the evaluation runs again");
    assert_eq!(second.trials_csv, report.trials_csv, "the same seed gives the same trials");
    assert_eq!(second.markdown, report.markdown, "the same seed gives the same table");
    t.stack.shutdown().await.unwrap();
}
