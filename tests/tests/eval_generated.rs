//! A seeded regression subset of generated worlds (`vlnav worlds generate`):
//! three development worlds of different families, one hybrid trial each,
//! through the real services. Checks that generated worlds run end to end,
//! that the report gains its per-family section, and that each trial ends
//! as pinned in `tests/tests/eval_generated/pinned.tsv` (outcome, steps,
//! frames, where the robot stopped): a change of behaviour shows here as a
//! diff to look at, and is re-pinned on purpose with
//! `VLNAV_BLESS=1 cargo test -p vlnav-e2e --test eval_generated`. The
//! figures themselves are measured on the test set (docs/eval/generated/).

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
    let mut got: Vec<String> = report
        .records
        .iter()
        .map(|r| {
            format!(
                "{}\t{:?}\t{}\t{}/{}\t{}\t{:.2}\t{:.2}",
                r.scenario,
                r.outcome,
                r.success(),
                r.steps_completed,
                r.steps_total,
                r.frames,
                r.final_position.x,
                r.final_position.y
            )
        })
        .collect();
    got.sort();
    let pinned_path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/eval_generated/pinned.tsv");
    let header = "# scenario\toutcome\tsuccess\tsteps\tframes\tfinal x\tfinal y (written by VLNAV_BLESS=1)";
    let text = format!("{header}\n{}\n", got.join("\n"));
    if std::env::var_os("VLNAV_BLESS").is_some() {
        std::fs::create_dir_all(pinned_path.parent().unwrap()).unwrap();
        std::fs::write(&pinned_path, &text).unwrap();
    } else {
        let pinned = std::fs::read_to_string(&pinned_path).unwrap_or_default();
        assert_eq!(
            pinned,
            text,
            "the regression subset no longer ends as pinned in {}; if the change is meant, re-pin with \
             VLNAV_BLESS=1 cargo test -p vlnav-e2e --test eval_generated",
            pinned_path.display()
        );
    }
    assert!(report.markdown.contains("## Generated worlds — per family"), "{}", report.markdown);
    assert!(report.markdown.contains("| **overall** | all |"), "{}", report.markdown);
    t.stack.shutdown().await.unwrap();
}
