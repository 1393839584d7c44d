//! Regression of the evaluation under realistic perception: a small seeded
//! subset through the real services (all-in-one stack with the measured
//! detector and ReID error model and the real colour + depth segmenter,
//! lockstep simulated robots over gRPC), with its per-trial results pinned.
//! A change to perception, control or the metrics that moves any of them
//! shows here; re-pin only for a change that should move them, and say why.

use vlnav_e2e::TestStack;
use vlnav_eval::PerceptionMode;
use vlnav_eval::metrics::Mode;

/// scenario, trial, outcome, success, success at 0.25 m, stopping error (m,
/// 2 decimals), hard contact events, contact events with people (the
/// crossing hall: people walk across the robot's route; its trial 0 goes to
/// a potted plant 12 m beyond the MOVE; it asked, not finding the plant,
/// until the `moved in` test looked 1° plus 5 cm to each side of a cell:
/// since, its search takes another way and finds it).
/// Garage trial 1 ("stop 1.5 m before the motorcycle") went to the bicycle,
/// which the measured detector calls a motorcycle one frame in five, and
/// later ran out of time beside it; since the class vote asks for twice as
/// many sightings as frames of another class, counted over the whole look,
/// and ignores sightings far from the candidate, it reaches the motorcycle
/// (and crossing trial 0 and garage trial 0 stop 1 cm nearer).
/// Crossing trial 1 stops 1 cm farther and symmetric trial 0 1 cm nearer
/// since the footprint guard and the goal shift keep the body out of no-go
/// cells too, and a no-go marking on the floor is remembered until the
/// image shows that floor (services/local-planner/src/control/memory.rs).
/// Garage trial 1 stops 1 cm farther since a turn in place counts
/// remembered cells 5 cm farther out (`memory_drift_m`, same file).
/// Crossing trial 0 stops 2 cm nearer since the robot waits for walking
/// people (services/local-planner/src/people.rs): its way to the plant
/// is no longer the same.
/// Crossing trial 1 stops 3 cm farther and symmetric trials 0 and 1 2 and
/// 1 cm farther since the local planner keeps its obstacle memory from one
/// step of a mission to the next (gateway/src/executor/machine.rs,
/// `StartStep::forget`): the ways to the landmarks, and so the views the
/// target's estimate is fused from, are no longer the same.
/// Crossing trial 0 stops 1 cm nearer, and crossing trial 1 (the 12 m
/// MOVE) 0.10 m farther, since the robot slows to 0.6 m/s near walking
/// people (services/local-planner/src/people.rs, `near_walker_mps`) and
/// the footprint guard sweeps a turn over its braking time
/// (services/local-planner/src/control/guard.rs): it weaves round the people at
/// other places, its odometry ends the MOVE 0.09 m off the commanded
/// 12 m, and the wheels' slip on the turns puts the true end 0.15 m from
/// it.
/// Crossing trials 0 and 1 stop 1 and 2 cm farther, garage trials 0 and 1
/// 1 cm farther and nearer, and symmetric trials 0 and 1 2 cm farther and
/// 1 cm nearer since the segmenter's default point stride is scaled to the
/// frame (services/segmenter/README.md): at the suite's 160 × 120 every
/// pixel of a marking, not one in 16, is a no-go point, so the ways round
/// the markings, and the views the targets are fused from, moved.
/// Crossing trial 0 stops 1 cm farther, crossing trial 1 2 cm nearer,
/// garage trials 0 and 1 1 cm nearer and farther and symmetric trial 0
/// 3 cm nearer since the segmenter places a marking's points where the
/// pixel's ray meets the floor and leaves out the foot of anything
/// standing (services/segmenter/README.md): the markings' cells moved.
/// Garage trial 1 stops 3 cm farther since a look-around that starts more
/// than a scan turn off the route's course turns onto the course first
/// (docs/perception.md): it sees the motorcycle from another heading, and
/// the views its place is fused from moved.
/// Crossing trial 0 stops 1 cm nearer, and crossing trial 1 (the 12 m
/// MOVE) now asks "my way is blocked" 7.1 m short, since the robot slows
/// near people, waits for a person in its way and gives way to them
/// (docs/design.md §4, "People in the way"): it meets the walkers at other
/// places. Over the whole realistic crossing hall (50 trials) success went
/// 62 → 64 %, and on the generated test set 65.9 → 71.7 %. It asks 7.2 m
/// short since the robot keeps behind walkers rather than swerving far off
/// for them (`services/local-planner/src/control/behind.rs`).
/// Crossing trial 1 reaches the end of its 12 m MOVE (0.06 m off), crossing
/// trial 0 stops 1 cm farther and garage trial 1 3 cm nearer since the
/// local planner's depth stride, like the segmenter's, is scaled to the
/// frame (`CloudParams::stride_for`): at 160 × 120 every column is sampled,
/// so the cells of walkers who crossed in front are seen to move and
/// forgotten once they have gone, instead of standing as a wall.
const PINNED: &str = "crossing 0 succeeded true true +0.03 0 0\n\
crossing 1 succeeded true true +0.06 0 0\n\
garage 0 succeeded true true +0.02 0 0\n\
garage 1 succeeded true true +0.04 0 0\n\
precise 0 succeeded true true +0.02 0 0\n\
precise 1 succeeded true true +0.03 0 0\n\
symmetric 0 succeeded true true +0.07 0 0\n\
symmetric 1 succeeded true true +0.07 0 0";

