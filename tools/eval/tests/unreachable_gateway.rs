//! With no gateway listening, every trial ends as an `error` record that says
//! why, and the run still writes its tables: a dead dependency never hangs
//! the harness or loses the trials that were asked for.

use vlnav_eval::metrics::Outcome;
use vlnav_eval::{EvalArgs, run_eval};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn trials_against_a_dead_gateway_are_errors_with_a_reason() {
    // A port nobody listens on: bind one, then free it.
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let out = tempfile::tempdir().unwrap();
    let args = EvalArgs {
        suite: std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/suite.toml"),
        trials: Some(2),
        scenarios: vec!["lab".into(), "corridor".into()],
        modes: vec![vlnav_eval::metrics::Mode::Hybrid],
        out: out.path().to_path_buf(),
        stall_timeout_s: 1.0,
        no_progress: true,
        ..EvalArgs::default()
    };
    let report = run_eval(args, vlnav_eval::Target::plaintext(format!("http://127.0.0.1:{port}"))).await.unwrap();
    assert_eq!(report.trials_run, 4);
    assert_eq!(report.records.len(), 4);
    for r in &report.records {
        assert_eq!(r.outcome, Outcome::Error, "{r:?}");
        assert!(r.reason.contains("did not attach"), "{}", r.reason);
        assert!(!r.success());
    }
    assert_eq!(report.summaries.len(), 2);
    assert!(report.summaries.iter().all(|s| s.trials == 2 && s.successes == 0 && s.failures.get("error") == Some(&2)));
    for f in ["report.md", "summary.csv", "trials.csv"] {
        assert!(out.path().join(f).is_file(), "{f} not written");
    }
    // Layout plots of the selected scenarios (2 instructions each are drawn).
    let layouts: Vec<_> = report.plots.iter().filter(|p| p.to_string_lossy().contains("layout-")).collect();
    assert_eq!(layouts.len(), 2 + 3, "lab has 2 instructions, corridor 3");
    assert!(report.markdown.contains("Indoor lab"));
}