fn args(out: &std::path::Path) -> vlnav_eval::EvalArgs {
    vlnav_eval::EvalArgs {
        trials: Some(2),
        seed: 11,
        scenarios: vec!["precise".into(), "symmetric".into(), "garage".into(), "crossing".into()],
        modes: vec![Mode::Hybrid],
        out: out.to_path_buf(),
        jobs: 4,
        stall_timeout_s: 120.0,
        no_progress: true,
        perception: PerceptionMode::Realistic,
        ..vlnav_eval::EvalArgs::default()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_seeded_realistic_subset_gives_its_pinned_results() {
    let t = TestStack::start(|a| {
        a.no_robot = true;
        a.perception = PerceptionMode::Realistic;
    })
    .await;
    let out = tempfile::tempdir().unwrap();
    let report = vlnav_eval::run_eval(args(out.path()), t.eval_target()).await.expect("the evaluation runs");
    let mut records = report.records.clone();
    records.sort_by(|a, b| (&a.scenario, a.trial).cmp(&(&b.scenario, b.trial)));
    let got: Vec<String> = records
        .iter()
        .map(|r| {
            format!(
                "{} {} {} {} {} {:+.2} {} {}",
                r.scenario,
                r.trial,
                r.outcome.as_str(),
                r.success(),
                r.success_within(0.25),
                r.stop_error_m(),
                r.contact.hard_events,
                r.contact.pedestrian_events
            )
        })
        .collect();
    let got = got.join("\n");
    println!("{got}");
    assert!(report.markdown.contains("Perception `realistic`"));
    assert_eq!(got, PINNED, "the realistic subset's results moved");
    // One trial re-run alone (`vlnav eval --trial 1`) keeps its seed and
    // gives the same record as in the full run.
    let alone = tempfile::tempdir().unwrap();
    let again =
        vlnav_eval::EvalArgs { scenarios: vec!["symmetric".into()], only_trials: vec![1], ..args(alone.path()) };
    let again = vlnav_eval::run_eval(again, t.eval_target()).await.expect("the trial runs again");
    let line = |csv: &str| csv.lines().find(|l| l.starts_with("symmetric,hybrid,1,")).map(str::to_owned);
    assert_eq!(again.records.len(), 1, "only the trial asked for");
    assert_eq!(line(&again.trials_csv), line(&report.trials_csv), "the same trial, the same record");
    assert!(line(&again.trials_csv).is_some());
    t.stack.shutdown().await.unwrap();
}
